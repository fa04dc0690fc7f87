"""Cost ladders and the per-scene model selector (SPEC §11), and rendering a user's scene file.

The parent is the virtual gold's ground truth (``export-truth virtual:gold``: spectral, glossy);
its ladder is built once per module with small settings (few distillation steps, one student,
one cost round, 6400 hemisphere pairs for the errors) so that the tests stay fast; what is checked does not depend on the rungs
being good, only on their files, metadata and recorded numbers being right.
"""

from __future__ import annotations

import json
import os
from pathlib import Path

import numpy as np
import pytest

from neuralbrdf.cli import render_command
from neuralbrdf.errors import InputError
from neuralbrdf.evaluation.scores import OnnxEvaluator
from neuralbrdf.evaluation.truth import export_truth
from neuralbrdf.lod.distill import DistillSettings
from neuralbrdf.lod.ladder import (
    COST_KEY,
    ERROR_KEY,
    PARENT_SHA256_KEY,
    RUNG_KEY,
    LadderSettings,
    build_ladder,
    file_sha256,
    read_ladder,
)
from neuralbrdf.lod.select import SelectSettings, best_combination, select
from neuralbrdf.kinds import load_model
from neuralbrdf.render.scene_file import SceneFile

FAST = LadderSettings(
    students=((1, 4),),
    distill=DistillSettings(n_pairs=4096, steps=150, batch=1024),
    abc_pairs=1024,
    abc_starts=2,
    cost_batches=(2**12, 2**14),
    cost_rounds=1,
    error_strata=(8, 10),
    rgb_tolerances=(3e-2,),
)


@pytest.fixture(scope="module")
def ladder(tmp_path_factory):
    folder = tmp_path_factory.mktemp("ladder")
    parent = folder / "gold.onnx"
    export_truth("virtual:gold", parent)
    document = build_ladder(parent, folder / "gold.ladder", FAST, log=lambda *_: None)
    return parent, folder / "gold.ladder", document


def test_rungs_obey_the_contract_and_record_parent_and_cost(ladder):
    parent, folder, document = ladder
    names = [r["name"] for r in document["rungs"]]
    assert {"full", "abc", "mlp_1x4"} <= set(names), document["failed"]
    sha = file_sha256(parent)
    assert document["parent"]["sha256"] == sha
    for rung in document["rungs"]:
        if rung["name"] == "full":
            assert Path(rung["file"]) == parent.resolve() and rung["relative_cost"] == 1.0
            continue
        if rung["name"].startswith("full_rgb"):  # the parent with a looser sRGB rule, RGB variants only
            assert Path(rung["file"]) == parent.resolve() and rung["variants"] == "rgb"
            assert float(rung["bsdf_properties"]["rgb_tolerance"]) > 1e-3
            assert 0 < rung["relative_cost"] < 1 and rung["hemisphere_logcos_rmse"] > 0
            continue
        model = load_model(folder / rung["file"])  # the contract check the renderer runs
        assert model.is_spectral and model.kind == rung["kind"]
        assert model.metadata[RUNG_KEY] == rung["name"]
        assert model.metadata[PARENT_SHA256_KEY] == sha
        assert float(model.metadata[ERROR_KEY]) == pytest.approx(rung["hemisphere_logcos_rmse"])
        assert float(model.metadata[COST_KEY]) == pytest.approx(rung["drjit_ns_per_query"])
        assert rung["drjit_ns_per_query"] > 0
    assert load_model(folder / "abc.onnx").details is not None  # the analytic sampler's parameters
    read = read_ladder(folder)
    assert read.rungs[0].name == "full" and {r.name for r in read.rungs} == set(names)


def _independent_logcos_rmse(model_path: Path, parent_path: Path, n: int = 20000) -> float:
    """The hemisphere log-cos RMSE recomputed from scratch: uniform (not stratified) directions with
    θ <= 80°, another seed, 31 wavelengths, plain NumPy."""
    rng = np.random.default_rng(12345)

    def directions():
        cos_theta = rng.uniform(np.cos(np.radians(80.0)), 1.0, n)
        phi = rng.uniform(0.0, 2 * np.pi, n)
        sin_theta = np.sqrt(1 - cos_theta**2)
        return np.stack([sin_theta * np.cos(phi), sin_theta * np.sin(phi), cos_theta], axis=1)

    wi, wo = directions(), directions()
    wavelengths = np.arange(400.0, 701.0, 10.0)
    rows_wi, rows_wo = np.repeat(wi, 31, axis=0), np.repeat(wo, 31, axis=0)
    lam = np.tile(wavelengths, n)
    f_model = OnnxEvaluator(model_path).values(rows_wi, rows_wo, lam)
    f_parent = OnnxEvaluator(parent_path).values(rows_wi, rows_wo, lam)
    cos_i = rows_wi[:, 2]
    residual = np.log1p(cos_i * f_parent) - np.log1p(cos_i * np.clip(f_model, 0, None))
    return float(np.sqrt(np.mean(residual**2)))


