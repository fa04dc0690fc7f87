"""Latent-only fitting of new materials on a frozen NLB network (docs/models.md#latent-fit-rgb-nlb; report §4.2).

As in Fan et al. (2022) and the report: load the pretrained network
(:func:`~neuralbrdf.lightning.nlb_module.load_pretrained`), freeze every weight, and optimise
only one latent per material with an L1 loss, Adam and an exponentially decaying learning rate
(config ``optimizer``/``lr_scheduler``, stepped every step).  Many materials are fitted at once:
one latent table, every material's samples in one full batch per step (or, for very large
plans, a random subset of ``data.batch_size`` samples per step).

The L1 is taken on ``ln(1 + f cos θi)`` by default (``loss_domain``, as in pretraining,
:mod:`~neuralbrdf.lightning.nlb_module`; it fitted better than the raw L1, (``benchmarks/README.md``, design measurements)).
The report's recipe is ``loss_domain: linear``, ``init_candidates: 0``,
``early_stop_patience: null`` (``configs/nlb_latent_report.yaml``).

**Start** (``init_candidates``).  With 0, every latent starts at the centroid of the
pretrained ones.  Otherwise each material starts from the pretrained code, among the centroid,
every measured proxy code and ``init_candidates`` other codes (evenly spaced in the table), with
the lowest loss on its own fitting samples: a start already near the material, so a few
hundred steps suffice and fits do not end in the centroid's basin.  The code with the lowest
loss *at the start* is not always the one whose basin fits best (measured: from the centroid
some metals ended with a third less in-plane loss), so with ``init_starts`` S > 1 the centroid
and the S − 1 best codes are each optimised for ``init_screen_steps`` steps (the config's
optimiser, all materials and starts at once) and each material continues from the start with
the lowest loss after them (on at most :data:`~neuralbrdf.lightning.latent_only.SCREEN_SAMPLES` samples).  Selection uses
the fitting samples only, never the truth.

**Latent prior** (``latent_prior_weight``, ``latent_prior_codes``).  Each material's loss gets
``latent_prior_weight · P(z)``, the negative log-density per dimension of a Gaussian fitted to
pretrained codes (:mod:`neuralbrdf.models.latent_prior`): a MAP fit that keeps the code among
those the network learned.  ``latent_prior_codes: measured`` fits the Gaussian to the codes of
the measured materials (``merl:``) and their blends (``merl-blend:``,
:mod:`neuralbrdf.data.proxy_corpus`); ``all`` to every code, the analytic corpus included.
Screening and the fit minimise the same loss.  Measured on the held-out MERL materials in
docs/design.md (*The latent prior*).

**Early stopping** (``early_stop_patience``).  The fit stops when the training loss has not
improved by a relative ``early_stop_tolerance`` for that many steps.

**The fit's last step is always evaluated** (:class:`~neuralbrdf.lightning.latent_only.ValidateFinalStep`): validation runs after
the final step (the last epoch, or an early stop) whatever ``check_val_every_n_epoch`` is, so
the metrics logged last — and ``checkpoints/fitted.ckpt``, saved at the end of validation —
describe the latents the fit ends with.

**Sources**: :class:`~neuralbrdf.lightning.latent_fit_data.LatentFitData` (the vocabulary of
:mod:`neuralbrdf.sources`).

**Metrics** (logged at every validation, so ``metrics.json`` holds the final values under
``fit/``):

* ``fit_logcos_rmse/<name>`` — the hemisphere log-cosine RMSE (docs/evaluate.md#metrics) of the fit on the
  material's own fitting samples;
* for NBRDF sources, ``plan_logcos_rmse/<name>`` — the same metric against the proxy on the pairs of
  ``eval_plan`` (default the Löw et al. set, docs/measure.md#sampling-plans): how well the fit generalises;
* and, when ``low2012_abc`` lists the proxy's material, ``abc_low2012/plan_logcos_rmse/<name>``
  — Löw et al.'s published full-data ABC fit (docs/formats.md#löw-et-als-abc-fits) on the same plan, the reference to beat;
* ``plan_logcos_rmse/mean`` over the NBRDF sources.  (Named apart from ``neuralbrdf evaluate``'s
  ``hemisphere_logcos_rmse`` over stratified hemisphere pairs: the same model scores differently.)

The frozen weights are checked bit for bit against the checkpoint at the end of every fit
(:meth:`LatentFitModule.on_fit_end`).  A checkpoint of this module is a self-contained fitted
material set — the network, the latents and their names — read back by :func:`neuralbrdf.kinds.nlb.load_fitted`
(e.g. for export).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import asdict

import numpy as np
import torch
from pytorch_lightning.cli import LRSchedulerCallable, OptimizerCallable

from neuralbrdf.data.proxy_corpus import is_blend_code, is_measured_code
from neuralbrdf.errors import InputError
from neuralbrdf.lightning.common import WritesKind
from neuralbrdf.lightning.latent_fit_data import FitSamples
from neuralbrdf.lightning.latent_only import LatentOnlyFit, check_fit_settings, check_weight
from neuralbrdf.lightning.nlb_module import PretrainedNlb, load_pretrained
from neuralbrdf.losses import check_loss_domain, log_cosine
from neuralbrdf.models.latent_prior import gaussian_of_codes, latent_prior_penalty
from neuralbrdf.models.nlb import LatentTable
from neuralbrdf.shipped import resolve_pretrained

#: How the default checkpoint is made (for the error message when it is missing; docs/models.md,
#: *Shipped RGB networks*).
PRETRAIN_COMMAND = ("python train.py fit --config configs/nlb_pretrain.yaml --model.latent_dim 32 "
                    "--data.proxy_blends 1024 --model.n_materials 5155")

#: Values of ``latent_prior_codes``: the codes the prior's Gaussian is fitted to (module docstring).
PRIOR_CODES = ("measured", "all")


def sample_errors_in(domain: str, pred: torch.Tensor, target: torch.Tensor, cos_i: torch.Tensor) -> torch.Tensor:
    """Absolute errors ``[S, N, C]`` of predictions ``[S, N, C]`` against ``target`` ``[N, C]`` in the
    loss ``domain``: of ``ln(1 + f cos θi)`` (``"log_cosine"``) or of ``f`` (``"linear"``)."""
    if domain == "log_cosine":
        shape = pred.shape
        pred = log_cosine(pred.reshape(-1, shape[-1]), cos_i.repeat(shape[0])).reshape(shape)
        target = log_cosine(target, cos_i)
    return (pred - target).abs()


class LatentFitModule(WritesKind, LatentOnlyFit):
    """Optimises one latent per material on a frozen pretrained NLB network (module docstring).

    Parameters
    ----------
    checkpoint:
        :class:`~neuralbrdf.lightning.nlb_module.NlbPretrainModule` checkpoint, or the name of
        a shipped one (``nlb_compact``, ``nlb_64x4``, …); ``None``: the default
        (:data:`~neuralbrdf.shipped.PRETRAINED_DEFAULT`).
    latent_init:
        Constant every latent starts from; ``None``: the centroid of the pretrained corpus
        latents.
    loss_domain:
        ``"log_cosine"`` (L1 of ``ln(1 + f cos θi)``) or ``"linear"`` (raw L1, as Fan et al.).
    init_candidates:
        Analytic pretrained codes tried as starts besides the centroid and the MERL codes
        (module docstring); 0: start at ``latent_init``.
    init_starts:
        Starts screened per material (module docstring); 1: the best code alone.
    init_screen_steps:
        Optimiser steps of the screening of ``init_starts`` > 1 starts.
    early_stop_patience:
        Steps without a relative loss improvement of ``early_stop_tolerance`` after which
        the fit stops; ``None``: run every step.
    latent_prior_weight:
        Weight of the latent prior ``P(z)`` in each material's loss (module docstring); 0: none
        (this class's default; ``configs/nlb_latent.yaml`` sets 0.01, chosen for the default network).
    latent_prior_codes:
        The pretrained codes the prior's Gaussian is fitted to: ``"measured"`` or ``"all"``.
    optimizer, lr_scheduler:
        Factories from the config; the scheduler steps every step.
    """

    KIND = "nlb"

    def __init__(
        self,
        checkpoint: str | None = None,
        latent_init: float | None = None,
        loss_domain: str = "log_cosine",
        init_candidates: int = 0,
        init_starts: int = 1,
        init_screen_steps: int = 100,
        early_stop_patience: int | None = None,
        early_stop_tolerance: float = 1e-3,
        latent_prior_weight: float = 0.0,
        latent_prior_codes: str = "all",
        optimizer: OptimizerCallable = torch.optim.Adam,
        lr_scheduler: LRSchedulerCallable | None = None,
    ) -> None:
        super().__init__(optimizer, lr_scheduler)
        check_loss_domain(loss_domain, "model.loss_domain")
        check_fit_settings(init_candidates, init_starts, init_screen_steps, early_stop_patience, early_stop_tolerance)
        if init_candidates and latent_init is not None:
            raise InputError("latent_init and init_candidates exclude each other", key="model.init_candidates")
        check_weight(latent_prior_weight, "model.latent_prior_weight")
        if latent_prior_codes not in PRIOR_CODES:
            raise InputError(f"must be one of {', '.join(PRIOR_CODES)}, got {latent_prior_codes!r}",
                             key="model.latent_prior_codes")
        path = resolve_pretrained(checkpoint)
        if checkpoint is None and not path.is_file():
            raise InputError(f"the default pretrained NLB checkpoint is missing; make it with `{PRETRAIN_COMMAND}`, "
                             "save its checkpoints/best.ckpt there with neuralbrdf.lightning.nlb_module.save_pretrained, "
                             "or set model.checkpoint", path=path)
        self.save_hyperparameters(ignore=["optimizer", "lr_scheduler"])
        pretrained = load_pretrained(path)
        self.freeze(pretrained.network)
        start = pretrained.latent_mean
        self._start = start if latent_init is None else torch.full_like(start, latent_init)
        self._candidates = [start_candidates(pretrained, init_candidates)] if init_candidates else None
        self._pretrained_name = path.name
        # Buffers (not saved): they move with the module to the fit's device.
        prior = gaussian_of_codes(prior_codes(pretrained, latent_prior_codes, path)) if latent_prior_weight else (None, None)
        self.register_buffer("_prior_mean", prior[0], persistent=False)
        self.register_buffer("_prior_precision", prior[1], persistent=False)
        self.latents: LatentTable | None = None

    def build_codes(self, names: Sequence[str]) -> None:
        """One latent per material, all at the starting point."""
        self.material_names = list(names)
        self.latents = LatentTable(len(names), self.network.latent_dim, 0.0, names)
        with torch.no_grad():
            self.latents.latents.copy_(self._start.expand(len(names), -1))

    build_latents = build_codes

    def code_parameters(self) -> list[torch.nn.Parameter]:
        return [self.latents.latents]

    def sample_errors(self, samples: FitSamples, codes: list[torch.Tensor]) -> torch.Tensor:
        (latents,) = codes
        n_starts = latents.shape[0]
        pred = self.network(samples.wi.repeat(n_starts, 1), samples.wo.repeat(n_starts, 1),
                            latents[:, samples.material].reshape(-1, latents.shape[-1])).reshape(n_starts, -1, 3)
        return sample_errors_in(self.hparams.loss_domain, pred, samples.f, samples.wi[:, 2]).mean(2)

    def prior_terms(self, codes: list[torch.Tensor]) -> torch.Tensor | float:
        """``latent_prior_weight · P(z)`` of each latent ``[..., d]``: ``[...]`` (0 without a prior)."""
        if self._prior_mean is None:
            return 0.0
        return self.hparams.latent_prior_weight * latent_prior_penalty(codes[0], self._prior_mean,
                                                                       self._prior_precision)

    def on_save_checkpoint(self, checkpoint: dict) -> None:
        super().on_save_checkpoint(checkpoint)
        checkpoint["material_names"] = self.material_names
        checkpoint["pretrained_network"] = self._pretrained_name
        checkpoint["nlb_config"] = asdict(self.network.config)

    def on_load_checkpoint(self, checkpoint: dict) -> None:
        self.build_codes(checkpoint["material_names"])

    def predict(self, samples: FitSamples) -> torch.Tensor:
        return self.network(samples.wi, samples.wo, self.latents(samples.material))


def start_candidates(pretrained: PretrainedNlb, n_analytic: int) -> torch.Tensor:
    """Candidate starting codes ``[K, latent_dim]``: the centroid, every measured proxy code
    (``merl:``, ``rgl:``, …) and ``n_analytic`` of the other codes (analytic, then proxy blends
    where the network was pretrained with them) evenly spaced in the table (module docstring)."""
    measured = [i for i, name in enumerate(pretrained.names) if is_measured_code(name)]
    others = [i for i in range(len(pretrained.latents)) if i not in set(measured)]
    picked = [others[int(j)] for j in np.linspace(0, len(others) - 1, min(n_analytic, len(others)))]
    return torch.cat([pretrained.latent_mean[None], pretrained.latents[measured + picked]])


def prior_codes(pretrained: PretrainedNlb, which: str, path) -> torch.Tensor:
    """The pretrained codes the latent prior is fitted to (module docstring): ``[M, latent_dim]``."""
    codes = pretrained.latents
    if which == "measured":
        codes = codes[[i for i, name in enumerate(pretrained.names) if is_measured_code(name) or is_blend_code(name)]]
    dim = pretrained.latents.shape[1]
    if len(codes) <= dim:  # fewer codes than dimensions + 1: a singular covariance
        kind = "codes of measured materials (names merl:…, merl-blend:…)" if which == "measured" else "codes"
        raise InputError(f"has {len(codes)} {kind} in {dim} latent dimensions; the latent prior's Gaussian needs "
                         f"more than {dim}: set model.latent_prior_codes: all, or model.latent_prior_weight: 0",
                         path=path)
    return codes
