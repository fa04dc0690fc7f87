"""What a model costs, measured as ratios in one process (docs/evaluate.md#metrics, Speed; shared by the study
and ``benchmarks/run.py``).

* :func:`render_ratio` — median render time of the model in the material-preview scene
  (:mod:`neuralbrdf.render.preview`) divided by that of Mitsuba's ``roughconductor`` rendered in
  the same process, variant, resolution, sample count and pass split, the timed renders taken
  round-robin so that load from other processes hits both alike;
* :func:`bench_throughput` — queries per second of an ``.onnx`` model through onnxruntime and
  Dr.Jit (:class:`~neuralbrdf.render.drjit_onnx.DrJitGraph`) and, given the torch module, PyTorch;
  warm-up call timed apart, then the median of ``repeats`` calls; optionally the Dr.Jit kernel's
  own run time (:func:`drjit_kernel_seconds`);
* :func:`drjit_operation_count` — the operations of the Dr.Jit kernel that evaluates a graph: a
  cost counted, not timed;
* :func:`parameter_count` — float weights stored in the ``.onnx`` file and the fitted scalars its
  kind keeps as constants (:attr:`neuralbrdf.kinds.Kind.scalar_parameters`; for an ``auto`` file
  the kind of the graph it holds, :func:`graph_kind`): what the file holds, not what its fit
  chose — a ``table`` or ``pca`` file counts its table's entries (``n_h · n_d · n_p`` per channel
  or band: 27 648 for RGB, 285 696 for 31 bands on the PCA basis's 48 × 24 × 8 nodes), not the
  ``K`` coefficients per channel a PCA fit solved for (``metrics.json``'s ``fit/pca/coefficients``),
  as an NLB file counts its pretrained decoder's weights beside its fitted latent;
* :func:`machine` — CPU, cores, versions and thread counts, recorded beside every figure.
"""

from __future__ import annotations

import gc
import os
import platform
import statistics
import time
from pathlib import Path

import numpy as np

SEED = 0
#: Largest query batch of :func:`bench_throughput` (a spectral batch holds 7 float32 per query:
#: ~470 MB at this size, times the backends' own buffers).
MAX_BATCH = 2**24


def timed(fn) -> float:
    """Wall time of ``fn()`` in seconds."""
    start = time.perf_counter()
    fn()
    return time.perf_counter() - start


def first_and_median(fn, repeats: int) -> dict:
    """``first_call_s`` (warm-up) then ``times_s`` and ``median_s`` of ``repeats`` calls."""
    first = timed(fn)
    values = [timed(fn) for _ in range(repeats)]
    return {"first_call_s": first, "times_s": values, "median_s": statistics.median(values)}


def machine() -> dict:
    """The machine and library versions a measurement was taken with."""
    import drjit as dr
    import mitsuba as mi
    import onnx
    import onnxruntime
    import torch

    cpu = platform.processor() or "unknown"
    cpuinfo = Path("/proc/cpuinfo")
    if cpuinfo.is_file():
        for line in cpuinfo.read_text().splitlines():
            if line.startswith("model name"):
                cpu = line.split(":", 1)[1].strip()
                break
    return {
        "cpu": cpu,
        "cores": os.cpu_count(),
        "platform": platform.platform(),
        "python": platform.python_version(),
        "versions": {
            "torch": torch.__version__,
            "onnxruntime": onnxruntime.__version__,
            "onnx": onnx.__version__,
            "mitsuba": mi.__version__,
            "drjit": dr.__version__,
        },
        "threads": {"torch": torch.get_num_threads(), "drjit": dr.thread_count()},
    }


def probe_inputs(batch: int, spectral: bool, seed: int = SEED) -> dict[str, np.ndarray]:
    """``batch`` random upper-hemisphere direction pairs (and wavelengths in 400–700 nm)."""
    rng = np.random.default_rng(seed)

    def hemisphere():
        v = rng.normal(size=(batch, 3))
        v[:, 2] = np.abs(v[:, 2])
        return (v / np.linalg.norm(v, axis=1, keepdims=True)).astype(np.float32)

    feeds = {"wi": hemisphere(), "wo": hemisphere()}
    if spectral:
        feeds["wavelength"] = rng.uniform(400.0, 700.0, batch).astype(np.float32)
    return feeds


