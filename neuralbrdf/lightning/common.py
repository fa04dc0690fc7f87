"""What the Lightning modules share: the optimiser factory, the kind written into checkpoints,
the collate function of data modules whose batches are whole materials, the option that reads
a measurement whose numbers look like a unit slip as it is, and a fitted model read at a table's pairs."""

from __future__ import annotations

from typing import TYPE_CHECKING

from neuralbrdf.kinds import CHECKPOINT_KIND_KEY

if TYPE_CHECKING:
    import numpy as np
    from torch import nn

    from neuralbrdf.data.table import BrdfTable

#: How a fit reads its ``data.path`` as it is (:mod:`neuralbrdf.data.units`): every data module
#: that reads a measurement takes ``trust_units``.
TRUST_UNITS_OPTION = "--data.trust_units true"


def scheduled_optimizer(groups, optimizer, lr_scheduler, interval: str):
    """Optimiser over parameter ``groups`` ``[(parameters, lr_scale), ...]`` and its scheduler.

    ``optimizer`` and ``lr_scheduler`` are the config's factories; each group's learning rate is
    the configured one times its ``lr_scale``.  The scheduler steps every ``interval``.
    """
    opt = optimizer([{"params": list(params)} for params, _ in groups])
    for group, (_, scale) in zip(opt.param_groups, groups):
        group["lr"] *= scale
    if lr_scheduler is None:
        return opt
    return {"optimizer": opt, "lr_scheduler": {"scheduler": lr_scheduler(opt), "interval": interval}}


class WritesKind:
    """Mixin for a LightningModule of a fitted model: its checkpoints name their kind.

    ``KIND`` is a registered :mod:`neuralbrdf.kinds` name; the exporter reads it back
    (:func:`neuralbrdf.kinds.checkpoint_kind`).  Subclasses overriding ``on_save_checkpoint``
    call ``super().on_save_checkpoint(checkpoint)``.
    """

    KIND: str

    def on_save_checkpoint(self, checkpoint: dict) -> None:
        checkpoint[CHECKPOINT_KIND_KEY] = self.KIND


def identity_collate(item):
    """A DataLoader ``collate_fn`` that hands over each item as it is (one material per batch)."""
    return item


def values_at_table(model: nn.Module, table: BrdfTable, spectral: bool) -> np.ndarray:
    """A model on directions (``model(wi, wo[, wavelength])``, sr⁻¹) at ``table``'s pairs ``[N, C]``,
    float64: at the table's bands when ``spectral``, else its RGB output."""
    import torch

    wi, wo = (torch.as_tensor(v, dtype=torch.float32) for v in table.vectors())
    with torch.no_grad():
        if not spectral:
            return model(wi, wo).double().numpy()
        bands = torch.as_tensor(table.wavelengths, dtype=torch.float32)
        n, k = len(wi), len(bands)
        values = model(wi.repeat_interleave(k, 0), wo.repeat_interleave(k, 0), bands.repeat(n))
        return values.reshape(n, k).double().numpy()
