"""Speed of the exported models and their fast paths, in one run, as ratios against Mitsuba's
``roughconductor`` rendered in the same run (docs/evaluate.md#metrics, docs/mitsuba-plugin.md, docs/results.md, docs/select.md).

    python benchmarks/run.py [--quick] [--repeats N] [--out benchmarks/results.json]

1. **Models.**

   * ``spectral_mlp`` — the spectral MLP trained on the shipped virtual gold measurement
     (``train.py fit --config configs/spectral_mlp.yaml``, fewer epochs with ``--quick``), exported
     with its RGB head ``f_rgb`` (``neuralbrdf export``; :mod:`neuralbrdf.lod.fast_paths`);
   * ``nlb`` — the default NLB network (``nlb_latent32_blends``) with the latent of its pretraining
     material :data:`NLB_MATERIAL`, exported with its fast path ``f_fast`` (``neuralbrdf export --fast``);
   * ``nlb_spectral`` — the spectral NLB fitted to the shipped virtual gold measurement
     (``configs/nlb_spectral.yaml``, spectral, one material), exported as ``neuralbrdf export --fast``
     does: ``f`` without the units the material never fires, its RGB head ``f_rgb`` and its fast path
     ``f_fast``;
   * ``abc`` — an ABC model with fixed parameters (:data:`ABC_BENCH_PARAMETERS`);
   * ``auto`` — the ``auto`` fit of the same virtual gold measurement (``configs/auto.yaml``), exported
     as ``neuralbrdf export`` does: the chosen candidate's graph (for the gold, ABC: no fast path);
   * ``flat`` — a nearly free spectral model (:class:`FlatSpectrum`): the plugin's own cost.

   The fast paths are distilled with the settings of ``configs/lod/default.yaml`` (``fast_paths``;
   ``--quick``: a few hundred steps).
2. **Renders.**  For each variant (``llvm_ad_rgb``, ``llvm_ad_spectral``) the material-preview
   scene of ``export/render.py`` is rendered with each configuration of :func:`render_configs`:
   Mitsuba's ``roughconductor`` (GGX gold, α = 0.2) in symbolic and wavefront mode, every model
   through the ``drjit`` backend (symbolic mode; the spectral MLP also through ``onnxruntime``, in
   wavefront mode), the NLB full and through its fast path, the spectral NLB through ``drjit`` and
   ``onnxruntime`` (its ``f`` in the spectral variant, its RGB head in the RGB one) and through its fast
   path (spectral variant; in RGB variants the RGB head is its fast path), and — RGB variant — the
   spectral MLP and the spectral NLB integrated to sRGB by the plugin's rule (``rgb_head`` off: what
   the RGB head replaces).  The
   first render of each (tracing and compilation) is timed apart; then ``repeats`` renders are
   taken round-robin over the configurations (each scene reloaded, one scene alive at a time), so
   that load from other processes hits all alike; median and shortest are reported, and the
   ratios of each against ``roughconductor`` of the same mode (onnxruntime against wavefront)
   for both.  Every configuration uses the same pass split.
3. **Fast-path image error.**  A fast path and its parent are the same file, so they sample the
   same paths: their first renders (same seed) differ by the fast path's own error: mean and p95
   CIEDE2000 of each RGB head against the spectral integration (RGB variant), of the NLB's fast
   path against the full NLB (both variants) and of the spectral NLB's fast path against its full
   network (spectral variant).
4. **Throughput.**  Raw model evaluation, queries per second at one batch size (10⁶; one query is
   one ``(wi, wo[, λ])``), for PyTorch (where the module is at hand), onnxruntime (the exported
   output), Dr.Jit (:class:`~neuralbrdf.render.drjit_onnx.DrJitGraph` on ``drjit.llvm`` arrays,
   ``dr.eval`` timed, tracing included) and ``drjit_kernel``: the same fused kernel's own run time
   from Dr.Jit's kernel history, tracing and compilation excluded
   (:func:`~neuralbrdf.study.cost.drjit_kernel_seconds`).  Warm-up call first, then the median of
   ``repeats`` calls.

Targets quoted beside the results (:data:`TARGETS`, not asserted).  Results go to a JSON file
(``--out``) and a printed table, with the machine, versions, thread counts, load average before
and after, configuration and seed.
"""

