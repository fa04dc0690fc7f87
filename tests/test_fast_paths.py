"""Fast paths inside a model file (docs/formats.md#onnx-model-files, docs/select.md): the contract's extra outputs, the plugin's choice
of output, ``neuralbrdf export`` distilling them, ``render --fast``, ``evaluate``, the ladder and
the selector.

Most tests use fast paths whose values are known (a Lambertian RGB head on a spectral Lambertian,
merged with :func:`~neuralbrdf.onnx_export.with_fast_paths`), so that which output was evaluated
shows in the value; the distillation itself runs once per module with tiny settings.
"""

from __future__ import annotations

import dataclasses
import json
import math
from pathlib import Path

import drjit as dr
import mitsuba as mi
import numpy as np
import onnx
import onnxruntime
import pytest
import torch

import onnx_fixtures as fx
from neuralbrdf.cli import export_command, render_command
from neuralbrdf.errors import InputError
from neuralbrdf.evaluation.scores import OnnxEvaluator, TorchEvaluator, hemisphere_scores
from neuralbrdf.evaluation.truth import export_truth
from neuralbrdf.kinds import abc as abc_kind
from neuralbrdf.kinds import load_model
from neuralbrdf.lod.config import load_lod_config
from neuralbrdf.lod.distill import DistillSettings, distill_student, rgb_teacher, teacher_samples
from neuralbrdf.lod.fast_paths import FastPathError, ImageCheck, add_fast_paths
from neuralbrdf.lod.ladder import FAST_RUNG, build_ladder, embedded_ladder
from neuralbrdf.lod.select import find_ladders
from neuralbrdf.models.student import DirectionalStudent
from neuralbrdf.onnx_contract import OUTPUT_F, OUTPUT_FAST, OUTPUT_RGB, fast_path_key, output_model
from neuralbrdf.onnx_export import with_fast_paths
from neuralbrdf.physics.abc import AbcParameters
from neuralbrdf.render import register
from neuralbrdf.render.fast_paths import ADD_COMMAND, chosen_output
from neuralbrdf.render.scene_file import SceneFile
from neuralbrdf.render.spectral_quadrature import RuleRgbEvaluator, full_rule

CONFIG = load_lod_config()  # the shipped configs/lod/default.yaml
TINY = dataclasses.replace(
    CONFIG.fast_paths,
    distill=dataclasses.replace(CONFIG.fast_paths.distill, n_pairs=4096, steps=300, batch=1024),
    error_strata=(8, 10), max_hemisphere_logcos_rmse=1.0,
    image_check=ImageCheck(resolution=24, spp=4, seed=0, max_delta_e2000_mean=100.0),
)
HEAD_ALBEDO = (0.8, 0.5, 0.2)


class RgbFromWavelength(torch.nn.Module):
    """An RGB output that reads the wavelength (not allowed for ``f_rgb``)."""

    def forward(self, wi, wo, wavelength):
        y = (wavelength / 700.0)[:, None].expand(-1, 3) * 0.1
        return torch.where(((wi[:, 2] > 0) & (wo[:, 2] > 0))[:, None], y, torch.zeros_like(y))


class NegativeRgb(torch.nn.Module):
    def forward(self, wi, wo):
        return torch.zeros_like(wi) - 0.5 * ((wi[:, 2:] > 0) & (wo[:, 2:] > 0))


def traced(module, tmp_path: Path, name: str, spectral: bool) -> onnx.ModelProto:
    path = fx.export_module(module, tmp_path / f"{name}.onnx", {}, spectral=spectral)
    return onnx.load(str(path))


def entries(output: str, error: float = 0.01, cost: float = 0.5) -> dict[str, str]:
    return {fast_path_key(output, "approximates"): "a fixture", fast_path_key(output, "hemisphere_logcos_rmse"): repr(error),
            fast_path_key(output, "relative_cost"): repr(cost)}


def with_paths(parent: Path, paths: dict[str, onnx.ModelProto], out: Path, metadata: dict | None = None) -> Path:
    if metadata is None:
        metadata = {k: v for output in paths for k, v in entries(output).items()}
    onnx.save(with_fast_paths(onnx.load(str(parent)), paths, metadata), str(out))
    return out


@pytest.fixture(scope="module")
def lambert_files(tmp_path_factory):
    """A spectral Lambertian with an RGB head ``HEAD_ALBEDO / π`` and a fast path ``0.3 + 0.6 (λ-400)/300``
    (over π), and an RGB Lambertian with a fast path of another albedo."""
    d = tmp_path_factory.mktemp("fast_paths")
    spectral = fx.write_spectral_lambert(d / "spectral.onnx")
    rgb = fx.write_lambert(d / "rgb.onnx", albedo=(0.5, 0.5, 0.5))
    head = traced(fx.Lambert(HEAD_ALBEDO), d, "head", spectral=False)
    fast_spectral = traced(fx.SpectralLambert(a=0.3), d, "fast_spectral", spectral=True)
    fast_rgb = traced(fx.Lambert((0.1, 0.2, 0.3)), d, "fast_rgb", spectral=False)
    return {
        "spectral": spectral,
        "rgb": rgb,
        "spectral+paths": with_paths(spectral, {OUTPUT_RGB: head, OUTPUT_FAST: fast_spectral}, d / "spectral_paths.onnx"),
        "rgb+fast": with_paths(rgb, {OUTPUT_FAST: fast_rgb}, d / "rgb_fast.onnx"),
        "dir": d,
    }


