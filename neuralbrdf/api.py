"""The Python API: read a material, fit a model to it, export, load, evaluate and render.

Every name here is also at the package's top level (``neuralbrdf.read``, ``neuralbrdf.fit``, ...),
imported on first use: ``import neuralbrdf`` loads neither PyTorch nor Mitsuba.  The command line
is a layer over the same functions, so a script and a shell command do the same thing::

    import neuralbrdf as nb

    gold = nb.read("virtual:gold")                        # or a table, GCMS raw + reference, .h5, .binary, .bsdf
    result = nb.fit("spectral_mlp", gold, run_dir="runs/gold")
    model = result.export("gold.onnx")                    # a validated ONNX file (docs/formats.md#onnx-model-files)
    f = model(wi, wo, wavelength)                         # BRDF in sr^-1, as numpy
    truth = nb.truth(gold, "gold_truth.onnx")
    scores = nb.evaluate(model, truth, "gold_eval")       # hemisphere, in-plane and image errors
    image = nb.render_image(model, "gold.png")            # linear RGB [H, W, 3]

Fits run through the same YAML configs and Lightning modules as ``neuralbrdf train`` (the configs
stay the single source of hyper-parameters): :data:`FIT_KINDS` names the config of each kind,
``overrides`` change single values like ``--key value`` on the command line.  Bad input raises
:class:`~neuralbrdf.errors.InputError` (one line naming the file, row or key); a fit that runs
and fails raises :class:`~neuralbrdf.errors.FitFailed`.  Units: angles in degrees, wavelengths
in nm, BRDF values in sr⁻¹ without the cosine factor; directions are unit vectors in the local
frame, ``z`` the normal, both pointing away from the surface (docs/formats.md#conventions).
"""

from __future__ import annotations

import json
import math
import os
import warnings
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

from neuralbrdf.errors import InputError
from neuralbrdf.render import DEFAULT_VARIANT

if TYPE_CHECKING:
    import numpy as np

    from neuralbrdf.data.table import BrdfTable

PathLike = str | os.PathLike[str]

#: Fit kinds and the shipped config each runs (``configs/NAME.yaml``): a new kind is one entry.
FIT_KINDS: dict[str, str] = {
    "abc": "abc",
    "spectral_mlp": "spectral_mlp",
    "nlb": "nlb_latent",
    "nlb_spectral": "nlb_spectral",
}
#: Source kinds with a ground truth everywhere (not only at measured directions).
TRUTH_KINDS = ("nbrdf", "merl", "rgl", "virtual")
VIRTUAL_PREFIX = "virtual:"


def _path(value, name: str, expected: str = "a file path (str or os.PathLike)") -> Path:
    """``value`` as a :class:`~pathlib.Path`, or :class:`InputError` naming the argument ``name``."""
    if isinstance(value, (str, os.PathLike)):
        return Path(value)
    raise InputError(f"{name}: expected {expected}, got {type(value).__name__} {value!r}")


def _text(name: str, value, optional: bool = True) -> None:
    """:class:`InputError` naming the argument ``name`` unless ``value`` is a string (or ``None``)."""
    if not (isinstance(value, str) or (optional and value is None)):
        expected = "a string or None" if optional else "a string"
        raise InputError(f"{name}: expected {expected}, got {type(value).__name__} {value!r}")


def _flags(**values) -> None:
    """:class:`InputError` naming the first of ``values`` that is not a real ``bool`` (``"no"`` and
    ``0`` are not flags: a string would be true)."""
    for name, value in values.items():
        if not isinstance(value, bool):
            raise InputError(f"{name}: expected True or False, got {type(value).__name__} {value!r}")


def _numbers(**values) -> None:
    """:class:`InputError` naming the first of ``values`` that is neither a finite real number nor ``None``."""
    for name, value in values.items():
        if value is not None and (isinstance(value, bool) or not isinstance(value, (int, float))
                                  or not math.isfinite(value)):
            raise InputError(f"{name}: expected a finite number, got {type(value).__name__} {value!r}")


# --------------------------------------------------------------------------- materials


@dataclass(frozen=True)
class Source:
    """A material read by :func:`read`: where it comes from and its samples.

    ``kind`` is ``table`` (a BRDF sample table, spherical or signed in-plane), ``gcms`` (a GCMS raw file calibrated
    against its Munsell N9 ``reference``, docs/formats.md#gcms-raw-measurement), ``nbrdf`` (an NBRDF proxy ``.h5``, docs/formats.md#nbrdf-proxy),
    ``merl`` (a MERL ``.binary`` measurement), ``rgl`` (an RGL ``.bsdf`` measurement, docs/formats.md#rgl-measurement-bsdf)
    or ``virtual`` (a stand-in of the virtual goniospectrophotometer,
    docs/measure.md#the-virtual-goniospectrophotometer: its shipped DS1 measurement).
    ``samples`` is the BRDF table a fit sees: the file, the calibrated measurement, or the proxy /
    measured table sampled on ``plan``.
    ``trust_units``: a measurement read as it is although its numbers look like a unit slip
    (:mod:`neuralbrdf.data.units`); a fit of this source reads it so too.
    """

    kind: str
    location: str
    samples: BrdfTable = field(repr=False)
    name: str
    reference: str | None = None
    plan: str | None = None
    trust_units: bool = False

    @property
    def is_spectral(self) -> bool:
        """Whether the samples have one column per wavelength (else linear sRGB)."""
        return self.samples.is_spectral

    @property
    def has_truth(self) -> bool:
        """Whether the material is known everywhere (:func:`truth` can export it), not only at
        its measured directions."""
        return self.kind in TRUTH_KINDS

    def options(self) -> dict[str, str]:
        """The material in the vocabulary of the training configs (``data.*`` keys,
        :mod:`neuralbrdf.sources`)."""
        if self.kind == "virtual":
            return {"virtual": self.location}
        from neuralbrdf.sources import SAMPLED_KEYS

        if self.kind in SAMPLED_KEYS:
            return {self.kind: self.location, "plan": self.plan}
        return {"path": self.location, **({} if self.reference is None else {"reference": self.reference}),
                **({"trust_units": True} if self.trust_units else {})}


