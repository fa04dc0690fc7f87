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

pytestmark = pytest.mark.filterwarnings("ignore:LightningCLI's args parameter is intended")

REPO = Path(__file__).resolve().parents[1]
CONFIG = REPO / "configs" / "abc.yaml"
NBRDF_DIR = REPO.parent / "shared" / "data" / "merl-nbrdf"
KNOWN = dict(kd=[0.05, 0.1, 0.2], A=[8.0, 6.0, 4.0], B=300.0, C=1.3, eta=1.6)


@pytest.fixture(autouse=True)
def keep_torch_threads():
    threads = torch.get_num_threads()
    yield
    torch.set_num_threads(threads)


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
    # the flow the README documents: --data.path alone (issue 8: it used to need --data.virtual null)
    status, run_dir = _fit(tmp_path, "--data.path", str(path))
    assert status == 0
    metrics = json.loads((run_dir / "metrics.json").read_text())
    assert metrics["fit/abc/success"] is True and metrics["fit/abc/failure_reason"] is None
    # the shared metric names (SPEC §9), on the data it was given; a table has no truth
    assert metrics["fit/inplane_glossy_rel_rmse"] < 0.05 and metrics["fit/inplane_diffuse_rel_rmse"] < 0.05
    assert "fit/hemisphere_logcos_rmse" not in metrics
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
    # Issue 13 class 3: the failure is also the command's (exit 1, status failed, no best).
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
def test_nbrdf_proxy_fit_logs_the_hemisphere_metric(tmp_path):
    args = ["--data.nbrdf", str(NBRDF_DIR / "nylon.h5"), "--data.plan", "DS3", "--data.eval_plan", "DS1"]
    status, run_dir = _fit(tmp_path, *args)
    metrics = json.loads((run_dir / "metrics.json").read_text())
    assert status == 0 and metrics["fit/abc/material"] == "nylon"
    assert 0 <= metrics["fit/val/hemisphere_logcos_rmse"] < 0.2
    assert metrics["fit/hemisphere_logcos_rmse"] == pytest.approx(metrics["fit/val/hemisphere_logcos_rmse"], rel=1e-6)
    assert metrics["fit/inplane_glossy_rel_rmse"] >= 0 and metrics["fit/inplane_diffuse_rel_rmse"] >= 0