# --------------------------------------------------------------------------- the contract


def test_a_file_with_fast_paths_loads_and_each_output_cuts_out_alone(lambert_files):
    model = load_model(lambert_files["spectral+paths"])
    assert set(model.fast_paths) == {OUTPUT_RGB, OUTPUT_FAST}
    assert model.fast_paths[OUTPUT_RGB].relative_cost == 0.5
    assert [o.name for o in model.proto.graph.output] == [OUTPUT_F, OUTPUT_RGB, OUTPUT_FAST]
    wi, wo = np.array([[0.3, 0.1, 0.9]], np.float32), np.array([[-0.2, 0.4, 0.8]], np.float32)
    values = {}
    for output in (OUTPUT_F, OUTPUT_RGB, OUTPUT_FAST):
        view = model.output_view(output)
        names = sorted(vi.name for vi in view.proto.graph.input)
        assert [o.name for o in view.proto.graph.output] == [OUTPUT_F] and not view.fast_paths
        session = onnxruntime.InferenceSession(view.proto.SerializeToString(), providers=["CPUExecutionProvider"])
        feeds = {"wi": wi, "wo": wo, "wavelength": np.array([550.0], np.float32)}
        values[output] = session.run(["f"], {n: feeds[n] for n in names})[0]
        assert names == (["wi", "wo"] if output == OUTPUT_RGB else ["wavelength", "wi", "wo"])
    assert values[OUTPUT_RGB] == pytest.approx(np.array([HEAD_ALBEDO]) / math.pi, rel=1e-6)
    assert values[OUTPUT_F] == pytest.approx((0.2 + 0.6 * 0.5) / math.pi, rel=1e-6)
    assert values[OUTPUT_FAST] == pytest.approx((0.3 + 0.6 * 0.5) / math.pi, rel=1e-6)
    assert not model.output_view(OUTPUT_RGB).is_spectral
    plain = load_model(lambert_files["spectral"])
    assert plain.output_view(OUTPUT_F) is plain  # nothing to cut


def test_output_model_keeps_only_what_the_output_reads(lambert_files):
    proto = load_model(lambert_files["spectral+paths"]).proto
    head = output_model(proto, OUTPUT_RGB)
    names = {n.name for n in head.graph.node}
    assert names and all(n.startswith(f"{OUTPUT_RGB}/") or n == f"{OUTPUT_RGB}_as_f" for n in names)
    assert all(i.name.startswith(f"{OUTPUT_RGB}/") for i in head.graph.initializer)
    full = output_model(proto, OUTPUT_F)
    assert not any(n.name.startswith(("f_rgb/", "f_fast/")) for n in full.graph.node)


@pytest.mark.parametrize("case, fragment", [
    ("rgb head of an RGB model", "'f_rgb' is the linear sRGB of a spectral model"),
    ("rgb head reading the wavelength", "'f_rgb' depends on 'wavelength'"),
    ("missing entry", "key 'neuralbrdf.f_fast.relative_cost': the fast path 'f_fast' lacks its metadata entry"),
    ("entry without output", "describes the fast path 'f_rgb', which the graph does not output"),
    ("negative fast path", "fast path 'f_fast': output 'f' is negative"),
    ("bad cost", "key 'neuralbrdf.f_fast.relative_cost': metadata value 0.0 must be > 0"),
])
def test_a_bad_fast_path_is_refused_naming_it(lambert_files, case, fragment):
    d = lambert_files["dir"]
    head = traced(fx.Lambert(HEAD_ALBEDO), d, "head2", spectral=False)
    out = d / f"bad_{case.replace(' ', '_')}.onnx"
    if case == "rgb head of an RGB model":
        with_paths(lambert_files["rgb"], {OUTPUT_RGB: head}, out)
    elif case == "rgb head reading the wavelength":
        with_paths(lambert_files["spectral"], {OUTPUT_RGB: traced(RgbFromWavelength(), d, "wl", True)}, out)
    elif case == "missing entry":
        metadata = entries(OUTPUT_FAST)
        del metadata[fast_path_key(OUTPUT_FAST, "relative_cost")]
        with_paths(lambert_files["rgb"], {OUTPUT_FAST: head}, out, metadata)
    elif case == "entry without output":
        with_paths(lambert_files["rgb"], {OUTPUT_FAST: head}, out, {**entries(OUTPUT_FAST), **entries(OUTPUT_RGB)})
    elif case == "negative fast path":
        with_paths(lambert_files["rgb"], {OUTPUT_FAST: traced(NegativeRgb(), d, "neg", False)}, out)
    else:
        with_paths(lambert_files["rgb"], {OUTPUT_FAST: head}, out, entries(OUTPUT_FAST, cost=0.0))
    with pytest.raises(InputError) as info:
        load_model(out)
    assert str(out) in str(info.value) and fragment in str(info.value)


