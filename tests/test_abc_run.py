"""The ABC fit run through ``train.py`` (configs/abc.yaml): outputs, failure reporting, sources."""

import json
from pathlib import Path

import numpy as np
import pytest
import torch

from neuralbrdf.data.plans import in_plane_plan
from neuralbrdf.sources import load_material
from neuralbrdf.data.table import BrdfTable, write_table
from neuralbrdf.geometry import inplane_to_spherical, inplane_to_vectors
from neuralbrdf.lightning.run import main
from neuralbrdf.physics.abc import AbcParameters, abc_brdf
from neuralbrdf.physics.fresnel import fresnel_dielectric
from neuralbrdf.physics.microfacet import microfacet_brdf
from neuralbrdf.cli.export_command import main as export_main
from neuralbrdf.cli.main import main as cli
from neuralbrdf.data.merl_binary import MERL_SHAPE, write_merl

pytestmark = pytest.mark.filterwarnings("ignore:LightningCLI's args parameter is intended")

REPO = Path(__file__).resolve().parents[1]
CONFIG = REPO / "configs" / "abc.yaml"
NBRDF_DIR = REPO.parent / "shared" / "data" / "merl-nbrdf"
KNOWN = dict(kd=[0.05, 0.1, 0.2], A=[8.0, 6.0, 4.0], B=300.0, C=1.3, eta=1.6)



def _table_of(tmp_path, values_fn, name="t.csv"):
    ti, tr = in_plane_plan("DS1")
    values = values_fn(*inplane_to_vectors(ti, tr))
    path = tmp_path / name
    write_table(BrdfTable(*inplane_to_spherical(ti, tr), values), path)
    return path


def _fit(tmp_path, *args):
    run_dir = tmp_path / "run"
    status = main(["fit", "--config", str(CONFIG), "--run_dir", str(run_dir), *args])
    return status, run_dir


def test_fit_recovers_known_parameters_and_writes_the_run(tmp_path):
    path = _table_of(tmp_path, lambda wi, wo: abc_brdf(wi, wo, **{k: np.asarray(v) for k, v in KNOWN.items()}))
    # the flow the docs describe: --data.path alone, no --data.virtual null needed
    status, run_dir = _fit(tmp_path, "--data.path", str(path))
    assert status == 0
    metrics = json.loads((run_dir / "metrics.json").read_text())
    assert metrics["fit/abc/success"] is True and metrics["fit/abc/failure_reason"] is None
    # the shared metric names (docs/evaluate.md#metrics), on the data it was given; a table has no truth
    assert metrics["fit/inplane_glossy_rel_rmse"] < 0.05 and metrics["fit/inplane_diffuse_rel_rmse"] < 0.05
    assert "fit/plan_logcos_rmse" not in metrics and "fit/hemisphere_logcos_rmse" not in metrics
    fitted = AbcParameters.from_dict(metrics["fit/abc/parameters"])
    np.testing.assert_allclose(fitted.kd, KNOWN["kd"], rtol=0.05)  # pi·min(f) includes a little specular
    np.testing.assert_allclose([fitted.B, fitted.C, fitted.eta], [KNOWN["B"], KNOWN["C"], KNOWN["eta"]], rtol=0.05)
    for name in ("config.yaml", "metrics.csv", "checkpoints/best.ckpt", "checkpoints/last.ckpt"):
        assert (run_dir / name).is_file()
    checkpoint = torch.load(run_dir / "checkpoints" / "best.ckpt", weights_only=False)
    assert checkpoint["neuralbrdf_kind"] == "abc" and checkpoint["abc_parameters"] == metrics["fit/abc/parameters"]