from __future__ import annotations

import argparse
import dataclasses
import gc
import json
import math
import os
import resource
import statistics
import subprocess
import sys
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import onnx
import torch

from neuralbrdf import kinds, onnx_export
from neuralbrdf.atomic import atomic_write
from neuralbrdf.kinds import abc as abc_kind
from neuralbrdf.kinds import contract_metadata
from neuralbrdf.models.directional import NlbWithLatent
from neuralbrdf.onnx_contract import OUTPUT_F, OUTPUT_FAST, OUTPUT_RGB
from neuralbrdf.physics.abc import AbcParameters
from neuralbrdf.render import preview
from neuralbrdf.shipped import PRETRAINED_DEFAULT
from neuralbrdf.study.cost import bench_throughput, machine
from neuralbrdf.study.cost import timed as _timed

ROOT = Path(__file__).resolve().parents[1]
SEED = 0
VARIANTS = ("llvm_ad_rgb", "llvm_ad_spectral")
#: The pretraining material of the default NLB network whose latent the benchmark's NLB uses.
NLB_MATERIAL = "merl:gold-metallic-paint2"
#: Löw et al.-like parameters of the ABC model (speed only).
ABC_BENCH_PARAMETERS = AbcParameters(kd=[0.1, 0.08, 0.05], A=[1.0, 0.8, 0.6], B=200.0, C=1.1, eta=1.5)
TARGETS = {
    "llvm_ad_rgb/spectral_mlp/drjit": "<= 1.2",
    "llvm_ad_rgb/spectral_mlp/onnxruntime": "<= 1.4",
    "llvm_ad_rgb/spectral_mlp rgb head image dE2000 mean": "<= 0.5",
    "llvm_ad_spectral/spectral_mlp/drjit": "<= 1.05",
    "llvm_ad_rgb/abc/drjit": "<= 1.2",
    "llvm_ad_spectral/abc/drjit": "<= 1.2",
    "llvm_ad_rgb/auto/drjit": "<= 1.2",
    "llvm_ad_spectral/auto/drjit": "<= 1.2",
    "llvm_ad_rgb/nlb_fast/drjit": "<= 1.2",
    "llvm_ad_spectral/nlb_fast/drjit": "<= 1.2",
    "nlb fast path image dE2000 mean": "<= 1.0",
    "llvm_ad_rgb/nlb_spectral/drjit": "<= 1.2",
    "llvm_ad_spectral/nlb_spectral_fast/drjit": "<= 1.2",
    "llvm_ad_spectral/nlb_spectral/drjit": "<= 1.5",
    "nlb_spectral fast path and rgb head image dE2000 mean": "<= 0.5",
}
#: The material the benchmark's spectral NLB is fitted to (its shipped DS1 measurement).
NLB_SPECTRAL_MATERIAL = "gold"


@dataclass(frozen=True)
class RenderConfig:
    """One timed render: ``model`` (``None``: roughconductor), backend, Dr.Jit mode, plugin
    properties (``fast``, ``rgb_head``), variants it applies to."""

    name: str
    model: str | None
    backend: str = "drjit"
    wavefront: bool = False
    fast: bool = False
    rgb_head: bool = True
    variants: tuple[str, ...] = VARIANTS

    @property
    def baseline(self) -> str:
        return "roughconductor/wavefront" if self.wavefront else "roughconductor/symbolic"


def render_configs() -> tuple[RenderConfig, ...]:
    return (
        RenderConfig("roughconductor/symbolic", None),
        RenderConfig("roughconductor/wavefront", None, wavefront=True),
        RenderConfig("spectral_mlp/drjit", "spectral_mlp"),
        RenderConfig("spectral_mlp/onnxruntime", "spectral_mlp", backend="onnxruntime", wavefront=True),
        RenderConfig("spectral_mlp_integrated/drjit", "spectral_mlp", rgb_head=False, variants=("llvm_ad_rgb",)),
        RenderConfig("abc/drjit", "abc"),
        RenderConfig("auto/drjit", "auto"),
        RenderConfig("nlb/drjit", "nlb"),
        RenderConfig("nlb_fast/drjit", "nlb", fast=True),
        RenderConfig("nlb_spectral/drjit", "nlb_spectral"),
        RenderConfig("nlb_spectral/onnxruntime", "nlb_spectral", backend="onnxruntime", wavefront=True),
        RenderConfig("nlb_spectral_integrated/drjit", "nlb_spectral", rgb_head=False, variants=("llvm_ad_rgb",)),
        RenderConfig("nlb_spectral_fast/drjit", "nlb_spectral", fast=True, variants=("llvm_ad_spectral",)),
        RenderConfig("flat_model/drjit", "flat"),
    )


