"""Ground truth and evaluation (docs/evaluate.md): truths equal the library's own evaluation, the metrics
of a truth against itself are 0, a truth scaled by a known factor gives the known errors, the
CIEDE2000 pipeline matches colour-science's own sRGB path, and the commands fail cleanly."""

import json
import math
from pathlib import Path

import colour
import numpy as np
import pytest
import torch

from neuralbrdf.cli.main import main as cli
from neuralbrdf.data.nbrdf import NbrdfNetwork
from neuralbrdf.evaluation.images import delta_e2000_map, image_scores
from neuralbrdf.evaluation.scores import (
    HEMISPHERE_MAX_THETA_DEG,
    OnnxEvaluator,
    TorchEvaluator,
    direction_scores,
    hemisphere_pairs,
    inplane_pairs,
)
from neuralbrdf.evaluation.truth import load_truth, truth_grid_nm
from neuralbrdf.geometry import spherical_to_vector
from neuralbrdf.onnx_export import write_model
from neuralbrdf.virtual.materials import MATERIALS

NBRDF_DIR = Path(__file__).resolve().parents[1].parent / "shared" / "data" / "merl-nbrdf"
#: 4 x 5 strata (400 hemisphere pairs) keep the metric tests fast; the pairs are the same kind.
QUICK_STRATA = (4, 5)
needs_nbrdf = pytest.mark.skipif(not NBRDF_DIR.is_dir(), reason="../shared/data/merl-nbrdf is absent")


def _random_pairs(n, seed, max_theta_deg=85.0):
    rng = np.random.default_rng(seed)

    def directions():
        cos = rng.uniform(np.cos(np.radians(max_theta_deg)), 1.0, n)
        return spherical_to_vector(np.degrees(np.arccos(cos)), rng.uniform(0.0, 360.0, n))

    return directions(), directions()


@pytest.fixture(scope="module")
def truth_files(tmp_path_factory):
    directory = tmp_path_factory.mktemp("truths")
    return {name: write_model(load_truth(f"virtual:{name}").exportable(), directory / f"{name}.onnx").path
            for name in MATERIALS}


@pytest.mark.parametrize("name", sorted(MATERIALS))
def test_virtual_truth_file_equals_the_library_material_on_its_grid(truth_files, name):
    wi, wo = _random_pairs(4000, seed=1)
    grid = truth_grid_nm()
    wavelength = np.random.default_rng(2).choice(grid, len(wi))
    expected = MATERIALS[name].brdf(wi, wo, grid)[np.arange(len(wi)), np.searchsorted(grid, wavelength)]
    got = OnnxEvaluator(truth_files[name]).values(wi, wo, wavelength)
    # float32 evaluation of the float64 library formula (thin film and GGX near grazing: ~1.6e-5)
    np.testing.assert_allclose(got, expected, rtol=2e-5, atol=1e-9)


def test_virtual_truth_interpolates_linearly_between_nodes_and_clamps_outside(truth_files):
    wi, wo = _random_pairs(500, seed=3)
    evaluator = OnnxEvaluator(truth_files["gold"])
    low, high = MATERIALS["gold"].brdf(wi, wo, np.array([400.0, 405.0])).T
    np.testing.assert_allclose(evaluator.values(wi, wo, np.full(len(wi), 402.0)), 0.6 * low + 0.4 * high, rtol=2e-5)
    np.testing.assert_allclose(evaluator.values(wi, wo, np.full(len(wi), 350.0)), low, rtol=2e-5)


@needs_nbrdf
@pytest.mark.parametrize("name", ["brass", "nylon", "blue-acrylic"])
def test_nbrdf_truth_file_equals_the_library_network(tmp_path, name):
    truth = load_truth(str(NBRDF_DIR / f"{name}.h5"))
    path = write_model(truth.exportable(), tmp_path / "t.onnx").path
    wi, wo = _random_pairs(4000, seed=4)
    wi32, wo32 = wi.astype(np.float32).astype(np.float64), wo.astype(np.float32).astype(np.float64)
    expected = NbrdfNetwork.load(NBRDF_DIR / f"{name}.h5").evaluate(wi32, wo32)
    # float32 arithmetic of a network whose pre-activations cancel: 3e-5 relative measured
    np.testing.assert_allclose(OnnxEvaluator(path).values(wi, wo), expected, rtol=5e-5, atol=1e-6)