def test_an_unknown_extra_output_and_a_duplicate_are_refused(lambert_files):
    d = lambert_files["dir"]
    head = traced(fx.Lambert(HEAD_ALBEDO), d, "head3", spectral=False)
    proto = with_fast_paths(onnx.load(str(lambert_files["rgb"])), {OUTPUT_FAST: head}, entries(OUTPUT_FAST))
    proto.graph.output[1].name = "f_slow"
    (producer,) = [n for n in proto.graph.node if OUTPUT_FAST in n.output]
    producer.output[:] = ["f_slow" if o == OUTPUT_FAST else o for o in producer.output]
    onnx.save(proto, str(d / "slow.onnx"))
    with pytest.raises(InputError, match=r"graph outputs are \['f', 'f_slow'\]; expected \['f'\], optionally"):
        load_model(d / "slow.onnx")
    with pytest.raises(ValueError, match="already has the fast path 'f_fast'"):
        with_fast_paths(onnx.load(str(lambert_files["rgb+fast"])), {OUTPUT_FAST: head}, {})


# --------------------------------------------------------------------------- the plugin's choice


def test_chosen_output_follows_variant_and_properties(lambert_files):
    both = load_model(lambert_files["spectral+paths"])
    plain = load_model(lambert_files["spectral"])
    rgb_fast = load_model(lambert_files["rgb+fast"])
    assert chosen_output(both, spectral_variant=False, fast=False, rgb_head=True) == OUTPUT_RGB
    assert chosen_output(both, spectral_variant=False, fast=False, rgb_head=False) == OUTPUT_F
    assert chosen_output(both, spectral_variant=False, fast=True, rgb_head=False) == OUTPUT_FAST
    assert chosen_output(both, spectral_variant=True, fast=False, rgb_head=True) == OUTPUT_F
    assert chosen_output(both, spectral_variant=True, fast=True, rgb_head=True) == OUTPUT_FAST
    assert chosen_output(plain, spectral_variant=False, fast=False, rgb_head=True) == OUTPUT_F
    assert chosen_output(rgb_fast, spectral_variant=False, fast=True, rgb_head=True) == OUTPUT_FAST
    with pytest.raises(InputError) as info:
        chosen_output(plain, spectral_variant=True, fast=True, rgb_head=True)
    assert ADD_COMMAND in str(info.value) and str(lambert_files["spectral"]) in str(info.value)


def _eval(bsdf, n=4):
    wi = np.tile([[0.3, 0.1, 0.9]], (n, 1)).astype(np.float32)
    wo = np.tile([[-0.2, 0.4, 0.8]], (n, 1)).astype(np.float32)
    wi /= np.linalg.norm(wi, axis=1, keepdims=True)
    wo /= np.linalg.norm(wo, axis=1, keepdims=True)
    si = dr.zeros(mi.SurfaceInteraction3f, n)
    si.wi = mi.Vector3f(wi.T)
    if mi.is_spectral:
        si.wavelengths = mi.Spectrum(np.full((4, n), 550.0, np.float32))
    value = bsdf.eval(mi.BSDFContext(), si, mi.Vector3f(wo.T))
    return np.asarray(value.numpy()).T[0] / wo[0, 2]


@pytest.mark.parametrize("backend", ["drjit", "onnxruntime"])
def test_the_plugin_evaluates_the_output_asked_for(lambert_files, backend):
    saved = dr.flag(dr.JitFlag.SymbolicLoops), dr.flag(dr.JitFlag.SymbolicCalls)
    dr.set_flag(dr.JitFlag.SymbolicLoops, False)
    dr.set_flag(dr.JitFlag.SymbolicCalls, False)
    try:
        path = str(lambert_files["spectral+paths"])
        mi.set_variant("llvm_ad_rgb")
        register()

        def load(**properties):
            return mi.load_dict({"type": "neuralbrdf", "filename": path, "backend": backend, **properties})

        head = load()
        assert head.output == OUTPUT_RGB and "output = f_rgb" in str(head)
        assert _eval(head) == pytest.approx(np.array(HEAD_ALBEDO) / math.pi, rel=1e-5)
        integrated = load(rgb_head=False)  # the spectrum integrated to sRGB: a grey-ish ramp, not the head
        assert integrated.output == OUTPUT_F and integrated.rgb_rule is not None
        assert not np.allclose(_eval(integrated), np.array(HEAD_ALBEDO) / math.pi, rtol=0.05)
        mi.set_variant("llvm_ad_spectral")
        register()
        assert _eval(load())[0] == pytest.approx(0.5 / math.pi, rel=1e-5)
        assert _eval(load(fast=True))[0] == pytest.approx(0.6 / math.pi, rel=1e-5)
        assert _eval(load(fast="true"))[0] == pytest.approx(0.6 / math.pi, rel=1e-5)  # as scene edits write it
        with pytest.raises(Exception, match="asks for a fast path and the model has none"):
            mi.load_dict({"type": "neuralbrdf", "filename": str(lambert_files["spectral"]), "fast": True})
        with pytest.raises(Exception, match="expected true or false, got 'maybe'"):
            load(fast="maybe")
    finally:
        dr.set_flag(dr.JitFlag.SymbolicLoops, saved[0])
        dr.set_flag(dr.JitFlag.SymbolicCalls, saved[1])


