"""One study cell: data → fit → export → evaluate → (main cell) cost, in a worker process.

    python -m neuralbrdf.study.cell CELL_DIR      # one cell
    python -m neuralbrdf.study.cell --serve       # a worker: one CELL_DIR per stdin line

``CELL_DIR/cell.json`` (written by the runner) holds the cell, its key, what its plan is measured
on (DS1..DS4 or a plan file's path), the material and variant entries of the profile, the truth
file and its SHA-256, the render/cost settings and whether the cell is the main one (rendered and
timed) or renders for its image metrics only; this writes
``CELL_DIR/result.json`` (recording the key and the truth's SHA-256, by which the runner checks a
cached result) last (atomically), so a cell whose ``result.json`` exists is finished and any other is rerun from
scratch.  A worker (:func:`serve`) imports torch, Lightning, onnxruntime and Mitsuba once (about
14 CPU-seconds, more than a typical stability cell's own work) and runs cells one after another,
each with its output (stdout and stderr, file descriptors included) in ``CELL_DIR/log.txt``; it
answers one line per cell on its own channel, and keeps each material's truth evaluator with its
values on the fixed direction pairs (:class:`~neuralbrdf.evaluation.scores.MemoEvaluator`: the
truth's share of the direction metrics, two thirds of them for a spectral truth, is computed
once per worker) and the truth's two renders (:data:`TRUTH_RENDERS`).  Steps:

1. **Data** (``data/NAME.csv``): a virtual material is measured by the virtual
   goniospectrophotometer (:mod:`neuralbrdf.virtual.instrument`) on the plan with the cell's
   relative noise and seed, together with the Munsell N9 reference (same noise, next seed), and
   calibrated (report Eq. 2.3); an NBRDF proxy or a MERL measurement is sampled on the plan
   (:func:`neuralbrdf.sources.sample_file`) and given the same multiplicative Gaussian noise;
   a user's table is used as it is.
2. **Fit** with ``train.py``'s entry (:func:`neuralbrdf.lightning.run.main`): the variant's config
   and overrides, the data (``--data.path``, for every method), ``--seed_everything SEED`` and the
   method's own seed options (:data:`~neuralbrdf.study.cells.SEEDING`: ABC's ``--model.seed``);
   wall time measured.  An ``auto`` cell records which candidate its fit kept, each candidate's
   in-plane error and why ABC was no candidate, if it was not (``result.json``'s ``auto``:
   :data:`AUTO_RESULT_KEYS`).
3. **Export** through the checkpoint's kind (:func:`neuralbrdf.onnx_export.export_checkpoint`, what
   ``neuralbrdf export`` runs); a graph that fails its validation is "export refused".
4. **Evaluate** with :func:`neuralbrdf.evaluation.evaluate.evaluate` (direction metrics; for the
   main cell, and every cell of a profile that renders its sweeps, also the renders) and the glossy relative RMSE per incident angle and per channel
   (:func:`neuralbrdf.metrics.relative_rmse_by_theta_i`, report Figs. 4.6/4.7 and 5.3).
5. **Cost** (main cell): :mod:`neuralbrdf.study.cost`.

Failure causes recorded (``failure``): ``non_finite_loss`` (a logged loss or the fit's own loss is
NaN/inf; for ``pca``, a fit whose data, ridge solution or in-plane error is not finite),
``optimizer_failure`` (the fit reported failure, e.g. ABC's ``success: false``, an ``auto`` fit in
which neither candidate fitted or a ``pca`` fit with no sample above the horizon, or training
stopped with an error), ``fit_refused``
(the fit rejected the data as bad input, exit status 2: e.g. a plan without samples in a required
split, or arguments of the variant the command line does not accept), ``export_refused``,
``evaluation_error``.  The fourth cause of
the failure map, error above twice the method's DS1 noise-free error, is decided across cells
by :mod:`neuralbrdf.study.aggregate`.
"""

from __future__ import annotations

import contextlib
import csv
import dataclasses
import functools
import io
import json
import math
import os
import subprocess
import sys
import threading
import time
import traceback
from pathlib import Path

import numpy as np

from neuralbrdf.atomic import atomic_write, file_version
from neuralbrdf.errors import EXIT_BAD_INPUT, EXIT_ENVIRONMENT, EnvironmentFailure

#: Reference seed offset: the Munsell N9 is measured with its own noise stream.
REFERENCE_SEED_OFFSET = 1
CHECKPOINTS = {"spectral_mlp": "best.ckpt", "abc": "best.ckpt", "nlb": "fitted.ckpt", "nlb_spectral": "fitted.ckpt",
               "auto": "best.ckpt", "pca": "best.ckpt"}
