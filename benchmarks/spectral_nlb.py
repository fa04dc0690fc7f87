"""Where users look: the spectral NLB against ABC, the RGB NLB and the spectral MLP on materials
no pretraining saw (docs/models.md#spectral-nlb, docs/evaluate.md).

    python benchmarks/spectral_nlb.py [--groups rgl_validation,report,merl_held_out] [--plans DS1]
        [--noise 0.01] [--no-render] [--methods M,...] [--mlp-args "ARG ..."] [--work DIR]
        [--out benchmarks/spectral_nlb.json] [--spectral-args ARG ...]

For every material of the chosen groups and every plan:

* ``nlb_spectral`` — ``configs/nlb_spectral.yaml``, all the group's materials in one batch
  (spectral measurements band by band, RGB ones per channel), plus ``--spectral-args`` (a
  settings sweep);
* ``nlb`` — ``configs/nlb_latent.yaml``, the RGB NLB's default fit, one batch;
* ``abc`` — ``configs/abc.yaml``, the in-plane ABC fit of the same samples, one per material;
* ``spectral_mlp`` — ``configs/spectral_mlp.yaml`` (virtual groups: it needs spectra), plus
  ``--mlp-args`` (one quoted string of overrides: a settings sweep);

each fit exported (``neuralbrdf export``) and scored by ``neuralbrdf evaluate`` against the
material's truth (``neuralbrdf export-truth``): the hemisphere log-cosine RMSE (102 400 pairs),
the in-plane glossy and diffuse errors, and — unless ``--no-render`` — the image ΔE2000 of the
material-preview scene (128 px, 64 spp; ``llvm_ad_rgb`` for the RGB proxies, ``llvm_ad_spectral``
for the virtual materials; model and truth at matched seeds, the truth-against-truth noise
stated).  A fit that fails is recorded as such.  Groups:

* ``rgl_validation`` — the RGL validation split (:data:`neuralbrdf.data.proxy_corpus.RGL_VALIDATION`,
  another lab): the spectral NLB's settings for RGB measurements are chosen here;
* ``virtual_validation`` — the virtual validation materials
  (:data:`neuralbrdf.virtual.materials.VALIDATION_MATERIALS`), measured by the virtual instrument
  with ``--noise``: the settings for spectral measurements are chosen here;
* ``merl_held_out`` — the ten MERL materials held out of pretraining (:data:`~neuralbrdf.data.proxy_corpus.HELD_OUT`);
* ``report`` — the report's five MERL materials;
* ``virtual`` — the four virtual stand-ins (gold, gonio, cyan, magenta), the test materials of
  the study, measured with ``--noise``.

``--methods`` runs only some of the methods (the summary's comparisons need ``nlb_spectral``).
Every cell (material × plan × method) is kept in ``--work`` (default ``runs/spectral_nlb``) and
reused when the script runs again with the same settings and the same config file contents.  Writes JSON (``--out``) and prints a
table with each group's medians and the spectral NLB's wins over ABC and the RGB NLB.
"""

from __future__ import annotations

import argparse
import hashlib
import json
import platform
import shlex
import sys
import time
from collections.abc import Sequence
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

from neuralbrdf.atomic import atomic_write  # noqa: E402
from neuralbrdf.data.nbrdf import REPORT_MATERIALS  # noqa: E402
from neuralbrdf.data.table import write_table  # noqa: E402
from neuralbrdf.data.proxy_corpus import HELD_OUT, RGL_VALIDATION  # noqa: E402
from neuralbrdf.evaluation.evaluate import RenderSettings, evaluate  # noqa: E402
from neuralbrdf.evaluation.truth import export_truth  # noqa: E402
from neuralbrdf.lightning.run import main as train_main  # noqa: E402
from neuralbrdf.onnx_export import export_checkpoint  # noqa: E402
from neuralbrdf.sources import virtual_measurement  # noqa: E402
from neuralbrdf.virtual.materials import VALIDATION_MATERIALS  # noqa: E402