@pytest.mark.parametrize("rung", ["abc", "mlp_1x4"])
def test_recorded_parent_error_is_reproduced_independently(ladder, rung):
    parent, folder, document = ladder
    recorded = next(r for r in document["rungs"] if r["name"] == rung)["hemisphere_logcos_rmse"]
    independent = _independent_logcos_rmse(folder / f"{rung}.onnx", parent)
    assert recorded > 1e-3  # a stand-in differs from its parent; 0 would mean it was compared to itself
    assert independent == pytest.approx(recorded, rel=0.2)


def test_a_failed_fit_is_listed_not_written(tmp_path):
    """A Lambertian parent has no specular signal: the ABC fit reports failure, no abc.onnx."""
    from onnx_fixtures import write_lambert

    parent = write_lambert(tmp_path / "lambert.onnx")
    document = build_ladder(parent, tmp_path / "out", FAST, log=lambda *_: None)
    assert [f["name"] for f in document["failed"]] == ["abc"]
    assert "specular" in document["failed"][0]["cause"]
    assert not (tmp_path / "out" / "abc.onnx").exists()
    assert [r["name"] for r in document["rungs"]] == ["full"]  # an RGB parent gets no spectral students


# --------------------------------------------------------------------------- choosing


def _option(rung, error, cost):
    return {"rung": rung, "error_contribution": error, "relative_cost": cost}


def test_best_combination_keeps_the_summed_error_within_tolerance():
    full = _option("full", 0.0, 1.0)
    options = {
        "a": [full, _option("abc", 0.6, 0.2), _option("mlp", 0.2, 0.6)],
        "b": [full, _option("abc", 0.5, 0.3), _option("mlp", 0.1, 0.6)],
    }
    chosen = best_combination(options, tolerance=1.0)
    assert {n: o["rung"] for n, o in chosen.items()} == {"a": "abc", "b": "mlp"}  # cost 0.8, error 0.7
    chosen = best_combination(options, tolerance=0.5)
    assert {n: o["rung"] for n, o in chosen.items()} == {"a": "mlp", "b": "mlp"}  # cost 1.2 (full+abc: 1.3)
    chosen = best_combination(options, tolerance=0.05)
    assert {n: o["rung"] for n, o in chosen.items()} == {"a": "full", "b": "full"}


# --------------------------------------------------------------------------- scenes

SCENE = """<scene version="3.0.0">
    <integrator type="path"><integer name="max_depth" value="3"/></integrator>
    <sensor type="perspective">
        <float name="fov" value="{fov}"/>
        <transform name="to_world"><lookat origin="0, 0, 4" target="0, 0, 0" up="0, 1, 0"/></transform>
        <film type="hdrfilm">
            <integer name="width" value="64"/><integer name="height" value="48"/>
            <rfilter type="box"/>
        </film>
    </sensor>
    <bsdf type="neuralbrdf" id="gold"><string name="filename" value="{model}"/></bsdf>
    <shape type="sphere">
        <point name="center" value="{center}"/><float name="radius" value="1"/>
        <ref id="gold"/>
    </shape>
    <shape type="rectangle">
        <transform name="to_world"><scale value="0.5"/>
            <lookat origin="-2, 3, 4" target="0, 0, 0" up="0, 1, 0"/></transform>
        <emitter type="area"><rgb name="radiance" value="20, 20, 20"/></emitter>
    </shape>
    <emitter type="constant"><rgb name="radiance" value="0.3, 0.3, 0.3"/></emitter>
</scene>
"""


def _scene(folder: Path, model: Path, visible: bool) -> Path:
    """The gold sphere filling the view (``visible``) or behind the camera (covering no pixel), its
    model named relative to the scene file."""
    folder.mkdir(parents=True, exist_ok=True)
    relative = os.path.relpath(model, folder)
    center = "0, 0, 0" if visible else "0, 0, 9"
    path = folder / "scene.xml"
    path.write_text(SCENE.format(fov=45 if visible else 30, model=relative, center=center))
    return path


