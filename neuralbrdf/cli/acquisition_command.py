"""The ``neuralbrdf plan`` and ``neuralbrdf acquire`` subcommands: arguments, one call into :mod:`neuralbrdf.api`, and what they print (docs/how-many-measurements.md)."""

from __future__ import annotations

from neuralbrdf import api

PLAN_HELP = "write the angle pairs to measure: a report plan, a designed plan, or the next pairs"
PLAN_DESCRIPTION = (
    "Write the direction pairs an operator measures, as signed in-plane theta_i,theta_r (degrees; 'low' as spherical "
    "theta_i,phi_i,theta_o,phi_o). 'plan DS1' .. 'plan DS4': the report's plans (Tables 4.1, 6.1, 6.2; 1001/185/57/6 "
    "pairs); 'plan low': the Low et al. 2012 full set (230 400 pairs). 'plan design --budget N': N pairs chosen with the "
    "prior to lower the expected hemisphere error of a fit from them most. 'plan next TABLE --count K': from what is "
    "measured so far, the K pairs to measure next, and the current fit's error estimated with an interval. Every "
    "--plan option of the other commands takes such a file (docs/how-many-measurements.md)."
)
ACQUIRE_HELP = "simulate a measuring session: measure, fit, ask for the next pairs, until a target or a budget"
ACQUIRE_DESCRIPTION = (
    "Simulate a session on a material with a truth (virtual:NAME, an NBRDF .h5, a MERL .binary, an RGL .bsdf): measure "
    "the start plan with the virtual instrument's noise, fit the spectral NLB, ask 'plan next' for --count pairs, "
    "measure them, and so on until the estimated preview CIEDE2000 is within --target-de (the upper end of its "
    "interval) or --max pairs are measured. Writes DIR/acquire.json (every step: pairs, estimated and true hemisphere "
    "log-cos RMSE and preview CIEDE2000), DIR/acquire.png (the curve of true and estimated error against the pairs), "
    "DIR/plan.csv (the pairs in the order measured), DIR/measurement.csv (the last measurement) and DIR/model.onnx "
    "(its fit, without a fast path: 'neuralbrdf export --model DIR/model.onnx --out FAST.onnx --fast' adds one)."
)


def _instrument_arguments(parser) -> None:
    parser.add_argument("--max-theta", type=float, default=60.0, help="largest angle either arm reaches from the "
                        "normal, degrees (default 60)")
    parser.add_argument("--step", type=float, default=1.0, help="angular step of the arms, degrees (default 1)")
    parser.add_argument("--retro-band", type=float, default=0.0, help="pairs with |theta_i + theta_r| below this "
                        "(degrees) are blocked: source and detector coincide at retro-reflection (default 0)")
    parser.add_argument("--config", default="default", help="acquisition settings (default: the shipped "
                        "configs/acquisition/default.yaml)")


def add_plan_arguments(parser, report_plans: tuple[str, ...]) -> None:
    sub = parser.add_subparsers(dest="plan", required=True, metavar="PLAN")
    for name in report_plans:
        p = sub.add_parser(name, help=f"the report's plan {name}" if name != "low" else "the Low et al. full set",
                           allow_abbrev=False)
        p.add_argument("--out", required=True, help="output CSV")
        p.set_defaults(func=write_report_plan)
    p = sub.add_parser("design", help="pairs chosen with the prior before anything is measured", allow_abbrev=False,
                       description="Choose BUDGET in-plane pairs that lower the expected hemisphere error of a fit "
                       "from them most, averaged over the prior's training materials (docs/how-many-measurements.md), "
                       "and write them in the order to measure them.")
    p.add_argument("--budget", type=int, required=True, help="number of pairs")
    p.add_argument("--out", required=True, help="output plan CSV (theta_i,theta_r)")
    p.add_argument("--kind", default="nlb_spectral", help="the model the plan is designed for: nlb_spectral (default), abc or pca")
    p.add_argument("--seed", type=int, default=None, help="which of the prior's materials the design averages over "
                   "(default: the config's)")
    _instrument_arguments(p)
    p.set_defaults(func=design)
    p = sub.add_parser("next", help="the pairs to measure next, and how good the fit is now", allow_abbrev=False,
                       description="Fit TABLE with the spectral NLB, estimate its hemisphere log-cos RMSE and preview "
                       "CIEDE2000 with an interval, and choose the COUNT pairs not measured yet that lower the "
                       "expected error most. Prints one line: the estimates and, with --target-de, 'enough' or "
                       "'measure these next'.")
    p.add_argument("table", help="the measurement so far: a BRDF table CSV (spherical or signed in-plane), or a GCMS "
                   "raw CSV with --reference")
    p.add_argument("--reference", default=None, help="Munsell N9 GCMS raw CSV, when TABLE is a GCMS raw file")
    p.add_argument("--count", type=int, default=1, help="pairs to choose (default 1)")
    p.add_argument("--out", required=True, help="output plan CSV of the pairs to measure next")
    p.add_argument("--target-de", type=float, default=None, help="preview CIEDE2000 the fit should reach")
    p.add_argument("--watch", action="store_true", help="stay running and answer again each time TABLE changes (the "
                   "network loaded once: seconds per answer at the instrument); a file that cannot be read is "
                   "reported and watched on; Ctrl-C stops")
    _instrument_arguments(p)
    p.set_defaults(func=next_measurements)


