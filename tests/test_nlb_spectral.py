"""Spectral NLB (docs/models.md#spectral-nlb, docs/formats.md#onnx-model-files): the channel-agnostic network, its pretraining, its latent
fit to RGB and spectral measurements, and its export.

Independent references: the network's own forward with explicit codes (the exported graph bakes
them), linear interpolation of codes computed by hand (FiLM is linear in the code, so
interpolating scale and shift is interpolating the code), scipy's multivariate normal for the
priors, and materials made from the network itself with known codes (a fit must find them).
"""

import json
import math
from pathlib import Path

import numpy as np
import pytest
import torch
from scipy import stats

from neuralbrdf.data.plans import plan_spherical
from neuralbrdf.data.table import BrdfTable, write_table
from neuralbrdf.errors import InputError
from neuralbrdf.geometry import spherical_pair_to_vectors
from neuralbrdf.kinds import load_exportable
from neuralbrdf.kinds.nlb_spectral import load_fitted_spectral
from neuralbrdf.lightning.latent_fit_data import FitSamples, LatentFitData
from neuralbrdf.lightning.nlb_spectral_fit import (
    SpectralLatentFitModule,
    interpolation_matrix,
    wavelength_nodes,
)
from neuralbrdf.lightning.nlb_spectral_module import (
    PretrainedSpectralNlb,
    SpectralNlbPretrainModule,
    load_spectral_pretrained,
    save_spectral_pretrained,
)
from neuralbrdf.lightning.run import main as train_main
from neuralbrdf.losses import log_cosine
from neuralbrdf.models.directional import SpectralNlbWithCodes
from neuralbrdf.models.latent_prior import gaussian_of_codes
from neuralbrdf.models.nlb_spectral import SpectralNlbConfig, SpectralNlbNetwork

ROOT = Path(__file__).resolve().parents[1]
CONFIGS = ROOT / "configs"
WAVELENGTHS = np.arange(400.0, 701.0, 10.0)


def random_network(seed=0, **kwargs):
    torch.manual_seed(seed)
    config = dict(shared_dim=4, channel_dim=3, width=16, depth=3) | kwargs
    network = SpectralNlbNetwork(**config)
    with torch.no_grad():
        network.output_layer.weight.normal_(0.0, 0.5)
        network.channel_scale.weight.normal_(0.0, 0.3)
    return network


def unit_pairs(n, seed=0):
    rng = np.random.default_rng(seed)
    v = rng.normal(size=(2, n, 3))
    v[..., 2] = np.abs(v[..., 2])
    v /= np.linalg.norm(v, axis=-1, keepdims=True)
    return torch.as_tensor(v[0], dtype=torch.float32), torch.as_tensor(v[1], dtype=torch.float32)


def pretrained_file(tmp_path, network=None, n_materials=40, seed=1):
    """A "pretrained" spectral NLB checkpoint with random codes (more codes than dimensions)."""
    network = network or random_network()
    generator = torch.Generator().manual_seed(seed)
    shared = 0.5 * torch.randn(n_materials, network.shared_dim, generator=generator)
    channels = 0.5 * torch.randn(n_materials, 3, network.channel_dim, generator=generator)
    names = tuple(f"merl:m{i}" if i < 4 else f"analytic:{i}" for i in range(n_materials))
    return save_spectral_pretrained(PretrainedSpectralNlb(network, shared, channels, "", names),
                                    tmp_path / "pretrained.ckpt")


# ------------------------------------------------------------------------------- network


def test_channels_share_the_trunk_and_each_channel_depends_on_its_own_code_only():
    network = random_network()
    wi, wo = unit_pairs(200)
    shared = torch.randn(4)
    channels = torch.randn(5, 3)
    with torch.no_grad():
        f = network(wi, wo, shared, channels)
        assert f.shape == (200, 5) and (f >= 0).all() and torch.isfinite(f).all()
        changed = channels.clone()
        changed[2] += 1.0
        g = network(wi, wo, shared, changed)
        single = network(wi, wo, shared, channels[2:3])
    torch.testing.assert_close(g[:, [0, 1, 3, 4]], f[:, [0, 1, 3, 4]], rtol=0, atol=0)
    assert (g[:, 2] - f[:, 2]).abs().max() > 1e-3
    torch.testing.assert_close(single[:, 0], f[:, 2])


