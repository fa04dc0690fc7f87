"""Accuracy where users look: fitted models against their truths (docs/evaluate.md).

    python benchmarks/accuracy.py [--out benchmarks/accuracy.json] [--work-dir out/accuracy] [--quick]
        [--part all|virtual|merl]

1. **Virtual materials.** The 3×10 spectral MLP trained on each shipped DS1 measurement (gold,
   gonio, cyan, magenta) with the report's loss (``configs/spectral_mlp_paper.yaml``) and with
   the default (``configs/spectral_mlp.yaml``), exported, and scored by ``neuralbrdf evaluate``
   against ``export-truth virtual:NAME`` in ``llvm_ad_spectral``.
2. **The report's MERL materials.** ABC (``configs/abc.yaml``) and the NLB latent fit
   (``configs/nlb_latent.yaml``, all five in one batch) from DS1 samples of the NBRDF proxies of
   tungsten-carbide, nylon, brass, blue-acrylic and specular-black-phenolic, scored against the
   proxies (``export-truth NAME.h5``) in ``llvm_ad_rgb``.  Skipped when ``../shared/data`` is absent.

Every step is cached in ``--work-dir`` (a run directory, an ``.onnx`` or an ``evaluation.json``
that exists is reused), so a killed run resumes.  Results go to ``--out`` (strict JSON) and a
printed table.  ``--quick`` (2 epochs, tiny renders, gold and nylon only) is the smoke test.
"""

from __future__ import annotations

import argparse
import json
import platform
import sys
import time
from dataclasses import dataclass
from pathlib import Path

import torch

from neuralbrdf.atomic import atomic_write
from neuralbrdf.data.nbrdf import REPORT_MATERIALS
from neuralbrdf.evaluation.evaluate import RenderSettings, evaluate
from neuralbrdf.evaluation.truth import export_truth
from neuralbrdf.onnx_export import export_checkpoint
from neuralbrdf.lightning.run import main as train

ROOT = Path(__file__).resolve().parents[1]
NBRDF_DIR = ROOT.parent / "shared" / "data" / "merl-nbrdf"
VIRTUAL = ("gold", "gonio", "cyan", "magenta")
SPECTRAL_CONFIGS = {"paper": "spectral_mlp_paper.yaml", "default": "spectral_mlp.yaml"}
REPORTED = ("image_delta_e2000_mean", "image_delta_e2000_p95", "hemisphere_logcos_rmse",
            "inplane_glossy_rel_rmse", "inplane_diffuse_rel_rmse")


@dataclass(frozen=True)
class Settings:
    epochs: int | None
    spp: int
    resolution: int
    virtual: tuple[str, ...]
    merl: tuple[str, ...]

    @classmethod
    def for_mode(cls, quick: bool) -> Settings:
        if quick:
            return cls(epochs=2, spp=4, resolution=32, virtual=("gold",), merl=("nylon",))
        return cls(epochs=None, spp=256, resolution=128, virtual=VIRTUAL, merl=REPORT_MATERIALS)



def _train(config: str, run_dir: Path, settings: Settings, *args: str) -> float:
    """Train once into ``run_dir`` (reused when it holds a finished run); wall time in s."""
    metrics = run_dir / "metrics.json"
    if metrics.exists():
        return json.loads(metrics.read_text()).get("fit/wall_time_s", 0.0)
    epochs = [] if settings.epochs is None else ["--trainer.max_epochs", str(settings.epochs)]
    status = train(["fit", "--config", str(ROOT / "configs" / config), "--run_dir", str(run_dir),
                    "--trainer.enable_progress_bar", "false", *epochs, *args])
    if status != 0:
        raise RuntimeError(f"training {config} into {run_dir} failed with status {status}")
    return json.loads(metrics.read_text()).get("fit/wall_time_s", 0.0)


def _cached(path: Path, make) -> Path:
    if not path.exists():
        make(path)
    return path


def _score(model: Path, truth: Path, out_dir: Path, settings: Settings, variant: str) -> dict:
    cached = out_dir / "evaluation.json"
    if cached.exists():
        return json.loads(cached.read_text())
    render = RenderSettings(variant=variant, spp=settings.spp, resolution=settings.resolution)
    return evaluate(model, truth, out_dir, render)


def _row(material: str, model: str, result: dict, fit_time_s: float) -> dict:
    return {"material": material, "model": model, "fit_time_s": fit_time_s,
            "noise_delta_e2000_mean": result["noise"]["image_delta_e2000_mean"],
            **{name: result[name] for name in REPORTED}, "evaluation": result}