def test_a_failed_fit_is_reported_as_failed(tmp_path):
    rng = np.random.default_rng(0)
    path = _table_of(tmp_path, lambda wi, wo: rng.uniform(0.1, 1.0, (wi.shape[0], 3)))  # no specular structure
    with pytest.warns(UserWarning, match="ABC fit of t FAILED"):
        status, run_dir = _fit(tmp_path, "--data.path", str(path))
    metrics = json.loads((run_dir / "metrics.json").read_text())
    assert metrics["fit/abc/success"] is False and metrics["fit/abc/failure_reason"]
    assert metrics["fit/train/success"] == 0.0
    # The failure is also the command's (exit 1, status failed, no best).
    assert status == 1 and metrics["status"] == "failed" and metrics["fit/abc/failure_reason"] in metrics["cause"]
    assert not (run_dir / "checkpoints" / "best.ckpt").exists()


def test_virtual_source_has_a_dense_truth_and_bad_sources_are_rejected(tmp_path, capsys):
    material = load_material(virtual="gold", eval_plan="DS2")
    assert material.fit.n_rows == 1001 and material.truth.n_rows == 185 and material.truth.is_spectral
    status, run_dir = _fit(tmp_path, "--data.path", str(tmp_path / "missing.csv"))
    assert status == 2 and "missing.csv" in capsys.readouterr().err
    status, run_dir = _fit(tmp_path, "--data.path", str(tmp_path / "missing.csv"), "--data.virtual", "cyan")
    assert status == 2 and "exactly one of" in capsys.readouterr().err
    assert not (run_dir / "metrics.json").exists()


@pytest.mark.skipif(not NBRDF_DIR.is_dir(), reason="../shared/data/merl-nbrdf is absent")
def test_nbrdf_proxy_fit_logs_the_plan_metric_named_apart_from_evaluates(tmp_path):
    """Its fit/hemisphere_logcos_rmse on the plan's pairs (0.0277) and evaluate's over hemisphere pairs
    (0.0050) were one name for two numbers."""
    args = ["--data.nbrdf", str(NBRDF_DIR / "nylon.h5"), "--data.plan", "DS3", "--data.eval_plan", "DS1"]
    status, run_dir = _fit(tmp_path, *args)
    metrics = json.loads((run_dir / "metrics.json").read_text())
    assert status == 0 and metrics["fit/abc/material"] == "nylon"
    assert 0 <= metrics["fit/val/plan_logcos_rmse"] < 0.2
    assert metrics["fit/plan_logcos_rmse"] == pytest.approx(metrics["fit/val/plan_logcos_rmse"], rel=1e-6)
    assert not [key for key in metrics if "hemisphere_logcos_rmse" in key]
    assert metrics["fit/inplane_glossy_rel_rmse"] >= 0 and metrics["fit/inplane_diffuse_rel_rmse"] >= 0


# --------------------------------------------------------------------------- a smooth material (Lambert + Beckmann)

ORANGE_KD = np.array([0.41, 0.13, 0.004])


def _lambert_beckmann(wi, wo, alpha, eta=1.5):
    specular = microfacet_brdf(wi, wo, alpha, lambda c: fresnel_dielectric(c, eta), "beckmann")
    above = (wi[:, 2] > 0) & (wo[:, 2] > 0)
    return np.where(above[:, None], ORANGE_KD / np.pi + specular[:, None], 0.0)


def _merl_cell_directions():
    """``wi, wo`` ``[90·90·180, 3]`` at the centre of every MERL cell (φh = 0; MERL's inverse index rule)."""
    n_h, n_d, n_phi = MERL_SHAPE
    i_h, i_d, i_phi = np.meshgrid(np.arange(n_h), np.arange(n_d), np.arange(n_phi), indexing="ij")
    theta_h = np.radians((i_h + 0.5) ** 2 / 90.0)
    theta_d, phi_d = np.radians((i_d + 0.5) * 90.0 / n_d), np.radians((i_phi + 0.5) * 180.0 / n_phi)
    d = np.stack([np.sin(theta_d) * np.cos(phi_d), np.sin(theta_d) * np.sin(phi_d), np.cos(theta_d)], axis=-1)
    c, s = np.cos(theta_h), np.sin(theta_h)
    wi = np.stack([c * d[..., 0] + s * d[..., 2], d[..., 1], -s * d[..., 0] + c * d[..., 2]], axis=-1)
    h = np.stack([s, np.zeros_like(s), c], axis=-1)
    wo = 2.0 * (wi * h).sum(axis=-1, keepdims=True) * h - wi
    return wi.reshape(-1, 3), wo.reshape(-1, 3)


