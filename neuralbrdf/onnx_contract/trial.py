"""The trial evaluation of a model file with onnxruntime (:mod:`neuralbrdf.onnx_contract`): ``f`` and
each fast path run on the probes (:mod:`~neuralbrdf.onnx_contract.probes`) must have the contract's
shape, be 0 below the horizon, and be finite and >= 0 everywhere on the dense probe."""

from __future__ import annotations

import numpy as np
import onnx
import onnxruntime

from neuralbrdf.errors import InputError
from neuralbrdf.onnx_contract.graph import output_model
from neuralbrdf.onnx_contract.probes import PROBE_WAVELENGTHS, dense_probe, probe_directions
from neuralbrdf.onnx_contract.schema import INPUT_WAVELENGTH, INPUT_WI, INPUT_WO, OUTPUT_F, OUTPUT_RGB


def check_dense_probe(session, path, wavelength_range) -> None:
    """Sign and finiteness of ``f`` over :func:`dense_probe` (every wavelength of
    :data:`PROBE_WAVELENGTHS` for spectral models); the first offending pair is named."""
    wi, wo, near_mirror = dense_probe()
    wavelengths = [None] if wavelength_range is None else np.linspace(*wavelength_range, PROBE_WAVELENGTHS)
    for wavelength in wavelengths:
        feeds = {INPUT_WI: wi, INPUT_WO: wo}
        if wavelength is not None:
            feeds[INPUT_WAVELENGTH] = np.full(len(wi), wavelength, dtype=np.float32)
        try:
            (f,) = session.run([OUTPUT_F], feeds)
        except Exception as error:
            raise InputError(f"onnxruntime fails to evaluate the graph: {error}", path=path) from None
        values = f.reshape(len(wi), -1)
        bad = ~(values >= 0) | ~np.isfinite(values)
        rows = np.flatnonzero(bad.any(axis=1))
        if rows.size:
            row = int(rows[np.argmin(np.nan_to_num(values[rows].min(axis=1), nan=-np.inf))])
            worst = values[row][bad[row]][0]
            theta_i = np.degrees(np.arccos(np.clip(wi[row, 2], -1, 1)))
            theta_o = np.degrees(np.arccos(np.clip(wo[row, 2], -1, 1)))
            where = " (near the mirror direction)" if near_mirror[row] else ""
            at = "" if wavelength is None else f" at {wavelength:g} nm"
            kind = "not finite" if not np.isfinite(worst) else "negative"
            raise InputError(
                f"output 'f' is {kind} ({worst:g} sr^-1) at {rows.size} of {len(wi)} probe pairs{at}, e.g. "
                f"theta_i = {theta_i:.2f} deg, theta_o = {theta_o:.2f} deg{where}; a BRDF is finite and >= 0",
                path=path,
            )


def check_fast_path(proto: onnx.ModelProto, output: str, path, wavelength_range) -> None:
    """A fast path evaluated like ``f`` (:func:`check_trial_evaluation`) on its own graph
    (:func:`output_model`); ``f_rgb`` must not read the wavelength."""
    model = output_model(proto, output)
    reads_wavelength = any(vi.name == INPUT_WAVELENGTH for vi in model.graph.input)
    if output == OUTPUT_RGB and reads_wavelength:
        raise InputError(f"output {output!r} depends on 'wavelength'; the linear sRGB is a function of wi, wo alone",
                         path=path)
    try:
        check_trial_evaluation(model, path, wavelength_range if reads_wavelength else None)
    except InputError as error:
        raise InputError(f"fast path {output!r}: {error.reason}", path=path) from None


def check_trial_evaluation(proto: onnx.ModelProto, path, wavelength_range) -> None:
    """Run the graph on :func:`probe_directions` (shape, zero below the horizon) and on
    :func:`dense_probe` (sign and finiteness) with onnxruntime and check its output."""
    try:
        session = onnxruntime.InferenceSession(
            proto.SerializeToString(), providers=["CPUExecutionProvider"]
        )
    except Exception as error:  # onnxruntime raises its own Fail/InvalidGraph types
        raise InputError(f"onnxruntime cannot load the graph: {error}", path=path) from None
    wi, wo, below = probe_directions()
    feeds = {INPUT_WI: wi, INPUT_WO: wo}
    expected_shape: tuple[int, ...] = (len(wi), 3)
    if wavelength_range is not None:
        feeds[INPUT_WAVELENGTH] = np.linspace(*wavelength_range, len(wi)).astype(np.float32)
        expected_shape = (len(wi),)
    try:
        (f,) = session.run([OUTPUT_F], feeds)
    except Exception as error:
        raise InputError(f"onnxruntime fails to evaluate the graph: {error}", path=path) from None
    if f.shape != expected_shape:
        raise InputError(
            f"output 'f' has shape {list(f.shape)} for {len(wi)} direction pairs, expected "
            f"{list(expected_shape)}",
            path=path,
        )
    if not np.all(np.isfinite(f)):
        raise InputError("output 'f' is not finite at some probe directions", path=path)
    if np.any(f < 0):
        raise InputError(
            f"output 'f' is negative (min {f.min():g} sr^-1) at some probe directions", path=path
        )
    if np.any(f[below] != 0):
        raise InputError(
            "output 'f' is not 0 when a direction is below the horizon (docs/formats.md#onnx-model-files)", path=path
        )
    check_dense_probe(session, path, wavelength_range)
