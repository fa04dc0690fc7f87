"""A material to fit, from any source a user has (docs/fit.md#your-measurement: any plan, any source).

The one vocabulary of every data module and config (``data.*`` keys, and the entries of a
latent fit's ``data.sources``).  One material comes from exactly one of:

* ``path`` — the user's measurement: a BRDF sample table (docs/formats.md#brdf-sample-table), a
  signed in-plane BRDF table (docs/formats.md#in-plane-brdf-table), or a GCMS raw file with its
  Munsell N9 ``reference`` (docs/formats.md#gcms-raw-measurement), checked for unit
  slips (:mod:`neuralbrdf.data.units`) unless ``trust_units``;
* ``nbrdf`` — a MERL-proxy NBRDF network (docs/formats.md#nbrdf-proxy) sampled on ``plan``;
* ``merl`` — a MERL ``.binary`` measurement (:mod:`neuralbrdf.data.merl_binary`) sampled on
  ``plan`` (nearest cell, RGB);
* ``rgl`` — an RGL material database ``.bsdf`` measurement (:mod:`neuralbrdf.data.rgl_bsdf`)
  sampled on ``plan`` through Mitsuba's ``measured`` plugin (spectral at 400–700 nm from a
  ``NAME_spec.bsdf``, RGB from a ``NAME_rgb.bsdf``);
* ``virtual`` — a stand-in of the virtual goniospectrophotometer (docs/measure.md#the-virtual-goniospectrophotometer): its shipped DS1
  measurement, calibrated against the shipped Munsell N9 reference.

with optional ``name`` (default: the file stem or the virtual material) and, for ``nbrdf``,
``merl`` and ``rgl``, ``plan``.  Proxies, measured files and virtual materials are defined
everywhere, so they also give a dense ``truth`` on
``eval_plan`` (default the Löw et al. set) for the hemisphere log-cosine RMSE (docs/evaluate.md#metrics); a
user's measurement has none.
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from neuralbrdf.data.loading import load_measurement
from neuralbrdf.data.merl_binary import MerlBrdf, sample_merl
from neuralbrdf.data.nbrdf import NbrdfNetwork, sample_plan
from neuralbrdf.data.rgl_bsdf import SUFFIX as RGL_SUFFIX
from neuralbrdf.data.rgl_bsdf import RglBsdf, sample_rgl
from neuralbrdf.data.plans import PLAN_HELP, check_plan, plan_label, plan_spherical
from neuralbrdf.data.table import BrdfTable
from neuralbrdf.errors import InputError
from neuralbrdf.geometry import spherical_pair_to_vectors
from neuralbrdf.virtual.instrument import GROUND_TRUTH_WAVELENGTHS_NM, default_data_path
from neuralbrdf.virtual.materials import REFERENCE_MATERIAL, get_material


#: Keys naming where a material comes from: exactly one per material.
SOURCE_KEYS = ("path", "nbrdf", "merl", "rgl", "virtual")
#: The files a material is sampled from, by their source key: how one is loaded (the result has a
#: ``name``) and how it is sampled on a plan (``plan`` applies to them).
SAMPLED_SOURCES = {
    "nbrdf": (NbrdfNetwork.load, sample_plan),
    "merl": (MerlBrdf.load, sample_merl),
    "rgl": (RglBsdf.load, sample_rgl),
}
SAMPLED_KEYS = tuple(SAMPLED_SOURCES)
#: File suffixes of the sampled sources -> their source key.
SAMPLED_SUFFIXES = {".h5": "nbrdf", ".json": "nbrdf", ".binary": "merl", RGL_SUFFIX: "rgl"}
#: Every key a material source may have.
MATERIAL_KEYS = (*SOURCE_KEYS, "reference", "plan", "name", "trust_units")


@dataclass(frozen=True)
class MaterialData:
    """Samples of one material: ``fit`` to fit on, ``truth`` (or ``None``) to evaluate on."""

    name: str
    fit: BrdfTable
    truth: BrdfTable | None


def _check_plan(plan: str | None, key: str) -> None:
    if plan is not None:
        check_plan(plan, key)


def virtual_truth(material: str, plan: str) -> BrdfTable:
    """Noiseless spectral BRDF of a virtual stand-in on any plan (400–700 nm, sr⁻¹)."""
    angles = plan_spherical(plan)
    values = get_material(material).brdf(*spherical_pair_to_vectors(*angles), GROUND_TRUTH_WAVELENGTHS_NM)
    return BrdfTable(*angles, values, GROUND_TRUTH_WAVELENGTHS_NM.copy(), source=f"virtual {material} on {plan_label(plan)}")


def load_fit_measurement(path, reference=None, trust_units: bool = False) -> BrdfTable:
    """:func:`~neuralbrdf.data.loading.load_measurement` for a fit: a spectral table must hold two
    or more wavelengths, since a fitted spectral model covers the range between its data's lowest
    and highest wavelength (one wavelength is no range: the model would claim wavelengths it never
    saw, or fail at export), and its values must carry a signal (:func:`check_signal`)."""
    table = load_measurement(path, reference, trust_units)
    if table.is_spectral and len(table.wavelengths) < 2:
        raise InputError(f"holds one wavelength ({float(table.wavelengths[0]):g} nm); a spectral fit needs samples at "
                         "two or more wavelengths, whose range the fitted model covers", path=path)
    check_signal(table, path)
    return table


def check_signal(table: BrdfTable, where: str | os.PathLike[str]) -> None:
    """Refuse a material whose values carry no signal to fit: every BRDF value 0 (a model fitted
    to it would be a model of nothing, reported as a success).  ``where`` names it."""
    if not np.any(table.values > 0):
        raise InputError(f"every BRDF value is 0 ({table.n_rows} rows): there is nothing to fit; check that the "
                         "values are the sample's (not an empty export, a dark frame or the wrong columns)", path=where)


#: Values of one channel within this fraction of the channel's largest value count as equal.
CONSTANT_TOLERANCE = 1e-6


def require_lobe(table: BrdfTable, where: str | os.PathLike[str], model: str) -> None:
    """Refuse, for a ``model`` that fits a specular lobe (ABC), a material whose every channel holds
    one value at every measured geometry (a Lambertian surface): no lobe to fit, so the fit could
    only fail with its lobe parameters at their bounds.  ``where`` names the material."""
    values = np.asarray(table.values, dtype=np.float64).reshape(table.n_rows, -1)
    spread = values.max(axis=0) - values.min(axis=0)
    if table.n_rows > 1 and np.all(spread <= CONSTANT_TOLERANCE * np.abs(values).max(axis=0)):
        raise InputError(f"every channel holds the same value at all {table.n_rows} geometries (a Lambertian "
                         f"surface): there is no specular lobe for the {model} model to fit; fit it with a model "
                         "without a required lobe (spectral_mlp, nlb, nlb_spectral)", path=where)


def virtual_measurement(material: str, plan, noise: float, seed: int, reference_seed: int) -> BrdfTable:
    """A measurement of the virtual instrument as a user makes one: ``material`` and the Munsell
    reference each measured on ``plan`` (a name, a plan file or a :class:`~neuralbrdf.data.plans.Plan`)
    with relative ``noise`` (noise streams ``seed`` and ``reference_seed``), calibrated against the
    reference (spectral, sr⁻¹)."""
    from neuralbrdf.data.calibration import calibrate
    from neuralbrdf.virtual.instrument import VirtualGoniospectrophotometer

    sample = VirtualGoniospectrophotometer(noise, seed=seed).measure_plan(material, plan)
    reference = VirtualGoniospectrophotometer(noise, seed=reference_seed).measure_plan(REFERENCE_MATERIAL, plan)
    return calibrate(sample, reference)


def sample_file(path: str | os.PathLike[str], plan: str, progress: bool = False) -> BrdfTable:
    """A MERL ``.binary`` measurement, an RGL ``.bsdf`` measurement (spectral or RGB as the file) or an
    NBRDF proxy ``.h5`` (RGB) sampled on ``plan`` (sr⁻¹); ``progress``: a progress bar while a network
    is evaluated."""
    key = SAMPLED_SUFFIXES.get(Path(path).suffix, "nbrdf")  # any other file: read as an NBRDF proxy, which names it
    load, sample = SAMPLED_SOURCES[key]
    return sample(load(path), plan, **({"progress": progress} if key == "nbrdf" else {}))


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
    trust_units: bool = False,
) -> MaterialData:
    """Load one material from exactly one source (module docstring); ``plan`` applies to the sampled
    files, ``trust_units`` to a ``path``."""
    sources = (("path", path), ("nbrdf", nbrdf), ("merl", merl), ("rgl", rgl), ("virtual", virtual))
    given = [key for key, value in sources if value is not None]
    if len(given) != 1:
        raise InputError(f"give exactly one of {', '.join('data.' + k for k in SOURCE_KEYS)}; got {given or 'none'}")
    if reference is not None and path is None:
        raise InputError("data.reference goes with a GCMS raw data.path", key="data.reference")
    _check_plan(plan, "data.plan")
    _check_plan(eval_plan, "data.eval_plan")
    if path is not None:
        return MaterialData(name or Path(path).stem, load_fit_measurement(path, reference, trust_units), None)
    for key, file in (("nbrdf", nbrdf), ("merl", merl), ("rgl", rgl)):
        if file is not None:
            load, sample = SAMPLED_SOURCES[key]
            material = load(file)
            fit = sample(material, plan)
            check_signal(fit, file)
            truth = None if eval_plan is None else sample(material, eval_plan)
            return MaterialData(name or material.name, fit, truth)
    fit = load_measurement(default_data_path(virtual), default_data_path(REFERENCE_MATERIAL))
    truth = None if eval_plan is None else virtual_truth(virtual, eval_plan)
    return MaterialData(name or virtual, fit, truth)


def check_source(source, where: str) -> dict[str, str | bool]:
    """One material source as a mapping of :data:`MATERIAL_KEYS`, checked (strings, and
    ``trust_units`` a bool); ``where`` names it in errors."""
    if not isinstance(source, dict):
        raise InputError(f"expected a mapping such as {{nbrdf: FILE.h5}}, got {source!r}", key=where)
    for key in source:
        if key not in MATERIAL_KEYS:
            raise InputError(f"unknown key {key!r}; expected {', '.join(MATERIAL_KEYS)}", key=where)
    given = [k for k in SOURCE_KEYS if k in source]
    if len(given) != 1:
        raise InputError(f"needs exactly one of {', '.join(SOURCE_KEYS)}, got {given or 'none'}", key=where)
    if "reference" in source and given[0] != "path":
        raise InputError("'reference' goes with a GCMS raw 'path'", key=where)
    if "plan" in source:
        if given[0] not in SAMPLED_KEYS:
            raise InputError(f"'plan' is for nbrdf, merl and rgl sources ({PLAN_HELP}); got {source['plan']!r}",
                             key=where)
        check_plan(source["plan"], f"{where}.plan")
    if "trust_units" in source and (given[0] != "path" or not isinstance(source["trust_units"], bool)):
        raise InputError(f"'trust_units' is true or false, for a 'path'; got {source['trust_units']!r}", key=where)
    return {k: v if k == "trust_units" else str(v) for k, v in source.items()}


def source_name(source: dict[str, str]) -> str:
    """The material name of a checked source: its ``name``, else the virtual material or the file stem."""
    if "name" in source:
        return source["name"]
    key = next(k for k in SOURCE_KEYS if k in source)
    return source[key] if key == "virtual" else Path(source[key]).stem
