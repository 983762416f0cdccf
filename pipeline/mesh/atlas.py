"""One shared xatlas texture atlas for all parts of a mesh, computed in a child process.

xatlas 0.0.11 segfaults on some very regular meshes (an icosphere of subdivision 6, whatever the
vertex order, face order or a rigid rotation). A crash in-process would kill the whole batch, so
xatlas runs in ``python -m sssbake.pipeline.mesh.atlas_worker``; if the child dies by a signal, the
parametrisation is retried once on positions jittered by ``JITTER`` × bounding-box diagonal (the
smallest jitter that charts that icosphere quickly and in few charts:
benchmarks/README.md#xatlas-crash-and-jitter). The jitter only shapes the parametrisation: the
returned ``vmapping`` points into the caller's unjittered vertices.

UV convention (glTF): u grows to the right, v grows downwards, origin at the top-left corner of
the image, i.e. of image row 0 as stored in memory. Texel ``(row, col)`` covers
``[col, col + 1) / width × [row, row + 1) / height`` and its centre is at
``((col + 0.5) / width, (row + 0.5) / height)``. This is xatlas's own layout (its chart image's row
``y`` is ``v × height``), so no flip is applied anywhere.

xatlas is not scale invariant (its tolerances are absolute, in float32): it charts a copy of the
mesh centred and scaled to a bounding-box diagonal of ``DIAGONAL`` (at extreme scales it failed, at
diagonal 0.1 it split the bunny into thousands of charts; 100 is the fastest of 1, 10 and 100:
benchmarks/README.md#xatlas-scale).

xatlas' charting grows faster than the mesh (the 50k-vertex dragon 30 s, 150k 180 s), so a part
of more than `PIECE_FACES` triangles is cut into pieces of about that many, runs of its triangles
in Morton order of their centroids (compact in space), and each piece is charted as a mesh of its
own; xatlas packs the charts of all pieces into one atlas. A piece's border is a chart border (a
seam) as well: the 150k dragon got 5 % more charts, in 17 s instead of 180
(benchmarks/README.md#xatlas-pieces).
"""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import tempfile
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from sssbake.pipeline.core.errors import SssbakeError
from sssbake.pipeline.core.morton import morton_codes
from sssbake.pipeline.mesh.atlas_resolution import RESOLUTION

# Jitter of the retry, as a fraction of the bounding-box diagonal (see the module docstring).
JITTER = 1e-4
JITTER_SEED = 0
# Bounding-box diagonal xatlas sees (see the module docstring).
DIAGONAL = 100.0
#: Atlas sides are multiples of this: block-compressed textures (BCn, ETC, ASTC 4x4, KTX2/Basis)
#: need whole 4x4 blocks. An exact ``resolution`` would take a second xatlas charting of the mesh
#: (minutes on large ones: xatlas' own size is an estimate), so the atlas is padded instead.
BLOCK = 4
#: Triangles per piece xatlas charts on its own (see the module docstring; 4000 charted the 150k
#: dragon in 17 s, 10000 in 24 s).
PIECE_FACES = 4000


class AtlasError(SssbakeError, ValueError):
    """The atlas step failed on this input."""


@dataclass(frozen=True, eq=False)
class AtlasPart:
    """The parametrisation of one part.

    Attributes
    ----------
    vmapping : (n_out,) int64
        For each atlas vertex, the index of the part's input vertex it copies (vertices on chart
        seams are duplicated).
    faces : (m, 3) int64
        The part's triangles, same order as the input, indexing the atlas vertices.
    uvs : (n_out, 2) float64
        Texture coordinates in [0, 1], glTF convention (origin top-left, v down).
    """

    vmapping: np.ndarray
    faces: np.ndarray
    uvs: np.ndarray


@dataclass(frozen=True, eq=False)
class Atlas:
    """A texture atlas shared by all parts of a mesh.

    Attributes
    ----------
    parts : tuple of AtlasPart
        Same order as the input parts.
    width, height : int
        Atlas size in texels, multiples of `BLOCK`. xatlas aims at ``resolution`` but grows the
        atlas when the charts and their padding do not fit (benchmarks/README.md#xatlas-scale);
        its size is then rounded up to whole blocks, the UVs rescaled so every chart keeps its
        texels.
    chart_count : int
        Charts over all parts.
    jittered : bool
        Whether the first xatlas run crashed and this atlas comes from the jittered retry.
    worker_peak_rss_mb : float
        Peak resident memory of the xatlas child process (NaN where the OS does not say).
    source : str
        Where the UVs come from (`proxy_atlas`): ``"TEXCOORD_<n>"`` the input's set n (``chart_count``
        0: not counted), ``"proxy"`` a simplified proxy's charts carried back, ``"charted"`` xatlas
        on the mesh itself.
    notes : tuple of str
        Why the layouts tried before `source` were refused.
    """

    parts: tuple[AtlasPart, ...]
    width: int
    height: int
    chart_count: int
    jittered: bool
    worker_peak_rss_mb: float
    source: str = "charted"
    notes: tuple[str, ...] = ()

    @property
    def input_uv_set(self) -> int | None:
        """The input TEXCOORD set the atlas is, or None when it was charted."""
        return int(self.source.removeprefix("TEXCOORD_")) if self.source.startswith("TEXCOORD_") else None


