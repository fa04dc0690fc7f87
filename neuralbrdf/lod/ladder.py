"""A cost ladder of cheaper stand-ins for an exported model (docs/select.md): ``neuralbrdf ladder``.

Every rung is a model file under the same ONNX contract (docs/formats.md#onnx-model-files), so both plugin backends, both
colour variants and the sampler render it unchanged:

* ``full`` — the parent file itself (error 0, the reference cost);
* ``abc`` — the ABC model (Löw et al. 2012, docs/models.md#abc) fitted with
  :func:`~neuralbrdf.fitting.abc_fit.fit_abc` to the parent's own dense samples
  (:func:`~neuralbrdf.lod.distill.abc_table`); kind ``abc``, so it keeps its analytic sampler;
* ``mlp_LxH`` — spectral parents only: smaller spectral MLPs (``L`` hidden layers of ``H`` units)
  distilled from the parent (:func:`~neuralbrdf.lod.distill.distill_spectral_mlp`); kind
  ``spectral_mlp``;
* ``table_HxDxP[xL]`` — every parent: the parent baked into a table over Rusinkiewicz angles (and
  wavelength) read by multilinear interpolation (:func:`~neuralbrdf.lod.bake.bake_table`; kind
  ``table``), at each node count of the settings' ``tables``: a fixed cost of a few dozen
  operations and 8–16 table reads per query, whatever the parent costs (the cheap rung of an NLB);
* ``full_rgbT`` — spectral parents in RGB variants only: the parent file itself with the
  plugin's reduced spectrum → sRGB rule (:mod:`~neuralbrdf.render.spectral_quadrature`) fitted
  to the looser held-out tolerance ``T`` (property ``rgb_tolerance``, default 1e-3): fewer
  network evaluations per RGB query.  Its error is the hemisphere log-cos RMSE of its linear
  sRGB against the exact 31-wavelength integral, its cost the ratio of the rules' wavelength
  counts (the network evaluations per RGB query).  No new file: the ladder records the property.
  Not offered when the parent has an RGB head (fast path ``f_rgb``), which the plugin uses in RGB
  variants instead of any rule;
* for a spectral parent with an RGB head (fast path ``f_rgb``) every stand-in rung applies in
  spectral variants only (ladder.json ``variants``): in RGB variants the parent itself renders
  through its head, at about one small network evaluation per query;
* ``fast`` — a parent with a fast path ``f_fast`` (``neuralbrdf export --fast``,
  :mod:`neuralbrdf.lod.fast_paths`): the parent file itself with the plugin property ``fast``, its
  error and cost measured like a rung file's.  A model file without a ladder folder still offers
  this rung to ``neuralbrdf select`` (:func:`embedded_ladder`, numbers from its metadata: the
  cost there is counted in Dr.Jit operations, not timed, :mod:`neuralbrdf.lod.fast_paths`).

Each rung records in its ``metadata_props`` (keys :data:`RUNG_KEY` …) what it approximates (the
parent's file name and SHA-256), its error against the parent — ``hemisphere_logcos_rmse``
(docs/evaluate.md#metrics, :func:`~neuralbrdf.evaluation.scores.hemisphere_scores`: 102 400 stratified pairs,
spectra compared at 31 wavelengths) — and its measured evaluation cost: Dr.Jit nanoseconds per
query (:class:`~neuralbrdf.render.drjit_onnx.DrJitGraph` on 2^20 and 2^22 random upper-hemisphere
pairs, one wavelength per query for spectral models, the kernel's own run time from Dr.Jit's
kernel history; :func:`drjit_costs`: all rungs and the
parent measured in interleaved rounds in one process, so that machine load hits them alike) and that cost
relative to the parent's.  ``DIR/ladder.json`` lists the rungs with the same numbers.

A rung whose fit fails (an ABC fit that reports failure, a student whose loss is not finite) is
not written; ladder.json lists it under ``failed`` with the cause.  All files of a ladder appear
together or not at all (:func:`neuralbrdf.atomic.atomic_paths`).
"""

