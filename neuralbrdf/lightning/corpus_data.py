"""The NLB pretraining corpus as a Lightning data module (SPEC §4.2; :mod:`neuralbrdf.data.corpus`).

The corpus materials are fixed by ``(n_materials, seed)``; their samples are generated on the
fly, one whole batch per dataset item, never stored.  Batch ``i`` of epoch ``e`` is drawn from
``numpy.random.default_rng([seed, stream, e, i])`` (stream 0 = training, 1 = validation), so a
run is reproducible whatever the number of processes: under DDP Lightning's distributed sampler
hands each process a disjoint set of batch indices.  ``train_dataloader`` reads the epoch from
the trainer, so with ``trainer.reload_dataloaders_every_n_epochs: 1`` every epoch sees fresh
directions; otherwise every epoch repeats epoch 0's samples.  Validation batches are the same in
every epoch: the training materials at directions not trained on.

A batch is a :class:`CorpusSamples` of float32 tensors (``material`` int64).
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import NamedTuple

import numpy as np
import pytorch_lightning as pl
import torch
from torch.utils.data import DataLoader, Dataset

from neuralbrdf.data.corpus import DEFAULT_ARCHETYPE_WEIGHTS, CorpusMaterials, generate_materials, sample_batch
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
    ) -> None:
        self.materials = materials
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
        batch = sample_batch(self.materials, self.batch_size, rng, self.uniform_fraction)
        return CorpusSamples(
            torch.from_numpy(batch.material).long(),
            *(torch.from_numpy(a).float() for a in (batch.wi, batch.wo, batch.f)),
        )


def _positive(name: str, value) -> None:
    if not isinstance(value, int) or isinstance(value, bool) or value < 1:
        raise InputError(f"must be a positive integer, got {value!r}", column=name)


class CorpusDataModule(pl.LightningDataModule):
    """Random analytic materials for NLB pretraining (module docstring).

    Parameters
    ----------
    n_materials:
        Corpus materials (one latent each; must equal the model's ``n_materials``).
    seed:
        Seed of the materials and of every batch.
    archetype_weights:
        Relative probabilities of diffuse, plastic, metal and layered materials.
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
    """

    def __init__(
        self,
        n_materials: int = 1024,
        seed: int = 0,
        archetype_weights: Sequence[float] = DEFAULT_ARCHETYPE_WEIGHTS,
        batch_size: int = 8192,
        batches_per_epoch: int = 500,
        val_batches: int = 8,
        uniform_fraction: float = 0.5,
        num_workers: int = 0,
    ) -> None:
        super().__init__()
        if not isinstance(num_workers, int) or num_workers < 0:
            raise InputError(f"must be a non-negative integer, got {num_workers!r}", column="num_workers")
        for name in ("n_materials", "batch_size", "batches_per_epoch", "val_batches"):
            _positive(name, locals()[name])
        if not 0.0 <= uniform_fraction <= 1.0:
            raise InputError(f"must lie in [0, 1], got {uniform_fraction}", column="uniform_fraction")
        self.save_hyperparameters()
        self.materials = generate_materials(n_materials, seed, tuple(archetype_weights))

    @property
    def n_materials(self) -> int:
        return len(self.materials)

    def _loader(self, n_batches: int, stream: int, epoch: int) -> DataLoader:
        batches = CorpusBatches(
            self.materials, self.hparams.batch_size, n_batches, self.hparams.seed, stream, epoch,
            self.hparams.uniform_fraction,
        )
        return DataLoader(batches, batch_size=None, shuffle=False, num_workers=self.hparams.num_workers)

    def train_dataloader(self) -> DataLoader:
        epoch = self.trainer.current_epoch if self.trainer is not None else 0
        return self._loader(self.hparams.batches_per_epoch, TRAIN_STREAM, epoch)

    def val_dataloader(self) -> DataLoader:
        return self._loader(self.hparams.val_batches, VAL_STREAM, 0)
