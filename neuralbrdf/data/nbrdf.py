"""MERL proxies: the Neural BRDF networks of Sztrajman et al. (2021) as materials (docs/formats.md#nbrdf-proxy).

A. Sztrajman, G. Rainer, T. Ritschel, T. Weyrich, "Neural BRDF representation and importance
sampling", Computer Graphics Forum 40(6), 2021 (code and weights: github.com/asztr/Neural-BRDF,
MIT licence).  Each network is a fit of one MERL material (Matusik et al. 2003, "A data-driven
reflectance model"; data CC-BY-SA 4.0 by MERL), stored as a Keras weight file ``NAME.h5`` and a
Keras architecture file ``NAME.json``.

The network (paper §3.1) maps the Rusinkiewicz (1998) half/difference vectors to RGB::

    x = (sin theta_h, 0, cos theta_h, d_x, d_y, d_z)          # h with phi_h = 0, d unit
    f = exp(W3 relu(W2 relu(W1 x + b1) + b2) + b3) - 1       # row vectors: y = x @ kernel + bias

giving the BRDF in sr⁻¹ per linear RGB channel (MERL's channel scales applied, no cosine).  We
clamp it at 0 and set it to exactly 0 when either direction is at or below the horizon.

Evaluation goes through the array API, so :meth:`NbrdfNetwork.evaluate` accepts NumPy arrays or
PyTorch tensors (any float dtype and device; torch inputs keep their autograd graph).

Two properties of the fitted networks, not of this code: they are isotropic by construction
but only approximately reciprocal (over random upper-hemisphere pairs the median relative
difference between ``f(wi, wo)`` and ``f(wo, wi)`` is 3-15 % for the five report materials);
and at the mirror configuration ``theta_h = 0`` they still depend on ``phi_d``, so a
convention is needed there (:func:`nbrdf_input`).
"""

from __future__ import annotations

import base64
import binascii
import json
from dataclasses import dataclass
from os import PathLike
from pathlib import Path

import h5py
import numpy as np
from array_api_compat import array_namespace, device
from tqdm.auto import tqdm

from neuralbrdf.atomic import note_input
from neuralbrdf.data.plans import plan_label, plan_spherical
from neuralbrdf.data.table import BrdfTable
from neuralbrdf.errors import InputError
from neuralbrdf.limits import MAX_JSON_BYTES, check_file_size, file_problem
from neuralbrdf.geometry import half_diff_vectors, normalize, spherical_pair_to_vectors

#: The report's five MERL materials: latent-fitting test materials, never pretraining data.
REPORT_MATERIALS = (
    "tungsten-carbide",
    "nylon",
    "brass",
    "blue-acrylic",
    "specular-black-phenolic",
)

#: ``(units, activation)`` of the three Dense layers, in order (paper §3.1).
DENSE_LAYERS = ((21, "relu"), (21, "relu"), (3, "linear"))
INPUT_SIZE = 6

#: Rows evaluated at once; bounds the intermediate activations to a few tens of MB.
CHUNK_ROWS = 2**18