from __future__ import annotations

import hashlib
import json
import math
import tempfile
import time
from dataclasses import asdict, dataclass
from pathlib import Path

import onnx

from neuralbrdf.atomic import atomic_paths
from neuralbrdf.errors import InputError
from neuralbrdf.evaluation.scores import HEMISPHERE_STRATA, MemoEvaluator, OnnxEvaluator, hemisphere_scores
from neuralbrdf.fitting.abc_fit import fit_abc
from neuralbrdf.kinds import Exportable, contract_metadata, load_model
from neuralbrdf.kinds import abc as abc_kind
from neuralbrdf.kinds.table import nodes_text
from neuralbrdf.lod.bake import bake_table
from neuralbrdf.lod.distill import ABC_WAVELENGTHS_NM, DistillSettings, abc_table, distill_spectral_mlp, teacher_samples
from neuralbrdf.onnx_contract import OUTPUT_F, OUTPUT_FAST, OUTPUT_RGB
from neuralbrdf.onnx_export import write_model
from neuralbrdf.render.fast_paths import FAST_PROPERTY

LADDER_FILE = "ladder.json"
#: The rung of a parent's own fast path (its ``f_fast`` output, plugin property ``fast``).
FAST_RUNG = "fast"
LADDER_FORMAT = "neuralbrdf.ladder/1"
#: Rung metadata keys (all strings, beside the contract's own keys).
RUNG_KEY = "neuralbrdf.ladder.rung"
PARENT_KEY = "neuralbrdf.ladder.parent"
PARENT_SHA256_KEY = "neuralbrdf.ladder.parent_sha256"
ERROR_KEY = "neuralbrdf.ladder.parent_hemisphere_logcos_rmse"
COST_KEY = "neuralbrdf.ladder.drjit_ns_per_query"
RELATIVE_COST_KEY = "neuralbrdf.ladder.relative_cost"
FULL_RUNG = "full"


@dataclass(frozen=True)
class LadderSettings:
    """What :func:`build_ladder` makes and how it measures (values: ``configs/lod/default.yaml``, section
    ``ladder``; :mod:`neuralbrdf.lod.config`)."""

    #: ``(hidden_layers, hidden)`` of the distilled students (spectral parents).
    students: tuple[tuple[int, int], ...]
    distill: DistillSettings
    abc_pairs: int
    abc_starts: int
    cost_batches: tuple[int, int]
    cost_rounds: int
    #: Node counts ``(θh, θd, φd, λ)`` of the baked-table rungs (``λ`` ignored for RGB parents).
    tables: tuple[tuple[int, int, int, int], ...]
    #: Held-out rms relative errors of the reduced spectrum → sRGB rule offered as RGB-variant rungs.
    rgb_tolerances: tuple[float, ...]
    seed: int
    #: ``(cos θ, φ)`` strata of the hemisphere pairs the errors are measured on: the metric's own
    #: definition (docs/evaluate.md), fewer for quick checks only.
    error_strata: tuple[int, int] = HEMISPHERE_STRATA


def file_sha256(path: Path) -> str:
    return hashlib.sha256(Path(path).read_bytes()).hexdigest()


# --------------------------------------------------------------------------- rungs


def _abc_rung(parent: OnnxEvaluator, settings: LadderSettings, provenance: str) -> Exportable:
    model = parent.model
    table = abc_table(parent, settings.abc_pairs, settings.seed, source=f"samples of {model.path.name}")
    result = fit_abc(table, n_starts=settings.abc_starts, seed=settings.seed)
    if not result.success:
        raise ValueError(f"ABC fit failed: {result.failure_reason}")
    return abc_kind.exportable(result.parameters, model.material, provenance)


