"""What every fast path changes in the picture: its image error against its parent (docs/evaluate.md, docs/select.md).

    python benchmarks/fast_paths.py [--work-dir out/fast_paths] [--out benchmarks/fast_paths.json]
        [--resolution 128] [--spp 64] [--quick]

1. **Models** (in ``--work-dir``; a step whose output is there is not run again):

   * the spectral MLP of each virtual material (``train.py fit --config configs/spectral_mlp.yaml
     --data.virtual NAME``), exported with its RGB head (``neuralbrdf export``);
   * one NLB latent fit (``configs/nlb_latent.yaml``, DS1) of the four virtual materials and the
     report's five MERL materials (NBRDF proxies in ``../shared/data/merl-nbrdf``; left out, and
     said so, when that folder is missing), each exported with its fast path (``neuralbrdf export
     --fast``);
   * the spectral NLB's fits (``configs/nlb_spectral.yaml``) of the same materials: the four
     virtual ones from their shipped spectral DS1 measurements in one batch, the five MERL ones
     (RGB) from DS1 in another, each exported with ``neuralbrdf export --fast`` (a spectral model
     gets its RGB head too).
2. **Images.**  The material-preview scene at ``--resolution`` and ``--spp``, seed 0: the RGB head
   against the spectral integration (``rgb_head`` off: the plugin's sRGB rule) in
   ``llvm_ad_rgb``; the NLB's fast path against the full NLB in ``llvm_ad_rgb`` and
   ``llvm_ad_spectral``; the spectral NLB rendered the way ``--fast`` renders it against its full
   network (``rgb_head`` off) in both variants — its ``f_fast``, or for a spectral model in
   ``llvm_ad_rgb`` its RGB head.  A fast path is an output of its parent's own file, so both sample
   the same paths and the difference is the fast path's error, not Monte Carlo noise.  Mean and p95
   CIEDE2000 per material, and the fast path's recorded error (its cost: ``benchmarks/run.py``).
3. Writes ``--out`` (strict JSON) and, beside it, ``fast_paths_<fast path>_<variant>.png``: per material the
   parent, the fast path and their ΔE2000 map (colour scale 0–2).

Target quoted (not asserted): mean ΔE2000 ≤ 0.5 for the RGB head and the spectral NLB's fast
path, ≤ 1.0 for the NLB fast path.
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
MERL = ROOT.parent / "shared" / "data" / "merl-nbrdf"
VIRTUAL = ("gold", "gonio", "cyan", "magenta")
REPORT_MERL = ("tungsten-carbide", "nylon", "brass", "blue-acrylic", "specular-black-phenolic")
TARGETS = {"rgb head": 0.5, "nlb fast path": 1.0, "nlb_spectral fast path": 0.5}
#: ΔE2000 of the maps' full colour scale.
MAP_MAX_DELTA_E = 2.0


def _run(command: list[str], log: Path) -> None:
    with open(log, "w") as handle:
        subprocess.run(command, cwd=ROOT, check=True, stdout=handle, stderr=subprocess.STDOUT)


def spectral_models(work: Path, quick: bool) -> dict[str, Path]:
    """The four virtual materials' spectral MLPs with their RGB heads (module docstring, 1)."""
    out = {}
    for name in VIRTUAL:
        run, model = work / "runs" / f"spectral_{name}", work / f"spectral_{name}.onnx"
        checkpoint = run / "checkpoints" / "best.ckpt"
        if not checkpoint.is_file():
            _run([sys.executable, "train.py", "fit", "--config", "configs/spectral_mlp.yaml", "--data.virtual", name,
                  "--run_dir", str(run), "--overwrite", "--trainer.enable_progress_bar", "false",
                  *(["--trainer.max_epochs", "2"] if quick else [])], work / f"train_spectral_{name}.log")
        if not model.is_file():
            _run([sys.executable, "-m", "neuralbrdf", "export", "--ckpt", str(checkpoint), "--out", str(model),
                  *_config(work, quick)], work / f"export_spectral_{name}.log")
        out[name] = model
    return out


def nlb_models(work: Path, quick: bool) -> dict[str, Path]:
    """The NLB fit of the virtual and (when present) the report's MERL materials, each with its
    fast path (module docstring, 1)."""
    sources = [{"virtual": name} for name in VIRTUAL]
    merl = [name for name in REPORT_MERL if (MERL / f"{name}.h5").is_file()]
    sources += [{"nbrdf": str(MERL / f"{name}.h5")} for name in merl]
    return fitted_models(work, "nlb_latent.yaml", "nlb", sources, [*VIRTUAL, *merl], quick)


