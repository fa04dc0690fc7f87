"""Speed of the exported models, in one run, as ratios against a named baseline (SPEC §5, §7, §8).

    python benchmarks/run.py [--quick] [--out benchmarks/results.json]

1. **Model.** Trains the spectral MLP on the shipped virtual gold measurement
   (``train.py fit --config configs/spectral_mlp.yaml``, fewer epochs with ``--quick``) and
   exports it (``neuralbrdf export``); likewise a ReLU ablation of it
   (``--model.activation relu``: the cheapest activation, less accurate) to show what the
   activation costs.
2. **Renders.** For each variant (``llvm_ad_rgb``, ``llvm_ad_spectral``) the material-preview
   scene of ``export/render.py`` is rendered at one resolution and sample count with

   * ``roughconductor/symbolic`` — Mitsuba's built-in rough gold, Dr.Jit's default mode;
   * ``roughconductor/wavefront`` — the same with symbolic loops and calls off;
   * ``drjit/symbolic`` — the model through the ``drjit`` backend (fused kernel);
   * ``onnxruntime/wavefront`` — the model through ``onnxruntime`` (one batched call per
     wavefront; needs wavefront mode);
   * ``flat_model_drjit/symbolic`` — a nearly free spectral model (:class:`FlatSpectrum`)
     through ``drjit``: the plugin's cost without a network;
   * ``relu_model_drjit/symbolic`` — the ReLU ablation through ``drjit``.

   The first render of each (scene already loaded; kernel tracing and compilation, possibly a
   hit in Dr.Jit's on-disk kernel cache) is timed separately, then the median of ``repeats``
   renders, taken round-robin over the configurations (each scene reloaded), is reported
   (``--quick``: the repeats follow the first render on the loaded scene, no reloads).  Every
   configuration uses the same pass split (the wavefront budget of ``export/render.py``), and
   only one scene is loaded at a time.  The figures are the ratios
   ``drjit/symbolic : roughconductor/symbolic``, ``onnxruntime/wavefront :
   roughconductor/wavefront``, ``onnxruntime/wavefront : roughconductor/symbolic``,
   ``flat_model_drjit/symbolic : roughconductor/symbolic`` and
   ``relu_model_drjit/symbolic : roughconductor/symbolic``.
3. **Throughput.** Raw model evaluation, queries per second at one batch size (10⁶; one query
   is one ``(wi, wo[, λ])``), for PyTorch (the :mod:`neuralbrdf.models.directional` module),
   onnxruntime (the exported file) and Dr.Jit (:class:`~neuralbrdf.render.drjit_onnx.DrJitGraph`
   on ``drjit.llvm`` arrays, ``dr.eval`` timed, tracing included) — for the spectral MLP, the
   compact NLB (the shipped pretrained network if present, else random weights of the same size:
   speed does not depend on the values, as long as none is zero), the ABC model and the ReLU
   spectral MLP.  Warm-up call first (its time
   reported as ``first_call_s``), then the median of ``repeats`` calls.

Targets quoted beside the results (not asserted; :data:`TARGETS`, issue 11): Dr.Jit render
≤ 1.10× roughconductor in ``llvm_ad_spectral`` and ≤ 1.30× in ``llvm_ad_rgb``; onnxruntime ≤
1.40× roughconductor in wavefront mode; fastest backend ≥ 150 M queries/s for the spectral MLP
and ≥ 10 M queries/s for the compact NLB on two cores.  Results go to a JSON file (``--out``,
default ``benchmarks/results.json``) and a printed table; the machine, versions, thread counts,
configuration and seed are recorded with them.
"""

from __future__ import annotations

import argparse
import gc
import json
import math
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
from neuralbrdf.physics.abc import AbcParameters
from neuralbrdf.models.directional import NlbWithLatent
from neuralbrdf.models.nlb import NlbNetwork
from neuralbrdf.render import preview
from neuralbrdf.shipped import PRETRAINED_DIR
from neuralbrdf.kinds import contract_metadata
from neuralbrdf.study.cost import bench_throughput, machine
from neuralbrdf.study.cost import timed as _timed