def _student_rung(samples, layers: int, hidden: int, parent: OnnxEvaluator, settings: LadderSettings,
                  provenance: str) -> Exportable:
    model = parent.model
    module = distill_spectral_mlp(samples, hidden, layers, model.wavelength_range_nm, settings.distill)
    metadata = contract_metadata("spectral_mlp", model.material, provenance,
                                 wavelength_range_nm=model.wavelength_range_nm)
    return Exportable(module, "spectral_mlp", model.material, metadata, model.wavelength_range_nm)


def _candidates(parent: OnnxEvaluator, settings: LadderSettings):
    """``(name, describes, build)`` of every stand-in rung this parent gets."""
    name = parent.model.path.name
    out = [("abc", f"ABC fit (docs/models.md#abc) to {settings.abc_pairs} x "
                   f"{len(ABC_WAVELENGTHS_NM) if parent.is_spectral else 3} samples of {name}",
            lambda provenance: _abc_rung(parent, settings, provenance))]
    for nodes in settings.tables:
        nodes = nodes if parent.is_spectral else nodes[:3]
        out.append((
            "table_" + "x".join(str(n) for n in nodes),
            f"{name} baked into a {nodes_text(nodes)} table over (θh, θd, φd"
            f"{', λ' if parent.is_spectral else ''}), multilinear interpolation",
            lambda provenance, nodes=nodes: bake_table(parent, nodes, parent.model.material, provenance),
        ))
    if parent.is_spectral:
        samples = []

        def shared_samples():
            if not samples:
                samples.append(teacher_samples(parent, settings.distill.n_pairs, settings.seed,
                                               parent.model.wavelength_range_nm))
            return samples[0]

        for layers, hidden in settings.students:
            out.append((
                f"mlp_{layers}x{hidden}",
                f"spectral MLP {layers}x{hidden} distilled from {settings.distill.n_pairs} samples of {name}",
                lambda provenance, layers=layers, hidden=hidden: _student_rung(
                    shared_samples(), layers, hidden, parent, settings, provenance),
            ))
    return out


# --------------------------------------------------------------------------- measurement


def drjit_costs(protos: dict[str, onnx.ModelProto], spectral: bool, batches: tuple[int, int], rounds: int) -> dict[str, float]:
    """Dr.Jit nanoseconds per query of each graph inside a kernel: the slope
    ``(t(large) − t(small)) / (large − small)`` of the shortest kernel run times of two batch sizes
    (Dr.Jit's kernel history, :func:`neuralbrdf.study.cost.drjit_kernel_seconds`: the kernel alone,
    without the tracing and interpretation of the graph in Python, which a render pays once per
    kernel, not per sample; the shortest: other processes only ever add time on a shared machine;
    the slope: a launch's fixed cost cancels).  Rounds are interleaved over the graphs and batch
    sizes, one warm-up call each first, on random upper-hemisphere pairs
    (:func:`neuralbrdf.study.cost.probe_inputs`)."""
    from neuralbrdf.render.drjit_onnx import DrJitGraph
    from neuralbrdf.study.cost import drjit_evaluate, drjit_inputs, drjit_kernel_seconds, probe_inputs

    inputs = {batch: drjit_inputs(probe_inputs(batch, spectral), spectral) for batch in batches}
    graphs = {name: DrJitGraph(proto) for name, proto in protos.items()}
    times = {(name, batch): [] for name in graphs for batch in batches}
    for name, graph in graphs.items():
        for batch in batches:
            drjit_evaluate(graph, inputs[batch])
    for _ in range(rounds):
        for name, graph in graphs.items():
            for batch in batches:
                times[name, batch].append(drjit_kernel_seconds(graph, inputs[batch]))
    small, large = batches
    return {name: max(1e9 * (min(times[name, large]) - min(times[name, small])) / (large - small), 1e-3)
            for name in graphs}