QUICK = dict(variant="llvm_ad_rgb", resolution=24, spp=4, max_spp=8, timing_repeats=1)


def test_an_object_covering_no_pixel_gets_its_cheapest_rung(ladder, tmp_path):
    parent, folder, document = ladder
    scene = _scene(parent.parent / "hidden", parent, visible=False)
    out = tmp_path / "SELECTED.xml"
    result = select(scene, out, SelectSettings(tolerance=0.5, **QUICK), log=lambda *_: None)
    cheapest = min(document["rungs"], key=lambda r: r["relative_cost"])
    (material,) = result["materials"]
    assert material["chosen_rung"] == cheapest["name"]
    assert result["image_delta_e2000_mean"] == 0.0  # nothing visible changed
    assert result["noise"]["render_seed_to_seed_delta_e2000_mean"] == pytest.approx(0.0, abs=1e-6)
    assert result["noise"]["estimate_seed_to_seed_delta_e2000"] == pytest.approx(0.0, abs=1e-6)

    # SELECTED.xml loads (relative paths rewritten for its folder) and renders
    from neuralbrdf.render.preview import set_variant
    from neuralbrdf.render.scene_file import render_scene_file

    selected = SceneFile(out)
    (chosen,) = selected.materials()
    assert chosen.model == (folder / cheapest["file"]).resolve()  # an absolute "file" stays as it is
    for key, value in cheapest["bsdf_properties"].items():
        assert chosen.element.find(f"*[@name='{key}']").get("value") == value
    set_variant("llvm_ad_rgb")
    selected.set_resolution(8, 6)
    image, _ = render_scene_file(selected, spp=1)
    assert image.shape == (6, 8, 3) and np.all(np.isfinite(image))
    written = json.loads(out.with_suffix(".json").read_text())
    for key in ("reference_time_s", "selected_time_s", "speedup", "image_delta_e2000_mean", "noise"):
        assert key in written
    assert {"name", "chosen_rung", "error_contribution", "cost"} <= set(written["materials"][0])


def test_a_close_up_keeps_the_full_model_under_a_tight_tolerance(ladder, tmp_path):
    parent, _, _ = ladder
    scene = _scene(parent.parent / "close", parent, visible=True)
    # spectral variant: the candidates are the stand-in files (in RGB variants the parent with a looser
    # sRGB rule keeps the sampler and the paths, and may legitimately stay within a tight tolerance)
    settings = SelectSettings(tolerance=0.05, **{**QUICK, "variant": "llvm_ad_spectral"})
    result = select(scene, tmp_path / "SELECTED.xml", settings, log=lambda *_: None)
    (material,) = result["materials"]
    assert material["chosen_rung"] == "full"
    # every stand-in changed the image by more than the tolerance
    assert all(o["error_contribution"] > 0.05 for o in result["candidates"]["gold"][1:])
    noise = result["noise"]
    assert noise["render_seed_to_seed_delta_e2000_mean"] > 0.05  # a close-up at <= 8 spp is noisy ...
    # ... and the JSON says whether the estimates' own noise met a quarter of the tolerance
    assert noise["estimate_noise_within_fraction_of_tolerance"] == (noise["estimate_seed_to_seed_delta_e2000"] <= 0.0125)


def test_select_refuses_a_scene_without_neural_materials(tmp_path):
    scene = tmp_path / "plain.xml"
    scene.write_text('<scene version="3.0.0"><shape type="sphere"/></scene>')
    with pytest.raises(InputError, match="no neuralbrdf material"):
        select(scene, tmp_path / "S.xml", SelectSettings(**QUICK))


# --------------------------------------------------------------------------- render.py --scene


def test_render_command_renders_a_user_scene(ladder, tmp_path):
    parent, _, _ = ladder
    scene = _scene(parent.parent / "user", parent, visible=True)
    out = tmp_path / "scene.png"
    code = render_command.main(["--scene", str(scene), "--out", str(out), "--variant", "llvm_ad_rgb", "--resolution", "16",
                        "--spp", "2", "--quiet"])
    assert code == 0 and out.is_file()
    code = render_command.main(["--scene", str(tmp_path / "missing.xml"), "--out", str(tmp_path / "x.png"), "--quiet"])
    assert code == 2 and not (tmp_path / "x.png").exists()
