"""Accuracy and fit time of the models against their targets (docs/models.md, docs/evaluate.md#metrics, docs/results.md).

    python benchmarks/models.py [--quick] [--only-nlb] [--checkpoint X.ckpt] [--out benchmarks/models.json]

Everything runs through ``train.py`` with the shipped configs, in one process, on this
machine, seeds from the configs:

1. **Spectral MLP** (``configs/spectral_mlp.yaml``) on the shipped virtual ``gold`` and
   ``gonio`` DS1 measurements: median glossy relative RMSE (Eq. 4.3) on the Table 5.1 test split
   at the best checkpoint, and the wall time of the 30-epoch fit.
2. **ABC on known parameters**: a noise-free DS1 table generated from fixed ABC parameters,
   fitted by ``configs/abc.yaml``; hemisphere log-cosine RMSE (docs/evaluate.md#metrics) on the Löw et al. set.
3. **NLB latent fit vs ABC** on the ten MERL proxies held out of pretraining
   (:data:`neuralbrdf.data.proxy_corpus.HELD_OUT`) and the report's five (``../shared/data``):
   hemisphere log-cosine RMSE against the proxy on the Löw set of (a) the latent fit
   (``configs/nlb_latent.yaml``, all materials in one batch) on DS1, DS3 and DS4, and on DS1 with
   the report's recipe (``configs/nlb_latent_report.yaml``), from the centroid start and from one start
   (no screening of starts), (b) an ABC fit on the same DS1
   samples, (c) Löw et al.'s published full-data ABC parameters; wall time of the latent fit of
   one material alone and per material in batches of 15 and of 100 (the 50 proxies on DS1 and
   DS3).  Targets on the held-out subset: (a) DS1 beats (b) on ≥ 80 % with a
   median ≤ 0.75 × (b)'s, beats (c) on ≥ 50 %, DS3 median ≤ 1.3 × DS1's; fits ≤ 5 s single,
   ≤ 1 s per material batched.
4. **Pretraining** of the shipped checkpoint, if its run directory is given with
   ``--pretrain-run DIR``: wall time (``DIR/metrics.json``) and the validation curve (log-cosine
   RMSE after each epoch, ``DIR/metrics.csv``), drawn to ``--curve-png``.

Writes JSON (``--out``) and prints a table.  ``--quick`` shortens the runs (smoke test only:
its numbers are not the benchmark).
"""

from __future__ import annotations

import argparse
import csv
import json
import platform
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import torch

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

from neuralbrdf.atomic import atomic_write  # noqa: E402
from neuralbrdf.data.nbrdf import REPORT_MATERIALS, NbrdfNetwork, available_materials, sample_plan  # noqa: E402
from neuralbrdf.data.proxy_corpus import HELD_OUT  # noqa: E402
from neuralbrdf.data.plans import in_plane_plan, plan_spherical  # noqa: E402
from neuralbrdf.data.table import BrdfTable, write_table  # noqa: E402
from neuralbrdf.fitting.abc_fit import fit_abc  # noqa: E402
from neuralbrdf.geometry import inplane_to_spherical, inplane_to_vectors, spherical_pair_to_vectors  # noqa: E402
from neuralbrdf.lightning.run import main as train_main  # noqa: E402
from neuralbrdf.metrics import hemisphere_logcos_rmse  # noqa: E402
from neuralbrdf.shipped import resolve_pretrained  # noqa: E402
from neuralbrdf.data.low2012 import load_low2012_parameters  # noqa: E402
from neuralbrdf.physics.abc import abc_brdf  # noqa: E402

SHARED_DATA = REPO.parent / "shared" / "data"
KNOWN_ABC = dict(kd=[0.05, 0.1, 0.2], A=[8.0, 6.0, 4.0], B=300.0, C=1.3, eta=1.6)
TARGETS = {
    "spectral_mlp_rel_rmse": 0.10,
    "abc_known_logcos_rmse": 0.01,
    "nlb_DS1_beats_abc_DS1_share": 0.8,
    "median_nlb_DS1_over_abc_DS1": 0.75,
    "nlb_DS1_beats_low2012_share": 0.5,
    "median_nlb_DS3_over_nlb_DS1": 1.3,
    "latent_fit_batched_100_per_material_s": 1.0,
    "spectral_mlp_fit_s": 30.0,
    "latent_fit_s": 5.0,
    "abc_fit_s": 5.0,
}


