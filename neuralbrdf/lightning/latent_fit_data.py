"""The materials of an NLB latent fit (:mod:`~neuralbrdf.lightning.latent_fit_module`) as batches.

``sources`` lists one material per entry in the vocabulary of every data module
(:mod:`neuralbrdf.sources`):

* ``{path: FILE}`` — a BRDF sample table (docs/formats.md#brdf-sample-table), RGB or spectral (converted to linear
  sRGB, docs/formats.md#spectral-to-linear-srgb), or with ``reference: MUNSELL`` a GCMS raw file and its Munsell N9
  reference (docs/formats.md#gcms-raw-measurement);
* ``{virtual: NAME}`` — a shipped virtual-instrument measurement (``cyan``, ``magenta``,
  ``gold``, ``gonio``) with the shipped reference;
* ``{nbrdf: FILE.h5}`` — an NBRDF proxy (docs/formats.md#nbrdf-proxy) sampled on ``plan`` (the entry's own
  ``plan`` key, else the data module's);
* ``{merl: FILE.binary}`` — a MERL measurement, sampled on ``plan`` likewise;
* ``{rgl: FILE.bsdf}`` — an RGL measurement (spectral from ``NAME_spec.bsdf``, RGB from
  ``NAME_rgb.bsdf``), sampled on ``plan`` likewise.

Each may carry ``name`` (default: the file stem or virtual material), and a ``path`` may carry
``trust_units: true`` (read as it is where its numbers look like a unit slip,
:mod:`neuralbrdf.data.units`).  ``--data.path FILE`` (with ``--data.reference`` and
``--data.trust_units``) drops a single measurement into any latent-fit config.

Values are linear sRGB (spectral tables converted, docs/formats.md#spectral-to-linear-srgb) unless ``spectral`` is set (or
automatic and every source has a spectrum): then every source must be spectral on one wavelength
grid (:attr:`LatentFitData.wavelengths_nm`), which the spectral NLB fits band by band
(:mod:`neuralbrdf.lightning.nlb_spectral_fit`).
"""

from __future__ import annotations

import os
import warnings
from collections.abc import Sequence
from pathlib import Path
from typing import NamedTuple

import numpy as np
import pytorch_lightning as pl
import torch
from torch.utils.data import DataLoader, Dataset

from neuralbrdf.data.low2012 import load_low2012_parameters
from neuralbrdf.data.plans import check_plan
from neuralbrdf.data.table import BrdfTable
from neuralbrdf.errors import InputError
from neuralbrdf.data.units import overridden_by
from neuralbrdf.lightning.common import TRUST_UNITS_OPTION, identity_collate
from neuralbrdf.sources import check_source, load_material, source_name


class FitSamples(NamedTuple):
    """Samples of one or more materials: ``material`` ``[N]`` int64, ``wi, wo`` ``[N, 3]`` and ``f``
    ``[N, C]`` float32 (``C`` = 3 RGB channels, or the wavelength bands of a spectral fit)."""

    material: torch.Tensor
    wi: torch.Tensor
    wo: torch.Tensor
    f: torch.Tensor


class EvalSet(NamedTuple):
    """One material's evaluation: its fitting samples, and (NBRDF) the proxy on the eval plan."""

    name: str
    fit: FitSamples
    truth: FitSamples | None
    abc: torch.Tensor | None  # Löw et al.'s ABC on truth's directions, [N, 3]


def _tensors(index: int, wi, wo, f) -> FitSamples:
    n = len(f)
    return FitSamples(
        torch.full((n,), index, dtype=torch.long),
        *(torch.as_tensor(np.asarray(a), dtype=torch.float32) for a in (wi, wo, f)),
    )


def table_samples(index: int, table: BrdfTable, spectral: bool = False) -> FitSamples:
    """A table's samples as material ``index`` of a fit: band by band when ``spectral``, else in linear sRGB."""
    if not spectral:
        table = table.to_rgb()
    return _tensors(index, *table.vectors(), table.values)


class _Steps(Dataset):
    """One batch per step: all ``samples``, or ``batch_size`` of them, a fresh random subset per
    request from a stream seeded by ``seed`` (reproducible in a single data-loading process)."""

    def __init__(self, samples: FitSamples, steps: int, batch_size: int | None, seed: int) -> None:
        self.samples, self.steps, self.batch_size = samples, steps, batch_size
        self.rng = np.random.default_rng(seed)

    def __len__(self) -> int:
        return self.steps

    def __getitem__(self, index: int) -> FitSamples:
        if not 0 <= index < self.steps:
            raise IndexError(index)
        n = len(self.samples.f)
        if self.batch_size is None or self.batch_size >= n:
            return self.samples
        rows = torch.from_numpy(self.rng.choice(n, self.batch_size, replace=False))
        return FitSamples(*(column[rows] for column in self.samples))


