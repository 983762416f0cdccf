"""spectral: verify (`technique.Technique`'s verify hooks). Its runtime is the plain Lambert
shader fed the subsurface normals, so it brings no draw of its own."""

from __future__ import annotations

import numpy as np

from sssbake.pipeline.core.materials import Material
from sssbake.pipeline.core.naive_normals import naive_normals
from sssbake.pipeline.core.surface import Surface
from sssbake.pipeline.render.image_metrics import rmse
from sssbake.pipeline.render.items import PLAIN_ALBEDO
from sssbake.pipeline.techniques.spectral.precompute import NAIVE_ALPHA, naive_parameters
from sssbake.pipeline.techniques.spectral.reader import read_spectral_glb, read_spectral_usd
from sssbake.pipeline.techniques.technique import VerifyShot, VerifyUnit


class SpectralVerify:
    """A mesh's subsurface normals (the surface they were filtered on), compared as a Lambert
    image scaled by its fit to the reference, beside Patro's naive normals."""

    draw = None

    def read(self, path) -> dict:
        return read_spectral_glb(path)

    def read_usd(self, path) -> dict:
        return read_spectral_usd(path)

    def verify_items(self, unit: VerifyUnit, data: dict, runtime: dict) -> tuple[dict, dict]:
        subsurface = np.concatenate([data[(unit.mesh, p)] for p in unit.primitives])
        # The file's normals stay the item's: the q draw's exit Fresnel then matches the baseline's.
        return ({**unit.base, "q": unit.lambert_q(subsurface)},
                {**unit.base, "normals": subsurface, "albedo": PLAIN_ALBEDO})

    def verify_figures(self, units: list[VerifyUnit], items: list[dict], shot: VerifyShot
                       ) -> tuple[np.ndarray, list, dict]:
        """The image scaled by its fit (``spectral_scale``), and the naive normals' fitted image
        (``naive_scale``, ``rmse_object_naive`` over the reference's pixels)."""
        image, spectral_scale = shot.fitted(shot.image)
        naive_items = [{**u.base, "q": u.lambert_q(default_naive_normals(u.surface, u.mm_per_unit, u.material)[u.weld])}
                       for u in units]
        naive, naive_scale = shot.fitted(shot.renderer.render(naive_items, shot.camera, shot.light)[0])
        return image, [naive], {"spectral_scale": spectral_scale.tolist(), "naive_scale": naive_scale.tolist(),
                                "rmse_object_naive": rmse(naive, shot.reference, shot.exposure, shot.reference_mask)}


def default_naive_normals(surface: Surface, mm_per_unit: float, material: Material) -> np.ndarray:
    """(n, 3) Patro's naive normals of `surface`'s vertices with the spectral precompute's defaults
    (σ_tr and radius from the material, `NAIVE_ALPHA`), without its eigensolve."""
    sigma_tr, radius = naive_parameters(material)
    return naive_normals(surface.positions * mm_per_unit, surface.normals, sigma_tr, NAIVE_ALPHA, radius)
