"""How the ``auto`` fit decides, and the alternatives it was measured against (docs/design.md
"Never worse than ABC").

    python benchmarks/auto_rules.py [--groups virtual_validation,rgl_validation,rgl_real]
        [--plan DS1] [--work runs/auto_rules] [--out benchmarks/auto_rules.json]

For every material the ABC fit and the spectral NLB's latent fit of its measurement (``nb.fit`` of
the shipped ``abc`` and ``nlb_spectral`` configs, exported) are evaluated at the measured pairs
and on stratified hemisphere pairs (12 x 16 strata: 36 864 pairs) against the truth.  A rule sees
only the measured pairs: each candidate's and each convex blend's ``(1 - w) f_ABC + w f_NLB``
(``w`` in steps of 0.05) log-cosine RMSE on the samples.  The rules:

* ``choice`` — the candidate with the lower error on the samples (what ``auto`` does);
* ``blend_fitted`` — the blend whose weight fits the samples best;
* ``blend_half`` — the even blend, ``w = 0.5``, whatever the samples say;
* ``choice_hedged_0.1`` / ``choice_hedged_0.25`` — the choice, blended 10 % / 25 % towards the other;
* ``choice_margin_10pct`` — the choice when one candidate's error is 10 % below the other's, else
  the even blend;
* ``abc``, ``nlb_spectral`` — always one candidate; ``oracle`` — the best blend for the hemisphere
  (needs the truth: a bound, not a rule).

For each rule and group: the median hemisphere log-cos RMSE over ABC's, the share of materials
at or below 1.02x ABC and strictly below it, the worst ratio, and the median over the spectral
NLB's.  Groups as in ``benchmarks/auto.py`` (the MERL held-out test set is left out: the rule was
chosen on these).  The fits and predictions are kept in ``--work`` and reused.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

import neuralbrdf as nb  # noqa: E402
from neuralbrdf.atomic import atomic_write  # noqa: E402
from neuralbrdf.evaluation.scores import OnnxEvaluator, compared_values, hemisphere_pairs, truth_evaluator  # noqa: E402
from neuralbrdf.geometry import spherical_to_vector  # noqa: E402
from auto import QUIET, materials  # noqa: E402  (benchmarks/auto.py)

GROUPS = ("virtual_validation", "rgl_validation", "rgl_real")
STRATA = (12, 16)
WEIGHTS = np.round(np.linspace(0.0, 1.0, 21), 2)


def _table_values(evaluator, table) -> np.ndarray:
    wi = spherical_to_vector(table.theta_i, table.phi_i)
    wo = spherical_to_vector(table.theta_o, table.phi_o)
    if table.wavelengths is not None and evaluator.is_spectral:
        n, k = len(wi), len(table.wavelengths)
        return evaluator.values(np.repeat(wi, k, 0), np.repeat(wo, k, 0), np.tile(table.wavelengths, n)).reshape(n, k)
    return evaluator.values(wi, wo, None)


def _logcos(pred, target, cos) -> float:
    return float(np.sqrt(np.mean((np.log1p(cos * np.clip(pred, 0, None)) - np.log1p(cos * target)) ** 2)))


def predictions(name: str, measurement: str, truth: str, plan: str, work: Path) -> dict | None:
    """Both candidates at the measured pairs and on the hemisphere, with the truth there."""
    kept = work / "predictions" / f"{name}_{plan}.npz"
    if kept.is_file():
        return dict(np.load(kept))
    folder = work / "runs" / f"{name}_{plan}"
    source = nb.read(measurement, name=name) if measurement.endswith(".csv") else nb.read(measurement, plan=plan,
                                                                                          name=name)
    models = {}
    for kind in ("abc", "nlb_spectral"):
        try:
            result = nb.fit(kind, source, run_dir=folder / kind, overwrite=True, overrides=QUIET)
        except nb.FitFailed:
            return None
        models[kind] = OnnxEvaluator(result.export(folder / f"{kind}.onnx", fast=False, rgb_head=False).path)
    if truth.endswith(".bsdf"):
        reference = truth_evaluator(truth)
    else:
        path = folder / "truth.onnx"
        nb.truth(truth, path)
        reference = OnnxEvaluator(path)
    spectral = reference.is_spectral and models["nlb_spectral"].is_spectral
    wi, wo = hemisphere_pairs(0, STRATA)
    table = source.samples
    out = {"cos_hemisphere": wi[:, 2:3].copy(), "hemisphere_truth": compared_values(reference, wi, wo, spectral),
           "samples": table.values, "cos_samples": np.cos(np.radians(table.theta_i))[:, None]}
    for kind, model in models.items():
        out[f"hemisphere_{kind}"] = compared_values(model, wi, wo, spectral)
        out[f"samples_{kind}"] = _table_values(model, table)
    kept.parent.mkdir(parents=True, exist_ok=True)
    np.savez_compressed(kept, **{k: v.astype(np.float32) for k, v in out.items()})
    return out


def curves(p: dict) -> tuple[np.ndarray, np.ndarray]:
    """Hemisphere and in-sample log-cos RMSE of every blend weight of :data:`WEIGHTS`."""
    blend = lambda key, w: (1 - w) * p[f"{key}_abc"].astype(np.float64) + w * p[f"{key}_nlb_spectral"]  # noqa: E731
    hemisphere = np.array([_logcos(blend("hemisphere", w), p["hemisphere_truth"], p["cos_hemisphere"]) for w in WEIGHTS])
    samples = np.array([_logcos(blend("samples", w), p["samples"], p["cos_samples"]) for w in WEIGHTS])
    return hemisphere, samples


def rules(hemisphere: np.ndarray, samples: np.ndarray) -> dict[str, float]:
    """The hemisphere error each rule's weight gives (module docstring)."""
    at = lambda w: float(hemisphere[int(round(w * 20))])  # noqa: E731
    nlb_better = samples[-1] < samples[0]
    return {
        "abc": at(0.0), "nlb_spectral": at(1.0), "oracle": float(hemisphere.min()),
        "choice": at(1.0 if nlb_better else 0.0),
        "blend_fitted": float(hemisphere[int(np.argmin(samples))]),
        "blend_half": at(0.5),
        "choice_hedged_0.1": at(0.9 if nlb_better else 0.1),
        "choice_hedged_0.25": at(0.75 if nlb_better else 0.25),
        "choice_margin_10pct": at(1.0) if samples[-1] < 0.9 * samples[0] else at(0.0) if samples[0] < 0.9 * samples[-1]
        else at(0.5),
    }