def spectral_nlb_models(work: Path, quick: bool) -> dict[str, Path]:
    """The spectral NLB's fits of the virtual (spectral) and, when present, the report's MERL (RGB)
    materials, each exported with its fast paths (module docstring, 1)."""
    merl = [name for name in REPORT_MERL if (MERL / f"{name}.h5").is_file()]
    models = fitted_models(work, "nlb_spectral.yaml", "nlb_spectral_virtual", [{"virtual": name} for name in VIRTUAL],
                           list(VIRTUAL), quick, ["--data.eval_plan", "null"])
    if merl:
        models |= fitted_models(work, "nlb_spectral.yaml", "nlb_spectral_merl",
                                [{"nbrdf": str(MERL / f"{name}.h5")} for name in merl], merl, quick,
                                ["--data.eval_plan", "null"])
    return models


def fitted_models(work: Path, config: str, label: str, sources: list[dict], names: list[str], quick: bool,
                  fit_args: list[str] = ()) -> dict[str, Path]:
    """One latent fit (``configs/CONFIG``, DS1) of ``sources`` in ``work/runs/LABEL`` and each of ``names``
    exported with its fast paths (``neuralbrdf export --fast``) to ``work/LABEL_NAME.onnx``."""
    run = work / "runs" / label
    checkpoint = run / "checkpoints" / "fitted.ckpt"
    if not checkpoint.is_file():
        _run([sys.executable, "train.py", "fit", "--config", f"configs/{config}", "--data.sources", json.dumps(sources),
              "--data.plan", "DS1", *fit_args, "--run_dir", str(run), "--overwrite", "--trainer.enable_progress_bar",
              "false", *(["--trainer.max_epochs", "1"] if quick else [])], work / f"fit_{label}.log")
    out = {}
    for name in names:
        model = work / f"{label}_{name}.onnx"
        if not model.is_file():
            _run([sys.executable, "-m", "neuralbrdf", "export", "--ckpt", str(checkpoint), "--material", name,
                  "--out", str(model), "--fast", *_config(work, quick)], work / f"export_{label}_{name}.log")
        out[name] = model
    return out


def _config(work: Path, quick: bool) -> list[str]:
    """``--config`` of a quick run: the shipped settings with a few hundred distillation steps."""
    if not quick:
        return []
    import yaml

    from neuralbrdf.lod.config import load_lod_config

    raw = yaml.safe_load(load_lod_config().path.read_text())
    raw["fast_paths"]["distill"].update(steps=200, n_pairs=4096, batch=1024)
    raw["fast_paths"].update(max_hemisphere_logcos_rmse=1.0)
    raw["fast_paths"]["image_check"].update(resolution=32, spp=4, max_delta_e2000_mean=100.0)
    path = work / "quick_lod.yaml"
    path.write_text(yaml.safe_dump(raw))
    return ["--config", str(path)]


def compare(model: Path, variant: str, resolution: int, spp: int, fast: bool) -> tuple[dict, np.ndarray, np.ndarray]:
    """Parent and fast path of ``model`` rendered at seed 0 (RGB head: ``rgb_head`` on against off;
    ``fast``: ``fast`` on against off); image metrics of the fast path against the parent, images."""
    from neuralbrdf.evaluation.images import image_scores
    from neuralbrdf.render.preview import Material, render

    parent = render(Material(model=model, rgb_head=False), variant, spp, resolution, 0)
    stand_in = render(Material(model=model, fast=fast), variant, spp, resolution, 0)
    metrics, _ = image_scores(stand_in, parent)
    return metrics, parent, stand_in


