"""Measurement tables: :func:`simulate` a measurement, :func:`calibrate` it, convert it :func:`to_rgb`,
:func:`sample` a material on a plan, :func:`plot` a table, run the :func:`demo`.

Each is what the ``neuralbrdf`` command of its name does (the command parses its options, calls
the function and prints); with ``out``, the table or figure is written atomically, in the formats of
docs/formats.md.  An argument in error is named in the one-line :class:`~neuralbrdf.errors.InputError`
(``key='plan'``; the command names its option, ``--plan``).
"""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING

from neuralbrdf.api.arguments import PathLike, as_path
from neuralbrdf.errors import InputError

if TYPE_CHECKING:
    from neuralbrdf.data.gcms import GcmsMeasurement
    from neuralbrdf.data.table import BrdfTable


def stand_ins() -> tuple[str, ...]:
    """The virtual stand-in materials (every virtual material but the Munsell N9 reference)."""
    from neuralbrdf.virtual.materials import MATERIALS, REFERENCE_MATERIAL

    return tuple(name for name in MATERIALS if name != REFERENCE_MATERIAL)


def simulate(material: str, out: PathLike | None = None, *, plan: str | PathLike = "DS1", noise: float = 0.0,
             noise_abs: float = 0.0, seed: int = 0, truth: bool = False) -> GcmsMeasurement | BrdfTable:
    """Measure the virtual ``material`` with the virtual goniospectrophotometer
    (docs/measure.md#the-virtual-goniospectrophotometer) on the in-plane ``plan`` (DS1-DS4 or an
    in-plane plan file): the GCMS raw measurement (radiance factor, 390-730 nm, with relative
    ``noise`` and additive ``noise_abs`` drawn from ``seed``), or with ``truth`` the noiseless
    spectral BRDF table (sr⁻¹, 400-700 nm).  With ``out``, also written as a CSV file.

    >>> import neuralbrdf as nb
    >>> nb.simulate("gold", plan="DS4", truth=True).n_rows
    6
    """
    from neuralbrdf.data.plans import check_plan, in_plane_plan
    from neuralbrdf.virtual.instrument import VirtualGoniospectrophotometer

    theta_i, theta_r = in_plane_plan(check_plan(plan, "plan", in_plane=True))
    if truth:
        result = VirtualGoniospectrophotometer().ground_truth(material, theta_i, theta_r)
    else:
        device = VirtualGoniospectrophotometer(noise_rel=noise, noise_abs=noise_abs, seed=seed)
        result = device.measure(material, theta_i, theta_r)
    if out is not None:
        from neuralbrdf.data.gcms import write_gcms
        from neuralbrdf.data.table import write_table

        (write_table if truth else write_gcms)(result, as_path(out, "out", "an output CSV path"))
    return result


def calibrate(sample: PathLike, reference: PathLike, out: PathLike | None = None, *,
              trust_units: bool = False) -> BrdfTable:
    """The spectral BRDF table (sr⁻¹, 400-700 nm) of a GCMS raw ``sample`` calibrated against the
    Munsell N9 ``reference`` measured at the same geometry (report Eq. 2.3), checked for unit slips
    unless ``trust_units`` (:mod:`neuralbrdf.data.units`); with ``out``, also written."""
    from neuralbrdf.data.calibration import calibrate as calibrate_measurement
    from neuralbrdf.data.gcms import read_gcms
    from neuralbrdf.data.units import check_units

    table = check_units(calibrate_measurement(read_gcms(as_path(sample, "sample")),
                                              read_gcms(as_path(reference, "reference"))), trust_units)
    if out is not None:
        from neuralbrdf.data.table import write_table

        write_table(table, as_path(out, "out", "an output CSV path"))
    return table


def to_rgb(table: PathLike, out: PathLike | None = None, *, trust_units: bool = False) -> BrdfTable:
    """The spectral BRDF table file ``table`` (spherical or signed in-plane) in linear sRGB (report
    Eq. 2.4 without the factor 100); with ``out``, written in the format it was read in."""
    from neuralbrdf.data.csvio import read_csv_header
    from neuralbrdf.data.inplane_table import is_inplane_header, write_inplane_table
    from neuralbrdf.data.loading import read_brdf_table
    from neuralbrdf.data.table import write_table

    path = as_path(table, "table")
    spectral = read_brdf_table(path, trust_units)
    if not spectral.is_spectral:
        raise InputError("already an RGB table; expected wavelength columns", path=path)
    rgb = spectral.to_rgb()
    if out is not None:
        write = write_inplane_table if is_inplane_header(read_csv_header(path)) else write_table
        write(rgb, as_path(out, "out", "an output CSV path"))
    return rgb