def test_scene_edits_write_boolean_properties(lambert_files, tmp_path):
    scene = tmp_path / "scene.xml"
    scene.write_text(f'<scene version="3.0.0"><bsdf type="neuralbrdf" id="m"><string name="filename" '
                     f'value="{lambert_files["rgb+fast"]}"/></bsdf></scene>')
    edited = SceneFile(scene)
    edited.set_all("fast", "true")
    assert '<boolean name="fast" value="true"' in edited.text()


# --------------------------------------------------------------------------- students and distillation


def test_a_student_is_reciprocal_isotropic_and_zero_below_the_horizon():
    torch.manual_seed(0)
    student = DirectionalStudent(8, 2, activation="tanh")
    rng = np.random.default_rng(1)
    wi, wo = (torch.from_numpy(upper(rng.normal(size=(64, 3)) + [0, 0, 1.5])).float() for _ in range(2))
    with torch.no_grad():
        f = student(wi, wo)
        assert torch.allclose(f, student(wo, wi), rtol=1e-5)  # reciprocity
        angle = 0.7
        rot = torch.tensor([[math.cos(angle), -math.sin(angle), 0.0], [math.sin(angle), math.cos(angle), 0.0], [0, 0, 1.0]])
        assert torch.allclose(f, student(wi @ rot.T, wo @ rot.T), rtol=1e-4)  # isotropy
        below = wi.clone()
        below[:, 2] *= -1
        assert torch.all(student(below, wo) == 0) and torch.all(f > 0)
    spectral = DirectionalStudent(4, 1, wavelength_range_nm=(400.0, 700.0))
    assert spectral(wi, wo, torch.full((64,), 500.0)).shape == (64,)


def upper(v):
    """Unit rows of ``v`` turned into the upper hemisphere."""
    v = v / np.linalg.norm(v, axis=1, keepdims=True)
    v[:, 2] = np.abs(v[:, 2]) + 1e-3
    return v / np.linalg.norm(v, axis=1, keepdims=True)


def test_distill_student_fits_an_rgb_teacher():
    """A student of a known smooth RGB BRDF (ABC, RGB) gets within a few per cent in log-cos."""
    parameters = AbcParameters(kd=[0.3, 0.2, 0.1], A=[0.2, 0.2, 0.2], B=20.0, C=1.0, eta=1.5)
    teacher = TorchEvaluator(abc_kind.exportable(parameters, "smooth", "test").module, False)
    samples = teacher_samples(teacher, 2048, seed=0)
    settings = DistillSettings(n_pairs=2048, steps=300, batch=512, lr=0.02, final_lr_fraction=0.05, seed=0)
    untrained = DirectionalStudent(8, 2, activation="relu")
    student = distill_student(samples, 8, 2, "relu", settings)
    after = hemisphere_scores(TorchEvaluator(student, False), teacher, strata=(6, 8))["hemisphere_logcos_rmse"]
    before = hemisphere_scores(TorchEvaluator(untrained, False), teacher, strata=(6, 8))["hemisphere_logcos_rmse"]
    assert after < 0.03 and after < before / 3


def test_rgb_teacher_is_the_plugins_exact_integral(lambert_files):
    """The RGB head's teacher is docs/formats.md#spectral-to-linear-srgb on all 31 wavelengths: the same numbers as the
    project's own spectral → sRGB conversion of the model's spectrum."""
    from neuralbrdf.data.colorimetry import spectral_to_linear_srgb

    parent = OnnxEvaluator(lambert_files["spectral"])
    teacher = rgb_teacher(parent)
    assert isinstance(teacher, RuleRgbEvaluator) and full_rule(parent.model.wavelength_range_nm).size == 31
    wi, wo = np.array([[0.0, 0.0, 1.0], [0.5, 0.1, 0.86]]), np.array([[0.3, 0.0, 0.954], [-0.4, 0.2, 0.89]])
    grid = np.arange(400.0, 701.0, 10.0)
    spectra = np.stack([parent.values(np.repeat(wi[k:k + 1], 31, 0), np.repeat(wo[k:k + 1], 31, 0), grid)
                        for k in range(len(wi))])
    expected = np.clip(spectral_to_linear_srgb(spectra, grid), 0.0, None)
    assert teacher.values(wi, wo) == pytest.approx(expected, rel=1e-5)
    assert rgb_teacher(OnnxEvaluator(lambert_files["rgb"])).values(wi, wo)[0] == pytest.approx([0.5 / math.pi] * 3)


@pytest.fixture(scope="module")
def distilled(tmp_path_factory):
    """The virtual gold's truth (spectral) with both fast paths, distilled with tiny settings."""
    d = tmp_path_factory.mktemp("distilled")
    parent = d / "gold.onnx"
    export_truth("virtual:gold", parent)
    out = d / "gold_fast.onnx"
    reports = add_fast_paths(parent, out, (OUTPUT_RGB, OUTPUT_FAST), TINY, log=lambda *_: None)
    return parent, out, reports