def test_zero_below_the_horizon_and_configuration_checked():
    network = random_network()
    wi, wo = unit_pairs(50)
    below = wo * torch.tensor([1.0, 1.0, -1.0])
    assert (network(wi, below, torch.randn(4), torch.randn(3, 3)) == 0).all()
    with pytest.raises(InputError, match="channel_layer"):
        SpectralNlbConfig(depth=3, channel_layer=3)
    with pytest.raises(InputError, match="channel codes"):
        network(wi, wo, torch.randn(4), torch.randn(3, 5))


@pytest.mark.parametrize("channel_layer", [0, 1, 2])
@pytest.mark.parametrize("channel_dim", [3, 8])
def test_exported_module_equals_the_network_with_its_codes_rgb_and_interpolated_in_wavelength(channel_layer,
                                                                                              channel_dim):
    """Both ways of interpolating in wavelength: the code (3 dimensions, 4 nodes, 16 units: 108
    multiply-adds per wavelength against the tables' 128) and the scale and shift tables (8 dimensions)."""
    network = random_network(channel_layer=channel_layer, channel_dim=channel_dim)
    wi, wo = unit_pairs(300, seed=3)
    shared, nodes = torch.randn(4), torch.randn(4, channel_dim)
    node_nm = [400.0, 500.0, 600.0, 700.0]
    with torch.no_grad():
        rgb = SpectralNlbWithCodes(network, shared, nodes[:3])(wi, wo)
        torch.testing.assert_close(rgb, network(wi, wo, shared, nodes[:3]))
        spectral = SpectralNlbWithCodes(network, shared, nodes, node_nm)
        assert spectral.interpolates_codes == (channel_dim == 3)
        # at a node: that node's code; between nodes: the linear interpolation of the two codes;
        # outside the range: the end node (clamped)
        for wavelength, code in ((500.0, nodes[1]), (530.0, 0.7 * nodes[1] + 0.3 * nodes[2]), (380.0, nodes[0]),
                                 (720.0, nodes[3])):
            got = spectral(wi, wo, torch.full((300,), wavelength))
            torch.testing.assert_close(got, network(wi, wo, shared, code[None])[:, 0], rtol=1e-5, atol=1e-6)


def silenced(network, units=(0, 3, 5)):
    """``network`` with hidden units of its middle layer that never fire (bias far below their range)."""
    with torch.no_grad():
        network.hidden_layers[0].bias[list(units)] = -1e3
    return network


@pytest.mark.parametrize("spectral, channel_dim", [(True, 3), (True, 8), (False, 3)])
def test_a_module_without_its_silent_units_is_the_same_function(spectral, channel_dim):
    """Units whose ReLU input never exceeds 0 contribute nothing: removing them (their rows and the
    next layer's columns, and their FiLM rows whether the code or the tables are interpolated) leaves
    f unchanged to float32 rounding; removing a live unit does not."""
    network = silenced(random_network(seed=2, channel_dim=channel_dim))
    shared, nodes = torch.randn(4), torch.randn(4 if spectral else 3, channel_dim)
    module = SpectralNlbWithCodes(network, shared, nodes, [400.0, 500.0, 600.0, 700.0] if spectral else None)
    peaks = module.unit_peaks(*unit_pairs(4000, seed=1))
    assert [len(p) for p in peaks] == [16, 16, 16]
    assert all(peaks[1][[0, 3, 5]] <= 0)
    keep = [p > 0 for p in peaks]
    pruned = module.without_units(keep)
    assert pruned.units == [int(k.sum()) for k in keep] and pruned.units[1] <= 13
    wi, wo = unit_pairs(3000, seed=2)
    arguments = (wi, wo, torch.linspace(380.0, 720.0, 3000)) if spectral else (wi, wo)
    with torch.no_grad():
        whole, without = module(*arguments), pruned(*arguments)
        torch.testing.assert_close(without, whole, rtol=1e-5, atol=1e-6)
        live = [k.clone() for k in keep]
        live[1][torch.nonzero(keep[1])[0]] = False
        assert not torch.allclose(module.without_units(live)(*arguments), whole, rtol=1e-3, atol=1e-4)


