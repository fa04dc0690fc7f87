"""NLB representation network, pretraining and latent-only fitting (docs/models.md, docs/evaluate.md#metrics).

Tiny networks and checkpoints are made here so that nothing needs the shipped checkpoint;
tests that use the MERL proxies skip when ``../shared/data`` is absent.
"""

import json
import math
from dataclasses import replace
import subprocess
import sys
import textwrap
from pathlib import Path
from unittest import mock

import numpy as np
import pytest
import pytorch_lightning as pl
import torch

from neuralbrdf import metrics as metrics_module
from neuralbrdf.data.loading import load_measurement
from neuralbrdf.data.plans import plan_spherical
from neuralbrdf.data.table import BrdfTable, write_table
from neuralbrdf.errors import InputError
from neuralbrdf.geometry import normalize, spherical_pair_to_vectors
from neuralbrdf.lightning.latent_fit_data import LatentFitData
from neuralbrdf.lightning.latent_fit_module import LatentFitModule, start_candidates
from neuralbrdf.shipped import PRETRAINED_DEFAULT
from neuralbrdf.kinds.nlb import load_fitted
from neuralbrdf.lightning.nlb_module import NlbPretrainModule, load_pretrained, save_pretrained
from neuralbrdf.losses import nlb_loss
from neuralbrdf.lightning.run import main as train_main
from neuralbrdf.models.nlb import (
    COMPACT, LOG1P_F_MAX, PAPER, PRE_ACTIVATION_MIN, LatentTable, NlbNetwork, resize_latent,
)
from neuralbrdf.virtual.instrument import default_data_path

ROOT = Path(__file__).resolve().parents[1]
CONFIGS = ROOT / "configs"
DATA = ROOT.parent / "shared" / "data"
NBRDF = DATA / "merl-nbrdf"
LOW2012 = DATA / "abc-low2012" / "low2012_abc_merl.csv"
needs_merl = pytest.mark.skipif(not NBRDF.is_dir(), reason=f"MERL NBRDF proxies not found at {NBRDF} (docs/formats.md#nbrdf-proxy)")


def hemisphere_directions(n_theta=91, n_phi=24, upper=True):
    """Grid over the whole hemisphere, theta from 0 to 90° (the last row 1e-7 rad above the horizon)."""
    theta = np.linspace(0.0, math.pi / 2, n_theta)
    theta[-1] = math.pi / 2 - 1e-7
    phi = np.linspace(0.0, 2 * math.pi, n_phi, endpoint=False)
    t, p = np.meshgrid(theta, phi, indexing="ij")
    v = np.stack([np.sin(t) * np.cos(p), np.sin(t) * np.sin(p), np.cos(t)], axis=-1).reshape(-1, 3)
    return torch.as_tensor(v if upper else v * [1, 1, -1], dtype=torch.float32)


def all_pairs(a, b):
    return a[:, None, :].expand(-1, len(b), -1).reshape(-1, 3), b[None, :, :].expand(len(a), -1, -1).reshape(-1, 3)


def randomised(network, std=0.5):
    """``network`` with random output weights: a fresh one outputs the constant 0.05 sr⁻¹."""
    with torch.no_grad():
        network.output_layer.weight.normal_(0.0, std)
    return network


def tiny_module(n_materials=6, **kwargs):
    """A small "pretrained" module: random weights and latents."""
    torch.manual_seed(0)
    module = NlbPretrainModule(n_materials=n_materials, latent_dim=4, width=16, depth=2, **kwargs)
    randomised(module.network)
    with torch.no_grad():
        module.latents.latents.normal_(0.0, 0.5)
    return module


def save_checkpoint(module, path):
    torch.save({"state_dict": module.state_dict(), "hyper_parameters": dict(module.hparams)}, path)
    return path


# ------------------------------------------------------------------------------- network


@pytest.mark.parametrize("config, grid", [(COMPACT, (31, 8)), (PAPER, (11, 6))], ids=["compact", "paper"])
def test_network_is_finite_and_non_negative_on_the_whole_hemisphere(config, grid):
    torch.manual_seed(1)
    network = randomised(NlbNetwork(**config.__dict__), std=1.0)
    wi, wo = all_pairs(hemisphere_directions(*grid), hemisphere_directions(*grid))
    for scale in (1.0, 30.0, 1e4):  # ordinary, large and absurd latents: still finite (capped)
        latent = scale * torch.randn(len(wi), config.latent_dim)
        with torch.no_grad():
            f = network(wi, wo, latent)
        assert f.shape == (len(wi), 3)
        assert torch.isfinite(f).all() and (f >= 0).all()
        assert f.max() <= math.expm1(LOG1P_F_MAX) * (1 + 1e-6)


def test_network_is_zero_below_and_on_the_horizon():
    torch.manual_seed(2)
    network = NlbNetwork()
    up, down = hemisphere_directions(10, 6), hemisphere_directions(10, 6, upper=False)
    horizon = up.clone()
    horizon[:, 2] = 0.0
    latent = torch.randn(COMPACT.latent_dim)
    for a, b in ((up, down), (down, up), (down, down), (up, horizon), (horizon, up)):
        wi, wo = all_pairs(a, b)
        assert (network(wi, wo, latent) == 0).all()
    wi, wo = all_pairs(up[:-6], up[:-6])  # the last theta row is within 1e-7 of the horizon
    assert (network(wi, wo, latent) > 0).all()


def test_output_stays_trainable_beyond_its_bounds():
    # Pre-activations far below the floor (-15) or above the cap (16) give the bound's value
    # but still a gradient (straight-through clip): e^y would be exactly 0 at y = -120.
    wi, wo = all_pairs(hemisphere_directions(5, 4)[:-4], hemisphere_directions(5, 4)[:-4])
    floor = math.expm1(math.log1p(math.exp(PRE_ACTIVATION_MIN)))
    for bias, value in ((-120.0, floor), (120.0, math.expm1(LOG1P_F_MAX))):
        network = randomised(NlbNetwork(latent_dim=4, width=8, depth=2), std=0.1)
        with torch.no_grad():
            network.output_layer.bias.fill_(bias)
        latent = torch.zeros(4, requires_grad=True)
        f = network(wi, wo, latent)
        torch.testing.assert_close(f, torch.full_like(f, value), rtol=1e-5, atol=0)
        f.sum().backward()
        assert network.output_layer.bias.grad.abs().min() > 0
        assert latent.grad.abs().sum() > 0