def test_add_fast_paths_records_error_and_cost_that_hold(distilled):
    parent, out, reports = distilled
    model = load_model(out)
    assert set(model.fast_paths) == {OUTPUT_RGB, OUTPUT_FAST}
    for report in reports:
        recorded = model.fast_paths[report.output]
        assert recorded.hemisphere_logcos_rmse == pytest.approx(report.hemisphere_logcos_rmse)
        assert 0 < recorded.relative_cost < 1 and "distilled from 4096 samples of the " in recorded.approximates
        # measured again, through onnxruntime, against the teacher: the record holds
        reference = OnnxEvaluator(parent)
        teacher = rgb_teacher(reference) if report.output == OUTPUT_RGB else reference
        again = hemisphere_scores(OnnxEvaluator(out, report.output), teacher, strata=TINY.error_strata)
        assert again["hemisphere_logcos_rmse"] == pytest.approx(recorded.hemisphere_logcos_rmse, rel=1e-3, abs=1e-5)
    # f itself is unchanged
    wi, wo = np.array([[0.2, 0.0, 0.98]]), np.array([[-0.2, 0.0, 0.98]])
    nm = np.array([550.0])
    assert OnnxEvaluator(out).values(wi, wo, nm) == pytest.approx(OnnxEvaluator(parent).values(wi, wo, nm), rel=1e-6)


def test_each_fast_path_records_its_image_error_against_f(distilled):
    """The record is the mean CIEDE2000 of the preview scene through the fast path against f, same
    seed and paths (measured again here from the written file), in the variant where it is used."""
    from neuralbrdf.evaluation.images import image_scores
    from neuralbrdf.render.preview import Material, render

    _, out, reports = distilled
    model = load_model(out)
    check = TINY.image_check
    for report in reports:
        recorded = model.fast_paths[report.output]
        variant = "llvm_ad_spectral" if report.output == OUTPUT_FAST else "llvm_ad_rgb"
        assert recorded.image_delta_e2000_mean == pytest.approx(report.image_delta_e2000_mean)
        assert variant in recorded.image_check and "24 px, 4 spp" in recorded.image_check
        f_image = render(Material(model=out, rgb_head=False), variant, check.spp, check.resolution, check.seed)
        image = render(Material(model=out, fast=report.output == OUTPUT_FAST, rgb_head=report.output == OUTPUT_RGB),
                       variant, check.spp, check.resolution, check.seed)
        again = image_scores(image, f_image)[0]["image_delta_e2000_mean"]
        assert recorded.image_delta_e2000_mean == pytest.approx(again, rel=1e-6) and again > 0


def test_a_student_above_its_image_bound_writes_nothing(distilled, tmp_path):
    parent, _, _ = distilled
    strict = dataclasses.replace(TINY, image_check=dataclasses.replace(TINY.image_check, max_delta_e2000_mean=1e-9))
    out = tmp_path / "never.onnx"
    with pytest.raises(FastPathError, match="image_check.max_delta_e2000_mean"):
        add_fast_paths(parent, out, (OUTPUT_FAST,), strict, log=lambda *_: None)
    assert not out.exists()


def test_a_student_above_its_error_bound_writes_nothing(distilled, tmp_path):
    parent, _, _ = distilled
    strict = dataclasses.replace(TINY, max_hemisphere_logcos_rmse=1e-9)
    out = tmp_path / "never.onnx"
    with pytest.raises(FastPathError, match="above the bound 1e-09"):
        add_fast_paths(parent, out, (OUTPUT_FAST,), strict, log=lambda *_: None)
    assert not out.exists()


# --------------------------------------------------------------------------- commands


def tiny_config(tmp_path: Path) -> Path:
    """configs/lod/default.yaml with the tiny fast-path settings of this module."""
    import yaml

    raw = yaml.safe_load(CONFIG.path.read_text())
    raw["fast_paths"]["distill"].update(n_pairs=4096, steps=100, batch=1024)
    raw["fast_paths"].update(error_strata=[6, 8], max_hemisphere_logcos_rmse=1.0)
    raw["fast_paths"]["image_check"].update(resolution=16, spp=2, max_delta_e2000_mean=100.0)
    path = tmp_path / "tiny.yaml"
    path.write_text(yaml.safe_dump(raw))
    return path


def test_export_command_adds_fast_paths_to_a_model_file(lambert_files, tmp_path, capsys):
    config = tiny_config(tmp_path)
    out = tmp_path / "with_head.onnx"
    assert export_command.main(["--model", str(lambert_files["spectral"]), "--out", str(out), "--config", str(config)]) == 0
    assert set(load_model(out).fast_paths) == {OUTPUT_RGB}  # a spectral model gets its RGB head by default
    assert "wrote" in capsys.readouterr().out
    # an RGB model has nothing to add without --fast; a spectral one with --no-rgb-head neither
    for source, flags in ((lambert_files["rgb"], []), (lambert_files["spectral"], ["--no-rgb-head"])):
        code = export_command.main(["--model", str(source), "--out", str(tmp_path / "x.onnx"), *flags])
        assert code == 2 and "nothing to add" in capsys.readouterr().err
    # an output may not be the model it reads
    code = export_command.main(["--model", str(out), "--out", str(out), "--fast", "--config", str(config)])
    assert code == 2
    assert not (tmp_path / "x.onnx").exists()


