"""Accuracy and fit time of the models against the targets of the models issue (SPEC §4, §5, §8).

    python benchmarks/models.py [--quick] [--out benchmarks/models.json]

Everything runs through ``train.py`` with the shipped configs, in one process, on this
machine, seeds from the configs:

1. **Spectral MLP** (``configs/spectral_mlp.yaml``) on the shipped virtual ``gold`` and
   ``gonio`` DS1 measurements: median glossy relative RMSE (Eq. 4.3) on the Table 5.1 test split
   at the best checkpoint, and the wall time of the 30-epoch fit.
2. **ABC on known parameters**: a noise-free DS1 table generated from fixed ABC parameters,
   fitted by ``configs/abc.yaml``; hemisphere log-cosine RMSE (SPEC §5) on the Löw et al. set.
3. **NLB latent fit vs ABC** on the report's five MERL proxies (``../shared/data``): hemisphere
   log-cosine RMSE on the Löw set of (a) the latent fit on DS1 (``configs/nlb_latent.yaml``),
   (b) an ABC fit on the same DS1 samples, (c) Löw et al.'s published full-data ABC parameters,
   (d) a latent fit on the full Löw set.  Goals: (a) < (b) on every material, (a) ≤ 1.15 × (d).
4. **Pretraining wall time** read from the shipped checkpoint's run, if its ``metrics.json`` is
   given with ``--pretrain-metrics``.

Writes JSON (``--out``) and prints a table.  ``--quick`` shortens the runs (smoke test only:
its numbers are not the benchmark).
"""

from __future__ import annotations

import argparse
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
from neuralbrdf.data.nbrdf import REPORT_MATERIALS, NbrdfNetwork, sample_plan  # noqa: E402
from neuralbrdf.data.plans import in_plane_plan, plan_spherical  # noqa: E402
from neuralbrdf.data.table import BrdfTable, write_table  # noqa: E402
from neuralbrdf.fitting.abc_fit import fit_abc  # noqa: E402
from neuralbrdf.geometry import inplane_to_spherical, inplane_to_vectors, spherical_pair_to_vectors  # noqa: E402
from neuralbrdf.lightning.run import main as train_main  # noqa: E402
from neuralbrdf.metrics import hemisphere_logcos_rmse  # noqa: E402
from neuralbrdf.models.abc import abc_brdf, load_low2012_parameters  # noqa: E402

SHARED_DATA = REPO.parent / "shared" / "data"
KNOWN_ABC = dict(kd=[0.05, 0.1, 0.2], A=[8.0, 6.0, 4.0], B=300.0, C=1.3, eta=1.6)
TARGETS = {
    "spectral_mlp_rel_rmse": 0.10,
    "abc_known_logcos_rmse": 0.01,
    "ds1_over_low_ratio": 1.15,
    "spectral_mlp_fit_s": 30.0,
    "latent_fit_s": 5.0,
    "abc_fit_s": 5.0,
}


def _train(run_dir: Path, config: str, *overrides: str) -> dict:
    args = ["fit", "--config", str(REPO / "configs" / config), "--run_dir", str(run_dir), *overrides]
    threads = torch.get_num_threads()
    status = train_main(args)
    torch.set_num_threads(threads)
    if status != 0:
        raise RuntimeError(f"train.py {' '.join(args)} exited {status}")
    return json.loads((run_dir / "metrics.json").read_text())


def _test(run_dir: Path, config: str, ckpt: Path, *overrides: str) -> dict:
    args = ["test", "--config", str(REPO / "configs" / config), "--ckpt_path", str(ckpt), *overrides]
    if train_main(args) != 0:
        raise RuntimeError(f"train.py {' '.join(args)} failed")
    return json.loads((run_dir / "metrics.json").read_text())


def spectral_mlp(work: Path, quick: bool) -> dict:
    results = {}
    for material in ("gold", "gonio"):
        run = work / f"spectral_mlp_{material}"
        extra = ["--trainer.max_epochs", "2"] if quick else []
        fit = _train(run, "spectral_mlp.yaml", "--data.virtual_material", material, *extra)
        test = _test(run, "spectral_mlp.yaml", run / "checkpoints" / "best.ckpt", "--data.virtual_material", material)
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


