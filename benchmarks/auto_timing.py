"""Fit time of the ``auto`` fit beside the spectral NLB's single-material fit, in one run
(docs/models.md#auto, docs/results.md).

    python benchmarks/auto_timing.py [--repeats 3] [--out benchmarks/auto_timing.json]

``neuralbrdf train fit`` of ``configs/auto.yaml`` and of ``configs/nlb_spectral.yaml`` (the
baseline), taken in turn ``--repeats`` times each, on

* **spectral**: the shipped DS1 measurement of the virtual gold (31 bands);
* **RGB**: the RGL validation proxy ``paper_green_rgb`` sampled on DS1 (the reference data's
  NBRDF proxy; skipped without it).

Reported: ``fit/wall_time_s`` (the fit proper, not the Python start-up), the medians, their ratio
(the target is 1.5x), ``fit/auto/fit_s`` (each candidate's own time inside the auto fit, run side
by side) and the machine's load average before and after: run it on an otherwise idle machine.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import statistics
import sys
import tempfile
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

from neuralbrdf.atomic import atomic_write  # noqa: E402
from neuralbrdf.lightning.run import main as train_main  # noqa: E402

PROXY = REPO.parent / "shared" / "data" / "rgl-nbrdf" / "paper_green_rgb.h5"
DATA = {"spectral": {"auto": ["--data.virtual", "gold"], "nlb_spectral": ["--data.sources", '[{"virtual": "gold"}]']},
        "rgb": {"auto": ["--data.nbrdf", str(PROXY)], "nlb_spectral": ["--data.sources", json.dumps([{"nbrdf": str(PROXY)}])]}}


def fit_once(config: str, data: list[str], run_dir: Path) -> dict:
    args = ["fit", "--config", config, "--run_dir", str(run_dir), "--overwrite", "--trainer.enable_progress_bar",
            "false", "--data.eval_plan", "null", *data]
    if train_main(args) != 0:
        raise RuntimeError(f"neuralbrdf train {' '.join(args)} failed")
    return json.loads((run_dir / "metrics.json").read_text())


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0], allow_abbrev=False)
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--out", default=str(REPO / "benchmarks" / "auto_timing.json"))
    args = parser.parse_args(argv)
    results = {"command": "python benchmarks/auto_timing.py", "repeats": args.repeats,
               "machine": {"cores": os.cpu_count(), "python": platform.python_version(),
                           "load_average_before": list(os.getloadavg())}, "fits": {}}
    with tempfile.TemporaryDirectory(prefix="neuralbrdf-auto-timing-") as work:
        for table, data in DATA.items():
            if table == "rgb" and not PROXY.is_file():
                continue
            runs = {"auto": [], "nlb_spectral": [], "auto_candidates": []}
            for repeat in range(args.repeats):
                for config in ("nlb_spectral", "auto"):
                    metrics = fit_once(config, data[config], Path(work) / f"{table}_{config}_{repeat}")
                    runs[config].append(metrics["fit/wall_time_s"])
                    if config == "auto":
                        runs["auto_candidates"].append(metrics["fit/auto/fit_s"])
            medians = {k: statistics.median(runs[k]) for k in ("auto", "nlb_spectral")}
            results["fits"][table] = {"runs_s": runs, "median_s": medians,
                                      "auto_over_nlb_spectral": medians["auto"] / medians["nlb_spectral"]}
    results["machine"]["load_average_after"] = list(os.getloadavg())
    with atomic_write(Path(args.out)) as handle:
        handle.write(json.dumps(results, indent=1) + "\n")
    for table, r in results["fits"].items():
        print(f"{table}: auto {r['median_s']['auto']:.2f} s, nlb_spectral {r['median_s']['nlb_spectral']:.2f} s "
              f"(median of {args.repeats}); auto / nlb_spectral {r['auto_over_nlb_spectral']:.2f}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
