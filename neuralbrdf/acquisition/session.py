"""``neuralbrdf acquire``: a simulated measuring session against a truth, and its curve of error against the number of pairs (docs/how-many-measurements.md).

A session starts from a plan (by default the shipped design for 6 pairs), then repeats: measure
the material at the new pairs (:meth:`~neuralbrdf.acquisition.truths.TruthMaterial.measure`: the
virtual instrument's noise), fit everything measured so far and ask what to measure next
(:func:`~neuralbrdf.acquisition.next_pairs.next_pairs`), until the estimate says a target
ΔE2000 is met (its interval's upper end within it) or the budget of pairs is spent.  At every
step it records what a user would see — the estimated hemisphere log-cos RMSE and preview
ΔE2000 with their intervals — beside what only a simulation knows, the true errors: the fit
exported and scored against the truth (:func:`neuralbrdf.evaluation.evaluate.evaluate`, the
hemisphere metric and the preview scene rendered with the truth at matched seeds).
"""

from __future__ import annotations

import json
import os
import tempfile
from dataclasses import asdict, dataclass, field
from pathlib import Path

import numpy as np

from neuralbrdf.acquisition.instrument import Instrument
from neuralbrdf.acquisition.next_pairs import EstimateSettings, next_pairs
from neuralbrdf.acquisition.truths import TruthMaterial
from neuralbrdf.data.plans import Plan, in_plane_plan, plan_label, write_plan
from neuralbrdf.data.table import BrdfTable
from neuralbrdf.errors import InputError


@dataclass(frozen=True)
class SessionSettings:
    """How a simulated session runs (``configs/acquisition/default.yaml``, section ``session``)."""

    start: str                 # the plan measured first: a name or a plan file (configs/... for shipped ones)
    count: int                 # pairs asked for at each step
    max_pairs: int             # the budget: no step goes beyond it
    noise: float               # relative noise of the virtual instrument
    resolution: int            # preview renders of the true ΔE2000 (pixels a side)
    spp: int                   # their samples per pixel
    seed: int                  # noise and render seed


@dataclass
class Step:
    """One step of a session: the pairs measured so far, the estimates, the true errors, and the
    pairs asked for next (none at the last step)."""

    pairs: int
    estimated_logcos: dict
    estimated_delta_e: dict
    true_logcos: float
    true_delta_e: float | None
    next_pairs: list[list[float]] = field(default_factory=list)
    enough: bool | None = None


@dataclass(frozen=True)
class SessionResult:
    """A session's steps, why it ended, the pairs measured in order and the last measurement and fit."""

    source: str
    steps: list[Step]
    stopped: str
    theta_i: np.ndarray
    theta_r: np.ndarray
    table: BrdfTable
    fitted: object

    def to_dict(self) -> dict:
        return {"source": self.source, "stopped": self.stopped, "steps": [asdict(s) for s in self.steps],
                "pairs": [[float(a), float(b)] for a, b in zip(self.theta_i, self.theta_r)]}


def _interval(interval) -> dict:
    return {"estimate": interval.estimate, "low": interval.low, "high": interval.high}


def _measure(material: TruthMaterial, theta_i, theta_r, noise: float, seed: int) -> BrdfTable:
    return material.measure(Plan.of_pairs(theta_i, theta_r, "session"), noise, seed)


def _joined(first: BrdfTable, second: BrdfTable) -> BrdfTable:
    return BrdfTable(*(np.concatenate([getattr(first, a), getattr(second, a)]) for a in
                       ("theta_i", "phi_i", "theta_o", "phi_o", "values")), first.wavelengths, source=first.source)


def true_errors(material: TruthMaterial, fitted, settings: SessionSettings, work: Path, renders: dict | None) -> tuple[float, float | None]:
    """The fit's hemisphere log-cos RMSE and, with ``renders`` (a cache of the truth's renders),
    its preview ΔE2000 mean against the truth (module docstring)."""
    from neuralbrdf.evaluation.evaluate import RenderSettings, evaluate, measurement_variant
    from neuralbrdf.evaluation.truth import export_truth
    from neuralbrdf.kinds.nlb_spectral import exportable
    from neuralbrdf.onnx_export import write_model

    # a new file each call: the files this command read (the last step's model) may not be overwritten
    handle, name = tempfile.mkstemp(prefix="model_", suffix=".onnx", dir=work)
    os.close(handle)
    model = Path(name)
    write_model(exportable(fitted.model(), fitted.name, "acquire: spectral NLB fit of a simulated session"), model)
    truth = Path(material.source) if Path(material.source).suffix == ".bsdf" else work / "truth.onnx"
    if not truth.is_file():
        export_truth(material.source, truth)
    variant = measurement_variant(truth, None)
    if fitted.node_wavelengths_nm is None and variant.endswith("spectral"):
        variant = "llvm_ad_rgb"
    result = evaluate(model, truth, work / "evaluation", RenderSettings(variant, settings.spp, settings.resolution,
                                                                          settings.seed),
                      render_images=renders is not None, truth_renders=renders)
    for name in ("evaluation.json", "model.png", "truth.png", "error_map.png", "comparison.png"):
        (work / "evaluation" / name).unlink(missing_ok=True)
    return result["hemisphere_logcos_rmse"], result.get("image_delta_e2000_mean") if renders is not None else None


