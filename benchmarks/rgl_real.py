"""A real measurement in, the real measurement as the truth: the four fitted models against an RGL
``.bsdf`` file (Dupuy & Jakob 2018, RGL material database, CC0), scored through Mitsuba's own
``measured`` plugin (docs/evaluate.md).

    python benchmarks/rgl_real.py [--bsdf FILE.bsdf] [--plans DS1,DS3] [--spp 64] [--resolution 128]
        [--work runs/rgl_real] [--out benchmarks/rgl_real.json]

Default file: ``../shared/data/rgl-bsdf/acrylic_felt_green_rgb.bsdf`` (an RGB file).  For every
plan, the measurement sampled on it (``neuralbrdf sample``: the plugin at the plan's pairs) is
fitted by

* ``abc`` — ``configs/abc.yaml`` (``--data.rgl FILE --data.plan PLAN``);
* ``nlb`` — ``configs/nlb_latent.yaml``, the RGB NLB's latent fit (``data.sources: [{rgl: FILE}]``);
* ``nlb_spectral`` — ``configs/nlb_spectral.yaml``, the spectral NLB (spectral files band by band,
  RGB ones per channel);
* ``spectral_mlp`` — ``configs/spectral_mlp.yaml`` on the spectral table: a spectral file's own
  bands, or an RGB file's samples upsampled to spectra as the renderer upsamples an RGB model in a
  spectral variant (Jakob & Hanika 2019, Mitsuba's ``srgb.coeff``; integrated back to linear sRGB
  they give the samples again within 1 %, median 0.14 %, on the shared file's DS1 samples).

Each fit is exported and scored by ``neuralbrdf evaluate --truth FILE``: hemisphere log-cos RMSE
(102 400 pairs) and in-plane errors against the plugin, and the image ΔE2000 (mean, p95) of the
material-preview scene against the plugin's own render (``--resolution`` px, ``--spp``, the file's
kind of variant, matched seeds, the truth-against-truth noise stated).  The comparison images of
the first plan are copied beside the JSON (``rgl_real_PLAN_METHOD.png``).  Cells are kept in
``--work`` and reused when the script runs again with the same settings and config file contents.  Writes JSON (``--out``)
and prints a table.
"""

from __future__ import annotations

import argparse
import hashlib
import json
import platform
import shutil
import sys
import time
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

from neuralbrdf.atomic import atomic_write  # noqa: E402
from neuralbrdf.data.calibration import CALIBRATED_WAVELENGTHS_NM  # noqa: E402
from neuralbrdf.data.rgl_bsdf import RglBsdf, sample_rgl  # noqa: E402
from neuralbrdf.data.table import BrdfTable, write_table  # noqa: E402
from neuralbrdf.evaluation.evaluate import RenderSettings, evaluate  # noqa: E402
from neuralbrdf.onnx_export import export_checkpoint  # noqa: E402
from spectral_nlb import SCORES, train_run  # noqa: E402  (benchmarks/spectral_nlb.py)

DEFAULT_FILE = REPO.parent / "shared" / "data" / "rgl-bsdf" / "acrylic_felt_green_rgb.bsdf"
METHODS = ("abc", "spectral_mlp", "nlb", "nlb_spectral")
CONFIGS = {"abc": "abc.yaml", "spectral_mlp": "spectral_mlp.yaml", "nlb": "nlb_latent.yaml",
           "nlb_spectral": "nlb_spectral.yaml"}
CHECKPOINT = {"abc": "best.ckpt", "spectral_mlp": "best.ckpt", "nlb": "fitted.ckpt", "nlb_spectral": "fitted.ckpt"}


def upsampled(table: BrdfTable) -> BrdfTable:
    """An RGB table's rows as spectra at the report's 31 bands, by the renderer's RGB upsampling."""
    import mitsuba as mi

    from neuralbrdf.data.rgl_bsdf import mitsuba_variant

    with mitsuba_variant("llvm_ad_spectral"):
        from neuralbrdf.render.mitsuba_bsdf import _upsampler

        rgb = mi.Color3f(*(mi.Float(table.values[:, c].astype(np.float32)) for c in range(3)))
        columns = []
        for nm in CALIBRATED_WAVELENGTHS_NM:
            spectrum = _upsampler().spectrum(rgb, mi.Spectrum(*[float(nm)] * 4))
            columns.append(np.asarray(spectrum, dtype=np.float64)[0])
    return BrdfTable(table.theta_i, table.phi_i, table.theta_o, table.phi_o, np.stack(columns, axis=1),
                     CALIBRATED_WAVELENGTHS_NM.copy(), source=f"{table.source}, upsampled (Jakob & Hanika 2019)")


def data_args(method: str, bsdf: Path, plan: str, spectral_table: Path) -> list[str]:
    if method == "abc":
        return ["--data.rgl", str(bsdf), "--data.plan", plan, "--data.eval_plan", "null"]
    if method == "spectral_mlp":
        return ["--data.path", str(spectral_table)]
    return ["--data.sources", json.dumps([{"rgl": str(bsdf)}]), "--data.plan", plan, "--data.eval_plan", "null"]