def parent_error(rung: Path, parent, strata: tuple[int, int] = HEMISPHERE_STRATA, output: str = OUTPUT_F) -> float:
    """``hemisphere_logcos_rmse`` of the model file ``rung`` (its ``output``) against the parent
    (module docstring)."""
    return float(hemisphere_scores(OnnxEvaluator(rung, output), parent, strata=strata)["hemisphere_logcos_rmse"])


# --------------------------------------------------------------------------- the ladder


def _with_metadata(path: Path, entries: dict[str, str]) -> bytes:
    proto = onnx.load(str(path))
    metadata = {entry.key: entry.value for entry in proto.metadata_props}
    metadata.update(entries)
    onnx.helper.set_model_props(proto, metadata)
    return proto.SerializeToString()


def build_ladder(model_path: str | Path, out_dir: str | Path, settings: LadderSettings, log=print) -> dict:
    """Make the stand-ins of ``model_path`` in ``out_dir`` and write ``out_dir/ladder.json``
    (module docstring); returns the JSON document."""
    model_path, out_dir = Path(model_path).resolve(), Path(out_dir)
    parent = OnnxEvaluator(model_path)
    reference = MemoEvaluator(parent)  # the parent on the same hemisphere pairs for every rung: once
    sha = file_sha256(model_path)
    rungs, failed, built = [], [], {}
    began = time.perf_counter()
    with tempfile.TemporaryDirectory(prefix="neuralbrdf-ladder-") as work:
        for name, describes, build in _candidates(parent, settings):
            start = time.perf_counter()
            provenance = f"ladder rung {name!r} of {model_path.name} (sha256 {sha[:12]}): {describes}"
            try:
                exportable = build(provenance)
                path = Path(work) / f"{name}.onnx"
                write_model(exportable, path)
            except (ValueError, InputError) as error:
                failed.append({"name": name, "approximates": describes, "cause": str(error)})
                log(f"{name}: failed: {error}")
                continue
            built[name] = (path, describes, time.perf_counter() - start)
            log(f"{name}: built in {built[name][2]:.1f} s")
        errors = {name: parent_error(path, reference, settings.error_strata) for name, (path, _, _) in built.items()}
        protos = {FULL_RUNG: parent.model.proto, **{name: load_model(path).proto for name, (path, _, _) in built.items()}}
        fast = OUTPUT_FAST in parent.file.fast_paths
        # With an RGB head the parent renders at one small evaluation per query in RGB variants,
        # which no spectral stand-in integrated through a rule undercuts: its rungs are for
        # spectral variants only.
        stand_in_variants = "spectral" if OUTPUT_RGB in parent.file.fast_paths else "rgb spectral"
        if fast:  # the parent's own fast path: its f_fast output
            protos[FAST_RUNG] = parent.file.output_view(OUTPUT_FAST).proto
        costs = drjit_costs(protos, parent.is_spectral, settings.cost_batches, settings.cost_rounds)
        if fast:
            start = time.perf_counter()
            error = parent_error(model_path, reference, settings.error_strata, output=OUTPUT_FAST)
            rungs.append(_entry(FAST_RUNG, str(model_path), parent.model.kind,
                                f"{model_path.name}'s own fast path: {parent.file.fast_paths[OUTPUT_FAST].approximates}",
                                error, costs[FAST_RUNG], costs[FAST_RUNG] / costs[FULL_RUNG],
                                time.perf_counter() - start, properties={FAST_PROPERTY: "true"},
                                variants=stand_in_variants))
        rungs.append(_entry(FULL_RUNG, str(model_path), parent.model.kind, "the parent itself", 0.0,
                            costs[FULL_RUNG], 1.0, 0.0))
        payloads = {}
        for name, (path, describes, seconds) in built.items():
            relative = costs[name] / costs[FULL_RUNG]
            payloads[name] = _with_metadata(path, {
                RUNG_KEY: name, PARENT_KEY: model_path.name, PARENT_SHA256_KEY: sha,
                ERROR_KEY: repr(errors[name]), COST_KEY: repr(costs[name]), RELATIVE_COST_KEY: repr(relative),
            })
            rungs.append(_entry(name, f"{name}.onnx", load_model(path).kind, describes, errors[name], costs[name],
                                relative, seconds, variants=stand_in_variants))
        if stand_in_variants != "spectral" and parent.is_spectral:  # an RGB head is cheaper than any rule
            rungs += _rgb_rule_rungs(parent, reference, model_path, costs[FULL_RUNG], settings)
    from neuralbrdf.study.cost import machine

    document = {
        "format": LADDER_FORMAT,
        "parent": {"file": str(model_path), "sha256": sha, "kind": parent.model.kind,
                   "material": parent.model.material, "spectral": parent.is_spectral},
        "error_metric": f"hemisphere_logcos_rmse against the parent (docs/evaluate.md#metrics; {math.prod(settings.error_strata) ** 2} "
                        "stratified pairs, theta <= 80 deg; spectra at 400-700 nm every 10 nm, else linear sRGB)",
        "cost_metric": "Dr.Jit ns per query inside a kernel (slope of the shortest kernel run times of batches of "
                       f"{settings.cost_batches[0]} and {settings.cost_batches[1]} random pairs, one wavelength per "
                       f"query for spectral models, {settings.cost_rounds} interleaved rounds); relative_cost = rung / full",
        "rungs": sorted(rungs, key=lambda r: r["relative_cost"], reverse=True),
        "failed": failed,
        "settings": _settings_dict(settings),
        "wall_time_s": time.perf_counter() - began,
        "machine": machine(),
    }
    targets = [out_dir / f"{name}.onnx" for name in payloads] + [out_dir / LADDER_FILE]
    with atomic_paths(*targets) as temporaries:
        for temporary, payload in zip(temporaries, payloads.values()):
            temporary.write_bytes(payload)
        temporaries[-1].write_text(json.dumps(document, indent=2, allow_nan=False) + "\n")
    return document