#: What a failed ``pca`` fit's one-line cause (``PCA fit of NAME: CAUSE``) says of a value that is not
#: finite (its data, its ridge solution or its in-plane error: ``non_finite_loss``); any other cause
#: (no sample above the horizon) is an ``optimizer_failure``.
PCA_NOT_FINITE = "not finite"
#: What a cell of method ``auto`` records of its fit (``result.json``'s ``auto``): ``metrics.json``'s
#: ``fit/auto/KEY`` for each key.
AUTO_RESULT_KEYS = ("choice", "inplane_logcos_rmse", "abc_failure")
#: Incident angles (degrees) of the per-angle relative RMSE: the DS1 grid.
PER_ANGLE_THETA_I = np.arange(-60.0, 60.1, 5.0)
LOSS_COLUMN_WORDS = ("loss",)
#: Truth evaluators a worker keeps (cells run material by material; each holds ~30 MB of values).
TRUTHS_KEPT = 2
#: The truth renders of the main cells (two per material and render settings, ~0.2 MB each at 128²),
#: rendered once per worker (:func:`neuralbrdf.evaluation.evaluate.evaluate`'s ``truth_renders``).
TRUTH_RENDERS: dict = {}
#: The worker's answer after each cell (the runner then reads ``result.json``, or reports a crash).
DONE = "done"


class CellFailure(Exception):
    def __init__(self, cause: str, message: str) -> None:
        super().__init__(message)
        self.cause = cause


