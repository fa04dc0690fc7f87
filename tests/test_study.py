"""The study command (docs/study.md): profile validation, cell keys, aggregation, and end to end on a tiny
profile with the report opened in headless Chromium."""

from __future__ import annotations

import json
import math
import re
import shutil
import subprocess
from pathlib import Path

import pytest
from browser import CHROMIUM, chromium_command

from neuralbrdf.cli.main import main as cli
from neuralbrdf.errors import InputError
from neuralbrdf.study import aggregate
from neuralbrdf.study.cells import Cell, cell_key, cell_settings, is_rendered, plan_cells, pretrained_network
from neuralbrdf.study.profile import load_profile
from neuralbrdf.study.report import NUMBER_FORMAT
from neuralbrdf.study.runner import group_members
from neuralbrdf.shipped import resolve_pretrained

ROOT = Path(__file__).resolve().parents[1]
TINY = ROOT / "tests" / "data" / "study_tiny.yaml"


def _write(tmp_path: Path, text: str) -> Path:
    path = tmp_path / "profile.yaml"
    path.write_text(text)
    return path


BASE = """render: {spp: 2, resolution: 16}
cost: {spp: 2, resolution: 16, repeats: 1, batch: 64}
materials:
  - {name: gold, truth: "virtual:gold"}
variants:
  - {name: abc, method: abc, config: configs/abc.yaml}
"""


@pytest.mark.parametrize("change, key", [
    (("method: abc", "method: ABC"), "variants[0].method"),
    (("configs/abc.yaml", "configs/nope.yaml"), "variants[0].config"),
    (("spp: 2, resolution: 16}\ncost", "spp: 0, resolution: 16}\ncost"), "render.spp"),
    (("truth: \"virtual:gold\"", "truth: gold.csv"), "materials[0].truth"),
    (("variants:", "variant:"), "variant"),
])
def test_profile_errors_name_file_and_key(tmp_path, change, key):
    path = _write(tmp_path, BASE.replace(*change))
    with pytest.raises(InputError) as error:
        load_profile(str(path))
    assert str(path) in str(error.value) and key in str(error.value)


def test_stability_entries_are_checked(tmp_path):
    path = _write(tmp_path, BASE + "stability: {variants: [abc], plans: [DS5]}\n")
    with pytest.raises(InputError, match=r"stability.plans\[0\]"):
        load_profile(str(path))
    path = _write(tmp_path, BASE + "stability: {variants: [mlp]}\n")
    with pytest.raises(InputError, match=r"stability.variants\[0\]"):
        load_profile(str(path))


def test_cells_and_keys(tmp_path):
    profile = load_profile(str(_write(tmp_path, BASE + "stability: {variants: [abc], plans: [DS1, DS4], "
                                                       "noise: [0.0, 0.1], seeds: [0, 1]}\n")))
    cells = plan_cells(profile)
    # per seed: DS1 and DS4 without noise, DS1 with 10 % noise -> 3 conditions x 2 seeds, no duplicates
    assert len(cells) == len(set(cells)) == 6
    assert cells[0] == Cell("gold", "abc", "DS1", 0.0, 0) and cells[0].is_main
    keys = {cell_key(c, profile) for c in cells}
    assert len(keys) == 6
    assert cell_key(cells[1], profile) == cell_key(cells[1], load_profile(str(profile.path)))
    changed = load_profile(str(_write(tmp_path, BASE.replace("configs/abc.yaml}", "configs/abc.yaml, args: [-x]}")
                                      + "stability: {variants: [abc]}\n")))
    assert cell_key(cells[0], changed) != cell_key(cells[0], profile)


def test_sweep_only_variants_are_neither_rendered_nor_timed(tmp_path):
    text = BASE + ("  - {name: g3, method: abc, config: configs/abc.yaml, group: g, label: three, speed_accuracy: false}\n"
                   "stability: {seeds: [0, 1]}\n")
    profile = load_profile(str(_write(tmp_path, text)))
    cells = plan_cells(profile)
    main, sweep = Cell("gold", "abc", "DS1", 0.0, 0), Cell("gold", "g3", "DS1", 0.0, 0)
    assert {main, sweep, Cell("gold", "g3", "DS1", 0.0, 1)} == set(cells)
    assert is_rendered(main, profile) and "render" in cell_settings(main, profile)
    assert sweep.is_main and not is_rendered(sweep, profile)
    assert "render" not in cell_settings(sweep, profile) and "cost" not in cell_settings(sweep, profile)
    with pytest.raises(InputError, match=r"variants\[1\].speed_accuracy"):
        load_profile(str(_write(tmp_path, text.replace("speed_accuracy: false", "speed_accuracy: no-ish"))))


def test_a_fast_variant_studies_the_models_fast_path(tmp_path, monkeypatch):
    """``fast: true`` keys its cells apart (the fast-path settings' file included) and exports the
    fitted model's ``f_fast`` as the cell's model (a model file of its own)."""
    from neuralbrdf.study import cell as cell_module

    text = BASE + "  - {name: abc_fast, method: abc, config: configs/abc.yaml, fast: true}\n"
    profile = load_profile(str(_write(tmp_path, text)))
    assert profile.variant("abc_fast").fast and not profile.variant("abc").fast
    plain, fast = Cell("gold", "abc", "DS1", 0.0, 0), Cell("gold", "abc_fast", "DS1", 0.0, 0)
    assert "fast" in cell_settings(fast, profile)["variant"] and "fast" not in cell_settings(plain, profile)["variant"]
    with pytest.raises(InputError, match=r"variants\[1\].fast"):
        load_profile(str(_write(tmp_path, text.replace("fast: true", "fast: quickly"))))
    calls = []
    monkeypatch.setattr("neuralbrdf.onnx_export.export_checkpoint", lambda ckpt, out: calls.append(("export", out)))
    monkeypatch.setattr(cell_module.subprocess, "run", lambda command, **kwargs: calls.append(("add", command)) or
                        subprocess.CompletedProcess(command, 0, "", ""))
    monkeypatch.setattr(cell_module, "fast_path_alone", lambda model, output, out: calls.append(("alone", output, out)))
    out = tmp_path / "model.onnx"
    assert cell_module.export({"variant": {"method": "abc", "fast": True}}, tmp_path / "run", out) == out
    assert [c[0] for c in calls] == ["export", "add", "alone"] and calls[2][1:] == ("f_fast", out)
    assert calls[1][1][2:4] == ["neuralbrdf", "export"] and "--fast" in calls[1][1]  # neuralbrdf export --fast
    monkeypatch.setattr(cell_module.subprocess, "run", lambda command, **kwargs: subprocess.CompletedProcess(
        command, 1, "", "error: x.onnx not written: the f_fast student renders ΔE2000 0.9 away"))
    with pytest.raises(cell_module.CellFailure, match="not written"):
        cell_module.export({"variant": {"method": "abc", "fast": True}}, tmp_path / "run", out)


def test_a_variant_fits_only_the_materials_it_names(tmp_path):
    text = BASE.replace("variants:", '  - {name: cyan, truth: "virtual:cyan"}\nvariants:') + (
        "  - {name: mlp, method: spectral_mlp, config: configs/spectral_mlp.yaml, materials: [cyan]}\n")
    cells = plan_cells(load_profile(str(_write(tmp_path, text))))
    assert [(c.material, c.variant) for c in cells] == [("gold", "abc"), ("cyan", "abc"), ("cyan", "mlp")]
    with pytest.raises(InputError, match=r"variants\[1\].materials\[0\].*no material named 'cyn'"):
        load_profile(str(_write(tmp_path, text.replace("[cyan]}", "[cyn]}"))))


def test_nlb_keys_follow_the_pretrained_networks_contents(tmp_path):
    import shutil

    from neuralbrdf.shipped import PRETRAINED_DEFAULT

    network = tmp_path / "net.ckpt"
    shutil.copy(PRETRAINED_DEFAULT, network)
    variants = ("variants:\n  - {name: nlb, method: nlb, config: configs/nlb_latent.yaml, args: [--model.checkpoint, NET]}\n"
                "  - {name: shipped, method: nlb, config: configs/nlb_latent.yaml}\n"
                "  - {name: by_name, method: nlb, config: configs/nlb_latent.yaml, args: [--model.checkpoint, nlb_latent32_blends]}\n")
    text = BASE.split("variants:")[0] + variants.replace("NET", str(network))
    profile = load_profile(str(_write(tmp_path, text)))
    key = {v: cell_key(Cell("gold", v, "DS1", 0.0, 0), profile) for v in ("nlb", "shipped", "by_name")}
    assert profile.variant("shipped").args == () and pretrained_network(profile.variant("by_name")) == "nlb_latent32_blends"
    settings = {v: cell_settings(Cell("gold", v, "DS1", 0.0, 0), profile)["variant"]["pretrained"] for v in key}
    assert settings["nlb"] == settings["shipped"] == settings["by_name"]  # the same bytes, three names
    network.write_bytes(network.read_bytes() + b"retrained")
    assert cell_key(Cell("gold", "nlb", "DS1", 0.0, 0), profile) != key["nlb"]
    assert cell_key(Cell("gold", "shipped", "DS1", 0.0, 0), profile) == key["shipped"]