ROOT = Path(__file__).resolve().parents[1]
SEED = 0
VARIANTS = ("llvm_ad_rgb", "llvm_ad_spectral")
#: (name, model: None for roughconductor / "trained" / "flat", backend, wavefront mode)
RENDER_CONFIGS = (
    ("roughconductor/symbolic", None, None, False),
    ("roughconductor/wavefront", None, None, True),
    ("drjit/symbolic", "trained", "drjit", False),
    ("onnxruntime/wavefront", "trained", "onnxruntime", True),
    ("flat_model_drjit/symbolic", "flat", "drjit", False),
    ("relu_model_drjit/symbolic", "relu", "drjit", False),
)
RATIOS = {
    "drjit_vs_roughconductor_symbolic": ("drjit/symbolic", "roughconductor/symbolic"),
    "flat_model_drjit_vs_roughconductor_symbolic": ("flat_model_drjit/symbolic", "roughconductor/symbolic"),
    "relu_model_drjit_vs_roughconductor_symbolic": ("relu_model_drjit/symbolic", "roughconductor/symbolic"),
    "onnxruntime_vs_roughconductor_wavefront": ("onnxruntime/wavefront", "roughconductor/wavefront"),
    "onnxruntime_vs_roughconductor_symbolic": ("onnxruntime/wavefront", "roughconductor/symbolic"),
}
TARGETS = {
    "llvm_ad_spectral/drjit_vs_roughconductor_symbolic": "<= 1.10",
    "llvm_ad_rgb/drjit_vs_roughconductor_symbolic": "<= 1.30",
    "llvm_ad_spectral/onnxruntime_vs_roughconductor_wavefront": "<= 1.40",
    "llvm_ad_rgb/onnxruntime_vs_roughconductor_wavefront": "<= 1.40",
    "spectral_mlp/fastest_backend_queries_per_s": ">= 150e6 on 2 cores",
    "nlb_compact/fastest_backend_queries_per_s": ">= 10e6 on 2 cores",
}
#: Löw et al.-like parameters of the ABC throughput model (speed only).
ABC_BENCH_PARAMETERS = AbcParameters(kd=[0.1, 0.08, 0.05], A=[1.0, 0.8, 0.6], B=200.0, C=1.1, eta=1.5)
#: The 48×3 graph of the throughput row; the default network (nlb_latent32_blends) is the same
#: graph, its latent folded into the input bias, so it costs the same.
PRETRAINED_NLB = PRETRAINED_DIR / "nlb_compact.ckpt"


@dataclass(frozen=True)
class Settings:
    epochs: int
    resolution: int
    spp: int
    repeats: int
    batch: int
    #: Timed renders round-robin over the configurations, each scene reloaded (a neural scene
    #: takes ~1 s to load: the proposal and sRGB rule are fitted); ``False`` (``--quick``, a
    #: smoke test) repeats the renders on the scene already loaded.
    round_robin: bool = True

    @classmethod
    def for_mode(cls, quick: bool) -> Settings:
        if quick:
            return cls(epochs=2, resolution=48, spp=4, repeats=2, batch=2**16, round_robin=False)
        return cls(epochs=30, resolution=256, spp=64, repeats=5, batch=10**6)


# --------------------------------------------------------------------------- model


def train_and_export(settings: Settings, workdir: Path, activation: str = "tanh") -> dict:
    """Train the spectral MLP with train.py (config as shipped, or another hidden activation)
    and export it; paths and wall times."""
    run_dir = workdir / f"spectral_mlp_{activation}_run"
    command = [
        sys.executable, str(ROOT / "train.py"), "fit", "--config", str(ROOT / "configs" / "spectral_mlp.yaml"),
        "--trainer.max_epochs", str(settings.epochs), "--run_dir", str(run_dir), "--seed_everything", str(SEED),
        "--model.activation", activation,
    ]
    train_s = _timed(lambda: subprocess.run(command, cwd=ROOT, check=True, capture_output=True, text=True))
    metrics = json.loads((run_dir / "metrics.json").read_text())
    model = workdir / f"gold_spectral_mlp_{activation}.onnx"
    checkpoint = run_dir / "checkpoints" / "best.ckpt"
    start = time.perf_counter()
    report = onnx_export.export_checkpoint(checkpoint, model)
    export_s = time.perf_counter() - start
    return {
        "activation": activation,
        "path": str(model),
        "checkpoint": str(checkpoint),
        "epochs": settings.epochs,
        "train_command_s": train_s,
        "val_rel_rmse_glossy_median": metrics.get("fit/val/rel_rmse_glossy_median"),
        "export_s": export_s,
        "export_max_rel_error": report.max_rel_error,
    }


# --------------------------------------------------------------------------- renders


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



