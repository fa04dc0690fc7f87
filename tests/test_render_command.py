"""``neuralbrdf render`` (``export/render.py``): the material-preview scene renders exported models in RGB and spectral
variants with both backends, to PNG and EXR written atomically; passes split and weight the
samples correctly; a Lambertian model renders like Mitsuba's own ``diffuse``; bad input exits 2."""

import subprocess
import sys
from pathlib import Path

import drjit as dr
import mitsuba as mi
import numpy as np
import pytest

import onnx_fixtures as fx
from neuralbrdf.cli import render_command
from neuralbrdf.render import preview as render


@pytest.fixture(scope="module")
def models(tmp_path_factory):
    d = tmp_path_factory.mktemp("render_models")
    return {
        "spectral": fx.write_inplane_spectral(d / "spectral.onnx"),
        "grey": fx.write_lambert(d / "grey.onnx", albedo=(0.5, 0.5, 0.5)),
    }


def read_exr(path: Path) -> np.ndarray:
    return np.array(mi.Bitmap(str(path)), dtype=np.float32)


@pytest.mark.parametrize("variant", ["llvm_ad_rgb", "llvm_ad_spectral"])
def test_renders_png_and_exr_in_rgb_and_spectral_variants(models, variant, tmp_path, capsys):
    out = tmp_path / "preview.png"
    args = ["--model", str(models["spectral"]), "--out", str(out), "--exr", "--variant", variant]
    assert render_command.main([*args, "--resolution", "32", "--spp", "4", "--quiet"]) == 0
    assert "wrote" in capsys.readouterr().out
    image = read_exr(out.with_suffix(".exr"))
    # (spectral variants may give slightly negative sRGB per pixel: out-of-gamut samples at 4 spp)
    assert image.shape == (32, 32, 3) and np.all(np.isfinite(image)) and image.mean() > 0
    centre, corner = image[12:20, 12:20].mean(), image[:4, :4].mean()
    assert centre > 0.02 and corner > 0.0  # the sphere and the floor both receive light
    png = np.array(mi.Bitmap(str(out)))
    assert png.shape == (32, 32, 3) and png.dtype == np.uint8 and png.max() > 0
    assert sorted(p.name for p in tmp_path.iterdir()) == ["preview.exr", "preview.png"]  # no temporary left


def test_onnxruntime_backend_renders_like_drjit_and_restores_symbolic_mode(models):
    # llvm_ad_rgb: in llvm_ad_spectral this scene is not reproducible — two renders with the same
    # seed differ by a whole path about once in twenty, even with Mitsuba's own roughconductor
    # (measured; RGB: 30 of 30 identical). Backend agreement in the spectral variant is
    # test_mitsuba_bsdf.py::test_backends_render_alike, on a scene that is reproducible.
    material = {"model": models["spectral"], "variant": "llvm_ad_rgb", "spp": 4, "resolution": 16, "seed": 3}
    flags = dr.flag(dr.JitFlag.SymbolicLoops), dr.flag(dr.JitFlag.SymbolicCalls)
    fused = render.render(render.Material(model=material["model"], backend="drjit"), **_kw(material))
    wavefront = render.render(render.Material(model=material["model"], backend="onnxruntime"), **_kw(material))
    assert (dr.flag(dr.JitFlag.SymbolicLoops), dr.flag(dr.JitFlag.SymbolicCalls)) == flags
    assert fused.mean() > 0.01
    # Same seed, same sampling: the backends agree to float32 (<= 1e-5), but a rare path can take
    # another branch (roulette, lobe choice) on such a difference; so compare with the Monte
    # Carlo noise between two seeds rather than with zero.
    other_seed = render.render(render.Material(model=material["model"], backend="drjit"), **{**_kw(material), "seed": 4})
    noise = np.sqrt(np.mean((fused - other_seed) ** 2))
    if np.sqrt(np.mean((fused - wavefront) ** 2)) <= 0.1 * noise:
        np.testing.assert_allclose(wavefront.mean(), fused.mean(), rtol=1e-3)
        return
    # Seen in two full runs (stops 7 and 8), never alone or in the render files' own runs: the two
    # backends' same-seed renders as far apart as two seeds, i.e. the sample streams diverged (cause
    # unknown; Mitsuba's own same-seed non-reproducibility is known in spectral variants).  Then the
    # backends must still agree as estimators: at 16 spp each, their difference is no larger than
    # that of two seeds of one backend, and their means agree within the Monte Carlo error.
    many = {**_kw(material), "spp": 16}
    fused = render.render(render.Material(model=material["model"], backend="drjit"), **many)
    wavefront = render.render(render.Material(model=material["model"], backend="onnxruntime"), **many)
    other_seed = render.render(render.Material(model=material["model"], backend="drjit"), **{**many, "seed": 4})
    noise = np.sqrt(np.mean((fused - other_seed) ** 2))
    assert np.sqrt(np.mean((fused - wavefront) ** 2)) <= 1.5 * noise
    assert abs(wavefront.mean() - fused.mean()) <= 4 * noise / np.sqrt(fused.size)