def _train(run_dir: Path, config: str, *overrides: str) -> dict:
    args = ["fit", "--config", str(REPO / "configs" / config), "--run_dir", str(run_dir),
            "--trainer.enable_progress_bar", "false", *overrides]
    threads = torch.get_num_threads()
    status = train_main(args)
    torch.set_num_threads(threads)
    if status != 0:
        raise RuntimeError(f"train.py {' '.join(args)} exited {status}")
    return json.loads((run_dir / "metrics.json").read_text())


def _test(run_dir: Path, config: str, ckpt: Path, *overrides: str) -> dict:
    args = ["test", "--config", str(REPO / "configs" / config), "--ckpt_path", str(ckpt),
            "--trainer.enable_progress_bar", "false", *overrides]
    if train_main(args) != 0:
        raise RuntimeError(f"train.py {' '.join(args)} failed")
    return json.loads((run_dir / "metrics.json").read_text())


def spectral_mlp(work: Path, quick: bool) -> dict:
    results = {}
    for material in ("gold", "gonio"):
        run = work / f"spectral_mlp_{material}"
        extra = ["--trainer.max_epochs", "2"] if quick else []
        fit = _train(run, "spectral_mlp.yaml", "--data.virtual", material, *extra)
        test = _test(run, "spectral_mlp.yaml", run / "checkpoints" / "best.ckpt", "--data.virtual", material)
        results[material] = {
            "test_rel_rmse_glossy_median": test["test/rel_rmse_glossy_median"],
            "fit_wall_time_s": fit["fit/wall_time_s"],
        }
    return results


def abc_known(work: Path) -> dict:
    ti, tr = in_plane_plan("DS1")
    params = {k: np.asarray(v) for k, v in KNOWN_ABC.items()}
    path = work / "abc_known_DS1.csv"
    write_table(BrdfTable(*inplane_to_spherical(ti, tr), abc_brdf(*inplane_to_vectors(ti, tr), **params)), path)
    metrics = _train(work / "abc_known", "abc.yaml", "--data.path", str(path), "--data.virtual", "null")
    fitted = metrics["fit/abc/parameters"]
    low = plan_spherical("low")
    wi, wo = spherical_pair_to_vectors(*low)
    truth = abc_brdf(wi, wo, **params)
    pred = abc_brdf(wi, wo, **{k: np.asarray(fitted[k]) for k in ("kd", "A", "B", "C", "eta")})
    return {
        "hemisphere_logcos_rmse": hemisphere_logcos_rmse(pred, truth, low[0]),
        "success": metrics["fit/abc/success"],
        "fit_wall_time_s": metrics["fit/train/wall_time_s"],
    }


#: NLB columns of the table: the default fit per plan, then DS1 with the report's recipe, from the
#: centroid, and from one start (the best code, no screening).
NLB_COLUMNS = ("nlb_DS1", "nlb_DS3", "nlb_DS4", "nlb_DS1_report_recipe", "nlb_DS1_centroid_start", "nlb_DS1_one_start")


def _latent_fit(work: Path, run: str, sources: list[dict], *overrides: str) -> dict:
    """``configs/nlb_latent.yaml`` fitted to ``sources``, its ``metrics.json``."""
    return _train(work / run, "nlb_latent.yaml", "--data.sources", json.dumps(sources), *overrides)