def virtual_rows(work: Path, settings: Settings) -> list[dict]:
    rows = []
    for name in settings.virtual:
        truth = _cached(work / f"truth_{name}.onnx", lambda p, n=name: export_truth(f"virtual:{n}", p))
        for label, config in SPECTRAL_CONFIGS.items():
            run = work / f"{name}_{label}"
            fit_time = _train(config, run, settings, "--data.virtual", name)
            model = _cached(work / f"{name}_{label}.onnx",
                            lambda p, r=run: export_checkpoint(r / "checkpoints" / "best.ckpt", p))
            result = _score(model, truth, work / f"eval_{name}_{label}", settings, "llvm_ad_spectral")
            rows.append(_row(name, f"spectral_mlp ({label} loss)", result, fit_time))
    return rows


def merl_rows(work: Path, settings: Settings) -> list[dict]:
    if not NBRDF_DIR.is_dir():
        return []
    rows = []
    sources = [f"{{nbrdf: {NBRDF_DIR / f'{m}.h5'}}}" for m in settings.merl]
    nlb_run = work / "nlb_latent_DS1"
    nlb_time = _train("nlb_latent.yaml", nlb_run, settings, "--data.sources", f"[{', '.join(sources)}]",
                      "--data.plan", "DS1")
    for name in settings.merl:
        truth = _cached(work / f"truth_{name}.onnx", lambda p, n=name: export_truth(str(NBRDF_DIR / f"{n}.h5"), p))
        abc_run = work / f"{name}_abc_DS1"
        abc_time = _train("abc.yaml", abc_run, settings, "--data.nbrdf", str(NBRDF_DIR / f"{name}.h5"),
                          "--data.plan", "DS1")
        for label, run, checkpoint, fit_time in (
            ("abc (DS1)", abc_run, "best.ckpt", abc_time),
            ("nlb latent (DS1)", nlb_run, "fitted.ckpt", nlb_time / len(settings.merl)),
        ):
            stem = label.split()[0]
            model = _cached(work / f"{name}_{stem}.onnx",
                            lambda p, r=run, c=checkpoint, n=name: export_checkpoint(r / "checkpoints" / c, p, n))
            result = _score(model, truth, work / f"eval_{name}_{stem}", settings, "llvm_ad_rgb")
            rows.append(_row(name, label, result, fit_time))
    return rows


def format_table(rows: list[dict]) -> str:
    header = "| material | model | ΔE mean | ΔE p95 | noise ΔE | hemisphere log-cos | glossy rel | diffuse rel | fit s |"
    lines = [header, "|" + "---|" * 9]
    for row in rows:
        lines.append(
            f"| {row['material']} | {row['model']} | {row['image_delta_e2000_mean']:.2f} | "
            f"{row['image_delta_e2000_p95']:.2f} | {row['noise_delta_e2000_mean']:.2f} | "
            f"{row['hemisphere_logcos_rmse']:.4f} | {row['inplane_glossy_rel_rmse']:.3f} | "
            f"{row['inplane_diffuse_rel_rmse']:.3f} | {row['fit_time_s']:.0f} |"
        )
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0], allow_abbrev=False)
    parser.add_argument("--out", default=str(ROOT / "benchmarks" / "accuracy.json"))
    parser.add_argument("--work-dir", default=str(ROOT / "out" / "accuracy"))
    parser.add_argument("--quick", action="store_true")
    parser.add_argument("--part", choices=("all", "virtual", "merl"), default="all",
                        help="run only the virtual materials or only the MERL proxies (default all)")
    args = parser.parse_args(argv)
    settings = Settings.for_mode(args.quick)
    work = Path(args.work_dir)
    started = time.perf_counter()
    rows = (virtual_rows(work, settings) if args.part != "merl" else []) + (
        merl_rows(work, settings) if args.part != "virtual" else [])
    result = {
        "command": "python benchmarks/accuracy.py" + (" --quick" if args.quick else "") + f" --part {args.part}",
        "machine": {"platform": platform.platform(), "processor": platform.processor(),
                    "torch_threads": torch.get_num_threads()},
        "settings": settings.__dict__ | {"virtual": list(settings.virtual), "merl": list(settings.merl)},
        "wall_time_s": time.perf_counter() - started,
        "rows": rows,
    }
    with atomic_write(args.out) as handle:
        json.dump(result, handle, indent=2, allow_nan=False)
    print(format_table(rows))
    print(f"-> {args.out} ({result['wall_time_s']:.0f} s)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
