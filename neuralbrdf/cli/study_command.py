"""The ``neuralbrdf study`` subcommand: arguments, one call into :func:`neuralbrdf.api.study` (the work is in
:mod:`neuralbrdf.study.runner`, imported only when the command runs), and what it prints."""

from __future__ import annotations

HELP = "run the speed/accuracy/stability study and write DIR/index.html"
DESCRIPTION = (
    "Fit every model variant of a study profile to every material (and, for the stability variants, every "
    "sampling plan, relative noise level and seed), score each fit against the material's truth, time it against "
    "Mitsuba's roughconductor, and write DIR/study.json, DIR/figures/*.png and DIR/index.html (docs/study.md). "
    "Finished cells are cached under DIR/cells/ by their settings: a rerun does only what is new, a killed run "
    "resumes; cached files that are damaged or belong elsewhere are redone. One study at a time runs in DIR. "
    "PROFILE is a shipped profile (quick, full, spectral, latent_prior, budget: configs/study/) or your own YAML file. "
    "With --cluster ADDRESS the cells run as tasks on the workers of a running Dask scheduler, the same cells with "
    "the same cache and report. With --report-only, DIR/figures and DIR/index.html are drawn again from "
    "DIR/study.json and no cell runs. Exit status: 0 when every cell gave a model; 1 when a cell crashed (the study is "
    "incomplete; a rerun retries it) or a fit failed (unless --allow-failures); 2 for bad input; 3 when a file could "
    "not be written (no space left on device) or the cluster could not run the study (no scheduler at ADDRESS, a "
    "worker that does not see DIR); 130 on Ctrl-C. The report and study.json's health say which cells."
)


def add_arguments(parser) -> None:
    parser.add_argument("--profile", help="quick, full, spectral, latent_prior, budget or a profile YAML file (needed unless --report-only)")
    parser.add_argument("--out", required=True, help="output folder (cache, figures, study.json, index.html)")
    parser.add_argument("--jobs", type=int, default=None, help="cells run at once on this machine, one core each (default 1)")
    parser.add_argument("--cluster", metavar="ADDRESS",
                        help="run the cells as tasks on the Dask scheduler at ADDRESS (tcp://HOST:PORT) instead: its "
                        "workers must see DIR and the profile's files at the same paths (docs/study.md, 'On a "
                        "cluster'); needs pip install 'neuralbrdf[cluster]'")
    parser.add_argument("--no-progress", action="store_true", help="no progress bar")
    parser.add_argument("--allow-failures", action="store_true",
                        help="exit 0 although some fits failed or were refused (expected in a stability sweep on "
                        "sparse plans; the failure map records them); a crashed cell still exits 1")
    parser.add_argument("--report-only", action="store_true",
                        help="draw DIR's figures and index.html again from DIR/study.json; run no cell")


def _check_cluster_extra() -> None:
    """One line, before any work, where Dask's ``distributed`` (the ``cluster`` extra) is not installed."""
    import importlib.util

    from neuralbrdf.errors import EnvironmentFailure

    if importlib.util.find_spec("distributed") is None:
        raise EnvironmentFailure("--cluster needs Dask's distributed package, which is not installed: "
                                 "pip install 'neuralbrdf[cluster]'")


def run(args) -> int:
    """Run the study; the exit status of its ``health`` (:mod:`neuralbrdf.study.health`)."""
    import sys

    from neuralbrdf import api
    from neuralbrdf.cli.commands import options
    from neuralbrdf.errors import InputError

    if args.report_only:
        print(f"-> {api.study_report(args.out)}")
        return
    if args.profile is None:
        raise InputError("--profile is required (or --report-only to redraw an existing study)", key="--profile")
    if args.cluster is not None and args.jobs is None:
        _check_cluster_extra()
    where = f"--cluster {args.cluster}" if args.cluster is not None else f"--jobs {args.jobs or 1}"
    allow = " --allow-failures" if args.allow_failures else ""
    with options(jobs="--jobs"):
        study = api.study(args.profile, args.out, jobs=args.jobs, cluster=args.cluster, progress=not args.no_progress,
                          allow_failures=args.allow_failures,
                          command=f"neuralbrdf study --profile {args.profile} --out {args.out} {where}{allow}")
    health = study["health"]
    above = sum(1 for p in study["points"] if p["failure"] == "error_above_2x_ds1")
    print(f"{len(study['points'])} cells ({study['run']['cells_run']} run, {study['run']['cells_cached']} cached; "
          f"{len(health['failed'])} failed to fit or score, {len(health['crashed'])} crashed, {above} failed by an error "
          f"above twice their DS1 error; the failure map shows all three) in "
          f"{study['run']['wall_time_s']:.0f} s -> {args.out}/index.html")
    print("Pareto (ΔE vs render cost, pooled): " + (", ".join(study["pareto"]["render_ratio"]["pooled"]) or "none"))
    if health["status"] != "complete":
        label = "error" if health["exit_status"] else "note"
        print(f"neuralbrdf study: {label}: {health['summary']}", file=sys.stderr)
    return health["exit_status"]