def run_cell(method: str, bsdf: Path, plan: str, settings: RenderSettings, work: Path) -> dict:
    """Fit, export and evaluate one method on one plan (kept in ``work``)."""
    config = (REPO / "configs" / CONFIGS[method]).read_text()
    key = hashlib.sha256(json.dumps([method, str(bsdf), bsdf.stat().st_size, plan, vars(settings), config]).encode())
    cell = work / f"{plan}_{method}_{key.hexdigest()[:12]}"
    done = cell / "scores.json"
    if done.is_file():
        return json.loads(done.read_text())
    print(f"[{plan}] {method} ...", flush=True)
    measurement = RglBsdf.load(bsdf)
    spectral_table = cell / f"{plan}_spectral.csv"
    if method == "spectral_mlp":
        table = sample_rgl(measurement, plan)
        write_table(table if table.is_spectral else upsampled(table), spectral_table)
    try:
        metrics = train_run(cell / "run", CONFIGS[method], *data_args(method, bsdf, plan, spectral_table))
    except RuntimeError as error:
        return {"failed": str(error)}
    model = cell / f"{method}.onnx"
    export_checkpoint(cell / "run" / "checkpoints" / CHECKPOINT[method], model)
    result = evaluate(model, bsdf, cell / "eval", settings)
    scores = {k: result.get(k) for k in SCORES} | {
        "fit_time_s": metrics["fit/wall_time_s"],
        "image_noise_delta_e2000_mean": result["noise"]["image_delta_e2000_mean"],
        "image_noise_delta_e2000_p95": result["noise"]["image_delta_e2000_p95"],
        "comparison": str(cell / "eval" / "comparison.png"),
    }
    with atomic_write(done) as handle:
        handle.write(json.dumps(scores, indent=2) + "\n")
    return scores


def print_table(results: dict) -> None:
    print(f"\n{results['file']}: against Mitsuba's measured plugin ({results['render']['variant']}, "
          f"{results['render']['resolution']} px, {results['render']['spp']} spp)")
    print(f"{'plan':<6}{'method':<14}{'log-cos RMSE':>13}{'ΔE mean':>9}{'ΔE p95':>8}{'noise ΔE':>10}{'fit s':>8}")
    for plan, rows in results["plans"].items():
        for method, scores in rows.items():
            if "failed" in scores:
                print(f"{plan:<6}{method:<14}  failed: {scores['failed'][:60]}")
                continue
            print(f"{plan:<6}{method:<14}{scores['hemisphere_logcos_rmse']:>13.4f}{scores['image_delta_e2000_mean']:>9.2f}"
                  f"{scores['image_delta_e2000_p95']:>8.2f}{scores['image_noise_delta_e2000_mean']:>10.2f}"
                  f"{scores['fit_time_s']:>8.1f}")


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0], allow_abbrev=False)
    parser.add_argument("--bsdf", default=str(DEFAULT_FILE), help="the RGL measurement (default: the shared file)")
    parser.add_argument("--plans", default="DS1,DS3")
    parser.add_argument("--spp", type=int, default=64)
    parser.add_argument("--resolution", type=int, default=128)
    parser.add_argument("--work", default=str(REPO / "runs" / "rgl_real"), help="cells kept here and reused")
    parser.add_argument("--out", default=str(REPO / "benchmarks" / "rgl_real.json"))
    args = parser.parse_args(argv)
    bsdf = Path(args.bsdf)
    if not bsdf.is_file():
        print(f"skipping: {bsdf} not found")
        return 0
    started = time.perf_counter()
    measurement = RglBsdf.load(bsdf)
    settings = RenderSettings(variant=measurement.variant, spp=args.spp, resolution=args.resolution)
    plans = args.plans.split(",")
    results = {"file": bsdf.name, "description": measurement.description, "spectral": measurement.is_spectral,
               "machine": {"platform": platform.platform()}, "render": vars(settings), "plans": {}}
    for plan in plans:
        results["plans"][plan] = {method: run_cell(method, bsdf, plan, settings, Path(args.work)) for method in METHODS}
    out = Path(args.out)
    for method, scores in results["plans"][plans[0]].items():
        comparison = scores.pop("comparison", None) if isinstance(scores, dict) else None
        if comparison:
            shutil.copyfile(comparison, out.with_name(f"{out.stem}_{plans[0]}_{method}.png"))
    for rows in results["plans"].values():
        for scores in rows.values():
            scores.pop("comparison", None)
    results["wall_time_s"] = time.perf_counter() - started
    with atomic_write(out) as handle:
        handle.write(json.dumps(results, indent=2, sort_keys=True) + "\n")
    print_table(results)
    print(f"\n-> {out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
