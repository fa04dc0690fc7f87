"""Bake a model file into a table (docs/select.md): the ``table_*`` rungs of a cost ladder.

:func:`bake_table` evaluates the parent (onnxruntime) at every node of a
:class:`~neuralbrdf.models.baked_table.BakedTable` — the Rusinkiewicz angle grid of
:func:`~neuralbrdf.models.baked_table.node_directions`, times the wavelength nodes of a spectral
parent — and wraps the values as a ``table`` model (:mod:`neuralbrdf.kinds.table`).  Nodes whose
directions reach below the horizon are evaluated at the horizon
(:func:`~neuralbrdf.models.baked_table.lifted`): an interpolated query next to the horizon then
blends grazing values, not zeros.  Point values at nodes, not a fit: the error between nodes is
the interpolation error, which the ladder measures against the parent over the hemisphere.
"""

from __future__ import annotations

import numpy as np
import torch

from neuralbrdf.kinds import Exportable, contract_metadata
from neuralbrdf.kinds.table import NAME, NODES_KEY, nodes_text
from neuralbrdf.models.baked_table import BakedTable, bake_values


def bake_table(evaluator, nodes: tuple[int, ...], material: str, provenance: str) -> Exportable:
    """A ``table`` model of ``evaluator`` (an :class:`~neuralbrdf.evaluation.scores.OnnxEvaluator`)
    with ``nodes`` = ``(n_h, n_d, n_p)`` for RGB parents, ``(n_h, n_d, n_p, n_λ)`` for spectral ones."""
    wavelength_range = evaluator.model.wavelength_range_nm if evaluator.is_spectral else None
    nodes = tuple(int(n) for n in nodes[: 4 if evaluator.is_spectral else 3])
    values = bake_values(evaluator, nodes, wavelength_range)
    if not np.all(np.isfinite(values)):
        raise ValueError(f"the parent is not finite at {int(np.sum(~np.isfinite(values)))} table nodes")
    module = BakedTable(torch.as_tensor(np.clip(values, 0.0, None), dtype=torch.float32), wavelength_range)
    metadata = contract_metadata(NAME, material, provenance, wavelength_range_nm=wavelength_range,
                                 kind_metadata={NODES_KEY: nodes_text(nodes)})
    return Exportable(module, NAME, material, metadata, wavelength_range)
