"""Files shipped inside the package: the pretrained NLB networks (SPEC §4.2).

A pretrained network is named by a path or by the stem of a shipped file (``nlb_compact``,
``nlb_64x4``, ``nlb_latent32_blends``, …); ``None`` is the default, ``nlb_latent32_blends`` (the
48×3 network with latent 32, pretrained with proxy blends; README, *NLB latent prior*).  Resolving a name touches no model
code, so callers that only need the file (a study's cache keys) do not import PyTorch.
"""

from __future__ import annotations

from pathlib import Path

#: Where the shipped pretrained checkpoints live.
PRETRAINED_DIR = Path(__file__).resolve().parent / "pretrained"
#: The latent fit's default network.
PRETRAINED_DEFAULT = PRETRAINED_DIR / "nlb_latent32_blends.ckpt"


def resolve_pretrained(checkpoint: str | None) -> Path:
    """The file of ``checkpoint``: the default for ``None``, a shipped network for its stem when
    no such path exists, else the path as given (which may not exist: the loader says so)."""
    if checkpoint is None:
        return PRETRAINED_DEFAULT
    path = Path(checkpoint)
    shipped = PRETRAINED_DIR / f"{checkpoint}.ckpt"
    return shipped if not path.is_file() and shipped.is_file() else path
