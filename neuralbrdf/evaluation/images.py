"""Image metrics of a render against the render of the truth (docs/evaluate.md).

Both images are linear sRGB ``[H, W, 3]`` rendered with the same scene, seeds and passes.

* ``image_rel_mse`` — ``Σ (m − t)² / Σ t²`` over every pixel and channel of the linear images
  (unitless; 0 for identical images, 1 for a black model);
* ``image_psnr`` — ``10 log10(1 / MSE)`` dB of the *displayed* images: clipped to [0, 1] and
  sRGB-encoded (IEC 61966-2-1 transfer function), as the PNG a person looks at; infinite (``None``
  in JSON) for identical images;
* ``image_delta_e2000_mean`` and ``image_delta_e2000_p95`` — CIEDE2000 (Sharma et al. 2005)
  per pixel, mean and 95th percentile, computed by colour-science on CIE L*a*b* (D65 white,
  the sRGB white point) of the clipped linear images: 1 is about a just-noticeable difference.

Clipping at 1 follows what the display shows: two highlights that both saturate differ by
nothing visible, and ``image_rel_mse`` (unclipped) is reported beside them.
"""

from __future__ import annotations

import colour
import numpy as np

#: The fixed names of the image metrics.
IMAGE_METRICS = ("image_rel_mse", "image_psnr", "image_delta_e2000_mean", "image_delta_e2000_p95")

_SRGB = colour.RGB_COLOURSPACES["sRGB"]


def _checked(name: str, image) -> np.ndarray:
    image = np.asarray(image, dtype=np.float64)
    if image.ndim != 3 or image.shape[-1] != 3:
        raise ValueError(f"{name} must be an [H, W, 3] linear RGB image, got shape {image.shape}")
    if not np.all(np.isfinite(image)):
        raise ValueError(f"{name} holds non-finite pixels")
    return image


def displayed(image) -> np.ndarray:
    """What a display shows of a linear sRGB image: clipped to [0, 1], sRGB-encoded (IEC 61966-2-1)."""
    return np.clip(_SRGB.cctf_encoding(np.clip(image, 0.0, 1.0)), 0.0, 1.0)


def linear_srgb_to_lab(image) -> np.ndarray:
    """CIE L*a*b* (D65) of a linear sRGB image clipped to [0, 1]."""
    xyz = colour.RGB_to_XYZ(np.clip(image, 0.0, 1.0), _SRGB, apply_cctf_decoding=False)
    return colour.XYZ_to_Lab(xyz, _SRGB.whitepoint)


def delta_e2000_map(model, truth) -> np.ndarray:
    """Per-pixel CIEDE2000 ``[H, W]`` between two linear sRGB images (module docstring)."""
    model, truth = _checked("model image", model), _checked("truth image", truth)
    if model.shape != truth.shape:
        raise ValueError(f"the images differ in shape: {model.shape} and {truth.shape}")
    return colour.delta_E(linear_srgb_to_lab(model), linear_srgb_to_lab(truth), method="CIE 2000")


def image_scores(model, truth) -> tuple[dict[str, float | None], np.ndarray]:
    """``(metrics, delta_e_map)``: the four metrics of :data:`IMAGE_METRICS` and the ΔE2000 map."""
    delta_e = delta_e2000_map(model, truth)
    model, truth = np.asarray(model, dtype=np.float64), np.asarray(truth, dtype=np.float64)
    energy = float(np.sum(truth * truth))
    if energy <= 0.0:
        raise ValueError("the truth image is black: the relative MSE is undefined")
    displayed_mse = float(np.mean((displayed(model) - displayed(truth)) ** 2))
    metrics = {
        "image_rel_mse": float(np.sum((model - truth) ** 2)) / energy,
        "image_psnr": None if displayed_mse == 0.0 else float(10.0 * np.log10(1.0 / displayed_mse)),
        "image_delta_e2000_mean": float(np.mean(delta_e)),
        "image_delta_e2000_p95": float(np.percentile(delta_e, 95)),
    }
    return metrics, delta_e
