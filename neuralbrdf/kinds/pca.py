"""Kind ``pca``: a material fitted in the PCA basis of measured BRDFs (Nielsen, Jensen &
Ramamoorthi 2015; docs/models.md#pca), baked into a table over Rusinkiewicz angles (and
wavelength) read by multilinear interpolation.

The graph is the fitted material's :class:`~neuralbrdf.models.pca_brdf.PcaTable`: its mapped
values ``ln(1 + f)`` read from a :class:`~neuralbrdf.models.baked_table.BakedTable` (the ``table``
kind's graph) and unmapped, ``f = expm1(y)`` — a table read and one exponential per channel,
rendered on the Dr.Jit path like any table.  Checkpoints come from
:class:`~neuralbrdf.lightning.pca_fit.PcaFitModule`.  Beside the graph the file says what it was
fitted with:

===================================  =======================================================
key                                  value
===================================  =======================================================
``neuralbrdf.pca.components``        the number of principal components ``K`` (>= 1)
``neuralbrdf.pca.ridge``             the ridge weight ``λ`` (>= 0)
``neuralbrdf.pca.basis_sha256``      sha256 of the basis file (64 hex digits)
``neuralbrdf.pca.nodes``             the table's node counts, ``"n_h x n_d x n_p"`` plus
                                     ``" x n_λ"`` for spectral models (as ``neuralbrdf.table.nodes``)
===================================  =======================================================

Sampled with a GGX mixture fitted to the model, like the neural kinds and tables.
"""

from __future__ import annotations

import re
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path

from neuralbrdf.errors import InputError
from neuralbrdf.kinds import Exportable, Kind, contract_metadata, pick_material, provenance
from neuralbrdf.kinds import table as table_kind
from neuralbrdf.onnx_contract import kind_key, metadata_float

NAME = "pca"
COMPONENTS_KEY = kind_key(NAME, "components")
RIDGE_KEY = kind_key(NAME, "ridge")
SHA256_KEY = kind_key(NAME, "basis_sha256")
NODES_KEY = kind_key(NAME, "nodes")
KEYS = (COMPONENTS_KEY, RIDGE_KEY, SHA256_KEY, NODES_KEY)
#: What a checkpoint of this kind holds (:mod:`neuralbrdf.lightning.pca_fit`).
CHECKPOINT_KEYS = ("material", "pca_mapped", "pca_mapping", "pca_epsilon", "pca_wavelength_range_nm",
                   "pca_components", "pca_ridge", "pca_basis_sha256")


@dataclass(frozen=True)
class PcaMetadata:
    """What a ``pca`` file says of its fit (module docstring)."""

    components: int
    ridge: float
    basis_sha256: str
    nodes: tuple[int, ...]

    def entries(self) -> dict[str, str]:
        """The file's ``neuralbrdf.pca.*`` metadata entries."""
        return {COMPONENTS_KEY: str(int(self.components)), RIDGE_KEY: repr(float(self.ridge)),
                SHA256_KEY: self.basis_sha256, NODES_KEY: table_kind.nodes_text(self.nodes)}


def read_metadata(metadata: Mapping[str, str], path, is_spectral: bool) -> PcaMetadata:
    """The fit's entries, checked, else :class:`InputError` naming the key."""
    missing = [key for key in KEYS if key not in metadata]
    if missing:
        raise InputError(f"PCA model lacks metadata keys {missing}", path=path)
    text = metadata[COMPONENTS_KEY]
    if not re.fullmatch(r"[0-9]+", text.strip()) or int(text) < 1:
        raise InputError(f"expected an integer >= 1, got {text!r}", path=path, key=COMPONENTS_KEY)
    ridge = metadata_float(metadata, RIDGE_KEY, path)
    if ridge < 0:
        raise InputError(f"metadata value {ridge!r} must be >= 0", path=path, key=RIDGE_KEY)
    sha256 = metadata[SHA256_KEY].strip()
    if not re.fullmatch(r"[0-9a-f]{64}", sha256):
        raise InputError(f"expected 64 lowercase hex digits, got {sha256!r}", path=path, key=SHA256_KEY)
    try:
        nodes = table_kind.read_nodes({table_kind.NODES_KEY: metadata[NODES_KEY]}, path, is_spectral)
    except InputError as error:
        raise InputError(error.reason, path=path, key=NODES_KEY) from None
    return PcaMetadata(int(text), ridge, sha256, nodes)


def from_checkpoint(checkpoint: dict, path: Path, material: str | None) -> Exportable:
    import torch

    from neuralbrdf.models.pca_brdf import PcaTable

    for key in CHECKPOINT_KEYS:
        if key not in checkpoint:
            raise InputError("PCA checkpoint lacks this key", path=path, key=key)
    name = pick_material([str(checkpoint["material"])], material, path)
    mapped = torch.as_tensor(checkpoint["pca_mapped"], dtype=torch.float32)
    wavelength_range = checkpoint["pca_wavelength_range_nm"]
    wavelength_range = None if wavelength_range is None else tuple(float(w) for w in wavelength_range)
    try:
        module = PcaTable(mapped, wavelength_range, str(checkpoint["pca_mapping"]), float(checkpoint["pca_epsilon"]))
    except ValueError as error:
        raise InputError(f"the checkpoint's table is not valid ({error})", path=path, key="pca_mapped") from None
    stored = PcaMetadata(int(checkpoint["pca_components"]), float(checkpoint["pca_ridge"]),
                         str(checkpoint["pca_basis_sha256"]), module.nodes)
    metadata = contract_metadata(NAME, name, provenance(checkpoint, path), wavelength_range_nm=wavelength_range,
                                 kind_metadata=stored.entries())
    return Exportable(module, NAME, name, metadata, wavelength_range)


KIND = Kind(
    name=NAME,
    summary="a material fitted in a PCA basis of measured BRDFs by ridge least squares, baked into a table "
            "over Rusinkiewicz angles (docs/models.md#pca)",
    read_metadata=read_metadata,
    from_checkpoint=from_checkpoint,
    recognises=lambda checkpoint: "pca_mapped" in checkpoint,
)