def test_initial_output_is_a_constant_diffuse_level():
    network = NlbNetwork()
    wi, wo = all_pairs(hemisphere_directions(6, 5)[:-5], hemisphere_directions(6, 5)[:-5])
    f = network(wi, wo, torch.randn(len(wi), COMPACT.latent_dim))
    torch.testing.assert_close(f, torch.full_like(f, 0.05))


def test_half_vector_features_and_shared_latent():
    network = randomised(NlbNetwork(latent_dim=3, width=8, depth=3, half_vector=True))
    wi, wo = all_pairs(hemisphere_directions(6, 5), hemisphere_directions(6, 5))
    features = network.features(wi, wo)
    torch.testing.assert_close(features[:, 6:], normalize(wi + wo))
    torch.testing.assert_close(features[:, :6], torch.cat([wi, wo], 1))
    latent = torch.tensor([0.3, -1.0, 2.0])
    torch.testing.assert_close(network(wi, wo, latent), network(wi, wo, latent.expand(len(wi), 3)))
    assert NlbNetwork(latent_dim=3, width=8, depth=3, half_vector=False).features(wi, wo).shape == (len(wi), 6)


def test_paper_network_size():
    # Fan et al.: 256 wide, an input layer then 16 residual 256x256 layers, ~1.07 M weights.
    expected = (6 + 32) * 256 + 256 + 16 * (256 * 256 + 256) + 256 * 3 + 3
    assert NlbNetwork(**PAPER.__dict__).parameter_count() == expected
    assert 1.0e6 < expected < 1.1e6


def test_residual_layers_add_their_input():
    network = randomised(NlbNetwork(latent_dim=2, width=8, depth=2, residual=True, half_vector=False))
    with torch.no_grad():
        network.hidden_layers[0].weight.zero_()
        network.hidden_layers[0].bias.fill_(-1.0)  # relu(...) = 0: the block is the identity
    plain = NlbNetwork(latent_dim=2, width=8, depth=1, residual=False, half_vector=False)
    plain.load_state_dict({k: v for k, v in network.state_dict().items() if not k.startswith("hidden")})
    wi, wo = all_pairs(hemisphere_directions(4, 3), hemisphere_directions(4, 3))
    latent = torch.tensor([0.5, -0.5])
    torch.testing.assert_close(network(wi, wo, latent), plain(wi, wo, latent))


@pytest.mark.parametrize("kwargs", [{"width": 0}, {"depth": 0}, {"latent_dim": -1}, {"width": 2.5}])
def test_bad_network_config_raises(kwargs):
    with pytest.raises(InputError):
        NlbNetwork(**kwargs)


def test_bad_network_inputs_raise():
    network = NlbNetwork(latent_dim=4)
    with pytest.raises(InputError):
        network(torch.zeros(5, 3), torch.zeros(4, 3), torch.zeros(4))
    with pytest.raises(InputError):
        network(torch.zeros(5, 3), torch.zeros(5, 3), torch.zeros(5))


def test_latent_table():
    table = LatentTable(3, 4, 0.25, names=["a", "b", "c"])
    assert len(table) == 3
    assert (table.latents == 0.25).all()
    assert table(torch.tensor([[2, 0]])).shape == (1, 2, 4)
    torch.testing.assert_close(table.latent("b"), table.latents[1])
    for bad in ({"names": ["a", "a", "b"]}, {"names": ["a"]}, {"init_value": float("nan")}):
        with pytest.raises(InputError):
            LatentTable(3, 4, **bad)
    with pytest.raises(InputError):
        table.latent("z")


# ------------------------------------------------------------------------------- losses


def test_loss_domains_against_numpy():
    rng = np.random.default_rng(0)
    pred, target = rng.gamma(0.5, 10.0, (100, 3)), rng.gamma(0.5, 10.0, (100, 3))
    wi = normalize(torch.as_tensor(rng.normal(size=(100, 3)) * [1, 1, 0] + [0, 0, 0.5]))
    cos = wi[:, 2].numpy()[:, None]
    expected = np.mean(np.abs(np.log(1 + pred * cos) - np.log(1 + target * cos)))
    got = nlb_loss(torch.as_tensor(pred), torch.as_tensor(target), wi, "log_cosine")
    assert float(got) == pytest.approx(expected, rel=1e-12)
    linear = nlb_loss(torch.as_tensor(pred), torch.as_tensor(target), wi, "linear")
    assert float(linear) == pytest.approx(np.mean(np.abs(pred - target)))
    with pytest.raises(InputError):
        nlb_loss(torch.as_tensor(pred), torch.as_tensor(target), wi, "log")


# ------------------------------------------------------------------------------- checkpoints


def test_load_pretrained_round_trip(tmp_path):
    module = tiny_module()
    pretrained = load_pretrained(save_checkpoint(module, tmp_path / "tiny.ckpt"))
    torch.testing.assert_close(pretrained.latents, module.latents.latents.detach(), rtol=0, atol=0)
    wi, wo = all_pairs(hemisphere_directions(5, 4), hemisphere_directions(5, 4))
    latent = module.latents.latents[2].detach()
    torch.testing.assert_close(pretrained.network(wi, wo, latent), module.network(wi, wo, latent), rtol=0, atol=0)


def test_save_pretrained_keeps_what_loading_and_warm_starts_need(tmp_path):
    module = tiny_module()
    pretrained = load_pretrained(save_checkpoint(module, tmp_path / "tiny.ckpt"))
    pretrained = type(pretrained)(pretrained.network, pretrained.latents, pretrained.source,
                                  tuple(f"analytic:{i}" for i in range(6)))
    saved = load_pretrained(save_pretrained(pretrained, tmp_path / "shipped.ckpt"))
    assert saved.names == pretrained.names and saved.network.config == pretrained.network.config
    torch.testing.assert_close(saved.latents, pretrained.latents, rtol=0, atol=0)
    for key, value in pretrained.network.state_dict().items():
        assert torch.equal(saved.network.state_dict()[key], value)
    written = torch.load(tmp_path / "shipped.ckpt", weights_only=True)
    assert set(written) == {"state_dict", "hyper_parameters", "material_names", "pytorch-lightning_version"}
    assert written["hyper_parameters"]["_class_path"] == "neuralbrdf.lightning.nlb_module.NlbPretrainModule"