def test_keys_follow_the_contents_of_config_overlays_in_the_arguments(tmp_path):
    overlay = tmp_path / "overlay.yaml"
    overlay.write_text("model:\n  init_args:\n    n_starts: 2\n")
    variants = (f"variants:\n  - {{name: abc, method: abc, config: configs/abc.yaml}}\n"
                f"  - {{name: two, method: abc, config: configs/abc.yaml, args: [--config, {overlay}]}}\n"
                f"  - {{name: joined, method: abc, config: configs/abc.yaml, args: [--config={overlay}]}}\n")
    profile = load_profile(str(_write(tmp_path, BASE.split("variants:")[0] + variants)))
    key = {v: cell_key(Cell("gold", v, "DS1", 0.0, 0), profile) for v in ("abc", "two", "joined")}
    assert "overlays" not in cell_settings(Cell("gold", "abc", "DS1", 0.0, 0), profile)["variant"]
    overlay.write_text("model:\n  init_args:\n    n_starts: 3\n")
    assert cell_key(Cell("gold", "two", "DS1", 0.0, 0), profile) != key["two"]
    assert cell_key(Cell("gold", "joined", "DS1", 0.0, 0), profile) != key["joined"]  # --config=PATH too
    assert cell_key(Cell("gold", "abc", "DS1", 0.0, 0), profile) == key["abc"]


def test_pooled_points_use_only_the_materials_every_model_fits():
    def main(material, model, ratio, delta_e):
        return {"material": material, "model": model, "method": model, "is_main": True, "failure": None,
                "cost": {"render_ratio": ratio}, "error": {"image_delta_e2000_mean": delta_e}}

    points = [main("gold", "abc", 1.0, 0.5), main("nylon", "abc", 1.0, 9.0),
              main("gold", "mlp", 1.2, 0.4)]  # the MLP cannot fit nylon (RGB)
    pooled = {q["model"]: q for q in aggregate.pooled_points(points, "render_ratio")}
    assert pooled["abc"]["materials"] == ["gold"] and pooled["abc"]["image_delta_e2000_mean"] == 0.5
    assert aggregate.pooled_points(points + [main("nylon", "nlb", 3.0, 1.0)], "render_ratio") == []


def test_group_tables_take_medians_over_seeds_on_shared_materials():
    from neuralbrdf.study.report import _group_tables

    def point(material, model, seed, value, plan="DS1"):
        return {"material": material, "model": model, "plan": plan, "noise": 0.0, "seed": seed,
                "error": {"hemisphere_logcos_rmse": value}}

    points = [point("gold", "a", s, v) for s, v in enumerate((0.1, 0.3, 0.2))]
    points += [point("gold", "b", s, v) for s, v in enumerate((0.5, 0.4))]
    points += [point("cyan", "a", 0, 0.7), point("cyan", "b", 0, 0.9),
               point("nylon", "a", 0, 0.01),  # b has no nylon: left out of both rows
               point("gold", "a", 3, 9.0, plan="DS4")]  # not DS1: left out
    [table] = aggregate.groups(points, {"size": [("one", "a"), ("two", "b")]}, ["nylon", "cyan", "gold"])
    assert table["group"] == "size" and table["materials"] == ["cyan", "gold"]
    a, b = table["members"]
    assert (a["label"], a["model"], b["label"]) == ("one", "a", "two")
    assert [v["median"] for v in a["per_material"]] == [0.7, 0.2]
    assert [v["median"] for v in b["per_material"]] == [0.9, pytest.approx(0.45)]
    assert a["median"] == pytest.approx(0.45) and b["median"] == pytest.approx(0.675)
    assert (a["cells"], b["cells"]) == (4, 3)
    study = {"groups": [table]}
    shown = re.findall(r'data-json="([^"]+)">([^<]+)<', _group_tables(study))
    assert len(shown) == 2 * 4
    for path, value in shown:
        assert value == NUMBER_FORMAT.format(_lookup(study, path))


def test_place_labels_keeps_labels_apart_and_inside_their_axes():
    import matplotlib.pyplot as plt

    from neuralbrdf.study.charts import layout_problems, place_labels

    fig, ax = plt.subplots(figsize=(6, 4), dpi=100)
    ax.set_xlim(0, 5)
    ax.set_ylim(0, 5)
    points = [(1.0, 1.0), (1.02, 1.01), (1.01, 1.0), (3.0, 4.0), (1.0, 1.03), (4.95, 2.0), (4.9, 2.02)]
    labels = [ax.annotate(f"spectral_mlp_{i}", xy, xytext=(4, 2), textcoords="offset points", fontsize=9,
                          arrowprops={"arrowstyle": "-"}) for i, xy in enumerate(points)]
    before = layout_problems(fig)
    assert any("overlap" in p for p in before) and any("leaves its axes" in p for p in before)
    place_labels(ax, labels)
    assert layout_problems(fig) == []
    assert labels[3].xyann == (4, 2)  # a label alone stays beside its point
    plt.close(fig)


def test_layout_problems_names_small_cut_off_and_overlapping_text():
    import matplotlib.pyplot as plt

    from neuralbrdf.study.charts import layout_problems

    fig, ax = plt.subplots(figsize=(4, 3), dpi=100)
    ax.set_title("fine title", fontsize=10)
    fig.text(0.1, 0.5, "tiny", fontsize=7)  # 9.7 px at 100 dpi
    fig.text(0.9, 0.9, "runs past the right edge")
    fig.text(0.3, 0.3, "first"), fig.text(0.31, 0.3, "second")
    problems = layout_problems(fig)
    assert "'tiny' is 9.7 px" in problems
    assert "'runs past the right edge' is cut off by the figure's edge" in problems
    assert "'second' and 'first' overlap" in problems
    assert not any("fine title" in p for p in problems)
    plt.close(fig)


def test_tick_labels_are_slanted_only_when_neighbours_would_touch():
    import matplotlib.pyplot as plt

    from neuralbrdf.study.charts import rotate_crowded_ticks

    def ticks(labels):
        fig, ax = plt.subplots(figsize=(6, 4))
        ax.set_xticks(range(len(labels)), labels)
        ax.set_xlim(-0.5, len(labels) - 0.5)
        return fig, ax

    # the latent-size group at its figure width: short labels on average (the old rule left them
    # level), but "32" stood 8 px from "32 (from scratch)" and read as one label
    fig, ax = ticks(["16 (shipped)", "4", "8", "16", "32", "32 (from scratch)"])
    assert rotate_crowded_ticks(ax)
    assert {label.get_rotation() for label in ax.get_xticklabels()} == {25.0}
    plt.close(fig)
    fig, ax = ticks(["DS1", "DS2", "DS3", "DS4"])
    assert not rotate_crowded_ticks(ax)
    assert {label.get_rotation() for label in ax.get_xticklabels()} == {0.0}
    plt.close(fig)


def test_pareto_front_against_brute_force():
    items = [("a", 1.0, 5.0), ("b", 2.0, 3.0), ("c", 3.0, 3.5), ("d", 0.5, 9.0), ("e", 4.0, 1.0), ("f", 4.0, 1.0)]
    assert aggregate.pareto_front(items) == ["d", "a", "b", "e", "f"]
    assert aggregate.pareto_front([]) == []


def _point(model, plan, noise, seed, error, failure=None, material="m", main=False, ratio=1.0, delta_e=1.0):
    return {"material": material, "variant": model, "plan": plan, "noise": noise, "seed": seed, "is_main": main,
            "failure": failure, "message": None,
            "cost": {"render_ratio": ratio, "fit_time_s": 1.0} if main else {"fit_time_s": 1.0},
            "error": {"hemisphere_logcos_rmse": error, "image_delta_e2000_mean": delta_e}}