def test_unit_peaks_take_the_largest_input_over_every_channel_code():
    """At the channel layer a unit's input is a ⊙ scale + shift of each code: its peak is the largest
    over codes and pairs (computed here by hand from the network's own FiLM)."""
    network = random_network(seed=5)
    shared, nodes = torch.randn(4), torch.randn(4, 3)
    module = SpectralNlbWithCodes(network, shared, nodes, [400.0, 500.0, 600.0, 700.0])
    wi, wo = unit_pairs(500, seed=3)
    with torch.no_grad():
        pre = network.shared_pre_activation(wi, wo, shared)
        scale, shift = network.film(nodes)
        expected = (pre[:, None, :] * scale + shift).amax((0, 1))
    torch.testing.assert_close(module.unit_peaks(wi, wo)[2], expected, rtol=1e-5, atol=1e-5)


def test_shared_pre_activation_with_a_code_table_equals_one_code_per_pair():
    network = random_network(seed=7)
    wi, wo = unit_pairs(200, seed=4)
    codes = torch.randn(5, 4)
    index = torch.randint(0, 5, (200,))
    torch.testing.assert_close(network.shared_pre_activation(wi, wo, codes, index),
                               network.shared_pre_activation(wi, wo, codes[index]), rtol=1e-5, atol=1e-6)


# ------------------------------------------------------------------------------- pretraining


def run_train(*args):
    assert train_main(["fit", *args]) == 0


def test_pretrain_config_runs_and_its_checkpoint_reads_back(tmp_path):
    run_train("--config", str(CONFIGS / "nlb_spectral_pretrain.yaml"), "--run_dir", str(tmp_path / "run"),
              "--trainer.max_epochs", "2", "--trainer.log_every_n_steps", "1", "--trainer.enable_progress_bar", "false",
              "--data.batches_per_epoch", "3", "--data.val_batches", "1", "--data.num_workers", "0",
              "--data.batch_size", "256", "--data.n_analytic", "24", "--model.n_materials", "24",
              "--data.proxy_dir", "null", "--data.proxy_blends", "0")
    metrics = json.loads((tmp_path / "run" / "metrics.json").read_text())
    assert metrics["status"] == "ok" and math.isfinite(metrics["fit/val/logcos_rmse"])
    pretrained = load_spectral_pretrained(tmp_path / "run" / "checkpoints" / "best.ckpt")
    assert pretrained.shared.shape == (24, 32) and pretrained.channels.shape == (24, 3, 8)
    assert pretrained.names[0] == "analytic:0" and pretrained.channel_codes.shape == (72, 8)
    again = load_spectral_pretrained(save_spectral_pretrained(pretrained, tmp_path / "copy.ckpt"))
    for key, value in pretrained.network.state_dict().items():
        torch.testing.assert_close(again.network.state_dict()[key], value, rtol=0, atol=0)
    torch.testing.assert_close(again.channels, pretrained.channels, rtol=0, atol=0)
    with pytest.raises(InputError, match="not a spectral NLB pretraining checkpoint"):
        load_spectral_pretrained(ROOT / "neuralbrdf" / "pretrained" / "nlb_compact.ckpt")  # the RGB network


def test_warm_start_copies_the_network_and_the_codes_of_the_same_names(tmp_path):
    path = pretrained_file(tmp_path)
    previous = load_spectral_pretrained(path)
    module = SpectralNlbPretrainModule(n_materials=3, shared_dim=4, channel_dim=3, width=16, depth=3,
                                       warm_start=str(path))
    module._warm_start(["analytic:7", "rgl:new", "merl:m1"])
    torch.testing.assert_close(module.latents.shared[0], previous.shared[7])
    torch.testing.assert_close(module.latents.channels[2], previous.channels[1])
    torch.testing.assert_close(module.latents.shared[1], previous.shared.mean(0))
    wider = SpectralNlbPretrainModule(n_materials=3, shared_dim=4, channel_dim=3, width=8, depth=3,
                                      warm_start=str(path))
    with pytest.raises(InputError, match="warm start"):
        wider._warm_start(["analytic:0"])