def test_export_command_fails_without_writing_when_a_student_misses_its_bound(lambert_files, tmp_path, capsys):
    import yaml

    config = tiny_config(tmp_path)
    raw = yaml.safe_load(config.read_text())
    raw["fast_paths"]["max_hemisphere_logcos_rmse"] = 1e-12
    config.write_text(yaml.safe_dump(raw))
    out = tmp_path / "never.onnx"
    code = export_command.main(["--model", str(lambert_files["rgb"]), "--out", str(out), "--fast", "--config", str(config)])
    assert code == 1 and "not written" in capsys.readouterr().err and not out.exists()


def test_render_fast_refuses_a_model_without_one_and_notes_it_in_a_scene(lambert_files, tmp_path, capsys):
    out = tmp_path / "image.png"
    code = render_command.main(["--model", str(lambert_files["rgb"]), "--out", str(out), "--fast", "--quiet",
                                "--resolution", "8", "--spp", "1"])
    assert code == 2 and ADD_COMMAND in capsys.readouterr().err and not out.exists()
    scene = tmp_path / "scene.xml"
    text = fx_scene(lambert_files["rgb"], lambert_files["rgb+fast"])
    scene.write_text(text)
    code = render_command.main(["--scene", str(scene), "--out", str(out), "--fast", "--quiet", "--spp", "1",
                                "--resolution", "8", "--variant", "llvm_ad_rgb"])
    err = capsys.readouterr().err
    assert code == 0 and "plain has no fast path and renders full" in err and out.exists()


def fx_scene(plain: Path, fast: Path) -> str:
    return f"""<scene version="3.0.0">
    <integrator type="path"><integer name="max_depth" value="2"/></integrator>
    <sensor type="perspective"><transform name="to_world"><lookat origin="0, 0, 4" target="0, 0, 0" up="0, 1, 0"/></transform>
        <film type="hdrfilm"><integer name="width" value="8"/><integer name="height" value="8"/></film></sensor>
    <bsdf type="neuralbrdf" id="plain"><string name="filename" value="{plain}"/></bsdf>
    <bsdf type="neuralbrdf" id="quick"><string name="filename" value="{fast}"/></bsdf>
    <shape type="sphere"><point name="center" value="-1, 0, 0"/><ref id="plain"/></shape>
    <shape type="sphere"><point name="center" value="1, 0, 0"/><ref id="quick"/></shape>
    <emitter type="constant"/>
</scene>"""


def test_a_missing_model_names_the_command_that_makes_it(tmp_path):
    scene = tmp_path / "scene.xml"
    scene.write_text('<scene version="3.0.0"><default name="neuralbrdf_models_command" value="bash make_models.sh"/>'
                     '<bsdf type="neuralbrdf" id="gold"><string name="filename" value="models/gold.onnx"/></bsdf></scene>')
    with pytest.raises(InputError, match="does not exist: .*gold.onnx; this scene's models are made by: bash make_models.sh"):
        SceneFile(scene).materials()
    demo = Path(__file__).resolve().parents[1] / "export" / "scenes" / "lod_demo.xml"
    assert "bash export/lod_models.sh" in SceneFile(demo).expand("$neuralbrdf_models_command")


# --------------------------------------------------------------------------- ladder and selection


def test_a_fast_path_is_a_rung_of_the_ladder_and_of_the_selector(lambert_files, tmp_path):
    parent = lambert_files["rgb+fast"]
    ladder = embedded_ladder(parent)
    assert [r.name for r in ladder.rungs] == ["full", FAST_RUNG]
    assert dict(ladder.rungs[1].properties) == {"fast": "true"} and ladder.rungs[1].relative_cost == 0.5
    assert embedded_ladder(lambert_files["rgb"]) is None
    scene = tmp_path / "scene.xml"
    scene.write_text(fx_scene(lambert_files["rgb"], parent))
    found = find_ladders(SceneFile(scene), [])
    assert found["plain"] is None and [r.name for r in found["quick"].rungs] == ["full", FAST_RUNG]
    settings = dataclasses.replace(CONFIG.ladder, students=(), tables=(), abc_pairs=256, abc_starts=1,
                                   cost_batches=(2**10, 2**12), cost_rounds=1, error_strata=(6, 8))
    document = build_ladder(parent, tmp_path / "ladder", settings, log=lambda *_: None)
    (fast,) = [r for r in document["rungs"] if r["name"] == FAST_RUNG]
    assert fast["bsdf_properties"] == {"fast": "true"} and Path(fast["file"]) == parent.resolve()
    # measured, not copied from the metadata (0.01): albedo (0.1, 0.2, 0.3) against 0.5
    expected = hemisphere_scores(OnnxEvaluator(parent, OUTPUT_FAST), OnnxEvaluator(parent), strata=(6, 8))
    assert fast["hemisphere_logcos_rmse"] == pytest.approx(expected["hemisphere_logcos_rmse"]) and expected[
        "hemisphere_logcos_rmse"] > 0.02


