"""The latent prior's weight, swept (docs/models.md, *NLB latent prior*).

    python benchmarks/latent_prior_sweep.py [--checkpoints nlb_latent32_blends,nlb_compact]
        [--weights 0,0.001,0.003,0.01,0.03,0.1,1] [--codes all|measured] [--plans DS1]
        [--out benchmarks/latent_prior_sweep.json]

For each pretrained network, plan and weight: ``configs/nlb_latent.yaml`` (the default fit, all
15 materials in one batch) with ``--model.latent_prior_weight W`` fitted to the ten held-out MERL
proxies and the report's five, each scored by the hemisphere log-cosine RMSE against its proxy on
the Löw et al. set (as ``benchmarks/models.py``).  Prints the median and mean per group, wins
against the in-plane ABC fit and Löw's full-data fit (from ``--abc-json``, a
``benchmarks/models.py`` output), and the weight a leave-one-out choice would take: for each of
the 15 materials, the weight with the lowest mean (or median) error over the other 14, and that
material's error at it — an estimate of the error of a weight chosen by validation, since the
held-out materials were seen when the default weight was chosen.  Writes JSON (``--out``).
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO / "benchmarks"))

from models import SHARED_DATA, _latent_fit  # noqa: E402

from neuralbrdf.atomic import atomic_write  # noqa: E402
from neuralbrdf.data.nbrdf import REPORT_MATERIALS  # noqa: E402
from neuralbrdf.data.proxy_corpus import HELD_OUT  # noqa: E402

MATERIALS = (*HELD_OUT, *REPORT_MATERIALS)


def sweep(checkpoints, weights, codes, plans) -> list[dict]:
    """One row per (network, plan, weight): the per-material hemisphere log-cos RMSE."""
    sources = [{"nbrdf": str(SHARED_DATA / "merl-nbrdf" / f"{name}.h5")} for name in MATERIALS]
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        for checkpoint in checkpoints:
            for plan in plans:
                for weight in weights:
                    run = f"{checkpoint}_{plan}_{weight}"
                    metrics = _latent_fit(Path(tmp), run, sources, "--data.plan", plan, "--model.checkpoint", checkpoint,
                                          "--model.latent_prior_weight", str(weight), "--model.latent_prior_codes", codes)
                    rows.append({"checkpoint": checkpoint, "plan": plan, "weight": weight, "codes": codes,
                                 "materials": {n: metrics[f"fit/plan_logcos_rmse/{n}"] for n in MATERIALS},
                                 "fit_s_per_material": metrics["fit/wall_time_s"] / len(MATERIALS)})
    return rows


def leave_one_out(rows: list[dict], statistic) -> dict:
    """For each material, the weight whose ``statistic`` over the other materials is lowest, and
    the material's error at that weight."""
    chosen = {}
    for name in MATERIALS:
        best = min(rows, key=lambda r: statistic([v for n, v in r["materials"].items() if n != name]))
        chosen[name] = {"weight": best["weight"], "error": best["materials"][name]}
    return chosen


def summarise(rows: list[dict], abc: dict | None) -> dict:
    summary = {}
    for row in rows:
        held = [row["materials"][n] for n in HELD_OUT]
        report = [row["materials"][n] for n in REPORT_MATERIALS]
        row["held_out"] = {"median": float(np.median(held)), "mean": float(np.mean(held))}
        row["report"] = {"median": float(np.median(report)), "mean": float(np.mean(report))}
        if abc:
            row["held_out"]["wins_vs_abc_DS1"] = sum(row["materials"][n] < abc[n]["abc_DS1"] for n in HELD_OUT)
            row["held_out"]["wins_vs_low2012"] = sum(row["materials"][n] < abc[n]["abc_low2012"] for n in HELD_OUT)
    for key in {(r["checkpoint"], r["plan"]) for r in rows}:
        group = [r for r in rows if (r["checkpoint"], r["plan"]) == key]
        entry = {}
        for name, statistic in (("mean", np.mean), ("median", np.median)):
            chosen = leave_one_out(group, statistic)
            held = [chosen[n]["error"] for n in HELD_OUT]
            entry[f"by_{name}"] = {"held_out_median": float(np.median(held)), "held_out_mean": float(np.mean(held)),
                                   "weights": {n: chosen[n]["weight"] for n in MATERIALS}}
        summary[f"{key[0]} {key[1]}"] = entry
    return summary


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0], allow_abbrev=False)
    parser.add_argument("--checkpoints", default="nlb_latent32_blends,nlb_compact")
    parser.add_argument("--weights", default="0,0.001,0.003,0.01,0.03,0.1,1")
    parser.add_argument("--codes", default="all", choices=("measured", "all"), help="model.latent_prior_codes")
    parser.add_argument("--plans", default="DS1")
    parser.add_argument("--abc-json", default=str(REPO / "benchmarks" / "models.json"),
                        help="benchmarks/models.py output with the ABC columns")
    parser.add_argument("--out", default=str(REPO / "benchmarks" / "latent_prior_sweep.json"))
    args = parser.parse_args(argv)
    weights = [float(w) for w in args.weights.split(",")]
    rows = sweep(args.checkpoints.split(","), weights, args.codes, args.plans.split(","))
    abc_path = Path(args.abc_json)
    abc = json.loads(abc_path.read_text())["nlb_vs_abc"]["materials"] if abc_path.is_file() else None
    leave_out = summarise(rows, abc)
    with atomic_write(args.out) as handle:
        handle.write(json.dumps({"rows": rows, "leave_one_out": leave_out}, indent=2, sort_keys=True) + "\n")
    print("network | plan | weight | held-out median / mean | wins vs ABC DS1, Löw | report's five median / mean")
    for r in rows:
        h, p = r["held_out"], r["report"]
        wins = f"{h['wins_vs_abc_DS1']}/10, {h['wins_vs_low2012']}/10" if abc else "-"
        print(f"{r['checkpoint']} | {r['plan']} | {r['weight']:g} | {h['median']:.4f} / {h['mean']:.4f} | {wins} | "
              f"{p['median']:.4f} / {p['mean']:.4f}")
    for key, entry in sorted(leave_out.items()):
        for name, chosen in entry.items():
            print(f"leave-one-out {key}, weight {name.replace('_', ' ')}: held-out median {chosen['held_out_median']:.4f}, "
                  f"mean {chosen['held_out_mean']:.4f}, weights {sorted(set(chosen['weights'].values()))}")
    print(f"\n-> {args.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
