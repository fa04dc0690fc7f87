"""Implementations of the ``neuralbrdf`` subcommands (argument parsing lives in :mod:`.main`).

Each parses nothing more, makes one call into :mod:`neuralbrdf.api` and prints: a message about
an argument of that call names the command's option (``plan`` as ``--plan``, :func:`options`).
"""

from __future__ import annotations

import contextlib
from pathlib import Path

from neuralbrdf import api
from neuralbrdf.data.plans import plan_label
from neuralbrdf.data.units import overridden_by
from neuralbrdf.errors import InputError

#: The option of the commands that read a measurement as it is where its numbers look like a unit slip.
TRUST_UNITS_FLAG = "--trust-units"


@contextlib.contextmanager
def options(**flags: str):
    """Within this block, an :class:`InputError` naming an argument of an API call (``key='plan'``)
    names the command's option for it (``options(plan="--plan")``), and a unit slip names
    :data:`TRUST_UNITS_FLAG` as the way past it."""
    try:
        with overridden_by(TRUST_UNITS_FLAG):
            yield
    except InputError as error:
        if error.key in flags:
            raise error.named(flags[error.key]) from None
        raise


def simulate(args) -> None:
    with options(plan="--plan"):
        table = api.simulate(args.material, args.out, plan=args.plan, noise=args.noise, noise_abs=args.noise_abs,
                             seed=args.seed, truth=args.truth)
    if args.truth:
        print(f"ground truth of {args.material} on {plan_label(args.plan)}: {table.n_rows} rows -> {args.out}")
    else:
        print(f"GCMS raw measurement of {args.material} on {plan_label(args.plan)} ({len(table.theta_i)} pairs) "
              f"-> {args.out}")


def calibrate(args) -> None:
    with options():
        table = api.calibrate(args.sample, args.reference, args.out, trust_units=args.trust_units)
    print(f"calibrated {table.n_rows} rows x {len(table.wavelengths)} wavelengths -> {args.out}")


def to_rgb(args) -> None:
    with options():
        table = api.to_rgb(args.table, args.out, trust_units=args.trust_units)
    print(f"linear sRGB table ({table.n_rows} rows) -> {args.out}")


def sample(args) -> None:
    with options(plan="--plan"):
        table = api.sample(args.material, args.plan, args.out, progress=True)
    print(f"{args.material} on {plan_label(args.plan)}: {table.n_rows} rows -> {args.out}")


def plot(args) -> None:
    with options():
        api.plot(args.table, args.out, reference=args.reference, theta_i=args.theta_i, trust_units=args.trust_units)
    print(f"plot -> {args.out}")


def demo(args) -> None:
    with options(materials="--material"):
        api.demo(args.out_dir, args.material, overwrite=args.overwrite, progress=True)
    print(f"demo outputs for {', '.join(args.material or api.stand_ins())} -> {Path(args.out_dir)}/")


def regenerate_default_data(args) -> None:
    for path in api.regenerate_default_data(args.out_dir, progress=True):
        print(path)


def export_truth(args) -> None:
    api.truth(args.source, args.out, log=print)


def evaluate(args) -> None:
    from neuralbrdf.evaluation.evaluate import format_table

    result = api.evaluate(args.model, args.truth, args.out_dir, scene=args.scene, material=args.material,
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
    tables = None if args.tables is None else [_counts(t, 4, "--tables") for t in args.tables]
    students = None if args.students is None else [_counts(t, 2, "--students") for t in args.students]
    document = api.ladder(args.model, args.out_dir, config=args.config, tables=tables, students=students)
    print(f"{'rung':<18} {'kind':<13} {'log-cos RMSE':>12} {'ns/query':>9} {'cost':>6}")
    for rung in document["rungs"]:
        print(f"{rung['name']:<18} {rung['kind']:<13} {rung['hemisphere_logcos_rmse']:>12.4f} "
              f"{rung['drjit_ns_per_query']:>9.2f} {rung['relative_cost']:>6.3f}")
    for failure in document["failed"]:
        print(f"{failure['name']}: not written ({failure['cause']})")
    print(f"-> {api.ladder_dir(args.model, args.out_dir)}/ladder.json")


#: ``neuralbrdf select`` options that override ``select.*`` of the config (``None``: not given).
SELECT_OVERRIDES = ("tolerance", "object_tolerance", "variant", "resolution", "spp", "max_spp", "seed")


def select(args) -> None:
    result = api.select(args.scene, args.out, ladders=args.ladder, config=args.config,
                        **{name: getattr(args, name) for name in SELECT_OVERRIDES})
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
