"""Build the PCA prior's basis (docs/models.md#pca) and choose its size and ridge weight on
validation materials.

    python benchmarks/pca_basis.py [--nodes 48x24x8] [--components 32] [--mapping log1p]
        [--out neuralbrdf/pretrained/pca_basis.npz] [--json benchmarks/pca_basis.json] [--no-sweep]

1. **The basis**: every RGB channel of every training proxy — the MERL and RGL NBRDF proxies of
   ``../shared/data`` outside ``NEVER_PRETRAINED`` (``neuralbrdf.models.pca_brdf.training_proxies``)
   — evaluated at the table's nodes, mapped and reduced to its principal components
   (``build_basis``); the first ``--components`` are written to ``--out``.
2. **The sweep** (skipped with ``--no-sweep``): on the nine RGL validation proxies
   (``RGL_VALIDATION``, never in the basis) sampled on DS1, DS3 and DS4, each channel's
   coefficients fitted by ``fit_channels`` for every mapping × K × ridge weight of the grid below,
   and the fitted table's hemisphere log-cosine RMSE against the proxy on 6 400 stratified pairs
   (``hemisphere_pairs(0, (8, 10))``, a quick stand-in for ``neuralbrdf evaluate``'s 102 400).
   The prior-scaled ridge (``λ Σ (c_k / s_k)²``, the shipped form) is compared with a plain one
   (``λ ‖c‖²``).  Also: how well the basis reproduces the training materials themselves (a
   dense fit from their own node values) — the basis's floor.

The shipped choice (``configs/pca.yaml``) is the setting whose mean over the three plans of the
median over materials is lowest, preferring fewer components within 1 %.
"""

from __future__ import annotations

import argparse
import json
import platform
import sys
import time
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

import torch  # noqa: E402

from neuralbrdf.atomic import atomic_write  # noqa: E402
from neuralbrdf.data.nbrdf import NbrdfNetwork, sample_plan  # noqa: E402
from neuralbrdf.data.proxy_corpus import RGL_VALIDATION  # noqa: E402
from neuralbrdf.evaluation.scores import hemisphere_pairs  # noqa: E402
from neuralbrdf.metrics import hemisphere_logcos_rmse  # noqa: E402
from neuralbrdf.models import pca_brdf  # noqa: E402

SHARED = REPO.parent / "shared" / "data"
PLANS = ("DS1", "DS3", "DS4")
SWEEP = {
    "mapping": (("log1p", 1e-3), ("nielsen", 1e-2)),
    "components": (8, 16, 24, 32, 48),
    "ridge": (0.0, 0.001, 0.002, 0.003, 0.005, 0.01, 0.02, 0.05, 0.1, 0.2),
    "plain_ridge": (0.001, 0.01, 0.1, 1.0),
}
STRATA = (8, 10)


def training_channels(nodes):
    """``(names, channels [3 M, P])`` of the training proxies at the nodes."""
    proxies = pca_brdf.training_proxies([SHARED / "merl-nbrdf", SHARED / "rgl-nbrdf"])
    values = np.stack([pca_brdf.proxy_node_values(file, nodes) for _, file in proxies])  # [M, P, 3]
    return [name for name, _ in proxies], values.transpose(0, 2, 1).reshape(-1, values.shape[1])


def with_scales(basis, scales):
    return pca_brdf.PcaBasis(basis.nodes, basis.mapping, basis.epsilon, basis.mean, basis.components, scales,
                             basis.explained_variance_ratio, basis.value_range, basis.materials)


def sweep(channels, names, nodes) -> dict:
    wi_h, wo_h = hemisphere_pairs(0, STRATA)
    theta_i = np.degrees(np.arccos(wi_h[:, 2]))
    wi_t, wo_t = torch.as_tensor(wi_h, dtype=torch.float32), torch.as_tensor(wo_h, dtype=torch.float32)
    validation = {}
    for name in RGL_VALIDATION:
        network = NbrdfNetwork.load(SHARED / "rgl-nbrdf" / f"{name}.h5")
        validation[name] = (network.evaluate(wi_h, wo_h), {plan: sample_plan(network, plan) for plan in PLANS})

    def errors(basis, fit_basis, ridge, plan):
        row = {}
        for name, (truth, tables) in validation.items():
            table = tables[plan]
            wi, wo = table.vectors()
            coefficients = pca_brdf.fit_channels(fit_basis, wi, wo, table.values, ridge)
            pred = pca_brdf.pca_table(basis, coefficients)(wi_t, wo_t).double().numpy()
            row[name] = hemisphere_logcos_rmse(pred, truth, theta_i)
        return row

    rows = []
    for mapping, epsilon in SWEEP["mapping"]:
        full = pca_brdf.build_basis(channels, names, nodes, max(SWEEP["components"]), mapping, epsilon)
        for k in SWEEP["components"]:
            basis = full.truncated(k)
            settings = [("prior", r, basis) for r in SWEEP["ridge"]]
            if mapping == "log1p":
                settings += [("plain", r, with_scales(basis, np.ones(k))) for r in SWEEP["plain_ridge"]]
            for form, ridge, fit_basis in settings:
                per_plan = {plan: errors(basis, fit_basis, ridge, plan) for plan in PLANS}
                medians = {plan: float(np.median(list(v.values()))) for plan, v in per_plan.items()}
                rows.append({"mapping": mapping, "epsilon": epsilon, "components": k, "ridge_form": form,
                             "ridge": ridge, "median": medians, "mean_of_medians": float(np.mean(list(medians.values()))),
                             "materials": per_plan})
                print(f"{mapping:8} K={k:2d} {form:5} λ={ridge:<6g} " + " ".join(f"{p} {m:.4f}" for p, m in medians.items())
                      + f"  mean {rows[-1]['mean_of_medians']:.4f}", flush=True)
    best = min(r["mean_of_medians"] for r in rows)
    chosen = min((r for r in rows if r["mean_of_medians"] <= 1.01 * best),
                 key=lambda r: (r["components"], r["mean_of_medians"]))
    return {"strata": list(STRATA), "plans": list(PLANS), "materials": list(RGL_VALIDATION), "grid": SWEEP,
            "rows": rows, "best_mean_of_medians": best,
            "chosen": {k: chosen[k] for k in ("mapping", "epsilon", "components", "ridge_form", "ridge", "median",
                                              "mean_of_medians")}}


