"""The error estimate of ``neuralbrdf plan next``: calibrated on training materials, its interval checked on validation materials (docs/how-many-measurements.md).

    python benchmarks/acquisition_calibration.py --split training   [--render] [--out ...]
    python benchmarks/acquisition_calibration.py --split validation [--render] [--out ...]

For every material of the split and every plan (DS4, ``design:6``, ``design:12``, DS3), the
material is measured at the plan's pairs with the session noise of
``configs/acquisition/default.yaml``, and ``plan next`` is asked for one pair: its answer carries
the fit's posterior spread ``s`` (:mod:`neuralbrdf.acquisition.next_pairs`).  The fit is scored
against the truth as ``neuralbrdf acquire`` scores it: hemisphere log-cos RMSE and, with
``--render``, the preview scene's mean CIEDE2000 (:func:`neuralbrdf.acquisition.session.true_errors`).

* ``training`` — the prior's training proxies (every fifth of the pretraining MERL and RGL
  proxies, :func:`neuralbrdf.data.proxy_corpus.pretraining_proxy_names`) and the virtual
  instrument's stand-ins: prints the 10 %, 50 % and 90 % quantiles of ``ln(true / s)``, the
  section ``estimate`` of the config.
* ``validation`` — the RGL validation proxies and the virtual validation materials, never seen by
  the prior or the design: prints how often the config's 80 % interval holds the true error.

Every cell is kept in ``--work`` and reused.
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

sys.path.insert(0, str(Path(__file__).resolve().parent))

from acquisition import GROUPS, REPO, SHARED, digest, plan_pairs  # noqa: E402

from neuralbrdf.acquisition.instrument import Instrument  # noqa: E402
from neuralbrdf.acquisition.latent_fit import fit_module  # noqa: E402
from neuralbrdf.acquisition.next_pairs import next_pairs  # noqa: E402
from neuralbrdf.acquisition.session import true_errors  # noqa: E402
from neuralbrdf.acquisition.settings import load_acquisition_config  # noqa: E402
from neuralbrdf.acquisition.truths import TruthMaterial  # noqa: E402
from neuralbrdf.atomic import atomic_write  # noqa: E402
from neuralbrdf.data.plans import Plan  # noqa: E402
from neuralbrdf.data.proxy_corpus import pretraining_proxy_names  # noqa: E402
from neuralbrdf.virtual.materials import MATERIALS  # noqa: E402

PLANS = ("DS4", "design:6", "design:12", "DS3")
QUANTILES = (0.1, 0.5, 0.9)


def training_sources() -> list[str]:
    sources = [f"virtual:{m}" for m in MATERIALS]
    for lab in ("merl-nbrdf", "rgl-nbrdf"):
        folder = SHARED / lab
        if folder.is_dir():
            sources += [str(folder / f"{n}.h5") for n in sorted(pretraining_proxy_names(folder))[::5]]
    return sources


def validation_sources() -> list[str]:
    return [*GROUPS["rgl_validation"](), *GROUPS["virtual_validation"]()] if SHARED.is_dir() else GROUPS["virtual_validation"]()


def cell(source: str, plan: str, config, render: bool, module, work: Path, renders: dict) -> dict:
    ti, tr = plan_pairs(plan, config.design, work)
    session = config.session
    path = work / "calibration" / f"{digest(source, ti.tolist(), tr.tolist(), vars(session), vars(config.design), render)}.json"
    if not path.is_file():
        material = TruthMaterial(source)
        table = material.measure(Plan.of_pairs(ti, tr, plan), session.noise, session.seed)
        answer = next_pairs(table, 1, Instrument(), config.design, config.estimate, module=module, name=material.name)
        with tempfile.TemporaryDirectory() as folder:
            logcos, delta_e = true_errors(material, answer.fitted, session, Path(folder),
                                          renders.setdefault(source, {}) if render else None)
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text(json.dumps({"spread": answer.spread, "logcos": logcos, "delta_e": delta_e}))
    return json.loads(path.read_text())


def coverage(cells: list[dict], key: str, quantiles) -> float:
    """How often ``spread · exp(q10) <= true <= spread · exp(q90)``."""
    held = [c["spread"] * np.exp(quantiles[0]) <= c[key] <= c["spread"] * np.exp(quantiles[2]) for c in cells]
    return float(np.mean(held))


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0], allow_abbrev=False)
    parser.add_argument("--split", choices=("training", "validation"), required=True)
    parser.add_argument("--render", action="store_true", help="also the preview CIEDE2000 (slow)")
    parser.add_argument("--work", default=str(REPO / "runs" / "acquisition"))
    parser.add_argument("--out", default=None, help="default benchmarks/acquisition_calibration_SPLIT.json")
    args = parser.parse_args(argv)
    config = load_acquisition_config()
    sources = training_sources() if args.split == "training" else validation_sources()
    module, renders, cells = fit_module(), {}, []
    started = time.perf_counter()
    for source in sources:
        for plan in PLANS:
            result = cell(source, plan, config, args.render, module, Path(args.work), renders)
            cells.append({"source": Path(source).stem if ":" not in source else source, "plan": plan, **result})
            print(f"{cells[-1]['source']} {plan}: spread {result['spread']:.4f}, log-cos {result['logcos']:.4f}, "
                  f"ΔE {result['delta_e']}", flush=True)
    keys = ["logcos"] + (["delta_e"] if args.render else [])
    ratios = {k: np.log([c[k] / c["spread"] for c in cells]) for k in keys}
    quantiles = {k: [float(q) for q in np.quantile(v, QUANTILES)] for k, v in ratios.items()}
    configured = {"logcos": config.estimate.logcos_quantiles, "delta_e": config.estimate.delta_e_quantiles}
    covered = {k: coverage(cells, k, configured[k]) for k in keys}
    result = {"machine": platform.platform(), "split": args.split, "plans": PLANS, "cells": cells,
              "quantiles_of_log_true_over_spread": quantiles, "configured_quantiles": configured,
              "configured_interval_coverage": covered, "wall_time_s": time.perf_counter() - started}
    out = args.out or str(REPO / "benchmarks" / f"acquisition_calibration_{args.split}.json")
    with atomic_write(out) as handle:
        handle.write(json.dumps(result, indent=2) + "\n")
    print(f"\n{len(cells)} fits of {len(sources)} materials")
    for k in keys:
        print(f"{k}: quantiles {QUANTILES} of ln(true / spread) = [{', '.join(f'{q:.2f}' for q in quantiles[k])}]; "
              f"the config's interval holds the true error on {covered[k]:.0%}")
    print(f"-> {out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