def read(source: PathLike, reference: PathLike | None = None, *, plan: str | PathLike | None = None,
         name: str | None = None, trust_units: bool = False) -> Source:
    """Read a material: a BRDF table (spherical or signed in-plane), a GCMS raw file with its
    Munsell N9 ``reference``, an NBRDF proxy ``NAME.h5``, a MERL ``NAME.binary`` or an RGL
    ``NAME.bsdf`` (spectral from a ``NAME_spec.bsdf``, RGB from a ``NAME_rgb.bsdf``; all three
    sampled on ``plan``: DS1 (default) to DS4, ``low``, or a plan file such as
    :func:`design_plan` writes), or ``virtual:NAME`` (``cyan``, ``magenta``, ``gold``,
    ``gonio``: the shipped DS1 measurement).  A measurement whose numbers look like a unit slip
    (angles in radians, wavelengths in µm, ... :mod:`neuralbrdf.data.units`) is refused unless
    ``trust_units``.

    >>> import neuralbrdf as nb
    >>> gold = nb.read("virtual:gold")
    >>> gold.kind, gold.name, gold.is_spectral, gold.samples.n_rows
    ('virtual', 'gold', True, 1001)
    >>> nb.read("virtual:silver")  # doctest: +ELLIPSIS
    Traceback (most recent call last):
    neuralbrdf.errors.InputError: unknown virtual material 'silver'; expected one of munsell_n9, cyan, magenta, gold, gonio, ...
    """
    from neuralbrdf.data.loading import load_measurement
    from neuralbrdf.data.plans import check_plan
    from neuralbrdf.sources import SAMPLED_SUFFIXES, sample_file

    text = os.fspath(_path(source, "source", "a file path or 'virtual:NAME'"))
    if reference is not None:
        _path(reference, "reference")
    if plan is not None and not isinstance(plan, (str, os.PathLike)):
        raise InputError(f"plan: expected a plan name or a plan file path, got {type(plan).__name__} {plan!r}")
    _text("name", name)
    _flags(trust_units=trust_units)
    suffix = Path(text).suffix
    sampled = not text.startswith(VIRTUAL_PREFIX) and suffix in SAMPLED_SUFFIXES
    if plan is not None and not sampled:
        raise InputError(f"plan {plan!r} applies to NBRDF (.h5), MERL (.binary) and RGL (.bsdf) files, not to {text}")
    if plan is not None:
        plan = check_plan(plan, "plan")
    if reference is not None and (text.startswith(VIRTUAL_PREFIX) or sampled):
        raise InputError(f"a Munsell reference goes with a GCMS raw file, not with {text}")
    if trust_units and (text.startswith(VIRTUAL_PREFIX) or sampled):
        raise InputError(f"trust_units goes with a measurement file, not with {text}")
    if text.startswith(VIRTUAL_PREFIX):
        from neuralbrdf.virtual.instrument import default_data_path
        from neuralbrdf.virtual.materials import REFERENCE_MATERIAL

        material = text[len(VIRTUAL_PREFIX):]
        samples = load_measurement(default_data_path(material), default_data_path(REFERENCE_MATERIAL))
        return Source("virtual", material, samples, name or material)
    if sampled:
        plan = plan or "DS1"
        samples = sample_file(text, plan)
        return Source(SAMPLED_SUFFIXES[suffix], text, samples, name or Path(text).stem, plan=plan)
    samples = load_measurement(text, reference, trust_units)
    return Source("table" if reference is None else "gcms", text, samples, name or Path(text).stem,
                  None if reference is None else os.fspath(reference), trust_units=trust_units)


# --------------------------------------------------------------------------- fitting


@dataclass(frozen=True)
class FitResult:
    """A finished fit: its run directory (config.yaml, checkpoints/, metrics.csv, metrics.json),
    the checkpoint to export and the metrics of ``metrics.json``."""

    kind: str
    run_dir: Path
    checkpoint: Path
    metrics: dict[str, Any] = field(repr=False)

    def export(self, out: PathLike, material: str | None = None, *, fast: bool | None = None, rgb_head: bool = True,
               config: str = "default") -> Model:
        """:func:`export` of this fit's checkpoint (the same file, checks and defaults)."""
        return export(self.checkpoint, out, material, fast=fast, rgb_head=rgb_head, config=config)


def _option(value) -> str:
    """A value as jsonargparse reads it from the command line (YAML/JSON; a non-finite float in
    YAML's spelling, which JSON lacks)."""
    if isinstance(value, str):
        return value
    if isinstance(value, float) and not math.isfinite(value):
        return ".nan" if math.isnan(value) else (".inf" if value > 0 else "-.inf")
    return json.dumps(value)


def _data_arguments(config: str, source: Source) -> list[str]:
    """The ``--data.*`` arguments that hand ``source`` to the data module of ``config``: its own
    keys when it takes them, else one entry of its ``sources`` list."""
    import yaml

    from neuralbrdf.configs_dir import overlay_base, resolve_config
    from neuralbrdf.lightning.config_errors import class_options

    path = resolve_config(config)
    if not path.is_file():
        from neuralbrdf.configs_dir import config_not_found

        raise config_not_found(config)
    class_path = None
    for file in (overlay_base(path), path):
        if file is not None:
            data = (yaml.safe_load(file.read_text(encoding="utf-8")) or {}).get("data")
            class_path = data.get("class_path", class_path) if isinstance(data, dict) else class_path
    accepted = class_options(class_path) if class_path else []
    options = source.options()
    if set(options) <= set(accepted):
        return [argument for key, value in options.items() for argument in (f"--data.{key}", _option(value))]
    if "sources" in accepted:
        return ["--data.sources", json.dumps([options])]
    from neuralbrdf.sources import SAMPLED_KEYS

    takes = [key for key in ("path", "reference", *SAMPLED_KEYS, "virtual") if key in accepted]
    raise InputError(f"the {Path(config).stem} config's data module takes {', '.join(takes)}; "
                     f"{source.location} is a {source.kind} source")


