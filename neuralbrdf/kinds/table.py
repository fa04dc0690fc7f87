"""Kind ``table``: a model baked into a table over Rusinkiewicz angles (and wavelength), read by
multilinear interpolation (:class:`~neuralbrdf.models.baked_table.BakedTable`; docs/select.md).

Made by ``neuralbrdf ladder`` from another model file (:func:`neuralbrdf.lod.distill.bake_table`),
never trained, so no checkpoint.  Its own metadata entry ``neuralbrdf.table.nodes`` gives the
node counts, ``"n_h x n_d x n_p"`` plus ``" x n_λ"`` for spectral tables.  Sampled with a GGX
mixture fitted to it like the neural kinds (a ladder's selector gives it its parent's instead).
"""

from __future__ import annotations

from collections.abc import Mapping

from neuralbrdf.errors import InputError
from neuralbrdf.kinds import Kind
from neuralbrdf.onnx_contract import kind_key

NAME = "table"
NODES_KEY = kind_key(NAME, "nodes")


def nodes_text(nodes: tuple[int, ...]) -> str:
    return " x ".join(str(n) for n in nodes)


def read_nodes(metadata: Mapping[str, str], path, is_spectral: bool) -> tuple[int, ...]:
    """The node counts of ``neuralbrdf.table.nodes``, checked (module docstring)."""
    expected = 4 if is_spectral else 3
    text = metadata.get(NODES_KEY)
    if text is None:
        raise InputError("a table model names its node counts", path=path, key=NODES_KEY)
    try:
        nodes = tuple(int(part) for part in text.split("x"))
    except ValueError:
        nodes = ()
    if len(nodes) != expected or min(nodes) < 2:
        raise InputError(f"expected {expected} node counts >= 2 like '32 x 16 x 8{' x 16' if is_spectral else ''}', "
                         f"got {text!r}", path=path, key=NODES_KEY)
    return nodes


KIND = Kind(
    name=NAME,
    summary="a model baked into a table over Rusinkiewicz angles, interpolated multilinearly (docs/select.md)",
    read_metadata=read_nodes,
)