def drjit_inputs(feeds: dict[str, np.ndarray], spectral: bool) -> tuple:
    """``(wi, wo, wavelength)`` of :func:`probe_inputs` as evaluated ``drjit.llvm`` columns, the
    arguments of a :class:`~neuralbrdf.render.drjit_onnx.DrJitGraph` (``wavelength`` ``None`` for RGB)."""
    import drjit as dr
    from drjit.llvm import Float

    wi = [Float(feeds["wi"][:, k]) for k in range(3)]
    wo = [Float(feeds["wo"][:, k]) for k in range(3)]
    wavelength = Float(feeds["wavelength"]) if spectral else None
    dr.eval(*wi, *wo, *([wavelength] if spectral else []))
    return wi, wo, wavelength


def drjit_evaluate(graph, inputs: tuple) -> None:
    """Evaluate ``graph`` on ``inputs`` (:func:`drjit_inputs`) to completion: the timed unit."""
    import drjit as dr

    dr.eval(*[c for c in graph(*inputs) if not isinstance(c, float)])
    dr.sync_thread()


def _jit_kernels(graph, inputs: tuple) -> list[dict]:
    """Dr.Jit's kernel history entries of the JIT kernels of one evaluation of ``graph``
    (:func:`drjit_evaluate`)."""
    import drjit as dr

    saved = dr.flag(dr.JitFlag.KernelHistory)
    dr.set_flag(dr.JitFlag.KernelHistory, True)
    dr.kernel_history()  # drops what earlier launches left
    try:
        drjit_evaluate(graph, inputs)
        history = dr.kernel_history()
    finally:
        dr.set_flag(dr.JitFlag.KernelHistory, saved)
    return [entry for entry in history if entry["type"] == dr.KernelType.JIT]


def drjit_kernel_seconds(graph, inputs: tuple) -> float:
    """Seconds the Dr.Jit kernels of one evaluation of ``graph`` (:func:`drjit_evaluate`) ran, from
    Dr.Jit's kernel history: the fused kernel alone, its tracing and compilation excluded."""
    return sum(entry["execution_time"] for entry in _jit_kernels(graph, inputs)) / 1e3


def drjit_operation_count(graph, inputs: tuple) -> int:
    """Operations of the Dr.Jit kernels of one evaluation of ``graph`` (their IR, from Dr.Jit's
    kernel history): what every query of a render runs, counted rather than timed, so the same on
    every run and machine (for one Dr.Jit version)."""
    return sum(int(entry["operation_count"]) for entry in _jit_kernels(graph, inputs))


def bench_throughput(proto, spectral: bool, batch: int, repeats: int, module=None, kernel_time: bool = False) -> dict:
    """Queries per second of one model (``onnx.ModelProto``) through onnxruntime and Dr.Jit, and
    through PyTorch when ``module`` (the same model as a torch module) is given; with
    ``kernel_time``, also ``drjit_kernel``: the Dr.Jit kernel's own run time
    (:func:`drjit_kernel_seconds`, tracing excluded)."""
    import onnxruntime

    from neuralbrdf.render.drjit_onnx import DrJitGraph

    feeds = probe_inputs(batch, spectral)
    names = ["wi", "wo", "wavelength"] if spectral else ["wi", "wo"]
    repeats = max(repeats, 3)
    results = {}
    if module is not None:
        import torch

        tensors = [torch.from_numpy(feeds[n]) for n in names]

        def torch_call():
            with torch.inference_mode():
                module(*tensors)

        results["pytorch"] = first_and_median(torch_call, repeats)

    session = None

    def make_session():
        nonlocal session
        session = onnxruntime.InferenceSession(proto.SerializeToString(), providers=["CPUExecutionProvider"])

    session_s = timed(make_session)
    results["onnxruntime"] = {
        "session_s": session_s,
        **first_and_median(lambda: session.run(["f"], {n: feeds[n] for n in names}), repeats),
    }

    graph = None

    def make_graph():
        nonlocal graph
        graph = DrJitGraph(proto)

    graph_s = timed(make_graph)
    inputs = drjit_inputs(feeds, spectral)
    results["drjit"] = {"graph_build_s": graph_s, "multiply_adds": graph.multiply_adds,
                        **first_and_median(lambda: drjit_evaluate(graph, inputs), repeats)}
    if kernel_time:
        kernels = [drjit_kernel_seconds(graph, inputs) for _ in range(repeats)]
        results["drjit_kernel"] = {"times_s": kernels, "median_s": statistics.median(kernels)}
    for entry in results.values():
        entry["queries_per_s"] = batch / entry["median_s"]
    return results