def fit(kind: str, data: Source | PathLike | None = None, *, config: PathLike | None = None,
        run_dir: PathLike | None = None, overrides: Mapping[str, Any] | None = None,
        overwrite: bool = False) -> FitResult:
    """Fit a model of ``kind`` (:data:`FIT_KINDS`: ``abc``, ``spectral_mlp``, ``nlb``, ``nlb_spectral``) to ``data``
    (a :class:`Source` or what :func:`read` takes; ``None``: the config's own data) through the
    kind's shipped config, or ``config`` (a shipped name or a YAML file); ``overrides`` sets config
    keys (``{"trainer.max_epochs": 5}``, as ``--trainer.max_epochs 5``).  ``run_dir``: where the run
    is written (default ``runs/<config>/<timestamp>``); a run there is replaced only with
    ``overwrite``.  Raises :class:`~neuralbrdf.errors.FitFailed` when the fit fails.

    >>> import tempfile, neuralbrdf as nb
    >>> quick = {"model.n_starts": 1, "data.eval_plan": None}     # one start, no hemisphere score: seconds
    >>> with tempfile.TemporaryDirectory() as folder:
    ...     result = nb.fit("abc", "virtual:gold", run_dir=f"{folder}/abc", overrides=quick)
    ...     print(result.checkpoint.name, result.metrics["status"], result.metrics["fit/abc/success"])
    best.ckpt ok True
    >>> nb.fit("abc", "virtual:gold", overrides={"model.n_start": 1})
    Traceback (most recent call last):
    neuralbrdf.errors.InputError: --model.n_start: AbcFitModule has no option 'n_start'; did you mean n_starts? (valid: bounds, max_evaluations, n_starts, seed)
    """
    import torch

    from neuralbrdf.data.units import overridden_by
    from neuralbrdf.lightning.run import METRICS_FILE, fitted_checkpoint, train

    if not isinstance(kind, str) or kind not in FIT_KINDS:
        raise InputError(f"unknown fit kind {kind!r}; expected one of {', '.join(FIT_KINDS)}")
    _flags(overwrite=overwrite)
    config = os.fspath(_path(config, "config", "a shipped config's name or a YAML file")) if config is not None \
        else FIT_KINDS[kind]
    if run_dir is not None:
        _path(run_dir, "run_dir")
    if overrides is not None and not isinstance(overrides, Mapping):
        raise InputError(f"overrides: expected a mapping of config keys to values such as {{'trainer.max_epochs': 5}}, "
                         f"got {type(overrides).__name__} {overrides!r}")
    if data is not None and not isinstance(data, Source):
        _path(data, "data", "a Source, a file path or 'virtual:NAME'")
    with overridden_by(f"nb.fit({kind!r}, nb.read(..., trust_units=True))"):
        source = read(data) if data is not None and not isinstance(data, Source) else data
    args = ["fit", "--config", config]
    if source is not None:
        args += _data_arguments(config, source)
    for key, value in (overrides or {}).items():
        args += [f"--{key}", _option(value)]
    if run_dir is not None:
        args += ["--run_dir", os.fspath(run_dir)]
    if overwrite:
        args.append("--overwrite")
    threads = torch.get_num_threads()
    try:
        cli = train(args)
    finally:
        torch.set_num_threads(threads)  # a config's num_threads holds for its run only
    metrics_path = cli.run_dir / METRICS_FILE
    metrics = json.loads(metrics_path.read_text(encoding="utf-8")) if metrics_path.is_file() else {}
    checkpoint = fitted_checkpoint(cli.run_dir)
    if checkpoint is None:
        raise InputError(f"the fit left no checkpoint to export in {cli.run_dir / 'checkpoints'}; the {config} "
                         "config must save one named best or fitted")
    return FitResult(kind, cli.run_dir, checkpoint, metrics)


# --------------------------------------------------------------------------- model files


