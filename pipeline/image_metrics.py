"""Image comparison for ``verify``: one exposure for both images, RMSE on [0, 1] values
(Hao & Varshney 2004's metric), per-channel best-fit scale, and PNGs for people."""

from __future__ import annotations

import os

import numpy as np

from ..exporters.atomic import atomic_path


def shared_exposure(reference: np.ndarray, mask: np.ndarray, percentile: float = 99.5) -> float:
    """Scale mapping the `percentile` of the reference's brightest channel over `mask` to 1."""
    values = reference[mask].max(axis=-1) if mask.any() else reference.reshape(-1, 3).max(axis=-1)
    level = float(np.percentile(values, percentile)) if values.size else 0.0
    return 1.0 / level if level > 0 else 1.0


def rmse(a: np.ndarray, b: np.ndarray, exposure: float, mask: np.ndarray | None = None) -> float:
    """RMSE of the exposed images clipped to [0, 1], over all pixels or those in `mask`."""
    d = np.clip(a * exposure, 0.0, 1.0) - np.clip(b * exposure, 0.0, 1.0)
    if mask is not None:
        d = d[mask]
    return float(np.sqrt(np.mean(d**2))) if d.size else 0.0


def best_fit_scale(image: np.ndarray, reference: np.ndarray, mask: np.ndarray) -> np.ndarray:
    """(3,) per-channel s minimising Σ (s·image - reference)² over `mask`."""
    a, b = image[mask], reference[mask]
    den = (a * a).sum(axis=0)
    return np.where(den > 0, (a * b).sum(axis=0) / np.where(den > 0, den, 1.0), 0.0)


def write_comparison_png(path: str | os.PathLike, images: list[np.ndarray], exposure: float) -> None:
    """Linear images side by side, exposed, sRGB-encoded; written atomically."""
    from PIL import Image

    row = np.concatenate([_srgb(np.clip(im * exposure, 0.0, 1.0)) for im in images], axis=1)
    with atomic_path(path) as tmp:
        Image.fromarray(row).save(tmp, format="PNG")


def write_difference_png(path: str | os.PathLike, a: np.ndarray, b: np.ndarray, exposure: float,
                         gain: float = 10.0) -> None:
    """|a - b| of the exposed images times `gain`, as grey; written atomically."""
    from PIL import Image

    d = np.abs(np.clip(a * exposure, 0, 1) - np.clip(b * exposure, 0, 1)).max(axis=-1)
    with atomic_path(path) as tmp:
        Image.fromarray((np.clip(d * gain, 0.0, 1.0) * 255 + 0.5).astype(np.uint8)).save(tmp, format="PNG")


def _srgb(x: np.ndarray) -> np.ndarray:
    s = np.where(x <= 0.0031308, 12.92 * x, 1.055 * np.power(x, 1 / 2.4) - 0.055)
    return (np.clip(s, 0.0, 1.0) * 255 + 0.5).astype(np.uint8)