# ------------------------------------------------------------------------------- latent fit


def network_table(network, shared, nodes, node_nm, plan, path, wavelengths=WAVELENGTHS):
    """A spectral table of the material ``(shared, nodes)`` on ``plan`` (exactly representable)."""
    angles = plan_spherical(plan)
    wi, wo = (torch.as_tensor(v, dtype=torch.float32) for v in spherical_pair_to_vectors(*angles))
    channels = interpolation_matrix(node_nm, wavelengths) @ nodes
    with torch.no_grad():
        values = network(wi, wo, shared, channels).double().numpy()
    write_table(BrdfTable(*angles, values, np.asarray(wavelengths, dtype=np.float64)), path)
    return path


def fit_module(path, **kwargs):
    settings = dict(init_candidates=4, init_starts=2, init_screen_steps=5, early_stop_patience=None,
                    node_step_nm=100.0, optimizer=lambda p: torch.optim.Adam(p, lr=0.05))
    return SpectralLatentFitModule(str(path), **{**settings, **kwargs})


def test_node_grid_and_interpolation_matrix():
    np.testing.assert_allclose(wavelength_nodes(WAVELENGTHS, 20.0), np.arange(400.0, 701.0, 20.0))
    np.testing.assert_allclose(wavelength_nodes(WAVELENGTHS, 70.0), np.linspace(400.0, 700.0, 6))  # 60 nm apart
    weights = interpolation_matrix([400.0, 500.0, 700.0], [400.0, 450.0, 600.0, 700.0])
    expected = torch.tensor([[1.0, 0.0, 0.0], [0.5, 0.5, 0.0], [0.0, 0.5, 0.5], [0.0, 0.0, 1.0]])
    torch.testing.assert_close(weights, expected)
    with pytest.raises(InputError, match="range"):
        wavelength_nodes(np.array([550.0]), 20.0)


def test_spectral_fit_recovers_a_material_made_from_the_network_and_beats_its_start(tmp_path):
    network = random_network(seed=4)
    checkpoint = pretrained_file(tmp_path, network)
    generator = torch.Generator().manual_seed(9)
    shared, nodes = 0.5 * torch.randn(4, generator=generator), 0.5 * torch.randn(4, 3, generator=generator)
    table = network_table(network, shared, nodes, [400.0, 500.0, 600.0, 700.0], "DS2", tmp_path / "m.csv")
    data = LatentFitData(path=str(table), spectral=True, eval_plan=None)
    data.setup()
    fit = fit_module(checkpoint)
    fit.set_channels(data.wavelengths_nm)
    assert fit.n_nodes == 4
    fit._set_channel_scale(data.train_samples, 1)
    fit.build_codes(data.material_names)
    samples = data.train_samples
    with torch.no_grad():
        start = fit.material_losses(samples, [p[None] for p in fit.code_parameters()])[0, 0]
    optimizer = torch.optim.Adam(fit.code_parameters(), lr=0.05)
    for _ in range(300):
        optimizer.zero_grad()
        codes = fit.code_parameters()
        loss = fit.sample_errors(samples, [c[None] for c in codes]).mean() + fit.prior_terms(codes).mean()
        loss.backward()
        optimizer.step()
    with torch.no_grad():
        end = fit.material_losses(samples, [p[None] for p in fit.code_parameters()])[0, 0]
        pred = fit.predict(samples)
    assert end < 0.2 * start
    relative = ((pred - samples.f).abs() / samples.f.clamp_min(1e-3)).median()
    assert relative < 0.05