def compute_atlas(
    parts: list[tuple[np.ndarray, np.ndarray]],
    resolution: int = RESOLUTION,
    padding: int = 4,
    *,
    timeout_s: float | None = None,
    piece_faces: int = PIECE_FACES,
) -> Atlas:
    """Parametrise all parts of a mesh into one xatlas atlas.

    Parameters
    ----------
    parts : list of (positions (n_i, 3) float64, faces (m_i, 3) int64)
    resolution : int
        Target atlas size in texels (xatlas estimates the texel density from it).
    padding : int
        Texels of gutter around every chart.
    timeout_s : float or None
        Wall-clock limit of each xatlas attempt, seconds; None: none of its own (a batch bounds
        the whole bake of an asset, `asset_process`: xatlas takes minutes on the largest meshes,
        so a fixed limit here failed them before the asset's own: benchmarks/README.md#xatlas-scale).
    piece_faces : int
        Parts with more triangles are charted in pieces of about this many (module docstring).

    Returns
    -------
    Atlas

    Raises
    ------
    AtlasError
        Bad input, xatlas crashing on the mesh and on its jittered copy, an xatlas error, or a
        timeout.
    """
    if not parts:
        raise AtlasError("atlas: no parts given; pass at least one (positions, faces) pair")
    if resolution < 1 or padding < 0:
        raise AtlasError(f"atlas: resolution must be >= 1 and padding >= 0, got {resolution}, {padding}")
    checked = []
    for i, (positions, faces) in enumerate(parts):
        positions = np.asarray(positions, dtype=np.float64)
        faces = np.asarray(faces)
        if positions.ndim != 2 or positions.shape[1] != 3 or not np.isfinite(positions).all():
            raise AtlasError(f"atlas: part {i} positions must be finite (n, 3), got {positions.shape}")
        if faces.ndim != 2 or faces.shape[1] != 3 or len(faces) == 0:
            raise AtlasError(f"atlas: part {i} faces must be a non-empty (m, 3) array, got {faces.shape}")
        if faces.min() < 0 or faces.max() >= len(positions):
            raise AtlasError(f"atlas: part {i} face indices outside 0..{len(positions) - 1}; clean the mesh first")
        checked.append((positions, faces.astype(np.uint32)))

    all_positions = np.concatenate([p for p, _ in checked])
    lo, hi = all_positions.min(axis=0), all_positions.max(axis=0)
    with np.errstate(over="ignore"):  # an overflowing extent is refused just below
        diagonal = float(np.linalg.norm(hi - lo))
    if not (np.isfinite(diagonal) and diagonal > 0):
        raise AtlasError(f"atlas: the mesh's bounding-box diagonal is {diagonal:.3g}; it must be finite and > 0 "
                         "(coincident or overflowing vertices); clean the mesh first")
    centre, factor = (lo + hi) / 2.0, DIAGONAL / diagonal
    checked = [((positions - centre) * factor, faces) for positions, faces in checked]
    rng = np.random.default_rng(JITTER_SEED)
    jitters = [rng.uniform(-1.0, 1.0, p.shape) * (JITTER * DIAGONAL) for p, _ in checked]
    pieces = [piece for i, (positions, faces) in enumerate(checked)
              for piece in _pieces(i, positions, faces, piece_faces)]

    with tempfile.TemporaryDirectory(prefix="sssbake-atlas-") as tmp:
        out_path = Path(tmp) / "out.npz"
        signals = []
        for attempt, jittered in enumerate((False, True)):
            in_path = Path(tmp) / f"in{attempt}.npz"
            arrays = {"n_parts": np.int64(len(pieces)), "resolution": np.int64(resolution),
                      "padding": np.int64(padding)}
            for j, piece in enumerate(pieces):
                positions = checked[piece.part][0] + jitters[piece.part] if jittered else checked[piece.part][0]
                arrays[f"positions_{j}"] = positions[piece.vertices].astype(np.float32)
                arrays[f"faces_{j}"] = piece.faces
            np.savez(in_path, **arrays)
            try:
                proc = subprocess.run(
                    [sys.executable, "-m", "sssbake.pipeline.mesh.atlas_worker", str(in_path), str(out_path), str(attempt),
                     str(os.getpid())],
                    capture_output=True, text=True, timeout=timeout_s,
                )
            except subprocess.TimeoutExpired:
                raise AtlasError(
                    f"atlas: xatlas ran longer than {timeout_s:g} s; simplify the mesh first or raise its timeout_s"
                ) from None
            if proc.returncode == 0:
                return _read_result(out_path, [len(faces) for _, faces in checked], pieces, jittered)
            if proc.returncode > 0:
                last = proc.stderr.strip().splitlines()[-1:] or ["no message"]
                raise AtlasError(f"atlas: xatlas failed ({last[0]}); check the mesh for degenerate faces")
            signals.append(_signal_name(-proc.returncode))
    raise AtlasError(
        f"atlas: xatlas crashed twice on this mesh ({signals[0]}; again with positions jittered by "
        f"{JITTER:g} of the diagonal: {signals[1]}); remesh or simplify it, or use a technique that needs no atlas"
    )


