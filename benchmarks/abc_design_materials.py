"""Build the ABC designer's materials (docs/how-many-measurements.md, "Designing for ABC or PCA").

    python benchmarks/abc_design_materials.py [--out neuralbrdf/pretrained/abc_design_materials.json]

``neuralbrdf plan design --kind abc`` averages its criterion over ABC materials of the prior's
training side: every training proxy — the MERL and RGL NBRDF proxies of ``../shared/data``
outside ``NEVER_PRETRAINED`` (``neuralbrdf.models.pca_brdf.training_proxies``, the materials the
PCA basis and the spectral NLB's pretraining use) — sampled on DS1 and fitted by ABC with the
settings of ``configs/abc.yaml``.  Fits that report failure are left out and listed.  Validation
and test materials never enter.  The file is small (a few kB) and ships with the package, so
designing needs no ``../shared``.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

from neuralbrdf.acquisition.abc_linear import DESIGN_MATERIALS  # noqa: E402
from neuralbrdf.atomic import atomic_write  # noqa: E402

SHARED = REPO.parent / "shared" / "data"


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0], allow_abbrev=False)
    parser.add_argument("--out", default=str(DESIGN_MATERIALS))
    args = parser.parse_args(argv)
    import neuralbrdf as nb
    from neuralbrdf.console import progress
    from neuralbrdf.fitting.abc_fit import fit_abc
    from neuralbrdf.lightning.config_models import abc_settings
    from neuralbrdf.models.pca_brdf import training_proxies

    settings = abc_settings("abc")
    proxies = training_proxies([SHARED / "merl-nbrdf", SHARED / "rgl-nbrdf"])
    materials, failed = [], []
    for name, file in progress(proxies, desc="ABC fits", unit="material"):
        result = fit_abc(nb.read(file, plan="DS1").samples, **settings)
        if not result.success:
            failed.append({"name": name, "reason": result.failure_reason})
            continue
        p = result.parameters
        materials.append({"name": name, "kd": [float(v) for v in p.kd], "A": [float(v) for v in p.A],
                          "B": float(p.B), "C": float(p.C), "eta": float(p.eta)})
    data = {"what": "ABC fits (configs/abc.yaml) of the training proxies sampled on DS1: the materials "
                    "`neuralbrdf plan design --kind abc` averages over",
            "command": "python benchmarks/abc_design_materials.py", "plan": "DS1",
            "materials": materials, "failed": failed}
    with atomic_write(args.out) as handle:
        handle.write(json.dumps(data, indent=1) + "\n")
    print(f"{len(materials)} materials, {len(failed)} failed fits left out -> {args.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
