"""Study profiles that sweep plan files (docs/study.md, "Error against the number of measured pairs"):
the plan read when the profile is, cell keys that follow its pairs, the cells measured at its pairs,
the chart of error against the number of pairs, and the shipped ``budget`` profile."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import numpy as np
import pytest

from neuralbrdf.cli.main import main as cli
from neuralbrdf.data.loading import read_brdf_table
from neuralbrdf.data.plans import in_plane_plan
from neuralbrdf.errors import InputError
from neuralbrdf.study.cells import Cell, cell_key, plan_cells
from neuralbrdf.study.profile import load_profile

ROOT = Path(__file__).resolve().parents[1]
DATA = ROOT / "tests" / "data"

BASE = """render: {spp: 2, resolution: 16}
cost: {spp: 2, resolution: 16, repeats: 1, batch: 64}
materials:
  - {name: gold, truth: "virtual:gold"}
variants:
  - {name: abc, method: abc, config: configs/abc.yaml}
stability: {variants: [abc], plans: [DS1, PLAN]}
"""


def _profile(tmp_path: Path, plan: str) -> Path:
    path = tmp_path / "profile.yaml"
    path.write_text(BASE.replace("PLAN", plan))
    return path


def _plan(path: Path, rows: list[str]) -> Path:
    path.write_text("theta_i,theta_r\n" + "".join(row + "\n" for row in rows))
    return path


@pytest.mark.parametrize("plan, rows, said", [
    ("nope.csv", None, "no such file"),
    ("bad.csv", ["30,20", "30,oops"], "line 3"),                              # not a number
    ("twice.csv", ["30,20", "30,20"], "listed twice"),
    ("sphere.csv", None, "out of the plane of incidence"),                    # a spherical, out-of-plane plan
    ("DS9", None, "or an in-plane plan file"),
    ("low", None, "or an in-plane plan file"),
    ("DS4.csv", ["30,20"], "a second plan named 'DS4'"),                      # its stem is a plan's name
    ("my plan.csv", ["30,20"], "without spaces"),
])
def test_a_bad_plan_is_one_line_naming_the_profile_the_key_and_the_file(tmp_path, plan, rows, said):
    if rows is not None:
        _plan(tmp_path / plan, rows)
    if plan == "sphere.csv":
        (tmp_path / plan).write_text("theta_i,phi_i,theta_o,phi_o\n30,0,20,90\n")
    path = _profile(tmp_path, f'"{plan}"')
    with pytest.raises(InputError) as error:
        load_profile(str(path))
    message = str(error.value)
    assert "\n" not in message and str(path) in message and "stability.plans[1]" in message and said in message
    if plan.endswith(".csv") and plan != "DS4.csv":
        assert str(tmp_path / plan) in message  # the plan file itself


def test_plan_files_resolve_beside_the_profile_shipped_or_absolute(tmp_path):
    beside = _plan(tmp_path / "mine.csv", ["30,20", "-30,10"])
    for given in ("mine.csv", str(beside), "configs/plans/nlb_spectral_6.csv"):
        profile = load_profile(str(_profile(tmp_path, given)))
        name = Path(given).stem
        assert profile.stability.plans == ("DS1", name)
        assert Path(profile.stability.plan(name)).is_file() and profile.stability.plan("DS1") == "DS1"
        assert profile.stability.pairs(name) == (2 if name == "mine" else 6)
        assert Cell("gold", "abc", name, 0.0, 0) in plan_cells(profile)


def test_a_plan_files_pairs_are_its_cells_key(tmp_path):
    plan = _plan(tmp_path / "mine.csv", ["30,20", "-30,10"])
    profile_path = _profile(tmp_path, "mine.csv")
    cell = Cell("gold", "abc", "mine", 0.0, 0)

    def key() -> str:
        return cell_key(cell, load_profile(str(profile_path)))

    first = key()
    assert first != cell_key(Cell("gold", "abc", "DS1", 0.0, 0), load_profile(str(profile_path)))
    _plan(plan, ["30.0,20.000", "-30,10"])  # the same pairs written otherwise: the same cells
    assert key() == first
    _plan(plan, ["30,20", "-30,12"])        # another pair: its cells run again
    assert key() != first
    here = key()
    moved = tmp_path / "elsewhere"
    moved.mkdir()
    shutil.move(plan, moved / "mine.csv")
    profile_path.write_text(BASE.replace("PLAN", str(moved / "mine.csv")))
    assert key() == here  # where the file lies does not matter


def test_a_cluster_worker_checks_it_sees_the_plan_file(tmp_path):
    pytest.importorskip("distributed")
    from neuralbrdf.study.cluster import cell_inputs

    material = {"table": None, "truth": "virtual:gold"}
    spec = {"truth": "t.onnx", "variant": {"config": "c.yaml"}, "material": material, "cell": {"plan": "mine"},
            "plan": str(tmp_path / "mine.csv")}
    assert str(tmp_path / "mine.csv") in cell_inputs(spec)
    assert cell_inputs({**spec, "cell": {"plan": "DS4"}, "plan": "DS4"}) == ["t.onnx", "c.yaml"]


@pytest.mark.skipif(not (ROOT.parent / "shared" / "data" / "rgl-nbrdf").is_dir(),
                    reason="the budget profile's RGL validation proxies are reference data (../shared)")
def test_the_budget_profile_sweeps_the_designed_plans_on_validation_materials():
    from neuralbrdf.data.proxy_corpus import RGL_VALIDATION
    from neuralbrdf.virtual.materials import VALIDATION_MATERIALS

    profile = load_profile("budget")
    assert [profile.stability.pairs(p) for p in profile.stability.plans] == [6, 6, 12, 24, 48, 57, 185, 1001]
    truths = {m.truth for m in profile.materials}
    assert {f"virtual:{name}" for name in VALIDATION_MATERIALS} <= truths
    assert {Path(t).stem for t in truths if t.endswith(".h5")} == set(RGL_VALIDATION)
    assert profile.stability.render and {v.name for v in profile.variants} == {"abc", "nlb_spectral", "auto", "pca"}
    assert {v.method for v in profile.variants} == {"abc", "nlb_spectral", "auto", "pca"}
    assert len(plan_cells(profile)) == len(profile.materials) * 4 * 8 == 480


def test_a_study_measures_a_plan_file_and_charts_error_against_pairs(tmp_path):
    out = tmp_path / "study"
    assert cli(["study", "--profile", str(DATA / "study_plans.yaml"), "--out", str(out), "--jobs", "2",
                "--no-progress", "--allow-failures"]) == 0
    study = json.loads((out / "study.json").read_text())
    points = {p["plan"]: p for p in study["points"]}
    assert {plan: p["pairs"] for plan, p in points.items()} == {"DS1": 1001, "DS4": 6, "study_plan": 8}
    for p in points.values():  # every sweep cell rendered: image metrics at every plan
        assert p["error"].get("image_delta_e2000_mean") is not None, p
    table = read_brdf_table(out / "cells" / points["study_plan"]["key"] / "data" / "gold.csv")
    measured = {tuple(np.round(pair, 4)) for pair in np.stack(table.inplane_angles(), axis=1)}
    assert measured == {tuple(np.round(pair, 4)) for pair in np.stack(in_plane_plan(DATA / "study_plan.csv"), axis=1)}
    assert study["figures"]["stability"]["pairs"] == "stability_pairs.png"
    assert (out / "figures" / "stability_pairs.png").is_file()
    assert 'src="figures/stability_pairs.png"' in (out / "index.html").read_text(encoding="utf-8")