def summary(by_material: dict[str, dict[str, float]]) -> dict:
    abc = np.array([r["abc"] for r in by_material.values()])
    nlb = np.array([r["nlb_spectral"] for r in by_material.values()])
    out = {}
    for rule in next(iter(by_material.values())):
        value = np.array([r[rule] for r in by_material.values()])
        ratio = value / abc
        out[rule] = {"median_over_abc": float(np.median(ratio)), "within_1.02_abc": float(np.mean(ratio <= 1.02)),
                     "below_abc": float(np.mean(ratio < 1.0)), "worst_over_abc": float(ratio.max()),
                     "median_over_nlb_spectral_median": float(np.median(value) / np.median(nlb))}
    return out


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0], allow_abbrev=False)
    parser.add_argument("--groups", default=",".join(GROUPS))
    parser.add_argument("--plan", default="DS1")
    parser.add_argument("--work", default=str(REPO / "runs" / "auto_rules"))
    parser.add_argument("--out", default=str(REPO / "benchmarks" / "auto_rules.json"))
    args = parser.parse_args(argv)
    work = Path(args.work)
    results = {"command": "python benchmarks/auto_rules.py " + " ".join(argv or sys.argv[1:]), "plan": args.plan,
               "hemisphere_strata": list(STRATA), "groups": {}}
    pooled: dict[str, dict[str, float]] = {}
    for group in args.groups.split(","):
        rows = {}
        for name, measurement, truth in materials(group, args.plan, work):
            print(f"[{group}] {name} ...", flush=True)
            p = predictions(name, measurement, truth, args.plan, work)
            if p is None:
                continue
            hemisphere, samples = curves(p)
            rows[name] = rules(hemisphere, samples) | {"weight_fitted": float(WEIGHTS[int(np.argmin(samples))]),
                                                       "weight_oracle": float(WEIGHTS[int(np.argmin(hemisphere))]),
                                                       "samples_abc": float(samples[0]),
                                                       "samples_nlb_spectral": float(samples[-1])}
        rule_rows = {n: {k: v for k, v in r.items() if not k.startswith(("weight_", "samples_"))} for n, r in rows.items()}
        pooled |= {f"{group}/{n}": r for n, r in rule_rows.items()}
        results["groups"][group] = {"materials": rows, "summary": summary(rule_rows)}
    validation = {k: v for k, v in pooled.items() if not k.startswith("rgl_real/")}
    results["validation_pooled"] = summary(validation) if validation else None
    with atomic_write(Path(args.out)) as handle:
        handle.write(json.dumps(results, indent=1) + "\n")
    for label, block in [*((g, b["summary"]) for g, b in results["groups"].items()),
                         ("validation (virtual + RGL proxies)", results["validation_pooled"])]:
        if not block:
            continue
        print(f"\n{label}: rule, median/ABC, <=1.02 ABC, <ABC, worst/ABC, median/NLB median")
        for rule, s in block.items():
            print(f"  {rule:<22}{s['median_over_abc']:7.3f}{s['within_1.02_abc']:7.2f}{s['below_abc']:7.2f}"
                  f"{s['worst_over_abc']:7.2f}{s['median_over_nlb_spectral_median']:7.3f}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