def _entry(name, file, kind, approximates, error, cost_ns, relative, build_s, properties=None,
           variants="rgb spectral") -> dict:
    return {"name": name, "file": file, "kind": kind, "approximates": approximates,
            "hemisphere_logcos_rmse": error, "drjit_ns_per_query": cost_ns, "relative_cost": relative,
            "build_time_s": build_s, "bsdf_properties": properties or {}, "variants": variants}


def _rgb_rule_rungs(parent: OnnxEvaluator, reference, model_path: Path, full_cost_ns: float,
                    settings: LadderSettings) -> list[dict]:
    """``full_rgbT`` rungs (module docstring)."""
    from neuralbrdf.render.load_time import fit_rgb_rule
    from neuralbrdf.render.spectral_quadrature import DEFAULT_RMS_TOLERANCE, RuleRgbEvaluator

    default = fit_rgb_rule(parent.model, parent.session, DEFAULT_RMS_TOLERANCE)
    out = []
    for tolerance in settings.rgb_tolerances:
        start = time.perf_counter()
        rule = fit_rgb_rule(parent.model, parent.session, tolerance)
        if rule.size >= default.size:
            continue  # no fewer wavelengths than the default rule: not cheaper
        scores = hemisphere_scores(RuleRgbEvaluator(parent, rule), reference, strata=settings.error_strata)
        error = float(scores["hemisphere_logcos_rmse"])
        relative = rule.size / default.size
        out.append(_entry(
            f"full_rgb{tolerance:g}", str(model_path), parent.model.kind,
            f"{model_path.name} in RGB variants with its sRGB rule at held-out rms {tolerance:g} ({rule.size} "
            f"wavelengths, {default.size} at the default {DEFAULT_RMS_TOLERANCE:g})",
            error, full_cost_ns * relative, relative, time.perf_counter() - start,
            properties={"rgb_tolerance": repr(float(tolerance))}, variants="rgb",
        ))
    return out