def nlb_vs_abc(work: Path, quick: bool, checkpoint: str | None, plans=("DS1", "DS3", "DS4"), timing=True,
               latent_prior_weight: float | None = None) -> dict:
    """NLB latent fits (DS1, DS3, DS4) against ABC on the held-out subset and the report's five.

    Hemisphere log-cosine RMSE against the NBRDF proxy on the Löw et al. set, for: the NLB
    latent fit (every material in one batch per plan), an ABC fit of the same DS1 samples, and
    Löw et al.'s published full-data ABC; and the fit times (batched and single-material).
    """
    nbrdf_dir = SHARED_DATA / "merl-nbrdf"
    low2012 = load_low2012_parameters(SHARED_DATA / "abc-low2012" / "low2012_abc_merl.csv")
    names = (*HELD_OUT, *REPORT_MATERIALS)
    if quick:
        names = names[:2]
    overrides = ["--trainer.max_epochs", "1", "--data.steps_per_epoch", "20"] if quick else []
    if checkpoint:
        overrides += ["--model.checkpoint", checkpoint]
    if latent_prior_weight is not None:
        overrides += ["--model.latent_prior_weight", str(latent_prior_weight)]
    sources = [{"nbrdf": str(nbrdf_dir / f"{name}.h5")} for name in names]
    fits = {plan: _latent_fit(work, f"latent_{plan}", sources, "--data.plan", plan, *overrides) for plan in plans}
    report_recipe = _latent_fit(work, "latent_DS1_report", sources, "--config",
                                str(REPO / "configs" / "nlb_latent_report.yaml"), *overrides)
    centroid = _latent_fit(work, "latent_DS1_centroid", sources, "--model.init_candidates", "0",
                           "--model.init_starts", "1", *overrides)
    one_start = _latent_fit(work, "latent_DS1_one_start", sources, "--model.init_starts", "1", *overrides)
    rows = {}
    low_angles = plan_spherical("low")
    for name in names:
        network = NbrdfNetwork.load(nbrdf_dir / f"{name}.h5")
        truth = sample_plan(network, "low")
        wi, wo = truth.vectors()
        abc = fit_abc(sample_plan(network, "DS1"))
        rows[name] = {
            **{f"nlb_{plan}": fits[plan][f"fit/plan_logcos_rmse/{name}"] for plan in fits},
            "nlb_DS1_report_recipe": report_recipe[f"fit/plan_logcos_rmse/{name}"],
            "nlb_DS1_centroid_start": centroid[f"fit/plan_logcos_rmse/{name}"],
            "nlb_DS1_one_start": one_start[f"fit/plan_logcos_rmse/{name}"],
            "abc_DS1": hemisphere_logcos_rmse(abc.parameters.evaluate(wi, wo), truth.values, low_angles[0]),
            "abc_DS1_success": abc.success,
            "abc_DS1_fit_s": abc.wall_time_s,
            "abc_low2012": hemisphere_logcos_rmse(low2012[name].evaluate(wi, wo), truth.values, low_angles[0]),
            "held_out": name in HELD_OUT,
        }
    fit_s = {
        **{f"batched_{len(names)}_{plan}_per_material": fits[plan]["fit/wall_time_s"] / len(names) for plan in fits},
        f"batched_{len(names)}_DS1_report_recipe_per_material": report_recipe["fit/wall_time_s"] / len(names),
        f"batched_{len(names)}_DS1_centroid_start_per_material": centroid["fit/wall_time_s"] / len(names),
        f"batched_{len(names)}_DS1_one_start_per_material": one_start["fit/wall_time_s"] / len(names),
        "epochs": {plan: fits[plan]["fit/epochs"] for plan in fits},
    }
    if timing:
        single = _latent_fit(work, "latent_single", sources[:1], "--data.eval_plan", "null", *overrides)
        batch = [{"nbrdf": str(nbrdf_dir / f"{n}.h5"), "plan": plan, "name": f"{n}@{plan}"}
                 for n in available_materials(nbrdf_dir) for plan in ("DS1", "DS3")][: 4 if quick else 100]
        batched = _latent_fit(work, "latent_batch100", batch, "--data.eval_plan", "null", *overrides)
        fit_s["single_DS1"] = single["fit/wall_time_s"]
        fit_s[f"batched_{len(batch)}_per_material"] = batched["fit/wall_time_s"] / len(batch)
    return {
        "materials": rows,
        "summary": {group: _summary({n: r for n, r in rows.items() if r["held_out"] == (group == "held_out")})
                    for group in ("held_out", "report")},
        "latent_fit_s": fit_s,
        "checkpoint": str(resolve_pretrained(checkpoint).relative_to(REPO)) if checkpoint is None else checkpoint,
        "latent_prior_weight": latent_prior_weight if latent_prior_weight is not None else "the config's",
    }


