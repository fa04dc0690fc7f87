"""Measured in-plane spectral BRDF samples for training (report §5.1, Table 5.1; docs/measure.md#sampling-plans, docs/models.md#spectral-mlp).

A measurement — a spectral BRDF table (docs/formats.md#brdf-sample-table) or a GCMS raw file with its Munsell N9
reference (docs/formats.md#gcms-raw-measurement) — becomes one sample per direction pair and wavelength: the triplets
``(theta_i, theta_r, lambda)`` of the report's MLP with the measured BRDF ``f`` (sr⁻¹).

**Signed angles.** Table 5.1 splits by the *signed* incident angle (test ``theta_i`` in {-50,
-35, -20, -5, 10, 25, 40, 55}).  Tables keep that sign (:func:`neuralbrdf.geometry.
inplane_to_spherical` stores the vectors' own azimuths) and
:meth:`~neuralbrdf.data.table.BrdfTable.inplane_angles` decodes it, so GCMS raw files and
tables split alike.  Out-of-plane rows are rejected: the model is trained on in-plane data only.

**Splits** (``test_split``, :data:`TEST_SPLITS`).  Whole incident angles go to the test split,
every ``theta_r`` and wavelength with them:

* ``table_5_1`` — report Table 5.1: test ``theta_i`` in {-50, -35, -20, -5, 10, 25, 40, 55}°,
  train the rest (DS1's 5° grid);
* ``every_third_theta_i`` — every third *measured* incident angle in ascending order, starting
  with the third (:func:`~neuralbrdf.data.plans.every_third_theta_i_split`; Table 5.1 on DS1's
  grid; DS2: test -30°, 15°, 60°; DS3: test 0°);
* ``none`` — no test split: validation and test run on the training data, so the checkpoint is
  chosen on training data and every ``val``/``test`` metric is a training metric.  DS4 (one
  incident angle, six samples) leaves nothing to hold out without losing part of the lobe;
* ``auto`` (default) — ``table_5_1`` when every Table 5.1 test angle was measured (DS1),
  otherwise ``every_third_theta_i`` when at least three incident angles were measured (DS2,
  DS3), otherwise ``none`` (DS4).  :attr:`MeasurementDataModule.resolved_test_split` says which.

``train`` is the training set; ``val`` and ``test`` are both the test set: the report picks
the checkpoint on the test split (§5.1.1, "This helps us choose the best-performing
checkpoint"), so validation runs on it too.  The numbers it reports, and those logged here,
are therefore not from data unseen by model selection.

The whole measurement (DS1: 1001 pairs × 31 wavelengths) is held in memory as tensors; a
training batch is one random index set gathered in a single indexing operation, not a
per-sample collation, and the training loader hands over a whole epoch of them at once
(:class:`EpochOfBatches`): with thousands of steps of a tiny network, the training loop's cost
per item it is given (hooks, optimiser wrapping) was three quarters of the fit.
"""

from __future__ import annotations

import os
from typing import Literal, NamedTuple

import numpy as np
import pytorch_lightning as pl
import torch
from torch.utils.data import BatchSampler, DataLoader, Dataset, RandomSampler, SequentialSampler

from neuralbrdf.sources import load_fit_measurement
from neuralbrdf.data.plans import SPECTRAL_MLP_TEST_THETA_I, every_third_theta_i_split, spectral_mlp_split
from neuralbrdf.data.table import BrdfTable
from neuralbrdf.errors import InputError
from neuralbrdf.data.units import overridden_by
from neuralbrdf.lightning.common import TRUST_UNITS_OPTION, identity_collate
from neuralbrdf.virtual.instrument import default_data_path
from neuralbrdf.virtual.materials import REFERENCE_MATERIAL


#: Test-split rules by config name (module docstring).
TEST_SPLITS = ("auto", "table_5_1", "every_third_theta_i", "none")


