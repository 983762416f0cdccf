"""Image comparison for ``verify``: one exposure for both images, RMSE on [0, 1] values
(Hao & Varshney 2004's metric), per-channel best-fit scale, and PNGs for people.

Images are linear float RGB arrays (H, W, 3); masks are (H, W) bool.
"""

from __future__ import annotations

import os

import numpy as np

from sssbake.exporters.atomic import atomic_path


def shared_exposure(reference: np.ndarray, mask: np.ndarray, percentile: float = 99.5) -> float:
    """One scale for every image of a comparison: maps the `percentile` of the reference's
    brightest channel over `mask` (all pixels when `mask` is empty) to 1; 1 for a black reference.

    Parameters
    ----------
    reference : (H, W, 3) float
    mask : (H, W) bool
    percentile : float in [0, 100]
    """
    reference = _image(reference, "reference")
    mask = _mask(mask, reference)
    if not 0.0 <= percentile <= 100.0:
        raise ValueError(f"image_metrics: percentile must be in [0, 100], got {percentile}")
    values = (reference[mask] if mask.any() else reference.reshape(-1, 3)).max(axis=-1)
    level = float(np.percentile(values, percentile)) if values.size else 0.0
    return 1.0 / level if level > 0 else 1.0


def rmse(a: np.ndarray, b: np.ndarray, exposure: float, mask: np.ndarray | None = None) -> float:
    """Root mean square difference of ``clip(a · exposure, 0, 1)`` and the same of `b`, over all
    pixels and channels, or over the pixels in `mask` (0 when it is empty).

    Parameters
    ----------
    a, b : (H, W, 3) float
    exposure : float
    mask : (H, W) bool, optional
    """
    a, b = _image(a, "a"), _image(b, "b")
    if a.shape != b.shape:
        raise ValueError(f"image_metrics: images differ in shape, {a.shape} vs {b.shape}")
    d = np.clip(a * exposure, 0.0, 1.0) - np.clip(b * exposure, 0.0, 1.0)
    if mask is not None:
        d = d[_mask(mask, a)]
    return float(np.sqrt(np.mean(d**2))) if d.size else 0.0


def best_fit_scale(image: np.ndarray, reference: np.ndarray, mask: np.ndarray) -> np.ndarray:
    """(3,) per-channel s minimising Σ_mask (s · image - reference)²; 0 where `image` is black.

    Parameters
    ----------
    image, reference : (H, W, 3) float
    mask : (H, W) bool
    """
    image, reference = _image(image, "image"), _image(reference, "reference")
    if image.shape != reference.shape:
        raise ValueError(f"image_metrics: images differ in shape, {image.shape} vs {reference.shape}")
    mask = _mask(mask, image)
    a, b = image[mask].astype(np.float64), reference[mask].astype(np.float64)
    den = (a * a).sum(axis=0)
    return np.where(den > 0, (a * b).sum(axis=0) / np.where(den > 0, den, 1.0), 0.0)


def write_comparison_png(path: str | os.PathLike, images: list[np.ndarray], exposure: float) -> None:
    """Linear (H, W, 3) images side by side, times `exposure`, sRGB-encoded; written atomically."""
    from PIL import Image

    images = [_image(im, "image") for im in images]
    if not images or len({im.shape for im in images}) != 1:
        raise ValueError(f"image_metrics: need one or more images of one shape, got {[im.shape for im in images]}")
    row = np.concatenate([_srgb(np.clip(im * exposure, 0.0, 1.0)) for im in images], axis=1)
    with atomic_path(path) as tmp:
        Image.fromarray(row).save(tmp, format="PNG")


def write_difference_png(path: str | os.PathLike, a: np.ndarray, b: np.ndarray, exposure: float,
                         gain: float = 10.0) -> None:
    """Largest channel of |a - b| (exposed and clipped as in `rmse`) times `gain`, through the
    magma colour map (black: equal, yellow-white: a difference of 1/gain or more); written atomically."""
    from matplotlib import colormaps
    from PIL import Image

    a, b = _image(a, "a"), _image(b, "b")
    if a.shape != b.shape:
        raise ValueError(f"image_metrics: images differ in shape, {a.shape} vs {b.shape}")
    d = np.abs(np.clip(a * exposure, 0, 1) - np.clip(b * exposure, 0, 1)).max(axis=-1)
    rgb = colormaps["magma"](np.clip(d * gain, 0.0, 1.0), bytes=True)[..., :3]
    with atomic_path(path) as tmp:
        Image.fromarray(np.ascontiguousarray(rgb)).save(tmp, format="PNG")


def _image(x: np.ndarray, name: str) -> np.ndarray:
    x = np.asarray(x)
    if x.ndim != 3 or x.shape[2] != 3 or not np.all(np.isfinite(x)):
        raise ValueError(f"image_metrics: {name} must be a finite (H, W, 3) image, got shape {x.shape}")
    return x


def _mask(mask: np.ndarray, image: np.ndarray) -> np.ndarray:
    mask = np.asarray(mask)
    if mask.shape != image.shape[:2] or mask.dtype != bool:
        raise ValueError(f"image_metrics: mask must be (H, W) bool = {image.shape[:2]}, got {mask.shape} {mask.dtype}")
    return mask


def _srgb(x: np.ndarray) -> np.ndarray:
    """uint8 sRGB of linear values in [0, 1]."""
    s = np.where(x <= 0.0031308, 12.92 * x, 1.055 * np.power(x, 1 / 2.4) - 0.055)
    return (np.clip(s, 0.0, 1.0) * 255 + 0.5).astype(np.uint8)
