"""A material with a truth, measured at any pairs and scored anywhere: the other side of a simulated session (docs/how-many-measurements.md).

``neuralbrdf acquire`` and the benchmarks measure a material whose BRDF is known everywhere —
``virtual:NAME`` (a stand-in or validation material of the virtual instrument), an NBRDF proxy
``NAME.h5``, a MERL ``NAME.binary`` or an RGL ``NAME.bsdf`` — at the pairs a plan asks for, and
score a fit of those measurements against the whole material:

* :meth:`TruthMaterial.measure` — a virtual material through the virtual goniospectrophotometer
  (:func:`~neuralbrdf.sources.virtual_measurement`: sample and Munsell N9 reference each with
  relative noise ``noise``, calibrated; spectral, 400–700 nm), any other through its own reader at
  the pairs (:data:`~neuralbrdf.sources.SAMPLED_SOURCES`) with the instrument's relative noise as
  calibration leaves it, ``f (1 + noise z₁) / (1 + noise z₂)`` per value (``z`` standard normal:
  the sample's and the reference's);
* :meth:`TruthMaterial.hemisphere_error` — ``hemisphere_logcos_rmse`` (docs/evaluate.md#metrics)
  of a model on directions against the truth, where ``neuralbrdf evaluate`` computes it: an RGL
  measurement through Mitsuba's own ``measured`` plugin, the others through their truth modules
  (:func:`~neuralbrdf.evaluation.truth.load_truth`).
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property
from pathlib import Path

import numpy as np

from neuralbrdf.data.plans import Plan
from neuralbrdf.data.table import BrdfTable
from neuralbrdf.errors import InputError
from neuralbrdf.limits import file_problem

VIRTUAL_PREFIX = "virtual:"


@dataclass(frozen=True)
class TruthMaterial:
    """A material known everywhere (module docstring), named by its ``source``."""

    source: str

    def __post_init__(self) -> None:
        from neuralbrdf.sources import SAMPLED_SUFFIXES

        if not (self.source.startswith(VIRTUAL_PREFIX) or Path(self.source).suffix in SAMPLED_SUFFIXES):
            raise InputError(f"expected virtual:NAME, an NBRDF .h5, a MERL .binary or an RGL .bsdf, got "
                             f"{self.source!r}: a measured table is known only where it was measured")
        if self.is_virtual:
            from neuralbrdf.virtual.materials import get_material

            get_material(self.source[len(VIRTUAL_PREFIX):])
        elif not Path(self.source).is_file():
            raise InputError(file_problem(self.source) or "file not found", path=self.source)

    @property
    def is_virtual(self) -> bool:
        return self.source.startswith(VIRTUAL_PREFIX)

    @property
    def name(self) -> str:
        return self.source[len(VIRTUAL_PREFIX):] if self.is_virtual else Path(self.source).stem

    @cached_property
    def _reader(self):
        from neuralbrdf.sources import SAMPLED_SOURCES, SAMPLED_SUFFIXES

        key = SAMPLED_SUFFIXES[Path(self.source).suffix]
        load, sample = SAMPLED_SOURCES[key]
        return load(self.source), sample

    def measure(self, plan: Plan, noise: float, seed: int) -> BrdfTable:
        """The material measured at ``plan``'s pairs with relative ``noise`` (module docstring); the
        sample's noise stream is ``seed``, the reference's ``seed + 1``."""
        if self.is_virtual:
            from neuralbrdf.sources import virtual_measurement

            return virtual_measurement(self.name, plan, noise, seed, seed + 1)
        brdf, sample = self._reader
        table = sample(brdf, plan)
        if noise:
            rng = np.random.default_rng(seed)
            sample_noise = 1.0 + noise * rng.standard_normal(table.values.shape)
            reference_noise = 1.0 + noise * rng.standard_normal(table.values.shape)
            table = BrdfTable(table.theta_i, table.phi_i, table.theta_o, table.phi_o,
                              np.clip(table.values * sample_noise / reference_noise, 0.0, None), table.wavelengths,
                              source=table.source)
        return table

    @cached_property
    def evaluator(self):
        """The truth as :mod:`neuralbrdf.evaluation.scores` evaluates it (module docstring)."""
        from neuralbrdf.evaluation.scores import MemoEvaluator, TorchEvaluator, truth_evaluator
        from neuralbrdf.evaluation.truth import load_truth

        if Path(self.source).suffix == ".bsdf":
            return MemoEvaluator(truth_evaluator(self.source))
        truth = load_truth(self.source)
        return MemoEvaluator(TorchEvaluator(truth.module, truth.is_spectral))

    def hemisphere_error(self, module, is_spectral: bool, strata: tuple[int, int] | None = None) -> float:
        """``hemisphere_logcos_rmse`` of ``module`` (a model on directions) against the truth."""
        from neuralbrdf.evaluation.scores import HEMISPHERE_STRATA, TorchEvaluator, hemisphere_scores

        scores = hemisphere_scores(TorchEvaluator(module, is_spectral), self.evaluator, strata=strata or HEMISPHERE_STRATA)
        return scores["hemisphere_logcos_rmse"]