class Model:
    """An exported model file (docs/formats.md#onnx-model-files), evaluated with onnxruntime: ``model(wi, wo[, wavelength])``.

    ``wi``, ``wo``: unit directions ``[N, 3]`` (or one ``[3]``); ``wavelength``: nm, ``[N]`` or one
    number within the model's :attr:`wavelength_range_nm`, for spectral models only; a wavelength
    outside it or a direction that is not finite is refused with
    :class:`~neuralbrdf.errors.InputError`.  Returns the BRDF in sr⁻¹: ``[N]`` for spectral models,
    ``[N, 3]`` (linear sRGB) otherwise; 0 below the horizon.
    """

    def __init__(self, path: PathLike) -> None:
        from neuralbrdf.evaluation.scores import OnnxEvaluator

        self._evaluator = OnnxEvaluator(path)
        info = self._evaluator.model
        self.path: Path = Path(path)
        self.kind: str = info.kind
        self.material: str = info.material
        self.is_spectral: bool = info.is_spectral
        self.wavelength_range_nm: tuple[float, float] | None = info.wavelength_range_nm

    def __call__(self, wi, wo, wavelength=None) -> np.ndarray:
        import numpy as np

        try:
            wi, wo = np.atleast_2d(np.asarray(wi, dtype=np.float64)), np.atleast_2d(np.asarray(wo, dtype=np.float64))
            wavelength = None if wavelength is None else np.asarray(wavelength, dtype=np.float64)
        except (TypeError, ValueError) as error:
            raise InputError(f"wi, wo and wavelength must be numbers (arrays of unit vectors, nm): {error}") from None
        if wi.shape != wo.shape or wi.ndim != 2 or wi.shape[1] != 3:
            raise InputError(f"wi and wo must both be [N, 3] unit vectors, got {list(wi.shape)} and {list(wo.shape)}")
        if self.is_spectral == (wavelength is None):
            raise InputError(f"{self.path.name} is {'spectral: give a wavelength (nm)' if self.is_spectral else 'RGB: give no wavelength'}")
        for name, directions in (("wi", wi), ("wo", wo)):
            bad = ~np.isfinite(directions).all(axis=1)
            if bad.any():
                raise InputError(f"{name}: direction {int(np.argmax(bad))} is not finite "
                                 f"({directions[int(np.argmax(bad))].tolist()}); expected unit vectors")
        if wavelength is not None:
            try:
                wavelength = np.broadcast_to(wavelength, (len(wi),))
            except ValueError:
                raise InputError(f"wavelength must be one number or {len(wi)} (one per direction pair), got shape "
                                 f"{list(wavelength.shape)}") from None
            low, high = self.wavelength_range_nm
            outside = ~((wavelength >= low) & (wavelength <= high))
            if outside.any():
                raise InputError(f"wavelength {wavelength[int(np.argmax(outside))]:g} nm is outside {self.path.name}'s "
                                 f"range {low:g}-{high:g} nm (wavelengths are in nm)")
        return self._evaluator.values(wi, wo, wavelength)

    def __repr__(self) -> str:
        spectrum = (f"spectral {self.wavelength_range_nm[0]:g}-{self.wavelength_range_nm[1]:g} nm"
                    if self.is_spectral else "RGB")
        return f"Model({str(self.path)!r}, kind={self.kind!r}, material={self.material!r}, {spectrum})"


def load(path: PathLike) -> Model:
    """Open an ``.onnx`` model file, checked against the contract (docs/formats.md#onnx-model-files).

    >>> import numpy as np, tempfile, neuralbrdf as nb
    >>> from neuralbrdf.geometry import inplane_to_vectors
    >>> with tempfile.TemporaryDirectory() as folder:
    ...     nb.truth("virtual:gold", f"{folder}/gold.onnx")
    ...     model = nb.load(f"{folder}/gold.onnx")
    Model('.../gold.onnx', kind='reference', material='gold', spectral 400-700 nm)
    >>> wi, wo = inplane_to_vectors(np.array([30.0, 30.0]), np.array([30.0, -20.0]))  # mirror, off-mirror
    >>> f = model(wi, wo, 550.0)                                                     # sr^-1 at 550 nm
    >>> f.shape, bool(f[0] > 10 * f[1])
    ((2,), True)
    """
    return Model(_path(path, "path", "a model file (.onnx) path"))


def export(checkpoint: PathLike, out: PathLike, material: str | None = None, *, fast: bool | None = None,
           rgb_head: bool = True, config: str = "default") -> Model:
    """Export a trained checkpoint (spectral MLP, ABC, or an NLB or spectral NLB latent fit;
    ``material`` when it holds several) to one ``.onnx`` file, validated against PyTorch before it
    is written — exactly what ``neuralbrdf export`` writes and prints: a spectral model gets its
    RGB head ``f_rgb`` unless ``rgb_head=False``; ``fast=True`` adds the compact copy ``f_fast``,
    which a spectral NLB model gets unless ``fast=False``;
    ``config`` names the fast paths' settings (docs/export-render.md).  The same checkpoint and
    options give the same bytes.

    >>> import tempfile, neuralbrdf as nb
    >>> quick = {"model.n_starts": 1, "data.eval_plan": None}     # one start, no hemisphere score: seconds
    >>> with tempfile.TemporaryDirectory() as folder:
    ...     result = nb.fit("abc", "virtual:gold", run_dir=f"{folder}/run", overrides=quick)
    ...     nb.export(result.checkpoint, f"{folder}/gold_abc.onnx", rgb_head=False)
    wrote .../gold_abc.onnx: abc model of 'gold'; onnxruntime vs PyTorch on 17408 probes: max error ...
    Model('.../gold_abc.onnx', kind='abc', material='gold', spectral 400-700 nm)
    """
    from neuralbrdf.exporting import export_model
    from neuralbrdf.lod.fast_paths import FastPathError
    from neuralbrdf.onnx_export import ExportValidationError

    _path(checkpoint, "checkpoint", "a checkpoint (.ckpt) path")
    _path(out, "out", "an output model file (.onnx) path")
    _text("material", material)
    _text("config", config, optional=False)
    _flags(rgb_head=rgb_head, **({} if fast is None else {"fast": fast}))
    try:
        export_model(out, checkpoint=checkpoint, material=material, fast=fast, rgb_head=rgb_head, config=config)
    except (ExportValidationError, FastPathError) as error:
        raise InputError(f"not written: {error}", path=out) from None
    return Model(out)


def truth(source: Source | PathLike, out: PathLike) -> Model:
    """Export the ground truth of a material to ``out`` (a ``reference`` model file that renders
    like a fitted one): ``virtual:NAME`` (spectral), an NBRDF proxy ``.h5`` or a MERL ``.binary``
    (RGB), an RGL ``.bsdf`` (a dense resampling, spectral or RGB as the file; its resampling error
    against Mitsuba's ``measured`` plugin is in the file's metadata), or a :class:`Source` of one of
    those.  A measurement table or GCMS raw file has no truth.

    >>> import tempfile, neuralbrdf as nb
    >>> with tempfile.TemporaryDirectory() as folder:
    ...     nb.truth(nb.read("virtual:gonio"), f"{folder}/gonio.onnx")
    Model('.../gonio.onnx', kind='reference', material='gonio', spectral 400-700 nm)
    """
    from neuralbrdf.evaluation.truth import export_truth

    _path(out, "out", "an output model file (.onnx) path")
    if not isinstance(source, Source):
        _path(source, "source", "a Source, 'virtual:NAME', an NBRDF .h5, a MERL .binary or an RGL .bsdf")
    if isinstance(source, Source):
        if not source.has_truth:
            raise InputError(f"a measurement ({source.kind}) is known only where it was measured; a truth comes from "
                             "virtual:NAME, an NBRDF .h5, a MERL .binary or an RGL .bsdf", path=source.location)
        source = VIRTUAL_PREFIX + source.location if source.kind == "virtual" else source.location
    export_truth(os.fspath(source), out)
    return Model(out)


