"""One material from any source as a Lightning data module: the ABC fit's data (docs/models.md)."""

from __future__ import annotations

import pytorch_lightning as pl
from torch.utils.data import DataLoader

from neuralbrdf.data.units import overridden_by
from neuralbrdf.lightning.common import TRUST_UNITS_OPTION, identity_collate
from neuralbrdf.sources import MaterialData, load_material


class SingleMaterialData(pl.LightningDataModule):
    """One material from any source (the vocabulary of :mod:`neuralbrdf.sources`).

    With no ``path``, ``nbrdf``, ``merl``, ``rgl`` or ``virtual`` given, the shipped virtual
    ``gold`` DS1 measurement is used.  Every stage sees the same single item: the whole material.

    Parameters
    ----------
    path, reference:
        A BRDF sample table (sr⁻¹), or a GCMS raw file with its Munsell N9 ``reference``.
    nbrdf:
        An NBRDF proxy ``NAME.h5`` (MERL-derived, RGB), sampled on ``plan``.
    merl:
        A MERL measurement ``NAME.binary`` (RGB), sampled on ``plan``.
    rgl:
        An RGL measurement ``NAME_spec.bsdf`` (spectral, 400–700 nm) or ``NAME_rgb.bsdf`` (RGB),
        sampled on ``plan`` through Mitsuba's ``measured`` plugin.
    virtual:
        A shipped virtual stand-in (cyan, magenta, gold, gonio): its DS1 measurement.
    plan:
        Sampling plan of an NBRDF proxy, MERL or RGL measurement: DS1, DS2, DS3, DS4 or low.
    eval_plan:
        Plan on which NBRDF, MERL, RGL and virtual sources are compared with the fit (hemisphere
        log-cosine RMSE); ``None``: no such evaluation.
    name:
        Material name (default: the file stem or the virtual material).
    trust_units:
        Read ``path`` as it is even where its numbers look like a unit slip
        (:mod:`neuralbrdf.data.units`).
    """

    def __init__(
        self,
        path: str | None = None,
        reference: str | None = None,
        nbrdf: str | None = None,
        merl: str | None = None,
        rgl: str | None = None,
        virtual: str | None = None,
        plan: str = "DS1",
        eval_plan: str | None = "low",
        name: str | None = None,
        trust_units: bool = False,
    ) -> None:
        super().__init__()
        self.save_hyperparameters()
        if path is None and nbrdf is None and merl is None and rgl is None and virtual is None:
            virtual = "gold"
        self._kwargs = dict(path=path, reference=reference, nbrdf=nbrdf, merl=merl, rgl=rgl, virtual=virtual,
                            plan=plan, eval_plan=eval_plan, name=name, trust_units=trust_units)
        self.material: MaterialData | None = None

    def prepare_data(self) -> None:
        # before the trainer writes anything: bad input fails with no output
        self.setup()

    def setup(self, stage: str | None = None) -> None:
        if self.material is None:
            with overridden_by(TRUST_UNITS_OPTION):
                self.material = load_material(**self._kwargs)

    def transfer_batch_to_device(self, batch, device, dataloader_idx):
        return batch  # a MaterialData of NumPy tables, used on the CPU as it is

    def _loader(self) -> DataLoader:
        return DataLoader([self.material], batch_size=None, collate_fn=identity_collate)

    train_dataloader = val_dataloader = test_dataloader = _loader