def _finite(value):
    if isinstance(value, float) and not math.isfinite(value):
        return None
    if isinstance(value, dict):
        return {k: _finite(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_finite(v) for v in value]
    return value


# --------------------------------------------------------------------------- data


def write_data(spec: dict, out: Path) -> Path:
    """The cell's training samples (module docstring, step 1); returns the table path."""
    from neuralbrdf.data.table import write_table

    cell, material = spec["cell"], spec["material"]
    if material["table"] is not None:
        return Path(material["table"])
    out.parent.mkdir(parents=True, exist_ok=True)
    if material["truth"].startswith("virtual:"):
        from neuralbrdf.sources import virtual_measurement

        table = virtual_measurement(material["truth"].split(":", 1)[1], spec["plan"], cell["noise"], cell["seed"],
                                    cell["seed"] + REFERENCE_SEED_OFFSET)
    else:  # an NBRDF proxy, a MERL or an RGL measurement
        from neuralbrdf.sources import sample_file

        table = sample_file(material["truth"], spec["plan"])
        if cell["noise"]:
            rng = np.random.default_rng([cell["seed"], 7])
            noisy = table.values * (1.0 + cell["noise"] * rng.standard_normal(table.values.shape))
            table = dataclasses.replace(table, values=np.clip(noisy, 0.0, None),
                                        source=f"{table.source} + {cell['noise']:g} relative noise")
    write_table(table, out)
    return out


# --------------------------------------------------------------------------- fit


def _data_args(material: dict, table: Path) -> list[str]:
    return ["--data.path", str(table), *(["--data.trust_units", "true"] if material.get("trust_units") else [])]


def _non_finite_logged_loss(run_dir: Path) -> bool:
    for path in run_dir.rglob("metrics.csv"):
        with path.open() as handle:
            for row in csv.DictReader(handle):
                for column, value in row.items():
                    if column and any(w in column for w in LOSS_COLUMN_WORDS) and value not in ("", None):
                        if not math.isfinite(float(value)):
                            return True
    return False


def fit_arguments(spec: dict, table: Path, run_dir: Path) -> list[str]:
    """``train.py``'s arguments for the cell (step 2): the variant's config and overrides, the data,
    the run directory and the cell's seed (:data:`~neuralbrdf.study.cells.SEEDING`)."""
    from neuralbrdf.study.cells import seed_args

    variant, cell = spec["variant"], spec["cell"]
    return ["fit", "--config", variant["config"], *variant["args"], *_data_args(spec["material"], table),
            "--run_dir", str(run_dir), "--seed_everything", str(cell["seed"]),
            *seed_args(variant["method"], cell["seed"]), "--trainer.enable_progress_bar", "false"]


def _errors(output: str) -> list[str]:
    """``train.py``'s error lines in ``output``, each as ``error: MESSAGE`` (its command name cut)."""
    from neuralbrdf.lightning.train_cli import PROG

    marker = f"{PROG}: "
    return [line.strip()[len(marker):] for line in output.splitlines() if line.strip().startswith(f"{marker}error:")]


def _refusal(output: str) -> str:
    """The one line that says why ``train.py`` refused its arguments (its ``error:`` line, or the
    option its parser named as not accepted)."""
    lines = [line.strip() for line in output.splitlines()]
    named = [line for line in lines if "is not accepted" in line or "unrecognized arguments" in line]
    return (named or _errors(output) or ["the fit refused its arguments"])[-1][:300]


def fit(spec: dict, table: Path, run_dir: Path) -> tuple[float, dict]:
    """Train the variant (step 2); ``(wall time s, metrics.json)`` or :class:`CellFailure`."""
    from neuralbrdf.lightning.run import main as train

    started = time.perf_counter()
    captured = io.StringIO()
    try:
        with contextlib.redirect_stderr(captured):
            status = train(fit_arguments(spec, table, run_dir))
    except SystemExit as refused:  # the command-line parser: an option of the variant's args it does not know
        raise CellFailure("fit_refused", f"the variant's arguments: {_refusal(captured.getvalue())} "
                                         f"(exit status {refused.code})") from None
    except Exception as error:  # the fit's own exception: its message says why
        message = f"{type(error).__name__}: {error}"
        cause = "non_finite_loss" if _non_finite_logged_loss(run_dir) or "finite" in message.lower() \
            or "nan" in message.lower() else "optimizer_failure"
        raise CellFailure(cause, message.splitlines()[0][:300]) from None
    finally:
        sys.stderr.write(captured.getvalue())
    wall = time.perf_counter() - started
    if status == EXIT_ENVIRONMENT or status > 128:  # the machine (a full disk) or a signal, not the fit: no
        # result, the cell runs again next time
        raise RuntimeError((_errors(captured.getvalue())[-1:] or [f"the fit ended with status {status}"])[0])
    if status == EXIT_BAD_INPUT:  # train.py's bad-input status: the fit refused these data (its one-line reason)
        reason = _errors(captured.getvalue())[-1:] or ["?"]
        raise CellFailure("fit_refused", reason[0][:300])
    if _non_finite_logged_loss(run_dir):
        raise CellFailure("non_finite_loss", "a logged training loss is NaN or infinite")
    if status != 0:  # train.py's "fit failed" status, with its one-line cause
        reason = _errors(captured.getvalue())[-1:]
        reason = reason[0][:300] if reason else f"training exited with status {status}"
        finite = "finite" in reason.lower() or "nan" in reason.lower()
        from neuralbrdf.lightning.auto_fit import NEITHER_FITTED

        if spec["variant"]["method"] == "auto" and NEITHER_FITTED in reason:
            # the fit's own verdict: neither candidate gave a model (an ABC failure and a spectral NLB
            # error that is not finite are its causes, named in the message), as ABC's success: false
            finite = False
        if spec["variant"]["method"] == "pca" and "PCA fit of " in reason:
            # the fit's own cause, read after "PCA fit of NAME: " (not from a material's name): a value
            # that is not finite, else no model could be made from these samples
            finite = PCA_NOT_FINITE in reason.split("PCA fit of ", 1)[1].split(": ", 1)[-1]
        raise CellFailure("non_finite_loss" if finite else "optimizer_failure", reason)
    metrics_path = run_dir / "metrics.json"
    metrics = json.loads(metrics_path.read_text()) if metrics_path.is_file() else {}
    if metrics.get("fit/abc/success") is False:
        raise CellFailure("optimizer_failure", f"ABC fit: {metrics.get('fit/abc/failure_reason')}")
    return wall, metrics


def auto_result(metrics: dict) -> dict:
    """What an ``auto`` cell records of its fit's ``metrics.json`` (:data:`AUTO_RESULT_KEYS`)."""
    return {key: metrics.get(f"fit/auto/{key}") for key in AUTO_RESULT_KEYS}


def export(spec: dict, run_dir: Path, out: Path) -> Path:
    """Export the fitted checkpoint (step 3) through its kind — for a ``fast`` variant its fast
    path ``f_fast`` as a model of its own (:func:`fast_path_alone`) — ; :class:`CellFailure` when refused."""
    from neuralbrdf.errors import InputError
    from neuralbrdf.onnx_contract import OUTPUT_FAST
    from neuralbrdf.onnx_export import ExportValidationError, export_checkpoint
    from neuralbrdf.study.cells import FAST_PATH_SETTINGS

    checkpoint = run_dir / "checkpoints" / CHECKPOINTS[spec["variant"]["method"]]
    try:
        if not spec["variant"].get("fast"):
            export_checkpoint(checkpoint, out)
            return out
        full, with_fast = out.with_name(f"{out.stem}_full.onnx"), out.with_name(f"{out.stem}_with_fast.onnx")
        export_checkpoint(checkpoint, full)
        # `neuralbrdf export` (a process of its own: the study imports nothing of neuralbrdf.lod,
        # which imports the study's cost module)
        done = subprocess.run([sys.executable, "-m", "neuralbrdf", "export", "--model", str(full), "--out",
                               str(with_fast), "--fast", "--no-rgb-head", "--config", FAST_PATH_SETTINGS],
                              capture_output=True, text=True)
        if done.returncode != 0:
            raise CellFailure("export_refused", (done.stderr.strip().splitlines() or ["neuralbrdf export failed"])[-1][:300])
        fast_path_alone(with_fast, OUTPUT_FAST, out)
    except (InputError, ExportValidationError) as error:
        raise CellFailure("export_refused", f"{type(error).__name__}: {error}"[:300]) from None
    return out


def fast_path_alone(model_path: Path, output: str, out: Path) -> Path:
    """Write ``out``: the fast path ``output`` of the file ``model_path`` as a model file of its own
    (its only output ``f``; the file's metadata without its fast paths' entries, the provenance
    saying which output it is), checked by the contract like any model file."""
    from onnx import helper

    from neuralbrdf.atomic import atomic_path
    from neuralbrdf.kinds import load_model
    from neuralbrdf.onnx_contract import FAST_PATH_OUTPUTS, PROVENANCE_KEY, WAVELENGTH_MAX_KEY, WAVELENGTH_MIN_KEY
    from neuralbrdf.onnx_export import save_checked

    model = load_model(model_path)
    recorded, view = model.fast_paths[output], model.output_view(output)
    dropped = () if view.is_spectral else (WAVELENGTH_MIN_KEY, WAVELENGTH_MAX_KEY)  # f_rgb: an RGB model
    metadata = {key: value for key, value in model.metadata.items() if key not in dropped
                and not (key.startswith("neuralbrdf.") and key.split(".")[1] in FAST_PATH_OUTPUTS)}
    metadata[PROVENANCE_KEY] = f"{metadata[PROVENANCE_KEY]}; its fast path {output}: {recorded.approximates}"
    proto = view.proto
    helper.set_model_props(proto, metadata)
    with atomic_path(out) as tmp:
        save_checked(proto, tmp, f"{output} alone")
    return out


# --------------------------------------------------------------------------- evaluate


@functools.lru_cache(maxsize=TRUTHS_KEPT)
def _truth_evaluator(version: tuple):
    from neuralbrdf.evaluation.scores import MemoEvaluator, truth_evaluator as open_truth

    return MemoEvaluator(open_truth(version[0]))


def truth_evaluator(truth: Path):
    """The worker's evaluator of a truth file, its values remembered (module docstring); a file
    changed on disk is loaded afresh."""
    return _truth_evaluator(file_version(truth))


def per_angle(model: Path, truth: Path) -> dict:
    """Glossy relative RMSE per incident angle (channel mean) and per angle × channel."""
    from neuralbrdf.evaluation.scores import COMPARISON_WAVELENGTHS_NM, OnnxEvaluator, compared_values, \
        compares_spectra, inplane_pairs
    from neuralbrdf.metrics import relative_rmse_by_theta_i

    m, t = OnnxEvaluator(model), truth_evaluator(truth)
    spectral = compares_spectra(m, t)
    theta_i, theta_r, wi, wo = inplane_pairs()
    keep = np.isin(np.round(theta_i, 6), PER_ANGLE_THETA_I)
    pred = compared_values(m, wi[keep], wo[keep], spectral)
    target = compared_values(t, wi[keep], wo[keep], spectral)
    result = relative_rmse_by_theta_i(pred, target, theta_i[keep], theta_r[keep])
    return {
        "theta_i_deg": result.theta_i.tolist(),
        "glossy_rel_rmse": [None if not math.isfinite(v) else float(v) for v in result.value],
        "channels": COMPARISON_WAVELENGTHS_NM.tolist() if spectral else ["R", "G", "B"],
        "per_channel": [[None if not math.isfinite(v) else float(v) for v in row] for row in result.per_channel],
    }


def render_variant(spec: dict, truth: Path) -> str:
    """The variant's own ``render_variant``, else the truth's kind of variant (spectral or RGB)."""
    from neuralbrdf.evaluation.scores import is_measurement

    chosen = spec["variant"]["render_variant"]
    if chosen:
        return chosen
    if is_measurement(truth):
        from neuralbrdf.data.rgl_bsdf import RglBsdf

        return RglBsdf.load(truth).variant
    from neuralbrdf.kinds import load_model

    return "llvm_ad_spectral" if load_model(truth).is_spectral else "llvm_ad_rgb"


def cost(spec: dict, model: Path, variant: str) -> dict:
    import onnx

    from neuralbrdf.kinds import load_model
    from neuralbrdf.study import cost as costs

    settings = spec["cost"]
    loaded = load_model(model)
    proto = onnx.load(str(model))
    ratio = costs.render_ratio(model, variant, settings["resolution"], settings["spp"], settings["repeats"])
    throughput = costs.bench_throughput(proto, loaded.is_spectral, settings["batch"], settings["repeats"])
    fastest = max(throughput, key=lambda b: throughput[b]["queries_per_s"])
    return {
        "render_ratio": ratio["render_ratio"],
        "render": ratio,
        "mqueries_per_s": throughput[fastest]["queries_per_s"] / 1e6,
        "fastest_backend": fastest,
        "throughput": {b: {"queries_per_s": r["queries_per_s"], "median_s": r["median_s"]} for b, r in throughput.items()},
        "parameters": costs.parameter_count(proto, costs.graph_kind(loaded)),
    }


def run_cell(cell_dir: Path) -> dict:
    """Run the cell described by ``cell_dir/cell.json`` and write ``result.json`` (module docstring)."""
    from neuralbrdf.evaluation.evaluate import RenderSettings, evaluate

    spec = json.loads((cell_dir / "cell.json").read_text())
    cell = spec["cell"]
    result = {**cell, "is_main": spec["is_main"], "key": spec["key"], "truth_sha256": spec["truth_sha256"],
              "failure": None, "message": None, "cost": {}, "error": {}, "per_angle": None, "renders": None}
    started, cpu_started = time.perf_counter(), time.process_time()
    steps, cpu_steps = result["step_times_s"], result["step_cpu_times_s"] = {}, {}

    def step(name: str) -> None:  # wall and CPU seconds of each step (CPU: what it would take on an idle core)
        steps[name] = time.perf_counter() - started - sum(steps.values())
        cpu_steps[name] = time.process_time() - cpu_started - sum(cpu_steps.values())

    try:
        table = write_data(spec, cell_dir / "data" / f"{cell['material']}.csv")
        step("data")
        fit_s, metrics = fit(spec, table, cell_dir / "run")
        result["cost"]["fit_time_s"] = fit_s
        if spec["variant"]["method"] == "auto":
            result["auto"] = auto_result(metrics)
        step("fit")
        model = export(spec, cell_dir / "run", cell_dir / "model.onnx")
        step("export")
        truth = Path(spec["truth"])
        variant = render_variant(spec, truth)
        try:
            settings = RenderSettings(variant=variant, spp=spec["render"]["spp"],
                                      resolution=spec["render"]["resolution"], seed=0)
            evaluation = evaluate(model, truth, cell_dir / "evaluation", settings, render_images=spec["images"],
                                  strata=tuple(spec["render"]["hemisphere_strata"]), truth_evaluator=truth_evaluator(truth),
                                  truth_renders=TRUTH_RENDERS)
            result["error"] = {k: evaluation.get(k) for k in (
                "hemisphere_logcos_rmse", "hemisphere_rel_rmse", "inplane_glossy_rel_rmse", "inplane_diffuse_rel_rmse",
                "image_delta_e2000_mean", "image_delta_e2000_p95", "image_psnr", "image_rel_mse") if k in evaluation}
            step("evaluate")
            if spec["is_main"]:
                result["render_noise"] = evaluation.get("noise")
                result["renders"] = {"variant": variant, "dir": "evaluation"}
                result["per_angle"] = per_angle(model, truth)
                step("per_angle")
        except EnvironmentFailure:
            raise  # the machine (a full disk): no result, the cell reruns next time
        except (ValueError, RuntimeError) as error:
            raise CellFailure("evaluation_error", f"{type(error).__name__}: {error}"[:300]) from None
        if spec["is_main"]:
            result["cost"].update(cost(spec, model, variant))
            step("cost")
    except CellFailure as failure:
        result["failure"], result["message"] = failure.cause, str(failure)
    result["cell_wall_time_s"] = time.perf_counter() - started
    result["cell_cpu_time_s"] = time.process_time() - cpu_started
    result = _finite(result)
    with atomic_write(cell_dir / "result.json") as handle:
        json.dump(result, handle, indent=1, allow_nan=False)
    return result


@contextlib.contextmanager
def _output_to(path: Path):
    """Stdout and stderr into ``path``: Python's streams and the file descriptors 1 and 2 (native libraries)."""
    sys.stdout.flush(), sys.stderr.flush()
    saved = os.dup(1), os.dup(2)
    with path.open("a", buffering=1) as log, contextlib.redirect_stdout(log), contextlib.redirect_stderr(log):
        os.dup2(log.fileno(), 1), os.dup2(log.fileno(), 2)
        try:
            yield
        finally:
            log.flush()
            os.dup2(saved[0], 1), os.dup2(saved[1], 2)
            os.close(saved[0]), os.close(saved[1])


def _run_logged(cell_dir: Path) -> None:
    import torch

    torch.use_deterministic_algorithms(False)  # as in a fresh process: a config sets it for its own fit only
    with _output_to(cell_dir / "log.txt"):
        try:
            run_cell(cell_dir)
        except Exception:  # no result.json: the runner reports the cell as crashed, with this log
            traceback.print_exc()


def _import_fitting() -> None:
    """Import what every fit uses before the first cell, so that no cell's fit time includes it."""
    import neuralbrdf.lightning.run  # noqa: F401
    from neuralbrdf.lightning import (abc_module, auto_fit, config_models, latent_fit_data,  # noqa: F401
                                      latent_fit_module, material_data, measurement_data, nlb_spectral_fit,
                                      pca_fit, spectral_mlp_module)


#: Environment variable naming the study process a worker serves (:func:`die_with_study`).
STUDY_PID_VARIABLE = "NEURALBRDF_STUDY_PID"
#: Seconds between a worker's checks that its study still runs.
STUDY_POLL_S = 0.1
#: Exit status of a worker whose study ended under it.
ORPHANED_EXIT = 70


def die_with_study(study_pid: int | None = None) -> None:
    """End this worker process as soon as the study that started it (``study_pid``, default
    :data:`STUDY_PID_VARIABLE` or the parent process) is gone, whatever it was doing: a study that
    was killed reads no answers, and a rerun must not find a cell folder still being written.  A
    thread polls the parent process every :data:`STUDY_POLL_S` seconds (Linux's parent-death signal
    would follow the thread that started the worker, one of the study's pool threads, not the study)."""
    if study_pid is None:
        study_pid = int(os.environ.get(STUDY_PID_VARIABLE) or os.getppid())

    def watch() -> None:
        while os.getppid() == study_pid:
            time.sleep(STUDY_POLL_S)
        os._exit(ORPHANED_EXIT)  # no cleanup: what the cell wrote is rerun by the next study

    threading.Thread(target=watch, name="die-with-study", daemon=True).start()


def serve(requests=None) -> None:
    """Run the cell of each line of ``requests`` (stdin) and answer :data:`DONE` on the original stdout;
    anything else the process prints between cells goes to stderr, never into the answers.  The
    worker ends with its study (:func:`die_with_study`)."""
    requests = sys.stdin if requests is None else requests
    die_with_study()
    with os.fdopen(os.dup(1), "w", buffering=1) as answers:
        os.dup2(2, 1)
        _import_fitting()
        for line in requests:
            if line.strip():
                _run_logged(Path(line.strip()))
                answers.write(DONE + "\n")


#: Threads of each library in a cell's process (:func:`_single_threaded`).
WORKER_THREADS = {"torch": 1, "drjit": 1}


def _single_threaded() -> None:
    """One thread for torch and for Dr.Jit (:data:`WORKER_THREADS`): ``--jobs`` workers use the
    cores."""
    os.environ.setdefault("OMP_NUM_THREADS", "1")
    import drjit
    import torch

    torch.set_num_threads(WORKER_THREADS["torch"])
    drjit.set_thread_count(WORKER_THREADS["drjit"])


def main(argv: list[str] | None = None) -> int:
    argv = sys.argv[1:] if argv is None else argv
    _single_threaded()
    if argv == ["--serve"]:
        serve()
        return 0
    try:
        run_cell(Path(argv[0]))
    except Exception:
        traceback.print_exc()
        return 1
    return 0


if __name__ == "__main__":
    sys.exit(main())