def test_threshold_failures_and_budgets():
    results = [
        _point("x", "DS1", 0.0, 0, 0.010, main=True, ratio=2.0, delta_e=1.5),
        _point("x", "DS1", 0.0, 1, 0.012),
        _point("x", "DS4", 0.0, 0, 0.030),     # > 2 x median(0.010, 0.012) = 0.022
        _point("x", "DS2", 0.0, 0, 0.020),
        _point("y", "DS1", 0.0, 0, None, failure="export_refused", main=True),
        _point("z", "DS1", 0.0, 0, 0.5, main=True, ratio=0.5, delta_e=8.0),
    ]
    points = aggregate.points_from_results(results, {"x": "abc", "y": "nlb", "z": "abc"}, aggregate.NAMED_PAIRS)
    assert [p["failure"] for p in points] == [None, None, "error_above_2x_ds1", None, "export_refused", None]
    assert points[3]["cost"]["render_ratio"] == 2.0  # the variant's main-cell cost
    rows = {(r["model"], r["condition"]): r for r in aggregate.failures(points)}
    assert rows[("x", "DS4")]["causes"] == {"error_above_2x_ds1": 1} and rows[("x", "DS1")]["failed"] == 0
    assert math.isclose(rows[("x", "DS1")]["median_error"], 0.011)
    assert math.isclose(rows[("x", "DS1")]["seed_std_error"], 0.002 / math.sqrt(2))
    assert rows[("x", "DS4")]["seed_std_error"] is None
    budget = {b["budget_delta_e"]: b["model"] for b in aggregate.budgets(points)}
    assert budget == {1.0: None, 2.0: "x", 5.0: "x", 10.0: "z"}
    assert aggregate.pareto(points)["render_ratio"]["per_material"]["m"] == ["z", "x"]
    sentences = aggregate.method_sentences(points, aggregate.failures(points))
    assert "DS4" in sentences["x"] and "no failure" in sentences["z"]
    assert "6 in-plane pairs instead of DS1's 1001" in sentences["x"]  # why: what DS4 takes from the fit
    assert aggregate.condition_change("DS1 10% noise", 1001) == "10% relative noise on every sample"
    assert set(aggregate.CAUSE_MEANING) == set(aggregate.CAUSES)
    # a seed that fails at DS1 without noise: no condition to blame, the general meaning
    rows = [{"model": "g", "condition": "DS1", "pairs": 1001, "cells": 10, "failed": 1, "causes": {"error_above_2x_ds1": 1}}]
    sentence = aggregate.method_sentences([{"model": "g", "failure": "error_above_2x_ds1", "message": None}], rows)["g"]
    assert "the reference condition: this seed's fit is far from the others'" in sentence


def _lookup(study: dict, path: str):
    value = study
    for part in path.split("."):
        value = value[int(part)] if isinstance(value, list) else value[part]
    return value


SYNTHETIC_MODELS = ("abc", "nlb", "nlb_compact", "nlb_64x4", "nlb_report_recipe", "spectral_mlp", "spectral_mlp_paper",
                    "spectral_mlp_2x8", "spectral_mlp_3x20", "spectral_mlp_4x32", "spectral_mlp_relu", "spectral_mlp_in_rgb")
LATENT_GROUP = [("32, blends + prior (default)", "nlb"), ("16 (nlb_compact)", "nlb_compact"), ("4", "nlb_64x4"),
                ("32 (from scratch)", "nlb_report_recipe")]


def synthetic_study(crashed: int = 0) -> dict:
    """A study.json as the full profile's: twelve models, most of them crowded at one cost and
    error, per-angle data (31 wavelengths on gold, RGB on nylon, none on cyan), sweeps over plans,
    noise and seeds, a variant group with long labels, and ``crashed`` cells without a result."""
    import numpy as np

    from neuralbrdf.study.cost import machine

    rng = np.random.default_rng(7)
    angles = list(np.arange(-60.0, 60.1, 5.0))
    results = []
    for material, channels in (("gold", list(np.arange(400.0, 701.0, 10.0))), ("cyan", list(np.arange(400.0, 701.0, 10.0))),
                               ("nylon", ["R", "G", "B"])):
        for k, model in enumerate(SYNTHETIC_MODELS):
            if material == "nylon" and model.startswith("spectral"):
                continue
            crowded = model.startswith("spectral_mlp_")
            cost = {"render_ratio": 1.0 + (0.01 * k if crowded else 0.3 * k), "mqueries_per_s": 10.0, "parameters": 100 + k,
                    "fit_time_s": 20.0 + (0.2 * k if crowded else 3.0 * k)}
            error = {"hemisphere_logcos_rmse": 0.01 + 0.001 * k, "image_delta_e2000_mean": 0.3 + (0.01 * k if crowded else 0.4 * k),
                     "image_delta_e2000_p95": 1.5}
            per_angle = {"theta_i_deg": angles, "glossy_rel_rmse": list(0.01 + 0.01 * rng.random(len(angles))),
                         "channels": channels, "per_channel": [list(0.01 + 0.05 * rng.random(len(channels))) for _ in angles]}
            results.append({"material": material, "variant": model, "plan": "DS1", "noise": 0.0, "seed": 0, "is_main": True,
                            "failure": None, "message": None, "cost": cost, "error": error,
                            "per_angle": None if material == "cyan" else per_angle, "key": f"{material}-{model}"})
            sweeps = [(plan, 0.0, seed) for plan in ("DS1", "DS2", "DS3", "DS4") for seed in range(3)][1:] + [
                ("DS1", noise, seed) for noise in (0.01, 0.1) for seed in range(3)] if model in ("abc", "nlb", "spectral_mlp") else (
                [("DS1", 0.0, seed) for seed in (1, 2)] if model in dict(map(reversed, LATENT_GROUP)) else [])
            for plan, noise, seed in sweeps:
                results.append({"material": material, "variant": model, "plan": plan, "noise": noise, "seed": seed,
                                "is_main": False, "failure": None, "message": None, "cost": {"fit_time_s": 1.0},
                                "error": {"hemisphere_logcos_rmse": 0.01 * (1 + int(plan[2]) ** 2 * rng.random())}})
    for i in range(crashed):
        results[-1 - i] = {**results[-1 - i], "failure": "cell_crashed", "error": {},
                           "message": "the cell's worker process died: Killed (log: cells/x/log.txt)"}
    methods = {m: "abc" if m == "abc" else "nlb" if m.startswith("nlb") else "spectral_mlp" for m in SYNTHETIC_MODELS}
    points = aggregate.points_from_results(results, methods, aggregate.NAMED_PAIRS)
    failures = aggregate.failures(points)
    return {"format": 1, "points": points, "pareto": aggregate.pareto(points), "failures": failures,
            "failure_causes": list(aggregate.CAUSES), "summary": aggregate.budgets(points),
            "groups": aggregate.groups(points, {"NLB latent size": LATENT_GROUP}, ["gold", "cyan", "nylon"]),
            "sentences": aggregate.method_sentences(points, failures), "machine": machine(),
            "run": {"profile": "configs/study/full.yaml", "command": "neuralbrdf study --profile full --out DIR --jobs 2",
                    "jobs": 2, "seeds": [0, 1, 2], "started": "2026-12-02T14:11:20+00:00", "cells_run": len(points),
                    "cells_cached": 0, "hemisphere_pairs": 6400}}


@pytest.fixture(scope="module")
def synthetic(tmp_path_factory):
    """:func:`synthetic_study` with two crashed cells, its figures drawn once into a folder, and
    what :func:`~neuralbrdf.study.charts.layout_problems` and the width said of each figure."""
    from neuralbrdf.study import charts, figures

    folder = tmp_path_factory.mktemp("synthetic")
    study = synthetic_study(crashed=2)
    problems, widths = {}, {}
    save = charts._save

    def checked(fig, path):
        problems[path.name] = charts.layout_problems(fig)
        widths[path.name] = fig.bbox.width
        return save(fig, path)

    with pytest.MonkeyPatch.context() as patch:
        patch.setattr(charts, "_save", checked)
        figs = figures.write_figures(study, folder)
    return {"study": study, "figures": figs, "folder": folder, "problems": problems, "widths": widths}


