"""``neuralbrdf plan design``: in-plane pairs chosen with the prior, before anything is measured (docs/how-many-measurements.md).

The designer picks ``budget`` pairs of an :class:`~neuralbrdf.acquisition.instrument.Instrument`
that minimise the expected hemisphere error of a fit from them, averaged over the prior's own
materials: the Bayesian I-optimal greedy design of :mod:`neuralbrdf.acquisition.linear_design`
on a model linearised at each design material.  For the spectral NLB (``kind: nlb_spectral``)
the design materials are codes of the pretrained network's corpus
(:class:`DesignSettings`: every measured proxy's code, and seeded subsets of the blends' and the
analytic materials'), the parameters their shared and R, G, B codes
(:mod:`neuralbrdf.acquisition.nlb_linear`), the prior the corpus codes' Gaussian.  Each value
is measured with a relative noise (``noise``, a fraction of the channel's mean ``ln(1 + f cos
θi)`` over the hemisphere, as the fit's channel-normalised loss counts errors) and the hemisphere
error is relative per channel the same way, so that a dark material counts as much as a bright
one; with ``normalise`` each material's criterion is divided by its prior value, so the design
lowers every material's error by the largest share rather than the largest materials' most.

Only the training side of the prior enters: the codes of materials the network was pretrained
on.  Its result is measured on validation materials the pretraining never saw
(``benchmarks/acquisition.py``).

For the PCA prior (``kind: pca``, Nielsen et al. 2015; :mod:`neuralbrdf.models.pca_brdf`) the fit
is linear — each channel's ``ln(1 + f)`` is ``μ + Φ c`` — so the design is exact rather than
linearised, and one problem serves every material and channel: the Jacobian of a pair is its row
``Φ(p)`` of the basis read at it, the prior the training coefficients' Gaussian ``diag(s²)``, and
the noise variance the fit's own ridge weight (the ridge solution is the MAP estimate of exactly
that model, so the design optimises the fit that is run).  The criterion is the integrated
variance of ``ln(1 + f)`` over the hemisphere pairs; the settings are the ``pca`` config's
(``components``, ``ridge``, ``basis``) and the design section's ``hemisphere_strata`` and ``seed``.

For ABC (``kind: abc``; report §4.1.1 after Löw et al. 2012) the design is the spectral NLB's,
linearised in ABC's parameters (:mod:`neuralbrdf.acquisition.abc_linear`) at each of the shipped
design materials — ABC fits of the training proxies — with the prior their Gaussian, and the same
relative noise, hemisphere errors and normalisation (RGB channels).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch

from neuralbrdf.acquisition.instrument import Instrument
from neuralbrdf.acquisition.linear_design import LinearisedProblem, expected_errors, greedy_design
from neuralbrdf.acquisition.nlb_linear import SpectralNlbLinearisation, code_covariance
from neuralbrdf.errors import InputError

#: Floor (in ``ln(1 + f cos θi)``) of a channel's mean value when it scales noise and errors.
SCALE_FLOOR = 1e-3


@dataclass(frozen=True)
class DesignSettings:
    """How plans are designed (``configs/acquisition/default.yaml``, section ``design``)."""

    noise: float               # relative noise of a measured value (module docstring)
    normalise: bool            # each design material counts by its share of error removed
    blends: int                # pretrained blends among the design materials (all measured proxies are)
    analytic: int              # pretrained analytic materials among them
    hemisphere_strata: tuple[int, int]   # (cos θ, φ) strata of the pairs H averages over
    seed: int                  # which blends and analytic materials; the hemisphere pairs


@dataclass(frozen=True)
class PlanDesign:
    """A designed plan: the pairs in the order to measure them (signed degrees), and the
    predicted relative hemisphere error (root of the mean criterion) before the first pair and
    after each."""

    theta_i: np.ndarray
    theta_r: np.ndarray
    predicted_error: list[float]
    kind: str
    instrument: Instrument


def _check_budget(budget, candidates: int) -> None:
    if not isinstance(budget, int) or isinstance(budget, bool) or not 1 <= budget <= candidates:
        raise InputError(f"expected a number of pairs from 1 to {candidates} (the distinct pairs this instrument "
                         f"can measure), got {budget!r}", key="--budget")


def design_material_rows(names: tuple[str, ...], settings: DesignSettings) -> list[int]:
    """Rows of the pretrained codes the design averages over: every measured material, and
    ``settings.blends`` blends and ``settings.analytic`` analytic materials drawn with ``seed``."""
    from neuralbrdf.data.proxy_corpus import is_blend_code, is_measured_code

    rng = np.random.default_rng(settings.seed)
    measured = [i for i, n in enumerate(names) if is_measured_code(n)]
    blends = [i for i, n in enumerate(names) if is_blend_code(n)]
    analytic = [i for i, n in enumerate(names) if not is_measured_code(n) and not is_blend_code(n)]
    rows = list(measured)
    for pool, count in ((blends, settings.blends), (analytic, settings.analytic)):
        rows += sorted(rng.choice(pool, min(count, len(pool)), replace=False).tolist()) if pool and count else []
    return rows


def relative_problem(linearisation: SpectralNlbLinearisation, thetas: torch.Tensor, candidates_wi: torch.Tensor,
                     candidates_wo: torch.Tensor, hemisphere_wi: torch.Tensor, hemisphere_wo: torch.Tensor,
                     covariance: torch.Tensor, noise: float, normalise: bool) -> LinearisedProblem:
    """The design problem of materials ``thetas`` ``[M, D]`` with relative noise and errors (module docstring)."""
    jacobians, hemispheres = [], []
    for theta in thetas:
        scale = linearisation.values(theta, hemisphere_wi, hemisphere_wo).mean(0).clamp_min(SCALE_FLOOR)  # [K]
        jh = linearisation.jacobians(theta, hemisphere_wi, hemisphere_wo) / scale[None, :, None]
        hemispheres.append(torch.einsum("qki,qkj->ij", jh.double(), jh.double()) / (jh.shape[0] * jh.shape[1]))
        jacobians.append(linearisation.jacobians(theta, candidates_wi, candidates_wo) / (noise * scale[None, :, None]))
    hemisphere = torch.stack(hemispheres)
    prior = covariance.expand(len(thetas), -1, -1).clone()
    if normalise:
        hemisphere = hemisphere / expected_errors(prior, hemisphere)[:, None, None]
    return LinearisedProblem(torch.stack(jacobians), hemisphere, prior)


def _greedy_plan(problem: LinearisedProblem, budget: int, theta_i: np.ndarray, theta_r: np.ndarray, kind: str,
                 instrument: Instrument, progress=None) -> PlanDesign:
    """The :func:`greedy_design` of ``problem`` over the candidates ``theta_i, theta_r`` as a plan."""
    design = greedy_design(problem, budget, progress=progress)
    chosen = np.asarray(design.chosen)
    return PlanDesign(theta_i[chosen], theta_r[chosen], [float(np.sqrt(c)) for c in design.criterion], kind,
                      instrument)


def design_nlb_spectral(budget: int, instrument: Instrument, settings: DesignSettings, checkpoint: str | None = None,
                        progress=None) -> PlanDesign:
    """The spectral NLB's design (module docstring); ``checkpoint``: a pretrained network (default the shipped one)."""
    from neuralbrdf.evaluation.scores import hemisphere_pairs
    from neuralbrdf.geometry import inplane_to_vectors
    from neuralbrdf.lightning.nlb_spectral_module import load_spectral_pretrained
    from neuralbrdf.shipped import SPECTRAL_DEFAULT, resolve_pretrained

    theta_i, theta_r = instrument.candidates()
    _check_budget(budget, len(theta_i))
    pretrained = load_spectral_pretrained(resolve_pretrained(checkpoint, SPECTRAL_DEFAULT))
    rows = design_material_rows(pretrained.names, settings)
    linearisation = SpectralNlbLinearisation(pretrained.network, torch.eye(3))
    thetas = torch.cat([pretrained.shared[rows], pretrained.channels[rows].reshape(len(rows), -1)], dim=1)
    wi, wo = (torch.as_tensor(v, dtype=torch.float32) for v in inplane_to_vectors(theta_i, theta_r))
    hwi, hwo = (torch.as_tensor(v, dtype=torch.float32) for v in hemisphere_pairs(settings.seed,
                                                                                   settings.hemisphere_strata))
    covariance = code_covariance(pretrained.shared, pretrained.channel_codes, 3)
    problem = relative_problem(linearisation, thetas, wi, wo, hwi, hwo, covariance, settings.noise, settings.normalise)
    return _greedy_plan(problem, budget, theta_i, theta_r, "nlb_spectral", instrument, progress)


