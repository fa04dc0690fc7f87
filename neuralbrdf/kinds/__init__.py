"""Model kinds: one module per kind, found by the registry here (docs/models.md, docs/formats.md#onnx-model-files).

A *kind* is what a model file or checkpoint is: ``spectral_mlp`` (the report's §5 network),
``nlb`` (a latent fit of the NLB network, docs/models.md#nlb), ``nlb_spectral`` (the spectral
NLB's), ``abc`` (Löw et al. 2012, docs/models.md#abc), ``auto`` (the better of ABC and the spectral
NLB on the measured samples, docs/models.md#auto), ``pca`` (Nielsen et al. 2015, docs/models.md#pca),
``reference`` (a ground-truth material, docs/evaluate.md#ground-truths), ``table`` (a baked ladder
rung).  Each lives in one module of this package that defines ``KIND``, a :class:`Kind` saying

* its name (the ``neuralbrdf.kind`` entry of an ``.onnx`` file and the ``neuralbrdf_kind``
  entry of a checkpoint, :data:`CHECKPOINT_KIND_KEY`);
* whether its models must be spectral;
* how to read and check its own metadata entries (``neuralbrdf.<kind>.*``);
* the sampling proposal the Mitsuba plugin draws directions from, by name (a GGX mixture
  fitted to the model for the neural kinds, the analytic lobe for ABC;
  :data:`neuralbrdf.render.sampling.PROPOSALS`);
* how to turn one of its checkpoints into an :class:`Exportable`.

A new kind is one new module here: the registry imports every module of the package on first
use.  Generic evaluation (onnxruntime, the Dr.Jit interpreter) reads the ``.onnx`` graph and
needs nothing from the kind.

:func:`load_model` is the full contract check of a file and :func:`contract_metadata` builds a
file's metadata the same way (the generic part of :mod:`neuralbrdf.onnx_contract` and the
kind's own); :func:`load_exportable`
gives a checkpoint's model to the exporter (:mod:`neuralbrdf.onnx_export`).  This module sits
below the exporter and the renderer: it imports neither.  Kind modules import PyTorch only inside
their checkpoint loaders, so that checking a file (what the renderer does at scene load) stays
light.
"""

from __future__ import annotations

import dataclasses
import importlib
import json
import os
import pkgutil
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

from neuralbrdf import onnx_contract
from neuralbrdf.errors import InputError, one_line
from neuralbrdf.onnx_contract import OnnxModel

if TYPE_CHECKING:
    from torch import nn

#: Checkpoint entry naming the kind; written by every Lightning module of a fitted model
#: (:class:`neuralbrdf.lightning.common.WritesKind`).
CHECKPOINT_KIND_KEY = "neuralbrdf_kind"


def _no_details(metadata: Mapping[str, str], path, is_spectral: bool) -> None:
    return None


@dataclass(frozen=True)
class Exportable:
    """A model ready to trace: the module, its contract metadata and whether it is spectral."""

    module: nn.Module
    kind: str
    material: str
    metadata: dict[str, str]
    wavelength_range_nm: tuple[float, float] | None

    @property
    def is_spectral(self) -> bool:
        return self.wavelength_range_nm is not None



