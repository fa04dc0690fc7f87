"""Where users look: the spectral NLB against ABC and the RGB NLB on measured materials no
pretraining saw (SPEC §4.2–4.3, §5, §9).

    python benchmarks/spectral_nlb.py [--groups rgl_validation,report,merl_held_out] [--plans DS1]
        [--no-render] [--spectral-args ARG ...] [--work DIR] [--out benchmarks/spectral_nlb.json]

For every material of the chosen groups (NBRDF proxies of ``../shared/data``) and every plan:

* ``nlb_spectral`` — ``configs/nlb_spectral.yaml`` (RGB per channel: the proxies are RGB), all
  the group's materials in one batch, plus ``--spectral-args`` (a settings sweep);
* ``nlb`` — ``configs/nlb_latent.yaml``, the RGB NLB's default fit, one batch;
* ``abc`` — ``configs/abc.yaml``, the in-plane ABC fit of the same samples, one per material;

each fit exported (``neuralbrdf export``) and scored by ``neuralbrdf evaluate`` against the
proxy's own export (``neuralbrdf export-truth``): the hemisphere log-cosine RMSE (102 400 pairs),
the in-plane glossy and diffuse errors, and — unless ``--no-render`` — the image ΔE2000 of the
material-preview scene in ``llvm_ad_rgb`` (128 px, 64 spp; model and truth at matched seeds, the
truth-against-truth noise stated).  Groups:

* ``rgl_validation`` — the RGL validation split (:data:`neuralbrdf.data.proxy_corpus.RGL_VALIDATION`,
  another lab): the spectral NLB's settings are chosen here;
* ``merl_held_out`` — the ten MERL materials held out of pretraining (:data:`~neuralbrdf.data.proxy_corpus.HELD_OUT`);
* ``report`` — the report's five MERL materials.

Every cell (material × plan × method) is kept in ``--work`` (default ``runs/spectral_nlb``) and
reused when the script runs again with the same settings.  Writes JSON (``--out``) and prints a
table with each group's medians and the spectral NLB's wins over ABC and the RGB NLB.
"""

from __future__ import annotations

import argparse
import hashlib
import json
import platform
import sys
import time
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

from neuralbrdf.atomic import atomic_write  # noqa: E402
from neuralbrdf.data.nbrdf import REPORT_MATERIALS  # noqa: E402
from neuralbrdf.data.proxy_corpus import HELD_OUT, RGL_VALIDATION  # noqa: E402
from neuralbrdf.evaluation.evaluate import RenderSettings, evaluate  # noqa: E402
from neuralbrdf.evaluation.truth import export_truth  # noqa: E402
from neuralbrdf.lightning.run import main as train_main  # noqa: E402
from neuralbrdf.onnx_export import export_checkpoint  # noqa: E402

SHARED = REPO.parent / "shared" / "data"
GROUPS = {
    "rgl_validation": (SHARED / "rgl-nbrdf", RGL_VALIDATION),
    "merl_held_out": (SHARED / "merl-nbrdf", HELD_OUT),
    "report": (SHARED / "merl-nbrdf", REPORT_MATERIALS),
}
METHODS = ("nlb_spectral", "nlb", "abc")
CONFIGS = {"nlb_spectral": "nlb_spectral.yaml", "nlb": "nlb_latent.yaml", "abc": "abc.yaml"}
RENDER = RenderSettings(variant="llvm_ad_rgb", spp=64, resolution=128)
SCORES = ("hemisphere_logcos_rmse", "image_delta_e2000_mean", "image_delta_e2000_p95", "inplane_glossy_rel_rmse",
          "inplane_diffuse_rel_rmse")


def _train(run_dir: Path, config: str, *overrides: str) -> dict:
    args = ["fit", "--config", str(REPO / "configs" / config), "--run_dir", str(run_dir), "--overwrite",
            "--trainer.enable_progress_bar", "false", *overrides]
    if train_main(args) != 0:
        raise RuntimeError(f"neuralbrdf train {' '.join(args)} failed")
    return json.loads((run_dir / "metrics.json").read_text())


def _fit_batch(method: str, folder: Path, names, plan: str, run_dir: Path, extra: list[str]) -> tuple[Path, float]:
    """One batch latent fit of ``names``; its checkpoint and fit time per material."""
    sources = [{"nbrdf": str(folder / f"{name}.h5")} for name in names]
    metrics = _train(run_dir, CONFIGS[method], "--data.sources", json.dumps(sources), "--data.plan", plan,
                     "--data.eval_plan", "null", *extra)
    return run_dir / "checkpoints" / "fitted.ckpt", metrics["fit/wall_time_s"] / len(names)


def _fit_abc(folder: Path, name: str, plan: str, run_dir: Path) -> tuple[Path, float]:
    metrics = _train(run_dir, CONFIGS["abc"], "--data.nbrdf", str(folder / f"{name}.h5"), "--data.plan", plan,
                     "--data.eval_plan", "null")
    return run_dir / "checkpoints" / "best.ckpt", metrics["fit/wall_time_s"]


def _digest(*parts) -> str:
    return hashlib.sha256(json.dumps(parts, sort_keys=True).encode()).hexdigest()[:12]


