"""The NLB pretraining corpus as a Lightning data module (docs/models.md#nlb; :mod:`neuralbrdf.data.corpus`).

The corpus materials are fixed by ``(n_analytic, seed)``; their samples are generated on the
fly, one whole batch per dataset item, never stored.  Batch ``i`` of epoch ``e`` is drawn from
``numpy.random.default_rng([seed, stream, e, i])`` (stream 0 = training, 1 = validation), so a
run is reproducible whatever the number of processes: under DDP Lightning's distributed sampler
hands each process a disjoint set of batch indices.  ``train_dataloader`` reads the epoch from
the trainer, so with ``trainer.reload_dataloaders_every_n_epochs: 1`` every epoch sees fresh
directions; otherwise every epoch repeats epoch 0's samples.  Validation batches are the same in
every epoch: the training materials at directions not trained on.

**Measured proxies** (``proxy_dir``: one folder or a list, one per lab;
:mod:`neuralbrdf.data.proxy_corpus`): a ``proxy_fraction`` of every batch comes from the NBRDF
proxies allowed in pretraining (never a held-out, validation or report material) and, with
``proxy_blends``, their geometric blends within each lab; they are materials
``n_analytic .. n_materials - 1`` of the latent table, after the analytic ones.

A batch is a :class:`CorpusSamples` of float32 tensors (``material`` int64).
"""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence
from typing import NamedTuple

import numpy as np
import pytorch_lightning as pl
import torch
from torch.utils.data import DataLoader, Dataset

from neuralbrdf.data.corpus import DEFAULT_ARCHETYPE_WEIGHTS, CorpusMaterials, generate_materials, sample_batch
from neuralbrdf.data.proxy_corpus import ProxyMaterials, ProxySet, pretraining_proxy_names
from neuralbrdf.errors import InputError

TRAIN_STREAM, VAL_STREAM = 0, 1


class CorpusSamples(NamedTuple):
    """One batch: ``material`` ``[N]`` int64; ``wi, wo`` ``[N, 3]``; ``f`` ``[N, 3]`` RGB in sr⁻¹."""

    material: torch.Tensor
    wi: torch.Tensor
    wo: torch.Tensor
    f: torch.Tensor


class CorpusBatches(Dataset):
    """``n_batches`` batches of ``batch_size`` corpus samples, item ``i`` generated on request."""

    def __init__(
        self,
        materials: CorpusMaterials,
        batch_size: int,
        n_batches: int,
        seed: int,
        stream: int,
        epoch: int = 0,
        uniform_fraction: float = 0.5,
        proxies: ProxySet | None = None,
        proxy_fraction: float = 0.0,
    ) -> None:
        self.materials = materials
        self.proxies = proxies
        self.n_proxy_samples = 0 if proxies is None else int(round(proxy_fraction * batch_size))
        self.batch_size = batch_size
        self.n_batches = n_batches
        self.seed = seed
        self.stream = stream
        self.epoch = epoch
        self.uniform_fraction = uniform_fraction

    def __len__(self) -> int:
        return self.n_batches

    def __getitem__(self, index: int) -> CorpusSamples:
        if not 0 <= index < self.n_batches:
            raise IndexError(index)
        rng = np.random.default_rng([self.seed, self.stream, self.epoch, int(index)])
        batches = [sample_batch(self.materials, self.batch_size - self.n_proxy_samples, rng, self.uniform_fraction)]
        if self.n_proxy_samples:
            proxy = self.proxies.sample_batch(self.n_proxy_samples, rng, self.uniform_fraction)
            batches.append(dataclasses.replace(proxy, material=proxy.material + len(self.materials)))
        return CorpusSamples(
            torch.from_numpy(np.concatenate([b.material for b in batches])).long(),
            *(torch.from_numpy(np.concatenate([getattr(b, k) for b in batches])).float() for k in ("wi", "wo", "f")),
        )


def _whole_number(name: str, value, minimum: int = 1) -> None:
    """Refuse ``value`` unless it is an ``int`` (not a ``bool``) of at least ``minimum`` (1 or 0)."""
    if not isinstance(value, int) or isinstance(value, bool) or value < minimum:
        kind = "positive" if minimum == 1 else "non-negative"
        raise InputError(f"must be a {kind} integer, got {value!r}", key=name)