def _kw(material):
    return {k: material[k] for k in ("variant", "spp", "resolution", "seed")}


def test_lambertian_model_renders_like_the_builtin_diffuse_reference(models):
    """Same scene, grey 0.5 Lambertian as a model file and as Mitsuba's ``diffuse``."""
    settings = {"variant": "llvm_ad_rgb", "spp": 16, "resolution": 24}
    diffuse = render.Material(reference_bsdf="diffuse")
    neural = render.render(render.Material(model=models["grey"]), seed=1, **settings)
    reference = render.render(diffuse, seed=1, **settings)
    noise = np.sqrt(np.mean((reference - render.render(diffuse, seed=2, **settings)) ** 2))
    assert np.sqrt(np.mean((neural - reference) ** 2)) <= 1.5 * noise
    np.testing.assert_allclose(neural.mean(axis=(0, 1)), reference.mean(axis=(0, 1)), rtol=0.03)


def test_passes_split_the_budget_and_weight_their_images(monkeypatch):
    assert render.pass_sizes(10, 4) == [4, 4, 2]
    assert render.pass_sizes(8, 4) == [4, 4]
    assert render.pass_sizes(3, 16) == [3]
    assert render.default_spp_per_pass(512, wavefront=False) == render.PASS_LANES_SYMBOLIC // 512**2
    assert render.default_spp_per_pass(4096, wavefront=True) == 1
    calls = []

    def fake_render(scene, spp, seed):
        calls.append((spp, seed))
        return np.full((2, 2, 3), float(spp), dtype=np.float32)  # a pass "measures" its own spp

    monkeypatch.setattr(render.mi, "render", fake_render)
    image = render.render_passes(None, spp=10, spp_per_pass=4, seed=5)
    assert [spp for spp, _ in calls] == [4, 4, 2]
    assert len({seed for _, seed in calls}) == 3  # every pass draws new samples
    np.testing.assert_allclose(image, (4 * 4 + 4 * 4 + 2 * 2) / 10)


def test_spp_split_into_passes_converges_like_one_pass(models):
    """Four 1-spp passes are an unbiased 4-spp estimate: same mean as one 4-spp pass."""
    scene_kw = {"variant": "llvm_ad_rgb", "spp": 4, "resolution": 24}
    material = render.Material(reference_bsdf="diffuse")
    one = render.render(material, seed=0, **scene_kw)
    split = render.render(material, seed=0, spp_per_pass=1, **scene_kw)
    assert not np.array_equal(one, split)
    np.testing.assert_allclose(split.mean(), one.mean(), rtol=0.05)