def test_a_bounded_c_fails_naming_the_parameter_and_the_flag_that_lets_it_fit(tmp_path, capsys):
    """The fit of a smooth material used to fail with 'C at its upper bound' and no way out."""
    path = _table_of(tmp_path, lambda wi, wo: _lambert_beckmann(wi, wo, 0.2), name="orange_DS1.csv")
    with pytest.warns(UserWarning, match="ABC fit of orange_DS1 FAILED"):
        status = main(["fit", "--config", str(CONFIG), "--run_dir", str(tmp_path / "bounded"), "--data.path",
                       str(path), "--model.bounds.C", "[0.001, 10]"])
    error = [line for line in capsys.readouterr().err.splitlines() if line.startswith("neuralbrdf train: error:")]
    assert status == 1 and len(error) == 1
    assert error[0].startswith("neuralbrdf train: error: fit failed: ABC fit of orange_DS1: C ran to its upper bound "
                               "(C = 10, B = ")
    assert "--model.bounds.C '[0.001, .inf]'" in error[0]
    assert not (tmp_path / "bounded" / "checkpoints" / "best.ckpt").exists()


def test_an_unknown_bound_is_one_line(tmp_path, capsys):
    status = main(["fit", "--config", str(CONFIG), "--run_dir", str(tmp_path / "run"), "--model.bounds.B", "[1, 10]"])
    err = capsys.readouterr().err
    assert status == 2 and err.count("\n") == 1
    assert "'model.bounds.B': unknown bound; expected one of A, sharpness, C, eta" in err, err
    assert not (tmp_path / "run").exists()


@pytest.mark.parametrize("key, value", [("n_starts", "0"), ("n_starts", "-1"), ("max_evaluations", "0"), ("seed", "-2")])
def test_fit_settings_out_of_range_are_one_line_before_the_run(tmp_path, capsys, key, value):
    status = main(["fit", "--config", str(CONFIG), "--run_dir", str(tmp_path / "run"), f"--model.{key}", value])
    err = capsys.readouterr().err
    assert status == 2 and err.count("\n") == 1
    assert f"'model.{key}': expected an integer >= " in err and f"got {value}" in err, err
    assert not (tmp_path / "run").exists()


@pytest.mark.slow
def test_a_smooth_material_from_a_merl_binary_fits_on_ds1_and_exports(tmp_path):
    """Lambert + Beckmann as a MERL .binary, sampled on DS1 -> fitted in the Gaussian limit -> ONNX."""
    wi, wo = _merl_cell_directions()
    values = _lambert_beckmann(wi, wo, 0.1)
    values[~((wi[:, 2] > 0) & (wo[:, 2] > 0))] = -1.0  # MERL's "not measured"
    binary, table = tmp_path / "orange.binary", tmp_path / "orange_DS1.csv"
    write_merl(values.T.reshape(3, *MERL_SHAPE), binary)
    assert cli(["sample", str(binary), "--plan", "DS1", "--out", str(table)]) == 0
    status, run_dir = _fit(tmp_path, "--data.path", str(table))
    metrics = json.loads((run_dir / "metrics.json").read_text())
    assert status == 0 and metrics["fit/abc/success"] is True, metrics["fit/abc/failure_reason"]
    assert metrics["fit/inplane_glossy_rel_rmse"] < 0.05
    fitted = AbcParameters.from_dict(metrics["fit/abc/parameters"])
    assert fitted.B * fitted.C == pytest.approx(2.0 / 0.1**2, rel=0.1) and fitted.eta == pytest.approx(1.5, rel=0.02)
    out = tmp_path / "orange.onnx"
    assert export_main(["--ckpt", str(run_dir / "checkpoints" / "best.ckpt"), "--out", str(out)]) == 0
    assert out.is_file()
