"""Latent-only fit of the spectral NLB to RGB or spectral measurements (docs/models.md#spectral-latent-fit; Fan et al. 2022).

The pretrained spectral NLB (:mod:`neuralbrdf.lightning.nlb_spectral_module`) is frozen; each new
material gets a **shared code** and **channel codes**, fitted latent-only from its samples, all
materials in one batch (:class:`~neuralbrdf.lightning.latent_only.LatentOnlyFit`: starts
screened on the fitting samples, early stopping, the last step evaluated):

* an RGB measurement has three channel codes, one per channel;
* a spectral measurement has channel codes at **wavelength nodes** ``node_step_nm`` apart over
  its range; the code of each measured band is their linear interpolation, so the measurement's
  spectrum reaches the prior band by band and the exported model
  (:class:`~neuralbrdf.models.directional.SpectralNlbWithCodes`) is evaluated at any wavelength.

**Loss.**  Per sample and channel the L1 error of ``ln(1 + f cos θi)`` (``loss_domain``), and with
``channel_normalised`` divided by that channel's mean ``ln(1 + f cos θi)`` over the material's
fitting samples: each channel then counts by its relative error, so a dark channel — the blue of
a dark blue paint, whose absolute errors are tiny — is fitted as carefully as a bright one, which
is what keeps hue where users look.  The mean over channels is a sample's error.

**Priors** (each material's loss gets them, like the RGB fit's latent prior,
:mod:`neuralbrdf.models.latent_prior`): ``shared_prior_weight · P_s(s)`` and
``channel_prior_weight · mean_k P_c(c_k)``, the negative log-densities per dimension of Gaussians
fitted to the pretrained shared and channel codes; and, for a spectral fit, ``smoothness_weight``
times the mean squared second difference of the node codes along wavelength (spectra of real
materials are smooth at the nodes' scale), per dimension.

**Starts** (``init_candidates``): the centroid of the pretrained codes, every measured proxy's
codes and ``init_candidates`` other pretrained materials'.  A pretrained material has RGB
channel codes; at a spectral material's nodes they are interpolated linearly between
:data:`RGB_CODE_WAVELENGTHS_NM`, the dominant wavelengths of the sRGB primaries.

Checkpoints hold the network, its configuration, the codes, the materials' names and the node
wavelengths (``None`` for RGB); :func:`neuralbrdf.kinds.nlb_spectral.load_fitted_spectral` reads
them back.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import asdict

import numpy as np
import torch
from pytorch_lightning.cli import LRSchedulerCallable, OptimizerCallable

from neuralbrdf.data.proxy_corpus import is_measured_code
from neuralbrdf.errors import InputError
from neuralbrdf.lightning.common import WritesKind
from neuralbrdf.lightning.latent_fit_data import FitSamples
from neuralbrdf.lightning.latent_fit_module import sample_errors_in
from neuralbrdf.lightning.latent_only import LatentOnlyFit, check_fit_settings, check_weight
from neuralbrdf.lightning.nlb_spectral_module import PretrainedSpectralNlb, load_spectral_pretrained
from neuralbrdf.losses import check_loss_domain, log_cosine
from neuralbrdf.models.directional import LinearInWavelength
from neuralbrdf.models.latent_prior import gaussian_of_codes, latent_prior_penalty
from neuralbrdf.models.nlb import masked_brdf
from neuralbrdf.models.nlb_spectral import SpectralLatentTable
from neuralbrdf.shipped import SPECTRAL_DEFAULT, resolve_pretrained

#: Wavelengths (nm) at which a pretrained material's B, G, R channel codes stand when its codes
#: start a spectral fit: the dominant wavelengths of the sRGB primaries (IEC 61966-2-1), rounded.
RGB_CODE_WAVELENGTHS_NM = (465.0, 550.0, 610.0)
#: Floor of a channel's mean ``ln(1 + f cos θi)`` when it normalises that channel's errors.
CHANNEL_SCALE_FLOOR = 1e-4
#: Values (pairs × channels) the screening of starts compares at most over all the materials of
#: a large fit (random batches; :meth:`SpectralLatentFitModule.screening_samples`): a batch of many
#: materials screens each on its share, so that screening stays a fraction of the fit.
SCREEN_VALUES = 8192


def wavelength_nodes(wavelengths_nm: np.ndarray, step_nm: float) -> np.ndarray:
    """Nodes at most ``step_nm`` apart, evenly spaced from the first to the last wavelength (nm)."""
    low, high = float(np.min(wavelengths_nm)), float(np.max(wavelengths_nm))
    if high <= low:
        raise InputError(f"a spectral fit needs a wavelength range, got {low:g}..{high:g} nm", key="data")
    return np.linspace(low, high, int(math.ceil((high - low) / step_nm - 1e-9)) + 1)


def interpolation_matrix(nodes_nm, wavelengths_nm) -> torch.Tensor:
    """``[B, K]`` weights of linear interpolation from ``K`` nodes to ``B`` wavelengths (clamped)."""
    return LinearInWavelength(nodes_nm)(torch.as_tensor(np.asarray(wavelengths_nm), dtype=torch.float32))


class SpectralLatentFitModule(WritesKind, LatentOnlyFit):
    """Fits a shared code and channel codes per material on the frozen spectral NLB (module docstring).

    Parameters
    ----------
    checkpoint:
        A :class:`~neuralbrdf.lightning.nlb_spectral_module.SpectralNlbPretrainModule`
        checkpoint, or the name of a shipped one; ``None``: the shipped ``nlb_spectral``.
    node_step_nm:
        Largest spacing (nm) of the wavelength nodes of a spectral fit.
    loss_domain:
        ``"log_cosine"`` or ``"linear"``.
    channel_normalised:
        Divide each channel's errors by its mean ``ln(1 + f cos θi)`` (module docstring).
    init_candidates, init_starts, init_screen_steps, early_stop_patience, early_stop_tolerance:
        Starts and stopping (:mod:`neuralbrdf.lightning.latent_only`).
    init_screen_values:
        Values (pairs × channels) of each material on which the candidates and starts are
        compared, at most (:meth:`screening_samples`); ``None``: all the samples.
    full_batch_iterations:
        When every step sees every sample, the fit is one L-BFGS run of at most this many
        iterations (:mod:`neuralbrdf.lightning.latent_only`); ``None``: the configured optimiser.
    shared_prior_weight, channel_prior_weight, smoothness_weight:
        Weights of the priors (module docstring); 0: none.
    optimizer, lr_scheduler:
        Factories from the config; the scheduler steps every step.
    """

    KIND = "nlb_spectral"

    def __init__(
        self,
        checkpoint: str | None = None,
        node_step_nm: float = 40.0,
        loss_domain: str = "log_cosine",
        channel_normalised: bool = True,
        init_candidates: int = 64,
        init_starts: int = 4,
        init_screen_steps: int = 100,
        init_screen_values: int | None = None,
        full_batch_iterations: int | None = None,
        early_stop_patience: int | None = 50,
        early_stop_tolerance: float = 1e-3,
        shared_prior_weight: float = 0.01,
        channel_prior_weight: float = 0.01,
        smoothness_weight: float = 0.1,
        optimizer: OptimizerCallable = torch.optim.Adam,
        lr_scheduler: LRSchedulerCallable | None = None,
    ) -> None:
        super().__init__(optimizer, lr_scheduler)
        check_loss_domain(loss_domain, "model.loss_domain")
        check_fit_settings(init_candidates, init_starts, init_screen_steps, early_stop_patience, early_stop_tolerance)
        for key, value in (("init_screen_values", init_screen_values), ("full_batch_iterations", full_batch_iterations)):
            if value is not None and (isinstance(value, bool) or not isinstance(value, int) or value < 1):
                raise InputError(f"must be a positive integer or null, got {value!r}", key=f"model.{key}")
        for key in ("shared_prior_weight", "channel_prior_weight", "smoothness_weight"):
            check_weight(locals()[key], f"model.{key}")
        if isinstance(node_step_nm, bool) or not (isinstance(node_step_nm, (int, float)) and node_step_nm > 0
                                                  and math.isfinite(node_step_nm)):
            raise InputError(f"must be a positive number of nm, got {node_step_nm!r}", key="model.node_step_nm")
        path = resolve_pretrained(checkpoint, SPECTRAL_DEFAULT)
        self.save_hyperparameters(ignore=["optimizer", "lr_scheduler"])
        pretrained = load_spectral_pretrained(path)
        self.freeze(pretrained.network)
        self._pretrained = pretrained
        self._pretrained_name = path.name
        self._init_candidates = init_candidates
        shared_prior = gaussian_of_codes(pretrained.shared) if shared_prior_weight else (None, None)
        channel_prior = gaussian_of_codes(pretrained.channel_codes) if channel_prior_weight else (None, None)
        for name, value in (("_shared_mean", shared_prior[0]), ("_shared_precision", shared_prior[1]),
                            ("_channel_mean", channel_prior[0]), ("_channel_precision", channel_prior[1])):
            self.register_buffer(name, value, persistent=False)
        self.node_wavelengths_nm: np.ndarray | None = None
        self.register_buffer("_interpolation", torch.eye(3), persistent=False)
        self.register_buffer("_channel_scale", torch.ones(1, 3), persistent=False)
        self.latents: SpectralLatentTable | None = None

    @property
    def pretrained(self) -> PretrainedSpectralNlb:
        """The frozen pretrained network and its corpus codes (the source of the starts and priors)."""
        return self._pretrained

    # ------------------------------------------------------------------ channels and codes

    def set_channels(self, wavelengths_nm: np.ndarray | None) -> None:
        """RGB channels (``None``) or the measured bands ``wavelengths_nm``: the node grid and the
        interpolation matrix from nodes to channels."""
        if wavelengths_nm is None:
            self.node_wavelengths_nm = None
            self._interpolation = torch.eye(3)
            return
        self.node_wavelengths_nm = wavelength_nodes(wavelengths_nm, self.hparams.node_step_nm)
        self._interpolation = interpolation_matrix(self.node_wavelengths_nm, wavelengths_nm)

    @property
    def n_nodes(self) -> int:
        return self._interpolation.shape[1]

    def screening_samples(self, samples: FitSamples) -> FitSamples:
        """A fixed random subset of each material's fitting samples (every channel) that holds at
        most ``init_screen_values`` values — in a large fit (random batches) at most its share of
        :data:`SCREEN_VALUES` —: the candidates and starts are compared on these."""
        if self.hparams.init_screen_values is None:
            return samples
        n_materials, channels = int(samples.material.max()) + 1, samples.f.shape[1]
        values = self.hparams.init_screen_values
        if not self._full_batch:
            values = min(values, SCREEN_VALUES // n_materials)
        limit = max(values // channels, 1)
        order = torch.randperm(len(samples.f), generator=torch.Generator().manual_seed(0))
        material = samples.material[order]
        rank = torch.zeros_like(material)  # position of each sample among its material's, in random order
        for m in material.unique():
            rows = material == m
            rank[rows] = torch.arange(int(rows.sum()))
        keep = order[rank < limit]
        return FitSamples(*(column[keep] for column in samples))

    def setup(self, stage: str) -> None:
        if not self.material_names:
            data = getattr(self.trainer, "datamodule", None)
            if data is None or not hasattr(data, "material_names"):
                raise InputError("the latent fit needs a LatentFitData data module (data.class_path)", key="data")
            self.set_channels(data.wavelengths_nm)
            self._set_channel_scale(data.train_samples, len(data.material_names))
            if self._init_candidates:
                self._candidates = self.start_candidates()
        super().setup(stage)

    def _set_channel_scale(self, samples: FitSamples, n_materials: int) -> None:
        """Per material and channel, the mean ``ln(1 + f cos θi)`` of its fitting samples (floored)."""
        if not self.hparams.channel_normalised:
            self._channel_scale = torch.ones(n_materials, samples.f.shape[1])
            return
        values = log_cosine(samples.f, samples.wi[:, 2])
        sums = torch.zeros(n_materials, values.shape[1]).index_add_(0, samples.material, values)
        counts = torch.zeros(n_materials).index_add_(0, samples.material, torch.ones(len(values)))
        self._channel_scale = (sums / counts[:, None]).clamp_min(CHANNEL_SCALE_FLOOR)

    def build_codes(self, names: Sequence[str]) -> None:
        """A shared code and node codes per material, at the pretrained codes' centroid."""
        self.material_names = list(names)
        network = self.network
        self.latents = SpectralLatentTable(len(names), network.shared_dim, network.channel_dim, self.n_nodes,
                                           0.0, names)
        with torch.no_grad():
            self.latents.shared.copy_(self._pretrained.shared.mean(0).expand_as(self.latents.shared))
            self.latents.channels.copy_(self._pretrained.channel_codes.mean(0).expand_as(self.latents.channels))

    def start_candidates(self) -> list[torch.Tensor]:
        """Starts ``[shared [K, ds], nodes [K, n_nodes, dc]]``: the centroid, every measured proxy and
        ``init_candidates`` other pretrained materials (module docstring)."""
        pretrained = self._pretrained
        measured = [i for i, name in enumerate(pretrained.names) if is_measured_code(name)]
        others = [i for i in range(len(pretrained.shared)) if i not in set(measured)]
        count = min(self._init_candidates, len(others))
        rows = measured + [others[int(j)] for j in np.linspace(0, len(others) - 1, count)]
        shared = torch.cat([pretrained.shared.mean(0)[None], pretrained.shared[rows]])
        centroid = pretrained.channel_codes.mean(0).expand(1, 3, -1)
        rgb = torch.cat([centroid, pretrained.channels[rows]])  # [K, 3 (R, G, B), dc]
        if self.node_wavelengths_nm is None:
            return [shared, rgb]
        to_nodes = interpolation_matrix(RGB_CODE_WAVELENGTHS_NM, self.node_wavelengths_nm)  # [n_nodes, 3: B, G, R]
        return [shared, torch.einsum("kc,mcd->mkd", to_nodes, rgb.flip(1))]

    def fit_samples(self, names: Sequence[str], samples: FitSamples, wavelengths_nm: np.ndarray | None) -> list[float]:
        """Fit the codes of the materials ``names`` to ``samples`` without a trainer, by the path a
        fit takes when every step sees every sample (:meth:`setup`, then one L-BFGS run per
        material): the codes ``neuralbrdf train fit`` reaches for the same data and settings, in
        one call (``wavelengths_nm``: the bands of a spectral fit, ``None`` for RGB).  Each
        material's final loss."""
        if self.hparams.full_batch_iterations is None:
            raise InputError("a fit without a trainer runs L-BFGS: set model.full_batch_iterations",
                             key="model.full_batch_iterations")
        self.set_channels(wavelengths_nm)
        self._set_channel_scale(samples, len(names))
        if self._init_candidates:
            self._candidates = self.start_candidates()
        self._full_batch = True
        self.build_codes(names)
        if self._candidates is not None:
            self.choose_starts(samples)
        return self.fit_each_by_lbfgs(samples)

    def code_parameters(self) -> list[torch.nn.Parameter]:
        return [self.latents.shared, self.latents.channels]

    # ------------------------------------------------------------------ loss

    def _values(self, samples: FitSamples, shared: torch.Tensor, nodes: torch.Tensor) -> torch.Tensor:
        """Values ``[S, N, C]`` under ``S`` sets of codes ``shared [S, n, ds]``, ``nodes [S, n, K, dc]``.

        The shared code's share of the input layer and the FiLM of each channel code are computed
        once per material and channel, not per sample; one material's are broadcast, not copied."""
        network, (n_starts, n) = self.network, shared.shape[:2]
        wi, wo = samples.wi.repeat(n_starts, 1), samples.wo.repeat(n_starts, 1)
        # row s·n + m of the flattened codes is start s of material m
        index = (samples.material + n * torch.arange(n_starts)[:, None]).reshape(-1)
        pre = network.shared_pre_activation(wi, wo, shared.reshape(-1, shared.shape[-1]), index)
        scale, shift = network.film(torch.einsum("ck,snkd->sncd", self._interpolation, nodes))  # [S, n, C, width]
        if n == 1:  # broadcast [S, 1, C, width] against [S, N, 1, width]: no per-sample copies
            log1p_f = network.decode(pre.reshape(n_starts, len(samples.f), 1, -1), scale, shift)
        else:
            scale, shift = (t.reshape(-1, *t.shape[2:])[index] for t in (scale, shift))
            log1p_f = network.decode(pre[:, None, :], scale, shift)
        pred = masked_brdf(wi, wo, log1p_f.reshape(len(wi), -1))
        return pred.reshape(n_starts, len(samples.f), -1)

    def sample_errors(self, samples: FitSamples, codes: list[torch.Tensor]) -> torch.Tensor:
        errors = sample_errors_in(self.hparams.loss_domain, self._values(samples, *codes), samples.f, samples.wi[:, 2])
        return (errors / self._channel_scale[samples.material]).mean(2)

    def prior_terms(self, codes: list[torch.Tensor]) -> torch.Tensor | float:
        shared, nodes = codes
        terms = 0.0
        if self._shared_mean is not None:
            terms = terms + self.hparams.shared_prior_weight * latent_prior_penalty(
                shared, self._shared_mean, self._shared_precision)
        if self._channel_mean is not None:
            terms = terms + self.hparams.channel_prior_weight * latent_prior_penalty(
                nodes, self._channel_mean, self._channel_precision).mean(-1)
        if self.hparams.smoothness_weight and self.node_wavelengths_nm is not None and nodes.shape[-2] >= 3:
            curvature = nodes[..., :-2, :] - 2.0 * nodes[..., 1:-1, :] + nodes[..., 2:, :]
            terms = terms + self.hparams.smoothness_weight * curvature.square().mean((-2, -1))
        return terms

    def predict(self, samples: FitSamples) -> torch.Tensor:
        return self._values(samples, self.latents.shared[None], self.latents.channels[None])[0]

    # ------------------------------------------------------------------ checkpoints

    def on_save_checkpoint(self, checkpoint: dict) -> None:
        super().on_save_checkpoint(checkpoint)
        checkpoint["material_names"] = self.material_names
        checkpoint["pretrained_network"] = self._pretrained_name
        checkpoint["spectral_nlb_config"] = asdict(self.network.config)
        nodes = self.node_wavelengths_nm
        checkpoint["node_wavelengths_nm"] = None if nodes is None else [float(w) for w in nodes]

    def on_load_checkpoint(self, checkpoint: dict) -> None:
        """Codes of the checkpoint's shape when no data module has set them up (the channels are
        then the nodes themselves)."""
        if self.material_names:
            return
        nodes = checkpoint.get("node_wavelengths_nm")
        self.node_wavelengths_nm = None if nodes is None else np.asarray(nodes, dtype=np.float64)
        self._interpolation = torch.eye(3 if nodes is None else len(nodes))
        self.build_codes(checkpoint["material_names"])