def self_reconstruction(basis, channels) -> dict:
    """Each training channel projected on the first K components (the ridge-0 fit from its own node
    values): the basis's floor, as the median and largest RMSE of ``ln(1 + f)`` over the nodes."""
    y = np.log1p(channels)
    projected = pca_brdf.to_mapped(channels.T, pca_brdf.node_cosines(basis.nodes), basis.mapping, basis.epsilon).T
    out = {}
    for k in sorted({8, 16, 24, basis.n_components} & set(range(1, basis.n_components + 1))):
        truncated = basis.truncated(k)
        coefficients = (projected - truncated.mean) @ truncated.components.T
        rebuilt = pca_brdf.node_values(truncated, coefficients).reshape(-1, len(channels)).T
        rmse = np.sqrt(np.mean((np.log1p(rebuilt) - y) ** 2, axis=1))
        out[str(k)] = {"median_log1p_rmse": float(np.median(rmse)), "max_log1p_rmse": float(rmse.max())}
    return out


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0], allow_abbrev=False)
    parser.add_argument("--nodes", default="48x24x8")
    parser.add_argument("--components", type=int, default=32)
    parser.add_argument("--mapping", default="log1p", choices=pca_brdf.MAPPINGS)
    parser.add_argument("--epsilon", type=float, default=1e-3, help="ε of the nielsen mapping")
    parser.add_argument("--out", default=str(pca_brdf.BASIS_FILE))
    parser.add_argument("--json", default=str(REPO / "benchmarks" / "pca_basis.json"))
    parser.add_argument("--no-sweep", action="store_true")
    args = parser.parse_args(argv)
    torch.set_num_threads(1)
    nodes = tuple(int(n) for n in args.nodes.split("x"))
    began = time.time()
    names, channels = training_channels(nodes)
    basis = pca_brdf.build_basis(channels, names, nodes, args.components, args.mapping, args.epsilon)
    sha256 = pca_brdf.save_basis(basis, args.out)
    size = Path(args.out).stat().st_size
    print(f"{args.out}: {len(names)} materials ({len(channels)} channels), nodes {args.nodes}, {args.components} "
          f"components explaining {basis.explained_variance_ratio.sum():.4%} of the variance; {size / 1e6:.2f} MB, "
          f"sha256 {sha256}")
    results = {
        "command": "python benchmarks/pca_basis.py " + " ".join(argv if argv is not None else sys.argv[1:]),
        "machine": {"python": platform.python_version()},
        "basis": {"file": str(Path(args.out).resolve().relative_to(REPO)) if Path(args.out).resolve().is_relative_to(REPO)
                  else args.out, "sha256": sha256, "bytes": size, "nodes": list(nodes), "mapping": args.mapping,
                  "components": args.components, "materials": names, "channels": len(channels),
                  "explained_variance_ratio": basis.explained_variance_ratio.tolist(),
                  "cumulative_explained_variance": np.cumsum(basis.explained_variance_ratio).tolist(),
                  "self_reconstruction": self_reconstruction(pca_brdf.load_basis(args.out), channels)},
    }
    if not args.no_sweep:
        results["sweep"] = sweep(channels, names, nodes)
        chosen = results["sweep"]["chosen"]
        print(f"chosen: {chosen['mapping']} K={chosen['components']} {chosen['ridge_form']} ridge {chosen['ridge']}: "
              + ", ".join(f"{p} {m:.4f}" for p, m in chosen["median"].items()))
    results["wall_s"] = time.time() - began
    with atomic_write(Path(args.json)) as handle:
        handle.write(json.dumps(results, indent=1) + "\n")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
