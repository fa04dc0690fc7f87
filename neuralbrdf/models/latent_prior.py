"""A Gaussian prior on NLB latent codes, for latent-only fits from few measurements (docs/models.md#latent-fit-rgb-nlb).

An auto-decoder's latent fit finds the code ``z`` that best explains a new material's samples.
From a few in-plane samples many codes explain them equally well, and the fit can wander out of
the region of codes the network was trained on, where its output off the measured plane is
arbitrary.  Park et al. (2019, *DeepSDF*, Eq. 9) regularise the codes with a zero-mean isotropic
Gaussian prior, which makes the fit a MAP estimate.  Here the Gaussian is the one fitted to the
pretrained codes themselves (:func:`gaussian_of_codes`), and the penalty is its negative
log-density per latent dimension, up to a constant (:func:`latent_prior_penalty`)::

    P(z) = ½ (z − μ)ᵀ Σ⁻¹ (z − μ) / d

The latent fit adds ``latent_prior_weight · P(z)`` to each material's data loss
(:mod:`neuralbrdf.lightning.latent_fit_module`).
"""

from __future__ import annotations

import torch

#: Added to the covariance's diagonal, so that it is invertible however few the codes.
COVARIANCE_RIDGE = 1e-6


def gaussian_of_codes(codes: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """Mean ``[d]`` and precision ``[d, d]`` (the inverse of the covariance, with
    :data:`COVARIANCE_RIDGE` on its diagonal) of codes ``[M, d]``, M ≥ 2."""
    if codes.ndim != 2 or len(codes) < 2:
        raise ValueError(f"need at least 2 codes [M, d], got shape {tuple(codes.shape)}")
    d = codes.shape[1]
    covariance = torch.cov(codes.T.double()).reshape(d, d)
    precision = torch.linalg.inv(covariance + COVARIANCE_RIDGE * torch.eye(d, dtype=torch.float64))
    return codes.mean(0), precision.to(codes.dtype)


def latent_prior_penalty(latents: torch.Tensor, mean: torch.Tensor, precision: torch.Tensor) -> torch.Tensor:
    """``½ (z − μ)ᵀ Λ (z − μ) / d`` of each code ``z`` of ``latents`` ``[..., d]``: ``[...]``."""
    offset = latents - mean
    return 0.5 * torch.einsum("...i,ij,...j->...", offset, precision, offset) / latents.shape[-1]