#: Image comparisons at matched paths: (fast path, its parent, variants).
IMAGE_PAIRS = (
    ("spectral_mlp/drjit", "spectral_mlp_integrated/drjit", ("llvm_ad_rgb",)),
    ("nlb_fast/drjit", "nlb/drjit", VARIANTS),
    ("nlb_spectral/drjit", "nlb_spectral_integrated/drjit", ("llvm_ad_rgb",)),
    ("nlb_spectral_fast/drjit", "nlb_spectral/drjit", ("llvm_ad_spectral",)),
)


@dataclass(frozen=True)
class Settings:
    epochs: int
    resolution: int
    spp: int
    repeats: int
    batch: int
    #: Distillation steps of the fast paths (``None``: the config's).
    distill_steps: int | None = None
    #: Timed renders round-robin over the configurations, each scene reloaded; ``False``
    #: (``--quick``, a smoke test) repeats the renders on the scene already loaded.
    round_robin: bool = True

    @classmethod
    def for_mode(cls, quick: bool, repeats: int | None) -> Settings:
        if quick:
            return cls(epochs=2, resolution=48, spp=4, repeats=repeats or 2, batch=2**16, distill_steps=200,
                       round_robin=False)
        return cls(epochs=30, resolution=256, spp=64, repeats=repeats or 5, batch=10**6)


# --------------------------------------------------------------------------- models


def _fast_path_settings(settings: Settings):
    from neuralbrdf.lod.config import load_lod_config

    config = load_lod_config().fast_paths
    if settings.distill_steps is None:
        return config
    small = dataclasses.replace(config.distill, steps=settings.distill_steps, n_pairs=8192, batch=1024)
    image = dataclasses.replace(config.image_check, resolution=32, spp=4, max_delta_e2000_mean=math.inf)
    return dataclasses.replace(config, distill=small, error_strata=(8, 10),
                               max_hemisphere_logcos_rmse=math.inf, image_check=image)


def with_fast_paths(model: Path, outputs: tuple[str, ...], settings: Settings) -> tuple[Path, dict]:
    """``model`` with its fast paths ``outputs`` added (as ``neuralbrdf export`` does); the new file
    and, per fast path, what it recorded (``build_s``: all of them together)."""
    from neuralbrdf.lod.fast_paths import add_fast_paths

    out = model.with_name(f"{model.stem}_{'_'.join(outputs)}.onnx")
    start = time.perf_counter()
    reports = add_fast_paths(model, out, outputs, _fast_path_settings(settings), log=lambda _: None)
    build_s = time.perf_counter() - start
    return out, {report.output: {**dataclasses.asdict(report), "build_s": build_s} for report in reports}


def fit_spectral_nlb(settings: Settings, workdir: Path) -> dict:
    """The spectral NLB fitted to :data:`NLB_SPECTRAL_MATERIAL`'s shipped measurement
    (``neuralbrdf train fit --config nlb_spectral``) and exported; paths, fit and export times."""
    run_dir = workdir / "nlb_spectral_run"
    command = [
        sys.executable, "-m", "neuralbrdf", "train", "fit", "--config", str(ROOT / "configs" / "nlb_spectral.yaml"),
        "--data.sources", json.dumps([{"virtual": NLB_SPECTRAL_MATERIAL}]), "--data.eval_plan", "null",
        "--run_dir", str(run_dir), "--trainer.enable_progress_bar", "false",
        *(["--trainer.max_epochs", "1", "--data.steps_per_epoch", "20"] if settings.distill_steps is not None else []),
    ]
    train_s = _timed(lambda: subprocess.run(command, cwd=ROOT, check=True, capture_output=True, text=True))
    metrics = json.loads((run_dir / "metrics.json").read_text())
    checkpoint = run_dir / "checkpoints" / "fitted.ckpt"
    model = workdir / f"{NLB_SPECTRAL_MATERIAL}_nlb_spectral.onnx"
    start = time.perf_counter()
    report = onnx_export.export_checkpoint(checkpoint, model)
    return {"path": str(model), "checkpoint": str(checkpoint), "material": NLB_SPECTRAL_MATERIAL,
            "train_command_s": train_s, "fit_wall_time_s": metrics.get("fit/wall_time_s"),
            "hidden_units": kinds.load_model(model).metadata.get("neuralbrdf.nlb_spectral.hidden_units"),
            "export_s": time.perf_counter() - start, "export_max_rel_error": report.max_rel_error}