def test_a_small_fit_is_one_lbfgs_run_per_material_on_the_full_batch_and_recovers_them(tmp_path, monkeypatch):
    """Data within data.full_batch_values are served whole at every step, and with
    model.full_batch_iterations the fit is one step: one L-BFGS run (with its line search) per
    material, each on its own samples, which finds the codes of materials made from the network;
    larger data keep random batches and the configured optimiser."""
    from neuralbrdf.lightning import latent_only

    network = random_network(seed=4)
    checkpoint = pretrained_file(tmp_path, network)
    generator = torch.Generator().manual_seed(9)
    tables = [network_table(network, 0.5 * torch.randn(4, generator=generator), 0.5 * torch.randn(4, 3, generator=generator),
                            [400.0, 500.0, 600.0, 700.0], "DS2", tmp_path / f"m{k}.csv") for k in range(2)]
    values = 2 * 185 * len(WAVELENGTHS)  # two materials: DS2's pairs x bands each
    sources = [{"path": str(t)} for t in tables]
    for limit, full in ((values, True), (values - 1, False)):
        data = LatentFitData(sources=sources, spectral=True, eval_plan=None, batch_values=310, full_batch_values=limit)
        data.setup()
        assert data.full_batch is full and len(next(iter(data.train_dataloader())).f) == (370 if full else 10)
    runs = []
    monkeypatch.setattr(latent_only, "lbfgs", lambda codes, iterations: runs.append(iterations) or torch.optim.LBFGS(
        codes, lr=1.0, max_iter=iterations, history_size=latent_only.LBFGS_HISTORY, line_search_fn="strong_wolfe"))
    run = tmp_path / "run"
    run_train("--config", str(CONFIGS / "nlb_spectral.yaml"), "--run_dir", str(run), "--model.checkpoint", str(checkpoint),
              "--data.sources", json.dumps(sources), "--data.eval_plan", "null", "--data.full_batch_values", str(values),
              "--model.full_batch_iterations", "60", "--model.node_step_nm", "100", "--model.init_screen_steps", "5",
              "--trainer.enable_progress_bar", "false")
    metrics = json.loads((run / "metrics.json").read_text())
    assert runs == [60, 60] and metrics["status"] == "ok"
    assert metrics["fit/fit_logcos_rmse/m0"] < 2e-3 and metrics["fit/fit_logcos_rmse/m1"] < 2e-3
    assert torch.load(run / "checkpoints" / "fitted.ckpt", weights_only=False)["global_step"] <= 1


def test_channel_normalisation_divides_each_channel_by_its_mean_log_cosine(tmp_path):
    network = random_network()
    checkpoint = pretrained_file(tmp_path, network)
    table = network_table(network, torch.randn(4), torch.randn(4, 3), [400.0, 500.0, 600.0, 700.0], "DS3",
                          tmp_path / "m.csv")
    data = LatentFitData(path=str(table), spectral=True, eval_plan=None)
    data.setup()
    samples = data.train_samples
    for normalised in (True, False):
        fit = fit_module(checkpoint, channel_normalised=normalised)
        fit.set_channels(data.wavelengths_nm)
        fit._set_channel_scale(samples, 1)
        fit.build_codes(data.material_names)
        codes = [p[None].detach() for p in fit.code_parameters()]
        with torch.no_grad():
            pred = fit._values(samples, *codes)[0]
            raw = (log_cosine(pred, samples.wi[:, 2]) - log_cosine(samples.f, samples.wi[:, 2])).abs()
            scale = log_cosine(samples.f, samples.wi[:, 2]).mean(0) if normalised else torch.ones(len(WAVELENGTHS))
            torch.testing.assert_close(fit.sample_errors(samples, codes)[0], (raw / scale).mean(1))