def graph_kind(model) -> str:
    """The kind whose graph the loaded model file ``model`` holds: its own kind, or for an ``auto``
    file the candidate it chose (``abc`` or ``nlb_spectral``; its graph is that kind's, constants
    included).  A ``pca`` file is its own kind: a baked table of the mapped values (one float
    initializer; under the shipped basis's ``ln(1 + f)`` mapping no fitted scalar is held as a
    constant), read as the ``table`` kind's is."""
    from neuralbrdf.kinds import auto

    return model.details.choice if model.kind == auto.NAME else model.kind


def parameter_count(proto, kind: str | None = None) -> int:
    """Floating-point values stored as initializers (weights, baked latent, tables: a ``table`` or
    ``pca`` file's entries, not a PCA fit's coefficients), plus the scalar parameters of ``kind``
    (registered in :mod:`neuralbrdf.kinds`) held as constants."""
    import onnx
    from onnx import numpy_helper

    from neuralbrdf import kinds

    floats = (onnx.TensorProto.FLOAT, onnx.TensorProto.DOUBLE, onnx.TensorProto.FLOAT16)
    stored = int(sum(numpy_helper.to_array(t).size for t in proto.graph.initializer if t.data_type in floats))
    return stored + (kinds.get(kind).scalar_parameters if kind is not None else 0)


def render_ratio(model: Path, variant: str, resolution: int, spp: int, repeats: int) -> dict:
    """Median render time of ``model`` ÷ that of ``roughconductor``, same process and settings
    (module docstring); both medians, the first (compiling) calls and the ratio."""
    from neuralbrdf.render import preview

    preview.set_variant(variant)
    spp_per_pass = preview.default_spp_per_pass(resolution, wavefront=False)
    materials = {"model": preview.Material(model=Path(model), backend="drjit"),
                 "roughconductor": preview.Material(reference_bsdf="roughconductor")}
    times: dict[str, list[float]] = {name: [] for name in materials}
    first: dict[str, float] = {}

    def render_once(name: str, seed: int) -> float:
        scene = preview.load_scene(materials[name], resolution)
        start = time.perf_counter()
        image = preview.render_passes(scene, spp, spp_per_pass, seed, False)
        elapsed = time.perf_counter() - start
        del scene
        gc.collect()
        if not np.all(np.isfinite(image)):
            raise RuntimeError(f"{variant} {name}: the render is not finite")
        return elapsed

    for name in materials:
        first[name] = render_once(name, SEED)
    for repeat in range(repeats):
        for name in materials:
            times[name].append(render_once(name, SEED + 1 + repeat))
    medians = {name: statistics.median(values) for name, values in times.items()}
    return {
        "variant": variant, "resolution": resolution, "spp": spp, "repeats": repeats,
        "model_median_s": medians["model"], "roughconductor_median_s": medians["roughconductor"],
        "first_call_s": first, "render_ratio": medians["model"] / medians["roughconductor"],
    }