def bench_renders(models: dict[str, Path], variant: str, settings: Settings) -> dict:
    """First-call and median render times of :data:`RENDER_CONFIGS` in ``variant``.

    One scene is alive at a time: in symbolic mode Dr.Jit traces every registered BSDF
    instance into a virtual call, so a scene left loaded would both slow the next one's kernel
    and, with the onnxruntime backend, break its symbolic render.  The timed renders go
    round-robin over the configurations (each scene reloaded, its kernels served from Dr.Jit's
    cache), so load from other processes hits every configuration alike.
    """
    preview.set_variant(variant)
    # Same pass split for every configuration: the wavefront budget (the smallest).
    spp_per_pass = preview.default_spp_per_pass(settings.resolution, wavefront=True)
    paths = settings.resolution * settings.resolution * settings.spp
    materials = {
        name: preview.Material(reference_bsdf="roughconductor")
        if model is None
        else preview.Material(model=models[model], backend=backend)
        for name, model, backend, _ in RENDER_CONFIGS
    }
    results = {name: {"wavefront": wavefront, "times_s": []} for name, _, _, wavefront in RENDER_CONFIGS}

    def load_and_render(name: str, seeds: list[int]) -> tuple[float, list[float]]:
        """``(load_s, render_s per seed)``; the scene is dropped before returning."""
        start = time.perf_counter()
        scene = preview.load_scene(materials[name], settings.resolution)
        load_s = time.perf_counter() - start
        rules = [rule for shape in scene.shapes() if (rule := getattr(shape.bsdf(), "rgb_rule", None))]
        if rules:  # a spectral model in an RGB variant: how many wavelengths it costs
            results[name]["rgb_rule"] = {
                "wavelengths_nm": list(rules[0].wavelengths_nm),
                "rms_relative_error": rules[0].rms_relative_error,
                "max_relative_error": rules[0].max_relative_error,
            }
        times = []
        for seed in seeds:
            start = time.perf_counter()
            image = preview.render_passes(scene, settings.spp, spp_per_pass, seed, results[name]["wavefront"])
            times.append(time.perf_counter() - start)
            if not np.all(np.isfinite(image)):
                raise RuntimeError(f"{variant} {name}: the render is not finite")
        del scene
        gc.collect()
        return load_s, times

    repeat_seeds = [SEED + 1 + repeat for repeat in range(settings.repeats)]
    for name in results:
        seeds = [SEED] if settings.round_robin else [SEED, *repeat_seeds]
        results[name]["scene_load_s"], times = load_and_render(name, seeds)
        results[name]["first_call_s"], results[name]["times_s"] = times[0], times[1:]
    for seed in repeat_seeds if settings.round_robin else []:
        for name in results:
            results[name]["times_s"].extend(load_and_render(name, [seed])[1])
    for entry in results.values():
        entry["median_s"] = statistics.median(entry["times_s"])
        entry["ns_per_path_sample"] = entry["median_s"] / paths * 1e9
    ratios = {key: results[a]["median_s"] / results[b]["median_s"] for key, (a, b) in RATIOS.items()}
    return {"configs": results, "ratios": ratios, "spp_per_pass": spp_per_pass}


# --------------------------------------------------------------------------- throughput


def nlb_module() -> tuple[torch.nn.Module, str]:
    """The compact NLB with one latent: the shipped pretrained network, else untrained weights."""
    if PRETRAINED_NLB.is_file():
        from neuralbrdf.lightning.nlb_module import load_pretrained

        pretrained = load_pretrained(PRETRAINED_NLB)
        return NlbWithLatent(pretrained.network, pretrained.latent_mean), "pretrained compact network"
    torch.manual_seed(SEED)
    network = NlbNetwork()
    with torch.no_grad():  # random everywhere: a zero layer would let Dr.Jit drop the network
        for parameter in network.parameters():
            parameter.copy_(torch.randn_like(parameter) * 0.2)
    latent = torch.randn(network.latent_dim)
    return NlbWithLatent(network, latent), "random weights of the compact size (speed only)"


def _nlb_exportable(module: torch.nn.Module):
    """The NLB built here (not from a checkpoint) in the exporter's form."""
    metadata = contract_metadata("nlb", "benchmark", "benchmarks/run.py")
    return onnx_export.Exportable(module.eval(), "nlb", "benchmark", metadata, None)


# --------------------------------------------------------------------------- report


