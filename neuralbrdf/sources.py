"""A material to fit, from any source a user has (SPEC §4.3: "any plan, any source").

The one vocabulary of every data module and config (``data.*`` keys, and the entries of a
latent fit's ``data.sources``).  One material comes from exactly one of:

* ``path`` — the user's measurement: a BRDF sample table (SPEC §2.1) or a GCMS raw file with
  its Munsell N9 ``reference`` (SPEC §2.2);
* ``nbrdf`` — a MERL-proxy NBRDF network (SPEC §2.4) sampled on ``plan``;
* ``merl`` — a MERL ``.binary`` measurement (:mod:`neuralbrdf.data.merl_binary`) sampled on
  ``plan`` (nearest cell, RGB);
* ``rgl`` — an RGL material database ``.bsdf`` measurement (:mod:`neuralbrdf.data.rgl_bsdf`)
  sampled on ``plan`` through Mitsuba's ``measured`` plugin (spectral at 400–700 nm from a
  ``NAME_spec.bsdf``, RGB from a ``NAME_rgb.bsdf``);
* ``virtual`` — a stand-in of the virtual goniospectrophotometer (SPEC §2.5): its shipped DS1
  measurement, calibrated against the shipped Munsell N9 reference.

with optional ``name`` (default: the file stem or the virtual material) and, for ``nbrdf``,
``merl`` and ``rgl``, ``plan``.  Proxies, measured files and virtual materials are defined
everywhere, so they also give a dense ``truth`` on
``eval_plan`` (default the Löw et al. set) for the hemisphere log-cosine RMSE (SPEC §5); a
user's measurement has none.
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path

from neuralbrdf.data.loading import load_measurement
from neuralbrdf.data.merl_binary import MerlBrdf, sample_merl
from neuralbrdf.data.nbrdf import NbrdfNetwork, sample_plan
from neuralbrdf.data.rgl_bsdf import SUFFIX as RGL_SUFFIX
from neuralbrdf.data.rgl_bsdf import RglBsdf, sample_rgl
from neuralbrdf.data.plans import PLAN_NAMES, plan_spherical
from neuralbrdf.data.table import BrdfTable
from neuralbrdf.errors import InputError
from neuralbrdf.geometry import spherical_pair_to_vectors
from neuralbrdf.virtual.instrument import GROUND_TRUTH_WAVELENGTHS_NM, default_data_path
from neuralbrdf.virtual.materials import REFERENCE_MATERIAL, get_material


#: Keys naming where a material comes from: exactly one per material.
SOURCE_KEYS = ("path", "nbrdf", "merl", "rgl", "virtual")
#: Source keys of files sampled on a plan (``plan`` applies to them).
SAMPLED_KEYS = ("nbrdf", "merl", "rgl")
#: Every key a material source may have.
MATERIAL_KEYS = (*SOURCE_KEYS, "reference", "plan", "name")


@dataclass(frozen=True)
class MaterialData:
    """Samples of one material: ``fit`` to fit on, ``truth`` (or ``None``) to evaluate on."""

    name: str
    fit: BrdfTable
    truth: BrdfTable | None


def _check_plan(plan: str | None, key: str) -> None:
    if plan is not None and plan not in PLAN_NAMES:
        raise InputError(f"unknown plan {plan!r}; expected one of {', '.join(PLAN_NAMES)}", column=key)


def virtual_truth(material: str, plan: str) -> BrdfTable:
    """Noiseless spectral BRDF of a virtual stand-in on any plan (400–700 nm, sr⁻¹)."""
    angles = plan_spherical(plan)
    values = get_material(material).brdf(*spherical_pair_to_vectors(*angles), GROUND_TRUTH_WAVELENGTHS_NM)
    return BrdfTable(*angles, values, GROUND_TRUTH_WAVELENGTHS_NM.copy(), source=f"virtual {material} on {plan}")


def load_fit_measurement(path, reference=None) -> BrdfTable:
    """:func:`~neuralbrdf.data.loading.load_measurement` for a fit: a spectral table must hold two
    or more wavelengths, since a fitted spectral model covers the range between its data's lowest
    and highest wavelength (one wavelength is no range: the model would claim wavelengths it never
    saw, or fail at export)."""
    table = load_measurement(path, reference)
    if table.is_spectral and len(table.wavelengths) < 2:
        raise InputError(f"holds one wavelength ({float(table.wavelengths[0]):g} nm); a spectral fit needs samples at "
                         "two or more wavelengths, whose range the fitted model covers", path=path)
    return table


def virtual_measurement(material: str, plan: str, noise: float, seed: int, reference_seed: int) -> BrdfTable:
    """A measurement of the virtual instrument as a user makes one: ``material`` and the Munsell
    reference each measured on ``plan`` with relative ``noise`` (noise streams ``seed`` and
    ``reference_seed``), calibrated against the reference (spectral, sr⁻¹)."""
    from neuralbrdf.data.calibration import calibrate
    from neuralbrdf.virtual.instrument import VirtualGoniospectrophotometer

    sample = VirtualGoniospectrophotometer(noise, seed=seed).measure_plan(material, plan)
    reference = VirtualGoniospectrophotometer(noise, seed=reference_seed).measure_plan(REFERENCE_MATERIAL, plan)
    return calibrate(sample, reference)


def sample_file(path: str | os.PathLike[str], plan: str, progress: bool = False) -> BrdfTable:
    """A MERL ``.binary`` measurement, an RGL ``.bsdf`` measurement (spectral or RGB as the file) or an
    NBRDF proxy ``.h5`` (RGB) sampled on ``plan`` (sr⁻¹); ``progress``: a progress bar while a network
    is evaluated."""
    if Path(path).suffix == ".binary":
        return sample_merl(MerlBrdf.load(path), plan)
    if Path(path).suffix == RGL_SUFFIX:
        return sample_rgl(RglBsdf.load(path), plan)
    return sample_plan(NbrdfNetwork.load(path), plan, progress=progress)


def load_material(
    *,
    path: str | None = None,
    reference: str | None = None,
    nbrdf: str | None = None,
    merl: str | None = None,
    rgl: str | None = None,
    virtual: str | None = None,
    plan: str = "DS1",
    eval_plan: str | None = "low",
    name: str | None = None,
) -> MaterialData:
    """Load one material from exactly one source (module docstring); ``plan`` applies to the sampled files."""
    sources = (("path", path), ("nbrdf", nbrdf), ("merl", merl), ("rgl", rgl), ("virtual", virtual))
    given = [key for key, value in sources if value is not None]
    if len(given) != 1:
        raise InputError(f"give exactly one of {', '.join('data.' + k for k in SOURCE_KEYS)}; got {given or 'none'}")
    if reference is not None and path is None:
        raise InputError("data.reference goes with a GCMS raw data.path", column="data.reference")
    _check_plan(plan, "data.plan")
    _check_plan(eval_plan, "data.eval_plan")
    if path is not None:
        return MaterialData(name or Path(path).stem, load_fit_measurement(path, reference), None)
    if nbrdf is not None:
        network = NbrdfNetwork.load(nbrdf)
        truth = None if eval_plan is None else sample_plan(network, eval_plan)
        return MaterialData(name or network.name, sample_plan(network, plan), truth)
    if merl is not None:
        brdf = MerlBrdf.load(merl)
        truth = None if eval_plan is None else sample_merl(brdf, eval_plan)
        return MaterialData(name or brdf.name, sample_merl(brdf, plan), truth)
    if rgl is not None:
        measurement = RglBsdf.load(rgl)
        truth = None if eval_plan is None else sample_rgl(measurement, eval_plan)
        return MaterialData(name or measurement.name, sample_rgl(measurement, plan), truth)
    fit = load_measurement(default_data_path(virtual), default_data_path(REFERENCE_MATERIAL))
    truth = None if eval_plan is None else virtual_truth(virtual, eval_plan)
    return MaterialData(name or virtual, fit, truth)


def check_source(source, where: str) -> dict[str, str]:
    """One material source as a mapping of :data:`MATERIAL_KEYS`, checked; ``where`` names it in errors."""
    if not isinstance(source, dict):
        raise InputError(f"expected a mapping such as {{nbrdf: FILE.h5}}, got {source!r}", column=where)
    for key in source:
        if key not in MATERIAL_KEYS:
            raise InputError(f"unknown key {key!r}; expected {', '.join(MATERIAL_KEYS)}", column=where)
    given = [k for k in SOURCE_KEYS if k in source]
    if len(given) != 1:
        raise InputError(f"needs exactly one of {', '.join(SOURCE_KEYS)}, got {given or 'none'}", column=where)
    if "reference" in source and given[0] != "path":
        raise InputError("'reference' goes with a GCMS raw 'path'", column=where)
    if "plan" in source and (given[0] not in SAMPLED_KEYS or source["plan"] not in PLAN_NAMES):
        raise InputError(f"'plan' is for nbrdf, merl and rgl sources, one of {', '.join(PLAN_NAMES)}; got "
                         f"{source['plan']!r}", column=where)
    return {k: str(v) for k, v in source.items()}


def source_name(source: dict[str, str]) -> str:
    """The material name of a checked source: its ``name``, else the virtual material or the file stem."""
    if "name" in source:
        return source["name"]
    key = next(k for k in SOURCE_KEYS if k in source)
    return source[key] if key == "virtual" else Path(source[key]).stem
