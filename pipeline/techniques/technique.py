"""The seam every technique plugs into: one `Technique` object per technique, listed in
`registry.TECHNIQUES`; bake, verify, tradeoff, the planner's pilot, the CLI and the report iterate
over the registry instead of naming techniques.

A technique's object is assembled in ``techniques/<name>/technique.py`` from one mixin per concern,
each in the module of that concern (``stage.py``: bake; ``verify.py``: reader, render items and
verify figures; ``pilot.py``: the planner's candidates; ``tradeoff.py``: the sweep) and its entry
(``entry.py``, `entry.TechniqueEntry`: its name, its options dataclass from ``options.py`` and its
tradeoff flags, which `registry` lists without importing the rest). Techniques never import the layers above
them (`sssbake.pipeline.options`, ``bake``, ``planning``, ``verify``, the CLI): those pass them
what they need.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Callable, ClassVar

import numpy as np

from sssbake.pipeline.core.errors import TradeoffError
from sssbake.pipeline.core.materials import Material
from sssbake.pipeline.core.surface import Surface
from sssbake.pipeline.mesh.atlas import Atlas
from sssbake.pipeline.mesh.baked import BakedAsset
from sssbake.pipeline.mesh.scene import Primitive
from sssbake.pipeline.techniques.entry import TechniqueEntry

#: A technique baked per mesh, on its welded surface (and atlas).
MESH = "mesh"
#: A technique baked per scattering material, without mesh data (its tables hang on the material).
MATERIAL = "material"


class Technique(TechniqueEntry):
    """The protocol each registered technique implements (see the module docstring), beyond its
    entry's (`entry.TechniqueEntry`: ``name``, ``options_type``, ``add_tradeoff_arguments``).

    Class attributes
    ----------------
    scope : str
        `MESH` or `MATERIAL`.
    stage_version : int
        Bump when the bake's output for the same input changes (part of its stage-cache key).
    needs_atlas : bool
        Whether its bake reads the mesh's atlas (its cache key then follows the atlas's).
    draw_unit : str
        What verify draws one render item of: ``"primitive"`` or ``"mesh"`` (all primitives of a mesh).
    vertex_keys : tuple of str
        Prefixes of the `VertexAttribute` keys its `vertex_attributes` write (``"sss:prt:"``):
        how `footprint` tells its attributes in a written file from other techniques' (default none).
    dependent_stages : dict of str to str
        Stages that run only inside this technique's bake, each with the reason the report's
        ``stages`` records when the technique runs for nothing in the asset (default none).

    Bake hooks (``<Cls>Stage`` in ``stage.py``)
    -------------------------------------------
    bake(target: BakeTarget, options) -> TechniqueBake
        Bake one mesh (`MESH`) or one material (`MATERIAL`) with the technique's `options_type`
        options; deterministic in its inputs (the result is cached).
    vertex_attributes(result: TechniqueBake, welded: (n,) int) -> tuple of VertexAttribute
        The attributes of one render primitive whose n vertices are the welded surface's `welded`
        (`MESH` scope; ``()`` when the technique stores no per-vertex data).
    extra_outputs(options) -> dict of str to callable
        Extra files of a bake, ``{name: make}``: ``<stem>.<name>.glb`` is written from
        ``make(BakedAsset) -> BakedAsset`` (default none).
    stage_options(options) -> options
        `options` with the fields its `bake` does not read under them set to their defaults: what
        the stage cache keys its bake on, so that changing such a field reruns nothing (default:
        `options` as they are).
    check_bake(result: TechniqueBake, target: BakeTarget, options)
        Raise (ValueError) unless `result`, read back from the stage cache, is what `bake` could
        have made of `target` under `options`: the shapes and index ranges of its data and tables,
        beyond the checks every technique's result gets (finite values, the data's own ``check()``,
        per-vertex data over the surface: ``bake.stages``); default none.

    Verify and runtime hooks (``<Cls>Verify`` in ``verify.py``)
    ------------------------------------------------------------
    draw : render.DrawKind or None
        How the renderer draws render items keyed by the technique's name (its ``runtime.py``);
        None for a technique drawn by the generic kinds (spectral: ``q`` and ``albedo``).
    self_reference_label : str or None
        verify's ``reference`` where `reference_item` replaced the dipole (None: it never does).
    read(path) -> dict of (mesh, primitive) to data
        The technique's data in a .glb, per primitive, as its ``reader.py`` decodes it.
    read_usd(path) -> dict of str to data
        The same data in a .usdc, per mesh prim path (per material prim for `MATERIAL` scope).
    verify_items(unit: VerifyUnit, data: dict, runtime: dict) -> (dict, dict)
        The render item verify compares with the reference for one draw unit, and the one it
        times (the runtime as it ships); `data` is `read`'s, `runtime` verify's settings
        (``lpv_steps``: int or None).
    reference_item(path, unit: VerifyUnit, data: dict, runtime: dict, memo: dict)
        ``(render item, (resolution, steps))`` of the technique's own reference for the unit,
        or None where the dipole serves; `memo` is kept across a file's units.
    verify_figures(units: list of VerifyUnit, items: list of dict, shot: VerifyShot)
        ``(image, pictures, figures)``: the image verify measures ((H, W, 3), the shot's or a
        fitted one), more (H, W, 3) pictures for the comparison PNG, and the technique's own
        figures for verify's result.

    Pilot hooks (``<Cls>Pilot`` in ``pilot.py``)
    ---------------------------------------------
    pilot_candidates(params: dict, options, vertices: int, deforming: bool) -> list of Candidate
        The configurations the planner's pilot tries for a planned entry with `params`
        (`BakeOptions` `options`, a mesh of `vertices` welded vertices), cheapest first; ``[]``
        for a technique without a pilot. Techniques with candidates also have:
    pilot_measures_all : bool
        Whether the pilot measures every candidate (for the budget check's estimates) or stops
        at the first within the budget.
    pilot_fallback : str or None
        The technique whose candidates follow these on a rigid mesh (screen's: prt).
    pilot_item(options, surface, mm_per_unit, material, vertices, memo) -> (dict, bool)
        The render item's technique keys for a candidate (`options` merged with its params) on
        the pilot's subsample `surface`, and whether it kept to its bytes; `memo` is kept across
        the technique's candidates.
    pilot_reference(item: dict, surface, options, memo) -> dict or None
        The technique's own reference's item keys for the `item` made last, or None where the
        dipole serves.
    Tradeoff hooks (``<Cls>Tradeoff`` in ``tradeoff.py``)
    ------------------------------------------------------
    run_tradeoff(path, mm_per_unit: float, material: Material, out_dir, args) -> dict
        Sweep its knobs on the largest mesh of `path`: ``rows`` (each with ``sweep``, ``seconds``,
        ``rmse_image``), ``frame_ms_sss``, ``frame_ms_plain``, ``frame_ratio``, ``outputs``
        (default: `TradeoffError`, no sweep).
    tradeoff_row(row: dict) -> str
        One row's knobs and size, as ``sssbake tradeoff`` prints it.
    """

    scope: ClassVar[str]
    stage_version: ClassVar[int]
    needs_atlas: ClassVar[bool]
    draw_unit: ClassVar[str]
    dependent_stages: ClassVar[dict[str, str]] = {}
    vertex_keys: ClassVar[tuple[str, ...]] = ()
    # verify and pilot defaults: the dipole is the reference, no figures of its own, no pilot
    self_reference_label: ClassVar[str | None] = None
    pilot_measures_all: ClassVar[bool] = True
    pilot_fallback: ClassVar[str | None] = None

    def extra_outputs(self, options) -> dict[str, Callable[[BakedAsset], BakedAsset]]:
        return {}

    def stage_options(self, options):
        return options

    def check_bake(self, result: TechniqueBake, target: BakeTarget, options) -> None:
        return None

    def reference_item(self, path, unit: VerifyUnit, data: dict, runtime: dict, memo: dict) -> None:
        return None

    def verify_figures(self, units: list[VerifyUnit], items: list[dict], shot: VerifyShot
                       ) -> tuple[np.ndarray, list, dict]:
        return shot.image, [], {}

    def pilot_candidates(self, params: dict, options, vertices: int, deforming: bool) -> list[Candidate]:
        return []

    def pilot_reference(self, item: dict, surface: Surface, options, memo: dict) -> dict | None:
        return None

    def run_tradeoff(self, path, mm_per_unit: float, material: Material, out_dir, args) -> dict:
        raise TradeoffError(f"tradeoff: {self.name} has no sweep")

    def __repr__(self) -> str:
        return f"<technique {self.name}>"


def same_tables(a, b) -> bool:
    """Whether two `TechniqueBake.tables` values are the same: dicts with the same keys in the same
    order, arrays of the same dtype, shape and values, lists and tuples item by item, the rest ``==``."""
    if isinstance(a, np.ndarray) or isinstance(b, np.ndarray):
        return type(a) is type(b) and a.dtype == b.dtype and a.shape == b.shape and np.array_equal(a, b)
    if isinstance(a, dict):
        return (type(b) is dict and list(a) == list(b)
                and all(same_tables(x, b[k]) for k, x in a.items()))
    if isinstance(a, (list, tuple)):
        return type(a) is type(b) and len(a) == len(b) and all(same_tables(x, y) for x, y in zip(a, b))
    return type(a) is type(b) and a == b


@dataclass(frozen=True)
class Candidate:
    """One configuration the planner's pilot may choose (`Technique.pilot_candidates`).

    Attributes
    ----------
    technique : str
    params : dict
        The bake options it sets on the full asset (flat `BakeOptions` names).
    label : str
        What a reader is told it is (e.g. ``"prt <= 12 B/vertex (412 reference points)"``).
    """

    technique: str
    params: dict
    label: str


@dataclass(frozen=True, eq=False)
class VerifyUnit:
    """What verify draws one render item of (`Technique.draw_unit`): primitives of one mesh
    instance, in the mesh's frame.

    Attributes
    ----------
    mesh : int
        The mesh's index in the file.
    primitives : tuple of int
        The primitives drawn together.
    primitive : Primitive
        Them merged (`render.items.merged_primitive`): n render vertices.
    surface : Surface
        Their welded surface, file units.
    weld : (n,) int
        The welded vertex of each render vertex.
    mm_per_unit : float
        The mesh's ``scaleMm``.
    material : Material
        Their scattering material.
    extras : dict
        The mesh's ``extras.sssbake``.
    base : dict
        The render item's geometry: ``positions`` (n, 3), ``normals`` (n, 3), ``faces`` (m, 3),
        ``model`` (4, 4) object to world, ``eta``.
    lambert_q : callable
        ``lambert_q(field) -> (n, 3)``: the grey q verify's light gives unit normals `field`
        (n, 3) at the render vertices (clamped cosine times shadow visibility).
    """

    mesh: int
    primitives: tuple[int, ...]
    primitive: Primitive
    surface: Surface
    weld: np.ndarray
    mm_per_unit: float
    material: Material
    extras: dict
    base: dict
    lambert_q: Callable[[np.ndarray], np.ndarray]


@dataclass(frozen=True)
class Budget:
    """What the asset may still spend when a technique starts (its worker's limits less what the
    bake already holds and took): a technique that can forecast its cost refuses up front rather
    than be killed at the limit.

    Attributes
    ----------
    memory_bytes : float or None
        Resident memory left (None: no limit).
    seconds : float or None
        Wall time left (None: no limit).
    """

    memory_bytes: float | None = None
    seconds: float | None = None


@dataclass(frozen=True, eq=False)
class BakeTarget:
    """What `Technique.bake` bakes: one mesh's geometry with its scattering material, or (`MATERIAL`
    scope) the material alone.

    Attributes
    ----------
    material : Material
        The scattering material (a mesh of several is baked with its first one's).
    mm_per_unit : float
        Millimetres per file unit of the mesh (its instance scale included); 1 for `MATERIAL` scope.
    surface : Surface or None
        The mesh's welded surface, file units (`MESH` scope).
    primitives : tuple of ((n_i, 3) float64, (n_i, 3) float64)
        Per render primitive, its positions and normals (`MESH` scope).
    atlas : Atlas or None
        The mesh's atlas when the technique `needs_atlas`, else None.
    atlas_padding : int
        The atlas's padding in texels (with `atlas`).
    budget : Budget or None
        What the asset may still spend (None: no limits); not part of the stage's key.
    """

    material: Material
    mm_per_unit: float = 1.0
    surface: Surface | None = None
    primitives: tuple[tuple[np.ndarray, np.ndarray], ...] = ()
    atlas: Atlas | None = None
    atlas_padding: int = 0
    budget: Budget | None = None


@dataclass(frozen=True, eq=False)
class TechniqueBake:
    """What `Technique.bake` made for one mesh or material (a stage-cache value).

    Attributes
    ----------
    data : object
        What `Technique.vertex_attributes` reads (e.g. `PrtData`; None when nothing is per vertex).
    tables : dict or None
        The mesh's or material's ``extras.sssbake[name]``: JSON-able, numpy arrays for binary
        tables; None stores nothing.
    report : dict
        The report's block for this mesh or material.
    warnings : tuple of str
        Warnings about the bake, said without naming the object: the bake prefixes each with
        ``mesh '<name>': `` (`MESH` scope) or ``material '<name>': `` (`MATERIAL` scope).
    """

    data: object = None
    tables: dict | None = None
    report: dict = field(default_factory=dict)
    warnings: tuple[str, ...] = ()


@dataclass(frozen=True, eq=False)
class VerifyShot:
    """What verify rendered of a file, for a technique's own figures (`Technique.verify_figures`).

    Attributes
    ----------
    renderer : render.Renderer
    camera : render.Camera
    light : render.RenderLight
    image : (H, W, 3) float32
        The technique's image.
    reference : (H, W, 3) float32
    reference_mask : (H, W) bool
        The reference's pixels.
    mask : (H, W) bool
        The object's pixels: the reference's or the image's.
    exposure : float
        The images' shared exposure.
    lit : (H, W, 3) bool
        Where the light reaches directly (the Lambert image's non-zero pixels).
    fitted : callable
        ``fitted(drawn) -> (drawn · fit, fit)``: an (H, W, 3) image times its per-channel
        least-squares fit (3,) to the reference.
    """

    renderer: object
    camera: object
    light: object
    image: np.ndarray
    reference: np.ndarray
    reference_mask: np.ndarray
    mask: np.ndarray
    exposure: float
    lit: np.ndarray
    fitted: Callable[[np.ndarray], tuple[np.ndarray, np.ndarray]]