def test_truth_sources_are_checked():
    with pytest.raises(Exception, match="unknown virtual material 'chrome'"):
        load_truth("virtual:chrome")
    with pytest.raises(Exception, match="unknown truth source"):
        load_truth("gold.csv")


def test_hemisphere_pairs_are_stratified_and_seeded():
    wi, wo = hemisphere_pairs(seed=0)
    assert len(wi) == len(wo) >= 100_000
    for directions in (wi, wo):
        np.testing.assert_allclose(np.linalg.norm(directions, axis=1), 1.0, atol=1e-12)
        assert np.all(directions[:, 2] >= np.cos(np.radians(HEMISPHERE_MAX_THETA_DEG)) - 1e-12)
        # every (cos theta, phi) cell of the 16 x 20 grid holds exactly N / 320 directions
        cos_low = np.cos(np.radians(HEMISPHERE_MAX_THETA_DEG))
        cell_c = np.floor((directions[:, 2] - cos_low) / (1 - cos_low) * 16).clip(0, 15)
        cell_p = np.floor((np.degrees(np.arctan2(directions[:, 1], directions[:, 0])) % 360) / 18).clip(0, 19)
        counts = np.bincount((cell_c * 20 + cell_p).astype(int), minlength=320)
        assert np.all(counts == len(wi) // 320)
    np.testing.assert_array_equal(hemisphere_pairs(seed=0)[0], wi)
    assert not np.array_equal(hemisphere_pairs(seed=1)[0], wi)


def test_inplane_grid_covers_plus_minus_60_every_degree():
    theta_i, theta_r, wi, wo = inplane_pairs()
    assert len(theta_i) == 121 * 121 and theta_i.min() == -60 and theta_r.max() == 60
    np.testing.assert_allclose(wi[:, 1], 0.0)


class _Scaled(torch.nn.Module):
    def __init__(self, module, factor):
        super().__init__()
        self.module, self.factor = module, factor

    def forward(self, *inputs):
        return self.factor * self.module(*inputs)


@pytest.mark.parametrize("source", ["virtual:gold", "virtual:cyan"])
def test_truth_scaled_by_a_known_factor_gives_the_known_errors(source):
    truth = load_truth(source)
    reference = TorchEvaluator(truth.module, truth.is_spectral)
    same = direction_scores(reference, reference, strata=QUICK_STRATA).metrics
    assert all(value == 0.0 for value in same.values())
    scaled = direction_scores(TorchEvaluator(_Scaled(truth.module, 1.25), True), reference, strata=QUICK_STRATA).metrics
    for name in ("hemisphere_rel_rmse", "inplane_glossy_rel_rmse", "inplane_diffuse_rel_rmse"):
        assert scaled[name] == pytest.approx(0.25, rel=1e-9)
    # log-cosine RMSE computed independently on the same pairs
    wi, wo = hemisphere_pairs(seed=0, strata=QUICK_STRATA)
    grid = np.arange(400.0, 701.0, 10.0)
    f = truth.module.material.brdf(wi, wo, grid)
    cos_i = wi[:, 2:3]
    expected = math.sqrt(np.mean((np.log1p(cos_i * f) - np.log1p(cos_i * 1.25 * f)) ** 2))
    assert scaled["hemisphere_logcos_rmse"] == pytest.approx(expected, rel=1e-6)


def test_rgb_model_against_spectral_truth_compares_in_linear_srgb(tmp_path):
    truth = load_truth("virtual:munsell_n9")
    grey = TorchEvaluator(_ConstantRgb((0.79 / math.pi,) * 3), is_spectral=False)
    scores = direction_scores(grey, TorchEvaluator(truth.module, True), strata=QUICK_STRATA)
    assert scores.comparison == "linear sRGB" and scores.per_wavelength is None
    # a flat spectrum c maps to about (c, c, c) (docs/formats.md#spectral-to-linear-srgb): within the 1 % of the colour pipeline
    assert scores.metrics["hemisphere_rel_rmse"] < 0.01


class _ConstantRgb(torch.nn.Module):
    def __init__(self, rgb):
        super().__init__()
        self.register_buffer("rgb", torch.tensor(rgb, dtype=torch.float64))

    def forward(self, wi, wo):
        above = (wi[:, 2] > 0) & (wo[:, 2] > 0)
        return torch.where(above[:, None], self.rgb.expand(len(wi), 3), torch.zeros(len(wi), 3, dtype=wi.dtype))


def test_delta_e2000_pipeline_matches_colour_science_srgb_path():
    rng = np.random.default_rng(5)
    a, b = rng.uniform(0.0, 1.0, (2, 8, 8, 3))
    srgb = colour.RGB_COLOURSPACES["sRGB"]

    def lab(linear):  # colour's own sRGB entry point, on the encoded values
        return colour.XYZ_to_Lab(colour.sRGB_to_XYZ(srgb.cctf_encoding(linear)), srgb.whitepoint)

    expected = colour.delta_E(lab(a), lab(b), method="CIE 2000")
    np.testing.assert_allclose(delta_e2000_map(a, b), expected, rtol=1e-6, atol=1e-8)
    white = delta_e2000_map(np.ones((1, 1, 3)), np.full((1, 1, 3), 0.5))
    assert white[0, 0] > 10  # white against mid grey: far apart


def test_image_scores_of_identical_and_scaled_images():
    rng = np.random.default_rng(6)
    truth = rng.uniform(0.05, 0.8, (16, 16, 3))
    metrics, delta_e = image_scores(truth, truth)
    assert metrics["image_rel_mse"] == 0 and metrics["image_psnr"] is None and np.all(delta_e == 0)
    metrics, _ = image_scores(0.5 * truth, truth)
    assert metrics["image_rel_mse"] == pytest.approx(0.25)
    with pytest.raises(ValueError, match="non-finite"):
        image_scores(np.full((2, 2, 3), np.nan), truth[:2, :2])


def test_evaluate_truth_against_itself_is_zero_everywhere(truth_files, tmp_path, capsys):
    out = tmp_path / "eval"
    args = [str(truth_files["cyan"]), "--truth", str(truth_files["cyan"]), "--out-dir", str(out),
            "--variant", "llvm_ad_rgb", "--spp", "8", "--resolution", "24"]
    assert cli(["evaluate", *args]) == 0
    printed = capsys.readouterr().out
    assert "image_delta_e2000_mean" in printed
    result = json.loads((out / "evaluation.json").read_text())
    for name in ("hemisphere_logcos_rmse", "hemisphere_rel_rmse", "inplane_glossy_rel_rmse",
                 "inplane_diffuse_rel_rmse", "image_rel_mse"):
        assert result[name] == 0.0, name
    assert result["image_delta_e2000_mean"] <= 0.01 and result["image_delta_e2000_p95"] <= 0.01
    assert result["noise"]["image_delta_e2000_mean"] > 0  # other seeds: noise, stated
    assert "sampled as this model samples" not in result["noise"]["what"]  # a model truth keeps its own proposal
    assert result["direction_details"]["per_wavelength"]["wavelength_nm"][0] == 400.0
    for name in ("model.png", "truth.png", "error_map.png", "comparison.png"):
        assert (out / name).stat().st_size > 0


def test_export_truth_command_and_its_errors(tmp_path, capsys):
    out = tmp_path / "gonio.onnx"
    assert cli(["export-truth", "virtual:gonio", "--out", str(out)]) == 0
    assert "reference model of 'gonio'" in capsys.readouterr().out
    model = OnnxEvaluator(out).model
    assert model.kind == "reference" and model.wavelength_range_nm == (400.0, 700.0)
    assert cli(["export-truth", "virtual:chrome", "--out", str(tmp_path / "x.onnx")]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "chrome" in err
    assert not (tmp_path / "x.onnx").exists()
    assert cli(["evaluate", str(tmp_path / "missing.onnx"), "--truth", str(out), "--out-dir", str(tmp_path / "e"),
                "--no-render"]) == 2
    assert "missing.onnx" in capsys.readouterr().err and not (tmp_path / "e").exists()


def test_memo_evaluator_computes_each_input_once():
    """MemoEvaluator hands out the inner evaluator's values, computes each distinct input once, keeps
    the most recently used ``entries`` inputs, and its values cannot be modified by a caller."""
    from neuralbrdf.evaluation.scores import MemoEvaluator, compared_values, hemisphere_pairs

    class Counting:
        is_spectral = True
        model = "inner model"

        def __init__(self):
            self.calls = 0

        def values(self, wi, wo, wavelength=None):
            self.calls += 1
            return wi[:, 2] * wo[:, 2] + wavelength / 1000.0

    inner = Counting()
    memo = MemoEvaluator(inner, entries=2)
    wi, wo = hemisphere_pairs(0, (2, 3))
    other_wi, other_wo = hemisphere_pairs(1, (2, 3))
    first = compared_values(memo, wi, wo, spectral=True)
    assert inner.calls == 1 and np.array_equal(first, compared_values(Counting(), wi, wo, spectral=True))
    assert np.array_equal(compared_values(memo, wi, wo, spectral=True), first) and inner.calls == 1
    compared_values(memo, other_wi, other_wo, spectral=True)
    assert inner.calls == 2
    compared_values(memo, wi, wo, spectral=False)  # same queries, another comparison: no new call
    assert inner.calls == 2
    wavelength = np.full(len(wi), 500.0)
    compared = memo.values(wi, wo, wavelength)
    assert inner.calls == 3 and not compared.flags.writeable
    memo.values(wi, wo, wavelength + 1.0)  # a third input drops the least recently used one
    memo.values(wi, wo, wavelength)
    assert inner.calls == 4
    compared_values(memo, other_wi, other_wo, spectral=True)
    assert inner.calls == 5 and memo.model == "inner model"


def test_truth_renders_are_kept_per_file_settings_and_seed(tmp_path, monkeypatch):
    from neuralbrdf.evaluation import evaluate as evaluation

    calls = []

    def fake_render(path, settings, seed, proposal=None, scene=None):
        calls.append((path.name, settings.spp, seed))
        return np.full((2, 2, 3), float(len(calls)), dtype=np.float32)

    monkeypatch.setattr(evaluation, "_render", fake_render)
    truth = tmp_path / "truth.onnx"
    truth.write_bytes(b"one")
    settings = evaluation.RenderSettings(spp=4, resolution=2)
    kept: dict = {}
    first = evaluation._render_kept(kept, truth, settings, 0)
    assert evaluation._render_kept(kept, truth, settings, 0) is first and len(calls) == 1
    assert not first.flags.writeable
    evaluation._render_kept(kept, truth, settings, 1)
    evaluation._render_kept(kept, truth, evaluation.RenderSettings(spp=8, resolution=2), 0)
    assert len(calls) == 3
    truth.write_bytes(b"changed")  # another file at the same path is rendered afresh
    assert evaluation._render_kept(kept, truth, settings, 0)[0, 0, 0] == 4.0
    evaluation._render_kept(None, truth, settings, 0)  # nothing kept: always rendered
    assert len(calls) == 5


def test_the_model_is_rendered_with_the_truths_proposal(truth_files, tmp_path, monkeypatch):
    from neuralbrdf.evaluation import evaluate as evaluation

    calls = []

    def fake_render(path, settings, seed, proposal=None, scene=None):
        calls.append((path.name, seed, proposal and proposal.name))
        return np.full((2, 2, 3), 0.5, dtype=np.float32)

    monkeypatch.setattr(evaluation, "_render", fake_render)
    evaluation.evaluate(truth_files["gold"], truth_files["cyan"], tmp_path / "eval",
                        evaluation.RenderSettings(spp=2, resolution=evaluation.MIN_RESOLUTION), strata=QUICK_STRATA)
    assert calls[0] == ("gold.onnx", 0, "cyan.onnx")  # the model: the truth's proposal, matched paths
    assert [c[2] for c in calls[1:]] == [None, None]  # the truth: its own, at two seeds


def test_a_model_sampled_with_another_files_proposal_renders_the_same_expectation(truth_files):
    from neuralbrdf.errors import InputError
    from neuralbrdf.evaluation.images import image_scores
    from neuralbrdf.render.preview import NEURAL_MATERIAL_MATCHED, Material, render

    matched = Material(model=truth_files["gold"], proposal=truth_files["cyan"])
    assert matched.scene_parameters()["material"] == NEURAL_MATERIAL_MATCHED
    assert matched.scene_parameters()["proposal"] == str(truth_files["cyan"].resolve())
    with pytest.raises(InputError, match="proposal"):
        Material(reference_bsdf="diffuse", proposal=truth_files["cyan"])
    own = render(Material(model=truth_files["gold"]), "llvm_ad_rgb", 64, 24, 0)
    other = render(matched, "llvm_ad_rgb", 64, 24, 0)
    again = render(Material(model=truth_files["gold"]), "llvm_ad_rgb", 64, 24, 1)
    # Another proposal changes the paths (not the same image) but not what they converge to:
    # its difference from the own-proposal render is of the size of two seeds' difference.
    assert not np.array_equal(own, other)
    changed, _ = image_scores(other, own)
    noise, _ = image_scores(again, own)
    assert abs(float(other.mean()) / float(own.mean()) - 1.0) < 0.03
    assert changed["image_delta_e2000_mean"] < 2.0 * noise["image_delta_e2000_mean"]


@pytest.mark.parametrize("options, message", [
    (["--resolution", "1"], "--resolution must be 16 to 2048 pixels, got 1"),
    (["--resolution", "100000"], "--resolution must be 16 to 2048 pixels, got 100000 (larger images are not needed"),
    (["--spp", "0"], "--spp must be a positive integer, got 0"),
    (["--seed", "-5"], "--seed must be a non-negative integer, got -5"),
    (["--variant", "bogus"], "unknown Mitsuba variant 'bogus'"),
])
def test_bad_render_settings_are_refused_before_any_work(truth_files, tmp_path, capsys, monkeypatch, options, message):
    """An image too small to hold the sphere (one background pixel scored ΔE 0), one too large to
    allocate, a negative seed (a traceback): one line, before a single metric is computed."""
    from neuralbrdf.evaluation import evaluate as evaluation

    monkeypatch.setattr(evaluation, "direction_scores", lambda *_, **__: pytest.fail("scored before the checks"))
    out = tmp_path / "eval"
    gold = str(truth_files["gold"])
    assert cli(["evaluate", gold, "--truth", gold, "--out-dir", str(out), "--spp", "2", *options]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and message in err, err
    assert not out.exists()


def test_an_output_folder_that_cannot_be_written_is_refused_before_any_work(truth_files, tmp_path, capsys,
                                                                            monkeypatch):
    from neuralbrdf.evaluation import evaluate as evaluation

    monkeypatch.setattr(evaluation, "direction_scores", lambda *_, **__: pytest.fail("scored before the checks"))
    taken = tmp_path / "taken"
    taken.write_text("mine")
    gold = str(truth_files["gold"])
    assert cli(["evaluate", gold, "--truth", gold, "--out-dir", str(taken), "--no-render"]) == 2
    assert f"{taken / 'evaluation.json'}: cannot write" in capsys.readouterr().err
    assert taken.read_text() == "mine"


def test_a_truth_that_is_not_a_ground_truth_is_noted_and_recorded(tmp_path, capsys):
    import hashlib

    from onnx_fixtures import write_lambert, write_nlb_like

    model, truth = write_lambert(tmp_path / "model.onnx"), write_nlb_like(tmp_path / "fitted.onnx")
    out = tmp_path / "eval"
    assert cli(["evaluate", str(model), "--truth", str(truth), "--out-dir", str(out), "--no-render"]) == 0
    note = (f"the truth {truth} is a 'nlb' model, not a ground truth (kind 'reference'): the scores measure how two "
            "models differ, not how far the model is from the material")
    assert f"warning: {note}\n" in capsys.readouterr().err
    result = json.loads((out / "evaluation.json").read_text())
    assert result["truth_kind"] == "nlb" and result["model_kind"] == "nlb" and result["notes"] == [note]
    assert result["truth_sha256"] == hashlib.sha256(truth.read_bytes()).hexdigest()
    assert result["model_wavelength_range_nm"] is None


def test_a_wavelength_range_edited_in_the_file_changes_the_scores_as_it_changes_renders(truth_files, tmp_path):
    """The renderer clamps wavelengths to the range a file declares; the scores do the same, so a file
    whose range was narrowed scores the error its renders show (it scored 0)."""
    import onnx

    proto = onnx.load(str(truth_files["gold"]))
    for entry in proto.metadata_props:
        if entry.key in ("neuralbrdf.wavelength_min", "neuralbrdf.wavelength_max"):
            entry.value = {"neuralbrdf.wavelength_min": "500", "neuralbrdf.wavelength_max": "600"}[entry.key]
    narrowed = tmp_path / "narrowed.onnx"
    onnx.save(proto, str(narrowed))
    truth = OnnxEvaluator(truth_files["gold"])
    same = direction_scores(OnnxEvaluator(truth_files["gold"]), truth, strata=QUICK_STRATA).metrics
    edited = direction_scores(OnnxEvaluator(narrowed), truth, strata=QUICK_STRATA).metrics
    assert same["hemisphere_logcos_rmse"] == 0.0 and edited["hemisphere_logcos_rmse"] > 1e-3
    assert edited["inplane_glossy_rel_rmse"] > 0.01