@dataclass(frozen=True)
class Kind:
    """One model kind (module docstring).

    Attributes
    ----------
    name:
        The kind's name in files; a Python identifier.
    summary:
        One line for help texts and error messages.
    spectral_only:
        Its models must take a ``wavelength`` input.
    read_metadata:
        ``(metadata, path, is_spectral) -> details``: checks the kind's own ``neuralbrdf.<kind>.*``
        entries and returns what it read (stored as :attr:`~neuralbrdf.onnx_contract.OnnxModel.details`), raising
        :class:`InputError` naming the file and key.
    proposal:
        The name of the renderer's sampling proposal (:data:`neuralbrdf.render.sampling.PROPOSALS`),
        fitted at scene load from the model and its :attr:`~neuralbrdf.onnx_contract.OnnxModel.details`.
    from_checkpoint:
        ``(checkpoint, path, material) -> Exportable`` for kinds trained by this library; ``None``
        for kinds that are written directly (``reference``).
    recognises:
        ``checkpoint -> bool`` for checkpoints written before :data:`CHECKPOINT_KIND_KEY` existed.
    scalar_parameters:
        Fitted values the graph holds as scalar constants rather than weight tensors (ABC's
        ``B``, ``C``, ``η``), so that a parameter count can include them.
    fast_by_default:
        ``neuralbrdf export`` adds the fast path ``f_fast`` to its models unless told not to
        (``--no-fast``): for kinds whose full network renders well above analytic cost.
    wants_fast:
        ``metadata -> bool``, for kinds whose files differ in that (``auto``: as the chosen kind);
        when given it decides instead of ``fast_by_default`` (:meth:`fast_default`).
    """

    name: str
    summary: str
    spectral_only: bool = False
    read_metadata: Callable[[Mapping[str, str], object, bool], object] = _no_details
    proposal: str = "fitted_ggx"
    from_checkpoint: Callable[[dict, Path, str | None], Exportable] | None = None
    recognises: Callable[[dict], bool] | None = None
    scalar_parameters: int = 0
    fast_by_default: bool = False
    wants_fast: Callable[[Mapping[str, str]], bool] | None = None

    def fast_default(self, metadata: Mapping[str, str]) -> bool:
        """Whether ``neuralbrdf export`` adds ``f_fast`` to a file of this kind with ``metadata`` unasked."""
        return self.wants_fast(metadata) if self.wants_fast is not None else self.fast_by_default


_REGISTRY: dict[str, Kind] = {}


def _discover() -> dict[str, Kind]:
    """The registry, filled on first use from every module of this package (all or nothing)."""
    if not _REGISTRY:
        found: dict[str, Kind] = {}
        for module_info in sorted(pkgutil.iter_modules(__path__), key=lambda m: m.name):
            module = importlib.import_module(f"{__name__}.{module_info.name}")
            kind = getattr(module, "KIND", None)
            if not isinstance(kind, Kind):
                raise TypeError(f"{module.__name__} defines no KIND = Kind(...)")
            if kind.name in found:
                raise TypeError(f"kind {kind.name!r} is defined twice ({module.__name__})")
            found[kind.name] = kind
        _REGISTRY.update(found)
    return _REGISTRY


def names() -> list[str]:
    """The registered kinds' names, sorted."""
    return sorted(_discover())


def get(name: str, path: str | os.PathLike[str] | None = None, key: str | None = None) -> Kind:
    """The kind called ``name``, else :class:`InputError` listing the registered ones."""
    kinds = _discover()
    if name not in kinds:
        raise InputError(f"unknown model kind {name!r}; expected one of {names()}", path=path, key=key)
    return kinds[name]


# --------------------------------------------------------------------------- model files


def load_model(path: str | os.PathLike[str]) -> OnnxModel:
    """``path`` checked against the whole contract: the shared part and its kind's own.

    Raises :class:`InputError` naming the file for everything
    :func:`neuralbrdf.onnx_contract.load_generic_model` refuses, an unregistered kind, a
    non-spectral model of a spectral-only kind, and bad kind-specific metadata.
    """
    model = onnx_contract.load_generic_model(path)
    details = _kind_details(model.kind, model.metadata, model.path, model.is_spectral)
    return dataclasses.replace(model, details=details)


def contract_metadata(
    kind: str,
    material: str,
    provenance: str,
    *,
    wavelength_range_nm: tuple[float, float] | None = None,
    kind_metadata: Mapping[str, str] | None = None,
) -> dict[str, str]:
    """A file's ``metadata_props``: :func:`~neuralbrdf.onnx_contract.generic_metadata` checked as
    :func:`load_model` checks it (``kind`` registered, spectral where it must be, its own entries
    ``kind_metadata`` valid); :class:`InputError` otherwise."""
    metadata = onnx_contract.generic_metadata(
        kind, material, provenance, wavelength_range_nm=wavelength_range_nm, kind_metadata=kind_metadata
    )
    _kind_details(kind, metadata, "<metadata>", wavelength_range_nm is not None)
    return metadata