# --------------------------------------------------------------------------- evaluation and rendering


def _model_path(model: Model | PathLike, name: str) -> Path:
    return model.path if isinstance(model, Model) else _path(model, name, "a Model or a model file (.onnx) path")


def _integers(**values) -> None:
    """:class:`InputError` naming the first of ``values`` that is neither an integer nor ``None``."""
    for name, value in values.items():
        if value is not None and (isinstance(value, bool) or not isinstance(value, int)):
            raise InputError(f"{name} must be an integer, got {type(value).__name__} {value!r}")


def _positive(**values) -> None:
    _integers(**values)
    for name, value in values.items():
        if value is not None and value < 1:
            raise InputError(f"{name} must be a positive integer, got {value!r}")


def evaluate(model: Model | PathLike, truth: Model | PathLike, out_dir: PathLike, *, scene: PathLike | None = None,
             material: str | None = None, variant: str | None = None, spp: int = 256,
             resolution: int | None = None, seed: int = 0, backend: str = "drjit", fast: bool = False,
             images: bool = True) -> dict:
    """Score ``model`` against ``truth`` (docs/evaluate.md): log-cosine and relative RMSE over the
    hemisphere, relative RMSE in the in-plane glossy and diffuse regions, and, with ``images``, the
    image errors (ΔE2000 mean and p95, PSNR) of both rendered with the same seeds in the material
    preview or in ``scene`` (any Mitsuba scene using the ``neuralbrdf`` BSDF; ``material`` names the
    one that carries model, then truth).  ``truth``: a reference model file, or an RGL measurement
    ``NAME.bsdf``, scored and rendered through Mitsuba's own ``measured`` plugin.  ``variant``:
    default ``llvm_ad_spectral``, or for a measurement the variant of its kind (``llvm_ad_rgb`` for
    an RGB file).  Writes ``out_dir/evaluation.json`` (and the images) and
    returns its content.  ``resolution``: default 128 in the preview, the scene's own film in a scene;
    ``fast``: render the model's fast path ``f_fast`` (``neuralbrdf export --fast``).  The model's
    fast paths are always scored against its ``f`` (``result["fast_paths"]``).

    >>> import tempfile, neuralbrdf as nb
    >>> with tempfile.TemporaryDirectory() as folder:
    ...     gold = nb.truth("virtual:gold", f"{folder}/gold.onnx")
    ...     cyan = nb.truth("virtual:cyan", f"{folder}/cyan.onnx")
    ...     scores = nb.evaluate(cyan, gold, f"{folder}/eval", images=False)   # directions only
    >>> round(scores["hemisphere_logcos_rmse"], 2), round(scores["inplane_glossy_rel_rmse"], 2)  # a diffuse ink is no gold
    (0.16, 0.89)
    """
    from neuralbrdf.evaluation.evaluate import DEFAULT_RESOLUTION, RenderSettings, SceneTarget, measurement_variant
    from neuralbrdf.evaluation.evaluate import evaluate as run_evaluation

    _integers(spp=spp, resolution=resolution, seed=seed)  # their values: checked by the evaluation
    _text("variant", variant)
    _text("material", material)
    _text("backend", backend, optional=False)
    _flags(fast=fast, images=images)
    variant = measurement_variant(_model_path(truth, "truth"), variant)
    settings = RenderSettings(variant, spp, DEFAULT_RESOLUTION if resolution is None else resolution, seed, backend,
                              fast)  # checked by the evaluation before any work
    target = None if scene is None else SceneTarget(_path(scene, "scene", "a Mitsuba scene file path"), material,
                                                    resolution)
    if target is None and material is not None:
        raise InputError("material names a material of a scene: give the scene too")
    result = run_evaluation(_model_path(model, "model"), _model_path(truth, "truth"),
                            _path(out_dir, "out_dir", "a folder path"), settings, render_images=images, scene=target)
    for note in result["notes"]:  # a truth that is no ground truth, a model scored against itself
        warnings.warn(note, stacklevel=2)
    return result


class RenderFailed(RuntimeError):
    """A render that produced a non-finite image (nothing was written)."""


