"""The chart of docs/how-many-measurements.md: error against the number of measured pairs on the validation materials.

    python benchmarks/acquisition_chart.py [--out docs/how_many_pairs.png]

Reads ``acquisition_calibration_validation.json`` (DS4, the designed 6 and 12 pairs and DS3 per
material, hemisphere log-cos and preview ΔE2000) and ``acquisition_sessions.json`` (the sessions'
steps from 6 to 24 pairs, hemisphere only).  Median over materials, the band from the 25th to the
75th percentile.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

from neuralbrdf.atomic import atomic_path  # noqa: E402

PAIRS = {"DS4": 6, "design:6": 6, "design:12": 12, "DS3": 57}


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0], allow_abbrev=False)
    parser.add_argument("--out", default=str(REPO / "docs" / "how_many_pairs.png"))
    args = parser.parse_args(argv)
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    cells = json.loads((REPO / "benchmarks" / "acquisition_calibration_validation.json").read_text())["cells"]
    sessions = json.loads((REPO / "benchmarks" / "acquisition_sessions.json").read_text())["materials"]
    steps = [m["steps"] for group in sessions.values() for m in group.values()]
    figure, axes = plt.subplots(1, 2, figsize=(10.5, 4.0))
    for axis, key, title in ((axes[0], "logcos", "hemisphere log-cos RMSE"), (axes[1], "delta_e", "preview ΔE2000 mean")):
        for plans, style, label in ((("DS4", "DS3"), "s-", "report plans DS4, DS3"),
                                    (("design:6", "design:12"), "o-", "designed plans")):
            values = [np.array([c[key] for c in cells if c["plan"] == p]) for p in plans]
            x = [PAIRS[p] for p in plans]
            axis.plot(x, [np.median(v) for v in values], style, label=label)
            axis.fill_between(x, [np.percentile(v, 25) for v in values], [np.percentile(v, 75) for v in values],
                              alpha=0.15)
        if key == "logcos":
            pairs = [s["pairs"] for s in steps[0]]
            values = np.array([[s["true_logcos"] for s in m] for m in steps])
            axis.plot(pairs, np.median(values, axis=0), "^-", color="tab:green", label="sessions (plan next)")
            axis.fill_between(pairs, np.percentile(values, 25, axis=0), np.percentile(values, 75, axis=0),
                              color="tab:green", alpha=0.15)
        axis.set_xscale("log")
        axis.minorticks_off()
        axis.set_xticks([6, 12, 18, 24, 57])
        axis.set_xticklabels(["6", "12", "18", "24", "57"])
        axis.set_xlabel("pairs measured")
        axis.set_ylabel(title)
        axis.grid(True, which="both", alpha=0.3)
        axis.legend(fontsize=8)
    figure.suptitle(f"{len(steps)} validation materials: median, band 25-75 %", fontsize=9)
    figure.tight_layout()
    with atomic_path(Path(args.out)) as tmp:
        figure.savefig(tmp, format="png", dpi=100)
    print(f"-> {args.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