@dataclass(frozen=True, eq=False)
class NbrdfNetwork:
    """Frozen weights of one NBRDF network.

    Attributes
    ----------
    name:
        Material name (the file stem, e.g. ``"brass"``).
    kernels:
        Three read-only float64 arrays of shapes ``[6, 21]``, ``[21, 21]``, ``[21, 3]``
        (Keras row-vector convention ``y = x @ kernel + bias``).
    biases:
        Three read-only float64 arrays of shapes ``[21]``, ``[21]``, ``[3]``.
    source:
        The ``.h5`` file the weights came from.
    """

    name: str
    kernels: tuple[np.ndarray, ...]
    biases: tuple[np.ndarray, ...]
    source: str = "<memory>"

    @classmethod
    def load(cls, path: str | PathLike[str]) -> NbrdfNetwork:
        """Read ``NAME.h5`` + ``NAME.json``; ``path`` may name either file of the pair.

        Raises :class:`InputError` naming the file and the key or dataset when a file is
        missing or unreadable, the architecture is not the NBRDF one, or a weight is missing,
        of the wrong shape or not finite.
        """
        path = Path(path)
        if path.suffix not in (".h5", ".json"):
            raise InputError("expected an NBRDF weight file NAME.h5 or NAME.json", path=path)
        h5_path, json_path = path.with_suffix(".h5"), path.with_suffix(".json")
        for file in (h5_path, json_path):
            if not file.is_file():
                where = "" if file.is_absolute() else f" at {file.resolve()} (relative to the folder the command runs in)"
                raise InputError(file_problem(file) or f"file not found{where}; an NBRDF network needs both NAME.h5 "
                                 "and NAME.json", path=file)
        note_input(h5_path)
        note_input(json_path)
        check_file_size(json_path, MAX_JSON_BYTES, "NBRDF architecture file")
        layer_names = _read_architecture(json_path)
        kernels, biases = _read_weights(h5_path, layer_names)
        return cls(name=h5_path.stem, kernels=kernels, biases=biases, source=str(h5_path))

    def forward(self, x):
        """Raw network output ``exp(mlp(x)) - 1``, ``[N, 3]``, of inputs ``[N, 6]`` (no clamp)."""
        xp = array_namespace(x)
        for layer, (kernel, bias) in enumerate(zip(self.kernels, self.biases)):
            kernel = xp.asarray(kernel, dtype=x.dtype, device=device(x), copy=True)
            bias = xp.asarray(bias, dtype=x.dtype, device=device(x), copy=True)
            x = x @ kernel + bias
            if DENSE_LAYERS[layer][1] == "relu":
                x = xp.clip(x, 0.0, None)
        return xp.exp(x) - 1.0

    def evaluate(self, wi, wo, *, chunk_rows: int = CHUNK_ROWS, progress: bool = False):
        """RGB BRDF in sr⁻¹ of direction pairs ``wi, wo`` (``[..., 3]``, broadcast together).

        Returns ``[..., 3]`` in the inputs' namespace and dtype: the network output clamped at
        0, exactly 0 where ``wi_z <= 0`` or ``wo_z <= 0``.  Rows are pushed through the network
        ``chunk_rows`` at a time (with a tqdm bar over chunks if ``progress``).  Calling the
        network is the same as calling this method.
        """
        xp = array_namespace(wi, wo)
        wi, wo = xp.broadcast_arrays(wi, wo)
        if wi.shape[-1] != 3:
            raise InputError(f"directions must have shape [..., 3], got {tuple(wi.shape)}")
        batch_shape = wi.shape[:-1]
        wi = xp.reshape(wi, (-1, 3))
        wo = xp.reshape(wo, (-1, 3))
        starts = range(0, max(wi.shape[0], 1), chunk_rows)  # one (empty) chunk for no rows
        chunks = [
            self.forward(nbrdf_input(wi[s : s + chunk_rows], wo[s : s + chunk_rows]))
            for s in tqdm(starts, desc=f"NBRDF {self.name}", unit="chunk", disable=not progress)
        ]
        f = xp.concat(chunks, axis=0)
        above = (wi[:, 2] > 0) & (wo[:, 2] > 0)
        f = xp.where(above[:, None], xp.clip(f, 0.0, None), xp.zeros_like(f))
        return xp.reshape(f, (*batch_shape, 3))

    __call__ = evaluate


def nbrdf_input(wi, wo):
    """Network input ``[..., 6] = (sin theta_h, 0, cos theta_h, d_x, d_y, d_z)`` of unit pairs.

    ``h`` and ``d`` are the Rusinkiewicz half and difference vectors
    (:func:`neuralbrdf.geometry.half_diff_vectors`); ``h`` is fed rotated to ``phi_h = 0``.
    Inputs are normalised first.  At the mirror configuration ``phi_h = phi_i`` (see
    :func:`~neuralbrdf.geometry.half_diff_vectors`): the networks are not ``phi_d``-invariant
    there, so the convention matters.
    """
    xp = array_namespace(wi, wo)
    h, d = half_diff_vectors(normalize(wi), normalize(wo))
    sin_th = xp.sqrt(h[..., 0] ** 2 + h[..., 1] ** 2)
    half = xp.stack([sin_th, xp.zeros_like(sin_th), h[..., 2]], axis=-1)
    return xp.concat([half, d], axis=-1)


def sample_directions(
    network: NbrdfNetwork,
    theta_i,
    phi_i,
    theta_o,
    phi_o,
    *,
    progress: bool = False,
    source: str | None = None,
) -> BrdfTable:
    """RGB :class:`BrdfTable` of ``network`` at spherical angle arrays (degrees, ``[N]``)."""
    angles = [np.asarray(a, dtype=np.float64).ravel() for a in (theta_i, phi_i, theta_o, phi_o)]
    wi, wo = spherical_pair_to_vectors(*angles)
    values = network.evaluate(wi, wo, progress=progress)
    return BrdfTable(*angles, values=values, source=source or f"nbrdf:{network.name}")


def sample_plan(network: NbrdfNetwork, plan_name: str, progress: bool = False) -> BrdfTable:
    """RGB :class:`BrdfTable` of ``network`` on a sampling plan of docs/measure.md#sampling-plans (e.g. ``"DS1"``)."""
    return sample_directions(
        network,
        *plan_spherical(plan_name),
        progress=progress,
        source=f"nbrdf:{network.name}:{plan_label(plan_name)}",
    )


