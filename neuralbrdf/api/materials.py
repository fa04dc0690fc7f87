"""Materials: :func:`read` a table, a GCMS raw file, a proxy, a measurement or a virtual stand-in as a :class:`Source`."""

from __future__ import annotations

import os
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING

from neuralbrdf.api.arguments import PathLike, as_path, check_flags, check_text
from neuralbrdf.errors import InputError

if TYPE_CHECKING:
    from neuralbrdf.data.table import BrdfTable

#: Source kinds with a ground truth everywhere (not only at measured directions).
TRUTH_KINDS = ("nbrdf", "merl", "rgl", "virtual")
VIRTUAL_PREFIX = "virtual:"


@dataclass(frozen=True)
class Source:
    """A material read by :func:`read`: where it comes from and its samples.

    ``kind`` is ``table`` (a BRDF sample table, spherical or signed in-plane), ``gcms`` (a GCMS raw file calibrated
    against its Munsell N9 ``reference``, docs/formats.md#gcms-raw-measurement), ``nbrdf`` (an NBRDF proxy ``.h5``, docs/formats.md#nbrdf-proxy),
    ``merl`` (a MERL ``.binary`` measurement), ``rgl`` (an RGL ``.bsdf`` measurement, docs/formats.md#rgl-measurement-bsdf)
    or ``virtual`` (a stand-in of the virtual goniospectrophotometer,
    docs/measure.md#the-virtual-goniospectrophotometer: its shipped DS1 measurement).
    ``samples`` is the BRDF table a fit sees: the file, the calibrated measurement, or the proxy /
    measured table sampled on ``plan``.
    ``trust_units``: a measurement read as it is although its numbers look like a unit slip
    (:mod:`neuralbrdf.data.units`); a fit of this source reads it so too.
    """

    kind: str
    location: str
    samples: BrdfTable = field(repr=False)
    name: str
    reference: str | None = None
    plan: str | None = None
    trust_units: bool = False

    @property
    def is_spectral(self) -> bool:
        """Whether the samples have one column per wavelength (else linear sRGB)."""
        return self.samples.is_spectral

    @property
    def has_truth(self) -> bool:
        """Whether the material is known everywhere (:func:`truth` can export it), not only at
        its measured directions."""
        return self.kind in TRUTH_KINDS

    def options(self) -> dict[str, str]:
        """The material in the vocabulary of the training configs (``data.*`` keys,
        :mod:`neuralbrdf.sources`)."""
        if self.kind == "virtual":
            return {"virtual": self.location}
        from neuralbrdf.sources import SAMPLED_KEYS

        if self.kind in SAMPLED_KEYS:
            return {self.kind: self.location, "plan": self.plan}
        return {"path": self.location, **({} if self.reference is None else {"reference": self.reference}),
                **({"trust_units": True} if self.trust_units else {})}


def read(source: PathLike, reference: PathLike | None = None, *, plan: str | PathLike | None = None,
         name: str | None = None, trust_units: bool = False) -> Source:
    """Read a material: a BRDF table (spherical or signed in-plane), a GCMS raw file with its
    Munsell N9 ``reference``, an NBRDF proxy ``NAME.h5``, a MERL ``NAME.binary`` or an RGL
    ``NAME.bsdf`` (spectral from a ``NAME_spec.bsdf``, RGB from a ``NAME_rgb.bsdf``; all three
    sampled on ``plan``: DS1 (default) to DS4, ``low``, or a plan file such as
    :func:`design_plan` writes), or ``virtual:NAME`` (``cyan``, ``magenta``, ``gold``,
    ``gonio``: the shipped DS1 measurement).  A measurement whose numbers look like a unit slip
    (angles in radians, wavelengths in µm, ... :mod:`neuralbrdf.data.units`) is refused unless
    ``trust_units``.

    >>> import neuralbrdf as nb
    >>> gold = nb.read("virtual:gold")
    >>> gold.kind, gold.name, gold.is_spectral, gold.samples.n_rows
    ('virtual', 'gold', True, 1001)
    >>> nb.read("virtual:silver")  # doctest: +ELLIPSIS
    Traceback (most recent call last):
    neuralbrdf.errors.InputError: unknown virtual material 'silver'; expected one of munsell_n9, cyan, magenta, gold, gonio, ...
    """
    from neuralbrdf.data.loading import load_measurement
    from neuralbrdf.data.plans import check_plan
    from neuralbrdf.sources import SAMPLED_SUFFIXES, sample_file

    text = os.fspath(as_path(source, "source", "a file path or 'virtual:NAME'"))
    if reference is not None:
        as_path(reference, "reference")
    if plan is not None and not isinstance(plan, (str, os.PathLike)):
        raise InputError(f"plan: expected a plan name or a plan file path, got {type(plan).__name__} {plan!r}")
    check_text("name", name)
    check_flags(trust_units=trust_units)
    suffix = Path(text).suffix
    sampled = not text.startswith(VIRTUAL_PREFIX) and suffix in SAMPLED_SUFFIXES
    if plan is not None and not sampled:
        raise InputError(f"plan {plan!r} applies to NBRDF (.h5), MERL (.binary) and RGL (.bsdf) files, not to {text}")
    if plan is not None:
        plan = check_plan(plan, "plan")
    if reference is not None and (text.startswith(VIRTUAL_PREFIX) or sampled):
        raise InputError(f"a Munsell reference goes with a GCMS raw file, not with {text}")
    if trust_units and (text.startswith(VIRTUAL_PREFIX) or sampled):
        raise InputError(f"trust_units goes with a measurement file, not with {text}")
    if text.startswith(VIRTUAL_PREFIX):
        from neuralbrdf.virtual.instrument import default_data_path
        from neuralbrdf.virtual.materials import REFERENCE_MATERIAL

        material = text[len(VIRTUAL_PREFIX):]
        samples = load_measurement(default_data_path(material), default_data_path(REFERENCE_MATERIAL))
        return Source("virtual", material, samples, name or material)
    if sampled:
        plan = plan or "DS1"
        samples = sample_file(text, plan)
        return Source(SAMPLED_SUFFIXES[suffix], text, samples, name or Path(text).stem, plan=plan)
    samples = load_measurement(text, reference, trust_units)
    return Source("table" if reference is None else "gcms", text, samples, name or Path(text).stem,
                  None if reference is None else os.fspath(reference), trust_units=trust_units)