def fit_auto(workdir: Path) -> dict:
    """The ``auto`` fit of :data:`NLB_SPECTRAL_MATERIAL`'s shipped measurement (``neuralbrdf train fit
    --config auto``), exported as ``neuralbrdf export`` exports it; paths, choice, fit and export times."""
    run_dir = workdir / "auto_run"
    command = [
        sys.executable, "-m", "neuralbrdf", "train", "fit", "--config", str(ROOT / "configs" / "auto.yaml"),
        "--data.virtual", NLB_SPECTRAL_MATERIAL, "--data.eval_plan", "null", "--run_dir", str(run_dir),
        "--trainer.enable_progress_bar", "false",
    ]
    train_s = _timed(lambda: subprocess.run(command, cwd=ROOT, check=True, capture_output=True, text=True))
    metrics = json.loads((run_dir / "metrics.json").read_text())
    checkpoint = run_dir / "checkpoints" / "best.ckpt"
    model = workdir / f"{NLB_SPECTRAL_MATERIAL}_auto.onnx"
    start = time.perf_counter()
    onnx_export.export_checkpoint(checkpoint, model)
    return {"path": str(model), "checkpoint": str(checkpoint), "material": NLB_SPECTRAL_MATERIAL,
            "choice": metrics["fit/auto/choice"], "train_command_s": train_s,
            "fit_wall_time_s": metrics.get("fit/wall_time_s"), "export_s": time.perf_counter() - start}


def train_spectral_mlp(settings: Settings, workdir: Path) -> dict:
    """Train the spectral MLP with train.py (config as shipped) and export it; paths and wall times."""
    run_dir = workdir / "spectral_mlp_run"
    command = [
        sys.executable, str(ROOT / "train.py"), "fit", "--config", str(ROOT / "configs" / "spectral_mlp.yaml"),
        "--trainer.max_epochs", str(settings.epochs), "--run_dir", str(run_dir), "--seed_everything", str(SEED),
    ]
    train_s = _timed(lambda: subprocess.run(command, cwd=ROOT, check=True, capture_output=True, text=True))
    metrics = json.loads((run_dir / "metrics.json").read_text())
    model = workdir / "gold_spectral_mlp.onnx"
    checkpoint = run_dir / "checkpoints" / "best.ckpt"
    start = time.perf_counter()
    report = onnx_export.export_checkpoint(checkpoint, model)
    return {
        "path": str(model), "checkpoint": str(checkpoint), "epochs": settings.epochs, "train_command_s": train_s,
        "val_rel_rmse_glossy_median": metrics.get("fit/val/rel_rmse_glossy_median"),
        "export_s": time.perf_counter() - start, "export_max_rel_error": report.max_rel_error,
    }


def nlb_exportable() -> onnx_export.Exportable:
    """The default NLB network with the latent of :data:`NLB_MATERIAL`."""
    from neuralbrdf.lightning.nlb_module import load_pretrained

    pretrained = load_pretrained(PRETRAINED_DEFAULT)
    latent = pretrained.latents[list(pretrained.names).index(NLB_MATERIAL)]
    module = NlbWithLatent(pretrained.network, latent).eval()
    metadata = contract_metadata("nlb", NLB_MATERIAL, f"benchmarks/run.py: {PRETRAINED_DEFAULT.name}, latent of {NLB_MATERIAL}")
    return onnx_export.Exportable(module, "nlb", NLB_MATERIAL, metadata, None)