class CorpusDataModule(pl.LightningDataModule):
    """Random analytic materials for NLB pretraining (module docstring).

    Parameters
    ----------
    n_analytic:
        Analytic corpus materials.  The model's ``n_materials`` (one latent each) is this plus
        the number of pretraining proxies and their blends (:attr:`n_materials` of the module).
    seed:
        Seed of the materials and of every batch.
    archetype_weights:
        Relative probabilities of diffuse, plastic, metal and layered materials.
    thin_film_probability:
        Share of the dielectric lobes under a thin interference film
        (:func:`~neuralbrdf.data.corpus.generate_materials`); 0: none.
    batch_size:
        Samples per training step (materials drawn uniformly per sample).
    batches_per_epoch:
        Training steps per epoch (split between processes under DDP).
    val_batches:
        Validation batches (same each epoch).
    uniform_fraction:
        Share of direction pairs uniform on the hemisphere; the rest follow a specular lobe.
    num_workers:
        DataLoader worker processes generating batches while the model trains (0: generate
        in the training process).
    proxy_dir:
        Folder of NBRDF proxies to mix in (the MERL ones of the reference data, README.md), or a list of folders,
        one per lab (``[…/merl-nbrdf, …/rgl-nbrdf]``); ``None``: the analytic corpus alone.
    proxy_fraction:
        Share of each batch drawn from the proxies (when ``proxy_dir`` is set).
    proxy_blends:
        Blends of two proxies of one lab added as further materials (seeded by ``seed``;
        :class:`~neuralbrdf.data.proxy_corpus.ProxyMaterials`), shared between the labs in
        proportion to their measured materials; 0: the measured proxies alone.
    proxy_blend_fraction:
        Share of the proxy samples drawn from the blends (when there are any).
    """

    def __init__(
        self,
        n_analytic: int = 1024,
        seed: int = 0,
        archetype_weights: Sequence[float] = DEFAULT_ARCHETYPE_WEIGHTS,
        thin_film_probability: float = 0.0,
        batch_size: int = 8192,
        batches_per_epoch: int = 500,
        val_batches: int = 8,
        uniform_fraction: float = 0.5,
        num_workers: int = 0,
        proxy_dir: str | list[str] | None = None,
        proxy_fraction: float = 0.5,
        proxy_blends: int = 0,
        proxy_blend_fraction: float = 0.5,
    ) -> None:
        super().__init__()
        if not isinstance(num_workers, int) or num_workers < 0:
            raise InputError(f"must be a non-negative integer, got {num_workers!r}", key="num_workers")
        for name in ("n_analytic", "batch_size", "batches_per_epoch", "val_batches"):
            _whole_number(name, locals()[name])
        if not 0.0 <= uniform_fraction <= 1.0:
            raise InputError(f"must lie in [0, 1], got {uniform_fraction}", key="uniform_fraction")
        if not 0.0 < proxy_fraction < 1.0:
            raise InputError(f"must lie in (0, 1), got {proxy_fraction}", key="proxy_fraction")
        _whole_number("proxy_blends", proxy_blends, minimum=0)
        if proxy_blends and proxy_dir is None:
            raise InputError("blends are made from measured proxies: set proxy_dir too, or proxy_blends: 0", key="proxy_blends")
        self.save_hyperparameters()
        self.materials = generate_materials(n_analytic, seed, tuple(archetype_weights), thin_film_probability)
        self.proxies = None
        if proxy_dir is not None:
            self.proxies = _proxy_set([proxy_dir] if isinstance(proxy_dir, str) else list(proxy_dir), proxy_blends,
                                      proxy_blend_fraction, seed)

    @property
    def n_materials(self) -> int:
        """Rows of the latent table: the analytic materials, then the proxies."""
        return len(self.materials) + (0 if self.proxies is None else len(self.proxies))

    @property
    def material_names(self) -> tuple[str, ...]:
        """``analytic:<i>`` for the generated materials, then the proxies' names
        (``merl:<name>``, ``merl-blend:…``, ``rgl:<name>``, …; :attr:`ProxyMaterials.material_names`)."""
        proxies = () if self.proxies is None else self.proxies.material_names
        return (*(f"analytic:{i}" for i in range(len(self.materials))), *proxies)

    def _loader(self, n_batches: int, stream: int, epoch: int) -> DataLoader:
        batches = CorpusBatches(
            self.materials, self.hparams.batch_size, n_batches, self.hparams.seed, stream, epoch,
            self.hparams.uniform_fraction, self.proxies, self.hparams.proxy_fraction,
        )
        return DataLoader(batches, batch_size=None, shuffle=False, num_workers=self.hparams.num_workers)

    def train_dataloader(self) -> DataLoader:
        epoch = self.trainer.current_epoch if self.trainer is not None else 0
        return self._loader(self.hparams.batches_per_epoch, TRAIN_STREAM, epoch)

    def val_dataloader(self) -> DataLoader:
        return self._loader(self.hparams.val_batches, VAL_STREAM, 0)


def _proxy_set(folders: list[str], n_blends: int, blend_fraction: float, seed: int) -> ProxySet:
    """One :class:`ProxyMaterials` per folder, the ``n_blends`` blends shared in proportion to the
    folders' pretraining materials (all of them for a single folder)."""
    names = [pretraining_proxy_names(folder) for folder in folders]
    total = sum(len(n) for n in names)
    blends = [n_blends * len(n) // max(total, 1) for n in names]
    blends[0] += n_blends - sum(blends)
    return ProxySet([ProxyMaterials(folder, folder_names, count, blend_fraction, seed)
                     for folder, folder_names, count in zip(folders, names, blends)])
