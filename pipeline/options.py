"""Bake options: one dataclass and its defaults, read by both the API and the CLI."""

from __future__ import annotations

from dataclasses import asdict, dataclass, fields, replace

OPAQUE = "opaque"


@dataclass(frozen=True)
class BakeOptions:
    """Per-asset settings.

    Attributes
    ----------
    material : str or dict
        Scattering material for surfaces no material rule matches: a preset name, ``"opaque"``, or a
        table (see `materials.material_from_spec`).
    scale_mm : float or None
        Millimetres per file unit. None: use the unit the file format declares (glTF: metres;
        USD: metersPerUnit when authored); formats without units (OBJ, PLY, STL) then fail with a
        clear error rather than a guess.
    materials : tuple of (glob, spec)
        Source material name patterns (case-insensitive) mapped to material specs.
    atlas_resolution : int
        Atlas and thickness texture size in texels (square).
    atlas_padding : int
        Gutter between charts in texels (>= 4 so 7×7 kernels stay inside a chart).
    thickness_rays : int
        Rays per sample for the thickness bake (1: straight along -n).
    validate : bool
        Run the Khronos glTF validator and UsdValidation on every export.
    """

    material: str | dict = "marble"
    scale_mm: float | None = None
    materials: tuple[tuple[str, str | dict], ...] = ()
    atlas_resolution: int = 512
    atlas_padding: int = 4
    thickness_rays: int = 1
    validate: bool = True

    def to_json(self) -> dict:
        return asdict(self)

    def merged(self, overrides: dict) -> "BakeOptions":
        """A copy with `overrides` applied; unknown keys raise ValueError naming them."""
        known = {f.name for f in fields(self)}
        unknown = sorted(set(overrides) - known)
        if unknown:
            raise ValueError(f"unknown option(s) {unknown}; known: {sorted(known)}")
        return replace(self, **overrides)


BAKE_DEFAULTS = BakeOptions()


def check_options(o: BakeOptions) -> None:
    """Raise ValueError with a one-line reason for an impossible setting."""
    if o.scale_mm is not None and not (isinstance(o.scale_mm, (int, float)) and 0 < o.scale_mm < float("inf")):
        raise ValueError(f"scale_mm must be a finite number > 0, got {o.scale_mm!r}")
    if not (16 <= o.atlas_resolution <= 8192):
        raise ValueError(f"atlas_resolution must be in [16, 8192], got {o.atlas_resolution}")
    if not (0 <= o.atlas_padding <= o.atlas_resolution // 8):
        raise ValueError(f"atlas_padding must be in [0, resolution/8], got {o.atlas_padding}")
    if not (1 <= o.thickness_rays <= 64):
        raise ValueError(f"thickness_rays must be in [1, 64], got {o.thickness_rays}")