def test_warm_start_copies_the_network_and_the_latents_of_the_same_material(tmp_path):
    previous = tiny_module()
    checkpoint = save_checkpoint(previous, tmp_path / "tiny.ckpt")  # unnamed: analytic:0..5
    module = NlbPretrainModule(n_materials=3, latent_dim=4, width=16, depth=2, warm_start=str(checkpoint))
    module._warm_start(["analytic:4", "merl:new", "analytic:1"])
    for key, value in previous.network.state_dict().items():
        assert torch.equal(module.network.state_dict()[key], value)
    old = previous.latents.latents.detach()
    expected = torch.stack([old[4], old.mean(0), old[1]])
    torch.testing.assert_close(module.latents.latents.detach(), expected, rtol=0, atol=1e-7)
    wider = NlbPretrainModule(n_materials=3, latent_dim=4, width=8, depth=2, warm_start=str(checkpoint))
    with pytest.raises(InputError, match="warm start"):
        wider._warm_start(["analytic:0"])


def test_resize_latent_keeps_the_function_where_it_can():
    module = tiny_module(n_materials=12)
    network, latents = module.network, module.latents.latents.detach()
    wi, wo = all_pairs(hemisphere_directions(5, 4), hemisphere_directions(5, 4))
    # Larger: padded latents give exactly the old outputs, and the new columns are not zero
    # (else the padded values would never receive a gradient).
    wider, padded = resize_latent(network, latents, 7, torch.Generator().manual_seed(1))
    assert padded.shape == (12, 7) and torch.all(padded[:, 4:] == 0)
    assert wider.input_layer.weight[:, -3:].abs().min() > 0
    torch.testing.assert_close(wider(wi, wo, padded[5]), network(wi, wo, latents[5]), rtol=0, atol=0)
    # Same size: a rotation of the latents, the outputs equal up to rounding.
    rotated, codes = resize_latent(network, latents, 4)
    torch.testing.assert_close(rotated(wi, wo, codes[3]), network(wi, wo, latents[3]), rtol=1e-5, atol=1e-6)
    # Smaller: the new network on a new code equals the old one on the code's projection onto
    # the leading principal directions, computed here independently with numpy.
    smaller, short = resize_latent(network, latents, 2)
    centred = latents.numpy() - latents.numpy().mean(0)
    _, _, vh = np.linalg.svd(centred, full_matrices=False)
    projected = latents.numpy().mean(0) + centred @ vh[:2].T @ vh[:2]
    expected = network(wi, wo, torch.as_tensor(projected[3], dtype=torch.float32))
    torch.testing.assert_close(smaller(wi, wo, short[3]), expected, rtol=1e-5, atol=1e-6)
    assert not torch.allclose(smaller(wi, wo, short[3]), network(wi, wo, latents[3]), atol=1e-4)
    with pytest.raises(InputError, match="latents must be"):
        resize_latent(network, latents[:, :3], 2)
    # fewer materials than latent values: still a full basis, the function kept on their codes
    few, codes = resize_latent(network, latents[:3], 4)
    torch.testing.assert_close(few(wi, wo, codes[1]), network(wi, wo, latents[1]), rtol=1e-5, atol=1e-6)


def test_warm_start_at_another_latent_size(tmp_path):
    previous = tiny_module()
    checkpoint = save_checkpoint(previous, tmp_path / "tiny.ckpt")
    module = NlbPretrainModule(n_materials=2, latent_dim=6, width=16, depth=2, warm_start=str(checkpoint))
    module._warm_start(["analytic:2", "analytic:0"])
    wi, wo = all_pairs(hemisphere_directions(5, 4), hemisphere_directions(5, 4))
    old = previous.latents.latents.detach()
    for row, source in enumerate((2, 0)):
        torch.testing.assert_close(module.network(wi, wo, module.latents.latents[row].detach()),
                                   previous.network(wi, wo, old[source]), rtol=0, atol=0)
    # smaller: a known material's code gives the old output at its projection (within the top two
    # principal directions of the old codes), an unknown one starts at the centroid (code 0)
    smaller = NlbPretrainModule(n_materials=2, latent_dim=2, width=16, depth=2, warm_start=str(checkpoint))
    smaller._warm_start(["analytic:2", "merl:new"])
    centred = old.numpy() - old.numpy().mean(0)
    _, _, vh = np.linalg.svd(centred, full_matrices=False)
    projected = torch.as_tensor(old.numpy().mean(0) + centred[2] @ vh[:2].T @ vh[:2], dtype=torch.float32)
    torch.testing.assert_close(smaller.network(wi, wo, smaller.latents.latents[0].detach()),
                               previous.network(wi, wo, projected), rtol=1e-5, atol=1e-6)
    torch.testing.assert_close(smaller.latents.latents[1].detach(), torch.zeros(2), rtol=0, atol=1e-6)


def test_load_pretrained_rejects_bad_files(tmp_path):
    with pytest.raises(InputError, match="not found"):
        load_pretrained(tmp_path / "missing.ckpt")
    (tmp_path / "text.ckpt").write_text("not a checkpoint")
    with pytest.raises(InputError, match="not a readable"):
        load_pretrained(tmp_path / "text.ckpt")
    torch.save({"state_dict": {}, "hyper_parameters": {}}, tmp_path / "empty.ckpt")
    with pytest.raises(InputError, match="not an NLB"):
        load_pretrained(tmp_path / "empty.ckpt")


def test_latent_fit_defaults_to_the_shipped_checkpoint():
    if PRETRAINED_DEFAULT.is_file():
        pretrained = load_pretrained(PRETRAINED_DEFAULT)
        assert pretrained.network.config == replace(COMPACT, latent_dim=32)  # nlb_latent32_blends
        assert torch.isfinite(pretrained.latents).all()
        assert LatentFitModule().network.config == pretrained.network.config
    else:
        with pytest.raises(InputError, match="nlb_pretrain.yaml"):
            LatentFitModule()


# ------------------------------------------------------------------------------- latent fit