def test_every_chart_is_legible_at_its_own_size(synthetic):
    """Each figure of a study as crowded as the full one: no text under 11 px, none cut off or over
    another, every point label inside its axes; no wider than the page shows unscaled."""
    from neuralbrdf.study.charts import FULL_WIDTH_PX

    figs = synthetic["figures"]
    assert set(figs["stability"]) == {"plans", "noise", "pairs", "group NLB latent size"}
    assert set(figs["rel_rmse_vs_angle"]) == set(figs["per_channel"]) == {"gold", "nylon"}
    assert len(synthetic["problems"]) == 1 + 3 + 4 + 1 + 2 + 2
    assert {name: p for name, p in synthetic["problems"].items() if p} == {}
    assert max(synthetic["widths"].values()) <= FULL_WIDTH_PX


def test_speed_accuracy_axes_start_at_zero_with_room_above_the_highest_point(tmp_path, monkeypatch):
    """Two models of nearly one ΔE: the axis is not a sliver around them with both at its top edge."""
    from neuralbrdf.study import charts

    drawn = []
    monkeypatch.setattr(charts, "_save", lambda fig, path: drawn.append(fig) or path.name)
    entries = [{"model": "abc", "method": "abc", "render_ratio": 1.1, "fit_time_s": 0.8, "image_delta_e2000_mean": 1.0194},
               {"model": "nlb", "method": "nlb", "render_ratio": 5.2, "fit_time_s": 2.3, "image_delta_e2000_mean": 1.0165}]
    charts.speed_accuracy(entries, {}, "nylon", tmp_path / "s.png")
    for ax in drawn[0].axes:
        assert ax.get_ylim() == pytest.approx((0.0, 1.15 * 1.0194))
    assert charts.layout_problems(drawn[0]) == []


def test_distinct_budget_rows_merge_neighbouring_budgets_that_choose_one_model():
    from neuralbrdf.study.report import distinct_budget_rows

    def row(material, budget, model):
        return {"material": material, "budget_delta_e": budget, "model": model}

    summary = [row("gold", 1, "relu"), row("gold", 2, "relu"), row("gold", 5, "abc"), row("gold", 10, "abc"),
               row("acrylic", 1, None), row("acrylic", 2, "abc"), row("acrylic", 5, "abc"), row("cyan", 1, "abc")]
    assert [(r["material"], r["model"], r["first"], r["last"]) for r in distinct_budget_rows(summary)] == [
        ("gold", "relu", 0, 1), ("gold", "abc", 2, 3), ("acrylic", None, 4, 4), ("acrylic", "abc", 5, 6), ("cyan", "abc", 7, 7)]


def test_report_leads_with_status_recommendation_and_pooled_chart(synthetic):
    from neuralbrdf.study.report import write_report

    study = synthetic["study"]
    page = write_report(study, synthetic["figures"], synthetic["folder"]).read_text(encoding="utf-8")
    order = [page.index(marker) for marker in (
        '<div class="status bad"><b>2 of', '<div class="status warn">', "<h2>Which model to use</h2>", 'class="rec"',
        "speed_accuracy_pooled.png", "<details>")]
    assert order == sorted(order)
    top = page[:page.index("<details>")]
    assert top.count("worker process died") == 2  # each crashed cell named at the top
    recommended = re.findall(r'<tr>(?:<td class="t m"[^>]*>[^<]*</td>)?<td>(.*?)</td><td class="t"><b>([^<]+)</b>', top)
    assert len(recommended) == len({(budget, model) for budget, model in recommended}) < len(study["summary"])
    assert "–" in recommended[0][0]  # budgets 1 to 10 that choose one model: one row
    assert "runs.jsonl" not in page and "history" not in page
    assert page.count("<details>") == 7 and 'alt=""' not in page


def test_report_says_when_every_cell_gave_a_result(synthetic, tmp_path):
    from neuralbrdf.study.report import write_report

    study = {**synthetic["study"], "points": [dict(p, failure=None) for p in synthetic["study"]["points"]]}
    shutil.copytree(synthetic["folder"] / "figures", tmp_path / "figures")
    page = write_report(study, synthetic["figures"], tmp_path).read_text(encoding="utf-8")
    assert f'<div class="status ok">Every one of the {len(study["points"])} cells gave a model.</div>' in page
    assert "status bad" not in page and "status warn" not in page
    assert "Over seeds 0, 1, 2 on gold, cyan, nylon (DS1, no noise)." in page
    points = [dict(p) for p in study["points"]]
    points[3]["failure"], points[3]["message"] = "non_finite_loss", "loss is nan at step 12"
    page = write_report({**study, "points": points, "health": {"repaired": [{"file": "x", "problem": "y"}]}},
                        synthetic["figures"], tmp_path).read_text(encoding="utf-8")
    assert (f'<div class="status bad"><b>1 of {len(points)} cells failed and have no model</b> (non-finite loss: 1)'
            in page) and "loss is nan at step 12" in page
    assert "1 cached file was damaged or stale and redone." in page


PROBE = """<script>
window.__errors = [];
window.addEventListener('error', e => window.__errors.push(String(e.message || e.target && e.target.src)), true);
window.addEventListener('load', () => {
  const collapsedHeight = document.documentElement.scrollHeight;
  const fonts = [];
  const walker = document.createTreeWalker(document.body, NodeFilter.SHOW_TEXT);
  while (walker.nextNode()) {
    const node = walker.currentNode;
    if (node.textContent.trim())
      fonts.push([parseFloat(getComputedStyle(node.parentElement).fontSize), node.textContent.trim().slice(0, 60)]);
  }
  document.querySelectorAll('details').forEach(d => { d.open = true; });
  const out = {images: [...document.images].map(i => [i.getAttribute('src'), i.naturalWidth,
                                                      i.getBoundingClientRect().width, i.getAttribute('alt') || '']),
               numbers: [...document.querySelectorAll('[data-json]')].map(e => [e.dataset.json, e.textContent]),
               fonts: fonts, collapsedHeight: collapsedHeight,
               expandedHeight: document.documentElement.scrollHeight, errors: window.__errors};
  const pre = document.createElement('pre'); pre.id = 'probe'; pre.textContent = JSON.stringify(out);
  document.body.appendChild(pre);
});
</script>"""
#: The page's width the report is checked at, and the most it may be tall with its details closed.
PAGE_WIDTH_PX = 1400
MAX_COLLAPSED_HEIGHT_PX = 15000


def check_in_browser(out_dir: Path) -> dict:
    """Open ``out_dir/index.html`` (with a probe script added, from a copy in a temporary folder)
    in headless Chromium 1400 px wide; assert images, alt texts, console, numbers, that no text is
    under 11 px, that no figure is shown smaller than drawn, and the height with details closed."""
    import html
    import tempfile

    from neuralbrdf.study.charts import MIN_TEXT_PX

    page = (out_dir / "index.html").read_text(encoding="utf-8")
    assert "<script" not in page and "http://" not in page and "https://" not in page  # static, nothing fetched
    base = f'<base href="{out_dir.resolve().as_uri()}/">'
    with tempfile.TemporaryDirectory() as scratch:
        probe = Path(scratch) / "probe.html"
        probe.write_text(page.replace("<head>", "<head>" + base + PROBE, 1), encoding="utf-8")
        run = subprocess.run(
            chromium_command(Path(scratch) / "profile", "--allow-file-access-from-files",
                             f"--window-size={PAGE_WIDTH_PX},1000", "--enable-logging=stderr", "--v=0",
                             "--virtual-time-budget=20000", "--dump-dom", probe.as_uri()),
            capture_output=True, text=True, timeout=180)
    found = re.search(r'<pre id="probe">(.*?)</pre>', run.stdout, re.S)
    assert found, run.stderr[-2000:]
    result = json.loads(html.unescape(found.group(1)))
    console = [line for line in run.stderr.splitlines() if "CONSOLE" in line]
    assert not console, console
    assert not result["errors"], result["errors"]
    assert result["images"] and all(natural > 0 for _, natural, _, _ in result["images"]), result["images"]
    assert all(alt.strip() for *_, alt in result["images"]), [src for src, *_, alt in result["images"] if not alt.strip()]
    shrunk = [(src, natural, shown) for src, natural, shown, _ in result["images"] if shown < natural - 0.5]
    assert not shrunk, shrunk  # chart text is >= 11 px only at the chart's own size
    small = [(size, text) for size, text in result["fonts"] if size < MIN_TEXT_PX]
    assert not small, small[:5]
    assert result["collapsedHeight"] <= MAX_COLLAPSED_HEIGHT_PX, result["collapsedHeight"]
    study = json.loads((out_dir / "study.json").read_text())
    assert result["numbers"]
    for path, shown in result["numbers"]:
        value = _lookup(study, path)
        if value is None:
            assert shown == "–", path
        else:
            assert shown == NUMBER_FORMAT.format(value), (path, shown, value)
            assert math.isclose(float(shown), value, rel_tol=1e-3, abs_tol=1e-12)
    return result


