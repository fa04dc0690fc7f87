"""The ``pca`` kind (docs/models.md#pca): the shipped basis, the ridge fit of a material's
coefficients, the fit run, and its export as a baked table."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import torch

import neuralbrdf as nb
from neuralbrdf import kinds
from neuralbrdf.data.plans import plan_spherical
from neuralbrdf.data.proxy_corpus import NEVER_PRETRAINED
from neuralbrdf.data.table import BrdfTable, write_table
from neuralbrdf.errors import InputError
from neuralbrdf.evaluation.scores import hemisphere_pairs
from neuralbrdf.geometry import spherical_to_vector
from neuralbrdf.kinds import pca as pca_kind
from neuralbrdf.lightning.pca_fit import PcaFitModule
from neuralbrdf.metrics import hemisphere_logcos_rmse
from neuralbrdf.models import pca_brdf
from neuralbrdf.models.baked_table import BakedTable
from neuralbrdf.physics.abc import AbcParameters

QUIET = {"trainer.enable_progress_bar": False, "data.eval_plan": None}
SHARED = Path(__file__).resolve().parents[2] / "shared" / "data"
GLOSSY = AbcParameters(kd=np.array([0.3, 0.2, 0.1]), A=np.array([2.0, 2.5, 3.0]), B=400.0, C=0.8, eta=1.5)


@pytest.fixture(scope="module")
def basis():
    return pca_brdf.load_basis()


def _table(values_of, plan: str = "DS2") -> BrdfTable:
    angles = plan_spherical(plan)
    wi, wo = spherical_to_vector(angles[0], angles[1]), spherical_to_vector(angles[2], angles[3])
    return BrdfTable(*angles, values_of(wi, wo), source=f"test table on {plan}")


@pytest.fixture(scope="module")
def rgb_table(tmp_path_factory):
    path = tmp_path_factory.mktemp("pca") / "glossy.csv"
    write_table(_table(GLOSSY.evaluate), path)
    return path


@pytest.fixture(scope="module")
def rgb_fit(tmp_path_factory, rgb_table):
    folder = tmp_path_factory.mktemp("pca_rgb")
    result = nb.fit("pca", rgb_table, run_dir=folder / "run", overrides=QUIET)
    return result, result.export(folder / "pca.onnx", rgb_head=False)


# --------------------------------------------------------------------------- the basis


def test_the_shipped_basis_loads_with_orthonormal_components_from_training_materials_only(basis):
    assert basis.n_components >= 24 and basis.mapping in pca_brdf.MAPPINGS
    assert np.prod(basis.nodes) == basis.mean.shape[0] == basis.components.shape[1]
    assert 5_000 <= np.prod(basis.nodes) <= 20_000
    assert np.allclose(basis.components @ basis.components.T, np.eye(basis.n_components), atol=1e-5)
    assert np.all(np.diff(basis.scales) <= 0) and np.all(basis.scales > 0)
    assert 0.99 < basis.explained_variance_ratio.sum() <= 1.0
    names = {material.partition(":")[2] for material in basis.materials}
    assert len(names) == len(basis.materials) >= 40 and not names & set(NEVER_PRETRAINED)
    assert pca_brdf.BASIS_FILE.stat().st_size < 2_000_000
    assert len(basis.sha256) == 64


def test_a_broken_basis_file_is_refused_naming_the_entry(tmp_path, basis):
    arrays = basis.arrays()
    arrays["components"] = arrays["components"] * 2.0
    np.savez(tmp_path / "bad.npz", **arrays)
    with pytest.raises(InputError, match="orthonormal") as error:
        pca_brdf.load_basis(tmp_path / "bad.npz")
    assert error.value.key == "components" and "bad.npz" in str(error.value)
    with pytest.raises(InputError, match="components from 1 to"):
        basis.truncated(basis.n_components + 1)


# --------------------------------------------------------------------------- the fit


def test_the_design_matrix_is_the_baked_tables_own_interpolation(basis):
    """Each component baked as a table (its three channels equal) and read by BakedTable at the
    pairs gives that column of the design matrix."""
    wi, wo = hemisphere_pairs(3, (4, 5))
    mean, design = pca_brdf.design_matrix(basis, wi, wo)
    for column, node_values in ((None, basis.mean), (0, basis.components[0]), (5, basis.components[5])):
        shifted = node_values - node_values.min()  # a table holds values >= 0
        table = BakedTable(torch.as_tensor(np.repeat(shifted.reshape(*basis.nodes, 1), 3, axis=3)))
        read = table(torch.as_tensor(wi, dtype=torch.float32), torch.as_tensor(wo, dtype=torch.float32))[:, 0]
        expected = (mean if column is None else design[:, column]) - node_values.min()
        assert np.allclose(read.double().numpy(), expected, atol=2e-5 * max(1.0, np.abs(shifted).max()))


def test_the_ridge_fit_is_the_least_squares_solution_of_the_augmented_system(basis):
    small = basis.truncated(12)
    wi, wo = hemisphere_pairs(1, (3, 4))
    values = GLOSSY.evaluate(wi, wo)
    mean, design = pca_brdf.design_matrix(small, wi, wo)
    targets = np.log1p(values) - mean[:, None]
    for ridge in (0.0, 0.003, 0.5):
        fitted = pca_brdf.fit_channels(small, wi, wo, values, ridge)
        augmented = np.vstack([design, np.sqrt(ridge) * np.diag(1.0 / small.scales)])
        rhs = np.vstack([targets, np.zeros((small.n_components, 3))])
        expected = np.linalg.lstsq(augmented, rhs, rcond=None)[0].T
        assert np.allclose(fitted, expected, rtol=1e-6, atol=1e-8), ridge
    # the model is linear in the coefficients at every pair: ln(1 + f) there is the fit's own μ + Φ c
    fitted = pca_brdf.fit_channels(small, wi, wo, values, 0.003)
    assert np.all(pca_brdf.mapped_nodes(small, fitted) > small.value_range[0])  # nothing clipped
    model = pca_brdf.pca_table(small, fitted)
    with torch.no_grad():
        f = model(torch.as_tensor(wi, dtype=torch.float32), torch.as_tensor(wo, dtype=torch.float32)).double().numpy()
    assert np.allclose(np.log1p(f), mean[:, None] + design @ fitted.T, rtol=1e-4, atol=1e-5)
    # a larger ridge weight pulls the coefficients toward the prior's mean, 0
    assert np.linalg.norm(pca_brdf.fit_channels(small, wi, wo, values, 10.0)) < np.linalg.norm(
        pca_brdf.fit_channels(small, wi, wo, values, 0.0))


def test_a_material_in_the_basis_span_is_recovered_exactly(basis):
    small = basis.truncated(3)
    coefficients = np.array([[0.3, -0.2, 0.2], [0.1, 0.1, -0.2], [-0.3, 0.4, 0.0]]) * small.scales
    assert np.all(pca_brdf.mapped_nodes(small, coefficients) > small.value_range[0])  # no node clipped
    # every node above the horizon once: the design matrix there is the components themselves
    node_wi, node_wo = pca_brdf.node_directions(small.nodes)
    above = (node_wi[:, 2] > 1e-6) & (node_wo[:, 2] > 1e-6)
    node_f = pca_brdf.node_values(small, coefficients).reshape(-1, 3)
    refit = pca_brdf.fit_channels(small, node_wi[above], node_wo[above], node_f[above], 0.0)
    assert np.allclose(refit, coefficients, rtol=1e-6, atol=1e-6)
    wi, wo = hemisphere_pairs(2, (6, 8))
    table = pca_brdf.pca_table(small, coefficients)
    values = table(torch.as_tensor(wi, dtype=torch.float32), torch.as_tensor(wo, dtype=torch.float32)).double().numpy()
    assert np.all(values >= 0) and np.all(np.isfinite(values)) and values.max() > 0


def test_a_training_material_is_reconstructed_from_its_own_dense_samples(basis):
    file = SHARED / "merl-nbrdf" / "green-plastic.h5"
    if not file.is_file():
        pytest.skip(f"reference data not found: {file}")
    from neuralbrdf.data.nbrdf import NbrdfNetwork

    assert "merl:green-plastic" in basis.materials
    network = NbrdfNetwork.load(file)
    wi, wo = hemisphere_pairs(5, (10, 12))  # 14 400 pairs
    coefficients = pca_brdf.fit_channels(basis, wi, wo, network.evaluate(wi, wo), 1e-4)
    check_wi, check_wo = hemisphere_pairs(6, (6, 8))
    pred = pca_brdf.pca_table(basis, coefficients)(torch.as_tensor(check_wi, dtype=torch.float32),
                                                   torch.as_tensor(check_wo, dtype=torch.float32)).double().numpy()
    error = hemisphere_logcos_rmse(pred, network.evaluate(check_wi, check_wo), np.degrees(np.arccos(check_wi[:, 2])))
    assert error < 0.01


def test_bad_samples_give_one_line_errors(basis):
    wi, wo = hemisphere_pairs(1, (2, 2))
    values = GLOSSY.evaluate(wi, wo)
    cases = [((wi[:0], wo[:0], values[:0]), "no sample above the horizon"),
             ((-wi, wo, values), "no sample above the horizon"),
             ((wi, wo, np.where(np.arange(len(wi))[:, None] == 3, np.nan, values)), "3 BRDF value"),
             ((wi, wo, values[:-1]), "expected values")]
    for (a, b, v), match in cases:
        with pytest.raises(InputError, match=match) as error:
            pca_brdf.fit_channels(basis, a, b, v, 0.003, source="m.csv")
        assert "\n" not in str(error.value) and "m.csv" in str(error.value)
    with pytest.raises(InputError, match="ridge weight"):
        pca_brdf.fit_channels(basis, wi, wo, values, float("nan"))


# --------------------------------------------------------------------------- the run and the file


def test_an_rgb_fit_exports_a_pca_table_equal_to_the_pytorch_model(rgb_fit, rgb_table):
    result, model = rgb_fit
    metrics = result.metrics
    assert metrics["status"] == "ok" and metrics["fit/pca/components"] == 32 and metrics["fit/pca/channels"] == 3
    assert np.shape(metrics["fit/pca/coefficients"]) == (3, 32)
    assert metrics["fit/pca/basis_sha256"] == pca_brdf.load_basis().sha256
    assert 0 < metrics["fit/pca/inplane_logcos_rmse"] < 0.2 and metrics["fit/inplane_glossy_rel_rmse"] is not None
    assert model.kind == "pca" and not model.is_spectral
    details = kinds.load_model(model.path).details
    assert (details.components, details.ridge, details.nodes) == (32, 0.003, pca_brdf.load_basis().nodes)
    assert details.basis_sha256 == metrics["fit/pca/basis_sha256"]
    # onnxruntime on the file against the checkpoint's PyTorch table
    exportable = kinds.load_exportable(result.checkpoint)
    assert isinstance(exportable.module, pca_brdf.PcaTable)
    wi, wo = hemisphere_pairs(4, (5, 6))
    with torch.no_grad():
        expected = exportable.module(torch.as_tensor(wi, dtype=torch.float32),
                                     torch.as_tensor(wo, dtype=torch.float32)).double().numpy()
    assert np.allclose(model(wi, wo), expected, rtol=1e-4, atol=1e-5)
    # the in-plane error in metrics.json is the file's own on the table
    table = nb.read(rgb_table).samples
    assert hemisphere_logcos_rmse(model(*table.vectors()), table.values, table.theta_i) == pytest.approx(
        metrics["fit/pca/inplane_logcos_rmse"], rel=1e-3, abs=1e-5)


def test_a_spectral_table_is_fitted_band_by_band_into_a_spectral_table(tmp_path):
    result = nb.fit("pca", "virtual:gold", run_dir=tmp_path / "run",
                    overrides={"trainer.enable_progress_bar": False})  # with its plan_logcos_rmse
    metrics = result.metrics
    assert metrics["status"] == "ok" and metrics["fit/pca/channels"] == 31
    assert 0 < metrics["fit/plan_logcos_rmse"] < 0.2
    model = result.export(tmp_path / "gold.onnx", rgb_head=False)
    assert model.is_spectral and model.kind == "pca"
    assert kinds.load_model(model.path).details.nodes == (*pca_brdf.load_basis().nodes, 31)
    wi, wo = hemisphere_pairs(0, (3, 3))
    f = model(wi, wo, np.full(len(wi), 555.0))
    assert np.all(np.isfinite(f)) and np.all(f >= 0) and f.max() > 0


def test_a_fit_that_cannot_be_made_fails_in_one_line_without_a_best_checkpoint(tmp_path, monkeypatch, rgb_table):
    monkeypatch.setattr(pca_brdf, "ridge_coefficients", lambda *args: np.full((3, 32), np.nan))
    with pytest.raises(nb.FitFailed, match="PCA fit of glossy: the ridge solution is not finite") as error:
        nb.fit("pca", rgb_table, run_dir=tmp_path / "run", overrides=QUIET)
    assert "\n" not in str(error.value)
    assert not (tmp_path / "run" / "checkpoints" / "best.ckpt").exists()


def test_bad_settings_are_refused_naming_the_option(tmp_path, rgb_table):
    with pytest.raises(InputError, match="components from 1 to 32"):
        nb.fit("pca", rgb_table, run_dir=tmp_path / "a", overrides={**QUIET, "model.components": 33})
    with pytest.raises(InputError, match="finite number >= 0"):
        PcaFitModule(ridge=-1.0)
    assert not (tmp_path / "a" / "checkpoints").exists()


def test_the_metadata_reader_names_the_key_of_a_bad_entry():
    good = pca_kind.PcaMetadata(24, 0.003, "a" * 64, (48, 24, 8)).entries()
    assert pca_kind.read_metadata(good, "m.onnx", False).nodes == (48, 24, 8)
    for key, value in ((pca_kind.COMPONENTS_KEY, "0"), (pca_kind.RIDGE_KEY, "-1"), (pca_kind.SHA256_KEY, "xyz"),
                       (pca_kind.NODES_KEY, "48 x 24")):
        with pytest.raises(InputError) as error:
            pca_kind.read_metadata({**good, key: value}, "m.onnx", False)
        assert error.value.key == key and "m.onnx" in str(error.value)
    with pytest.raises(InputError, match="lacks metadata keys"):
        pca_kind.read_metadata({k: v for k, v in good.items() if k != pca_kind.RIDGE_KEY}, "m.onnx", False)


def test_a_pca_file_renders(rgb_fit):
    pytest.importorskip("mitsuba")
    _, model = rgb_fit
    image = nb.render_image(model, spp=4, resolution=16, variant="llvm_ad_rgb")
    assert np.all(np.isfinite(image)) and image.max() > 0
