"""Implementations of the ``neuralbrdf`` subcommands (argument parsing lives in :mod:`.main`)."""

from __future__ import annotations

import dataclasses
from pathlib import Path


from neuralbrdf.console import progress
from neuralbrdf.data import plans
from neuralbrdf.data.calibration import calibrate as calibrate_measurement
from neuralbrdf.data.gcms import read_gcms, write_gcms
from neuralbrdf.data.csvio import read_csv_header
from neuralbrdf.data.inplane_table import is_inplane_header, write_inplane_table
from neuralbrdf.data.loading import load_measurement, read_brdf_table
from neuralbrdf.data.units import check_units, overridden_by
from neuralbrdf.sources import sample_file, virtual_truth
from neuralbrdf.data.table import write_table
from neuralbrdf.errors import InputError
from neuralbrdf.plotting import DEFAULT_THETA_I_DEG, plot_inplane
from neuralbrdf.virtual import instrument
from neuralbrdf.virtual.materials import MATERIALS, REFERENCE_MATERIAL

STAND_INS = tuple(name for name in MATERIALS if name != REFERENCE_MATERIAL)


def simulate(args) -> None:
    theta_i, theta_r = plans.in_plane_plan(plans.check_plan(args.plan, "--plan", in_plane=True))
    if args.truth:
        table = instrument.VirtualGoniospectrophotometer().ground_truth(args.material, theta_i, theta_r)
        write_table(table, args.out)
        print(f"ground truth of {args.material} on {plans.plan_label(args.plan)}: {table.n_rows} rows -> {args.out}")
        return
    device = instrument.VirtualGoniospectrophotometer(noise_rel=args.noise, noise_abs=args.noise_abs, seed=args.seed)
    write_gcms(device.measure(args.material, theta_i, theta_r), args.out)
    print(f"GCMS raw measurement of {args.material} on {plans.plan_label(args.plan)} ({len(theta_i)} pairs) -> {args.out}")


#: The option of the commands that read a measurement as it is where its numbers look like a unit slip.
TRUST_UNITS_FLAG = "--trust-units"


def calibrate(args) -> None:
    with overridden_by(TRUST_UNITS_FLAG):
        table = check_units(calibrate_measurement(read_gcms(args.sample), read_gcms(args.reference)), args.trust_units)
    write_table(table, args.out)
    print(f"calibrated {table.n_rows} rows x {len(table.wavelengths)} wavelengths -> {args.out}")


def to_rgb(args) -> None:
    with overridden_by(TRUST_UNITS_FLAG):
        table = read_brdf_table(args.table, args.trust_units)
    if not table.is_spectral:
        raise InputError("already an RGB table; expected wavelength columns", path=args.table)
    write = write_inplane_table if is_inplane_header(read_csv_header(args.table)) else write_table
    write(table.to_rgb(), args.out)  # in the format it was read in
    print(f"linear sRGB table ({table.n_rows} rows) -> {args.out}")


def sample(args) -> None:
    plans.check_plan(args.plan, "--plan")
    source = str(args.material)
    if source.startswith("virtual:"):
        table = virtual_truth(source[len("virtual:"):], args.plan)
    else:
        table = sample_file(source, args.plan, progress=True)
    write_table(table, args.out)
    print(f"{source} on {plans.plan_label(args.plan)}: {table.n_rows} rows -> {args.out}")


def plot(args) -> None:
    with overridden_by(TRUST_UNITS_FLAG):
        table = load_measurement(args.table, args.reference, args.trust_units)
    plot_inplane(table, args.out, theta_i_deg=args.theta_i or DEFAULT_THETA_I_DEG)
    print(f"plot -> {args.out}")


def demo_outputs(out_dir: Path, materials) -> list[Path]:
    """The files ``neuralbrdf demo`` writes for ``materials`` into ``out_dir``."""
    return [out_dir / f"{name}_DS1{suffix}" for name in materials for suffix in ("_spectral.csv", "_rgb.csv", ".png")]


def demo(args) -> None:
    out = Path(args.out_dir)
    materials = args.material or STAND_INS
    for name in materials:
        if name not in STAND_INS:
            raise InputError(f"unknown stand-in {name!r}; expected {', '.join(STAND_INS)}", key="--material")
    existing = [path.name for path in demo_outputs(out, materials) if path.exists() or path.is_symlink()]
    if existing and not args.overwrite:  # checked before any work: a rerun never replaces them silently
        raise InputError(f"already holds the demo's outputs ({', '.join(existing[:3])}{', ...' if len(existing) > 3 else ''}); "
                         "pass --overwrite to replace them, or choose another --out-dir", path=out)
    reference = read_gcms(instrument.default_data_path(REFERENCE_MATERIAL))
    for name in progress(materials, desc="demo", unit="material"):
        sample = read_gcms(instrument.default_data_path(name))
        spectral = calibrate_measurement(sample, reference)
        write_table(spectral, out / f"{name}_DS1_spectral.csv")
        write_table(spectral.to_rgb(), out / f"{name}_DS1_rgb.csv")
        plot_inplane(spectral, out / f"{name}_DS1.png", title=f"virtual {name}, DS1, calibrated")
    print(f"demo outputs for {', '.join(materials)} -> {out}/")