def _summary(rows: dict) -> dict:
    """Medians and the targets' win rates over a group of materials."""
    if not rows:
        return {}
    keys = [k for k in (*NLB_COLUMNS, "abc_DS1", "abc_low2012")
            if k in next(iter(rows.values()))]
    column = {k: np.array([r[k] for r in rows.values()]) for k in keys}
    median = {k: float(np.median(v)) for k, v in column.items()}
    summary = {
        "median": median,
        "nlb_DS1_beats_abc_DS1": float(np.mean(column["nlb_DS1"] < column["abc_DS1"])),
        "nlb_DS1_beats_low2012": float(np.mean(column["nlb_DS1"] < column["abc_low2012"])),
        "median_nlb_DS1_over_abc_DS1": median["nlb_DS1"] / median["abc_DS1"],
    }
    if "nlb_DS3" in median:
        summary["median_nlb_DS3_over_nlb_DS1"] = median["nlb_DS3"] / median["nlb_DS1"]
    return summary


def pretraining(run_dir: Path, curve_png: Path | None) -> dict:
    """Wall time and validation curve of a pretraining run (module docstring, item 4)."""
    metrics = json.loads((run_dir / "metrics.json").read_text())
    with (run_dir / "metrics.csv").open() as handle:
        curve = [{"step": int(row["step"]) + 1, "epoch": int(row["epoch"]), "val_logcos_rmse": float(row["val/logcos_rmse"])}
                 for row in csv.DictReader(handle) if row.get("val/logcos_rmse")]
    if curve_png is not None and curve:
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt

        fig, ax = plt.subplots(figsize=(5.0, 3.2), dpi=100)
        ax.plot([p["step"] for p in curve], [p["val_logcos_rmse"] for p in curve], "o-", ms=3)
        ax.set(xlabel="optimiser steps of this run", ylabel="validation log-cos RMSE",
               title=f"NLB pretraining ({metrics['fit/wall_time_s'] / 60:.0f} min)")
        ax.grid(alpha=0.3)
        fig.tight_layout()
        with atomic_write(curve_png, "wb") as handle:
            fig.savefig(handle, format="png")
        plt.close(fig)
    return {"run_dir": str(run_dir), "wall_time_s": metrics["fit/wall_time_s"], "curve": curve}


def print_table(results: dict) -> None:
    if "spectral_mlp" in results:
        _print_spectral_and_abc(results)
    _print_nlb(results)


def _print_spectral_and_abc(results: dict) -> None:
    print("\nSpectral MLP (virtual DS1, Table 5.1 test split, best checkpoint)")
    print(f"{'material':<10}{'median glossy rel. RMSE':>26}{'fit s':>9}   target ≤ 0.10, ≤ 30 s")
    for name, row in results["spectral_mlp"].items():
        print(f"{name:<10}{row['test_rel_rmse_glossy_median']:>26.4f}{row['fit_wall_time_s']:>9.1f}")
    abc = results["abc_known"]
    print(f"\nABC on known parameters (noise-free DS1): hemisphere log-cos RMSE {abc['hemisphere_logcos_rmse']:.5f} "
          f"(target ≤ 0.01), success {abc['success']}, fit {abc['fit_wall_time_s']:.2f} s (target ≤ 5 s)")


def _cells(row: dict) -> str:
    keys = (*NLB_COLUMNS, "abc_DS1", "abc_low2012")
    return "".join(f"{row[k]:>9.4f}" if k in row else f"{'-':>9}" for k in keys)