def render_image(model: Model | PathLike | None = None, out: PathLike | None = None, *, scene: PathLike | None = None,
           material: str | None = None, reference_bsdf: str | None = None, variant: str = DEFAULT_VARIANT,
           spp: int = 64, resolution: int | None = None, seed: int = 0, backend: str | None = None,
           rgb_tolerance: float | None = None, max_depth: int | None = None, spp_per_pass: int | None = None,
           exr: bool = False, fast: bool = False, progress: bool = False) -> np.ndarray:
    """Render ``model`` (a :class:`Model` or ``.onnx`` file; or Mitsuba's built-in
    ``reference_bsdf``) in the material-preview scene, or in ``scene`` (any Mitsuba scene file using
    the ``neuralbrdf`` BSDF; with ``model``, the ``neuralbrdf`` material ``material`` carries it,
    without, the scene renders as it is).  Returns the linear RGB image ``[H, W, 3]``; with ``out``
    (``.png``) also writes the 8-bit sRGB PNG and, with ``exr``, the linear EXR beside it (both or
    neither).  Defaults: 256² in the preview (a scene's own film), path depth 5 (a scene's own),
    the ``drjit`` backend; ``rgb_tolerance``: spectral models in RGB variants (see ``neuralbrdf
    render --help``); ``fast``: each model's fast path ``f_fast`` (``neuralbrdf export --fast``;
    refused for a model without one, in a scene such models render full with a warning).
    Raises :class:`RenderFailed` for a non-finite image.

    >>> import tempfile, neuralbrdf as nb
    >>> with tempfile.TemporaryDirectory() as folder:
    ...     gold = nb.truth("virtual:gold", f"{folder}/gold.onnx")
    ...     image = nb.render_image(gold, f"{folder}/gold.png", spp=2, resolution=8)
    >>> image.shape, image.dtype
    ((8, 8, 3), dtype('float32'))
    """
    import numpy as np

    from neuralbrdf.atomic import check_outputs, command_inputs
    from neuralbrdf.render.mitsuba_bsdf import clamped_values, reset_clamped_values
    from neuralbrdf.render.preview import set_variant, write_images

    _positive(spp=spp, resolution=resolution, max_depth=max_depth, spp_per_pass=spp_per_pass)
    if isinstance(seed, bool) or not isinstance(seed, int) or seed < 0:
        raise InputError(f"seed must be a non-negative integer, got {seed!r}")
    _text("variant", variant, optional=False)
    for name, value in (("material", material), ("reference_bsdf", reference_bsdf), ("backend", backend)):
        _text(name, value)
    _numbers(rgb_tolerance=rgb_tolerance)
    _flags(exr=exr, fast=fast, progress=progress)
    written = []
    if out is not None:
        out = _path(out, "out", "an output image (.png) path")
        if out.suffix.lower() != ".png":
            raise InputError("the output must be a .png file (with exr, a linear EXR is written beside it)", path=out)
        written = [out, out.with_suffix(".exr")] if exr else [out]
    with command_inputs():  # an output may not be one of the inputs (the model, the scene)
        if scene is not None:
            draw = _scene_renderer(_path(scene, "scene", "a Mitsuba scene file path"),
                                   None if model is None else _model_path(model, "model"), material, resolution,
                                   max_depth, backend, rgb_tolerance, spp, spp_per_pass, fast)
        else:
            draw = _preview_renderer(None if model is None else _model_path(model, "model"), reference_bsdf, resolution,
                                     max_depth, backend, rgb_tolerance, variant, fast)
        check_outputs(*written)
        set_variant(variant)
        reset_clamped_values()
        image = draw(variant, spp, seed, spp_per_pass, progress)
        if not np.all(np.isfinite(image)):
            raise RenderFailed("the render is not finite; nothing written")
        if out is not None:
            write_images(image, out, written[1] if exr else None)
    clamped = clamped_values()
    if clamped:
        warnings.warn(f"{clamped} model evaluations were negative or not finite and were clamped to 0 (the model is "
                      "wrong somewhere its load-time probe did not look)", stacklevel=2)
    return image


def _preview_renderer(model: Path | None, reference_bsdf: str | None, resolution, max_depth, backend, rgb_tolerance,
                      variant: str, fast: bool):
    """The preview scene's render, its material checked now (before any output is touched)."""
    from neuralbrdf.render.preview import DEFAULT_MAX_DEPTH, Material, render as render_preview, within_drjit_budget
    from neuralbrdf.render.spectral_quadrature import DEFAULT_RMS_TOLERANCE

    if (model is None) == (reference_bsdf is None):
        raise InputError("render a model or a built-in reference BSDF (or a scene)")
    material = within_drjit_budget(Material(
        model=model, backend=backend or "drjit", reference_bsdf=reference_bsdf,
        rgb_tolerance=DEFAULT_RMS_TOLERANCE if rgb_tolerance is None else rgb_tolerance, fast=fast,
    ))
    if fast:
        if model is None:
            raise InputError("fast renders a model's fast path; give a model or a scene", key="--fast")
        from neuralbrdf.kinds import load_model
        from neuralbrdf.render.fast_paths import chosen_output

        chosen_output(load_model(model), "_spectral" in variant, True, True)  # one line if it has none

    def draw(variant, spp, seed, spp_per_pass, progress):
        return render_preview(material, variant, spp, resolution or 256, seed, spp_per_pass,
                              max_depth or DEFAULT_MAX_DEPTH, progress=progress)

    return draw


def _scene_renderer(scene: Path, model: Path | None, material: str | None, resolution, max_depth, backend,
                    rgb_tolerance, spp, spp_per_pass, fast: bool):
    """A user's scene with the options given applied (the others left as the scene has them)."""
    from neuralbrdf.render.preview import check_render_size
    from neuralbrdf.render.scene_file import SceneFile, render_scene_file

    scene_file = SceneFile(scene)
    names = [m.name for m in scene_file.materials()]
    if model is not None:
        from neuralbrdf.evaluation.evaluate import SceneTarget

        scene_file.set_model(SceneTarget(scene, material).material_name(), model)
    elif material is not None:
        raise InputError("material names where a model goes: give the model too")
    elif not names:
        warnings.warn(f"{scene} has no neuralbrdf material; rendering it as it is", stacklevel=3)
    if resolution is not None:
        check_render_size(resolution, min(spp, spp_per_pass or spp), False)
        scene_file.set_resolution(resolution)
    if max_depth is not None:
        scene_file.set_max_depth(max_depth)
    if backend is not None:
        scene_file.set_all("backend", backend)
    if rgb_tolerance is not None:
        scene_file.set_all("rgb_tolerance", repr(float(rgb_tolerance)))
    if fast:
        _set_fast(scene_file)

    def draw(variant, spp, seed, spp_per_pass, progress):
        return render_scene_file(scene_file, spp, seed, spp_per_pass, progress=progress)[0]

    return draw