SHARED = REPO.parent / "shared" / "data"
#: Measured groups: NBRDF proxies (RGB) of a folder.
PROXY_GROUPS = {
    "rgl_validation": (SHARED / "rgl-nbrdf", RGL_VALIDATION),
    "merl_held_out": (SHARED / "merl-nbrdf", HELD_OUT),
    "report": (SHARED / "merl-nbrdf", REPORT_MATERIALS),
}
#: Virtual groups: spectral measurements of the virtual instrument (GCMS raw + Munsell reference,
#: calibrated), with ``--noise`` relative noise.
VIRTUAL_GROUPS = {"virtual_validation": tuple(VALIDATION_MATERIALS), "virtual": ("gold", "gonio", "cyan", "magenta")}
GROUPS = (*PROXY_GROUPS, *VIRTUAL_GROUPS)
#: Methods of each kind of group (the spectral MLP needs spectra).
METHODS = {"proxy": ("nlb_spectral", "nlb", "abc"), "virtual": ("nlb_spectral", "nlb", "abc", "spectral_mlp")}
CONFIGS = {"nlb_spectral": "nlb_spectral.yaml", "nlb": "nlb_latent.yaml", "abc": "abc.yaml",
           "spectral_mlp": "spectral_mlp.yaml"}
BATCHED = ("nlb_spectral", "nlb")
CHECKPOINT = {"nlb_spectral": "fitted.ckpt", "nlb": "fitted.ckpt", "abc": "best.ckpt", "spectral_mlp": "best.ckpt"}
RENDER = {"proxy": RenderSettings(variant="llvm_ad_rgb", spp=64, resolution=128),
          "virtual": RenderSettings(variant="llvm_ad_spectral", spp=64, resolution=128)}
SCORES = ("hemisphere_logcos_rmse", "image_delta_e2000_mean", "image_delta_e2000_p95", "inplane_glossy_rel_rmse",
          "inplane_diffuse_rel_rmse")


def train_run(run_dir: Path, config: str, *overrides: str) -> dict:
    """``neuralbrdf train fit`` of ``configs/CONFIG`` into ``run_dir`` (replaced); its ``metrics.json``."""
    args = ["fit", "--config", str(REPO / "configs" / config), "--run_dir", str(run_dir), "--overwrite",
            "--trainer.enable_progress_bar", "false", *overrides]
    if train_main(args) != 0:
        raise RuntimeError(f"neuralbrdf train {' '.join(args)} failed")
    return json.loads((run_dir / "metrics.json").read_text())


def _digest(*parts) -> str:
    return hashlib.sha256(json.dumps(parts, sort_keys=True).encode()).hexdigest()[:12]


class Group:
    """The materials of a group on one plan: their fitting sources, data arguments and truths."""

    def __init__(self, name: str, plan: str, noise: float, work: Path) -> None:
        self.name, self.plan, self.work = name, plan, work
        self.kind = "proxy" if name in PROXY_GROUPS else "virtual"
        if self.kind == "proxy":
            folder, self.materials = PROXY_GROUPS[name]
            self.sources = {m: {"nbrdf": str(folder / f"{m}.h5")} for m in self.materials}
            self.truth_sources = {m: str(folder / f"{m}.h5") for m in self.materials}
        else:
            self.materials = VIRTUAL_GROUPS[name]
            self.sources = {m: {"path": str(self._measure(m, noise)), "name": m} for m in self.materials}
            self.truth_sources = {m: f"virtual:{m}" for m in self.materials}

    def _measure(self, material: str, noise: float) -> Path:
        """The calibrated spectral table of a virtual measurement (seed 0; kept in the work folder)."""
        path = self.work / "tables" / f"{material}_{self.plan}_noise{noise:g}.csv"
        if not path.is_file():
            path.parent.mkdir(parents=True, exist_ok=True)
            write_table(virtual_measurement(material, self.plan, noise, seed=0, reference_seed=1), path)
        return path

    def data_args(self, material: str) -> list[str]:
        source = self.sources[material]
        if "nbrdf" in source:
            return ["--data.nbrdf", source["nbrdf"], "--data.plan", self.plan, "--data.eval_plan", "null"]
        return ["--data.path", source["path"]]

    def truth(self, material: str) -> Path:
        path = self.work / "truths" / f"{material}.onnx"
        if not path.is_file():
            export_truth(self.truth_sources[material], path)
        return path