def test_priors_are_gaussians_of_the_pretrained_codes_and_a_second_difference(tmp_path):
    checkpoint = pretrained_file(tmp_path)
    pretrained = load_spectral_pretrained(checkpoint)
    fit = fit_module(checkpoint, shared_prior_weight=0.3, channel_prior_weight=0.2, smoothness_weight=0.5)
    fit.set_channels(np.arange(400.0, 701.0, 10.0))  # a spectral fit: nodes 100 nm apart, 4 of them
    shared, nodes = torch.randn(2, 4), torch.randn(2, 4, 3)
    expected = []
    for s, c in zip(shared, nodes):
        mean, precision = gaussian_of_codes(pretrained.shared)
        p_s = -stats.multivariate_normal(mean.double(), np.linalg.inv(precision.double())).logpdf(s.double())
        p_s0 = -stats.multivariate_normal(mean.double(), np.linalg.inv(precision.double())).logpdf(mean.double())
        mean_c, precision_c = gaussian_of_codes(pretrained.channel_codes)
        normal_c = stats.multivariate_normal(mean_c.double(), np.linalg.inv(precision_c.double()))
        p_c = np.mean([-normal_c.logpdf(code.double()) + normal_c.logpdf(mean_c.double()) for code in c])
        curvature = np.mean([((c[k - 1] - 2 * c[k] + c[k + 1]) ** 2).mean().item() for k in range(1, 3)])
        expected.append(0.3 * (p_s - p_s0) / 4 + 0.2 * p_c / 3 + 0.5 * curvature)
    np.testing.assert_allclose(fit.prior_terms([shared, nodes]).numpy(), expected, rtol=1e-4)
    fit.set_channels(None)  # RGB: the channels are no wavelength sequence, no smoothness
    without_smoothness = fit_module(checkpoint, shared_prior_weight=0.3, channel_prior_weight=0.2)
    torch.testing.assert_close(fit.prior_terms([shared, nodes[:, :3]]),
                               without_smoothness.prior_terms([shared, nodes[:, :3]]), rtol=0, atol=0)
    assert fit_module(checkpoint, shared_prior_weight=0, channel_prior_weight=0).prior_terms([shared, nodes]) == 0


def test_fit_config_end_to_end_spectral_and_rgb_with_export(tmp_path):
    """The shipped config on two tables (one run spectral, one RGB); every material exports and
    the file is the fitted model: spectral with its nodes' range, or RGB, without the units the
    material never uses."""
    network = silenced(random_network(seed=6))
    checkpoint = pretrained_file(tmp_path, network)
    node_nm = [400.0, 500.0, 600.0, 700.0]
    tables = [network_table(network, torch.randn(4), torch.randn(4, 3), node_nm, "DS3", tmp_path / f"m{k}.csv")
              for k in range(2)]
    sources = json.dumps([{"path": str(t)} for t in tables])
    common = ["--model.checkpoint", str(checkpoint), "--trainer.max_epochs", "1", "--data.steps_per_epoch", "5",
              "--model.init_screen_steps", "2", "--trainer.enable_progress_bar", "false",
              "--data.sources", sources, "--model.node_step_nm", "100"]
    for spectral in ("true", "false"):
        run = tmp_path / f"run_{spectral}"
        run_train("--config", str(CONFIGS / "nlb_spectral.yaml"), "--run_dir", str(run), "--data.spectral", spectral,
                  *common)
        metrics = json.loads((run / "metrics.json").read_text())
        assert metrics["status"] == "ok" and math.isfinite(metrics["fit/fit_logcos_rmse/m0"])
        fitted = load_fitted_spectral(run / "checkpoints" / "fitted.ckpt")
        assert sorted(fitted.shared) == ["m0", "m1"]
        exportable = load_exportable(run / "checkpoints" / "fitted.ckpt", "m1")
        assert exportable.kind == "nlb_spectral"
        if spectral == "true":
            assert fitted.node_wavelengths_nm == tuple(node_nm) and exportable.wavelength_range_nm == (400.0, 700.0)
        else:
            assert fitted.node_wavelengths_nm is None and exportable.wavelength_range_nm is None
        assert_exported_file_is_the_whole_network(fitted, exportable, tmp_path / f"m1_{spectral}.onnx")