def _signal_name(number: int) -> str:
    try:
        return f"signal {number}, {signal.Signals(number).name}"
    except ValueError:
        return f"signal {number}"


@dataclass(frozen=True, eq=False)
class _Piece:
    """Triangles of one part that xatlas charts as a mesh of its own.

    Attributes
    ----------
    part : int
    triangles : (m,) int64
        The part's triangles in the piece, in the piece's order.
    vertices : (k,) int64
        The part's vertices the piece uses; `faces` index them.
    faces : (m, 3) uint32
    """

    part: int
    triangles: np.ndarray
    vertices: np.ndarray
    faces: np.ndarray


def _pieces(part: int, positions: np.ndarray, faces: np.ndarray, piece_faces: int) -> list[_Piece]:
    """Part `part` cut into runs of about `piece_faces` triangles in Morton order of their centroids
    (the whole part when it has no more)."""
    count = -(-len(faces) // max(piece_faces, 1))
    if count <= 1:
        return [_Piece(part, np.arange(len(faces)), np.arange(len(positions)), faces)]
    centroids = positions[faces].mean(axis=1)
    lo, span = centroids.min(axis=0), np.ptp(centroids, axis=0).max()
    cells = np.floor((centroids - lo) / max(span, 1e-300) * (2**20 - 1)).astype(np.int64)
    order = np.argsort(morton_codes(cells), kind="stable")
    pieces = []
    for triangles in np.array_split(order, count):
        vertices, local = np.unique(faces[triangles], return_inverse=True)
        pieces.append(_Piece(part, triangles, vertices, local.reshape(-1, 3).astype(np.uint32)))
    return pieces


def _read_result(path: Path, part_faces: list[int], pieces: list[_Piece], jittered: bool) -> Atlas:
    """The worker's atlas of `pieces`, put together per part: each piece's atlas vertices follow
    the previous pieces', its triangles go back to their places in the part."""
    with np.load(path) as data:
        width, height = int(data["width"]), int(data["height"])
        padded = np.array([-(-width // BLOCK) * BLOCK, -(-height // BLOCK) * BLOCK])
        # UVs are fractions of the atlas: scaled by old / new size, each texel keeps its place.
        shrink = np.array([width, height], dtype=np.float64) / padded
        vmappings, uvs = [[] for _ in part_faces], [[] for _ in part_faces]
        faces = [np.empty((m, 3), dtype=np.int64) for m in part_faces]
        offsets = [0] * len(part_faces)  # atlas vertices of each part so far
        for j, piece in enumerate(pieces):
            offset = offsets[piece.part]
            vmappings[piece.part].append(piece.vertices[data[f"vmapping_{j}"].astype(np.int64)])
            offsets[piece.part] += len(vmappings[piece.part][-1])
            uvs[piece.part].append(data[f"uvs_{j}"].astype(np.float64).reshape(-1, 2) * shrink)
            faces[piece.part][piece.triangles] = data[f"faces_{j}"].astype(np.int64).reshape(-1, 3) + offset
        parts = tuple(AtlasPart(np.concatenate(v), f, np.concatenate(u)) for v, f, u in zip(vmappings, faces, uvs))
        return Atlas(
            parts=parts,
            width=int(padded[0]),
            height=int(padded[1]),
            chart_count=int(data["chart_count"]),
            jittered=jittered,
            worker_peak_rss_mb=float(data["peak_rss_mb"]),
        )