def design_pca(budget: int, instrument: Instrument, settings: DesignSettings, config: str = "pca",
               progress=None) -> PlanDesign:
    """The PCA prior's design (module docstring), with the settings of the fit config ``config``."""
    from neuralbrdf.evaluation.scores import hemisphere_pairs
    from neuralbrdf.geometry import inplane_to_vectors
    from neuralbrdf.lightning.config_models import model_settings
    from neuralbrdf.lightning.pca_fit import PcaFitModule
    from neuralbrdf.models.pca_brdf import design_matrix

    theta_i, theta_r = instrument.candidates()
    _check_budget(budget, len(theta_i))
    fit = PcaFitModule(**model_settings(config, PcaFitModule))  # the basis and ridge the fit would use, checked
    basis, ridge = fit.basis, float(fit.hparams.ridge)
    if not ridge > 0:
        raise InputError(f"a design needs the fit's noise: a ridge weight > 0, got {ridge!r}", key="model.ridge")
    _, candidates = design_matrix(basis, *inplane_to_vectors(theta_i, theta_r))           # [C, K]
    _, hemisphere = design_matrix(basis, *hemisphere_pairs(settings.seed, settings.hemisphere_strata))
    jacobians = torch.as_tensor(candidates / np.sqrt(ridge), dtype=torch.float64)[None, :, None, :]
    problem = LinearisedProblem(
        jacobians, torch.as_tensor(hemisphere.T @ hemisphere / len(hemisphere), dtype=torch.float64)[None],
        torch.diag(torch.as_tensor(basis.scales, dtype=torch.float64) ** 2)[None])
    return _greedy_plan(problem, budget, theta_i, theta_r, "pca", instrument, progress)