def assert_exported_file_is_the_whole_network(fitted, exportable, path):
    """The written file (without the material's silent units) against the whole network with the
    material's codes, through onnxruntime and the Dr.Jit interpreter, on the contract's dense probe
    at several wavelengths."""
    import drjit as dr
    import onnxruntime
    from drjit.llvm import Float

    from neuralbrdf.kinds import load_model
    from neuralbrdf.onnx_contract import dense_probe
    from neuralbrdf.onnx_export import write_model
    from neuralbrdf.render.drjit_onnx import DrJitGraph

    write_model(exportable, path)
    model = load_model(path)
    kept = [int(k.split("/")[0]) for k in model.metadata["neuralbrdf.nlb_spectral.hidden_units"].split()]
    assert kept == exportable.module.units and kept[1] <= 13  # the silenced units are gone
    wi, wo, _ = dense_probe()
    session = onnxruntime.InferenceSession(str(path), providers=["CPUExecutionProvider"])
    whole = fitted.model("m1").eval()
    graph = DrJitGraph.from_model(model)
    columns = [[Float(v[:, k]) for k in range(3)] for v in (wi, wo)]
    for wavelength in ((410.0, 555.5, 700.0) if model.is_spectral else (None,)):
        feeds = {"wi": wi, "wo": wo}
        if wavelength is not None:
            feeds["wavelength"] = np.full(len(wi), wavelength, np.float32)
        (got,) = session.run(["f"], feeds)
        with torch.no_grad():
            expected = whole(*(torch.from_numpy(v) for v in feeds.values())).numpy()
        np.testing.assert_allclose(got, expected, rtol=2e-5, atol=1e-6)
        drjit = graph(*columns, None if wavelength is None else Float(feeds["wavelength"]))
        np.testing.assert_allclose(np.stack([c.numpy() for c in drjit], axis=-1).reshape(got.shape), got,
                                   rtol=2e-5, atol=1e-6)
    dr.sync_thread()


def test_fit_time_counts_the_screening_of_starts(tmp_path, monkeypatch):
    """``fit/wall_time_s`` runs from the module's set-up, where the starts are screened (a clock
    that jumps 1000 s during the screening shows it), to the end of the fit."""
    import time

    from neuralbrdf.lightning.latent_only import LatentOnlyFit

    jump, real_clock, real_choose = [0.0], time.perf_counter, LatentOnlyFit.choose_starts

    def choose_starts(self, samples):
        real_choose(self, samples)
        jump[0] += 1000.0

    monkeypatch.setattr(time, "perf_counter", lambda: real_clock() + jump[0])
    monkeypatch.setattr(LatentOnlyFit, "choose_starts", choose_starts)
    network = random_network(seed=3)
    table = network_table(network, torch.randn(4), torch.randn(4, 3), [400.0, 500.0, 600.0, 700.0], "DS4",
                          tmp_path / "m.csv")
    run_train("--config", str(CONFIGS / "nlb_spectral.yaml"), "--run_dir", str(tmp_path / "run"),
              "--model.checkpoint", str(pretrained_file(tmp_path, network)), "--data.path", str(table),
              "--trainer.max_epochs", "1", "--data.steps_per_epoch", "2", "--model.init_screen_steps", "1",
              "--trainer.enable_progress_bar", "false", "--data.eval_plan", "null")
    assert 1000.0 <= json.loads((tmp_path / "run" / "metrics.json").read_text())["fit/wall_time_s"] < 1600.0


def test_screening_sees_at_most_init_screen_values_of_each_material_and_of_all(tmp_path, monkeypatch):
    from neuralbrdf.lightning import nlb_spectral_fit

    network = random_network()
    module = fit_module(pretrained_file(tmp_path, network), init_screen_values=21)  # 7 pairs of 3 channels
    material = torch.tensor([0] * 20 + [1] * 5 + [2] * 9)
    wi, wo = unit_pairs(len(material))
    samples = FitSamples(material, wi, wo, torch.rand(len(material), 3))
    chosen = module.screening_samples(samples)
    assert torch.bincount(chosen.material).tolist() == [7, 5, 7]
    assert len(set(map(tuple, chosen.wi.tolist()))) == 19  # distinct samples, each once
    monkeypatch.setattr(nlb_spectral_fit, "SCREEN_VALUES", 36)  # a large fit: 12 values, 4 pairs each
    assert torch.bincount(module.screening_samples(samples).material).tolist() == [4, 4, 4]
    module._full_batch = True  # a small fit: init_screen_values alone
    assert torch.bincount(module.screening_samples(samples).material).tolist() == [7, 5, 7]
    assert fit_module(pretrained_file(tmp_path, network)).screening_samples(samples) is samples  # None: all
    with pytest.raises(InputError, match="init_screen_values"):
        fit_module(pretrained_file(tmp_path, network), init_screen_values=0)