class FlatSpectrum(torch.nn.Module):
    """A nearly free spectral model, ``f = (0.5 + 1e-4 (λ − 550 nm)) / π``: renders with it time the
    plugin's own machinery (Python BSDF, proposal sampling) without a network."""

    def forward(self, wi: torch.Tensor, wo: torch.Tensor, wavelength: torch.Tensor) -> torch.Tensor:
        f = (0.5 + 1e-4 * (wavelength - 550.0)) / math.pi
        return torch.where((wi[:, 2] > 0) & (wo[:, 2] > 0), f, torch.zeros_like(f))


def write_flat_model(path: Path) -> Path:
    metadata = contract_metadata("spectral_mlp", "flat", "benchmarks/run.py", wavelength_range_nm=(400.0, 700.0))
    exportable = onnx_export.Exportable(FlatSpectrum(), "spectral_mlp", "flat", metadata, (400.0, 700.0))
    onnx.save(onnx_export.trace(exportable), str(path))
    return path


# --------------------------------------------------------------------------- renders


def _evaluated(scene) -> dict:
    """Which output the scene's ``neuralbrdf`` BSDF evaluates and, for a spectral output in an RGB
    variant, the wavelengths of its sRGB rule (none for roughconductor)."""
    for shape in scene.shapes():
        bsdf = shape.bsdf()
        if hasattr(bsdf, "output"):
            rule = bsdf.rgb_rule
            return {"output": bsdf.output, **({"rgb_rule_wavelengths_nm": list(rule.wavelengths_nm)} if rule else {})}
    return {}


def bench_renders(models: dict[str, Path], variant: str, settings: Settings) -> dict:
    """First-call, median and shortest render times of the configurations of ``variant``, their
    ratios, and the image errors of :data:`IMAGE_PAIRS` (module docstring)."""
    from neuralbrdf.evaluation.images import image_scores

    preview.set_variant(variant)
    spp_per_pass = preview.default_spp_per_pass(settings.resolution, wavefront=True)  # one split for all
    paths = settings.resolution * settings.resolution * settings.spp
    configs = {c.name: c for c in render_configs() if variant in c.variants}
    materials = {
        name: preview.Material(reference_bsdf="roughconductor") if c.model is None else
        preview.Material(model=models[c.model], backend=c.backend, fast=c.fast, rgb_head=c.rgb_head)
        for name, c in configs.items()
    }
    results = {name: {"wavefront": c.wavefront, "times_s": []} for name, c in configs.items()}
    first_images = {}

    def load_and_render(name: str, seeds: list[int]) -> tuple[float, list[float], np.ndarray]:
        """``(load_s, render_s per seed, first image)``; the scene is dropped before returning."""
        start = time.perf_counter()
        scene = preview.load_scene(materials[name], settings.resolution)
        load_s = time.perf_counter() - start
        results[name].update(_evaluated(scene))
        times, image = [], None
        for seed in seeds:
            start = time.perf_counter()
            rendered = preview.render_passes(scene, settings.spp, spp_per_pass, seed, results[name]["wavefront"])
            times.append(time.perf_counter() - start)
            if not np.all(np.isfinite(rendered)):
                raise RuntimeError(f"{variant} {name}: the render is not finite")
            image = rendered if image is None else image
        del scene
        gc.collect()
        return load_s, times, image

    repeat_seeds = [SEED + 1 + repeat for repeat in range(settings.repeats)]
    for name in results:
        seeds = [SEED] if settings.round_robin else [SEED, *repeat_seeds]
        results[name]["scene_load_s"], times, first_images[name] = load_and_render(name, seeds)
        results[name]["first_call_s"], results[name]["times_s"] = times[0], times[1:]
    for seed in repeat_seeds if settings.round_robin else []:
        for name in results:
            results[name]["times_s"].extend(load_and_render(name, [seed])[1])
    for entry in results.values():
        entry["median_s"] = statistics.median(entry["times_s"])
        entry["shortest_s"] = min(entry["times_s"])
        entry["ns_per_path_sample"] = entry["median_s"] / paths * 1e9
    ratios = {}
    for name, config in configs.items():
        if config.model is None:
            continue
        base = results[config.baseline]
        ratios[name] = {"median": results[name]["median_s"] / base["median_s"],
                        "shortest": results[name]["shortest_s"] / base["shortest_s"], "baseline": config.baseline}
    images = {}
    for fast, parent, variants in IMAGE_PAIRS:
        if variant in variants:
            metrics, _ = image_scores(first_images[fast], first_images[parent])
            images[f"{fast} vs {parent}"] = metrics
    return {"configs": results, "ratios": ratios, "image_errors": images, "spp_per_pass": spp_per_pass}