def design_abc(budget: int, instrument: Instrument, settings: DesignSettings, materials: str | None = None,
               progress=None) -> PlanDesign:
    """ABC's design (module docstring); ``materials``: a design-materials file (default the shipped one)."""
    from neuralbrdf.acquisition.abc_linear import DESIGN_MATERIALS, AbcLinearisation, design_thetas, parameter_covariance
    from neuralbrdf.evaluation.scores import hemisphere_pairs
    from neuralbrdf.geometry import inplane_to_vectors

    theta_i, theta_r = instrument.candidates()
    _check_budget(budget, len(theta_i))
    _, thetas = design_thetas(materials or DESIGN_MATERIALS)
    wi, wo = (torch.as_tensor(v, dtype=torch.float64) for v in inplane_to_vectors(theta_i, theta_r))
    hwi, hwo = (torch.as_tensor(v, dtype=torch.float64) for v in hemisphere_pairs(settings.seed,
                                                                                    settings.hemisphere_strata))
    problem = relative_problem(AbcLinearisation(3), thetas, wi, wo, hwi, hwo, parameter_covariance(thetas),
                               settings.noise, settings.normalise)
    return _greedy_plan(problem, budget, theta_i, theta_r, "abc", instrument, progress)


#: The kinds a plan can be designed for, and their designers.
DESIGNERS = {"nlb_spectral": design_nlb_spectral, "abc": design_abc, "pca": design_pca}


def design(kind: str, budget: int, instrument: Instrument, settings: DesignSettings, progress: bool = False) -> PlanDesign:
    """The plan of ``budget`` pairs designed for ``kind`` (:data:`DESIGNERS`), with a progress bar when ``progress``."""
    if kind not in DESIGNERS:
        raise InputError(f"unknown kind {kind!r}; expected one of {', '.join(DESIGNERS)}", key="--kind")
    from neuralbrdf.console import progress as bar

    with bar(total=budget, desc=f"design {kind}", unit="pair", disable=not progress) as pairs:
        return DESIGNERS[kind](budget, instrument, settings, progress=lambda _: pairs.update(1))