def _table(results: dict) -> str:
    lines = []
    lines.append(
        f"machine: {results['machine']['cpu']}, {results['machine']['cores']} cores; "
        f"scene {results['settings']['resolution']}^2 x {results['settings']['spp']} spp, "
        f"median of {results['settings']['repeats']}"
    )
    for key in ("model", "relu_model"):
        model = results[key]
        lines.append(
            f"spectral MLP ({model['activation']}): {model['epochs']} epochs, "
            f"val glossy rel. RMSE {model['val_rel_rmse_glossy_median']:.3g}"
        )
    lines.append("")
    lines.append(f"{'variant':<18}{'configuration':<26}{'first call s':>13}{'median s':>10}{'ns/sample':>11}")
    for variant, entry in results["render"].items():
        for name, r in entry["configs"].items():
            rule = r.get("rgb_rule")
            lines.append(
                f"{variant:<18}{name:<26}{r['first_call_s']:>13.2f}{r['median_s']:>10.3f}"
                f"{r['ns_per_path_sample']:>11.0f}"
                + (f"  (sRGB from {len(rule['wavelengths_nm'])} of 31 wavelengths)" if rule else "")
            )
        for key, value in entry["ratios"].items():
            target = TARGETS.get(f"{variant}/{key}", "")
            lines.append(f"{'':<18}{key:<44}{value:>8.2f}x  {('target ' + target) if target else ''}")
    lines.append("")
    lines.append(f"{'model':<20}{'backend':<14}{'first call s':>13}{'median s':>10}{'M queries/s':>13}")
    for name, entry in results["throughput"].items():
        for backend, r in entry["backends"].items():
            lines.append(
                f"{name:<20}{backend:<14}{r['first_call_s']:>13.3f}{r['median_s']:>10.4f}"
                f"{r['queries_per_s'] / 1e6:>13.1f}"
            )
    targets = ", ".join(f"{key.split('/')[0]} {value}" for key, value in TARGETS.items() if "queries" in key)
    lines.append(f"(batch {results['settings']['batch']}; targets, fastest backend: {targets})")
    return "\n".join(lines)


def run(quick: bool, out: Path) -> dict:
    settings = Settings.for_mode(quick)
    started = time.perf_counter()
    results = {
        "command": "python benchmarks/run.py" + (" --quick" if quick else ""),
        "quick": quick,
        "seed": SEED,
        "machine": machine(),
        "settings": settings.__dict__,
        "targets": TARGETS,
    }
    with tempfile.TemporaryDirectory(prefix="neuralbrdf-bench-") as tmp:
        workdir = Path(tmp)
        results["model"] = train_and_export(settings, workdir)
        results["relu_model"] = train_and_export(settings, workdir, activation="relu")
        render_models = {
            "trained": Path(results["model"]["path"]),
            "flat": write_flat_model(workdir / "flat.onnx"),
            "relu": Path(results["relu_model"]["path"]),
        }
        results["render"] = {variant: bench_renders(render_models, variant, settings) for variant in VARIANTS}

        spectral = kinds.load_exportable(results["model"]["checkpoint"])
        spectral_relu = kinds.load_exportable(results["relu_model"]["checkpoint"])
        nlb, nlb_note = nlb_module()
        models = {
            "spectral_mlp": (spectral, "trained above"),
            "spectral_mlp_relu": (spectral_relu, "ReLU ablation, trained above"),
            "nlb_compact": (_nlb_exportable(nlb), nlb_note),
            "abc": (abc_kind.exportable(ABC_BENCH_PARAMETERS, "benchmark", "benchmarks/run.py"),
                    "analytic, fixed parameters"),
        }
        results["throughput"] = {}
        for name, (exportable, note) in models.items():
            proto = onnx_export.trace(exportable)
            backends = bench_throughput(proto, exportable.is_spectral, settings.batch, settings.repeats, exportable.module)
            fastest = max(backends, key=lambda b: backends[b]["queries_per_s"])
            results["throughput"][name] = {"note": note, "backends": backends, "fastest": fastest}
    results["peak_rss_mb"] = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
    results["wall_time_s"] = time.perf_counter() - started
    with atomic_write(out) as handle:
        json.dump(results, handle, indent=2)
        handle.write("\n")
    return results


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="benchmarks/run.py", description=__doc__.split("\n\n")[0])
    parser.add_argument("--quick", action="store_true", help="tiny scene, 2 epochs, small batch (smoke test)")
    parser.add_argument("--out", default=str(ROOT / "benchmarks" / "results.json"), help="JSON results file")
    args = parser.parse_args(argv)
    results = run(args.quick, Path(args.out))
    print(_table(results))
    print(f"\nwrote {args.out} ({results['wall_time_s']:.0f} s)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