def resolve_test_split(rule: str, theta_i_deg: np.ndarray) -> str:
    """The rule ``auto`` stands for given the measured incident angles; other rules unchanged."""
    if rule != "auto":
        return rule
    measured = np.unique(np.round(np.asarray(theta_i_deg, dtype=np.float64), 6))
    if np.isin(np.array(SPECTRAL_MLP_TEST_THETA_I), measured).all():
        return "table_5_1"
    return "every_third_theta_i" if len(measured) >= 3 else "none"


def held_out_mask(rule: str, theta_i_deg: np.ndarray) -> np.ndarray:
    """Boolean ``[N]`` mask of the rows a (resolved) rule puts in the test split."""
    masks = {
        "table_5_1": spectral_mlp_split,
        "every_third_theta_i": every_third_theta_i_split,
        "none": lambda theta_i: np.zeros(len(theta_i), dtype=bool),
    }
    return masks[rule](theta_i_deg)


class SpectralSamples(NamedTuple):
    """Flat spectral samples, all ``[M]``.

    Angles in degrees, wavelength in nm and BRDF in sr⁻¹ are float32; ``pair_index`` (int64) is
    the row of the measurement each sample comes from — two measured rows may share their
    angles (a table's folded mirror twins), so the angles alone do not identify a row.
    """

    theta_i_deg: torch.Tensor
    theta_r_deg: torch.Tensor
    wavelength_nm: torch.Tensor
    brdf: torch.Tensor
    pair_index: torch.Tensor


class InMemorySamples(Dataset):
    """:class:`SpectralSamples` as a dataset indexed by *lists* of sample indices (one batch each)."""

    def __init__(self, samples: SpectralSamples) -> None:
        self.samples = samples

    def __len__(self) -> int:
        return len(self.samples.brdf)

    def __getitem__(self, indices) -> SpectralSamples:
        index = torch.as_tensor(indices, dtype=torch.long)
        return SpectralSamples(*(column[index] for column in self.samples))


class EpochOfBatches(Dataset):
    """One item: every training batch of an epoch, in order, as a list of :class:`SpectralSamples`.

    The index sets come from ``batch_sampler`` when the item is fetched, so each epoch is
    shuffled afresh, with the same random draws as a loader that hands the batches one by one.
    """

    def __init__(self, samples: SpectralSamples, batch_sampler: BatchSampler) -> None:
        self.batches = InMemorySamples(samples)
        self.batch_sampler = batch_sampler

    def __len__(self) -> int:
        return 1

    def __getitem__(self, item: int) -> list[SpectralSamples]:
        return [self.batches[indices] for indices in self.batch_sampler]


def load_inplane_spectral(path, reference=None, trust_units: bool = False) -> tuple[BrdfTable, np.ndarray, np.ndarray]:
    """A spectral measurement and its signed in-plane angles ``(table, theta_i, theta_r)``.

    ``path`` is a spectral BRDF table (spherical or signed in-plane) or a GCMS raw file (then
    ``reference`` is its Munsell N9 file, see :func:`~neuralbrdf.sources.load_fit_measurement`).
    """
    table = load_fit_measurement(path, reference, trust_units)
    if not table.is_spectral:
        raise InputError("is an RGB table; the spectral MLP needs one column per wavelength (nm)", path=path)
    out_of_plane = np.flatnonzero(~table.in_plane_mask())
    if out_of_plane.size:
        row = int(out_of_plane[0])
        raise InputError(
            f"row {row}: out of plane (phi_o - phi_i = {table.phi_o[row] - table.phi_i[row]:g}°); the spectral "
            f"MLP trains on in-plane samples only ({out_of_plane.size} out-of-plane rows)",
            path=path,
        )
    return (table, *table.inplane_angles())