def network_table(module, material, plan, path):
    """A BRDF table of the tiny network with corpus latent ``material`` on ``plan``: a known target."""
    angles = plan_spherical(plan)
    wi, wo = (torch.as_tensor(v, dtype=torch.float32) for v in spherical_pair_to_vectors(*angles))
    with torch.no_grad():
        values = module.network(wi, wo, module.latents.latents[material]).double().numpy()
    write_table(BrdfTable(*angles, values=values), path)
    return path


def test_latent_fit_leaves_every_network_weight_bit_identical(tmp_path):
    module = tiny_module()
    checkpoint = save_checkpoint(module, tmp_path / "tiny.ckpt")
    sources = [{"path": str(network_table(module, k, "DS2", tmp_path / f"m{k}.csv"))} for k in (1, 4)]
    data = LatentFitData(sources, eval_plan=None, steps_per_epoch=40)
    fit = LatentFitModule(str(checkpoint), optimizer=lambda p: torch.optim.Adam(p, lr=0.05))
    trainer = pl.Trainer(accelerator="cpu", max_epochs=2, logger=False, enable_checkpointing=False,
                         enable_progress_bar=False, enable_model_summary=False)
    trainer.fit(fit, data)
    stored = torch.load(checkpoint, weights_only=True)["state_dict"]
    for key, value in fit.network.state_dict().items():
        assert torch.equal(value, stored[f"network.{key}"]), key
    assert not any(p.requires_grad for p in fit.network.parameters())
    # ... while the latents moved from the centroid towards the materials' own
    start = stored["latents.latents"].mean(0)
    fitted = fit.latents.latents.detach()
    assert not torch.equal(fitted[0], start)
    data.setup()
    samples = data.train_samples
    with torch.no_grad():
        before = nlb_loss(fit.network(samples.wi, samples.wo, start), samples.f, samples.wi, "log_cosine")
        after = nlb_loss(fit.predict(samples), samples.f, samples.wi, "log_cosine")
    assert after < 0.2 * before
    assert fit.material_names == ["m1", "m4"]


def test_latent_fit_starts_each_material_at_its_best_pretrained_code(tmp_path):
    module = tiny_module()
    names = ["analytic:0", "analytic:1", "merl:a", "analytic:3", "merl:b", "analytic:5"]
    checkpoint = tmp_path / "tiny.ckpt"
    torch.save({"state_dict": module.state_dict(), "hyper_parameters": dict(module.hparams),
                "material_names": names}, checkpoint)
    pretrained = load_pretrained(checkpoint)
    assert pretrained.names == tuple(names)
    candidates = start_candidates(pretrained, 2)  # centroid, merl:a, merl:b, analytic:0 and :5
    expected = torch.stack([pretrained.latent_mean, *pretrained.latents[[2, 4, 0, 5]]])
    torch.testing.assert_close(candidates, expected, rtol=0, atol=0)
    # Tables made from merl:b and analytic:5: each start is exactly that code (zero loss).
    sources = [{"path": str(network_table(module, k, "DS2", tmp_path / f"m{k}.csv"))} for k in (4, 5)]
    data = LatentFitData(sources, eval_plan=None)
    data.setup()
    fit = LatentFitModule(str(checkpoint), init_candidates=2)
    fit.build_latents(data.material_names)
    fit.choose_starts(data.train_samples)
    torch.testing.assert_close(fit.latents.latents.detach(), pretrained.latents[[4, 5]], rtol=0, atol=0)
    with pytest.raises(InputError, match="exclude"):
        LatentFitModule(str(checkpoint), init_candidates=2, latent_init=0.0)
    with pytest.raises(InputError):
        LatentFitModule(str(checkpoint), early_stop_patience=0)


def _tables_off_the_codes(module, tmp_path):
    """Two materials whose tables lie between corpus codes: no candidate fits them exactly."""
    sources = []
    for k, (a, b) in enumerate([(1, 4), (3, 5)]):
        blend = 0.5 * (module.latents.latents[a] + module.latents.latents[b])
        angles = plan_spherical("DS2")
        wi, wo = (torch.as_tensor(v, dtype=torch.float32) for v in spherical_pair_to_vectors(*angles))
        with torch.no_grad():
            values = module.network(wi, wo, blend).double().numpy()
        write_table(BrdfTable(*angles, values=values), tmp_path / f"blend{k}.csv")
        sources.append({"path": str(tmp_path / f"blend{k}.csv")})
    data = LatentFitData(sources, eval_plan=None)
    data.setup()
    return data


@pytest.mark.parametrize("domain", ["log_cosine", "linear"])
def test_material_losses_are_each_materials_own_loss(tmp_path, domain):
    module = tiny_module()
    checkpoint = save_checkpoint(module, tmp_path / "tiny.ckpt")
    data = _tables_off_the_codes(module, tmp_path)
    fit = LatentFitModule(str(checkpoint), loss_domain=domain)
    fit.build_latents(data.material_names)
    samples = data.train_samples
    codes = module.latents.latents[:3, None].expand(3, 2, -1).detach()
    with torch.no_grad():
        losses = fit.material_losses(samples, [codes])
        for s in range(3):
            for m in range(2):
                own = samples.material == m
                expected = nlb_loss(fit.network(samples.wi[own], samples.wo[own], codes[s, m]), samples.f[own],
                                    samples.wi[own], domain)
                torch.testing.assert_close(losses[s, m], expected, rtol=1e-5, atol=1e-7)