def test_candidates_scored_in_chunks_start_each_material_from_its_lowest_loss_candidate(tmp_path, monkeypatch):
    """With one start, each material starts from the candidate of lowest loss on its own samples,
    whatever the chunks the candidates are scored in (here 3, which does not divide their number):
    two materials made from two of the candidates, one of them in the last, shorter chunk, each
    start from their own."""
    from neuralbrdf.lightning import latent_only

    network = random_network(seed=5)
    fit = fit_module(pretrained_file(tmp_path, network), init_candidates=6, init_starts=1)
    fit.set_channels(np.asarray(WAVELENGTHS))
    candidates = fit.start_candidates()
    assert len(candidates[0]) % 3 != 0
    made_from = [len(candidates[0]) - 1, 2]
    paths = [network_table(network, candidates[0][k], candidates[1][k], fit.node_wavelengths_nm, "DS3",
                           tmp_path / f"m{i}.csv") for i, k in enumerate(made_from)]
    data = LatentFitData(sources=[{"path": str(path)} for path in paths], spectral=True, eval_plan=None)
    data.setup()
    fit._set_channel_scale(data.train_samples, 2)
    monkeypatch.setattr(latent_only, "CANDIDATE_VALUES", 3 * data.train_samples.f.numel())  # 3 to an evaluation
    fit._candidates = candidates
    fit.build_codes(data.material_names)
    fit.choose_starts(data.train_samples)
    torch.testing.assert_close(fit.latents.shared.detach(), candidates[0][made_from])
    torch.testing.assert_close(fit.latents.channels.detach(), candidates[1][made_from])


def test_spectral_fit_refuses_rgb_sources_and_mixed_wavelength_grids(tmp_path):
    network = random_network()
    node_nm = [400.0, 500.0, 600.0, 700.0]
    a = network_table(network, torch.randn(4), torch.randn(4, 3), node_nm, "DS4", tmp_path / "a.csv")
    b = network_table(network, torch.randn(4), torch.randn(4, 3), node_nm, "DS4", tmp_path / "b.csv",
                      wavelengths=np.arange(400.0, 701.0, 20.0))
    with pytest.raises(InputError, match="share a wavelength grid"):
        LatentFitData(sources=[{"path": str(a)}, {"path": str(b)}], spectral=True).setup()
    with pytest.raises(InputError, match="NBRDF proxies are RGB"):
        LatentFitData(sources=[{"nbrdf": "x.h5"}], spectral=True)
    angles = plan_spherical("DS4")
    write_table(BrdfTable(*angles, np.full((len(angles[0]), 3), 0.1)), tmp_path / "rgb.csv")
    with pytest.raises(InputError, match="RGB table"):
        LatentFitData(path=str(tmp_path / "rgb.csv"), spectral=True).setup()


def test_automatic_mode_is_spectral_only_when_every_source_has_a_spectrum(tmp_path):
    network = random_network()
    node_nm = [400.0, 500.0, 600.0, 700.0]
    spectral = network_table(network, torch.randn(4), torch.randn(4, 3), node_nm, "DS4", tmp_path / "s.csv")
    angles = plan_spherical("DS4")
    write_table(BrdfTable(*angles, np.full((len(angles[0]), 3), 0.1)), tmp_path / "rgb.csv")
    alone = LatentFitData(path=str(spectral), spectral=None, eval_plan=None)
    alone.setup()
    assert alone.spectral and alone.train_samples.f.shape[1] == len(WAVELENGTHS)
    mixed = LatentFitData(sources=[{"path": str(spectral)}, {"path": str(tmp_path / "rgb.csv")}], spectral=None)
    mixed.setup()
    assert not mixed.spectral and mixed.train_samples.f.shape[1] == 3 and mixed.wavelengths_nm is None


def test_batch_values_draw_as_many_pairs_as_hold_that_many_values(tmp_path):
    network = random_network()
    table = network_table(network, torch.randn(4), torch.randn(4, 3), [400.0, 500.0, 600.0, 700.0], "DS1",
                          tmp_path / "m.csv")
    data = LatentFitData(path=str(table), spectral=True, eval_plan=None, batch_values=310)
    data.setup()
    batch = next(iter(data.train_dataloader()))
    assert batch.f.shape == (10, len(WAVELENGTHS))  # 310 values over 31 bands
    with pytest.raises(InputError, match="not both"):
        LatentFitData(path=str(table), batch_size=5, batch_values=310)