def _fit(group: Group, method: str, run_dir: Path, extra: list[str]) -> tuple[dict, dict]:
    """Checkpoints and fit times (per material) of ``method`` on every material of ``group``."""
    if method in BATCHED:
        sources = [group.sources[m] for m in group.materials]
        metrics = train_run(run_dir, CONFIGS[method], "--data.sources", json.dumps(sources), "--data.plan", group.plan,
                         "--data.eval_plan", "null", *extra)
        per_material = metrics["fit/wall_time_s"] / len(group.materials)
        return ({m: run_dir / "checkpoints" / CHECKPOINT[method] for m in group.materials},
                {m: per_material for m in group.materials})
    checkpoints, times = {}, {}
    for material in group.materials:
        try:
            metrics = train_run(run_dir / material, CONFIGS[method], *group.data_args(material), *extra)
        except RuntimeError as error:
            checkpoints[material], times[material] = None, str(error)
            continue
        checkpoints[material] = run_dir / material / "checkpoints" / CHECKPOINT[method]
        times[material] = metrics["fit/wall_time_s"]
    return checkpoints, times


def run_group(group: Group, work: Path, render: bool, spectral_args: list[str], mlp_args: list[str] = (),
              methods: Sequence[str] | None = None) -> dict:
    """Every method (of ``methods``, default all) on every material of ``group``: ``{material: {method: scores}}``."""
    extra = {"nlb_spectral": list(spectral_args), "spectral_mlp": list(mlp_args)}
    settings = {method: extra.get(method, []) for method in METHODS[group.kind] if methods is None or method in methods}
    rows: dict[str, dict] = {name: {} for name in group.materials}
    renders: dict = {}
    render_settings = RENDER[group.kind]
    for method in settings:
        key = _digest(group.name, group.plan, method, settings[method], render, vars(render_settings),
                      [group.sources[m] for m in group.materials], (REPO / "configs" / CONFIGS[method]).read_text())
        cell_dir = work / f"{group.name}_{group.plan}_{method}_{key}"
        done = cell_dir / "scores.json"
        if not done.is_file():
            print(f"[{group.name} {group.plan}] {method} ...", flush=True)
            checkpoints, fit_s = _fit(group, method, cell_dir / "run", settings[method])
            scores = {}
            for name in group.materials:
                if checkpoints[name] is None:
                    scores[name] = {"failed": fit_s[name]}
                    continue
                model = cell_dir / f"{name}.onnx"
                export_checkpoint(checkpoints[name], model, name if method in BATCHED else None)
                result = evaluate(model, group.truth(name), cell_dir / "eval" / name, render_settings,
                                  render_images=render, truth_renders=renders)
                scores[name] = {k: result.get(k) for k in SCORES} | {"fit_s_per_material": fit_s[name]}
                if render:
                    scores[name]["image_noise_delta_e2000_mean"] = result["noise"]["image_delta_e2000_mean"]
            with atomic_write(done) as handle:
                handle.write(json.dumps(scores, indent=2) + "\n")
        for name, value in json.loads(done.read_text()).items():
            rows[name][method] = value
    return rows


def summarise(rows: dict) -> dict:
    """Per metric: medians and means per method over the materials every method fitted, the
    spectral NLB's share of wins against each other method, and failures per method."""
    methods = list(next(iter(rows.values())))
    summary = {"failed": {m: sum("failed" in r[m] for r in rows.values()) for m in methods}}
    others = [m for m in methods if m != "nlb_spectral"] if "nlb_spectral" in methods else []
    fitted = [r for r in rows.values() if not any("failed" in r[m] for m in methods)]
    for metric in ("hemisphere_logcos_rmse", "image_delta_e2000_mean"):
        if not fitted or any(r[m].get(metric) is None for r in fitted for m in methods):
            continue
        values = {m: np.array([r[m][metric] for r in fitted], dtype=float) for m in methods}
        summary[metric] = {
            "materials": len(fitted),
            "median": {m: float(np.median(v)) for m, v in values.items()},
            "mean": {m: float(np.mean(v)) for m, v in values.items()},
            "nlb_spectral_beats": {m: float(np.mean(values["nlb_spectral"] < values[m])) for m in others},
            "median_nlb_spectral_over": {m: float(np.median(values["nlb_spectral"]) / np.median(values[m]))
                                         for m in others},
        }
    return summary


def _cell(scores: dict, metric: str, digits: int) -> str:
    value = None if "failed" in scores else scores.get(metric)
    return f"{'fail' if 'failed' in scores else '-':>13}" if value is None else f"{value:>13.{digits}f}"