def _settings_dict(settings: LadderSettings) -> dict:
    document = asdict(settings)
    document["students"] = [list(s) for s in settings.students]
    return document


# --------------------------------------------------------------------------- reading


@dataclass(frozen=True)
class Rung:
    """One rung of a read ladder: its file (absolute), cost and error against the parent, the
    plugin properties it needs and the colour variants it applies in (``rgb``, ``spectral``)."""

    name: str
    path: Path
    kind: str
    relative_cost: float
    hemisphere_logcos_rmse: float
    properties: tuple[tuple[str, str], ...] = ()
    variants: tuple[str, ...] = ("rgb", "spectral")

    def applies_in(self, rgb_variant: bool) -> bool:
        return ("rgb" if rgb_variant else "spectral") in self.variants


@dataclass(frozen=True)
class Ladder:
    parent: Path
    parent_sha256: str
    rungs: tuple[Rung, ...]  # the full model first, then by decreasing cost


def read_ladder(folder: str | Path) -> Ladder:
    """``folder/ladder.json`` (as :func:`build_ladder` writes it), checked; rung files resolved
    against ``folder``."""
    folder = Path(folder)
    path = folder / LADDER_FILE
    if not path.is_file():
        raise InputError("no ladder.json here (make one with 'neuralbrdf ladder MODEL.onnx --out-dir DIR')", path=folder)
    try:
        document = json.loads(path.read_text())
    except (json.JSONDecodeError, UnicodeDecodeError) as error:
        raise InputError(f"not JSON: {error}", path=path) from None
    if not isinstance(document, dict) or document.get("format") != LADDER_FORMAT:
        raise InputError(f"not a ladder file (format must be {LADDER_FORMAT!r})", path=path, key="format")
    try:
        parent = document["parent"]
        rungs = []
        for entry in document["rungs"]:
            file = Path(entry["file"])
            properties = entry.get("bsdf_properties", {})
            if not isinstance(properties, dict):
                raise TypeError("bsdf_properties must be a mapping")
            rungs.append(Rung(str(entry["name"]), file if file.is_absolute() else folder.resolve() / file,
                              str(entry["kind"]), float(entry["relative_cost"]),
                              float(entry["hemisphere_logcos_rmse"]),
                              tuple((str(k), str(v)) for k, v in properties.items()),
                              tuple(str(entry.get("variants", "rgb spectral")).split())))
        ladder = Ladder(Path(parent["file"]), str(parent["sha256"]),
                        tuple(sorted(rungs, key=lambda r: (r.name != FULL_RUNG, -r.relative_cost))))
    except (KeyError, TypeError, ValueError) as error:
        raise InputError(f"malformed ladder entry ({type(error).__name__}: {error})", path=path) from None
    if not ladder.rungs or ladder.rungs[0].name != FULL_RUNG:
        raise InputError("a ladder lists its full model as rung 'full'", path=path, key="rungs")
    return ladder


def embedded_ladder(model_path: str | Path) -> Ladder | None:
    """The ladder of a model file without a ladder folder whose file has a fast path ``f_fast``:
    the full model and that fast path (plugin property ``fast``), with the error and relative cost
    its metadata records; ``None`` for a file without one."""
    model = load_model(model_path)
    if OUTPUT_FAST not in model.fast_paths:
        return None
    path = Path(model_path).resolve()
    recorded = model.fast_paths[OUTPUT_FAST]
    variants = ("spectral",) if OUTPUT_RGB in model.fast_paths else ("rgb", "spectral")  # as build_ladder's
    return Ladder(path, file_sha256(path), (
        Rung(FULL_RUNG, path, model.kind, 1.0, 0.0),
        Rung(FAST_RUNG, path, model.kind, recorded.relative_cost, recorded.hemisphere_logcos_rmse,
             ((FAST_PROPERTY, "true"),), variants),
    ))