def flatten_samples(table: BrdfTable, theta_i: np.ndarray, theta_r: np.ndarray) -> SpectralSamples:
    """One sample per (row, wavelength), row-major."""
    n_rows, n_wavelengths = table.values.shape
    columns = (
        np.repeat(theta_i, n_wavelengths),
        np.repeat(theta_r, n_wavelengths),
        np.tile(table.wavelengths, n_rows),
        table.values.reshape(-1),
    )
    return SpectralSamples(
        *(torch.as_tensor(c, dtype=torch.float32) for c in columns),
        torch.arange(n_rows).repeat_interleave(n_wavelengths),
    )


class MeasurementDataModule(pl.LightningDataModule):
    """Train/test split (Table 5.1 or another rule) of one spectral in-plane measurement (module docstring).

    Parameters
    ----------
    path:
        Spectral BRDF table or GCMS raw file.  ``None``: the shipped virtual DS1 measurement of
        ``virtual`` with the shipped Munsell N9 reference (the vocabulary of :mod:`neuralbrdf.sources`).
    reference:
        Munsell N9 GCMS raw file for a GCMS raw ``path``; must be ``None`` for a table.
    virtual:
        Shipped stand-in used when ``path`` is ``None``: cyan, magenta, gold or gonio.
    test_split:
        Which incident angles are held out: ``auto`` (default: Table 5.1 on DS1, every third
        measured angle on DS2/DS3, none on DS4), ``table_5_1``, ``every_third_theta_i`` or
        ``none`` (:data:`TEST_SPLITS`, module docstring).
    batch_size:
        Training samples per optimiser step (drawn without replacement, reshuffled every epoch; the
        loader gives an epoch's batches together, :class:`EpochOfBatches`).
    min_steps_per_epoch:
        Least optimiser steps per epoch: a smaller training split is drawn again, reshuffled, until
        the epoch holds this many full batches (a sparse plan otherwise gets a few steps per epoch).
    eval_batch_size:
        Samples per validation/test step, rounded up to whole direction pairs (every wavelength
        of a pair in one batch, so an evaluation cut short by ``limit_val_batches`` or the
        sanity check still scores whole pairs); ``None``: the whole split in one batch.
    num_workers:
        DataLoader worker processes (0: load in the main process; the data is in memory).
    trust_units:
        Read ``path`` as it is even where its numbers look like a unit slip
        (:mod:`neuralbrdf.data.units`).
    """

    def __init__(
        self,
        path: str | None = None,
        reference: str | None = None,
        virtual: str = "gold",
        test_split: Literal[TEST_SPLITS] = "auto",
        batch_size: int = 512,
        eval_batch_size: int | None = None,
        num_workers: int = 0,
        trust_units: bool = False,
        min_steps_per_epoch: int = 1,
    ) -> None:
        super().__init__()
        self.save_hyperparameters()  # recorded in checkpoints: where the model's data came from
        if batch_size < 1 or (eval_batch_size is not None and eval_batch_size < 1):
            raise InputError(f"batch_size and eval_batch_size must be >= 1, got {batch_size} and {eval_batch_size}")
        if isinstance(min_steps_per_epoch, bool) or not isinstance(min_steps_per_epoch, int) or min_steps_per_epoch < 1:
            raise InputError(f"must be a positive integer, got {min_steps_per_epoch!r}", key="data.min_steps_per_epoch")
        if test_split not in TEST_SPLITS:
            raise InputError(f"test_split must be one of {', '.join(TEST_SPLITS)}, got {test_split!r}")
        if path is None:
            path = str(default_data_path(virtual))
            reference = str(default_data_path(REFERENCE_MATERIAL)) if reference is None else reference
        self.path = os.fspath(path)
        self.reference = None if reference is None else os.fspath(reference)
        self.test_split = test_split
        #: The rule applied (``auto`` resolved against the measured angles), set by :meth:`setup`.
        self.resolved_test_split: str | None = None
        self.batch_size = batch_size
        self.min_steps_per_epoch = min_steps_per_epoch
        self.eval_batch_size = eval_batch_size
        self.num_workers = num_workers
        self.trust_units = trust_units
        self._measurement: tuple[BrdfTable, np.ndarray, np.ndarray] | None = None
        self.train_samples: SpectralSamples | None = None
        self.test_samples: SpectralSamples | None = None
        self.n_wavelengths = 0

    def measurement(self) -> tuple[BrdfTable, np.ndarray, np.ndarray]:
        """The table and its signed in-plane angles, read once (:func:`load_inplane_spectral`)."""
        if self._measurement is None:
            with overridden_by(TRUST_UNITS_OPTION):
                self._measurement = load_inplane_spectral(self.path, self.reference, self.trust_units)
        return self._measurement

    def prepare_data(self) -> None:
        # Runs before the trainer creates its log directory: bad input fails before any output.
        self.measurement()

    def setup(self, stage: str | None = None) -> None:
        if self.train_samples is not None:
            return
        table, theta_i, theta_r = self.measurement()
        samples = flatten_samples(table, theta_i, theta_r)
        rule = resolve_test_split(self.test_split, theta_i)
        is_test = torch.as_tensor(np.repeat(held_out_mask(rule, theta_i), len(table.wavelengths)))
        if rule != "none" and (bool(is_test.all()) or not bool(is_test.any())):
            which = "every" if bool(is_test.all()) else "no"
            rules = {
                "table_5_1": f"Table 5.1 test split (test theta_i in "
                f"{', '.join(f'{a:g}' for a in SPECTRAL_MLP_TEST_THETA_I)}°, train: the rest of the 5° grid)",
                "every_third_theta_i": "every_third_theta_i test split (every third measured theta_i from the third)",
            }
            raise InputError(
                f"{which} row falls in the {rules[rule]}; incident angles found: "
                f"{', '.join(f'{a:g}' for a in np.unique(theta_i))}; choose another data.test_split "
                f"({', '.join(TEST_SPLITS)})",
                path=self.path,
            )
        self.resolved_test_split = rule
        self.train_samples = SpectralSamples(*(column[~is_test] for column in samples))
        # No test split: validation (checkpoint choice) and test run on the training data.
        held_out = ~is_test if rule == "none" else is_test
        self.test_samples = SpectralSamples(*(column[held_out] for column in samples))
        self.n_wavelengths = len(table.wavelengths)

    def _loader(self, samples: SpectralSamples, batch_size: int, shuffle: bool) -> DataLoader:
        dataset = InMemorySamples(samples)
        order = RandomSampler(dataset) if shuffle else SequentialSampler(dataset)
        return DataLoader(
            dataset,
            sampler=BatchSampler(order, batch_size, drop_last=False),
            batch_size=None,
            num_workers=self.num_workers,
            persistent_workers=self.num_workers > 0,
        )

    def _eval_loader(self) -> DataLoader:
        size = self.eval_batch_size or len(self.test_samples.brdf)
        whole_pairs = -(-size // self.n_wavelengths) * self.n_wavelengths
        return self._loader(self.test_samples, whole_pairs, shuffle=False)

    def train_dataloader(self) -> DataLoader:
        """One item per epoch: the epoch's shuffled batches of ``batch_size`` (:class:`EpochOfBatches`),
        at least ``min_steps_per_epoch`` of them."""
        dataset = InMemorySamples(self.train_samples)
        if -(-len(dataset) // self.batch_size) < self.min_steps_per_epoch:
            # without replacement, RandomSampler draws successive permutations when asked for more samples than it holds
            order = RandomSampler(dataset, num_samples=self.min_steps_per_epoch * self.batch_size)
        else:
            order = RandomSampler(dataset)
        epoch = EpochOfBatches(self.train_samples, BatchSampler(order, self.batch_size, drop_last=False))
        return DataLoader(epoch, batch_size=None, collate_fn=identity_collate, num_workers=self.num_workers,
                          persistent_workers=self.num_workers > 0)

    def val_dataloader(self) -> DataLoader:
        return self._eval_loader()

    def test_dataloader(self) -> DataLoader:
        return self._eval_loader()