@pytest.mark.skipif(CHROMIUM is None, reason="needs Debian's chromium (installed by .ci/run)")
@pytest.mark.parametrize("folder", ["docs/study", "docs/study/spectral", "docs/study/full"])
def test_committed_reports_read_at_100_percent(folder):
    """The reports in the repository: legible at 1400 px, short with details closed, every figure
    with alt text and at its own size, every number as in their study.json."""
    result = check_in_browser(ROOT / folder)
    assert min(size for size, _ in result["fonts"]) >= 11


@pytest.mark.slow
@pytest.mark.parametrize("folder", ["docs/study", "docs/study/spectral", "docs/study/full"])
def test_committed_reports_are_what_their_study_json_draws(folder, tmp_path):
    """``neuralbrdf study --report-only`` on a copy of the committed study.json (and the renders the
    study copied from its cells) gives the committed page and the same figure files (redraw them
    after changing the report)."""
    from neuralbrdf.study.report import rebuild

    shutil.copy(ROOT / folder / "study.json", tmp_path / "study.json")
    renders = ROOT / folder / "figures" / "renders"  # copies of the cells' renders: inputs, not drawn
    if renders.is_dir():
        shutil.copytree(renders, tmp_path / "figures" / "renders")
    rebuild(tmp_path)
    assert (tmp_path / "index.html").read_text(encoding="utf-8") == (ROOT / folder / "index.html").read_text(encoding="utf-8")
    assert (tmp_path / "study.json").read_bytes() == (ROOT / folder / "study.json").read_bytes()
    names = sorted(p.relative_to(tmp_path).as_posix() for p in (tmp_path / "figures").rglob("*.png"))
    assert names == sorted(p.relative_to(ROOT / folder).as_posix() for p in (ROOT / folder / "figures").rglob("*.png"))


@pytest.mark.skipif(CHROMIUM is None, reason="needs Debian's chromium (installed by .ci/run)")
def test_tiny_study_end_to_end(tmp_path, capsys):
    out = tmp_path / "study"
    assert cli(["study", "--profile", str(TINY), "--out", str(out), "--jobs", "2", "--no-progress"]) == 0
    study = json.loads((out / "study.json").read_text())
    points = study["points"]
    assert [(p["model"], p["plan"]) for p in points] == [("abc", "DS1"), ("spectral_mlp", "DS1")]
    for p in points:
        assert set(p) >= {"material", "model", "plan", "noise", "seed", "cost", "error", "failure"}
    for p in points:  # the main cells ran, were timed against roughconductor and rendered
        assert p["failure"] is None, p["message"]
        assert p["cost"]["render_ratio"] > 0 and p["cost"]["mqueries_per_s"] > 0 and p["cost"]["parameters"] > 0
        assert p["error"]["image_delta_e2000_mean"] >= 0 and p["error"]["hemisphere_logcos_rmse"] > 0
    assert set(study["pareto"]["render_ratio"]["pooled"]) <= {"abc", "spectral_mlp"}
    assert study["pareto"]["render_ratio"]["pooled"]
    assert [(f["condition"], f["cells"]) for f in study["failures"]] == [("DS1", 1), ("DS1", 1)]
    result = check_in_browser(out)
    assert len(result["images"]) >= 6
    assert {"figures/renders/gold/truth.png", "figures/renders/gold/abc.png"} <= {src for src, *_ in result["images"]}
    assert all(p.get("per_angle") for p in points)  # the data of the per-angle charts is in study.json
    # a second run with nothing new reuses every cell, and study.json still keeps the run that made them
    assert cli(["study", "--profile", str(TINY), "--out", str(out), "--no-progress"]) == 0
    again = json.loads((out / "study.json").read_text())
    assert again["run"]["cells_run"] == 0 and again["run"]["cells_cached"] == 2
    assert [p["error"] for p in again["points"]] == [p["error"] for p in points]
    history = again["run"]["history"]
    assert [(h["cells_run"], h["cells_cached"]) for h in history] == [(2, 0), (0, 2)]
    assert history[0]["wall_time_s"] == study["run"]["wall_time_s"]
    # the page is drawn again from study.json alone: no cell folder, figures and renders as before
    shutil.rmtree(out / "cells")
    (out / "index.html").unlink()
    for figure in (out / "figures").glob("*.png"):
        figure.unlink()
    (out / "figures" / "left_over.png").write_bytes(b"an earlier report's figure")
    before = (out / "study.json").read_text()
    assert cli(["study", "--report-only", "--out", str(out)]) == 0
    assert (out / "study.json").read_text() == before  # its figures were already listed: nothing changed
    assert not (out / "figures" / "left_over.png").exists()
    assert check_in_browser(out)["images"] == result["images"]


def test_report_only_and_missing_profile_are_one_line_errors(tmp_path, capsys):
    assert cli(["study", "--report-only", "--out", str(tmp_path)]) == 2
    error = capsys.readouterr().err.strip()
    assert error.count("\n") == 0 and str(tmp_path / "study.json") in error and "no study.json here" in error
    (tmp_path / "study.json").write_text('{"points": []}')
    assert cli(["study", "--report-only", "--out", str(tmp_path)]) == 2
    assert "missing key(s) pareto, failures" in capsys.readouterr().err
    assert cli(["study", "--out", str(tmp_path)]) == 2
    assert "--profile is required" in capsys.readouterr().err
    assert not (tmp_path / "index.html").exists()


def test_a_cell_that_ends_without_a_result_replaces_what_was_in_its_folder_with_its_log(tmp_path):
    """A cell that ended without result.json (here a real worker given a spec it cannot run) is
    ``cell_crashed``, and its folder holds its own record (cell.json, log.txt) in place of what an
    earlier run left there; nothing of its attempt folder stays beside it."""
    from neuralbrdf.study.workers import CellWorker, run_in_worker

    cell = Cell("gold", "abc", "DS1", 0.0, 0)
    spec = {"cell": vars(cell), "key": "k", "truth_sha256": "t", "is_main": True, "not": "a cell"}
    folder = tmp_path / "k"
    folder.mkdir()
    (folder / "stale.txt").write_text("left over")
    worker = CellWorker()
    try:
        result = run_in_worker(spec, tmp_path, worker)
    finally:
        worker.close()
    assert result["failure"] == "cell_crashed" and "cells/k/log.txt" in result["message"]
    assert result["is_main"]  # as the spec said: a crashed main cell still marks its (material, variant)
    assert sorted(p.name for p in folder.iterdir()) == ["cell.json", "log.txt"]
    assert "KeyError" in (folder / "log.txt").read_text()
    assert [p.name for p in tmp_path.iterdir()] == ["k"]


FAKE_CELL = ("import json, os, sys; from pathlib import Path; import neuralbrdf.study.cell as c; "
             "c._import_fitting = lambda: None; "
             "c.run_cell = lambda folder: os._exit(3) if json.loads((folder / 'cell.json').read_text())['key'] == 'crash' "
             "else (folder / 'result.json').write_text('{\"pid\": %d}' % os.getpid()); c.serve()")


def test_a_cell_that_kills_its_worker_is_reported_and_the_worker_replaced(tmp_path):
    """Crash isolation of the persistent workers: the dead worker's cell is ``cell_crashed``, the next
    cell runs in a new process, and a worker serves several cells."""
    import sys

    from neuralbrdf.study.workers import CellWorker, run_in_worker

    def spec(key, cell):
        return {"cell": vars(cell), "key": key, "truth_sha256": "t", "is_main": False}

    worker = CellWorker((sys.executable, "-c", FAKE_CELL))
    try:
        first = run_in_worker(spec("ok1", Cell("gold", "abc", "DS1", 0.0, 0)), tmp_path, worker)
        second = run_in_worker(spec("ok2", Cell("gold", "abc", "DS1", 0.0, 1)), tmp_path, worker)
        assert first["pid"] == second["pid"]  # one process ran both
        crashed = run_in_worker(spec("crash", Cell("gold", "abc", "DS2", 0.0, 0)), tmp_path, worker)
        assert crashed["failure"] == "cell_crashed" and "worker process died" in crashed["message"]
        after = run_in_worker(spec("ok3", Cell("gold", "abc", "DS3", 0.0, 0)), tmp_path, worker)
        assert after["pid"] != first["pid"]
    finally:
        worker.close()
    assert sorted(p.name for p in tmp_path.iterdir()) == ["crash", "ok1", "ok2", "ok3"]


