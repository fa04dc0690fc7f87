"""Cost ladders and the per-scene model selector (docs/select.md), and rendering a user's scene file.

The parent is the virtual gold's ground truth (``export-truth virtual:gold``: spectral, glossy);
its ladder is built once per module with small settings (few distillation steps, one student,
one cost round, 6400 hemisphere pairs for the errors) so that the tests stay fast; what is checked does not depend on the rungs
being good, only on their files, metadata and recorded numbers being right.
"""

from __future__ import annotations

import dataclasses
import json
import os
from pathlib import Path

import numpy as np
import pytest

from neuralbrdf.cli import render_command
from neuralbrdf.errors import InputError
from neuralbrdf.evaluation.scores import OnnxEvaluator
from neuralbrdf.evaluation.truth import export_truth
from neuralbrdf.lod.config import load_lod_config
from neuralbrdf.lod.ladder import (
    COST_KEY,
    ERROR_KEY,
    PARENT_SHA256_KEY,
    RUNG_KEY,
    build_ladder,
    file_sha256,
    read_ladder,
)
from neuralbrdf.lod.select import best_combination, on_object_mean, select
from neuralbrdf.kinds import load_model
from neuralbrdf.render.scene_file import SceneFile, material_coverage

CONFIG = load_lod_config()  # the shipped configs/lod/default.yaml
FAST = dataclasses.replace(
    CONFIG.ladder,
    students=((1, 4),),
    distill=dataclasses.replace(CONFIG.ladder.distill, n_pairs=4096, steps=150, batch=1024),
    abc_pairs=1024,
    abc_starts=2,
    cost_batches=(2**12, 2**14),
    cost_rounds=1,
    error_strata=(8, 10),
    rgb_tolerances=(3e-2,),
    tables=((12, 8, 4, 8),),
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
    assert {"full", "abc", "mlp_1x4", "table_12x8x4x8"} <= set(names), document["failed"]
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


@pytest.mark.parametrize("rung", ["abc", "mlp_1x4", "table_12x8x4x8"])
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
    # an RGB parent gets no spectral students; its table (RGB: no wavelength axis) reproduces a Lambertian
    assert sorted(r["name"] for r in document["rungs"]) == ["full", "table_12x8x4"]
    table = next(r for r in document["rungs"] if r["name"] == "table_12x8x4")
    assert table["kind"] == "table" and table["hemisphere_logcos_rmse"] < 1e-6


def _auto_file(path: Path) -> Path:
    """A model file of kind ``auto`` that chose ABC (RGB), written as ``neuralbrdf export`` writes one."""
    from neuralbrdf.kinds import auto as auto_kind
    from neuralbrdf.onnx_export import write_model
    from neuralbrdf.physics.abc import AbcParameters

    parameters = AbcParameters(kd=np.array([0.3, 0.2, 0.1]), A=np.array([2.0, 2.5, 3.0]), B=400.0, C=0.8, eta=1.5)
    checkpoint = {"auto_choice": "abc", "material": "glossy", "auto_inplane_logcos_rmse": {"abc": 0.01, "nlb_spectral": 0.02},
                  "abc_parameters": parameters.to_dict()}
    write_model(auto_kind.from_checkpoint(checkpoint, path.with_suffix(".ckpt"), None), path)
    return path


def test_an_auto_file_is_laddered_and_selected_like_any_model(tmp_path):
    """Nothing of the ladder or the selector depends on the parent's kind: an ``auto`` file gets its
    rungs, its stand-ins sample with its proposal (the chosen kind's: here the ABC lobe), and a fast
    path ``f_fast`` in it is a rung of ``select`` without a ladder folder (one that chose ABC has none
    unless exported with it)."""
    import onnx
    from onnx_fixtures import Lambert, export_module

    from neuralbrdf.lod.ladder import FAST_RUNG, embedded_ladder
    from neuralbrdf.onnx_contract import OUTPUT_FAST, fast_path_key
    from neuralbrdf.onnx_export import with_fast_paths
    from neuralbrdf.render.load_time import fitted_proposal
    from neuralbrdf.render.sampling import AbcLobe

    parent = _auto_file(tmp_path / "auto.onnx")
    assert load_model(parent).kind == "auto" and embedded_ladder(parent) is None
    settings = dataclasses.replace(FAST, abc_pairs=256, abc_starts=1, cost_batches=(2**10, 2**12))
    document = build_ladder(parent, tmp_path / "auto.ladder", settings, log=lambda *_: None)
    assert document["parent"]["kind"] == "auto" and not document["failed"], document["failed"]
    kinds = {r["name"]: r["kind"] for r in document["rungs"]}
    assert kinds == {"full": "auto", "abc": "abc", "table_12x8x4": "table"}
    read = read_ladder(tmp_path / "auto.ladder")
    assert read.rungs[0].kind == "auto" and {r.name for r in read.rungs} == set(kinds)
    # select renders each stand-in with its parent's file as the proposal: the auto file's is the chosen ABC lobe
    assert fitted_proposal(load_model(parent)).lobe == AbcLobe(400.0, 0.8)
    fast = onnx.load(str(export_module(Lambert((0.1, 0.2, 0.3)), tmp_path / "fast.onnx", {}, spectral=False)))
    entries = {fast_path_key(OUTPUT_FAST, "approximates"): "a fixture",
               fast_path_key(OUTPUT_FAST, "hemisphere_logcos_rmse"): "0.01", fast_path_key(OUTPUT_FAST, "relative_cost"): "0.5"}
    with_fast = tmp_path / "auto_fast.onnx"
    onnx.save(with_fast_paths(onnx.load(str(parent)), {OUTPUT_FAST: fast}, entries), str(with_fast))
    ladder = embedded_ladder(with_fast)
    assert [(r.name, r.kind) for r in ladder.rungs] == [("full", "auto"), (FAST_RUNG, "auto")]
    assert dict(ladder.rungs[1].properties) == {"fast": "true"} and ladder.rungs[1].relative_cost == 0.5


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


def test_best_combination_bounds_each_objects_own_error():
    """A small object: its stand-in changes the whole image by 0.1 but its own pixels by 2.5."""
    options = {
        "small": [dict(_option("full", 0.0, 1.0), on_object_delta_e2000=0.0),
                  dict(_option("mlp", 0.1, 0.2), on_object_delta_e2000=2.5),
                  dict(_option("abc", 0.05, 0.6), on_object_delta_e2000=0.8)],
        "hidden": [dict(_option("full", 0.0, 1.0), on_object_delta_e2000=None),  # covers no pixel
                   dict(_option("mlp", 0.0, 0.2), on_object_delta_e2000=None)],
    }
    whole_image_only = best_combination(options, tolerance=1.0, object_tolerance=float("inf"))
    assert {n: o["rung"] for n, o in whole_image_only.items()} == {"small": "mlp", "hidden": "mlp"}
    chosen = best_combination(options, tolerance=1.0)  # object tolerance = tolerance
    assert {n: o["rung"] for n, o in chosen.items()} == {"small": "abc", "hidden": "mlp"}
    chosen = best_combination(options, tolerance=1.0, object_tolerance=0.5)
    assert {n: o["rung"] for n, o in chosen.items()} == {"small": "full", "hidden": "mlp"}


def test_on_object_mean_weights_pixels_by_coverage():
    delta = np.array([[4.0, 2.0], [1.0, 7.0]])
    coverage = np.array([[1.0, 0.5], [0.0, 0.0]])
    assert on_object_mean(delta, coverage) == pytest.approx((4.0 + 0.5 * 2.0) / 1.5)
    assert on_object_mean(delta, np.zeros_like(delta)) is None


# --------------------------------------------------------------------------- configuration


def test_the_shipped_config_holds_every_setting_and_refuses_bad_keys(tmp_path):
    assert CONFIG.path.parts[-2:] == ("lod", "default.yaml") and CONFIG.select.object_tolerance is None
    assert load_lod_config("default") == CONFIG
    assert CONFIG.select.object_bound == CONFIG.select.tolerance
    text = CONFIG.path.read_text()
    cases = {
        "unknown": (text.replace("  spp: 32", "  spp: 32\n  spp_typo: 3"), "select.spp_typo"),
        "missing": (text.replace("  coverage_subpixels: 4", ""), "select.coverage_subpixels"),
        "type": (text.replace("    steps: 12000", "    steps: many"), "ladder.distill.steps"),
        "bool": (text.replace("  seed: 0  ", "  seed: true  "), "select.seed"),
    }
    for name, (edited, key) in cases.items():
        assert edited != text, name
        path = tmp_path / f"{name}.yaml"
        path.write_text(edited)
        with pytest.raises(InputError, match=key.replace(".", r"\.")):
            load_lod_config(path)


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


#: Where the gold sphere (radius 1) is: filling the view, behind the camera (covering no pixel), far.
PLACEMENTS = {"close": ("0, 0, 0", 45), "hidden": ("0, 0, 9", 30), "far": ("0, 0, -8", 45)}


def _scene(folder: Path, model: Path, placement: str) -> Path:
    """The gold sphere at ``placement`` (:data:`PLACEMENTS`), its model named relative to the scene file."""
    folder.mkdir(parents=True, exist_ok=True)
    relative = os.path.relpath(model, folder)
    center, fov = PLACEMENTS[placement]
    path = folder / "scene.xml"
    path.write_text(SCENE.format(fov=fov, model=relative, center=center))
    return path


def test_coverage_is_the_spheres_disc(ladder, tmp_path):
    """Pixel centres (one ray per pixel) inside the sphere's silhouette, computed from the pinhole
    geometry: the ray through a pixel centre hits the unit sphere 4 away iff its angle to the axis is
    below asin(1/4).  Behind the camera the sphere covers nothing."""
    from neuralbrdf.render.preview import set_variant

    parent, _, _ = ladder
    set_variant("llvm_ad_rgb")
    coverage = material_coverage(SceneFile(_scene(tmp_path / "c", parent, "close")), subpixels=1)["gold"]
    height, width = coverage.shape
    tan_half = np.tan(np.radians(45 / 2))  # Mitsuba's fov is horizontal by default
    u = (2 * (np.arange(width) + 0.5) / width - 1) * tan_half
    v = (2 * (np.arange(height) + 0.5) / height - 1) * tan_half * height / width
    tan_angle = np.hypot(u[None, :], v[:, None])
    inside = tan_angle < np.tan(np.arcsin(1 / 4))
    assert inside.sum() > 300
    assert np.sum(inside != (coverage > 0.5)) <= 2  # pixel centres on the rim: rounding either way
    assert set(np.unique(coverage)) <= {0.0, 1.0}
    fine = material_coverage(SceneFile(_scene(tmp_path / "c", parent, "close")), subpixels=4)["gold"]
    assert fine.sum() == pytest.approx(inside.sum(), rel=0.03)
    hidden = material_coverage(SceneFile(_scene(tmp_path / "h", parent, "hidden")))["gold"]
    assert hidden.shape == (48, 64) and hidden.sum() == 0


def test_coverage_lies_where_the_render_shows_the_object(ladder, tmp_path):
    """Orientation and material matching: an off-centre sphere whose BSDF is nested without an id
    (named after its shape), and a second shape with a plain diffuse BSDF.  Rendered pixels the
    material does not cover show the constant background or the diffuse shape; covered ones the
    glossy gold, which is nowhere the grey background."""
    from neuralbrdf.render.preview import set_variant
    from neuralbrdf.render.scene_file import render_scene_file

    parent, _, _ = ladder
    lights = SCENE[SCENE.index('    <shape type="rectangle">'):SCENE.index("</scene>")]
    path = tmp_path / "offcentre.xml"
    path.write_text(f"""<scene version="3.0.0">
    <integrator type="path"><integer name="max_depth" value="3"/></integrator>
    <sensor type="perspective">
        <float name="fov" value="45"/>
        <transform name="to_world"><lookat origin="0, 0, 4" target="0, 0, 0" up="0, 1, 0"/></transform>
        <film type="hdrfilm"><integer name="width" value="64"/><integer name="height" value="48"/>
            <rfilter type="box"/></film>
    </sensor>
    <shape type="sphere" id="ball">
        <point name="center" value="1.1, 0.55, 0"/><float name="radius" value="0.6"/>
        <bsdf type="neuralbrdf"><string name="filename" value="{parent}"/></bsdf>
    </shape>
    <shape type="sphere">
        <point name="center" value="-1.2, -0.5, 0"/><float name="radius" value="0.5"/><bsdf type="diffuse"/>
    </shape>
{lights}</scene>
""")
    scene = SceneFile(path)
    assert [m.name for m in scene.materials()] == ["ball"]
    set_variant("llvm_ad_rgb")
    coverage = material_coverage(scene)["ball"]
    image, _ = render_scene_file(scene, spp=4)
    height, width = coverage.shape
    covered = coverage == 1.0
    assert 0.03 < covered.mean() < 0.3
    rows, cols = np.nonzero(covered)
    assert cols.mean() > width / 2 and rows.mean() < height / 2  # right and up, like the sphere's centre
    background = np.all(np.abs(image - 0.3) < 1e-4, axis=2)
    assert not np.any(background & covered)
    assert np.mean(background[coverage == 0.0]) > 0.6  # the rest: mostly background, the diffuse ball


QUICK = dataclasses.replace(CONFIG.select, variant="llvm_ad_rgb", resolution=24, spp=4, max_spp=8, timing_repeats=1)


def test_an_object_covering_no_pixel_gets_its_cheapest_rung(ladder, tmp_path):
    parent, folder, document = ladder
    scene = _scene(parent.parent / "hidden", parent, "hidden")
    out = tmp_path / "SELECTED.xml"
    result = select(scene, out, dataclasses.replace(QUICK, tolerance=0.5), log=lambda *_: None)
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
    scene = _scene(parent.parent / "close", parent, "close")
    # spectral variant: the candidates are the stand-in files (in RGB variants the parent with a looser
    # sRGB rule keeps the sampler and the paths, and may legitimately stay within a tight tolerance)
    settings = dataclasses.replace(QUICK, tolerance=0.05, variant="llvm_ad_spectral")
    result = select(scene, tmp_path / "SELECTED.xml", settings, log=lambda *_: None)
    (material,) = result["materials"]
    assert material["chosen_rung"] == "full"
    # every stand-in changed the image by more than the tolerance
    assert all(o["error_contribution"] > 0.05 for o in result["candidates"]["gold"][1:])
    noise = result["noise"]
    assert noise["render_seed_to_seed_delta_e2000_mean"] > 0.05  # a close-up at <= 8 spp is noisy ...
    # ... and the JSON says whether the estimates' own noise met a quarter of the tolerance
    assert noise["estimate_noise_within_fraction_of_tolerance"] == (noise["estimate_seed_to_seed_delta_e2000"] <= 0.0125)


def _cheap_ladder(folder: Path, target: Path) -> Path:
    """A copy of the ladder with every stand-in far cheaper than its parent (relative costs 0.1,
    0.2, ...): the fast fixture's measured costs (one round of small batches) are noise, and a
    stand-in measured as dearer than its parent would never be chosen by any rule."""
    import shutil

    shutil.copytree(folder, target)
    document = json.loads((target / "ladder.json").read_text())
    for k, rung in enumerate(r for r in document["rungs"] if r["name"] != "full"):
        rung["relative_cost"] = 0.1 * (k + 1)
    (target / "ladder.json").write_text(json.dumps(document))
    return target


def test_a_small_object_keeps_its_own_error_within_the_object_tolerance(ladder, tmp_path):
    """The far sphere covers a few per cent of the frame, so the whole-image mean dilutes its error:
    the rule before the per-object bound (whole image only) takes a stand-in that is visibly wrong
    on the sphere; with both bounds at 0.5 ΔE the choice must hold on the sphere's own pixels."""
    parent, folder, _ = ladder
    scene = _scene(parent.parent / "far", parent, "far")
    ladders = [_cheap_ladder(folder, tmp_path / "ladder")]
    settings = dataclasses.replace(QUICK, variant="llvm_ad_spectral", resolution=32, tolerance=0.5)
    result = select(scene, tmp_path / "SELECTED.xml", settings, ladders, log=lambda *_: None)
    (material,) = result["materials"]
    assert 0 < material["coverage_pixels"] < 0.1 * 32 * 24
    whole_image_only = best_combination(result["candidates"], 0.5, object_tolerance=float("inf"))["gold"]
    assert whole_image_only["rung"] != "full"
    assert whole_image_only["error_contribution"] <= 0.5 < whole_image_only["on_object_delta_e2000"]
    assert material["chosen_rung"] != whole_image_only["rung"]
    assert material["on_object_delta_e2000"] <= 0.5
    assert material["on_object_delta_e2000_selected_scene"] <= 0.5
    assert result["image_delta_e2000_mean"] <= 0.5
    assert result["verified_within_bounds"]


def test_select_refuses_a_scene_without_neural_materials(tmp_path):
    scene = tmp_path / "plain.xml"
    scene.write_text('<scene version="3.0.0"><shape type="sphere"/></scene>')
    with pytest.raises(InputError, match="no neuralbrdf material"):
        select(scene, tmp_path / "S.xml", QUICK)


def test_select_command_reads_its_config_and_refuses_bad_settings(tmp_path, capsys):
    from neuralbrdf.cli.main import main

    scene = tmp_path / "plain.xml"
    scene.write_text('<scene version="3.0.0"><shape type="sphere"/></scene>')
    out = tmp_path / "S.xml"
    bad = tmp_path / "bad.yaml"
    bad.write_text(CONFIG.path.read_text().replace("  tolerance: 1.0", "  tolerance: 1.0\n  tolerence: 2"))
    assert main(["select", str(scene), "--out", str(out), "--config", str(bad)]) == 2
    assert "select.tolerence" in capsys.readouterr().err
    assert main(["select", str(scene), "--out", str(out), "--object-tolerance", "0"]) == 2
    assert "--object-tolerance" in capsys.readouterr().err
    assert main(["select", str(scene), "--out", str(out), "--tolerance", "0.5"]) == 2  # the config's other values are valid
    assert "no neuralbrdf material" in capsys.readouterr().err
    assert not out.exists()


def test_ladder_command_takes_tables_and_students_from_its_options(tmp_path, capsys):
    from neuralbrdf.cli.main import main
    from onnx_fixtures import write_lambert

    parent = write_lambert(tmp_path / "lambert.onnx")
    fast = tmp_path / "fast.yaml"
    fast.write_text(CONFIG.path.read_text().replace("cost_batches: [1048576, 4194304]", "cost_batches: [4096, 16384]")
                    .replace("cost_rounds: 9", "cost_rounds: 1").replace("abc_starts: 8", "abc_starts: 1"))
    out = tmp_path / "out"
    assert main(["ladder", str(parent), "--out-dir", str(out), "--tables", "4x3"]) == 2
    assert "--tables '4x3'" in capsys.readouterr().err and not out.exists()
    assert main(["ladder", str(parent), "--out-dir", str(out), "--config", str(fast), "--tables", "4x3x2x5",
                 "--students"]) == 0
    document = json.loads((out / "ladder.json").read_text())
    assert document["settings"]["tables"] == [[4, 3, 2, 5]] and document["settings"]["students"] == []
    assert sorted(r["name"] for r in document["rungs"]) == ["full", "table_4x3x2"]


# --------------------------------------------------------------------------- render.py --scene


def test_render_command_renders_a_user_scene(ladder, tmp_path):
    parent, _, _ = ladder
    scene = _scene(parent.parent / "user", parent, "close")
    out = tmp_path / "scene.png"
    code = render_command.main(["--scene", str(scene), "--out", str(out), "--variant", "llvm_ad_rgb", "--resolution", "16",
                        "--spp", "2", "--quiet"])
    assert code == 0 and out.is_file()
    code = render_command.main(["--scene", str(tmp_path / "missing.xml"), "--out", str(tmp_path / "x.png"), "--quiet"])
    assert code == 2 and not (tmp_path / "x.png").exists()


GOOD_SCENE = ('<scene version="3.0.0"><integrator type="path"/><sensor type="perspective"><film type="hdrfilm">'
              '<integer name="width" value="16"/><integer name="height" value="12"/></film></sensor>'
              '<bsdf type="neuralbrdf" id="m"><string name="filename" value="model.onnx"/></bsdf>'
              '<shape type="sphere"><ref id="m"/></shape><emitter type="constant"/></scene>')


@pytest.mark.parametrize("options, message", [
    (["--tolerance", "inf"], "--tolerance must be a finite number > 0, got inf"),
    (["--tolerance", "nan"], "--tolerance must be a finite number > 0, got nan"),
    (["--tolerance", "0"], "--tolerance must be a finite number > 0, got 0.0"),
    (["--tolerance", "-1"], "--tolerance must be a finite number > 0, got -1.0"),
    (["--object-tolerance", "inf"], "--object-tolerance must be a finite number > 0, got inf"),
    (["--seed", "-3"], "seed must be a non-negative integer, got -3"),
    (["--resolution", "1000000"], "resolution must be at most 1024"),
    (["--out", "SCENE"], "is also an input of this command"),
])
def test_select_refuses_bad_settings_and_outputs_before_any_render(tmp_path, capsys, monkeypatch, options, message):
    """A tolerance of inf ran the whole selection, then failed writing its JSON; a negative seed and a
    huge resolution were tracebacks; an output that is the scene failed after every render."""
    from neuralbrdf.cli.main import main
    from neuralbrdf.lod import select as selection
    from onnx_fixtures import write_lambert

    monkeypatch.setattr(selection, "material_coverage", lambda *_: pytest.fail("rendered before the checks"))
    write_lambert(tmp_path / "model.onnx")
    scene = tmp_path / "scene.xml"
    scene.write_text(GOOD_SCENE)
    options = [str(scene) if o == "SCENE" else o for o in options]
    out = ["--out", str(tmp_path / "S.xml")] if "--out" not in options else []
    assert main(["select", str(scene), *out, *options]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and message in err, err
    assert sorted(p.name for p in tmp_path.iterdir()) == ["model.onnx", "scene.xml"]


def test_a_scene_that_cannot_render_is_one_line_naming_it(tmp_path, capsys):
    from neuralbrdf.cli.main import main
    from onnx_fixtures import write_lambert

    write_lambert(tmp_path / "model.onnx")
    scene = tmp_path / "scene.xml"  # no <integrator>
    scene.write_text('<scene version="3.0.0"><sensor type="perspective"><film type="hdrfilm"><integer name="width" '
                     'value="16"/><integer name="height" value="16"/></film></sensor><bsdf type="neuralbrdf" id="m">'
                     '<string name="filename" value="model.onnx"/></bsdf><shape type="sphere"><ref id="m"/></shape>'
                     '<emitter type="constant"/></scene>')
    assert main(["select", str(scene), "--out", str(tmp_path / "S.xml"), "--variant", "llvm_ad_rgb",
                 "--resolution", "16", "--spp", "2", "--max-spp", "2"]) == 2
    err = capsys.readouterr().err
    assert err == f"neuralbrdf select: error: {scene}: cannot render the scene: No integrator specified! Add an " \
                  "integrator in the scene description or provide an integrator directly as argument.\n", err


@pytest.mark.parametrize("change, ladder, message", [
    (("</scene>", ""), None, "not XML: no element found"),
    ((GOOD_SCENE, '<shape type="sphere"/>'), None, "the root element is <shape>, expected <scene>"),
    (('value="model.onnx"', 'value="missing.onnx"'), None, "the model file of neuralbrdf material 'm' does not exist"),
    (('value="16"', 'value="wide"'), None, "the film's width/height are not numbers"),
    (("", ""), '{"rungs": [', "ladder.json: not JSON"),
])
def test_a_malformed_scene_or_ladder_is_one_line_before_any_render(tmp_path, capsys, monkeypatch, change, ladder,
                                                                    message):
    from neuralbrdf.cli.main import main
    from neuralbrdf.lod import select as selection
    from onnx_fixtures import write_lambert

    monkeypatch.setattr(selection, "material_coverage", lambda *_: pytest.fail("rendered before the checks"))
    write_lambert(tmp_path / "model.onnx")
    scene = tmp_path / "scene.xml"
    scene.write_text(GOOD_SCENE.replace(*change))
    extra = []
    if ladder is not None:
        (tmp_path / "bad.ladder").mkdir()
        (tmp_path / "bad.ladder" / "ladder.json").write_text(ladder)
        extra = ["--ladder", str(tmp_path / "bad.ladder")]
    assert main(["select", str(scene), "--out", str(tmp_path / "S.xml"), *extra]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and message in err, err
    assert not (tmp_path / "S.xml").exists()