def print_table(results: dict) -> None:
    for label, block in results["groups"].items():
        methods = list(next(iter(block["materials"].values())))
        print(f"\n{label}: hemisphere log-cos RMSE | image ΔE2000 mean")
        print(f"{'material':<24}" + "".join(f"{m:>13}" for m in methods) + "  |" + "".join(f"{m:>13}" for m in methods))
        for name, row in block["materials"].items():
            print(f"{name:<24}" + "".join(_cell(row[m], "hemisphere_logcos_rmse", 4) for m in methods) + "  |"
                  + "".join(_cell(row[m], "image_delta_e2000_mean", 2) for m in methods))
        summary = block["summary"]
        for metric in ("hemisphere_logcos_rmse", "image_delta_e2000_mean"):
            if metric in summary:
                s = summary[metric]
                line = f"  {metric} over {s['materials']}: medians " + ", ".join(f"{m} {v:.4g}" for m, v in s["median"].items())
                if s["nlb_spectral_beats"]:
                    line += ("; nlb_spectral beats " + ", ".join(f"{m} on {v:.0%}" for m, v in s["nlb_spectral_beats"].items())
                             + "; median nlb_spectral / "
                             + ", ".join(f"{m} {v:.2f}" for m, v in s["median_nlb_spectral_over"].items()))
                print(line)
        failed = {m: n for m, n in summary["failed"].items() if n}
        if failed:
            print(f"  failed fits: {failed}")


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0], allow_abbrev=False)
    parser.add_argument("--groups", default="rgl_validation,report,merl_held_out",
                        help=f"comma-separated, of {', '.join(GROUPS)}")
    parser.add_argument("--plans", default="DS1")
    parser.add_argument("--noise", type=float, default=0.01, help="relative noise of virtual measurements")
    parser.add_argument("--no-render", action="store_true", help="hemisphere and in-plane scores only (no images)")
    parser.add_argument("--methods", default=None, help=f"comma-separated, of {', '.join(CONFIGS)} (default: all)")
    parser.add_argument("--mlp-args", default="", help='overrides of the spectral MLP fit, one quoted string, e.g. '
                                                       '"--data.min_steps_per_epoch 164"')
    parser.add_argument("--spectral-args", nargs=argparse.REMAINDER, default=[],
                        help="overrides of the spectral NLB fit (last on the command line), e.g. "
                             "--model.channel_prior_weight 0.1")
    parser.add_argument("--work", default=str(REPO / "runs" / "spectral_nlb"), help="cells kept here and reused")
    parser.add_argument("--out", default=str(REPO / "benchmarks" / "spectral_nlb.json"))
    args = parser.parse_args(argv)
    unknown = sorted(set(args.groups.split(",")) - set(GROUPS))
    if unknown:
        parser.error(f"unknown groups {unknown}; expected some of {', '.join(GROUPS)}")
    methods = None if args.methods is None else args.methods.split(",")
    if methods is not None and sorted(set(methods) - set(CONFIGS)):
        parser.error(f"unknown methods {sorted(set(methods) - set(CONFIGS))}; expected some of {', '.join(CONFIGS)}")
    mlp_args = shlex.split(args.mlp_args)
    started = time.perf_counter()
    work = Path(args.work)
    results = {"machine": {"platform": platform.platform()}, "noise": args.noise,
               "render": None if args.no_render else {kind: vars(r) for kind, r in RENDER.items()},
               "spectral_args": args.spectral_args, "mlp_args": mlp_args, "methods": methods, "groups": {}}
    for name in args.groups.split(","):
        if name in PROXY_GROUPS and not PROXY_GROUPS[name][0].is_dir():
            print(f"skipping {name}: {PROXY_GROUPS[name][0]} not found")
            continue
        for plan in args.plans.split(","):
            rows = run_group(Group(name, plan, args.noise, work), work, not args.no_render, args.spectral_args,
                             mlp_args, methods)
            results["groups"][f"{name} {plan}"] = {"materials": rows, "summary": summarise(rows)}
    results["wall_time_s"] = time.perf_counter() - started
    with atomic_write(args.out) as handle:
        handle.write(json.dumps(results, indent=2, sort_keys=True) + "\n")
    print_table(results)
    print(f"\n-> {args.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
