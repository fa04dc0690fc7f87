"""Model files: :func:`export` a checkpoint, :func:`load` a file, export a material's :func:`truth`."""

from __future__ import annotations

import os
from pathlib import Path
from typing import TYPE_CHECKING

from neuralbrdf.api.arguments import PathLike, as_path, check_flags, check_text
from neuralbrdf.api.materials import VIRTUAL_PREFIX, Source
from neuralbrdf.errors import InputError

if TYPE_CHECKING:
    import numpy as np


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
    return Model(as_path(path, "path", "a model file (.onnx) path"))


class ExportFailed(InputError):
    """An export whose graph failed its validation against PyTorch, or a fast path its error bound;
    nothing was written.  ``failure`` says which check and by how much."""

    def __init__(self, out: PathLike, failure: Exception) -> None:
        super().__init__(f"not written: {failure}", path=out)
        self.failure = failure


def export(checkpoint: PathLike | None, out: PathLike, material: str | None = None, *, model: PathLike | None = None,
           fast: bool | None = None, rgb_head: bool = True, config: str = "default") -> Model:
    """Export a trained checkpoint (spectral MLP, ABC, or an NLB or spectral NLB latent fit;
    ``material`` when it holds several) to one ``.onnx`` file, validated against PyTorch before it
    is written — exactly what ``neuralbrdf export`` writes and prints: a spectral model gets its
    RGB head ``f_rgb`` unless ``rgb_head=False``; ``fast=True`` adds the compact copy ``f_fast``,
    which a spectral NLB model gets unless ``fast=False``;
    ``config`` names the fast paths' settings (docs/export-render.md).  The same checkpoint and
    options give the same bytes.  With ``model`` (an exported file) instead of a checkpoint
    (``None``), the fast paths asked for are added to a copy of it.  Raises :class:`ExportFailed`
    (an :class:`InputError`) when the graph or a fast path fails its check.

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

    if checkpoint is not None or model is None:
        as_path(checkpoint, "checkpoint", "a checkpoint (.ckpt) path")
    if model is not None:
        as_path(model, "model", "a model file (.onnx) path")
    as_path(out, "out", "an output model file (.onnx) path")
    check_text("material", material)
    check_text("config", config, optional=False)
    check_flags(rgb_head=rgb_head, **({} if fast is None else {"fast": fast}))
    try:
        export_model(out, checkpoint=checkpoint, model=model, material=material, fast=fast, rgb_head=rgb_head,
                     config=config)
    except (ExportValidationError, FastPathError) as error:
        raise ExportFailed(out, error) from None
    return Model(out)


def truth(source: Source | PathLike, out: PathLike, *, log=None) -> Model:
    """Export the ground truth of a material to ``out`` (a ``reference`` model file that renders
    like a fitted one): ``virtual:NAME`` (spectral), an NBRDF proxy ``.h5`` or a MERL ``.binary``
    (RGB), an RGL ``.bsdf`` (a dense resampling, spectral or RGB as the file; its resampling error
    against Mitsuba's ``measured`` plugin is in the file's metadata), or a :class:`Source` of one of
    those.  A measurement table or GCMS raw file has no truth.  ``log`` (``print``: what
    ``neuralbrdf export-truth`` prints) gets a line on the file written, its check against PyTorch
    and, for a resampled measurement, the resampling's error.

    >>> import tempfile, neuralbrdf as nb
    >>> with tempfile.TemporaryDirectory() as folder:
    ...     nb.truth(nb.read("virtual:gonio"), f"{folder}/gonio.onnx")
    Model('.../gonio.onnx', kind='reference', material='gonio', spectral 400-700 nm)
    """
    from neuralbrdf.evaluation.truth import describe_resampling, load_truth
    from neuralbrdf.onnx_export import write_model

    as_path(out, "out", "an output model file (.onnx) path")
    if not isinstance(source, Source):
        as_path(source, "source", "a Source, 'virtual:NAME', an NBRDF .h5, a MERL .binary or an RGL .bsdf")
    if isinstance(source, Source):
        if not source.has_truth:
            raise InputError(f"a measurement ({source.kind}) is known only where it was measured; a truth comes from "
                             "virtual:NAME, an NBRDF .h5, a MERL .binary or an RGL .bsdf", path=source.location)
        source = VIRTUAL_PREFIX + source.location if source.kind == "virtual" else source.location
    material = load_truth(os.fspath(source))
    report = write_model(material.exportable(), out)
    if log is not None:
        log(f"wrote {report.path}: reference model of {report.material!r}; onnxruntime vs PyTorch on {report.n_probes} "
            f"probes: max error {report.max_abs_error:.2g} sr^-1, {report.max_rel_error:.2g} relative")
        if material.kind_metadata:
            log(describe_resampling(material.kind_metadata))
    return Model(out)


def model_path(model: Model | PathLike, name: str) -> Path:
    """The file of ``model`` (a :class:`Model` or a path), or :class:`InputError` naming the argument ``name``."""
    return model.path if isinstance(model, Model) else as_path(model, name, "a Model or a model file (.onnx) path")
