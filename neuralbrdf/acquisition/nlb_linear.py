"""The spectral NLB linearised in its codes: the Jacobians and the Gaussian prior that the designer and ``plan next`` use (docs/how-many-measurements.md).

A spectral NLB material (:mod:`neuralbrdf.models.nlb_spectral`) is a shared code ``s`` and node
codes ``c_j``; channel ``k`` (R, G, B, or a measured band) takes the code ``Σ_j W_kj c_j``
(``W`` the interpolation from nodes to channels, the identity for RGB).  Its parameters are
``θ = [s, c_1 … c_n]``, and what a measurement of channel ``k`` at a pair tells about them is the
value the fit compares, ``y_k = ln(1 + f_k cos θi)`` (the loss domain of
:mod:`neuralbrdf.lightning.nlb_spectral_fit`).

:meth:`SpectralNlbLinearisation.jacobians` gives ``∂y_k/∂θ`` at many pairs in one backward pass:
each (pair, channel) gets its own copy of ``s`` and of its channel code, so the gradient of
``Σ y`` with respect to the copies is every row of the Jacobian at once; the node codes' rows
follow from the chain rule through ``W``.

:func:`code_covariance` is the prior over ``θ``: the covariance of the pretrained corpus codes
(:mod:`neuralbrdf.lightning.nlb_spectral_module`), the shared code's block and one channel-code
block per node — the Gaussians whose negative log-densities the fit adds to its loss
(:func:`~neuralbrdf.models.latent_prior.gaussian_of_codes`).
"""

from __future__ import annotations

import torch

from neuralbrdf.models.latent_prior import COVARIANCE_RIDGE
from neuralbrdf.models.nlb import masked_brdf
from neuralbrdf.models.nlb_spectral import SpectralNlbNetwork

#: Pairs per backward pass of :meth:`SpectralNlbLinearisation.jacobians` (bounds its memory).
CHUNK_PAIRS = 4096


class SpectralNlbLinearisation:
    """``y(θ; wi, wo)`` ``[N, K]`` and its Jacobian ``[N, K, D]`` for a frozen ``network`` and the
    interpolation ``weights`` ``[K, n_nodes]`` from node codes to channels (module docstring)."""

    def __init__(self, network: SpectralNlbNetwork, weights: torch.Tensor) -> None:
        self.network = network.requires_grad_(False)
        self.weights = torch.as_tensor(weights, dtype=torch.float32)
        self.shared_dim, self.channel_dim = network.shared_dim, network.channel_dim
        self.n_nodes = self.weights.shape[1]

    @property
    def dimension(self) -> int:
        return self.shared_dim + self.n_nodes * self.channel_dim

    def parameters_of(self, shared: torch.Tensor, nodes: torch.Tensor) -> torch.Tensor:
        """``θ`` ``[D]`` of a shared code ``[ds]`` and node codes ``[n_nodes, dc]``."""
        return torch.cat([torch.as_tensor(shared).reshape(-1), torch.as_tensor(nodes).reshape(-1)]).float()

    def _split(self, theta: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        theta = torch.as_tensor(theta, dtype=torch.float32)
        return theta[: self.shared_dim], theta[self.shared_dim:].reshape(self.n_nodes, self.channel_dim)

    def _log_cosine(self, wi, wo, shared_rows, channel_rows) -> torch.Tensor:
        """``y`` ``[N, K]`` with a shared code and a channel code per (pair, channel) ``[N, K, d]``."""
        n, k = channel_rows.shape[:2]
        pre = self.network.shared_pre_activation(wi.repeat_interleave(k, 0), wo.repeat_interleave(k, 0),
                                                 shared_rows.reshape(n * k, -1))
        scale, shift = self.network.film(channel_rows.reshape(n * k, -1))
        log1p_f = self.network.decode(pre, scale, shift).reshape(n, k)
        f = masked_brdf(wi, wo, log1p_f)
        return torch.log1p(f * wi[:, 2:3].clamp_min(0.0))

    def values(self, theta: torch.Tensor, wi: torch.Tensor, wo: torch.Tensor) -> torch.Tensor:
        """``y`` ``[N, K]`` at unit directions ``wi, wo`` ``[N, 3]``."""
        shared, nodes = self._split(theta)
        channels = self.weights @ nodes                                           # [K, dc]
        out = []
        with torch.no_grad():
            for start in range(0, len(wi), CHUNK_PAIRS):
                w1, w2 = wi[start:start + CHUNK_PAIRS].float(), wo[start:start + CHUNK_PAIRS].float()
                n = len(w1)
                out.append(self._log_cosine(w1, w2, shared.expand(n, len(channels), -1),
                                            channels.expand(n, -1, -1)))
        return torch.cat(out)

    def jacobians(self, theta: torch.Tensor, wi: torch.Tensor, wo: torch.Tensor) -> torch.Tensor:
        """``∂y/∂θ`` ``[N, K, D]`` at unit directions ``wi, wo`` ``[N, 3]`` (module docstring)."""
        shared, nodes = self._split(theta)
        channels = self.weights @ nodes
        k = len(channels)
        out = []
        for start in range(0, len(wi), CHUNK_PAIRS):
            w1, w2 = wi[start:start + CHUNK_PAIRS].float(), wo[start:start + CHUNK_PAIRS].float()
            n = len(w1)
            shared_rows = shared.expand(n, k, -1).clone().requires_grad_(True)
            channel_rows = channels.expand(n, -1, -1).clone().requires_grad_(True)
            with torch.enable_grad():
                y = self._log_cosine(w1, w2, shared_rows, channel_rows)
                d_shared, d_channel = torch.autograd.grad(y.sum(), (shared_rows, channel_rows))
            d_nodes = torch.einsum("kj,nkd->nkjd", self.weights, d_channel).reshape(n, k, -1)
            out.append(torch.cat([d_shared, d_nodes], dim=-1))
        return torch.cat(out)


def code_covariance(shared_codes: torch.Tensor, channel_codes: torch.Tensor, n_nodes: int) -> torch.Tensor:
    """The prior covariance ``[D, D]`` (float64) of ``θ`` (module docstring) from the corpus's
    shared codes ``[M, ds]`` and channel codes ``[M', dc]``: block-diagonal, the shared block then
    ``n_nodes`` channel blocks, each with :data:`COVARIANCE_RIDGE` on its diagonal."""
    blocks = [torch.cov(shared_codes.double().T)] + [torch.cov(channel_codes.double().T)] * n_nodes
    covariance = torch.block_diag(*blocks)
    return covariance + COVARIANCE_RIDGE * torch.eye(len(covariance), dtype=torch.float64)
