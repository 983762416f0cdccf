"""1-D Lloyd-Max scalar quantiser: a lookup table of levels and one code per value (Hao & Varshney
2004 §4 quantise q to 8 bits this way)."""

from __future__ import annotations

import numpy as np

#: Values the levels are fitted to at most; the rest are only encoded (a 1M sample fixes 256
#: levels to well within their spacing).
FIT_SAMPLE = 1_000_000


def lloyd_quantizer(values: np.ndarray, levels: int = 256, iterations: int = 60, tol: float = 1e-6,
                    seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """Fit a Lloyd-Max quantiser to `values` and encode them.

    Parameters
    ----------
    values : (...) float64
        Finite values.
    levels : int
        2 .. 65536 reconstruction levels.
    iterations, tol : int, float
        Stop after `iterations` or when the mean squared error improves by less than `tol`
        relative.

    Returns
    -------
    lut : (levels,) float64
        Sorted reconstruction levels (repeated at the top when the data has fewer distinct values).
    codes : values.shape uint8 (levels <= 256) or uint16
    """
    values = np.asarray(values, dtype=np.float64)
    if not 2 <= levels <= 65536:
        raise ValueError(f"lloyd: levels must be in [2, 65536], got {levels}")
    if values.size == 0 or not np.all(np.isfinite(values)):
        raise ValueError("lloyd: need a non-empty array of finite values")
    flat = values.ravel()
    sample = flat if flat.size <= FIT_SAMPLE else np.random.default_rng(seed).choice(flat, FIT_SAMPLE, replace=False)
    sample = np.sort(sample)
    distinct = np.unique(sample)
    if len(distinct) <= levels:
        lut = np.concatenate([distinct, np.full(levels - len(distinct), distinct[-1])])
    else:
        lut = _companded_start(sample, levels)
        cumsum = np.concatenate([[0.0], np.cumsum(sample)])
        previous = None
        for _ in range(iterations):
            edges = np.searchsorted(sample, 0.5 * (lut[1:] + lut[:-1]))
            bounds = np.concatenate([[0], edges, [len(sample)]])
            counts = np.diff(bounds)
            sums = cumsum[bounds[1:]] - cumsum[bounds[:-1]]
            # An empty cell keeps its level (it cannot lower the error anywhere).
            lut = np.sort(np.where(counts > 0, sums / np.maximum(counts, 1), lut))
            mse = np.mean((sample - lut[_encode(sample, lut)]) ** 2)
            if previous is not None and previous - mse <= tol * previous:
                break
            previous = mse
    codes = _encode(flat, lut).astype(np.uint8 if levels <= 256 else np.uint16)
    return lut, codes.reshape(values.shape)


def _companded_start(sample: np.ndarray, levels: int) -> np.ndarray:
    """Levels spaced with density ∝ p(x)^(1/3), the high-resolution optimum (Panter-Dite), so
    Lloyd starts near its fixed point even for long-tailed data such as q."""
    bins = max(4 * levels, 1024)
    density, edges = np.histogram(sample, bins=bins)
    weight = np.cumsum(np.concatenate([[0.0], density.astype(np.float64) ** (1.0 / 3.0)]))
    lut = np.interp((np.arange(levels) + 0.5) / levels * weight[-1], weight, edges)
    return np.sort(lut)


def _encode(values: np.ndarray, lut: np.ndarray) -> np.ndarray:
    """Index of the nearest level (ties to the lower one)."""
    return np.searchsorted(0.5 * (lut[1:] + lut[:-1]), values, side="right")


def snr_db(values: np.ndarray, decoded: np.ndarray) -> float:
    """Signal-to-noise ratio 10 log10(Σ x² / Σ (x - x̂)²) in dB (inf when exact)."""
    noise = float(np.sum((np.asarray(values) - np.asarray(decoded)) ** 2))
    signal = float(np.sum(np.asarray(values) ** 2))
    return float("inf") if noise == 0.0 else 10.0 * np.log10(signal / noise)