def mosaic(rows: list[tuple[str, np.ndarray, np.ndarray]], title: str, path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from neuralbrdf.evaluation.images import delta_e2000_map, displayed

    fig, axes = plt.subplots(len(rows), 3, figsize=(7.5, 2.5 * len(rows)), squeeze=False)
    for (name, parent, stand_in), row in zip(rows, axes):
        delta = delta_e2000_map(stand_in, parent)
        for ax, image, label in ((row[0], displayed(parent), f"{name}: parent"), (row[1], displayed(stand_in), "fast path")):
            ax.imshow(image)
            ax.set_title(label, fontsize=8)
        shown = row[2].imshow(delta, cmap="magma", vmin=0.0, vmax=MAP_MAX_DELTA_E)
        row[2].set_title(f"ΔE2000 mean {delta.mean():.3f}", fontsize=8)
        fig.colorbar(shown, ax=row[2], fraction=0.046, pad=0.04)
        for ax in row:
            ax.set_axis_off()
    fig.suptitle(title, fontsize=9)
    fig.savefig(path, dpi=90, bbox_inches="tight")
    plt.close(fig)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0], allow_abbrev=False)
    parser.add_argument("--work-dir", default=str(ROOT / "out" / "fast_paths"), help="models and logs (kept; reused)")
    parser.add_argument("--out", default=str(ROOT / "benchmarks" / "fast_paths.json"))
    parser.add_argument("--resolution", type=int, default=128)
    parser.add_argument("--spp", type=int, default=64)
    parser.add_argument("--quick", action="store_true", help="short trainings and distillations, 32 px, 4 spp")
    args = parser.parse_args(argv)
    if args.quick:
        args.resolution, args.spp = 32, 4
    from neuralbrdf.atomic import atomic_write
    from neuralbrdf.evaluation.fast_paths import rendered_output
    from neuralbrdf.kinds import load_model
    from neuralbrdf.study.cost import machine

    work = Path(args.work_dir)
    work.mkdir(parents=True, exist_ok=True)
    began = time.perf_counter()
    cases = [("rgb head", name, path, "llvm_ad_rgb", False) for name, path in spectral_models(work, args.quick).items()]
    nlb = nlb_models(work, args.quick)
    cases += [("nlb fast path", name, path, variant, True) for variant in ("llvm_ad_rgb", "llvm_ad_spectral")
              for name, path in nlb.items()]
    cases += [("nlb_spectral fast path", name, path, variant, True) for variant in ("llvm_ad_rgb", "llvm_ad_spectral")
              for name, path in spectral_nlb_models(work, args.quick).items()]
    results, pictures = [], {}
    for what, name, path, variant, fast in cases:
        metrics, parent, stand_in = compare(path, variant, args.resolution, args.spp, fast)
        file = load_model(path)
        output = rendered_output(file, variant, fast)
        recorded = file.fast_paths[output]
        results.append({"fast_path": what, "material": name, "variant": variant, "output": output, **metrics,
                        "recorded_hemisphere_logcos_rmse": recorded.hemisphere_logcos_rmse,
                        "recorded_image_delta_e2000_mean": recorded.image_delta_e2000_mean})
        pictures.setdefault((what, variant), []).append((name, parent, stand_in))
        print(f"{what:<14} {name:<24} {variant:<17} ΔE2000 mean {metrics['image_delta_e2000_mean']:.3f} "
              f"p95 {metrics['image_delta_e2000_p95']:.3f}  (recorded log-cos RMSE {recorded.hemisphere_logcos_rmse:.4f})",
              flush=True)
    out = Path(args.out)
    for (what, variant), rows in pictures.items():
        mosaic(rows, f"{what} against its parent, {variant}, {args.resolution} px, {args.spp} spp, matched paths",
               out.with_name(f"fast_paths_{what.replace(' ', '_')}_{variant}.png"))
    summary = {f"{what} {variant}": max(r["image_delta_e2000_mean"] for r in results
                                        if r["fast_path"] == what and r["variant"] == variant)
               for what, variant in pictures}
    document = {"command": "python benchmarks/fast_paths.py" + (" --quick" if args.quick else ""),
                "resolution": args.resolution, "spp": args.spp, "machine": machine(), "targets_mean_delta_e2000": TARGETS,
                "largest_mean_delta_e2000": summary, "results": results, "wall_time_s": time.perf_counter() - began,
                "merl_materials": [name for name in nlb if name not in VIRTUAL]}
    with atomic_write(out) as handle:
        json.dump(document, handle, indent=2, allow_nan=False)
        handle.write("\n")
    for key, value in summary.items():
        print(f"largest mean ΔE2000, {key}: {value:.3f} (target <= {TARGETS[key.rsplit(' ', 1)[0]]})")
    print(f"wrote {out} ({document['wall_time_s']:.0f} s)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
