"""screen: verify and the runtime (`technique.Technique`'s verify hooks)."""

from __future__ import annotations

import numpy as np

from sssbake.pipeline.techniques.screen.reader import read_screen_glb, read_screen_usd
from sssbake.pipeline.techniques.screen.runtime import SCREEN_DRAW
from sssbake.pipeline.techniques.technique import VerifyShot, VerifyUnit

#: A screen pixel whose gather found less than this share of Rd's integral on the surface counts
#: as missing surface (silhouettes, occluders, the image's edge).
LOW_SHARE = 0.9


class ScreenVerify:
    """A primitive drawn with its material's `ScreenSamples` (nothing per vertex); compared with the
    dipole, with where screen space misses light (`screen_misses`)."""

    draw = SCREEN_DRAW

    def read(self, path) -> dict:
        return read_screen_glb(path)

    def read_usd(self, path) -> dict:
        return read_screen_usd(path)

    def verify_items(self, unit: VerifyUnit, data: dict, runtime: dict) -> tuple[dict, dict]:
        item = {**unit.base, "screen": data[(unit.mesh, unit.primitives[0])], "mm_per_unit": unit.mm_per_unit}
        return item, item

    def verify_figures(self, units: list[VerifyUnit], items: list[dict], shot: VerifyShot
                       ) -> tuple[np.ndarray, list, dict]:
        return shot.image, [], screen_misses(items, shot)


def screen_misses(items: list[dict], shot: VerifyShot) -> dict:
    """Where the screen technique's image lacks the reference's light, and why.

    Parameters
    ----------
    items : list of dict
        The screen render items.
    shot : VerifyShot
        Its image, the reference, the object's pixels (``mask``) and the pixels the light
        reaches directly (``lit``).

    Returns
    -------
    dict
        ``low_share_pixels``: share of the object's pixels whose gather found under `LOW_SHARE`
        of Rd's integral on the surface (the smallest over the items covering it);
        ``missed_share``: Σ max(reference - image, 0) / Σ reference over the object's pixels
        (all channels); ``missed_share_unlit``, ``missed_share_low_share``: the parts of it at
        pixels the light does not reach directly (light that came through the object from
        surfaces the camera cannot see) and at low-share pixels; ``bytes_per_material``: the
        tables' float32 bytes of the first item.
    """
    image, reference, mask = shot.image, shot.reference, shot.mask
    share = np.ones(image.shape[:2])
    for item in items:
        passes = shot.renderer.passes(item, shot.light, shot.camera)
        share = np.where(passes["covered"], np.minimum(share, passes["share"]), share)
    lit = shot.lit.any(axis=-1) if shot.lit.ndim == 3 else shot.lit
    low = mask & (share < LOW_SHARE)
    missing = np.maximum(reference - image, 0.0).sum(axis=-1)
    total = max(float(reference[mask].sum()), 1e-300)
    samples = items[0]["screen"]
    return {"low_share_pixels": float(low.sum() / max(mask.sum(), 1)),
            "missed_share": float(missing[mask].sum() / total),
            "missed_share_unlit": float(missing[mask & ~lit].sum() / total),
            "missed_share_low_share": float(missing[low].sum() / total),
            "bytes_per_material": int(4 * (samples.offsets.size + samples.weights.size + samples.table.size))}