# --------------------------------------------------------------------------- throughput


def bench_models_throughput(models: dict[str, Path], modules: dict[str, torch.nn.Module], settings: Settings) -> dict:
    """Throughput of every model's ``f`` and of each fast path (module docstring, 4)."""
    out = {}
    cases = (("spectral_mlp", "spectral_mlp", OUTPUT_F), ("spectral_mlp rgb head", "spectral_mlp", OUTPUT_RGB),
             ("nlb", "nlb", OUTPUT_F), ("nlb fast path", "nlb", OUTPUT_FAST), ("abc", "abc", OUTPUT_F),
             ("nlb_spectral", "nlb_spectral", OUTPUT_F), ("nlb_spectral rgb head", "nlb_spectral", OUTPUT_RGB),
             ("nlb_spectral fast path", "nlb_spectral", OUTPUT_FAST))
    for name, model, output in cases:
        view = kinds.load_model(models[model]).output_view(output)
        module = modules.get(model) if output == OUTPUT_F else None
        backends = bench_throughput(view.proto, view.is_spectral, settings.batch, settings.repeats, module,
                                    kernel_time=True)
        out[name] = {"output": output, "backends": backends,
                     "fastest": max(backends, key=lambda b: backends[b]["queries_per_s"])}
    return out


# --------------------------------------------------------------------------- report


def _table(results: dict) -> str:
    load = results["load_average"]
    lines = [
        f"machine: {results['machine']['cpu']}, {results['machine']['cores']} cores; load average (1 min) "
        f"{load['before'][0]:.1f} before, {load['after'][0]:.1f} after; scene {results['settings']['resolution']}^2 x "
        f"{results['settings']['spp']} spp, {results['settings']['repeats']} renders each, round-robin",
        f"spectral MLP: {results['models']['spectral_mlp']['epochs']} epochs, val glossy rel. RMSE "
        f"{results['models']['spectral_mlp']['val_rel_rmse_glossy_median']:.3g}",
        f"spectral NLB: {results['models']['nlb_spectral']['material']}, fitted in "
        f"{results['models']['nlb_spectral']['fit_wall_time_s']:.1f} s, hidden units "
        f"{results['models']['nlb_spectral']['hidden_units']}",
    ]
    for output, fast in results["fast_paths"].items():
        lines.append(f"{output}: {fast['approximates']}; log-cos RMSE {fast['hemisphere_logcos_rmse']:.4f}, "
                     f"image dE2000 {fast['image_delta_e2000_mean']:.3f} (export check), relative cost "
                     f"{fast['relative_cost']:.2f} (built in {fast['build_s']:.0f} s)")
    lines += ["", f"{'variant':<18}{'configuration':<32}{'output':<8}{'first s':>9}{'median s':>10}{'short s':>9}"
                  f"{'x rc median':>12}{'x rc short':>11}  target"]
    for variant, entry in results["render"].items():
        for name, r in entry["configs"].items():
            ratio = entry["ratios"].get(name)
            target = TARGETS.get(f"{variant}/{name}", "")
            lines.append(
                f"{variant:<18}{name:<32}{r.get('output', ''):<8}{r['first_call_s']:>9.2f}{r['median_s']:>10.3f}"
                f"{r['shortest_s']:>9.3f}" + (f"{ratio['median']:>12.2f}{ratio['shortest']:>11.2f}  {target}" if ratio else "")
            )
        for pair, metrics in entry["image_errors"].items():
            lines.append(f"{variant:<18}image {pair}: dE2000 mean {metrics['image_delta_e2000_mean']:.3f}, "
                         f"p95 {metrics['image_delta_e2000_p95']:.3f}")
    lines += ["", "(x rc: render time over roughconductor's in the same mode; onnxruntime against wavefront mode)", "",
              f"{'model':<24}{'backend':<14}{'median s':>10}{'M queries/s':>13}"]
    for name, entry in results["throughput"].items():
        for backend, r in entry["backends"].items():
            lines.append(f"{name:<24}{backend:<14}{r['median_s']:>10.4f}{r['queries_per_s'] / 1e6:>13.1f}")
    lines.append(f"(batch {results['settings']['batch']}; drjit: one traced call; drjit_kernel: the fused kernel's own "
                 "run time from Dr.Jit's kernel history, tracing and compilation excluded)")
    return "\n".join(lines)