def test_a_stopped_cell_leaves_nothing(tmp_path):
    """A cell stopped while it runs (its cluster task cancelled) has its worker killed and its
    attempt folder removed: no cell folder appears."""
    import sys
    import time

    from neuralbrdf.study.workers import CellStopped, CellWorker, run_in_worker

    started = tmp_path / "started"
    endless = ("import sys, time\nfor line in sys.stdin:\n    open(%r, 'w').write(line)\n    time.sleep(600)\n"
               % str(started))
    worker = CellWorker((sys.executable, "-c", endless))
    cells = tmp_path / "cells"
    deadline = time.monotonic() + 60
    try:
        with pytest.raises(CellStopped):
            run_in_worker({"cell": {}, "key": "k", "is_main": False}, cells, worker,
                          should_stop=lambda: started.is_file() or time.monotonic() > deadline)
        assert worker.process is None
    finally:
        worker.close()
    assert started.is_file() and list(cells.iterdir()) == []


def test_worker_logs_each_cell_and_answers_once(tmp_path, monkeypatch):
    """A cell that raises leaves its traceback, native (file-descriptor) output included, in its own
    log and no result; the worker answers once per cell and goes on."""
    import io
    import os

    from neuralbrdf.study import cell

    for name in ("bad", "good"):
        (tmp_path / name).mkdir()
    (tmp_path / "good" / "cell.json").write_text("{}")
    seen = []

    def fake_run(folder):
        os.write(1, f"native {folder.name}\n".encode())
        seen.append(folder.name)
        json.loads((folder / "cell.json").read_text())

    monkeypatch.setattr(cell, "run_cell", fake_run)
    monkeypatch.setattr(cell, "_import_fitting", lambda: None)
    answers_read, answers_write = os.pipe()
    saved = os.dup(1)
    os.dup2(answers_write, 1)
    try:
        cell.serve(io.StringIO(f"{tmp_path / 'bad'}\n\n{tmp_path / 'good'}\n"))
    finally:
        os.dup2(saved, 1)
        os.close(saved), os.close(answers_write)
    with os.fdopen(answers_read) as answers:
        assert answers.read() == cell.DONE + "\n" + cell.DONE + "\n"
    assert seen == ["bad", "good"]
    bad = (tmp_path / "bad" / "log.txt").read_text()
    assert "native bad" in bad and "FileNotFoundError" in bad
    assert (tmp_path / "good" / "log.txt").read_text() == "native good\n"


@pytest.mark.slow
@pytest.mark.skipif(CHROMIUM is None, reason="needs Debian's chromium")
def test_quick_profile(tmp_path):
    out = tmp_path / "quick"
    assert cli(["study", "--profile", "quick", "--out", str(out), "--jobs", "2", "--no-progress"]) == 0
    study = json.loads((out / "study.json").read_text())
    assert {p["material"] for p in study["points"]} == {"gold", "nylon"}
    check_in_browser(out)


@pytest.mark.skipif(not (ROOT.parent / "shared" / "data" / "merl-nbrdf").is_dir(),
                    reason="../shared/data/merl-nbrdf is absent (the shipped profiles name its proxies)")
def test_shipped_profiles_are_valid():
    quick = load_profile("quick")
    assert [m.name for m in quick.materials] == ["gold", "nylon"]
    assert len(plan_cells(quick)) == 22
    prior = load_profile("latent_prior")  # the prior's code sets: 9 materials x 3 fits, no renders
    assert len(plan_cells(prior)) == 27 and not any(v.speed_accuracy for v in prior.variants)
    try:
        load_profile("full")
    except InputError as error:
        if "no such file" not in str(error):
            raise
        pytest.skip(f"full.yaml names a config of a branch not merged yet ({error})")
    full = load_profile("full")
    assert len(full.materials) == 9 and {"abc", "nlb", "spectral_mlp"} <= set(full.stability.variants)
    for variant in full.variants:  # every pretrained network a variant names is shipped
        if variant.method == "nlb":
            assert resolve_pretrained(pretrained_network(variant)).is_file(), variant.name
    latent = next(g for g in group_members(full).items() if g[0] == "NLB latent size")[1]
    assert [label for label, _ in latent] == ["32, blends + prior (default)", "16 (nlb_compact)", "4", "8", "16", "32", "32 (from scratch)"]


def test_parameter_count_counts_float_initializers():
    import numpy as np
    import onnx
    from onnx import helper, numpy_helper

    from neuralbrdf.study.cost import parameter_count

    weights = [numpy_helper.from_array(np.zeros((3, 7), np.float32), "w"),
               numpy_helper.from_array(np.zeros(7, np.float32), "b"),
               numpy_helper.from_array(np.array([1, 2], np.int64), "shape")]  # not a parameter
    graph = helper.make_graph([], "g", [], [], initializer=weights)
    assert parameter_count(helper.make_model(graph)) == 3 * 7 + 7
    assert isinstance(onnx.TensorProto.FLOAT, int)


def test_parameter_count_of_an_abc_file_counts_every_fitted_value(tmp_path):
    """kd and A per channel are weights of the graph; B, C and eta are constants in its arithmetic."""
    import onnx

    from neuralbrdf.kinds import abc as abc_kind
    from neuralbrdf.onnx_export import write_model
    from neuralbrdf.physics.abc import AbcParameters
    from neuralbrdf.study.cost import parameter_count

    parameters = AbcParameters(kd=[0.1, 0.2, 0.3], A=[1.0, 0.9, 0.8], B=40.0, C=1.5, eta=1.5)
    path = tmp_path / "abc.onnx"
    write_model(abc_kind.exportable(parameters, "m", "test"), path)
    assert parameter_count(onnx.load(str(path)), "abc") == 3 + 3 + 3


def test_seeds_that_repeat_a_fit_exactly_count_once():
    """A deterministic fit run at five seeds is one fit: the stability figures, the group tables and
    the seed captions see one point, while seeds that changed the result all stay."""
    def point(model, seed, error, noise=0.0):
        return {"material": "gold", "model": model, "plan": "DS1", "noise": noise, "seed": seed, "failure": None,
                "error": {aggregate.THRESHOLD_METRIC: error, "per_angle_list": [seed]}}

    same = [point("nlb", seed, 0.01) for seed in range(5)]
    varied = [point("abc", seed, 0.02 + seed * 1e-4) for seed in range(5)]
    noisy = [point("nlb", seed, 0.01, noise=0.01) for seed in range(2)]  # same value, another condition
    kept = aggregate.distinct_fits(same + varied + noisy)
    assert [(p["model"], p["seed"], p["noise"]) for p in kept] == [
        ("nlb", 0, 0.0), *[("abc", s, 0.0) for s in range(5)], ("nlb", 0, 0.01)]
    table = aggregate.groups(same + varied, {"g": [("NLB", "nlb"), ("ABC", "abc")]}, ["gold"])[0]
    assert [row["cells"] for row in table["members"]] == [1, 5]


# --------------------------------------------------------------------------- the auto method

AUTO = BASE + "  - {name: auto, method: auto, config: configs/auto.yaml}\n"


def test_every_list_of_methods_knows_auto():
    """The methods a profile may name are those whose checkpoint, seeding and colour the study knows;
    ``auto`` is deterministic without noise (its ABC candidate's starts come from its ABC config)."""
    import yaml

    from neuralbrdf.configs_dir import resolve_config
    from neuralbrdf.study.cell import CHECKPOINTS
    from neuralbrdf.study.cells import SEEDING, seed_args, seeding_description
    from neuralbrdf.study.charts import METHOD_COLOURS
    from neuralbrdf.study.profile import METHODS

    assert "auto" in METHODS
    assert set(METHODS) == set(CHECKPOINTS) == set(SEEDING) == set(METHOD_COLOURS)
    assert len(set(METHOD_COLOURS.values())) == len(METHOD_COLOURS)  # one colour per method
    callbacks = yaml.safe_load(resolve_config("auto").read_text())["trainer"]["callbacks"]
    saved = next(c["init_args"]["filename"] for c in callbacks if c["class_path"].endswith("ModelCheckpoint"))
    assert CHECKPOINTS["auto"] == f"{saved}.ckpt" == CHECKPOINTS["abc"]
    assert seed_args("auto", 3) == [] and SEEDING["auto"].varies is None
    assert "seed 0 only" in seeding_description("auto") and "model.seed" in seeding_description("auto")