def regenerate_default_data(args) -> None:
    written = instrument.regenerate_default_data(args.out_dir, progress=True)
    for path in written:
        print(path)


def export_truth(args) -> None:
    from neuralbrdf.evaluation.truth import describe_resampling, load_truth
    from neuralbrdf.onnx_export import write_model

    truth = load_truth(args.source)
    report = write_model(truth.exportable(), args.out)
    print(
        f"wrote {report.path}: reference model of {report.material!r}; onnxruntime vs PyTorch on {report.n_probes} "
        f"probes: max error {report.max_abs_error:.2g} sr^-1, {report.max_rel_error:.2g} relative"
    )
    if truth.kind_metadata:
        print(describe_resampling(truth.kind_metadata))


def evaluate(args) -> None:
    from neuralbrdf.api import evaluate as run_evaluation
    from neuralbrdf.evaluation.evaluate import format_table

    result = run_evaluation(args.model, args.truth, args.out_dir, scene=args.scene, material=args.material,
                            variant=args.variant, spp=args.spp, resolution=args.resolution, seed=args.seed,
                            backend=args.backend, fast=args.fast, images=not args.no_render)
    print(format_table(result))  # its notes were warnings (neuralbrdf.api.evaluate)
    print(f"-> {args.out_dir}/evaluation.json" + ("" if args.no_render else ", model.png, truth.png, error_map.png, comparison.png"))


def _counts(text: str, length: int, option: str) -> tuple[int, ...]:
    """``"32x16x8x16"`` as ``(32, 16, 8, 16)``: ``length`` positive integers, else :class:`InputError`."""
    try:
        counts = tuple(int(part) for part in text.lower().split("x"))
    except ValueError:
        counts = ()
    if len(counts) != length or min(counts) < 1:
        raise InputError(f"{option} {text!r}: expected {length} positive integers joined by 'x'", key=option)
    return counts


def ladder(args) -> None:
    from neuralbrdf.lod.config import load_lod_config
    from neuralbrdf.lod.ladder import build_ladder
    from neuralbrdf.lod.select import default_ladder_dir

    settings = load_lod_config(args.config).ladder
    if args.tables is not None:
        settings = dataclasses.replace(settings, tables=tuple(_counts(t, 4, "--tables") for t in args.tables))
    if args.students is not None:
        settings = dataclasses.replace(settings, students=tuple(_counts(t, 2, "--students") for t in args.students))
    out_dir = Path(args.out_dir) if args.out_dir else default_ladder_dir(Path(args.model))
    document = build_ladder(args.model, out_dir, settings)
    print(f"{'rung':<18} {'kind':<13} {'log-cos RMSE':>12} {'ns/query':>9} {'cost':>6}")
    for rung in document["rungs"]:
        print(f"{rung['name']:<18} {rung['kind']:<13} {rung['hemisphere_logcos_rmse']:>12.4f} "
              f"{rung['drjit_ns_per_query']:>9.2f} {rung['relative_cost']:>6.3f}")
    for failure in document["failed"]:
        print(f"{failure['name']}: not written ({failure['cause']})")
    print(f"-> {out_dir}/ladder.json")


#: ``neuralbrdf select`` options that override ``select.*`` of the config (``None``: not given).
SELECT_OVERRIDES = ("tolerance", "object_tolerance", "variant", "resolution", "spp", "max_spp", "seed")


def select(args) -> None:
    from neuralbrdf.lod.config import load_lod_config
    from neuralbrdf.lod.select import select as run_selection

    settings = load_lod_config(args.config).select
    settings = dataclasses.replace(settings, **{name: getattr(args, name) for name in SELECT_OVERRIDES
                                                if getattr(args, name) is not None})
    settings = dataclasses.replace(settings, max_spp=max(settings.max_spp, settings.spp))
    result = run_selection(args.scene, args.out, settings, [Path(d) for d in args.ladder])
    print(f"{'material':<12} {'rung':<12} {'dE2000 image':>12} {'on object':>9} {'cost':>6}")
    for material in result["materials"]:
        on_object = material["on_object_delta_e2000_selected_scene"]
        print(f"{material['name']:<12} {material['chosen_rung']:<12} {material['error_contribution']:>12.3f} "
              f"{'-' if on_object is None else f'{on_object:.3f}':>9} {material['cost']:>6.3f}")
    print(f"speed-up {result['speedup']:.2f}x ({result['reference_time_s']:.2f} s -> {result['selected_time_s']:.2f} s), "
          f"mean dE2000 {result['image_delta_e2000_mean']:.3f} at {result['noise']['spp']} spp (render noise "
          f"{result['noise']['render_seed_to_seed_delta_e2000_mean']:.3f}, estimate noise "
          f"{result['noise']['estimate_seed_to_seed_delta_e2000']:.3f}); selection {result['selection_time_s']:.0f} s")
    print(f"-> {args.out}, {Path(args.out).with_suffix('.json')}")