def run(quick: bool, out: Path, repeats: int | None = None) -> dict:
    settings = Settings.for_mode(quick, repeats)
    started = time.perf_counter()
    results = {
        "command": "python benchmarks/run.py" + (" --quick" if quick else ""),
        "quick": quick,
        "seed": SEED,
        "machine": machine(),
        "load_average": {"before": list(os.getloadavg())},
        "settings": settings.__dict__,
        "targets": TARGETS,
    }
    with tempfile.TemporaryDirectory(prefix="neuralbrdf-bench-") as tmp:
        workdir = Path(tmp)
        spectral = train_spectral_mlp(settings, workdir)
        nlb = nlb_exportable()
        nlb_path = onnx_export.write_model(nlb, workdir / "nlb.onnx").path
        abc = abc_kind.exportable(ABC_BENCH_PARAMETERS, "benchmark", "benchmarks/run.py")
        abc_path = onnx_export.write_model(abc, workdir / "abc.onnx").path
        spectral_nlb = fit_spectral_nlb(settings, workdir)
        auto = fit_auto(workdir)
        spectral_path, spectral_paths = with_fast_paths(Path(spectral["path"]), (OUTPUT_RGB,), settings)
        nlb_fast_path, nlb_paths = with_fast_paths(nlb_path, (OUTPUT_FAST,), settings)
        spectral_nlb_path, spectral_nlb_paths = with_fast_paths(Path(spectral_nlb["path"]), (OUTPUT_RGB, OUTPUT_FAST),
                                                                settings)
        results["models"] = {"spectral_mlp": spectral, "nlb": {"network": PRETRAINED_DEFAULT.name, "latent": NLB_MATERIAL},
                             "abc": ABC_BENCH_PARAMETERS.to_dict(), "nlb_spectral": spectral_nlb,
                             "auto": auto}
        results["fast_paths"] = {f"{model} {output}": entry
                                 for model, paths in (("spectral_mlp", spectral_paths), ("nlb", nlb_paths),
                                                      ("nlb_spectral", spectral_nlb_paths))
                                 for output, entry in paths.items()}
        models = {"spectral_mlp": spectral_path, "nlb": nlb_fast_path, "abc": abc_path, "auto": Path(auto["path"]),
                  "nlb_spectral": spectral_nlb_path, "flat": write_flat_model(workdir / "flat.onnx")}
        results["render"] = {variant: bench_renders(models, variant, settings) for variant in VARIANTS}
        modules = {"spectral_mlp": kinds.load_exportable(spectral["checkpoint"]).module, "nlb": nlb.module,
                   "abc": abc.module, "nlb_spectral": kinds.load_exportable(spectral_nlb["checkpoint"]).module,
                   "auto": kinds.load_exportable(auto["checkpoint"]).module}
        results["throughput"] = bench_models_throughput(models, modules, settings)
    results["load_average"]["after"] = list(os.getloadavg())
    results["peak_rss_mb"] = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
    results["wall_time_s"] = time.perf_counter() - started
    with atomic_write(out) as handle:
        json.dump(results, handle, indent=2, allow_nan=False)
        handle.write("\n")
    return results


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="benchmarks/run.py", description=__doc__.split("\n\n")[0], allow_abbrev=False)
    parser.add_argument("--quick", action="store_true", help="tiny scene, 2 epochs, short distillations (smoke test)")
    parser.add_argument("--repeats", type=int, default=None, help="timed renders per configuration (default 5; quick 2)")
    parser.add_argument("--out", default=str(ROOT / "benchmarks" / "results.json"), help="JSON results file")
    args = parser.parse_args(argv)
    if args.repeats is not None and args.repeats < 1:
        parser.error("--repeats must be a positive integer")
    results = run(args.quick, Path(args.out), args.repeats)
    print(_table(results))
    print(f"\nwrote {args.out} ({results['wall_time_s']:.0f} s)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
