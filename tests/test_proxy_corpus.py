"""MERL proxies in NLB pretraining (neuralbrdf.data.proxy_corpus): held-out materials never seen."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import torch

from neuralbrdf.data.nbrdf import REPORT_MATERIALS, NbrdfNetwork, available_materials
from neuralbrdf.data.proxy_corpus import (
    HELD_OUT,
    NEVER_PRETRAINED,
    RGL_VALIDATION,
    ProxyMaterials,
    ProxySet,
    is_blend_code,
    is_measured_code,
    pretraining_proxy_names,
    sample_proxy_directions,
)
from neuralbrdf.errors import InputError

MERL = Path(__file__).resolve().parents[2] / "shared" / "data" / "merl-nbrdf"
RGL = MERL.parent / "rgl-nbrdf"
needs_merl = pytest.mark.skipif(not MERL.is_dir(), reason=f"MERL NBRDF proxies not found at {MERL}")
needs_rgl = pytest.mark.skipif(not (MERL.is_dir() and RGL.is_dir()), reason=f"NBRDF proxies not found at {MERL}, {RGL}")


def test_held_out_subset_is_ten_materials_disjoint_from_the_report_materials():
    assert len(HELD_OUT) == len(set(HELD_OUT)) == 10
    assert not set(HELD_OUT) & set(REPORT_MATERIALS)
    assert set(NEVER_PRETRAINED) == set(HELD_OUT) | set(REPORT_MATERIALS) | set(RGL_VALIDATION)
    assert len(RGL_VALIDATION) == len(set(RGL_VALIDATION)) == 9


@needs_merl
def test_pretraining_proxies_exclude_held_out_and_report_materials():
    names = pretraining_proxy_names(MERL)
    assert set(HELD_OUT) <= set(available_materials(MERL))
    assert len(names) == len(available_materials(MERL)) - len(HELD_OUT) - len(REPORT_MATERIALS) == 35
    assert not set(names) & set(NEVER_PRETRAINED)
    with pytest.raises(InputError, match="held out"):
        ProxyMaterials(MERL, (names[0], HELD_OUT[3]))


def test_proxy_directions_are_unit_above_the_horizon_and_cover_mirror_and_grazing():
    rng = np.random.default_rng(1)
    wi, wo = sample_proxy_directions(rng, 20000, uniform_fraction=0.5)
    for w in (wi, wo):
        np.testing.assert_allclose(np.linalg.norm(w, axis=1), 1.0, atol=1e-12)
        assert (w[:, 2] > 0).all()
    mirror = wi * np.array([-1.0, -1.0, 1.0])
    near_mirror = np.degrees(np.arccos(np.clip((wo * mirror).sum(1), -1, 1))) < 2.0
    # Uniform pairs alone put ~0.03 % of wo within 2 degrees of the mirror direction.
    assert near_mirror.mean() > 0.05
    assert (wi[:, 2] < np.cos(np.radians(75))).mean() > 0.2


@needs_merl
def test_proxy_batches_are_the_proxies_values_and_follow_the_analytic_materials():
    from neuralbrdf.lightning.corpus_data import CorpusDataModule

    data = CorpusDataModule(n_analytic=6, batch_size=400, batches_per_epoch=2, val_batches=1,
                            proxy_dir=str(MERL), proxy_fraction=0.25)
    n_proxies = len(pretraining_proxy_names(MERL))
    assert data.n_materials == 6 + n_proxies
    assert data.material_names[6] == f"merl:{pretraining_proxy_names(MERL)[0]}"
    batch = data.train_dataloader().dataset[0]
    proxy_rows = batch.material >= 6
    assert proxy_rows.sum() == 100
    row = int(torch.nonzero(proxy_rows)[0])
    name = pretraining_proxy_names(MERL)[int(batch.material[row]) - 6]
    expected = NbrdfNetwork.load(MERL / f"{name}.h5").evaluate(batch.wi[row : row + 1].double().numpy(),
                                                                batch.wo[row : row + 1].double().numpy())
    np.testing.assert_allclose(batch.f[row].numpy(), expected[0], rtol=1e-5, atol=1e-7)
    again = data.train_dataloader().dataset[0]
    assert torch.equal(again.f, batch.f)


@pytest.mark.parametrize("checkpoint", ["nlb_compact", "nlb_latent32_scratch", "nlb_latent32_blends"])
def test_shipped_checkpoints_never_saw_a_held_out_or_report_material(checkpoint):
    import re

    from neuralbrdf.lightning.nlb_module import load_pretrained
    from neuralbrdf.shipped import resolve_pretrained

    names = load_pretrained(resolve_pretrained(checkpoint)).names
    proxies = {n.removeprefix("merl:") for n in names if n.startswith("merl:")}
    blend_parents = {p for n in names if n.startswith("merl-blend:")
                     for p in re.fullmatch(r"merl-blend:[0-9.]+\*(.+)\+[0-9.]+\*(.+)", n).groups()}
    assert proxies and not (proxies | blend_parents) & set(NEVER_PRETRAINED)
    assert blend_parents <= proxies
    assert (len(blend_parents) > 0) == (checkpoint == "nlb_latent32_blends")


@needs_merl
def test_blends_are_weighted_geometric_means_of_two_distinct_proxies_below_their_linear_mix():
    names = pretraining_proxy_names(MERL)[:4]
    proxies = ProxyMaterials(MERL, names, n_blends=6, seed=3)
    assert len(proxies) == 4 + 6
    assert (proxies.blend_parents[:, 0] != proxies.blend_parents[:, 1]).all()
    assert ((0.2 <= proxies.blend_weights) & (proxies.blend_weights <= 0.8)).all()
    rng = np.random.default_rng(0)
    wi, wo = sample_proxy_directions(rng, 300, uniform_fraction=0.5)
    networks = [NbrdfNetwork.load(MERL / f"{n}.h5") for n in names]
    for blend, ((j, k), a) in enumerate(zip(proxies.blend_parents, proxies.blend_weights)):
        f = proxies.evaluate(np.full(300, 4 + blend), wi, wo)
        fj, fk = networks[j].evaluate(wi, wo), networks[k].evaluate(wi, wo)
        lit = fj > 1e-4
        np.testing.assert_allclose(f[lit & (fk > 1e-4)], (fj ** a * fk ** (1 - a))[lit & (fk > 1e-4)], rtol=1e-9)
        assert (f <= a * fj + (1 - a) * fk + 1e-12).all()
        weight = f"{a:.3f}*{names[j]}+{1 - a:.3f}*{names[k]}"
        assert proxies.material_names[4 + blend] == f"merl-blend:{weight}"
    np.testing.assert_allclose(proxies.evaluate(np.zeros(300, int), wi, wo), networks[0].evaluate(wi, wo), rtol=1e-12)


@needs_merl
def test_blend_batches_take_their_share_of_proxy_samples_with_each_row_its_parents_geometric_mean():
    from neuralbrdf.lightning.corpus_data import CorpusDataModule

    names = pretraining_proxy_names(MERL)
    blended = CorpusDataModule(n_analytic=6, batch_size=4000, batches_per_epoch=1, val_batches=1,
                               proxy_dir=str(MERL), proxy_fraction=0.5, proxy_blends=40, proxy_blend_fraction=0.3)
    assert blended.n_materials == 6 + len(names) + 40 == len(blended.material_names)
    assert blended.material_names[6 + len(names)].startswith("merl-blend:")
    batch = blended.train_dataloader().dataset[0]
    from_blends = (batch.material >= 6 + len(names)).sum() / (batch.material >= 6).sum()
    assert 0.25 < float(from_blends) < 0.35
    assert torch.isfinite(batch.f).all() and (batch.f >= 0).all()
    # Rows of a mixed batch, measured and blended, against their parents evaluated independently.
    (proxies,) = blended.proxies.labs
    rows = [int(torch.nonzero(batch.material == m)[0]) for m in (6, 6 + len(names), 6 + len(names) + 1)]
    for row in rows:
        wi, wo = batch.wi[row : row + 1].double().numpy(), batch.wo[row : row + 1].double().numpy()
        index = int(batch.material[row]) - 6
        if index < len(names):
            expected = NbrdfNetwork.load(MERL / f"{names[index]}.h5").evaluate(wi, wo)
        else:
            (j, k), a = proxies.blend_parents[index - len(names)], proxies.blend_weights[index - len(names)]
            fj, fk = (NbrdfNetwork.load(MERL / f"{names[n]}.h5").evaluate(wi, wo) for n in (j, k))
            expected = np.maximum(fj, 1e-6) ** a * np.maximum(fk, 1e-6) ** (1 - a)
        np.testing.assert_allclose(batch.f[row].numpy(), expected[0], rtol=1e-5, atol=1e-7)


@needs_merl
def test_without_blends_the_proxy_samples_follow_the_unblended_random_stream():
    """Materials, then directions, drawn from the batch's generator after the analytic samples:
    the order the shipped networks were pretrained with."""
    from neuralbrdf.data.corpus import sample_batch
    from neuralbrdf.lightning.corpus_data import CorpusDataModule

    data = CorpusDataModule(n_analytic=6, batch_size=400, batches_per_epoch=1, val_batches=1,
                            proxy_dir=str(MERL), proxy_fraction=0.5, proxy_blends=0)
    batch = data.train_dataloader().dataset[0]
    rng = np.random.default_rng([0, 0, 0, 0])  # seed, training stream, epoch, batch index
    sample_batch(data.materials, 200, rng, 0.5)
    material = rng.integers(0, len(pretraining_proxy_names(MERL)), size=200)
    wi, wo = sample_proxy_directions(rng, 200, 0.5)
    np.testing.assert_array_equal(batch.material[200:].numpy(), material + 6)
    np.testing.assert_allclose(batch.wi[200:].numpy(), wi, rtol=1e-6, atol=1e-7)
    np.testing.assert_allclose(batch.wo[200:].numpy(), wo, rtol=1e-6, atol=1e-7)


@pytest.mark.parametrize("value", [-1, 2.5, True])
def test_proxy_blends_must_be_a_non_negative_integer(value):
    from neuralbrdf.lightning.corpus_data import CorpusDataModule

    with pytest.raises(InputError, match="proxy_blends"):
        CorpusDataModule(n_analytic=6, proxy_blends=value)


def test_proxy_blends_need_the_proxies():
    from neuralbrdf.lightning.corpus_data import CorpusDataModule

    with pytest.raises(InputError, match="proxy_dir"):
        CorpusDataModule(n_analytic=6, proxy_blends=4)


@needs_rgl
def test_rgl_validation_split_is_never_pretrained_and_labs_are_named():
    assert set(RGL_VALIDATION) <= set(available_materials(RGL))
    names = pretraining_proxy_names(RGL)
    assert len(names) == len(available_materials(RGL)) - len(RGL_VALIDATION) == 17
    with pytest.raises(InputError, match="held out"):
        ProxyMaterials(RGL, (names[0], RGL_VALIDATION[0]))
    rgl = ProxyMaterials(RGL, names[:3], n_blends=2)
    assert rgl.material_names[:3] == tuple(f"rgl:{n}" for n in names[:3])
    assert all(is_measured_code(n) for n in rgl.material_names[:3])
    assert all(is_blend_code(n) and not is_measured_code(n) for n in rgl.material_names[3:])
    assert not is_measured_code("analytic:3") and not is_blend_code("analytic:3")


@needs_rgl
def test_batched_proxy_evaluation_equals_each_network_and_labs_share_a_batch():
    """Every network at once (stacked weights) gives what each network's own evaluate gives, at
    and below the horizon; a two-lab batch holds both labs' materials at their own indices."""
    merl = ProxyMaterials(MERL, pretraining_proxy_names(MERL)[:4], n_blends=3, seed=1)
    rgl = ProxyMaterials(RGL, pretraining_proxy_names(RGL)[:3], n_blends=2, seed=1)
    rng = np.random.default_rng(0)
    wi, wo = sample_proxy_directions(rng, 600, 0.5)
    wo[:20, 2] *= -1.0  # below the horizon: exactly 0
    material = rng.integers(0, len(merl.networks), 600)
    expected = np.stack([merl.networks[m].evaluate(wi[i:i + 1], wo[i:i + 1])[0] for i, m in enumerate(material)])
    np.testing.assert_allclose(merl.evaluate(material, wi, wo), expected, rtol=1e-12, atol=1e-15)
    assert (merl.evaluate(material[:20], wi[:20], wo[:20]) == 0).all()
    both = ProxySet([merl, rgl])
    assert len(both) == len(merl) + len(rgl) and both.material_names == merl.material_names + rgl.material_names
    batch = both.sample_batch(3000, np.random.default_rng(2), 0.5)
    from_rgl = batch.material >= len(merl)
    assert 0.2 < from_rgl.mean() < 0.6  # 3 of 7 measured materials
    np.testing.assert_allclose(batch.f[from_rgl], rgl.evaluate(batch.material[from_rgl] - len(merl),
                                                                  batch.wi[from_rgl], batch.wo[from_rgl]))