def run_group(group: str, plan: str, work: Path, render: bool, spectral_args: list[str], truths: dict) -> dict:
    """Every method on every material of ``group`` from ``plan``: ``{material: {method: scores}}``."""
    folder, names = GROUPS[group]
    settings = {"nlb_spectral": spectral_args, "nlb": [], "abc": []}
    rows: dict[str, dict] = {name: {} for name in names}
    renders: dict = {}
    for method in METHODS:
        key = _digest(group, plan, method, settings[method], render, RENDER.spp, RENDER.resolution)
        cell_dir = work / f"{group}_{plan}_{method}_{key}"
        done = cell_dir / "scores.json"
        if done.is_file():
            for name, scores in json.loads(done.read_text()).items():
                rows[name][method] = scores
            continue
        print(f"[{group} {plan}] {method} ...", flush=True)
        fit_s = {}
        if method == "abc":
            checkpoints = {}
            for name in names:
                checkpoints[name], fit_s[name] = _fit_abc(folder, name, plan, cell_dir / "runs" / name)
        else:
            checkpoint, per_material = _fit_batch(method, folder, names, plan, cell_dir / "run", settings[method])
            checkpoints = {name: checkpoint for name in names}
            fit_s = {name: per_material for name in names}
        scores = {}
        for name in names:
            model = cell_dir / f"{name}.onnx"
            export_checkpoint(checkpoints[name], model, None if method == "abc" else name)
            if name not in truths:
                truths[name] = work / "truths" / f"{name}.onnx"
                if not truths[name].is_file():
                    export_truth(str(folder / f"{name}.h5"), truths[name])
            result = evaluate(model, truths[name], cell_dir / "eval" / name, RENDER, render_images=render,
                              truth_renders=renders)
            scores[name] = {k: result.get(k) for k in SCORES} | {"fit_s_per_material": fit_s[name]}
            if render:
                scores[name]["image_noise_delta_e2000_mean"] = result["noise"]["image_delta_e2000_mean"]
        with atomic_write(done) as handle:
            handle.write(json.dumps(scores, indent=2) + "\n")
        for name, value in scores.items():
            rows[name][method] = value
    return rows


def summarise(rows: dict) -> dict:
    """Medians per method and the spectral NLB's wins (log-cos and, when rendered, ΔE)."""
    summary = {}
    for metric in ("hemisphere_logcos_rmse", "image_delta_e2000_mean"):
        values = {m: np.array([r[m][metric] for r in rows.values() if r[m].get(metric) is not None], dtype=float)
                  for m in METHODS}
        if any(len(v) != len(rows) for v in values.values()):
            continue
        summary[metric] = {
            "median": {m: float(np.median(v)) for m, v in values.items()},
            "mean": {m: float(np.mean(v)) for m, v in values.items()},
            "nlb_spectral_beats_abc": float(np.mean(values["nlb_spectral"] < values["abc"])),
            "nlb_spectral_beats_nlb": float(np.mean(values["nlb_spectral"] < values["nlb"])),
            "nlb_beats_abc": float(np.mean(values["nlb"] < values["abc"])),
            "median_nlb_spectral_over_abc": float(np.median(values["nlb_spectral"]) / np.median(values["abc"])),
        }
    return summary


def print_table(results: dict) -> None:
    for label, block in results["groups"].items():
        print(f"\n{label}: hemisphere log-cos RMSE | image ΔE2000 mean (llvm_ad_rgb, {RENDER.spp} spp)")
        print(f"{'material':<28}" + "".join(f"{m:>14}" for m in METHODS) + "  |" + "".join(f"{m:>14}" for m in METHODS))
        for name, row in block["materials"].items():
            logcos = "".join(f"{row[m]['hemisphere_logcos_rmse']:>14.4f}" for m in METHODS)
            delta_e = "".join(f"{row[m]['image_delta_e2000_mean']:>14.2f}" if row[m].get("image_delta_e2000_mean")
                              is not None else f"{'-':>14}" for m in METHODS)
            print(f"{name:<28}{logcos}  |{delta_e}")
        for metric, summary in block["summary"].items():
            medians = ", ".join(f"{m} {v:.4g}" for m, v in summary["median"].items())
            print(f"  {metric}: medians {medians}; nlb_spectral beats abc on {summary['nlb_spectral_beats_abc']:.0%}, "
                  f"the RGB nlb on {summary['nlb_spectral_beats_nlb']:.0%}; median nlb_spectral/abc "
                  f"{summary['median_nlb_spectral_over_abc']:.2f} (RGB nlb beats abc on {summary['nlb_beats_abc']:.0%})")


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--groups", default="rgl_validation,report,merl_held_out")
    parser.add_argument("--plans", default="DS1")
    parser.add_argument("--no-render", action="store_true", help="hemisphere and in-plane scores only (no images)")
    parser.add_argument("--spectral-args", nargs=argparse.REMAINDER, default=[],
                        help="overrides of the spectral NLB fit (last on the command line), e.g. "
                             "--model.channel_prior_weight 0.1")
    parser.add_argument("--work", default=str(REPO / "runs" / "spectral_nlb"), help="cells kept here and reused")
    parser.add_argument("--out", default=str(REPO / "benchmarks" / "spectral_nlb.json"))
    args = parser.parse_args(argv)
    started = time.perf_counter()
    work = Path(args.work)
    truths: dict = {}
    results = {"machine": {"platform": platform.platform()}, "render": None if args.no_render else vars(RENDER),
               "spectral_args": args.spectral_args, "groups": {}}
    for group in args.groups.split(","):
        if not GROUPS[group][0].is_dir():
            print(f"skipping {group}: {GROUPS[group][0]} not found")
            continue
        for plan in args.plans.split(","):
            rows = run_group(group, plan, work, not args.no_render, args.spectral_args, truths)
            results["groups"][f"{group} {plan}"] = {"materials": rows, "summary": summarise(rows)}
    results["wall_time_s"] = time.perf_counter() - started
    with atomic_write(args.out) as handle:
        handle.write(json.dumps(results, indent=2, sort_keys=True) + "\n")
    print_table(results)
    print(f"\n-> {args.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