def run_session(source: str, settings: SessionSettings, instrument: Instrument, design, estimate: EstimateSettings,
                target_delta_e: float | None = None, render: bool = True, progress=None) -> SessionResult:
    """Run a simulated session on ``source`` (module docstring); ``progress(step)`` after each step."""
    from neuralbrdf.acquisition.latent_fit import fit_module

    material = TruthMaterial(source)
    theta_i, theta_r = in_plane_plan(settings.start)
    if len(theta_i) > settings.max_pairs:
        raise InputError(f"the start plan {plan_label(settings.start)} holds {len(theta_i)} pairs, more than the budget "
                         f"of {settings.max_pairs}", key="--max")
    if target_delta_e is not None and not target_delta_e > 0:
        raise InputError(f"expected a positive ΔE2000, got {target_delta_e!r}", key="--target-de")
    module = fit_module()
    table = _measure(material, theta_i, theta_r, settings.noise, settings.seed)
    steps: list[Step] = []
    renders: dict | None = {} if render else None
    with tempfile.TemporaryDirectory(prefix="neuralbrdf-acquire-") as folder:
        while True:
            room = settings.max_pairs - len(theta_i)
            count = max(1, min(settings.count, room))
            answer = next_pairs(table, count, instrument, design, estimate, module=module, name=material.name)
            logcos, delta_e = true_errors(material, answer.fitted, settings, Path(folder), renders)
            enough = answer.enough(target_delta_e)
            step = Step(len(theta_i), _interval(answer.logcos), _interval(answer.delta_e), logcos, delta_e,
                        enough=enough)
            steps.append(step)
            if progress is not None:
                progress(step)
            if enough:
                stopped = f"the estimated ΔE2000 is within {target_delta_e:g} (interval {answer.delta_e.low:.2g}-" \
                          f"{answer.delta_e.high:.2g})"
                break
            if room <= 0:
                stopped = f"the budget of {settings.max_pairs} pairs is spent"
                break
            step.next_pairs = [[float(a), float(b)] for a, b in zip(answer.theta_i, answer.theta_r)]
            new = _measure(material, answer.theta_i, answer.theta_r, settings.noise, settings.seed + 2 * len(steps))
            table = _joined(table, new)
            theta_i = np.concatenate([theta_i, answer.theta_i])
            theta_r = np.concatenate([theta_r, answer.theta_r])
    return SessionResult(source, steps, stopped, theta_i, theta_r, table, answer.fitted)


#: The files :func:`write_session` writes into its folder.
SESSION_FILES = ("acquire.json", "acquire.png", "plan.csv", "measurement.csv", "model.onnx")


def check_session_outputs(out_dir: Path, overwrite: bool) -> None:
    """:class:`InputError` before any work where ``out_dir`` holds a session's outputs (unless
    ``overwrite``) or an output may not be written there (:func:`~neuralbrdf.atomic.check_outputs`)."""
    from neuralbrdf.atomic import check_outputs

    paths = [out_dir / name for name in SESSION_FILES]
    existing = [p.name for p in paths if p.exists() or p.is_symlink()]
    if existing and not overwrite:
        raise InputError(f"already holds a session's outputs ({', '.join(existing)}); pass --overwrite to replace "
                         "them, or choose another --out-dir", path=out_dir)
    check_outputs(*paths)


def write_session(result: SessionResult, out_dir: Path) -> list[Path]:
    """``acquire.json``, ``acquire.png`` (the curve), ``plan.csv`` (the pairs in the order measured),
    ``measurement.csv`` (the last table) and ``model.onnx`` (the last fit) into ``out_dir``."""
    from neuralbrdf.atomic import atomic_write
    from neuralbrdf.data.table import write_table
    from neuralbrdf.kinds.nlb_spectral import exportable
    from neuralbrdf.onnx_export import write_model

    out_dir.mkdir(parents=True, exist_ok=True)
    paths = [out_dir / name for name in SESSION_FILES]
    with atomic_write(paths[0]) as handle:
        handle.write(json.dumps(result.to_dict(), indent=2) + "\n")
    plot_session(result, paths[1])
    write_plan((result.theta_i, result.theta_r), paths[2])
    write_table(result.table, paths[3])
    write_model(exportable(result.fitted.model(), result.fitted.name,
                           f"acquire {result.source}: spectral NLB fit of {len(result.theta_i)} pairs"), paths[4])
    return paths


def plot_session(result: SessionResult, path: Path) -> None:
    """The curve: estimated (with its interval) and true errors against the pairs measured."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from neuralbrdf.atomic import atomic_path

    pairs = [s.pairs for s in result.steps]
    panels = [("hemisphere log-cos RMSE", "estimated_logcos", "true_logcos")]
    if any(s.true_delta_e is not None for s in result.steps):
        panels.append(("preview ΔE2000 mean", "estimated_delta_e", "true_delta_e"))
    figure, axes = plt.subplots(1, len(panels), figsize=(5.2 * len(panels), 3.8), squeeze=False)
    for axis, (title, estimated, true) in zip(axes[0], panels):
        est = [getattr(s, estimated) for s in result.steps]
        axis.fill_between(pairs, [e["low"] for e in est], [e["high"] for e in est], color="tab:blue", alpha=0.2,
                          label="estimate, interval")
        axis.plot(pairs, [e["estimate"] for e in est], "o-", color="tab:blue", label="estimate")
        axis.plot(pairs, [getattr(s, true) for s in result.steps], "s-", color="black", label="true")
        axis.set_xlabel("pairs measured")
        axis.set_ylabel(title)
        axis.set_yscale("log")
        axis.grid(True, which="both", alpha=0.3)
        axis.legend(fontsize=8)
    figure.suptitle(f"acquire {Path(result.source).name}: {result.stopped}", fontsize=9)
    figure.tight_layout()
    with atomic_path(path) as tmp:
        figure.savefig(tmp, format="png", dpi=110)
    plt.close(figure)
