"""Fit time of the spectral NLB's latent fit, single and batched, beside the RGB NLB's (docs/models.md#spectral-nlb,
docs/results.md).

    python benchmarks/spectral_nlb_timing.py [--batch 100] [--work runs/spectral_nlb_timing]
        [--out benchmarks/spectral_nlb_timing.json]

Four fits of each of ``configs/nlb_spectral.yaml`` and ``configs/nlb_latent.yaml`` (the RGB
NLB, the baseline measured in the same run), through ``neuralbrdf train fit`` as a user runs them:

* **single, spectral**: the virtual gold measured on DS1 (31 bands, 1 % noise) alone;
* **batched, spectral**: ``--batch`` spectral DS1 measurements in one fit — the ten virtual
  materials (four stand-ins, six validation materials) measured again with other noise seeds
  until the batch is full;
* **single, RGB** and **batched, RGB**: the same tables in linear sRGB (what the RGB NLB reads;
  the spectral NLB fits them per channel).

Reported: ``fit/wall_time_s`` (the latent fit proper: the screening of starts and the optimiser,
not the Python start-up or the loading of the tables) of ``--repeats`` runs of each fit, taken in
turn with the RGB NLB's (so that load from elsewhere hits both alike); their median per material,
every run's time, and the spectral NLB over the RGB NLB.  On this project's virtual 2-core machine
one fit's time varies by ±25 % from minute to minute, so one run says little.  The tables are kept
in ``--work``; the runs are redone every time.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import statistics
import sys
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

from neuralbrdf.atomic import atomic_write  # noqa: E402
from neuralbrdf.data.table import read_table, write_table  # noqa: E402
from neuralbrdf.sources import virtual_measurement  # noqa: E402
from neuralbrdf.virtual.materials import VALIDATION_MATERIALS  # noqa: E402
from spectral_nlb import train_run  # noqa: E402  (benchmarks/spectral_nlb.py)

MATERIALS = ("gold", "gonio", "cyan", "magenta", *VALIDATION_MATERIALS)
CONFIGS = {"nlb_spectral": "nlb_spectral.yaml", "nlb": "nlb_latent.yaml"}
NOISE = 0.01
PLAN = "DS1"


def measurement(work: Path, material: str, seed: int, rgb: bool) -> Path:
    """A calibrated DS1 measurement of ``material`` (noise seed ``seed``), spectral or in sRGB."""
    spectral = work / "tables" / f"{material}_seed{seed}.csv"
    if not spectral.is_file():
        spectral.parent.mkdir(parents=True, exist_ok=True)
        write_table(virtual_measurement(material, PLAN, NOISE, seed=2 * seed, reference_seed=2 * seed + 1), spectral)
    if not rgb:
        return spectral
    path = spectral.with_name(f"{spectral.stem}_rgb.csv")
    if not path.is_file():
        write_table(read_table(spectral).to_rgb(), path)
    return path


def fit_seconds(work: Path, method: str, tables: list[Path], label: str) -> float:
    """``fit/wall_time_s`` of one latent fit of ``tables`` in one batch."""
    sources = [{"path": str(t), "name": t.stem} for t in tables]
    return train_run(work / "runs" / method / label, CONFIGS[method], "--data.sources", json.dumps(sources),
                     "--data.eval_plan", "null")["fit/wall_time_s"]


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0], allow_abbrev=False)
    parser.add_argument("--batch", type=int, default=100, help="materials in the batched fits")
    parser.add_argument("--repeats", type=int, default=3, help="runs of each fit (the median is reported)")
    parser.add_argument("--work", default=str(REPO / "runs" / "spectral_nlb_timing"))
    parser.add_argument("--out", default=str(REPO / "benchmarks" / "spectral_nlb_timing.json"))
    args = parser.parse_args(argv)
    work = Path(args.work)
    load_before = os.getloadavg()
    batches = {"single": [("gold", 0)], "batched": [(MATERIALS[i % len(MATERIALS)], i // len(MATERIALS))
                                                    for i in range(args.batch)]}
    results = {}
    for colour in ("spectral", "rgb"):
        for label, members in batches.items():
            tables = [measurement(work, m, seed, colour == "rgb") for m, seed in members]
            runs = {method: [] for method in CONFIGS}
            for repeat in range(args.repeats):
                for method in CONFIGS:
                    runs[method].append(fit_seconds(work, method, tables, f"{colour}_{label}_run{repeat}"))
            row = {"materials": len(tables)}
            for method, seconds in runs.items():
                median = statistics.median(seconds)
                row[method] = {"fit_s": median, "fit_s_per_material": median / len(tables), "runs_s": seconds}
            row["nlb_spectral_over_nlb"] = row["nlb_spectral"]["fit_s"] / row["nlb"]["fit_s"]
            results[f"{colour} {label}"] = row
    output = {
        "command": "python benchmarks/spectral_nlb_timing.py" + (f" --batch {args.batch}" if args.batch != 100 else "")
                   + (f" --repeats {args.repeats}" if args.repeats != 3 else ""),
        "repeats": args.repeats,
        "machine": {"cpu": platform.processor() or platform.machine(), "cores": os.cpu_count(),
                    "python": platform.python_version(), "load_average_before": load_before,
                    "load_average_after": os.getloadavg()},
        "targets": {"single_s_per_material": 2.0, "batched_s_per_material": 0.1},
        "fits": results,
    }
    with atomic_write(Path(args.out)) as handle:
        handle.write(json.dumps(output, indent=2) + "\n")
    print(f"{'fit':<20}{'materials':>10}{'spectral NLB s/mat':>20}{'RGB NLB s/mat':>16}{'ratio':>8}")
    for label, row in results.items():
        print(f"{label:<20}{row['materials']:>10}{row['nlb_spectral']['fit_s_per_material']:>20.3f}"
              f"{row['nlb']['fit_s_per_material']:>16.3f}{row['nlb_spectral_over_nlb']:>8.2f}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
