"""Reads an asset file into a `Scene`: dispatch by file extension, the shared `AssetError`, and
the checks every reader's output must pass (finite positions, face indices in range, triangles).
"""

from __future__ import annotations

import contextlib
import logging
import os
import warnings
from pathlib import Path

import numpy as np

from sssbake.pipeline.core.errors import AssetError
from sssbake.pipeline.mesh.scene import Scene

SUPPORTED_EXTENSIONS = (".obj", ".ply", ".stl", ".gltf", ".glb", ".usd", ".usda", ".usdc")


def load_scene(path: str | os.PathLike, allow_roots: tuple[str, ...] = ()) -> Scene:
    """Read an OBJ, PLY, STL, glTF/GLB or USD file.

    Parameters
    ----------
    path : str or os.PathLike
    allow_roots : tuple of str
        Folders besides the asset's own that the files it references may lie in
        (`confine.Confinement`); a reference outside them all is refused.

    Returns
    -------
    Scene
        ``source`` is ``str(path)``; arrays as documented in `sssbake.pipeline.mesh.scene`.

    Raises
    ------
    AssetError
        For every problem with the file (missing, unsupported type, truncated, corrupt, no
        triangles, non-finite positions, face indices out of range, a reference outside the
        allowed folders) and a Python module its reader lacks; no other exception escapes for a
        bad file.
    """
    path = os.fspath(path)
    ext = Path(path).suffix.lower()
    if ext not in SUPPORTED_EXTENSIONS:
        raise AssetError(
            path, f"unsupported file type '{ext or Path(path).name}' (supported: {', '.join(SUPPORTED_EXTENSIONS)})"
        )
    try:
        size = os.stat(path).st_size
    except FileNotFoundError:
        raise AssetError(path, "file not found") from None
    except OSError as e:
        raise AssetError(path, f"cannot read file: {e.strerror or e}") from None
    if os.path.isdir(path):
        raise AssetError(path, "is a folder, not a file")
    if size == 0:
        raise AssetError(path, "empty file (0 bytes)")
    if ext in (".usd", ".usda", ".usdc") and not _utf8(path):
        # pxr takes a path as UTF-8 text, and a layer is known by its path
        raise AssetError(path, "USD cannot open a file whose path is not UTF-8: rename it")
    from sssbake.pipeline.mesh.confine import Confinement

    try:
        with _quiet_parsers():
            scene = _reader(ext)(path, Confinement.for_asset(path, allow_roots))
    except AssetError:
        raise
    except ImportError as e:  # a missing library is not a corrupt file (parsers import some on the way)
        raise AssetError(path, _missing_module(e)) from e
    except OSError as e:
        raise AssetError(path, f"cannot read file: {e.strerror or e}") from e
    except Exception as e:  # any parser failure on a bad file must reach the user as one line
        detail = str(e).splitlines()[0] if str(e) else ""
        raise AssetError(path, f"corrupt {ext[1:].upper()} file ({type(e).__name__}: {detail})") from e
    check_scene(scene)
    return scene


def _utf8(path: str) -> bool:
    """Whether `path` is UTF-8 (os.fsdecode escapes the bytes of a name that is not)."""
    try:
        path.encode("utf-8")
    except UnicodeEncodeError:
        return False
    return True


def _reader(ext: str):
    """The reader of files with extension `ext`."""
    # Imported here, not at module level: they import AssetError from this module, and a glTF-only
    # batch need not pay for importing trimesh or pxr.
    if ext in (".gltf", ".glb"):
        from sssbake.pipeline.mesh.load_gltf import load_gltf

        return load_gltf
    if ext in (".usd", ".usda", ".usdc"):
        from sssbake.pipeline.mesh.load_usd import load_usd

        return load_usd
    from sssbake.pipeline.mesh.load_trimesh import load_trimesh

    return load_trimesh


# Modules whose pip package has another name.
_PIP_NAMES = {"PIL": "pillow", "pxr": "usd-core"}


def _missing_module(e: ImportError) -> str:
    """What to say when reading a file fails on `e`: which module, and how to install it."""
    top = (e.name or "").split(".")[0]
    if not top:  # a library's own ImportError, naming no module
        return f"needs a Python module that failed to import ({e})"
    return f"needs the Python module {top} ({e}): pip install {_PIP_NAMES.get(top, top.replace('_', '-'))}"


@contextlib.contextmanager
def _quiet_parsers():
    """Mute what parsers say about a broken file on their way to a result or an exception.

    numpy warns (overflow in a cast) and trimesh logs tracebacks of what it recovered from; on the
    command line both land on stderr as screenfuls. The readers' checks decide, in one line.
    """
    log = logging.getLogger("trimesh")
    level = log.level
    log.setLevel(logging.CRITICAL)
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", RuntimeWarning)
            yield
    finally:
        log.setLevel(level)


def check_scene(scene: Scene) -> None:
    """Refuse a scene that later stages cannot work with.

    Checks every primitive for (n, 3) positions that are all finite, finite UVs and colours, and
    (m, 3) faces whose indices lie in ``[0, n)``, and the scene for at least one triangle.

    Raises
    ------
    AssetError
        Naming ``scene.source``, the mesh and the problem.
    """
    total_faces = 0
    total_vertices = 0
    for mesh in scene.meshes:
        for prim in mesh.primitives:
            pos, faces = prim.positions, prim.faces
            where = f"in mesh '{mesh.name}'"
            if pos.ndim != 2 or pos.shape[1] != 3:
                raise AssetError(scene.source, f"vertex positions have shape {pos.shape}, expected (n, 3) {where}")
            if faces.ndim != 2 or faces.shape[1] != 3:
                raise AssetError(scene.source, f"faces have shape {faces.shape}, expected (m, 3) {where}")
            bad = int(np.count_nonzero(~np.isfinite(pos).all(axis=1)))
            if bad:
                raise AssetError(scene.source, f"non-finite vertex positions ({bad} of {len(pos)}) {where}")
            # Normals and tangents that are not finite are recomputed by cleaning; UVs and colours cannot be.
            named = [(f"texture coordinates (UV set {k})", uv) for k, uv in enumerate(prim.uvs)]
            for what, values in named + [("vertex colours", prim.colors)]:
                bad = 0 if values is None else int(np.count_nonzero(~np.isfinite(values).all(axis=1)))
                if bad:
                    raise AssetError(scene.source, f"non-finite {what} ({bad} of {len(values)} vertices) {where}")
            if faces.size:
                lo, hi = int(faces.min()), int(faces.max())
                if lo < 0:
                    raise AssetError(scene.source, f"negative face index {lo} {where}")
                if hi >= len(pos):
                    raise AssetError(scene.source, f"face index {hi} out of range for {len(pos)} vertices {where}")
            total_faces += len(faces)
            total_vertices += len(pos)
    if total_faces == 0:
        raise AssetError(scene.source, f"no triangles ({total_vertices} vertices, 0 faces)")