def test_screened_starts_keep_each_materials_lowest_loss_after_screening(tmp_path):
    module = tiny_module()
    checkpoint = save_checkpoint(module, tmp_path / "tiny.ckpt")
    data = _tables_off_the_codes(module, tmp_path)
    samples = data.train_samples
    # Without steps that move the codes (lr 0), screening every candidate is the plain best start.
    single = LatentFitModule(str(checkpoint), init_candidates=2)
    frozen = LatentFitModule(str(checkpoint), init_candidates=2, init_starts=5, init_screen_steps=1,
                             optimizer=lambda params: torch.optim.SGD(params, lr=0.0))
    for fit in (single, frozen):
        fit.build_latents(data.material_names)
        fit.choose_starts(samples)
    torch.testing.assert_close(frozen.latents.latents, single.latents.latents, rtol=0, atol=0)
    # With steps, each material keeps the start whose loss after screening is lowest.
    screened = LatentFitModule(str(checkpoint), init_candidates=2, init_starts=3, init_screen_steps=30,
                               optimizer=lambda params: torch.optim.Adam(params, lr=0.05))
    screened.build_latents(data.material_names)
    recorded = []
    original = screened.material_losses
    screened.material_losses = lambda *args: recorded.append(original(*args)) or recorded[-1]
    screened.choose_starts(samples)
    after_screening = recorded[-1].detach()
    with torch.no_grad():
        chosen = original(samples, [screened.latents.latents[None]])[0]
        plain = original(samples, [single.latents.latents[None]])[0]
    torch.testing.assert_close(chosen, after_screening.min(0).values, rtol=1e-6, atol=1e-8)
    assert torch.all(chosen < plain)  # screening improved on the plain best start here
    with pytest.raises(InputError, match="candidates"):
        LatentFitModule(str(checkpoint), init_starts=2)
    with pytest.raises(InputError, match="positive integer"):
        LatentFitModule(str(checkpoint), init_candidates=2, init_starts=0)


def test_latent_fit_detects_a_changed_weight(tmp_path):
    fit = LatentFitModule(str(save_checkpoint(tiny_module(), tmp_path / "tiny.ckpt")))
    with torch.no_grad():
        fit.network.output_layer.bias[0] += 1e-6
    with pytest.raises(RuntimeError, match="changed"):
        fit.on_fit_end()


@pytest.mark.parametrize(
    "sources",
    [
        [],
        [{"tabel": "x.csv"}],
        [{"path": "a.csv", "gcms": "b.csv"}],
        [{"virtual": "gold", "reference": "r.csv"}],
        [{"path": "a.csv", "plan": "DS1"}],
        [{"nbrdf": "a.h5", "plan": "DS9"}],
        [{"virtual": "gold"}, {"virtual": "gold"}],
        ["gold"],
    ],
)
def test_bad_latent_sources_raise(sources):
    with pytest.raises(InputError) as info:
        LatentFitData(sources)
    assert info.value.key.startswith("data.sources")


def test_latent_sources_of_the_same_measurement_agree(tmp_path):
    gcms, reference = default_data_path("gold"), default_data_path("munsell_n9")
    write_table(load_measurement(gcms, reference), tmp_path / "gold.csv")
    sources = [{"virtual": "gold"}, {"path": str(gcms), "reference": str(reference), "name": "raw"},
               {"path": str(tmp_path / "gold.csv"), "name": "table"}]
    data = LatentFitData(sources, eval_plan=None)
    data.setup()
    assert data.material_names == ["gold", "raw", "table"]
    samples = [item.fit for item in data.eval_sets]
    assert len(samples[0].f) == 1001  # DS1
    for other in samples[1:]:
        torch.testing.assert_close(other.f, samples[0].f)
        torch.testing.assert_close(other.wi, samples[0].wi)
    assert data.train_samples.material.tolist() == [0] * 1001 + [1] * 1001 + [2] * 1001


def test_data_path_drops_a_single_measurement_in_place_of_the_sources(tmp_path):
    gcms, reference = default_data_path("gold"), default_data_path("munsell_n9")
    data = LatentFitData([{"virtual": "cyan"}], path=str(gcms), reference=str(reference), eval_plan=None)
    data.setup()
    assert data.material_names == ["gold_DS1"] and len(data.train_samples.f) == 1001
    with pytest.raises(InputError, match="data.reference"):
        LatentFitData([{"virtual": "cyan"}], reference=str(reference))


def test_a_missing_abc_reference_warns_when_the_data_is_made(tmp_path):
    with pytest.warns(UserWarning, match=r"^data.low2012_abc: .*missing.csv not found; no comparison with Löw"):
        data = LatentFitData([{"virtual": "gold"}], low2012_abc=str(tmp_path / "missing.csv"))
    data.setup()  # the fit goes on without the comparison
    assert data.low2012_abc is None and data.eval_sets[0].abc is None


def test_bad_plans_raise():
    with pytest.raises(InputError):
        LatentFitData([{"virtual": "gold"}], plan="DS7")
    with pytest.raises(InputError):
        LatentFitData([{"virtual": "gold"}], eval_plan="lowe")


# ------------------------------------------------------------------------------- DDP

DDP_SCRIPT = textwrap.dedent(
    """
    import json, sys
    import pytorch_lightning as pl
    import torch
    from neuralbrdf.lightning.corpus_data import CorpusDataModule
    from neuralbrdf.lightning.nlb_module import NlbPretrainModule

    class FirstBatch(pl.Callback):
        def on_train_batch_start(self, trainer, module, batch, batch_idx):
            if batch_idx == 0:
                self.materials = batch.material[:16].tolist()

    if __name__ == "__main__":
        out = sys.argv[1]
        torch.set_num_threads(1)
        pl.seed_everything(0)
        data = CorpusDataModule(n_analytic=8, batch_size=64, batches_per_epoch=4, val_batches=2)
        model = NlbPretrainModule(n_materials=8, latent_dim=4, width=8, depth=2)
        first = FirstBatch()
        trainer = pl.Trainer(accelerator="cpu", devices=2, strategy="ddp", max_steps=2, logger=False,
                             enable_checkpointing=False, enable_progress_bar=False,
                             enable_model_summary=False, limit_val_batches=1, callbacks=[first])
        trainer.fit(model, data)
        state = {k: v.tolist() for k, v in model.state_dict().items()}
        backend = torch.distributed.get_backend() if torch.distributed.is_initialized() else None
        report = {"step": trainer.global_step, "world": trainer.world_size, "backend": backend,
                  "first": first.materials, "state": state,
                  "val": float(trainer.callback_metrics["val/logcos_rmse"])}
        with open(f"{out}/rank{trainer.global_rank}.json", "w") as handle:
            json.dump(report, handle)
        # torch asks for this before exit: a process group left to the interpreter's teardown
        # can abort the process (SIGABRT) after the work is done
        torch.distributed.destroy_process_group()
    """
)


