"""The ABC model linearised in its parameters: the Jacobians and the Gaussian prior that ``plan design --kind abc`` uses (docs/how-many-measurements.md).

An ABC material (report §4.1.1, after Löw et al. 2012; :mod:`neuralbrdf.physics.abc`) is, per
channel ``k``, ``f_k = kd_k/π + A_k F(η) G D(B, C) / (π cos θi cos θo)``.  Its parameters are
taken in the coordinates of the fit (:mod:`neuralbrdf.fitting.abc_fit`):
``θ = [kd_1 … kd_K, ln A_1 … ln A_K, ln(B·C), s = ln(1 + 1/C), ln η]`` — the fit's optimiser
sees the last ``K + 3`` of them; ``kd`` it sets from the smallest measured value, which a plan
informs only through pairs far from the lobe, so the design counts it as a parameter of its own
(linear, since ``kd = 0`` is a common value).  A measurement of channel ``k`` at a pair tells the
value the fit compares, ``y_k = ln(1 + f_k cos θi)`` (``L_cus``, report Eq. 4.2).

:meth:`AbcLinearisation.jacobians` gives ``∂y_k/∂θ`` ``[N, K, D]`` (``D = 2K + 3``, float64) with one
backward pass.  :func:`design_thetas` reads the shipped
design materials (``abc_design_materials.json``: ABC fits of the training proxies on DS1, built
by ``benchmarks/abc_design_materials.py``) and :func:`parameter_covariance` is their Gaussian:
the covariance of ``θ`` over the design materials plus a ridge.
"""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import torch

from neuralbrdf.errors import InputError
from neuralbrdf.physics.abc import abc_brdf_by_sharpness
from neuralbrdf.shipped import PRETRAINED_DIR

#: The shipped design materials (module docstring).
DESIGN_MATERIALS = PRETRAINED_DIR / "abc_design_materials.json"
#: Added to the diagonal of the design materials' covariance (a floor on every parameter's prior variance).
COVARIANCE_RIDGE = 1e-4


class AbcLinearisation:
    """``y(θ; wi, wo)`` ``[N, K]`` and its Jacobian ``[N, K, D]`` for ``channels`` channels (module docstring)."""

    def __init__(self, channels: int) -> None:
        self.channels = channels

    @property
    def dimension(self) -> int:
        return 2 * self.channels + 3

    def _log_cosine(self, theta: torch.Tensor, wi: torch.Tensor, wo: torch.Tensor) -> torch.Tensor:
        k = self.channels
        f = abc_brdf_by_sharpness(wi, wo, theta[:k], torch.exp(theta[k:2 * k]), torch.exp(theta[2 * k]),
                                  torch.expm1(theta[2 * k + 1]), torch.exp(theta[2 * k + 2]))
        return torch.log1p(f * wi[:, 2:3].clamp_min(0.0))

    def values(self, theta: torch.Tensor, wi: torch.Tensor, wo: torch.Tensor) -> torch.Tensor:
        """``y`` ``[N, K]`` at unit directions ``wi, wo`` ``[N, 3]``."""
        with torch.no_grad():
            return self._log_cosine(torch.as_tensor(theta, dtype=torch.float64), wi.double(), wo.double())

    def jacobians(self, theta: torch.Tensor, wi: torch.Tensor, wo: torch.Tensor) -> torch.Tensor:
        """``∂y/∂θ`` ``[N, K, D]`` at unit directions ``wi, wo`` ``[N, 3]``.

        ``f_k = kd_k · d + A_k · ℓ`` with ``d = 1/π`` above the horizon and ``ℓ`` the lobe of unit
        ``A``, which depends only on the three lobe parameters: those get one copy per pair, so
        one backward pass of ``Σ ℓ`` gives every pair's ``∂ℓ/∂(ln(B·C), s, ln η)``; the channel
        parameters follow by the chain rule through ``y_k = ln(1 + f_k cos θi)``."""
        k, n = self.channels, len(wi)
        wi, wo, theta = wi.double(), wo.double(), torch.as_tensor(theta, dtype=torch.float64)
        kd, amplitude = theta[:k], torch.exp(theta[k:2 * k])
        lobe_parameters = theta[2 * k:].expand(n, 3).clone().requires_grad_(True)
        with torch.enable_grad():
            sharpness, tail, eta = torch.exp(lobe_parameters[:, 0]), torch.expm1(lobe_parameters[:, 1]), \
                torch.exp(lobe_parameters[:, 2])
            one = torch.ones(1, dtype=torch.float64)
            lobe = abc_brdf_by_sharpness(wi, wo, 0.0 * one, one, sharpness, tail, eta)[:, 0]       # [N]
            (d_lobe,) = torch.autograd.grad(lobe.sum(), lobe_parameters)                            # [N, 3]
        with torch.no_grad():
            diffuse = abc_brdf_by_sharpness(wi, wo, one, 0.0 * one, 1.0, 0.0, 2.0)[:, 0]            # 1/π above
            cosine = wi[:, 2].clamp_min(0.0)
            f = diffuse[:, None] * kd + lobe.detach()[:, None] * amplitude                          # [N, K]
            dy_df = (cosine[:, None] / (1.0 + f * cosine[:, None]))                                 # [N, K]
            jacobian = torch.zeros(n, k, self.dimension, dtype=torch.float64)
            channel = torch.arange(k)
            jacobian[:, channel, channel] = dy_df * diffuse[:, None]
            jacobian[:, channel, k + channel] = dy_df * amplitude * lobe.detach()[:, None]
            jacobian[:, :, 2 * k:] = (dy_df * amplitude)[:, :, None] * d_lobe[:, None, :]
        return jacobian


def theta_of(kd, A, B: float, C: float, eta: float) -> torch.Tensor:
    """``θ`` ``[2K + 3]`` (module docstring) of ABC parameters."""
    kd, A = np.asarray(kd, dtype=np.float64), np.asarray(A, dtype=np.float64)
    return torch.as_tensor(np.concatenate([kd, np.log(A), [math.log(B * C), math.log1p(1.0 / C), math.log(eta)]]))


def design_thetas(path: str | Path = DESIGN_MATERIALS) -> tuple[tuple[str, ...], torch.Tensor]:
    """Names and ``θ`` ``[M, 9]`` of the design materials (RGB; module docstring)."""
    try:
        entries = json.loads(Path(path).read_text(encoding="utf-8"))["materials"]
        names = tuple(str(e["name"]) for e in entries)
        thetas = torch.stack([theta_of(e["kd"], e["A"], e["B"], e["C"], e["eta"]) for e in entries])
    except (OSError, ValueError, KeyError, TypeError) as error:
        raise InputError(f"is not a file of ABC design materials ({error}); rebuild it with "
                         "python benchmarks/abc_design_materials.py", path=path) from None
    if not len(names) >= 2 or tuple(thetas.shape[1:]) != (9,) or not torch.isfinite(thetas).all():
        raise InputError("expected at least two RGB materials with finite parameters", path=path)
    return names, thetas


def parameter_covariance(thetas: torch.Tensor) -> torch.Tensor:
    """The prior covariance ``[D, D]`` (float64) of ``θ``: over the materials ``thetas`` ``[M, D]``,
    plus :data:`COVARIANCE_RIDGE` on the diagonal."""
    return torch.cov(thetas.double().T) + COVARIANCE_RIDGE * torch.eye(thetas.shape[1], dtype=torch.float64)