def test_a_spectral_parent_with_an_rgb_head_gets_no_rgb_rule_rungs(lambert_files, tmp_path):
    settings = dataclasses.replace(CONFIG.ladder, students=(), tables=(), abc_pairs=256, abc_starts=1,
                                   cost_batches=(2**10, 2**12), cost_rounds=1, error_strata=(6, 8),
                                   rgb_tolerances=(0.5,))
    rungs = {r["name"]: r for r in build_ladder(lambert_files["spectral+paths"], tmp_path / "a", settings,
                                                log=lambda *_: None)["rungs"]}
    assert FAST_RUNG in rungs and not any(n.startswith("full_rgb") for n in rungs)
    # in RGB variants the parent renders through its head: its stand-ins are for spectral variants
    assert all(r["variants"] == "spectral" for n, r in rungs.items() if n != "full")
    fast = embedded_ladder(lambert_files["spectral+paths"]).rungs[1]
    assert fast.applies_in(rgb_variant=False) and not fast.applies_in(rgb_variant=True)
    assert embedded_ladder(lambert_files["rgb+fast"]).rungs[1].applies_in(rgb_variant=True)


def test_evaluate_reports_the_fast_paths(lambert_files, tmp_path):
    from neuralbrdf.evaluation.evaluate import RenderSettings, evaluate, format_table

    truth = lambert_files["spectral"]
    result = evaluate(lambert_files["spectral+paths"], truth, tmp_path / "eval",
                      RenderSettings("llvm_ad_rgb", spp=2, resolution=16), strata=(6, 8))
    assert result["rendered_output"] == OUTPUT_RGB
    head = result["fast_paths"][OUTPUT_RGB]
    parent = OnnxEvaluator(lambert_files["spectral+paths"])
    expected = hemisphere_scores(OnnxEvaluator(lambert_files["spectral+paths"], OUTPUT_RGB), rgb_teacher(parent),
                                 strata=(6, 8))["hemisphere_logcos_rmse"]
    assert head["recorded_hemisphere_logcos_rmse"] == 0.01  # what the fixture's metadata claims ...
    assert head["hemisphere_logcos_rmse"] == pytest.approx(expected) and expected > 0.012  # ... and what holds
    assert head["image_against_f"]["image_delta_e2000_mean"] > 1.0  # an orange head on a grey spectrum
    assert "fast path f_rgb" in format_table(result)
    assert json.loads((tmp_path / "eval" / "evaluation.json").read_text())["fast_paths"][OUTPUT_FAST]
    spectral = evaluate(lambert_files["spectral+paths"], truth, tmp_path / "eval2",
                        RenderSettings("llvm_ad_spectral", spp=2, resolution=16), strata=(6, 8))
    assert spectral["rendered_output"] == OUTPUT_F and "image_against_f" not in spectral["fast_paths"][OUTPUT_RGB]


def test_evaluate_fast_renders_the_models_fast_path_and_the_truth_as_it_is(lambert_files, tmp_path):
    from neuralbrdf.evaluation.evaluate import RenderSettings, evaluate

    result = evaluate(lambert_files["rgb+fast"], lambert_files["rgb"], tmp_path / "eval",
                      RenderSettings("llvm_ad_rgb", spp=2, resolution=16, fast=True), strata=(6, 8))
    assert result["rendered_output"] == OUTPUT_FAST
    assert result["fast_paths"][OUTPUT_FAST]["image_against_f"]["image_delta_e2000_mean"] > 1.0


def test_drjit_costs_time_the_kernel_not_the_python_around_it(lambert_files, tmp_path):
    """A 16-wide network costs more per query than a constant, whatever the Python around each
    call (which a slope of wall times on a loaded machine drowned: a head's cost came out 0)."""
    from neuralbrdf.lod.ladder import drjit_costs

    protos = {"constant": load_model(lambert_files["rgb"]).proto,
              "network": load_model(fx.write_nlb_like(tmp_path / "nlb.onnx")).proto}
    costs = drjit_costs(protos, False, (2**14, 2**16), rounds=3)
    assert costs["network"] > 2 * costs["constant"] > 0


def test_any_spectral_file_gets_its_fast_paths_the_spectral_nlb_too(tmp_path, capsys):
    """The fast paths are distilled from the file, whatever its kind: a spectral NLB (latent codes,
    a ``wavelength`` input) gets an RGB head and a spectral compact copy."""
    from neuralbrdf.kinds import contract_metadata
    from neuralbrdf.models.directional import SpectralNlbWithCodes
    from neuralbrdf.models.nlb_spectral import SpectralNlbNetwork
    from neuralbrdf.onnx_export import Exportable, write_model

    torch.manual_seed(0)
    network = SpectralNlbNetwork(shared_dim=4, channel_dim=3, width=16, depth=3)
    module = SpectralNlbWithCodes(network, 0.3 * torch.randn(4), 0.3 * torch.randn(4, 3), (400.0, 500.0, 600.0, 700.0))
    metadata = contract_metadata("nlb_spectral", "random", "test", wavelength_range_nm=module.wavelength_range_nm)
    source = write_model(Exportable(module.eval(), "nlb_spectral", "random", metadata, module.wavelength_range_nm),
                         tmp_path / "nlb_spectral.onnx").path
    out = tmp_path / "with_paths.onnx"
    assert export_command.main(["--model", str(source), "--out", str(out), "--fast", "--config", str(tiny_config(tmp_path))]) == 0
    model = load_model(out)
    assert model.kind == "nlb_spectral" and set(model.fast_paths) == {OUTPUT_RGB, OUTPUT_FAST}
    assert model.output_view(OUTPUT_FAST).is_spectral and not model.output_view(OUTPUT_RGB).is_spectral
    # unasked, the spectral NLB gets its fast path too (its full network is the costliest to render)
    for flags, expected in (([], {OUTPUT_RGB, OUTPUT_FAST}), (["--no-fast"], {OUTPUT_RGB})):
        again = tmp_path / f"again{len(flags)}.onnx"
        assert export_command.main(["--model", str(source), "--out", str(again), *flags,
                                    "--config", str(tiny_config(tmp_path))]) == 0
        assert set(load_model(again).fast_paths) == expected