def _set_fast(scene_file) -> None:
    """``fast`` in a scene: property ``fast`` on every material whose model has a fast path."""
    from neuralbrdf.kinds import load_model
    from neuralbrdf.onnx_contract import OUTPUT_FAST
    from neuralbrdf.render.fast_paths import ADD_COMMAND, FAST_PROPERTY

    without = []
    for material in scene_file.materials():
        if OUTPUT_FAST in load_model(material.model).fast_paths:
            scene_file.set_property(material.element, FAST_PROPERTY, "true")
        else:
            without.append(material.name)
    if without:
        warnings.warn(f"fast: {', '.join(without)} {'has' if len(without) == 1 else 'have'} no fast path and "
                      f"{'renders' if len(without) == 1 else 'render'} full (add one: {ADD_COMMAND})", stacklevel=4)


# --------------------------------------------------------------------------- measuring a fraction of the pairs


def _instrument(max_theta: float, step: float, retro_band: float):
    from neuralbrdf.acquisition.instrument import Instrument

    return Instrument(max_theta, step, retro_band)


def _acquisition_config(config: PathLike, overrides: Mapping[str, Any] | None, section: str):
    """The ``section`` of an acquisition config (a shipped name or a YAML file) with ``overrides``."""
    import dataclasses

    from neuralbrdf.acquisition.settings import load_acquisition_config

    _path(config, "config", "a shipped config's name or a YAML file")
    settings = getattr(load_acquisition_config(config), section)
    if overrides is None:
        return settings
    if not isinstance(overrides, Mapping):
        raise InputError(f"overrides: expected a mapping of {section} settings, got {type(overrides).__name__}")
    fields = {f.name for f in dataclasses.fields(settings)}
    for key in overrides:
        if key not in fields:
            raise InputError(f"unknown {section} setting; expected one of {', '.join(sorted(fields))}", key=str(key))
    return dataclasses.replace(settings, **overrides)


def design_plan(budget: int, out: PathLike | None = None, *, kind: str = "nlb_spectral", max_theta: float = 60.0,
                step: float = 1.0, retro_band: float = 0.0, config: PathLike = "default",
                overrides: Mapping[str, Any] | None = None, progress: bool = False):
    """``budget`` in-plane pairs for an instrument that reaches ``max_theta`` degrees in steps of
    ``step`` degrees and cannot measure within ``retro_band`` degrees of retro-reflection, chosen
    with the prior of ``kind`` to lower the expected hemisphere error of its fit most
    (docs/how-many-measurements.md); with ``out``, also written as a plan file (the format of
    ``neuralbrdf plan DS3``), pairs in the order to measure them.  ``overrides``: settings of the
    config's ``design`` section (``{"seed": 1}``).  Returns the
    :class:`~neuralbrdf.acquisition.design.PlanDesign`.

    >>> import neuralbrdf as nb
    >>> plan = nb.design_plan(3, step=10.0, overrides={"blends": 0, "analytic": 0})   # a coarse instrument: seconds
    >>> len(plan.theta_i), plan.predicted_error[0] > plan.predicted_error[-1]
    (3, True)
    >>> nb.design_plan(0)
    Traceback (most recent call last):
    neuralbrdf.errors.InputError: option '--budget': expected a number of pairs from 1 to 3721 (the distinct pairs this instrument can measure), got 0
    """
    from neuralbrdf.acquisition.design import design

    _integers(budget=budget)
    _text("kind", kind, optional=False)
    _numbers(max_theta=max_theta, step=step, retro_band=retro_band)
    _flags(progress=progress)
    settings = _acquisition_config(config, overrides, "design")
    instrument = _instrument(max_theta, step, retro_band)
    if out is not None:
        from neuralbrdf.atomic import check_outputs

        check_outputs(_path(out, "out", "an output plan file (.csv) path"))
    plan = design(kind, budget, instrument, settings, progress=progress)
    if out is not None:
        from neuralbrdf.data.plans import write_plan

        write_plan((plan.theta_i, plan.theta_r), out)
    return plan


def next_pairs(measurement: Source | PathLike, count: int = 1, out: PathLike | None = None, *,
               reference: PathLike | None = None, max_theta: float = 60.0, step: float = 1.0, retro_band: float = 0.0,
               config: PathLike = "default"):
    """From a ``measurement`` (a :class:`Source` or what :func:`read` takes, with its GCMS
    ``reference``), the ``count`` pairs of the instrument to measure next and the current fit's
    error, estimated with an interval (docs/how-many-measurements.md); with ``out``, the pairs are
    also written as a plan file.  Returns :class:`~neuralbrdf.acquisition.next_pairs.NextPairs`
    (``.enough(target_delta_e)`` says whether a target is met).

    >>> import neuralbrdf as nb
    >>> answer = nb.next_pairs(nb.read("virtual:gold", plan="DS4"), count=2, step=5.0)
    >>> answer.measured, len(answer.theta_i), answer.logcos.low < answer.logcos.estimate < answer.logcos.high
    (6, 2, True)
    """
    from neuralbrdf.acquisition.next_pairs import next_pairs as answer

    _integers(count=count)
    _numbers(max_theta=max_theta, step=step, retro_band=retro_band)
    if not isinstance(measurement, Source):
        measurement = read(measurement, reference)
    elif reference is not None:
        raise InputError("reference goes with a GCMS raw file path, not with a Source (read it with its reference)")
    from neuralbrdf.acquisition.settings import load_acquisition_config

    settings = load_acquisition_config(_path(config, "config", "a shipped config's name or a YAML file"))
    if out is not None:
        from neuralbrdf.atomic import check_outputs

        check_outputs(_path(out, "out", "an output plan file (.csv) path"))
    result = answer(measurement.samples, count, _instrument(max_theta, step, retro_band), settings.design,
                    settings.estimate, name=measurement.name)
    if out is not None:
        from neuralbrdf.data.plans import write_plan

        write_plan((result.theta_i, result.theta_r), out)
    return result