def _kind_details(name: str, metadata: Mapping[str, str], path, is_spectral: bool) -> object:
    kind = get(name, path=path, key=onnx_contract.KIND_KEY)
    if kind.spectral_only and not is_spectral:
        raise InputError(f"a {kind.name} model must take a 'wavelength' input", path=path)
    return kind.read_metadata(metadata, path, is_spectral)


# --------------------------------------------------------------------------- checkpoints


def module_class_name(checkpoint: dict) -> str:
    """The class name of the LightningModule that wrote ``checkpoint`` (``""`` when not recorded)."""
    class_path = str((checkpoint.get("hyper_parameters") or {}).get("_class_path", ""))
    return class_path.rsplit(".", 1)[-1]


def checkpoint_kind(checkpoint: dict, path: str | os.PathLike[str]) -> Kind:
    """The kind of a checkpoint: its :data:`CHECKPOINT_KIND_KEY` entry, else its layout."""
    name = checkpoint.get(CHECKPOINT_KIND_KEY)
    trained = [kind for kind in _discover().values() if kind.from_checkpoint is not None]
    if name is None:
        name = next((kind.name for kind in trained if kind.recognises and kind.recognises(checkpoint)), None)
    expected = sorted(kind.name for kind in trained)
    if name is None or name not in {kind.name for kind in trained}:
        found = "no such key" if name is None else repr(name)
        raise InputError(
            f"unknown checkpoint kind ({found}); expected one of {expected}", path=path, key=CHECKPOINT_KIND_KEY
        )
    return get(name)


def _compact_json(value) -> str:
    def clean(v):
        if isinstance(v, dict):
            return {k: clean(x) for k, x in v.items() if k != "_instantiator"}
        if isinstance(v, (list, tuple)):
            return [clean(x) for x in v]
        return v if isinstance(v, (str, int, float, bool, type(None))) else str(v)

    return json.dumps(clean(value), sort_keys=True, separators=(",", ":"))


def provenance(checkpoint: dict, path: Path) -> str:
    """Short provenance of an export: checkpoint file, epoch/step, model and data configuration."""
    parts = [f"checkpoint {path.name}"]
    if "epoch" in checkpoint:
        parts.append(f"epoch {checkpoint['epoch']} step {checkpoint.get('global_step', '?')}")
    if "pretrained_network" in checkpoint:  # a latent fit: the network it was fitted on
        parts.append(f"pretrained network {checkpoint['pretrained_network']}")
    for key, label in (("hyper_parameters", "model"), ("datamodule_hyper_parameters", "data")):
        if checkpoint.get(key):
            parts.append(f"{label} {_compact_json(dict(checkpoint[key]))}")
    return "; ".join(parts)


def pick_material(available: list[str], requested: str | None, path: str | os.PathLike[str]) -> str:
    """``requested`` if the checkpoint holds it, the only material when ``None``, else :class:`InputError`."""
    if requested is None:
        if len(available) != 1:
            raise InputError(
                f"the checkpoint holds {len(available)} materials {available}; choose one with --material", path=path
            )
        return available[0]
    if requested not in available:
        raise InputError(f"no material {requested!r} in the checkpoint; it holds {available}", path=path)
    return requested


def load_exportable(ckpt: str | os.PathLike[str], material: str | None = None) -> Exportable:
    """The model of checkpoint ``ckpt`` as a function of directions, with its contract metadata."""
    from neuralbrdf.checkpoints import read_checkpoint

    path = Path(ckpt)
    checkpoint = read_checkpoint(path)
    kind = checkpoint_kind(checkpoint, path)
    try:
        exportable = kind.from_checkpoint(checkpoint, path, material)
    except InputError as error:
        if error.path is None:  # raised by a constructor that does not know the file
            raise InputError(error.reason, path=path, column=error.column, key=error.key) from None
        raise
    except (KeyError, TypeError, ValueError, RuntimeError, AttributeError) as error:
        # load_state_dict and friends on a checkpoint of the right kind but wrong content
        raise InputError(f"not a valid {kind.name} checkpoint ({one_line(error)})", path=path) from None
    exportable.module.eval().requires_grad_(False)
    return exportable