def available_materials(data_dir: str | PathLike[str]) -> tuple[str, ...]:
    """Sorted material names (stems of ``*.h5``) in an NBRDF folder such as ``merl-nbrdf/``."""
    data_dir = Path(data_dir)
    if not data_dir.is_dir():
        raise InputError("NBRDF folder not found", path=data_dir)
    return tuple(sorted(p.stem for p in data_dir.glob("*.h5")))


def _read_architecture(json_path: Path) -> tuple[str, ...]:
    """Check the Keras model JSON is the NBRDF network; return the Dense layer names."""
    try:
        model = json.loads(json_path.read_text(encoding="utf-8"))
    except UnicodeDecodeError as err:
        raise InputError(f"not UTF-8 text: {err}", path=json_path) from None
    except json.JSONDecodeError as err:
        raise InputError(
            f"invalid JSON: {err.msg} (column {err.colno})", path=json_path, line=err.lineno
        ) from None

    def field(obj, where: str, key: str):
        if not isinstance(obj, dict) or key not in obj:
            raise InputError("missing key", path=json_path, key=f"{where}{key}")
        return obj[key]

    def expect(found, expected, key: str) -> None:
        if found != expected:
            raise InputError(
                f"expected {expected!r}, found {found!r}", path=json_path, key=key
            )

    expect(field(model, "", "class_name"), "Sequential", "class_name")
    layers = field(field(model, "", "config"), "config.", "layers")
    if not isinstance(layers, list):
        raise InputError("expected a list of layers", path=json_path, key="config.layers")
    classes = [field(layer, f"config.layers[{i}].", "class_name") for i, layer in enumerate(layers)]
    expect(classes, ["Dense"] * len(DENSE_LAYERS) + ["Lambda"], "config.layers")

    configs = [field(layer, f"config.layers[{i}].", "config") for i, layer in enumerate(layers)]
    where = [f"config.layers[{i}].config." for i in range(len(layers))]
    expect(field(configs[0], where[0], "batch_input_shape"), [None, INPUT_SIZE],
           f"{where[0]}batch_input_shape")
    names = []
    for config, at, (units, activation) in zip(configs, where, DENSE_LAYERS):
        for key, value in (("units", units), ("activation", activation), ("use_bias", True)):
            expect(field(config, at, key), value, at + key)
        name = field(config, at, "name")
        if not isinstance(name, str) or not name:
            raise InputError(f"expected a layer name, found {name!r}", path=json_path,
                             key=f"{at}name")
        names.append(name)
    if not _lambda_calls_exp(field(configs[-1], where[-1], "function")):
        raise InputError("expected a Keras lambda computing exp(x) - 1", path=json_path,
                         key=f"{where[-1]}function")
    return tuple(names)


def _lambda_calls_exp(function) -> bool:
    """Whether a serialised Keras Lambda (base64 marshalled bytecode) refers to ``exp``.

    The bytecode is not executed or unmarshalled (unsafe and Python-version specific); the
    ``exp`` name in its symbol table is the check available for ``lambda x: K.exp(x) - 1``.
    """
    if not isinstance(function, list) or not function or not isinstance(function[0], str):
        return False
    try:
        code = base64.b64decode(function[0], validate=False)
    except (binascii.Error, ValueError):
        return False
    return b"exp" in code


def _read_weights(h5_path: Path, layer_names) -> tuple[tuple[np.ndarray, ...], ...]:
    """Kernels and biases of the Dense layers, checked for shape and finiteness (float64)."""
    kernels, biases = [], []
    try:
        with h5py.File(h5_path, "r") as weights:
            fan_in = INPUT_SIZE
            for name, (units, _) in zip(layer_names, DENSE_LAYERS):
                kernels.append(_read_dataset(weights, h5_path, f"{name}/{name}/kernel:0",
                                             (fan_in, units)))
                biases.append(_read_dataset(weights, h5_path, f"{name}/{name}/bias:0", (units,)))
                fan_in = units
    except OSError as err:
        raise InputError(f"not a readable HDF5 weight file: {err}", path=h5_path) from None
    return tuple(kernels), tuple(biases)


def _read_dataset(weights: h5py.File, h5_path: Path, key: str, shape: tuple[int, ...]):
    dataset = weights.get(key)
    if not isinstance(dataset, h5py.Dataset):
        raise InputError(f"missing dataset, expected a float array of shape {shape}",
                         path=h5_path, key=key)
    if dataset.shape != shape or dataset.dtype.kind != "f":
        raise InputError(
            f"expected a float array of shape {shape}, found {dataset.dtype} {dataset.shape}",
            path=h5_path, key=key,
        )
    values = np.asarray(dataset[()], dtype=np.float64)
    if not np.all(np.isfinite(values)):
        raise InputError("weights must be finite, found NaN or infinity", path=h5_path,
                         key=key)
    values.setflags(write=False)
    return values