def test_pretraining_runs_under_two_process_ddp(tmp_path):
    script = tmp_path / "ddp_step.py"
    script.write_text(DDP_SCRIPT)
    result = subprocess.run([sys.executable, str(script), str(tmp_path)], cwd=tmp_path, capture_output=True,
                            text=True, timeout=300)
    assert result.returncode == 0, result.stderr[-3000:]
    ranks = [json.loads((tmp_path / f"rank{r}.json").read_text()) for r in (0, 1)]
    for rank in ranks:
        assert rank["step"] == 2 and rank["world"] == 2 and rank["backend"] == "gloo"
    assert ranks[0]["first"] != ranks[1]["first"]  # each process drew its own batches
    assert ranks[0]["state"] == ranks[1]["state"]  # ... and the gradients were all-reduced
    assert ranks[0]["val"] == ranks[1]["val"]
    initial = NlbPretrainModule(n_materials=8, latent_dim=4, width=8, depth=2)
    assert ranks[0]["state"]["latents.latents"] != initial.latents.latents.tolist()  # training moved the latents


# ------------------------------------------------------------------------------- configs through train.py


def train(*args):
    """``train.py fit ARGS`` in this process (one thread); returns the exit status."""
    with mock.patch.object(sys, "argv", ["train.py"]):
        status = train_main(["fit", *args, "--num_threads", "1"])
    torch.set_num_threads(1)
    return status


def run_train(*args):
    assert train(*args) == 0


@pytest.fixture(scope="module")
def pretrained_run(tmp_path_factory):
    run_dir = tmp_path_factory.mktemp("nlb_pretrain")
    run_train("--config", str(CONFIGS / "nlb_pretrain.yaml"), "--run_dir", str(run_dir),
              "--trainer.max_epochs", "2", "--trainer.log_every_n_steps", "1",
              "--data.batches_per_epoch", "3", "--data.val_batches", "1", "--data.num_workers", "0",
              "--data.batch_size", "256", "--data.n_analytic", "24", "--model.n_materials", "24",
              "--data.proxy_dir", "null")  # 24 codes: more than the 16 latent dimensions a prior over them needs
    return run_dir


def test_compact_pretrain_config_runs(pretrained_run):
    metrics = json.loads((pretrained_run / "metrics.json").read_text())
    assert metrics["fit/epochs"] == 2
    assert math.isfinite(metrics["fit/val/logcos_rmse"]) and math.isfinite(metrics["fit/train/loss_epoch"])
    pretrained = load_pretrained(pretrained_run / "checkpoints" / "last.ckpt")
    assert pretrained.network.config == COMPACT and pretrained.latents.shape == (24, COMPACT.latent_dim)


def test_paper_pretrain_config_runs(tmp_path):
    run_train("--config", str(CONFIGS / "nlb_pretrain.yaml"), "--config", str(CONFIGS / "nlb_pretrain_paper.yaml"),
              "--run_dir", str(tmp_path),
              "--trainer.max_epochs", "1", "--trainer.log_every_n_steps", "1",
              "--data.batches_per_epoch", "2", "--data.val_batches", "1", "--data.num_workers", "0",
              "--data.batch_size", "64", "--data.n_analytic", "8", "--model.n_materials", "8",
              "--data.proxy_dir", "null")
    pretrained = load_pretrained(tmp_path / "checkpoints" / "last.ckpt")
    assert pretrained.network.config == PAPER
    assert math.isfinite(json.loads((tmp_path / "metrics.json").read_text())["fit/val/logcos_rmse"])


def test_pretrain_rejects_a_latent_table_of_the_wrong_size(tmp_path):
    status = train("--config", str(CONFIGS / "nlb_pretrain.yaml"), "--run_dir", str(tmp_path),
                   "--data.n_analytic", "16", "--model.n_materials", "17", "--data.proxy_dir", "null")
    assert status == 2


def latent_run(pretrained_run, tmp_path, sources, *extra):
    run_train("--config", str(CONFIGS / "nlb_latent.yaml"), "--run_dir", str(tmp_path),
              "--model.checkpoint", str(pretrained_run / "checkpoints" / "last.ckpt"),
              "--trainer.max_epochs", "1", "--trainer.check_val_every_n_epoch", "1",
              "--trainer.log_every_n_steps", "1", "--data.steps_per_epoch", "3",
              "--data.sources", json.dumps(sources), *extra)
    return json.loads((tmp_path / "metrics.json").read_text())


@pytest.mark.parametrize(
    "extra, steps",
    [
        (("--trainer.max_epochs", "2"), 6),  # fewer epochs than check_val_every_n_epoch
        (("--trainer.max_epochs", "5", "--trainer.check_val_every_n_epoch", "3"), 15),  # not a multiple
        (("--trainer.max_epochs", "5", "--model.early_stop_patience", "1",  # early stop at step 2
          "--model.early_stop_tolerance", "0.99"), 2),
    ],
    ids=["few-epochs", "uneven-epochs", "early-stop"],
)
def test_latent_fit_checkpoint_is_the_model_its_metrics_describe(pretrained_run, tmp_path, extra, steps):
    """fitted.ckpt always exists and holds the final latents, which the
    last-logged metrics describe (validation follows the last step whatever the epoch count)."""
    module = tiny_module()
    sources = [{"path": str(network_table(module, k, "DS2", tmp_path / f"m{k}.csv"))} for k in (1, 4)]
    run_train("--config", str(CONFIGS / "nlb_latent.yaml"), "--run_dir", str(tmp_path / "run"),
              "--model.checkpoint", str(pretrained_run / "checkpoints" / "last.ckpt"),
              "--trainer.check_val_every_n_epoch", "10", "--data.steps_per_epoch", "3",
              "--data.sources", json.dumps(sources), *extra)
    metrics = json.loads((tmp_path / "run" / "metrics.json").read_text())
    checkpoint = tmp_path / "run" / "checkpoints" / "fitted.ckpt"
    assert torch.load(checkpoint, weights_only=True)["global_step"] == steps
    fitted = load_fitted(checkpoint)
    data = LatentFitData(sources, eval_plan=None)
    data.setup()
    for index, name in enumerate(("m1", "m4")):
        rows = data.train_samples.material == index
        wi, wo, f = (column[rows] for column in data.train_samples[1:])
        with torch.no_grad():
            pred = fitted.network(wi, wo, fitted.latents[name])
        theta_i = torch.rad2deg(torch.acos(wi[:, 2]))
        assert metrics[f"fit/fit_logcos_rmse/{name}"] == pytest.approx(
            float(metrics_module.hemisphere_logcos_rmse(pred, f, theta_i)), rel=1e-5)


