"""Kind ``reference``: a ground-truth material written by ``neuralbrdf export-truth`` (docs/evaluate.md#ground-truths).

A virtual material's own formula (spectral) or an NBRDF proxy network (RGB) on directions
(:mod:`neuralbrdf.evaluation.truth`).  Not trained here, so no checkpoint; sampled with a GGX
mixture fitted to it like the neural kinds.
"""

from neuralbrdf.kinds import Kind

KIND = Kind(name="reference", summary="a ground-truth material for evaluation (docs/evaluate.md#ground-truths)")