def _print_nlb(results: dict) -> None:
    if "nlb_vs_abc" in results:
        nlb = results["nlb_vs_abc"]
        print(f"\nHemisphere log-cos RMSE on the Löw set against the MERL proxies ({nlb['checkpoint']})")
        head = (f"{'material':<26}{'NLB DS1':>9}{'NLB DS3':>9}{'NLB DS4':>9}{'DS1 rep.':>9}{'DS1 ctr.':>9}{'DS1 1st.':>9}"
                f"{'ABC DS1':>9}{'Löw ABC':>9}  NLB<ABC NLB<Löw")
        for group in ("held_out", "report"):
            print(f"-- {'held-out subset' if group == 'held_out' else 'report materials'}\n{head}")
            for name, row in nlb["materials"].items():
                if row["held_out"] != (group == "held_out"):
                    continue
                print(f"{name:<26}{_cells(row)}"
                      f"  {str(row['nlb_DS1'] < row['abc_DS1']):>7} {str(row['nlb_DS1'] < row['abc_low2012']):>7}")
            summary = nlb["summary"][group]
            if summary:
                m = summary["median"]
                print(f"{'median':<26}{_cells(m)}")
                print(f"NLB DS1 beats ABC DS1 on {summary['nlb_DS1_beats_abc_DS1']:.0%} (target ≥ 80 %), "
                      f"Löw on {summary['nlb_DS1_beats_low2012']:.0%} (≥ 50 %); median NLB DS1 / ABC DS1 "
                      f"{summary['median_nlb_DS1_over_abc_DS1']:.2f} (≤ 0.75), NLB DS3 / DS1 "
                      f"{summary.get('median_nlb_DS3_over_nlb_DS1', float('nan')):.2f} (≤ 1.3)")
        print("latent fit wall time (s): " + ", ".join(
            f"{k} {v:.2f}" for k, v in nlb["latent_fit_s"].items() if k != "epochs")
              + " (targets: single ≤ 5 s, batched 100 ≤ 1 s per material)")
    if "pretraining" in results:
        run = results["pretraining"]
        last = run["curve"][-1] if run["curve"] else {"step": 0, "val_logcos_rmse": float("nan")}
        print(f"\nNLB pretraining: {run['wall_time_s'] / 3600:.2f} h (target ≤ 2 h), {last['step']} steps, "
              f"final validation log-cos RMSE {last['val_logcos_rmse']:.4f}")


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0], allow_abbrev=False)
    parser.add_argument("--quick", action="store_true", help="short runs: a smoke test, not the benchmark")
    parser.add_argument("--out", default=str(REPO / "benchmarks" / "models.json"), help="JSON output")
    parser.add_argument("--pretrain-run", help="run directory of the pretraining (wall time, validation curve)")
    parser.add_argument("--curve-png", help="where to draw the pretraining curve (with --pretrain-run)")
    parser.add_argument("--checkpoint", help="pretrained NLB checkpoint (default: the shipped one)")
    parser.add_argument("--only-nlb", action="store_true", help="only the NLB-vs-ABC section")
    parser.add_argument("--plans", default="DS1,DS3,DS4", help="plans of the NLB latent fits (comma-separated)")
    parser.add_argument("--skip-timing", action="store_true", help="no single / 100-material timing fits")
    parser.add_argument("--latent-prior-weight", type=float,
                        help="the NLB fits' model.latent_prior_weight (default: the config's; 0 to reproduce "
                             "the measurements of other networks made before the prior)")
    args = parser.parse_args(argv)
    started = time.perf_counter()
    results = {
        "machine": {"platform": platform.platform(), "cpus": torch.get_num_threads(), "torch": torch.__version__},
        "quick": args.quick,
        "targets": TARGETS,
    }
    with tempfile.TemporaryDirectory() as tmp:
        work = Path(tmp)
        if not args.only_nlb:
            results["spectral_mlp"] = spectral_mlp(work, args.quick)
            results["abc_known"] = abc_known(work)
        if (SHARED_DATA / "merl-nbrdf").is_dir():
            results["nlb_vs_abc"] = nlb_vs_abc(work, args.quick, args.checkpoint, tuple(args.plans.split(",")),
                                               not args.skip_timing, args.latent_prior_weight)
    if args.pretrain_run:
        results["pretraining"] = pretraining(Path(args.pretrain_run), args.curve_png and Path(args.curve_png))
    results["total_wall_time_s"] = time.perf_counter() - started
    with atomic_write(args.out) as handle:
        handle.write(json.dumps(results, indent=2, sort_keys=True) + "\n")
    print_table(results)
    print(f"\n-> {args.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