BAD_ARGUMENTS = {
    "missing model": (["--model", "{tmp}/none.onnx"], "no such ONNX model file"),
    "not a png": (["--model", "{spectral}", "--out", "{tmp}/x.jpg"], "must be a .png"),
    "unknown variant": (["--model", "{spectral}", "--variant", "llvm_ad_rgbx"], "unknown Mitsuba variant"),
    "scalar variant": (["--model", "{spectral}", "--variant", "scalar_rgb"], "does not support Mitsuba variant"),
    "no samples": (["--model", "{spectral}", "--spp", "0"], "spp must be a positive integer"),
    "bad rgb tolerance": (["--model", "{spectral}", "--rgb-tolerance", "2"], "rgb_tolerance must be in [0, 1)"),
}


@pytest.mark.parametrize("case", list(BAD_ARGUMENTS))
def test_bad_input_exits_2_with_one_line(models, case, tmp_path, capsys):
    arguments, message = BAD_ARGUMENTS[case]
    arguments = [a.format(tmp=tmp_path, spectral=models["spectral"]) for a in arguments]
    if "--out" not in arguments:
        arguments += ["--out", str(tmp_path / "x.png")]
    assert render_command.main(["--resolution", "8", "--spp", "1", "--quiet", *arguments]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and err.startswith("neuralbrdf render: error: ") and message in err, err
    assert list(tmp_path.iterdir()) == []


# --------------------------------------------------------------------------- bad input and outputs


def test_user_errors_are_one_line_before_any_rendering(models, tmp_path, capsys, monkeypatch):
    """Outputs and sizes are checked before rendering starts."""
    from neuralbrdf.render import preview

    monkeypatch.setattr(preview, "render_passes", lambda *a, **k: pytest.fail("rendered before refusing"))
    model_as_png = tmp_path / "model.png"
    model_as_png.write_bytes(Path(models["spectral"]).read_bytes())
    folder_png = tmp_path / "folder.png"
    folder_png.mkdir()
    blocker = tmp_path / "file"
    blocker.write_text("")
    cases = {
        "absurd resolution": (["--model", str(models["spectral"]), "--resolution", "1000000", "--out", str(tmp_path / "a.png")],
                              "would need about"),
        "out is the model": (["--model", str(model_as_png), "--out", str(model_as_png)], "is also an input"),
        "out is a directory": (["--model", str(models["spectral"]), "--out", str(folder_png)], "a directory"),
        "unwritable output": (["--model", str(models["spectral"]), "--out", str(blocker / "x.png")], "cannot write"),
    }
    for name, (arguments, message) in cases.items():
        assert render_command.main(["--spp", "1", "--quiet", *arguments]) == 2, name
        err = capsys.readouterr().err
        assert err.count("\n") == 1 and err.startswith("neuralbrdf render: error: ") and message in err, (name, err)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["file", "folder.png", "model.png"]


def test_cuda_variant_without_a_gpu_is_one_line(models, tmp_path, capsys):
    import subprocess as sp
    import sys

    probe = sp.run([sys.executable, "-c", "import mitsuba as mi; mi.set_variant('cuda_ad_rgb'); mi.Float(1).numpy()"],
                   capture_output=True)
    if probe.returncode == 0:
        pytest.skip("this machine has a CUDA device")
    assert render_command.main(["--model", str(models["spectral"]), "--variant", "cuda_ad_rgb", "--out", str(tmp_path / "x.png")]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "cuda_ad_rgb" in err and "no CUDA device" in err, err
    assert list(tmp_path.iterdir()) == []


def test_negative_model_values_are_clamped_and_counted(tmp_path, monkeypatch, capsys):
    """What the load-time probe misses never reaches the image as negative radiance."""
    import torch
    import onnx_fixtures as fx
    from neuralbrdf.onnx_contract import model as contract_model

    class HalfNegative(torch.nn.Module):
        def forward(self, wi, wo):
            f = (wo[:, 0:1] - 0.2).expand(-1, 3)  # negative for half of the outgoing directions
            above = (wi[:, 2:3] > 0) & (wo[:, 2:3] > 0)
            return torch.where(above, f, torch.zeros_like(f))

    path = fx.export_module(HalfNegative(), tmp_path / "neg.onnx", fx.rgb_metadata("nlb"), spectral=False)
    monkeypatch.setattr(contract_model, "check_trial_evaluation", lambda *a: None)  # a probe that missed it
    out = tmp_path / "neg.png"
    assert render_command.main(["--model", str(path), "--resolution", "16", "--spp", "2", "--quiet", "--exr", "--out", str(out)]) == 0
    err = capsys.readouterr().err
    assert "were negative or not finite and were clamped to 0" in err, err
    import mitsuba as mi

    assert np.asarray(mi.Bitmap(str(out.with_suffix(".exr")))).min() >= 0


def test_help_states_how_outputs_and_sizes_are_checked():
    text = " ".join(render_command.build_parser().format_help().split())
    assert "symbolic link is written through" in text and "75% of this machine's memory" in text


OLD_LLVM = Path("/usr/lib/x86_64-linux-gnu/libLLVM-15.so.1")


@pytest.mark.skipif(not OLD_LLVM.is_file(), reason="no LLVM 15 on this machine to stand for an old LLVM")
def test_an_llvm_older_than_19_is_one_line_before_rendering(models, tmp_path):
    """With LLVM 15 Dr.Jit starts but aborts (rc 134, 56 lines of 'Cannot select') in render kernels."""
    import os
    import subprocess
    import sys

    out = tmp_path / "x.png"
    proc = subprocess.run(
        [sys.executable, str(Path(__file__).resolve().parents[1] / "export" / "render.py"), "--model", str(models["grey"]), "--out", str(out),
         "--resolution", "8", "--spp", "1", "--quiet"],
        capture_output=True, text=True, env={**os.environ, "DRJIT_LIBLLVM_PATH": str(OLD_LLVM)}, timeout=300,
    )
    assert proc.returncode == 2, proc.stderr[-500:]
    assert proc.stderr.count("\n") == 1 and "libllvm19" in proc.stderr and "LLVM 15" in proc.stderr
    assert not out.exists()


def test_a_scene_loaded_without_the_plugin_registered_says_what_to_call(models, tmp_path):
    """Not Mitsuba's bare 'Plugin "neuralbrdf" not found!'."""
    scene = tmp_path / "mine.xml"
    scene.write_text(f'<scene version="3.0.0"><bsdf type="neuralbrdf" id="m">'
                     f'<string name="filename" value="{models["grey"]}"/></bsdf></scene>')
    code = ("import mitsuba as mi; mi.set_variant('llvm_ad_rgb')\n"
            "from neuralbrdf.errors import InputError\n"
            "from neuralbrdf.render.scene_file import SceneFile\n"
            f"try:\n    SceneFile({str(scene)!r}).load()\nexcept InputError as error:\n    print(error)\n")
    result = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert str(scene) in result.stdout and "call neuralbrdf.render.register() after mi.set_variant('llvm_ad_rgb')" \
        in result.stdout, result.stdout + result.stderr


def test_the_preview_scene_loads_its_emitters_in_file_order_every_time(models):
    """Mitsuba's object merging (``optimize``) and parallel loading ordered the two area lights by
    memory address: 2-3 of 30 loads in one process swapped them, and a render of a fixed seed then
    drew its emitter samples from the other light — one of two different images, which broke the
    matched paths of the image metrics (a study cell's ΔE 2.36 at a re-evaluated 0.31)."""
    mi.set_variant("llvm_ad_spectral")
    from neuralbrdf.render import register

    register()
    kept, orders = [], set()
    for i in range(40):
        scene = render.load_scene(render.Material(model=models["grey" if i % 3 else "spectral"]), 16)
        if i % 4 == 0:
            kept.append(scene)  # the memory layout changes from load to load, as in a study worker
        orders.add(tuple(tuple(np.round(np.asarray(e.bbox().center()), 3).ravel()) if e.bbox().valid() else None
                         for e in scene.emitters()))
    assert len(orders) == 1
    [order] = orders
    assert order[-1] is None  # the constant environment last, as in the file; the key light (x < 0) first
    assert order[0][0] < 0 < order[1][0]