def acquire(source: PathLike, out_dir: PathLike | None = None, *, start: PathLike | None = None,
            target_delta_e: float | None = None, max_pairs: int | None = None, count: int | None = None,
            noise: float | None = None, seed: int | None = None, render: bool = True, max_theta: float = 60.0,
            step: float = 1.0, retro_band: float = 0.0, config: PathLike = "default", overwrite: bool = False,
            progress=None):
    """A simulated session on a material with a truth (``virtual:NAME``, an NBRDF ``.h5``, a MERL
    ``.binary``, an RGL ``.bsdf``): measure ``start`` (a plan name or file; default the config's),
    fit, ask :func:`next_pairs` for ``count`` more, measure them with the virtual instrument's
    ``noise``, until the estimated preview ΔE2000 is within ``target_delta_e`` or ``max_pairs`` are
    measured (docs/how-many-measurements.md).  ``render``: the true ΔE2000 of every step (preview
    renders; without, the true hemisphere error only).  With ``out_dir``: writes ``acquire.json``,
    ``acquire.png`` (the curve of true and estimated error against the pairs), ``plan.csv``,
    ``measurement.csv`` and ``model.onnx``, refusing a folder that holds them unless ``overwrite``.
    ``progress(step)`` is called after each step.  Returns the
    :class:`~neuralbrdf.acquisition.session.SessionResult`.

    >>> import neuralbrdf as nb
    >>> session = nb.acquire("virtual:val-blue", start="DS4", max_pairs=7, render=False, step=10.0)
    >>> [step.pairs for step in session.steps], session.stopped
    ([6, 7], 'the budget of 7 pairs is spent')
    """
    from neuralbrdf.acquisition.session import check_session_outputs, run_session, write_session
    from neuralbrdf.acquisition.settings import load_acquisition_config
    from neuralbrdf.data.plans import check_plan

    settings = load_acquisition_config(_path(config, "config", "a shipped config's name or a YAML file"))
    _integers(max_pairs=max_pairs, count=count, seed=seed)
    _numbers(target_delta_e=target_delta_e, noise=noise, max_theta=max_theta, step=step, retro_band=retro_band)
    _flags(render=render, overwrite=overwrite)
    if progress is not None and not callable(progress):
        raise InputError(f"progress: expected a function called after each step, got {type(progress).__name__}")
    changes = {key: value for key, value in (("start", None if start is None else check_plan(start, "start",
                                                                                                in_plane=True)),
                                             ("max_pairs", max_pairs), ("count", count), ("noise", noise),
                                             ("seed", seed)) if value is not None}
    import dataclasses

    session = dataclasses.replace(settings.session, **changes)
    if out_dir is not None:
        check_session_outputs(_path(out_dir, "out_dir", "a folder path"), overwrite)
    result = run_session(os.fspath(_path(source, "source", "'virtual:NAME' or a file path")), session,
                         _instrument(max_theta, step, retro_band), settings.design, settings.estimate, target_delta_e,
                         render=render, progress=progress)
    if out_dir is not None:
        write_session(result, Path(out_dir))
    return result


# --------------------------------------------------------------------------- exploring


def view(*models: Model | PathLike, truth: Model | PathLike | None = None,
         table: Source | BrdfTable | PathLike | None = None, reference: PathLike | None = None,
         host: str = "127.0.0.1", port: int = 0):
    """Serve the interactive BRDF explorer of ``neuralbrdf view`` for ``models`` (model files, any
    kind), a ``truth`` (kind ``reference``) and a measurement ``table`` (a :class:`Source`, a table,
    or what :func:`read` takes, with its ``reference`` for a GCMS raw file) in a background thread
    and return the running :class:`~neuralbrdf.explorer.server.Viewer`: open ``viewer.url`` in a
    browser, ``viewer.stop()`` ends it (or use it in a ``with`` block).  ``host`` ``127.0.0.1``:
    this machine only; ``port`` 0: a free one.

    >>> import json, tempfile, urllib.request, neuralbrdf as nb
    >>> with tempfile.TemporaryDirectory() as folder:
    ...     gold = nb.truth("virtual:gold", f"{folder}/gold.onnx")
    ...     with nb.view(gold, table="virtual:gold") as viewer:
    ...         scene = json.load(urllib.request.urlopen(viewer.url + "api/scene"))
    >>> viewer.url  # doctest: +ELLIPSIS
    'http://127.0.0.1:.../'
    >>> [source["kind"] for source in scene["sources"]], scene["measured"]["rows"]
    (['reference'], 1001)
    """
    from neuralbrdf.data.table import BrdfTable as Table
    from neuralbrdf.explorer.launch import open_scene
    from neuralbrdf.explorer.server import Viewer

    _text("host", host, optional=False)
    _integers(port=port)
    label = None
    if table is not None and not isinstance(table, (Source, Table)):
        from neuralbrdf.data.units import overridden_by

        label = os.fspath(table)
        with overridden_by("nb.view(..., table=nb.read(TABLE, trust_units=True))"):
            table = read(table, reference)
    elif reference is not None:
        raise InputError("a Munsell reference goes with a GCMS raw table file")
    if isinstance(table, Source):
        label = label or table.location
        table = table.samples
    scene = open_scene([_model_path(m, f"models[{i}]") for i, m in enumerate(models)],
                       None if truth is None else _model_path(truth, "truth"), table, label)
    return Viewer(scene, host, port).start()


__all__ = ["FIT_KINDS", "FitResult", "Model", "RenderFailed", "Source", "acquire", "design_plan", "evaluate", "export",
           "fit", "load", "next_pairs", "read", "render_image", "truth", "view"]