@pytest.mark.filterwarnings("ignore:.*negative linear-sRGB value")  # cyan lies partly outside sRGB
def test_latent_config_runs_on_a_shipped_measurement(pretrained_run, tmp_path):
    metrics = latent_run(pretrained_run, tmp_path, [{"virtual": "gold"}, {"virtual": "cyan", "name": "ink"}])
    assert math.isfinite(metrics["fit/fit_logcos_rmse/gold"]) and math.isfinite(metrics["fit/fit_logcos_rmse/ink"])
    # virtual materials have a truth: the fit is scored against it on the evaluation plan
    assert math.isfinite(metrics["fit/plan_logcos_rmse/gold"]) and math.isfinite(metrics["fit/plan_logcos_rmse/ink"])
    fitted = load_fitted(tmp_path / "checkpoints" / "fitted.ckpt")
    pretrained = load_pretrained(pretrained_run / "checkpoints" / "last.ckpt")
    assert sorted(fitted.latents) == ["gold", "ink"]
    for key, value in fitted.network.state_dict().items():
        assert torch.equal(value, pretrained.network.state_dict()[key])
    assert not torch.equal(fitted.latents["gold"], fitted.latents["ink"])


def test_load_fitted_rejects_a_pretraining_checkpoint(pretrained_run):
    with pytest.raises(InputError, match="not a latent-fit checkpoint"):
        load_fitted(pretrained_run / "checkpoints" / "last.ckpt")


@needs_merl
def test_latent_config_evaluates_nbrdf_sources_on_the_low_plan(pretrained_run, tmp_path):
    sources = [{"nbrdf": str(NBRDF / "brass.h5"), "plan": "DS4"}, {"nbrdf": str(NBRDF / "nylon.h5")}]
    metrics = latent_run(pretrained_run, tmp_path, sources, "--data.plan", "DS3", "--data.low2012_abc", str(LOW2012))
    for material in ("brass", "nylon"):
        assert 0 < metrics[f"fit/plan_logcos_rmse/{material}"] < 10
        assert 0 < metrics[f"fit/abc_low2012/plan_logcos_rmse/{material}"] < 0.1
    assert metrics["fit/plan_logcos_rmse/mean"] == pytest.approx(
        (metrics["fit/plan_logcos_rmse/brass"] + metrics["fit/plan_logcos_rmse/nylon"]) / 2)
    # the shared names of docs/evaluate.md#metrics: per material, and their mean under the bare names
    for material in ("brass", "nylon"):
        logged = metrics[f"fit/plan_logcos_rmse/{material}"]
        assert metrics[f"fit/materials/{material}/plan_logcos_rmse"] == pytest.approx(logged, rel=1e-5)
        assert metrics[f"fit/materials/{material}/inplane_glossy_rel_rmse"] > 0
        assert metrics[f"fit/materials/{material}/inplane_diffuse_rel_rmse"] > 0
    assert metrics["fit/plan_logcos_rmse"] == pytest.approx(metrics["fit/plan_logcos_rmse/mean"], rel=1e-5)
    assert not [key for key in metrics if "hemisphere_logcos_rmse" in key]  # evaluate's name, another number


def test_the_latent_config_refuses_a_prior_on_measured_codes_a_network_lacks(pretrained_run, tmp_path, capsys):
    """A prior fitted to measured-material codes on an analytic-only network, which has none:
    exit 2 with the file and the way out."""
    status = train("--config", str(CONFIGS / "nlb_latent.yaml"), "--run_dir", str(tmp_path),
                   "--model.checkpoint", str(pretrained_run / "checkpoints" / "last.ckpt"),
                   "--model.latent_prior_codes", "measured", "--data.sources", json.dumps([{"virtual": "gold"}]))
    assert status == 2
    message = capsys.readouterr().err
    assert "last.ckpt" in message and "latent_prior_codes: all" in message


@pytest.mark.filterwarnings("ignore:.*negative linear-sRGB value")  # cyan lies partly outside sRGB
def test_latent_fit_minibatches_are_seeded_subsets():
    sources = [{"virtual": "gold"}, {"virtual": "cyan"}]
    data = LatentFitData(sources, eval_plan=None, steps_per_epoch=3, batch_size=500)
    data.setup()
    first = list(data.train_dataloader())
    again = LatentFitData(sources, eval_plan=None, steps_per_epoch=3, batch_size=500)
    again.setup()
    for a, b in zip(first, again.train_dataloader()):
        torch.testing.assert_close(a.f, b.f, rtol=0, atol=0)
    assert all(len(batch.f) == 500 for batch in first)
    assert not torch.equal(first[0].wi, first[1].wi)
    assert set(torch.cat([b.material for b in first]).tolist()) == {0, 1}
    with pytest.raises(InputError):
        LatentFitData([{"virtual": "gold"}], batch_size=0)


# ------------------------------------------------------------------------------- latent prior


def test_latent_prior_is_the_codes_gaussian_negative_log_density_per_dimension():
    from scipy.stats import multivariate_normal

    from neuralbrdf.models.latent_prior import COVARIANCE_RIDGE, gaussian_of_codes, latent_prior_penalty

    generator = torch.Generator().manual_seed(3)
    codes = torch.randn(40, 4, generator=generator, dtype=torch.float64) @ torch.tensor(
        [[1.0, 0.3, 0.0, 0.0], [0.0, 0.5, 0.2, 0.0], [0.0, 0.0, 2.0, 0.1], [0.0, 0.0, 0.0, 0.7]], dtype=torch.float64)
    mean, precision = gaussian_of_codes(codes)
    covariance = np.cov(codes.numpy(), rowvar=False) + COVARIANCE_RIDGE * np.eye(4)
    np.testing.assert_allclose(mean.numpy(), codes.numpy().mean(0), rtol=1e-12)
    np.testing.assert_allclose(precision.numpy(), np.linalg.inv(covariance), rtol=1e-9)
    z = torch.randn(3, 2, 4, generator=generator, dtype=torch.float64)
    gaussian = multivariate_normal(codes.numpy().mean(0), covariance)
    expected = (gaussian.logpdf(mean.numpy()) - gaussian.logpdf(z.numpy())) / 4
    np.testing.assert_allclose(latent_prior_penalty(z, mean, precision).numpy(), expected, rtol=1e-9)
    assert float(latent_prior_penalty(mean, mean, precision)) == 0.0
    z.requires_grad_(True)
    assert torch.autograd.gradcheck(lambda x: latent_prior_penalty(x, mean, precision), (z,))
    with pytest.raises(ValueError, match="at least 2 codes"):
        gaussian_of_codes(codes[:1])