def sample(material: PathLike, plan: str | PathLike, out: PathLike | None = None, *,
           progress: bool = False) -> BrdfTable:
    """``material`` sampled on ``plan`` (DS1-DS4, ``low`` or a plan file) as a BRDF table (sr⁻¹): a
    MERL ``.binary``, an RGL ``.bsdf``, an NBRDF proxy ``.h5`` (``progress``: a bar while its network
    runs) or ``virtual:NAME``, a virtual stand-in's noiseless truth; with ``out``, also written.

    >>> import neuralbrdf as nb
    >>> nb.sample("virtual:gold", "DS4").n_rows
    6
    """
    from neuralbrdf.data.plans import check_plan
    from neuralbrdf.sources import sample_file, virtual_truth

    check_plan(plan, "plan")
    source = str(as_path(material, "material", "a file path or 'virtual:NAME'"))
    if source.startswith("virtual:"):
        table = virtual_truth(source[len("virtual:"):], plan)
    else:
        table = sample_file(source, plan, progress=progress)
    if out is not None:
        from neuralbrdf.data.table import write_table

        write_table(table, as_path(out, "out", "an output CSV path"))
    return table


def plot(table: PathLike, out: PathLike, *, reference: PathLike | None = None, theta_i=None,
         trust_units: bool = False, title: str | None = None) -> Path:
    """Write a figure (``.png``, ``.pdf`` or ``.svg``) of the BRDF table ``table``'s in-plane
    slices at the incident angles ``theta_i`` (degrees, signed; default a few) and, for a spectral
    table, its mirror-direction spectra; a GCMS raw file is calibrated against ``reference`` first.
    Returns ``out``."""
    from neuralbrdf.data.loading import load_measurement
    from neuralbrdf.plotting import DEFAULT_THETA_I_DEG, plot_inplane

    measurement = load_measurement(as_path(table, "table"), reference, trust_units)
    out = as_path(out, "out", "an output figure path (.png, .pdf or .svg)")
    plot_inplane(measurement, out, theta_i_deg=theta_i or DEFAULT_THETA_I_DEG, title=title)
    return out


def demo_outputs(out_dir: PathLike, materials) -> list[Path]:
    """The files :func:`demo` writes for ``materials`` into ``out_dir``."""
    return [Path(out_dir) / f"{name}_DS1{suffix}" for name in materials
            for suffix in ("_spectral.csv", "_rgb.csv", ".png")]


def demo(out_dir: PathLike = "out/demo", materials=None, *, overwrite: bool = False,
         progress: bool = False) -> list[Path]:
    """The main job on the shipped virtual DS1 measurements: for every stand-in of ``materials``
    (default all, :func:`stand_ins`) calibrate against the Munsell N9 reference, convert to linear
    sRGB and plot, into ``out_dir`` (:func:`demo_outputs`); files of an earlier demo there are
    refused before any work unless ``overwrite``.  Returns the files written."""
    from neuralbrdf.console import progress as progress_bar
    from neuralbrdf.data.calibration import calibrate as calibrate_measurement
    from neuralbrdf.data.gcms import read_gcms
    from neuralbrdf.data.table import write_table
    from neuralbrdf.plotting import plot_inplane
    from neuralbrdf.virtual.instrument import default_data_path
    from neuralbrdf.virtual.materials import REFERENCE_MATERIAL

    out = as_path(out_dir, "out_dir", "a folder path")
    materials = list(materials or stand_ins())
    for name in materials:
        if name not in stand_ins():
            raise InputError(f"unknown stand-in {name!r}; expected {', '.join(stand_ins())}", key="materials")
    outputs = demo_outputs(out, materials)
    existing = [path.name for path in outputs if path.exists() or path.is_symlink()]
    if existing and not overwrite:  # checked before any work: a rerun never replaces them silently
        raise InputError(f"already holds the demo's outputs ({', '.join(existing[:3])}"
                         f"{', ...' if len(existing) > 3 else ''}); pass --overwrite to replace them, or choose "
                         "another --out-dir", path=out)
    reference = read_gcms(default_data_path(REFERENCE_MATERIAL))
    for name in progress_bar(materials, desc="demo", unit="material") if progress else materials:
        spectral = calibrate_measurement(read_gcms(default_data_path(name)), reference)
        write_table(spectral, out / f"{name}_DS1_spectral.csv")
        write_table(spectral.to_rgb(), out / f"{name}_DS1_rgb.csv")
        plot_inplane(spectral, out / f"{name}_DS1.png", title=f"virtual {name}, DS1, calibrated")
    return outputs


def regenerate_default_data(out_dir: PathLike | None = None, *, progress: bool = False) -> list[Path]:
    """Re-simulate the shipped DS1 GCMS raw files (the stand-ins and the Munsell N9 reference) with
    the instrument's documented default noise and seed into ``out_dir`` (default: the package's
    data); returns the files written."""
    from neuralbrdf.virtual.instrument import regenerate_default_data as regenerate

    return regenerate(None if out_dir is None else as_path(out_dir, "out_dir", "a folder path"), progress=progress)
