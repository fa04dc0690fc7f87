"""Files shipped inside the package: the pretrained NLB networks (docs/models.md#nlb).

A pretrained network is named by a path or by the stem of a shipped file (``nlb_compact``,
``nlb_64x4``, ``nlb_latent32_blends``, ``nlb_spectral``, …); ``None`` is the default of the fit
that asks: ``nlb_latent32_blends`` for the RGB NLB (the 48×3 network with latent 32, pretrained
with proxy blends), ``nlb_spectral`` for the spectral NLB.  Resolving a name touches no model
code, so callers that only need the file (a study's cache keys) do not import PyTorch.
"""

from __future__ import annotations

from pathlib import Path

#: Where the shipped pretrained checkpoints live.
PRETRAINED_DIR = Path(__file__).resolve().parent / "pretrained"
#: The latent fit's default network.
PRETRAINED_DEFAULT = PRETRAINED_DIR / "nlb_latent32_blends.ckpt"
#: The spectral NLB fit's default network (:mod:`neuralbrdf.lightning.nlb_spectral_fit`).
SPECTRAL_DEFAULT = PRETRAINED_DIR / "nlb_spectral.ckpt"


def resolve_pretrained(checkpoint: str | None, default: Path = PRETRAINED_DEFAULT) -> Path:
    """The file of ``checkpoint``: ``default`` for ``None``, a shipped network for its stem when
    no such path exists, else the path as given (which may not exist: the loader says so)."""
    if checkpoint is None:
        return default
    path = Path(checkpoint)
    shipped = PRETRAINED_DIR / f"{checkpoint}.ckpt"
    return shipped if not path.is_file() and shipped.is_file() else path