#: Names of a tiny network's codes: six of measured materials (more than its 4 latent dimensions).
NAMED = ("analytic:0", *(f"merl:{c}" for c in "abcde"), "merl-blend:0.5*a+0.5*b", "analytic:7")


def _named_checkpoint(tmp_path, names=NAMED):
    module = tiny_module(n_materials=len(names))
    path = tmp_path / "named.ckpt"
    torch.save({"state_dict": module.state_dict(), "hyper_parameters": dict(module.hparams),
                "material_names": list(names)}, path)
    return module, path


def test_latent_prior_enters_each_materials_loss_with_its_weight(tmp_path):
    from neuralbrdf.models.latent_prior import gaussian_of_codes, latent_prior_penalty

    module, checkpoint = _named_checkpoint(tmp_path)
    codes_table = module.latents.latents.detach()
    # two materials on plans of different sizes (DS2 and DS4), each at its own code
    sources = [{"path": str(network_table(module, k, plan, tmp_path / f"m{k}.csv"))} for k, plan in ((0, "DS2"), (7, "DS4"))]
    data = LatentFitData(sources, eval_plan=None)
    data.setup()
    samples = data.train_samples
    counts = torch.bincount(samples.material).double()
    assert counts[0] > 3 * counts[1]
    codes = torch.stack([codes_table[[2, 5]], codes_table[[0, 7]]])  # [S=2 starts, n=2 materials, d]
    plain = LatentFitModule(str(checkpoint))
    for which, prior_codes in (("measured", codes_table[1:7]), ("all", codes_table)):
        fit = LatentFitModule(str(checkpoint), latent_prior_weight=0.2, latent_prior_codes=which)
        for f in (plain, fit):
            f.build_latents(data.material_names)
        penalty = latent_prior_penalty(codes, *gaussian_of_codes(prior_codes))  # [S, n]
        with torch.no_grad():
            difference = fit.material_losses(samples, [codes]) - plain.material_losses(samples, [codes])
        torch.testing.assert_close(difference, 0.2 * penalty, rtol=1e-5, atol=1e-7)  # screening: per material
        # training: every sample carries its material's prior term, so each material's share is
        # (data loss + prior) in proportion to its samples
        with torch.no_grad():
            fit.latents.latents.copy_(codes[0])
        with mock.patch.object(fit, "log"), mock.patch.object(fit, "_track_convergence"):
            loss = fit.training_step(samples, 0)
        data_loss = nlb_loss(fit.predict(samples), samples.f, samples.wi, "log_cosine")
        expected = data_loss + 0.2 * float((penalty[0].double() * counts).sum() / counts.sum())
        torch.testing.assert_close(loss, expected.float(), rtol=1e-5, atol=1e-7)


def test_a_strong_latent_prior_pulls_the_fit_to_the_measured_codes_mean(tmp_path):
    module, checkpoint = _named_checkpoint(tmp_path)
    sources = [{"path": str(network_table(module, k, "DS2", tmp_path / f"m{k}.csv"))} for k in (0, 7)]
    prior_mean = module.latents.latents.detach()[1:7].mean(0)
    fitted = {}
    for weight in (0.0, 1e3):
        data = LatentFitData(sources, eval_plan=None, steps_per_epoch=300)
        fit = LatentFitModule(str(checkpoint), latent_prior_weight=weight, latent_prior_codes="measured",
                              optimizer=lambda p: torch.optim.Adam(p, lr=0.05),
                              lr_scheduler=lambda o: torch.optim.lr_scheduler.ExponentialLR(o, 0.98))
        trainer = pl.Trainer(accelerator="cpu", max_epochs=1, logger=False, enable_checkpointing=False,
                             enable_progress_bar=False, enable_model_summary=False)
        trainer.fit(fit, data)
        fitted[weight] = fit.latents.latents.detach()
    # without the prior each fit finds its own analytic code, with a strong one both sit at the mean
    torch.testing.assert_close(fitted[0.0], module.latents.latents.detach()[[0, 7]], rtol=0, atol=0.05)
    torch.testing.assert_close(fitted[1e3], prior_mean.expand(2, -1), rtol=0, atol=0.01)


def test_bad_latent_prior_settings_raise(tmp_path):
    checkpoint = save_checkpoint(tiny_module(), tmp_path / "unnamed.ckpt")  # no measured codes
    LatentFitModule(str(checkpoint), latent_prior_weight=0.0)  # no prior: no codes needed
    LatentFitModule(str(checkpoint), latent_prior_weight=0.1, latent_prior_codes="all")
    with pytest.raises(InputError, match="latent_prior_codes: all") as error:
        LatentFitModule(str(checkpoint), latent_prior_weight=0.1, latent_prior_codes="measured")
    assert "unnamed.ckpt" in str(error.value)
    for weight in (-0.1, float("nan"), float("inf"), True, "0.1"):
        with pytest.raises(InputError, match="latent_prior_weight"):
            LatentFitModule(str(checkpoint), latent_prior_weight=weight)
    with pytest.raises(InputError, match="latent_prior_codes"):
        LatentFitModule(str(checkpoint), latent_prior_weight=0.1, latent_prior_codes="merl")
    # as many measured codes as latent dimensions: a singular covariance, refused
    _, four = _named_checkpoint(tmp_path, ("analytic:0", "merl:a", "merl:b", "merl:c", "merl:d", "analytic:5"))
    with pytest.raises(InputError, match=r"has 4 codes of measured materials .* in 4 latent dimensions"):
        LatentFitModule(str(four), latent_prior_weight=0.1, latent_prior_codes="measured")
