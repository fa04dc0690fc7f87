"""The whole pipeline from Python: read -> fit -> export -> evaluate -> render.

    python examples/api_end_to_end.py [--out-dir out/api] [--quick]

Reads the virtual gold's shipped DS1 measurement (1001 in-plane direction pairs, 31 wavelengths),
fits the spectral MLP through the shipped config (``configs/spectral_mlp.yaml``, the same run as
``neuralbrdf train fit --config spectral_mlp``), exports it to ONNX, exports the material's ground
truth, scores the model against it where users look (hemisphere, in-plane regions, rendered image)
and renders it in the material-preview scene.  Everything lands in ``--out-dir``, replaced on a
rerun.  ``--quick``: one epoch, no RGB head in the model file and tiny renders (seconds; what the
test runs).
"""

from __future__ import annotations

import argparse
from pathlib import Path

import neuralbrdf as nb


def main(argv: list[str] | None = None) -> dict:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0], allow_abbrev=False)
    parser.add_argument("--out-dir", default="out/api", help="output folder (default out/api)")
    parser.add_argument("--quick", action="store_true", help="one epoch, no RGB head, evaluation at 16 pixels and 2 spp, last render at 32 pixels and 8 spp")
    args = parser.parse_args(argv)
    out = Path(args.out_dir)

    gold = nb.read("virtual:gold")
    print(f"read {gold.name}: {gold.samples.n_rows} direction pairs x {len(gold.samples.wavelengths)} wavelengths")

    overrides = {"trainer.max_epochs": 1} if args.quick else {}
    result = nb.fit("spectral_mlp", gold, run_dir=out / "run", overrides=overrides, overwrite=True)
    print(f"fit: {result.checkpoint} (in-plane relative RMSE: glossy "
          f"{result.metrics['fit/inplane_glossy_rel_rmse']:.3f}, diffuse {result.metrics['fit/inplane_diffuse_rel_rmse']:.3f})")

    model = result.export(out / "gold.onnx", rgb_head=not args.quick)  # --quick: no RGB head (seconds to distil)
    truth = nb.truth(gold, out / "gold_truth.onnx")
    print(f"export: {model}; truth: {truth}")

    spp, resolution = (2, 16) if args.quick else (256, 128)
    scores = nb.evaluate(model, truth, out / "eval", spp=spp, resolution=resolution)
    print(f"evaluate: hemisphere log-cos RMSE {scores['hemisphere_logcos_rmse']:.4f}, image CIEDE2000 mean "
          f"{scores['image_delta_e2000_mean']:.2f} (render noise {scores['noise']['image_delta_e2000_mean']:.2f}) "
          f"-> {out / 'eval'}")

    image = nb.render_image(model, out / "gold.png", spp=spp * 4, resolution=resolution * 2)
    print(f"render: {image.shape[1]}x{image.shape[0]} -> {out / 'gold.png'}")
    return scores


if __name__ == "__main__":
    main()