class _Items(Dataset):
    def __init__(self, items: Sequence) -> None:
        self.items = list(items)

    def __len__(self) -> int:
        return len(self.items)

    def __getitem__(self, index):
        return self.items[index]


class LatentFitData(pl.LightningDataModule):
    """Materials to fit, all in one batch (module docstring).

    Parameters
    ----------
    sources:
        One mapping per material, in the vocabulary of :mod:`neuralbrdf.sources`.
    path, reference, trust_units:
        A single measurement to fit instead of ``sources`` (``--data.path FILE`` drops a user's
        BRDF table, or GCMS raw file with its Munsell N9 ``reference``, into any config), read as
        it is with ``trust_units``.
    plan:
        Sampling plan (docs/measure.md#sampling-plans) of NBRDF and MERL sources without their own ``plan``.
    eval_plan:
        Plan on which NBRDF, MERL and virtual sources (which have a truth) are compared with the
        fit; ``None``: no such evaluation.
    low2012_abc:
        Löw et al.'s ABC fits (``abc-low2012/low2012_abc_merl.csv``) to compare with; ``None``
        or a missing file: none (warned, unless the reference data a clone lacks).
    steps_per_epoch:
        Optimisation steps per epoch.
    batch_size:
        ``None`` (default): every step sees every sample of every material (one full batch).
        Else each step sees this many samples drawn at random from all of them: for plans too
        large for full-batch steps, such as five materials on the Löw et al. set (1.15 M pairs).
    batch_values:
        Instead of ``batch_size``: each step sees as many direction pairs as hold this many values
        over the channels (pairs × 3 for RGB, pairs × bands for a spectral fit), so a step costs
        about the same whatever the number of channels.
    full_batch_values:
        Every step sees every sample when they hold at most this many values (pairs × channels),
        whatever ``batch_size`` or ``batch_values`` say: a small fit (one material, a few) is then
        deterministic, which lets the fit optimise it by L-BFGS
        (:mod:`neuralbrdf.lightning.latent_only`); ``None``: no such rule.
    seed:
        Seed of those draws.
    spectral:
        ``True``: keep spectral values (every source a spectral table on one wavelength grid);
        ``False``: convert them to linear sRGB; ``None`` (automatic): spectral when every source
        has a spectrum, else linear sRGB.
    """

    def __init__(
        self,
        sources: list[dict[str, str | bool]] | None = None,
        path: str | None = None,
        reference: str | None = None,
        plan: str = "DS1",
        eval_plan: str | None = "low",
        low2012_abc: str | None = None,
        steps_per_epoch: int = 100,
        batch_size: int | None = None,
        batch_values: int | None = None,
        full_batch_values: int | None = None,
        seed: int = 0,
        spectral: bool | None = False,
        trust_units: bool = False,
    ) -> None:
        super().__init__()
        #: How a unit slip in each source is overridden (:mod:`neuralbrdf.data.units`).
        self._override = [TRUST_UNITS_OPTION]
        if path is not None:
            sources = [{"path": path, **({} if reference is None else {"reference": reference}),
                        **({"trust_units": True} if trust_units else {})}]
        elif reference is not None:
            raise InputError("data.reference goes with a GCMS raw data.path", key="data.reference")
        elif trust_units:
            raise InputError("data.trust_units goes with data.path (in data.sources, a source's own trust_units)",
                             key="data.trust_units")
        if not sources:
            raise InputError("at least one source is needed", key="data.sources")
        plan, eval_plan = (None if value is None else check_plan(value, key)
                           for value, key in ((plan, "data.plan"), (eval_plan, "data.eval_plan")))
        if not isinstance(steps_per_epoch, int) or steps_per_epoch < 1:
            raise InputError(f"must be a positive integer, got {steps_per_epoch!r}", key="data.steps_per_epoch")
        self.sources = [check_source(s, f"data.sources[{i}]") for i, s in enumerate(sources)]
        if path is None:
            self._override = [f"trust_units: true in data.sources[{i}]" for i in range(len(self.sources))]
        self.material_names = [source_name(s) for s in self.sources]
        duplicates = sorted({n for n in self.material_names if self.material_names.count(n) > 1})
        if duplicates:
            raise InputError(
                f"material names must be unique, {duplicates} repeat (set 'name')", key="data.sources"
            )
        if low2012_abc is not None and not os.path.isfile(low2012_abc):  # optional: skipped
            if Path(low2012_abc).parts[:2] != ("..", "shared"):  # the reference data a user may never have: quietly
                warnings.warn(f"data.low2012_abc: {low2012_abc} not found; no comparison with Löw et al.'s ABC fits",
                              stacklevel=2)
            low2012_abc = None
        self.plan, self.eval_plan, self.low2012_abc = plan, eval_plan, low2012_abc
        for key, value in (("batch_size", batch_size), ("batch_values", batch_values),
                           ("full_batch_values", full_batch_values)):
            if value is not None and (not isinstance(value, int) or isinstance(value, bool) or value < 1):
                raise InputError(f"must be a positive integer or null, got {value!r}", key=f"data.{key}")
        if batch_size is not None and batch_values is not None:
            raise InputError("give data.batch_size (pairs) or data.batch_values (values), not both",
                             key="data.batch_values")
        self.steps_per_epoch, self.batch_size, self.seed = steps_per_epoch, batch_size, seed
        self.batch_values, self.full_batch_values = batch_values, full_batch_values
        self.spectral = spectral
        if self.spectral:
            rgb = [name for name, source in zip(self.material_names, self.sources) if "nbrdf" in source]
            if rgb:
                raise InputError(f"NBRDF proxies are RGB and cannot enter a spectral fit: {rgb}; "
                                 "fit them with data.spectral: false", key="data.sources")
        #: The wavelength grid (nm) of a spectral fit, once set up; ``None`` for RGB.
        self.wavelengths_nm: np.ndarray | None = None
        self._steps: _Steps | None = None
        self.train_samples: FitSamples | None = None
        self.eval_sets: list[EvalSet] = []

    def _material(self, index: int, source: dict[str, str]):
        with overridden_by(self._override[index]):
            return load_material(
                path=source.get("path"),
                reference=source.get("reference"),
                nbrdf=source.get("nbrdf"),
                merl=source.get("merl"),
                rgl=source.get("rgl"),
                virtual=source.get("virtual"),
                plan=source.get("plan", self.plan),
                eval_plan=self.eval_plan if "path" not in source else None,
                name=self.material_names[index],
                trust_units=source.get("trust_units", False),
            )

    def _samples(self, index: int, source: dict[str, str], material, abc_fits) -> EvalSet:
        name = self.material_names[index]
        if self.spectral:
            self._check_grid(material.fit, name)
        fit = table_samples(index, material.fit, self.spectral)
        if material.truth is None:
            return EvalSet(name, fit, None, None)
        if self.spectral:
            self._check_grid(material.truth, f"{name} (truth)")
        abc = None
        measured = source.get("nbrdf") or source.get("merl")  # Löw et al. fitted the MERL materials by name
        abc_params = abc_fits.get(Path(measured).stem) if measured else None
        if abc_params is not None:
            abc = torch.as_tensor(abc_params.evaluate(*material.truth.vectors()), dtype=torch.float32)
        return EvalSet(name, fit, table_samples(index, material.truth, self.spectral), abc)

    def _check_grid(self, table: BrdfTable, name: str) -> None:
        """Refuse an RGB table, or a wavelength grid other than the first source's, in a spectral fit."""
        if table.wavelengths is None:
            raise InputError(f"{name} is an RGB table; a spectral fit needs spectral values", path=table.source)
        if self.wavelengths_nm is None:
            self.wavelengths_nm = table.wavelengths.copy()
        elif not np.array_equal(table.wavelengths, self.wavelengths_nm):
            raise InputError(f"{name} is sampled at {table.wavelengths.min():g}..{table.wavelengths.max():g} nm in "
                             f"{table.wavelengths.size} bands, the first source at {self.wavelengths_nm.min():g}.."
                             f"{self.wavelengths_nm.max():g} nm in {self.wavelengths_nm.size}: the materials of one "
                             "spectral fit share a wavelength grid", path=table.source)

    def setup(self, stage: str | None = None) -> None:
        if self.train_samples is not None:
            return
        abc_fits = {} if self.low2012_abc is None else load_low2012_parameters(self.low2012_abc)
        materials = [self._material(i, s) for i, s in enumerate(self.sources)]
        if self.spectral is None:  # automatic: spectral when every measurement has a spectrum
            self.spectral = all(m.fit.wavelengths is not None for m in materials)
        self.eval_sets = [self._samples(i, s, m, abc_fits) for i, (s, m) in enumerate(zip(self.sources, materials))]
        self.train_samples = FitSamples(*(torch.cat(c) for c in zip(*(e.fit for e in self.eval_sets))))

    def _pairs_per_step(self) -> int | None:
        """Direction pairs of each step's batch (``None``: all)."""
        if self.full_batch_values is not None and self.train_samples.f.numel() <= self.full_batch_values:
            return None
        if self.batch_values is not None:  # as many pairs as give that many values over the channels
            return max(self.batch_values // self.train_samples.f.shape[1], 1)
        return self.batch_size

    @property
    def full_batch(self) -> bool:
        """Every step sees every sample (once set up)."""
        pairs = self._pairs_per_step()
        return pairs is None or pairs >= len(self.train_samples.f)

    def train_dataloader(self) -> DataLoader:
        if self._steps is None:  # one stream of random subsets for the whole fit
            self._steps = _Steps(self.train_samples, self.steps_per_epoch, self._pairs_per_step(), self.seed)
        return DataLoader(self._steps, batch_size=None)

    def val_dataloader(self) -> DataLoader:
        return DataLoader(_Items(self.eval_sets), batch_size=None, collate_fn=identity_collate)