def test_an_auto_variant_is_fitted_like_abc_and_keyed_by_its_candidates(tmp_path):
    """A profile naming ``method: auto`` validates; its cells pass the data as ABC's do, with no seed
    option, run noise-free at seed 0 only, and their keys hold the contents of both candidates'
    configs and of the spectral NLB's pretrained network."""
    from neuralbrdf.configs_dir import resolve_config
    from neuralbrdf.shipped import SPECTRAL_DEFAULT
    from neuralbrdf.study.cell import fit_arguments
    from neuralbrdf.study.cells import file_digest
    from neuralbrdf.study.runner import cell_spec

    profile = load_profile(str(_write(tmp_path, AUTO + "stability: {variants: [abc, auto], plans: [DS1, DS4], "
                                                       "noise: [0.0, 0.1], seeds: [0, 1]}\n")))
    assert profile.variant("auto").method == "auto"
    assert Path(profile.variant("auto").config) == resolve_config("auto").resolve()
    assert [c for c in plan_cells(profile) if c.variant == "auto"] == [
        Cell("gold", "auto", "DS1", 0.0, 0), Cell("gold", "auto", "DS4", 0.0, 0),
        Cell("gold", "auto", "DS1", 0.1, 0), Cell("gold", "auto", "DS1", 0.1, 1)]
    table, run = tmp_path / "gold.csv", tmp_path / "run"

    def arguments(variant: str) -> list[str]:
        spec = cell_spec(Cell("gold", variant, "DS4", 0.1, 1), "k", profile, (tmp_path / "truth.onnx", "sha"))
        return fit_arguments(spec, table, run)

    common = ["--data.path", str(table), "--run_dir", str(run), "--seed_everything", "1"]
    assert arguments("auto") == ["fit", "--config", profile.variant("auto").config, *common,
                                 "--trainer.enable_progress_bar", "false"]
    assert arguments("abc") == ["fit", "--config", profile.variant("abc").config, *common, "--model.seed", "1",
                                "--trainer.enable_progress_bar", "false"]
    main = Cell("gold", "auto", "DS1", 0.0, 0)
    candidates = cell_settings(main, profile)["variant"]["candidates"]
    assert candidates == {"configs": {"abc": [file_digest(str(resolve_config("abc")))],
                                      "nlb_spectral": [file_digest(str(resolve_config("nlb_spectral")))]},
                          "pretrained": file_digest(str(SPECTRAL_DEFAULT))}
    assert "candidates" not in cell_settings(Cell("gold", "abc", "DS1", 0.0, 0), profile)["variant"]
    # another ABC candidate (an override naming its config): another key
    mine = tmp_path / "my_abc.yaml"
    mine.write_text(resolve_config("abc").read_text().replace("n_starts: 8", "n_starts: 2"))
    other = load_profile(str(_write(tmp_path, BASE + "  - {name: auto, method: auto, config: configs/auto.yaml, "
                                                     f"args: [--model.abc_config, {mine}]}}\n")))
    assert cell_settings(main, other)["variant"]["candidates"]["configs"]["abc"] == [file_digest(str(mine))]
    assert cell_key(main, other) != cell_key(main, profile)


def test_an_auto_fit_in_which_neither_candidate_fits_is_an_optimiser_failure(tmp_path, monkeypatch):
    """As an ABC fit that reports failure: the cell's cause is ``optimizer_failure`` with the fit's own
    reason, though that reason names the spectral NLB's error that is not finite."""
    from neuralbrdf.lightning.auto_fit import NEITHER_FITTED, AutoFitModule
    from neuralbrdf.study import cell as cell_module
    from neuralbrdf.study.runner import cell_spec

    monkeypatch.setattr(AutoFitModule, "_fit_nlb", lambda self, table: self.errors.update(nlb_spectral=math.nan))
    monkeypatch.setattr(AutoFitModule, "_fit_abc", lambda self, table: setattr(self, "abc_failure", "test: no ABC"))
    profile = load_profile(str(_write(tmp_path, AUTO)))
    spec = cell_spec(Cell("gold", "auto", "DS4", 0.0, 0), "k", profile, (tmp_path / "truth.onnx", "sha"))
    table = cell_module.write_data(spec, tmp_path / "data" / "gold.csv")
    with pytest.raises(cell_module.CellFailure) as failure:
        cell_module.fit(spec, table, tmp_path / "run")
    assert failure.value.cause == "optimizer_failure", failure.value
    assert NEITHER_FITTED in str(failure.value) and "test: no ABC" in str(failure.value)
    assert not (tmp_path / "run" / "checkpoints" / "best.ckpt").exists()


def test_an_auto_cell_runs_and_records_its_choice(tmp_path):
    """One real cell of ``auto`` (the virtual gold on DS4, scored on few hemisphere pairs, no render):
    the exported file says the choice the cell records, the lower of the candidates' in-plane
    errors; the choice reaches study.json's point, the report's table and the model's sentence."""
    from neuralbrdf.kinds import load_model
    from neuralbrdf.study import cell as cell_module
    from neuralbrdf.study.cache import Repairs, truth_file
    from neuralbrdf.study.report import _points_table
    from neuralbrdf.study.runner import cell_spec

    profile = load_profile(str(_write(tmp_path, BASE.replace("  - {name: abc, method: abc, config: configs/abc.yaml}\n",
                                                             "") + "  - {name: auto, method: auto, config: "
                                      "configs/auto.yaml, speed_accuracy: false}\nhemisphere_strata: [4, 5]\n")))
    cell = Cell("gold", "auto", "DS4", 0.0, 0)
    folder = tmp_path / "cell"
    folder.mkdir()
    spec = cell_spec(cell, cell_key(cell, profile), profile, truth_file(profile.materials[0], tmp_path, Repairs(tmp_path)))
    (folder / "cell.json").write_text(json.dumps(spec))
    result = cell_module.run_cell(folder)
    assert result["failure"] is None, result["message"]
    assert json.loads((folder / "result.json").read_text())["auto"] == result["auto"]
    chosen, errors = result["auto"]["choice"], result["auto"]["inplane_logcos_rmse"]
    assert chosen == min(errors, key=lambda kind: math.inf if errors[kind] is None else errors[kind])
    assert set(errors) == {"abc", "nlb_spectral"} and result["error"]["hemisphere_logcos_rmse"] > 0
    assert load_model(folder / "model.onnx").details.choice == chosen
    points = aggregate.points_from_results([result], {"auto": "auto"}, {"DS4": 6})
    assert points[0]["method"] == "auto" and points[0]["auto"] == result["auto"]
    assert f"Its fit kept {chosen} in 1 of 1 fitted cells." in aggregate.method_sentences(points, [])["auto"]
    assert f"auto ({chosen})" in _points_table({"points": points})


def test_parameter_count_of_an_auto_file_is_that_of_the_graph_it_holds(tmp_path):
    """An auto file that chose ABC holds ABC's graph: its scalars B, C and eta count as an ABC file's do."""
    from neuralbrdf.kinds import auto as auto_kind
    from neuralbrdf.kinds import load_model
    from neuralbrdf.onnx_export import write_model
    from neuralbrdf.physics.abc import AbcParameters
    from neuralbrdf.study.cost import graph_kind, parameter_count

    parameters = AbcParameters(kd=[0.1, 0.2, 0.3], A=[1.0, 0.9, 0.8], B=40.0, C=1.5, eta=1.5)
    checkpoint = {"auto_choice": "abc", "material": "m", "auto_inplane_logcos_rmse": {"abc": 0.01, "nlb_spectral": 0.02},
                  "abc_parameters": parameters.to_dict()}
    path = tmp_path / "auto.onnx"
    write_model(auto_kind.from_checkpoint(checkpoint, tmp_path / "auto.ckpt", None), path)
    model = load_model(path)
    assert model.kind == "auto" and graph_kind(model) == "abc"
    assert parameter_count(model.proto, graph_kind(model)) == 3 + 3 + 3


# --------------------------------------------------------------------------- the pca method

PCA = BASE + "  - {name: pca, method: pca, config: configs/pca.yaml}\n"