def write_report_plan(args) -> None:
    columns = api.write_plan(args.plan, args.out)
    print(f"{args.plan}: {len(columns[0])} direction pairs -> {args.out}")


def design(args) -> None:
    overrides = None if args.seed is None else {"seed": args.seed}
    plan = api.design_plan(args.budget, args.out, kind=args.kind, max_theta=args.max_theta, step=args.step,
                           retro_band=args.retro_band, config=args.config, overrides=overrides, progress=True)
    print(f"designed for {plan.kind}: {len(plan.theta_i)} pairs, predicted relative hemisphere error "
          f"{plan.predicted_error[0]:.3g} before and {plan.predicted_error[-1]:.3g} after -> {args.out}")


def _pairs(count: int) -> str:
    return f"{count} pair{'' if count == 1 else 's'}"


def _interval(interval, digits: int) -> str:
    return f"{interval.estimate:.{digits}f} (80 % interval {interval.low:.{digits}f}-{interval.high:.{digits}f})"


def next_measurements(args) -> None:
    import sys
    import time

    from neuralbrdf.errors import InputError

    if args.target_de is not None and not args.target_de > 0:
        raise InputError(f"expected a positive CIEDE2000, got {args.target_de}", key="--target-de")

    def say(answer) -> None:
        verdict = answer.enough(args.target_de)
        said = "" if verdict is None else (f"; target ΔE2000 {args.target_de:g}: " +
                                           ("enough" if verdict else "measure these next"))
        when = time.strftime("%H:%M:%S ") if args.watch else ""
        print(f"{when}{_pairs(answer.measured)} measured; the fit's error now: hemisphere log-cos RMSE "
              f"{_interval(answer.logcos, 4)}, preview ΔE2000 {_interval(answer.delta_e, 2)}{said} -> {args.out} "
              f"({_pairs(len(answer.theta_i))})", flush=True)

    options = dict(reference=args.reference, max_theta=args.max_theta, step=args.step, retro_band=args.retro_band,
                   config=args.config)
    if not args.watch:
        say(api.next_pairs(args.table, args.count, args.out, **options))
        return
    print(f"watching {args.table}: an answer each time it changes (Ctrl-C stops)", flush=True)
    try:
        api.watch_next_pairs(args.table, args.count, args.out, on_answer=say,
                             on_error=lambda error: print(f"{time.strftime('%H:%M:%S')} {error} (watching on)",
                                                          file=sys.stderr, flush=True), **options)
    except KeyboardInterrupt:  # how watching ends: the last answer's plan file is whole (written atomically)
        pass
    print("stopped", flush=True)


def add_acquire_arguments(parser) -> None:
    parser.add_argument("source", help="virtual:NAME, an NBRDF .h5, a MERL .binary or an RGL .bsdf")
    parser.add_argument("--out-dir", required=True, help="output folder")
    parser.add_argument("--start", default=None, help="plan measured first: DS1-DS4 or a plan file (default: the "
                        "config's, the shipped design of 6 pairs)")
    parser.add_argument("--target-de", type=float, default=None, help="stop when the estimated preview CIEDE2000 "
                        "(its interval's upper end) is within this")
    parser.add_argument("--max", type=int, default=None, dest="max_pairs", help="budget of pairs (default: the "
                        "config's, 24)")
    parser.add_argument("--count", type=int, default=None, help="pairs measured at each step (default 1)")
    parser.add_argument("--noise", type=float, default=None, help="relative noise of the virtual instrument "
                        "(default 0.01)")
    parser.add_argument("--seed", type=int, default=None, help="noise and render seed (default 0)")
    parser.add_argument("--no-render", action="store_true", help="no preview renders: the true hemisphere error only")
    parser.add_argument("--overwrite", action="store_true", help="replace the outputs of an earlier session in "
                        "--out-dir")
    _instrument_arguments(parser)


def acquire(args) -> None:
    def report(step) -> None:
        true_de = "" if step.true_delta_e is None else f", true ΔE2000 {step.true_delta_e:.2f}"
        print(f"{step.pairs} pairs: estimated log-cos {step.estimated_logcos['estimate']:.4f} "
              f"({step.estimated_logcos['low']:.4f}-{step.estimated_logcos['high']:.4f}), true "
              f"{step.true_logcos:.4f}; estimated ΔE2000 {step.estimated_delta_e['estimate']:.2f} "
              f"({step.estimated_delta_e['low']:.2f}-{step.estimated_delta_e['high']:.2f}){true_de}", flush=True)

    result = api.acquire(args.source, args.out_dir, start=args.start, target_delta_e=args.target_de,
                         max_pairs=args.max_pairs, count=args.count, noise=args.noise, seed=args.seed,
                         render=not args.no_render, max_theta=args.max_theta, step=args.step,
                         retro_band=args.retro_band, config=args.config, overwrite=args.overwrite, progress=report)
    print(f"stopped after {len(result.theta_i)} pairs: {result.stopped} -> {args.out_dir}/")