def nlb_vs_abc(work: Path, quick: bool) -> dict:
    nbrdf_dir = SHARED_DATA / "merl-nbrdf"
    low2012 = load_low2012_parameters(SHARED_DATA / "abc-low2012" / "low2012_abc_merl.csv")
    steps = ["--trainer.max_epochs", "1", "--data.steps_per_epoch", "20"] if quick else []
    ds1 = _train(work / "latent_DS1", "nlb_latent.yaml", *steps)
    low = _train(work / "latent_low", "nlb_latent.yaml", "--data.plan", "low", "--data.batch_size", "65536", *steps)
    rows = {}
    low_angles = plan_spherical("low")
    for name in REPORT_MATERIALS:
        network = NbrdfNetwork.load(nbrdf_dir / f"{name}.h5")
        truth = sample_plan(network, "low")
        wi, wo = truth.vectors()
        abc = fit_abc(sample_plan(network, "DS1"))
        rows[name] = {
            "nlb_DS1": ds1[f"fit/hemisphere_logcos_rmse/{name}"],
            "abc_DS1": hemisphere_logcos_rmse(abc.parameters.evaluate(wi, wo), truth.values, low_angles[0]),
            "abc_DS1_success": abc.success,
            "abc_DS1_fit_s": abc.wall_time_s,
            "abc_low2012": hemisphere_logcos_rmse(low2012[name].evaluate(wi, wo), truth.values, low_angles[0]),
            "nlb_low": low[f"fit/hemisphere_logcos_rmse/{name}"],
        }
        rows[name]["ds1_over_low"] = rows[name]["nlb_DS1"] / rows[name]["nlb_low"]
    return {
        "materials": rows,
        "latent_fit_DS1_wall_time_s": ds1["fit/wall_time_s"],
        "latent_fit_DS1_wall_time_per_material_s": ds1["fit/wall_time_s"] / len(REPORT_MATERIALS),
    }


def print_table(results: dict) -> None:
    print("\nSpectral MLP (virtual DS1, Table 5.1 test split, best checkpoint)")
    print(f"{'material':<10}{'median glossy rel. RMSE':>26}{'fit s':>9}   target ≤ 0.10, ≤ 30 s")
    for name, row in results["spectral_mlp"].items():
        print(f"{name:<10}{row['test_rel_rmse_glossy_median']:>26.4f}{row['fit_wall_time_s']:>9.1f}")
    abc = results["abc_known"]
    print(f"\nABC on known parameters (noise-free DS1): hemisphere log-cos RMSE {abc['hemisphere_logcos_rmse']:.5f} "
          f"(target ≤ 0.01), success {abc['success']}, fit {abc['fit_wall_time_s']:.2f} s (target ≤ 5 s)")
    if "nlb_vs_abc" in results:
        nlb = results["nlb_vs_abc"]
        print("\nHemisphere log-cos RMSE on the Löw set (MERL proxies)")
        head = f"{'material':<26}{'NLB DS1':>9}{'ABC DS1':>9}{'Löw ABC':>9}{'NLB Low':>9}{'DS1/Low':>9}  NLB<ABC"
        print(head)
        for name, row in nlb["materials"].items():
            print(f"{name:<26}{row['nlb_DS1']:>9.4f}{row['abc_DS1']:>9.4f}{row['abc_low2012']:>9.4f}"
                  f"{row['nlb_low']:>9.4f}{row['ds1_over_low']:>9.2f}  {row['nlb_DS1'] < row['abc_DS1']}")
        print(f"latent fit of all five in one batch: {nlb['latent_fit_DS1_wall_time_s']:.1f} s "
              f"({nlb['latent_fit_DS1_wall_time_per_material_s']:.1f} s per material; target ≤ 5 s)")
    if "pretraining_wall_time_s" in results:
        print(f"\nNLB pretraining: {results['pretraining_wall_time_s'] / 3600:.2f} h (target ≤ 2 h)")


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--quick", action="store_true", help="short runs: a smoke test, not the benchmark")
    parser.add_argument("--out", default=str(REPO / "benchmarks" / "models.json"), help="JSON output")
    parser.add_argument("--pretrain-metrics", help="metrics.json of the pretraining run (for its wall time)")
    args = parser.parse_args(argv)
    started = time.perf_counter()
    results = {
        "machine": {"platform": platform.platform(), "cpus": torch.get_num_threads(), "torch": torch.__version__},
        "quick": args.quick,
        "targets": TARGETS,
    }
    with tempfile.TemporaryDirectory() as tmp:
        work = Path(tmp)
        results["spectral_mlp"] = spectral_mlp(work, args.quick)
        results["abc_known"] = abc_known(work)
        if (SHARED_DATA / "merl-nbrdf").is_dir():
            results["nlb_vs_abc"] = nlb_vs_abc(work, args.quick)
    if args.pretrain_metrics:
        results["pretraining_wall_time_s"] = json.loads(Path(args.pretrain_metrics).read_text())["fit/wall_time_s"]
    results["total_wall_time_s"] = time.perf_counter() - started
    with atomic_write(args.out) as handle:
        handle.write(json.dumps(results, indent=2, sort_keys=True) + "\n")
    print_table(results)
    print(f"\n-> {args.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