def test_a_fast_path_alone_is_a_model_file_whose_f_is_that_output(distilled, tmp_path):
    """What a study's ``fast`` variant scores: the fast path cut out of its file (its only output
    ``f``, no fast-path metadata, the provenance saying which output it was)."""
    from neuralbrdf.study.cell import fast_path_alone

    _, with_paths, _ = distilled
    for output, spectral in ((OUTPUT_FAST, True), (OUTPUT_RGB, False)):
        out = fast_path_alone(with_paths, output, tmp_path / f"{output}.onnx")
        alone = load_model(out)
        assert alone.kind == load_model(with_paths).kind and alone.fast_paths == {} and alone.is_spectral is spectral
        assert f"its fast path {output}" in alone.metadata["neuralbrdf.provenance"]
        wi, wo = np.array([[0.2, 0.1, 0.97], [0.5, -0.3, 0.81]]), np.array([[-0.3, 0.0, 0.95], [0.1, 0.6, 0.79]])
        nm = np.array([480.0, 610.0])
        assert OnnxEvaluator(out).values(wi, wo, nm if spectral else None) == pytest.approx(
            OnnxEvaluator(with_paths, output).values(wi, wo, nm if spectral else None), rel=1e-6)


# --------------------------------------------------------------------------- which models get an RGB head


def test_observer_coverage_is_the_share_of_each_cie_weight_in_the_range():
    """Against colour-science's own CMFs and D65, summed by hand on the 10 nm grid."""
    import colour

    from neuralbrdf.data.colorimetry import observer_coverage

    grid = np.arange(400, 701, 10)
    cmfs = colour.MSDS_CMFS["CIE 1931 2 Degree Standard Observer"]
    d65 = colour.SDS_ILLUMINANTS["D65"]
    weighted = np.array([d65[w] * cmfs[w] for w in grid])
    inside = (grid >= 500) & (grid <= 600)
    np.testing.assert_allclose(observer_coverage((500.0, 600.0)), weighted[inside].sum(0) / weighted.sum(0), rtol=1e-6)
    np.testing.assert_allclose(observer_coverage((380.0, 780.0)), 1.0)
    np.testing.assert_allclose(observer_coverage((800.0, 900.0)), 0.0)


def test_a_spectral_model_outside_the_visible_range_gets_no_rgb_head(tmp_path, capsys):
    """A spectral fit of 800-900 nm exported an RGB head distilled from its value at 800 nm, clamped
    across 400-700 nm; the file is written without one, with a warning, and the head is refused
    when asked for."""
    from neuralbrdf.cli.main import main as cli
    from neuralbrdf.data.table import read_table, write_table
    from neuralbrdf.lightning.run import main as train

    infrared_model = fx.write_spectral_lambert(tmp_path / "ir.onnx", wavelength_range=(800.0, 900.0))
    with pytest.raises(InputError, match=r"covers 800-900 nm, which holds 0 % of the CIE 1931 observer's weight"):
        add_fast_paths(infrared_model, tmp_path / "never.onnx", (OUTPUT_RGB,), TINY)
    assert not (tmp_path / "never.onnx").exists()

    visible = tmp_path / "visible.csv"
    assert cli(["simulate", "--material", "gold", "--plan", "DS2", "--truth", "--out", str(visible)]) == 0
    table = read_table(visible)
    infrared = tmp_path / "infrared.csv"
    write_table(dataclasses.replace(table, wavelengths=np.linspace(800.0, 900.0, len(table.wavelengths))), infrared)
    threads = torch.get_num_threads()
    assert train(["fit", "--config", "abc", "--data.path", str(infrared), "--run_dir", str(tmp_path / "run"),
                  "--model.n_starts", "1", "--data.eval_plan", "null", "--trainer.enable_progress_bar", "false"]) == 0
    torch.set_num_threads(threads)
    capsys.readouterr()
    out = tmp_path / "abc.onnx"
    with pytest.warns(UserWarning, match="covers 800-900 nm.*it gets no RGB head"):
        status = export_command.main(["--ckpt", str(tmp_path / "run" / "checkpoints" / "best.ckpt"), "--out", str(out)])
    assert status == 0
    assert load_model(out).wavelength_range_nm == (800.0, 900.0) and load_model(out).fast_paths == {}