def test_every_list_of_methods_knows_pca():
    """``pca`` is a study method: its checkpoint is the one its config saves, and it is deterministic
    without noise (a closed-form ridge solve in a fixed basis), so it takes no seed option."""
    import yaml

    from neuralbrdf.configs_dir import resolve_config
    from neuralbrdf.study.cell import CHECKPOINTS
    from neuralbrdf.study.cells import SEEDING, seed_args, seeding_description
    from neuralbrdf.study.charts import METHOD_COLOURS
    from neuralbrdf.study.profile import METHODS

    assert "pca" in METHODS
    assert set(METHODS) == set(CHECKPOINTS) == set(SEEDING) == set(METHOD_COLOURS)
    assert len(set(METHOD_COLOURS.values())) == len(METHOD_COLOURS)
    callbacks = yaml.safe_load(resolve_config("pca").read_text())["trainer"]["callbacks"]
    saved = next(c["init_args"]["filename"] for c in callbacks if c["class_path"].endswith("ModelCheckpoint"))
    assert CHECKPOINTS["pca"] == f"{saved}.ckpt"
    assert seed_args("pca", 3) == [] and SEEDING["pca"].varies is None
    assert "seed 0 only" in seeding_description("pca") and "ridge" in seeding_description("pca")


def test_a_pca_variant_is_fitted_like_abc_without_a_seed_option_and_keyed_by_its_basis(tmp_path):
    """A profile naming ``method: pca`` validates; its cells pass the data as ABC's do, with no seed
    option, run noise-free at seed 0 only, and their keys hold the contents of the basis file."""
    from neuralbrdf.configs_dir import resolve_config
    from neuralbrdf.models.pca_brdf import BASIS_FILE
    from neuralbrdf.study.cell import fit_arguments
    from neuralbrdf.study.cells import PCA_BASIS_DEFAULT, file_digest, pca_basis
    from neuralbrdf.study.runner import cell_spec

    profile = load_profile(str(_write(tmp_path, PCA + "stability: {variants: [abc, pca], plans: [DS1, DS4], "
                                                      "noise: [0.0, 0.1], seeds: [0, 1]}\n")))
    assert profile.variant("pca").method == "pca"
    assert Path(profile.variant("pca").config) == resolve_config("pca").resolve()
    assert [c for c in plan_cells(profile) if c.variant == "pca"] == [
        Cell("gold", "pca", "DS1", 0.0, 0), Cell("gold", "pca", "DS4", 0.0, 0),
        Cell("gold", "pca", "DS1", 0.1, 0), Cell("gold", "pca", "DS1", 0.1, 1)]
    table, run = tmp_path / "gold.csv", tmp_path / "run"
    spec = cell_spec(Cell("gold", "pca", "DS4", 0.1, 1), "k", profile, (tmp_path / "truth.onnx", "sha"))
    assert fit_arguments(spec, table, run) == [
        "fit", "--config", profile.variant("pca").config, "--data.path", str(table), "--run_dir", str(run),
        "--seed_everything", "1", "--trainer.enable_progress_bar", "false"]
    main = Cell("gold", "pca", "DS1", 0.0, 0)
    assert PCA_BASIS_DEFAULT == BASIS_FILE and pca_basis(profile.variant("pca")) == BASIS_FILE
    assert cell_settings(main, profile)["variant"]["basis"] == file_digest(str(BASIS_FILE))
    assert "basis" not in cell_settings(Cell("gold", "abc", "DS1", 0.0, 0), profile)["variant"]
    # another basis (an override): another key
    mine = tmp_path / "my_basis.npz"
    mine.write_bytes(BASIS_FILE.read_bytes() + b"\0")
    other = load_profile(str(_write(tmp_path, BASE + "  - {name: pca, method: pca, config: configs/pca.yaml, "
                                                     f"args: [--model.basis, {mine}]}}\n")))
    assert pca_basis(other.variant("pca")) == mine
    assert cell_settings(main, other)["variant"]["basis"] == file_digest(str(mine))
    assert cell_key(main, other) != cell_key(main, profile)


@pytest.mark.parametrize("cause, expected", [
    ("not_finite", "non_finite_loss"),
    ("no_sample", "optimizer_failure"),
])
def test_a_failed_pca_fit_is_mapped_by_its_own_cause(tmp_path, monkeypatch, cause, expected):
    """A ``pca`` fit that fails on a value that is not finite is a non-finite loss; one that cannot be
    made from its samples an optimiser failure — read from the fit's cause, not from the material's
    name (``nan_gold`` holds "nan")."""
    import numpy as np

    from neuralbrdf.errors import InputError
    from neuralbrdf.models import pca_brdf
    from neuralbrdf.study import cell as cell_module
    from neuralbrdf.study.runner import cell_spec

    if cause == "not_finite":
        monkeypatch.setattr(pca_brdf, "ridge_coefficients", lambda *args: np.full((31, 32), np.nan))
    else:
        def no_sample(*args, source=None, **kwargs):
            raise InputError("no sample above the horizon to fit the PCA coefficients to", path=source)

        monkeypatch.setattr(pca_brdf, "fit_channels", no_sample)
    profile = load_profile(str(_write(tmp_path, PCA.replace("name: gold", "name: nan_gold"))))
    spec = cell_spec(Cell("nan_gold", "pca", "DS4", 0.0, 0), "k", profile, (tmp_path / "truth.onnx", "sha"))
    table = cell_module.write_data(spec, tmp_path / "data" / "nan_gold.csv")
    with pytest.raises(cell_module.CellFailure) as failure:
        cell_module.fit(spec, table, tmp_path / "run")
    assert failure.value.cause == expected, failure.value
    assert "PCA fit of nan_gold: " in str(failure.value)
    assert not (tmp_path / "run" / "checkpoints" / "best.ckpt").exists()


def test_a_pca_cell_runs_and_counts_its_table_entries(tmp_path):
    """One real cell of ``pca`` (the virtual gold on DS4, scored on few hemisphere pairs, no render):
    the exported file is a ``pca`` file, and its parameter count is its baked table's entries (the
    basis's nodes × 31 bands), not its 32 coefficients per band."""
    import onnx

    from neuralbrdf.kinds import load_model
    from neuralbrdf.models.pca_brdf import load_basis
    from neuralbrdf.study import cell as cell_module
    from neuralbrdf.study.cache import Repairs, truth_file
    from neuralbrdf.study.cost import graph_kind, parameter_count
    from neuralbrdf.study.runner import cell_spec

    profile = load_profile(str(_write(tmp_path, BASE.replace("  - {name: abc, method: abc, config: configs/abc.yaml}\n",
                                                             "") + "  - {name: pca, method: pca, config: "
                                      "configs/pca.yaml, speed_accuracy: false}\nhemisphere_strata: [4, 5]\n")))
    cell = Cell("gold", "pca", "DS4", 0.0, 0)
    folder = tmp_path / "cell"
    folder.mkdir()
    spec = cell_spec(cell, cell_key(cell, profile), profile, truth_file(profile.materials[0], tmp_path, Repairs(tmp_path)))
    (folder / "cell.json").write_text(json.dumps(spec))
    result = cell_module.run_cell(folder)
    assert result["failure"] is None, result["message"]
    assert result["error"]["hemisphere_logcos_rmse"] > 0 and result["cost"]["fit_time_s"] > 0
    model = load_model(folder / "model.onnx")
    assert model.kind == "pca" and graph_kind(model) == "pca" and model.details.components == 32
    nodes = load_basis().nodes
    assert model.details.nodes == (*nodes, 31)
    count = parameter_count(onnx.load(str(folder / "model.onnx")), graph_kind(model))
    assert count == nodes[0] * nodes[1] * nodes[2] * 31 == 285_696


def test_a_report_of_a_profile_that_times_nothing_recommends_nothing_rather_than_no_model(synthetic, tmp_path):
    """The budget profile sweeps plans and times no cell: its report must not say "no model within
    this budget" for every material, as if every model had failed."""
    from neuralbrdf.study.report import write_report

    points = [dict(p, is_main=False) for p in synthetic["study"]["points"]]
    shutil.copytree(synthetic["folder"] / "figures", tmp_path / "figures")
    page = write_report({**synthetic["study"], "points": points}, synthetic["figures"], tmp_path).read_text(
        encoding="utf-8")
    assert "This profile times no model" in page
    assert "no model within this budget" not in page and "speed_accuracy_pooled.png" not in page
    assert "stability_pairs.png" in page
