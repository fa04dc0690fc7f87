"""The level-of-detail targets on ``export/scenes/lod_demo.xml`` (docs/select.md), one run per variant.

    python benchmarks/lod_demo.py --variant llvm_ad_spectral [--out-dir out/lod/demo_spectral]
        [--resolution 128] [--reference-spp 256] [--timing-spp 64] [--tolerance T] [--object-tolerance T]

Needs the demo models and their ladders (``bash export/lod_models.sh``).  Steps:

1. ``neuralbrdf select`` on the scene (settings of ``configs/lod/default.yaml``, the variant and
   tolerances from the options), timed: target ≤ 3 min on 2 cores;
2. the all-full scene and ``SELECTED.xml`` rendered at ``--resolution`` with
   ``--reference-spp``: the selected scene with each stand-in sampling like its parent (matched
   paths, as the selector measures) against the all-full render at the same seed, whole-image
   mean ΔE2000 — the stand-ins' bias: target ≤ 1.0; beside it the selected scene as written
   (own samplers) against the same reference, and the all-full scene at another seed (the
   Monte Carlo noise both of those carry); the same per material over the pixels it covers
   (:func:`~neuralbrdf.render.scene_file.material_coverage` at the target resolution);
3. both timed at ``--timing-spp`` in Dr.Jit's symbolic mode, after one compiling render each,
   ``--repeats`` interleaved renders, the shortest of each (other processes on a shared machine
   only ever add time): target speed-up ≥ 1.5×.

Writes ``full.png``, ``selected.png``, ``delta_e.png`` (the ΔE2000 map), ``comparison.png``
and ``lod_demo.json`` (strict JSON) into ``--out-dir``.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import statistics
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
SCENE = ROOT / "export" / "scenes" / "lod_demo.xml"


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0], allow_abbrev=False)
    parser.add_argument("--variant", default="llvm_ad_spectral")
    parser.add_argument("--out-dir", default=None)
    parser.add_argument("--resolution", type=int, default=128, help="width of the target renders (default 128)")
    parser.add_argument("--reference-spp", type=int, default=256)
    parser.add_argument("--timing-spp", type=int, default=64)
    parser.add_argument("--repeats", type=int, default=5)
    parser.add_argument("--tolerance", type=float, default=None, help="default: select.tolerance of configs/lod/default.yaml")
    parser.add_argument("--object-tolerance", type=float, default=None,
                        help="default: select.object_tolerance of configs/lod/default.yaml")
    parser.add_argument("--preview-gold", action="store_true",
                        help="the material-preview scene with only the gold (close-up) instead of lod_demo.xml")
    args = parser.parse_args(argv)
    tag = "preview_gold" if args.preview_gold else "demo"
    out = Path(args.out_dir or ROOT / "out" / "lod" / f"{tag}_{args.variant}")
    out.mkdir(parents=True, exist_ok=True)
    scene_path = _preview_gold_scene(out) if args.preview_gold else SCENE

    from neuralbrdf.evaluation.images import delta_e2000_map
    from neuralbrdf.lod.config import load_lod_config
    from neuralbrdf.lod.select import film_aspect, on_object_mean, select
    from neuralbrdf.render.preview import set_variant, write_images
    from neuralbrdf.render.scene_file import SceneFile, material_coverage, render_scene_file
    from neuralbrdf.study.cost import machine

    overrides = {"tolerance": args.tolerance, "object_tolerance": args.object_tolerance}
    settings = dataclasses.replace(load_lod_config().select, variant=args.variant,
                                   **{k: v for k, v in overrides.items() if v is not None})
    began = time.perf_counter()
    selection = select(scene_path, out / "SELECTED.xml", settings)
    selection_s = time.perf_counter() - began

    set_variant(args.variant)
    scenes = {"full": SceneFile(scene_path), "selected": SceneFile(out / "SELECTED.xml")}
    height = round(args.resolution * film_aspect(scenes["full"]))
    for scene in scenes.values():
        scene.set_resolution(args.resolution, height)
    # The selected scene once more with each stand-in sampling like its parent (same paths at the same
    # seed: the difference to the all-full render is the stand-ins' bias; neuralbrdf.lod.select).
    matched = scenes["selected"].copy()
    for material in selection["materials"]:
        if Path(material["file"]).resolve() != Path(material["model"]).resolve():
            SceneFile.set_property(next(m for m in matched.materials() if m.name == material["name"]).element,
                                   "proposal", str(Path(material["model"]).resolve()))
    renders = (("full", scenes["full"], 0), ("selected_matched", matched, 0), ("selected", scenes["selected"], 0),
               ("full_other_seed", scenes["full"], 1))
    images = {}
    for name, scene, seed in renders:
        images[name], _ = render_scene_file(scene, args.reference_spp, seed)
        print(f"{name}: rendered at {args.reference_spp} spp", file=sys.stderr)
    delta_e = delta_e2000_map(images["selected_matched"], images["full"])
    delta_e_own = delta_e2000_map(images["selected"], images["full"])
    noise = delta_e2000_map(images["full_other_seed"], images["full"])
    coverage = material_coverage(scenes["full"], settings.coverage_subpixels)
    on_object = {name: {"chosen_rung": next(m["chosen_rung"] for m in selection["materials"] if m["name"] == name),
                        "coverage_pixels": float(weights.sum()),
                        "delta_e2000_mean": on_object_mean(delta_e, weights),
                        "delta_e2000_mean_own_proposals": on_object_mean(delta_e_own, weights),
                        "reference_noise_delta_e2000_mean": on_object_mean(noise, weights)}
                 for name, weights in coverage.items()}

    times = {name: [] for name in scenes}
    for name, scene in scenes.items():
        render_scene_file(scene, args.timing_spp, 7)  # compiles
    for repeat in range(args.repeats):
        for name, scene in scenes.items():
            times[name].append(render_scene_file(scene, args.timing_spp, 8 + repeat)[1])
    full_s, selected_s = min(times["full"]), min(times["selected"])
    medians = {name: statistics.median(t) for name, t in times.items()}

    write_images(images["full"], out / "full.png")
    write_images(images["selected"], out / "selected.png")
    _delta_e_figure(delta_e, images, out, args, on_object)
    result = {
        "variant": args.variant,
        "scene": str(scene_path),
        "chosen": {m["name"]: m["chosen_rung"] for m in selection["materials"]},
        "selection_time_s": selection_s,
        "selection_cpu_s": selection["selection_cpu_s"],
        "selection": {k: selection[k] for k in ("speedup", "image_delta_e2000_mean", "noise", "render", "renders",
                                                "phase_times_s", "tolerance_delta_e2000",
                                                "object_tolerance_delta_e2000")},
        "selection_materials": selection["materials"],
        "target_render": {"width": args.resolution, "height": height,
                          "reference_spp": args.reference_spp, "timing_spp": args.timing_spp,
                          "repeats": args.repeats},
        "image_delta_e2000_mean": float(delta_e.mean()),
        "image_delta_e2000_p95": float(np.percentile(delta_e, 95)),
        "image_delta_e2000_mean_own_proposals": float(delta_e_own.mean()),
        "reference_noise_delta_e2000_mean": float(noise.mean()),
        "on_object": on_object,
        "delta_e_note": "image_delta_e2000_mean: selected scene with each stand-in sampling like its parent, same seed "
                        "(same paths) against the all-full render: the stand-ins' bias. *_own_proposals: the selected "
                        "scene as written (own samplers) against the all-full render at the same seed: bias plus Monte "
                        "Carlo noise, whose size the all-full scene at another seed shows (reference_noise_*)",
        "full_time_s": full_s,
        "selected_time_s": selected_s,
        "times_s": times,
        "timing_statistic": "shortest of the interleaved repeats (the median ratio: speedup_of_medians)",
        "speedup_of_medians": medians["full"] / medians["selected"],
        "speedup": full_s / selected_s,
        "targets": {
            "speedup_at_least_1.5": full_s / selected_s >= 1.5,
            "delta_e2000_mean_at_most_1": float(delta_e.mean()) <= 1.0,
            "on_object_delta_e2000_mean_within_object_tolerance": all(
                o["delta_e2000_mean"] is None or o["delta_e2000_mean"] <= selection["object_tolerance_delta_e2000"]
                for o in on_object.values()),
            "selection_at_most_180_s": selection_s <= 180.0,
        },
        "machine": machine(),
    }
    (out / "lod_demo.json").write_text(json.dumps(result, indent=2, allow_nan=False) + "\n")
    print(json.dumps({k: result[k] for k in ("chosen", "selection_time_s", "selection_cpu_s", "image_delta_e2000_mean", "on_object",
                                             "image_delta_e2000_mean_own_proposals", "reference_noise_delta_e2000_mean",
                                             "speedup", "targets")}, indent=2))
    return 0


def _preview_gold_scene(out: Path) -> Path:
    """The package's material-preview scene with the demo's gold model on the sphere (a close-up)."""
    from neuralbrdf.render.preview import SCENE_FILE

    model = ROOT / "out" / "lod" / "models" / "gold.onnx"
    text = SCENE_FILE.read_text().replace(
        '<include filename="$material"/>',
        f'<bsdf type="neuralbrdf" id="material"><string name="filename" value="{model}"/></bsdf>',
    )
    path = out / "preview_gold.xml"
    path.write_text(text)
    return path


def _delta_e_figure(delta_e, images, out: Path, args, on_object: dict) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from neuralbrdf.evaluation.images import displayed

    figure, axes = plt.subplots(1, 3, figsize=(12, 3.4), constrained_layout=True)
    axes[0].imshow(displayed(images["full"]))
    axes[0].set_title(f"all full ({args.reference_spp} spp)")
    axes[1].imshow(displayed(images["selected_matched"]))
    axes[1].set_title("selected (matched paths)")
    shown = axes[2].imshow(delta_e, cmap="magma", vmin=0, vmax=max(2.0, float(np.percentile(delta_e, 99))))
    per_object = [o["delta_e2000_mean"] for o in on_object.values() if o["delta_e2000_mean"] is not None]
    axes[2].set_title(f"CIEDE2000, mean {delta_e.mean():.2f}; on an object at most {max(per_object, default=0):.2f}")
    figure.colorbar(shown, ax=axes[2], shrink=0.8)
    for axis in axes:
        axis.set_axis_off()
    figure.suptitle(f"{'preview scene, gold only' if args.preview_gold else 'lod_demo.xml'}, {args.variant}")
    figure.savefig(out / "comparison.png", dpi=110)
    plt.close(figure)


if __name__ == "__main__":
    sys.exit(main())
