"""OBJ, PLY and STL through trimesh, unprocessed (no merging or cleaning: that is a later stage).

trimesh is lenient with broken files (a truncated STL loads as nothing, a PLY whose header
overstates its vertex count loads as garbage), so the headers are checked here first to name
the actual problem.
"""

from __future__ import annotations

import io
import os
import re
import warnings
from pathlib import Path

import numpy as np
import PIL.Image
import trimesh

from sssbake.pipeline.core.errors import AssetError
from sssbake.pipeline.mesh.confine import Confinement
from sssbake.pipeline.mesh.digest import bytes_digest
from sssbake.pipeline.mesh.scene import Image, Mesh, Node, Primitive, Scene, SourceMaterial, Texture, TextureRef

PLY_TYPES = {  # PLY property type → numpy type
    "char": "i1", "uchar": "u1", "int8": "i1", "uint8": "u1",
    "short": "i2", "ushort": "u2", "int16": "i2", "uint16": "u2",
    "int": "i4", "uint": "u4", "int32": "i4", "uint32": "u4",
    "float": "f4", "float32": "f4", "double": "f8", "float64": "f8",
}
PLY_BYTE_ORDERS = {"binary_little_endian": "<", "binary_big_endian": ">"}
PLY_FACE_LISTS = ("vertex_indices", "vertex_index")


def load_trimesh(path: str, confinement: Confinement | None = None) -> Scene:
    """Read an OBJ, PLY or STL file.

    One `Mesh` (one primitive) per trimesh geometry, one node per geometry instance. The
    formats carry no unit, so ``meters_per_unit`` is None; up axis ``"Y"``.

    Parameters
    ----------
    path : str
    confinement : Confinement or None
        Where an OBJ's material libraries and textures may lie (default: the asset's folder only).

    Returns
    -------
    Scene
        Positions (n, 3) float64, faces (m, 3) int64; vertex normals (n, 3) only when the file
        has them; UVs (n, 2) flipped to glTF convention (v down); vertex colours (n, 4) in [0, 1].

    Raises
    ------
    AssetError
        Truncated PLY/STL, malformed vertex line or face index out of range in an OBJ, no triangles.
    """
    ext = Path(path).suffix.lower()
    data = Path(path).read_bytes()
    if ext == ".ply":
        _check_ply(path, data)
    elif ext == ".stl":
        _check_stl(path, data)
    else:
        _check_obj_zero_index(path, data)
    kwargs = {"split_objects": True} if ext == ".obj" else {}
    confinement = confinement or Confinement.for_asset(path)
    resolver = _ConfinedResolver(path, confinement, _obj_mtllib(data) if ext == ".obj" else "")
    try:
        # From the bytes already read: trimesh opens nothing itself, so it parses what was checked
        # above, and names no mesh after a file name it could not encode (`_mesh_names`).
        loaded = trimesh.load_scene(io.BytesIO(data), file_type=ext[1:], process=False, resolver=resolver, **kwargs)
    except (IndexError, OverflowError) as e:  # OverflowError: trimesh's int64 cast of an index past its range
        if ext == ".obj":
            raise AssetError(path, _obj_index_problem(data)) from e
        raise
    except ValueError as e:
        short = _obj_short_vertex(data) if ext == ".obj" else None
        if short:
            raise AssetError(path, short) from e
        raise
    if resolver.refused is not None:
        raise resolver.refused
    label = _mesh_names(loaded, ext, resolver.file_name)
    meshes: list[Mesh] = []
    names: dict[str, int] = {}
    materials: dict[str | int, int] = {}
    material_list: list[SourceMaterial] = []
    images: list[Image] = []
    has_materials = ext == ".obj" and b"usemtl" in data
    points = 0
    for name, geom in loaded.geometry.items():
        if not isinstance(geom, trimesh.Trimesh):
            points += len(getattr(geom, "vertices", ()))
            continue
        material = None
        if has_materials and getattr(geom.visual, "material", None) is not None:
            # Objects split from one OBJ carry copies of a shared MTL material: one entry per name.
            key = geom.visual.material.name or id(geom.visual.material)
            if key not in materials:
                materials[key] = len(material_list)
                material_list.append(_material(geom.visual.material, len(material_list), images))
            material = materials[key]
        names[name] = len(meshes)
        meshes.append(Mesh(label.get(name, name), (_primitive(geom, material),)))
    if not any(len(m.primitives[0].faces) for m in meshes):
        found = f"{points} vertices but no faces" if points else "no geometry"
        raise AssetError(path, f"no triangles: the file has {found}")
    nodes = []
    for node_name in loaded.graph.nodes_geometry:
        matrix, geom_name = loaded.graph[node_name]
        if geom_name in names:
            nodes.append(Node(str(label.get(node_name, node_name)), np.asarray(matrix, np.float64), names[geom_name]))
    return Scene(
        source=path,
        meshes=tuple(meshes),
        nodes=tuple(nodes),
        roots=tuple(range(len(nodes))),
        materials=tuple(material_list),
        textures=tuple(Texture(i) for i in range(len(images))),
        images=tuple(images),
        up_axis="Y",
        meters_per_unit=None,
        dependencies=tuple(dict.fromkeys(resolver.read)),
    )


def _mesh_names(loaded: trimesh.Scene, ext: str, file_name: str) -> dict[str, str]:
    """trimesh's name -> ours, for the one name that differs: trimesh names a PLY's or an STL's lone
    unnamed geometry after the file it opened, and ``geometry_0`` when given bytes; ours is then the
    file's name (`_ConfinedResolver.file_name`), as an OBJ's unnamed object gets from trimesh."""
    return {"geometry_0": file_name} if ext != ".obj" and list(loaded.geometry) == ["geometry_0"] else {}


class _ConfinedResolver(trimesh.resolvers.FilePathResolver):
    """trimesh's file resolver for an OBJ's ``mtllib`` and ``map_Kd`` and a PLY's ``TextureFile``,
    reading only what the confinement allows.

    A name is taken from the folder the asset is named in, then from the folder its real file
    lies in (a symlinked asset's companions may sit beside either). trimesh swallows whatever a
    material library or texture raises and goes on without it, so the first refusal is kept in
    `refused` for the loader to raise once trimesh returns.
    """

    def __init__(self, path: str, confinement: Confinement, mtllib: str):
        super().__init__(path)
        # What an OBJ's unnamed object is named after (and `_mesh_names` a PLY's or STL's mesh):
        # bytes of the name that are not UTF-8 as \xNN, since trimesh encodes names as UTF-8
        self.file_name = os.fsencode(os.path.basename(path)).decode("utf-8", "backslashreplace")
        self.confinement = confinement
        self.mtllib = mtllib
        self.folders = tuple(dict.fromkeys([self.parent, os.path.dirname(os.path.realpath(path))]))
        self.refused: AssetError | None = None
        self.read: list[tuple[str, str]] = []  # the files read and their digests (`Scene.dependencies`)

    def get(self, name: str) -> bytes:
        name = name.strip()
        what = f"{'material library' if name == self.mtllib else 'texture'} '{name}'"
        # os.path.join keeps an absolute name absolute: it is checked, not re-rooted.
        targets = [os.path.join(folder, name) for folder in self.folders]
        target = next((t for t in targets if os.path.lexists(t)), targets[0])
        try:
            real = self.confinement.check(target, what)
        except AssetError as e:
            self.refused = self.refused or e
            raise
        try:
            data = real.read_bytes()
        except FileNotFoundError:  # trimesh goes on without it; its appearing later changes the bake
            self.read.append((str(real), ""))
            raise
        self.read.append((str(real), bytes_digest(data)))
        if name != self.mtllib:
            try:
                _check_texture_pixels(self.confinement.asset, what, data)
            except AssetError as e:
                self.refused = self.refused or e
                raise
        return data


def _check_texture_pixels(path: str, what: str, data: bytes) -> None:
    """Refuse a texture whose header declares more pixels than PIL decodes without complaint
    (``PIL.Image.MAX_IMAGE_PIXELS``, 89 M by default): trimesh decodes it in full, and a small file
    of 100000 × 100000 pixels is a decompression bomb. Only the header is read here; bytes PIL cannot
    identify are left to trimesh, which goes on without them."""
    limit = PIL.Image.MAX_IMAGE_PIXELS
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always", PIL.Image.DecompressionBombWarning)
        try:
            with PIL.Image.open(io.BytesIO(data)) as image:
                width, height = image.size
        except PIL.Image.DecompressionBombError as e:  # over twice the limit: PIL gives no size, only its count
            raise AssetError(path, f"{what} is over the {limit / 1e6:.0f} M pixel limit of "
                                   f"PIL.Image.MAX_IMAGE_PIXELS ({e})") from None
        except (PIL.UnidentifiedImageError, OSError, ValueError):
            return
    if any(issubclass(w.category, PIL.Image.DecompressionBombWarning) for w in caught):
        raise AssetError(path, f"{what} is {width} × {height} pixels, over the {limit / 1e6:.0f} M pixel limit "
                               "of PIL.Image.MAX_IMAGE_PIXELS")


def _obj_mtllib(data: bytes) -> str:
    """The material library an OBJ names: what follows its first ``mtllib``, as trimesh reads it."""
    start = data.find(b"mtllib")
    if start < 0:
        return ""
    end = data.find(b"\n", start)
    return data[start + 6 : end if end >= 0 else len(data)].decode("utf-8", "replace").strip()


def _check_obj_zero_index(path: str, data: bytes) -> None:
    """Refuse an OBJ face corner whose vertex, texture or normal index is 0 (OBJ counts from 1).

    Vectorised over the file's bytes (no Python loop over lines): a token of zeros (``0``,
    ``-0``, ``00``) after a space, tab or slash, on a line whose first word is ``f``.
    """
    text = np.frombuffer(data, np.uint8)
    padded = np.append(text, np.frombuffer(b"\n", np.uint8))  # the file's end ends the last token

    def one_of(values: bytes, at: np.ndarray | slice = slice(None)) -> np.ndarray:
        chosen = padded[at]
        return np.logical_or.reduce([chosen == v for v in values])

    separator = one_of(b" \t/", slice(None, -1))
    before = np.zeros(len(text), bool)  # the bytes before position i end a token
    before[1:] = separator[:-1]
    before[2:] |= one_of(b"+-", slice(1, -2)) & separator[:-2]
    starts = np.flatnonzero(before & (text == ord("0")))
    end = starts + 1
    while True:  # past the run of zeros: as many passes as the longest run
        more = padded[end] == ord("0")
        if not more.any():
            break
        end += more
    starts = starts[one_of(b" \t/\r\n", end)]
    if not len(starts):
        return
    newlines = np.flatnonzero(text == ord("\n"))
    line = np.searchsorted(newlines, starts)
    first = np.append(0, newlines + 1)[line]
    while True:  # past the indentation of the candidate lines
        blank = one_of(b" \t", first)
        if not blank.any():
            break
        first += blank
    face = (padded[first] == ord("f")) & one_of(b" \t", first + 1)
    if face.any():
        raise AssetError(path, f"face index 0 on line {int(line[face][0]) + 1}: OBJ indices start at 1 "
                               "(negative ones count back)")


def _primitive(geom: trimesh.Trimesh, material: int | None) -> Primitive:
    """Arrays of one trimesh geometry, keeping only what the file stated."""
    n = len(geom.vertices)
    # trimesh computes vertex normals lazily; they sit in the cache before any access only when
    # the loader read them from the file.
    normals = geom._cache.cache.get("vertex_normals")
    uvs: tuple[np.ndarray, ...] = ()
    uv = getattr(geom.visual, "uv", None) if geom.visual.kind == "texture" else None
    if uv is not None and len(uv) == n:
        uv = np.asarray(uv, np.float64)
        # OBJ's "vt u" leaves v at 0; trimesh cuts every vt row to the shortest one's length.
        v = uv[:, 1] if uv.shape[1] > 1 else np.zeros(n)
        uvs = (np.column_stack([uv[:, 0], 1.0 - v]),) if uv.shape[1] else ()
    if geom.visual.kind == "vertex":
        colors = np.asarray(geom.visual.vertex_colors, np.float64) / 255.0
    else:
        colors = _ply_colors(geom.metadata.get("_ply_raw"), n)
    return Primitive(
        positions=np.asarray(geom.vertices, np.float64),
        faces=np.asarray(geom.faces, np.int64).reshape(-1, 3),
        normals=None if normals is None or len(normals) != n else np.asarray(normals, np.float64),
        uvs=uvs,
        colors=colors,
        material=material,
    )


def _ply_colors(raw: dict | None, n: int) -> np.ndarray | None:
    """(n, 4) float64 colours from a PLY's raw vertex properties, or None.

    trimesh drops vertex colours when the PLY also has UVs; the raw element data keeps them.
    """
    if not raw or "vertex" not in raw:
        return None
    data = raw["vertex"]["data"]
    fields = data.dtype.names if isinstance(data, np.ndarray) else tuple(data)
    if not fields or not all(c in fields for c in ("red", "green", "blue")):
        return None
    channels = [np.asarray(data[c]).reshape(-1) for c in ("red", "green", "blue", "alpha") if c in fields]
    if len(channels[0]) != n:
        return None
    rgba = np.column_stack([_unit(c) for c in channels])
    return rgba if rgba.shape[1] == 4 else np.column_stack([rgba, np.ones(n)])


def _unit(channel: np.ndarray) -> np.ndarray:
    """Integer colour channel to [0, 1] by its type's range; float channels are taken as is."""
    if channel.dtype.kind in "ui":
        return channel.astype(np.float64) / np.iinfo(channel.dtype).max
    return channel.astype(np.float64)


def _material(material, index: int, images: list[Image]) -> SourceMaterial:
    """A `SourceMaterial` from a trimesh (MTL) material; a base colour image is re-encoded as PNG."""
    pbr = material.to_pbr() if hasattr(material, "to_pbr") else material
    factor = np.asarray(pbr.baseColorFactor if pbr.baseColorFactor is not None else (255, 255, 255, 255))
    factor = factor / 255.0 if factor.dtype.kind in "ui" else factor.astype(np.float64)
    texture = None
    image = getattr(pbr, "baseColorTexture", None)
    if image is not None:
        buf = io.BytesIO()
        image.save(buf, format="PNG")
        texture = TextureRef(len(images))
        name = material.name or f"material_{index}"
        images.append(Image(f"{name}_base_color", "image/png", buf.getvalue()))
    return SourceMaterial(
        name=material.name or f"material_{index}",
        base_color_factor=tuple(float(x) for x in np.resize(factor, 4)),
        base_color_texture=texture,
    )


def _obj_index_problem(data: bytes) -> str:
    """Name the first out-of-range vertex index of an OBJ's faces (trimesh only says IndexError)."""
    text = data.decode("utf-8", "replace")
    count = len(re.findall(r"^v\s", text, re.M))
    face_text = "\n".join(re.findall(r"^f\s+(.*)$", text, re.M))
    # The first number of each corner ("7", "7/2", "7//3") is the vertex index.
    # Python ints: an index past int64 ("f 1 2 18446744073709551616") is named, not overflowed.
    index = np.array([int(i) for i in re.findall(r"(?:^|\s)(-?\d+)", face_text)], dtype=object)
    bad = index[(index > count) | (index < -count) | (index == 0)]
    if not len(bad):
        return f"face index out of range for {count} vertices (texture or normal index out of range?)"
    return f"face index {int(bad[0])} out of range for {count} vertices"


def _obj_short_vertex(data: bytes) -> str | None:
    """Name the first ``v`` line without three numbers (numpy's parser only says ValueError)."""
    text = data.decode("utf-8", "replace")
    number = r"[-+]?(?:\d+\.?\d*|\.\d+)(?:e[-+]?\d+)?|[-+]?(?:nan|inf)"
    bad = re.search(rf"^v(?!(?:[ \t]+(?:{number})){{3}}(?:\s|$))[ \t].*$", text, re.M | re.I)
    if bad is None:
        return None
    line = text.count("\n", 0, bad.start()) + 1
    return f"line {line}: vertex '{bad.group(0).strip()[:40]}' does not start with 3 numbers (truncated file?)"


def _check_ply(path: str, data: bytes) -> None:
    """Check a PLY's face lists, then compare its header with the size of its data; raise `AssetError`
    naming the first problem (a face of fewer than 3 vertices, a face index that is not a whole number
    of the list's type, missing data)."""
    end = data.find(b"end_header")
    if not data.startswith(b"ply") or end < 0:
        raise AssetError(path, "not a PLY file: no 'ply ... end_header' header")
    body_start = data.find(b"\n", end)
    body = data[body_start + 1 :] if body_start >= 0 else b""
    fmt = None
    elements: list[list] = []  # [name, count, [(property, list count type or None, value type), ...]]
    for line in data[:end].decode("ascii", "replace").splitlines():
        words = line.split()
        if not words:
            continue
        if words[0] == "format" and len(words) > 1:
            fmt = words[1]
        elif words[0] == "element" and len(words) == 3 and words[2].isdigit():
            elements.append([words[1], int(words[2]), []])
        elif words[0] == "property" and elements and len(words) >= 3:
            if words[1] == "list" and len(words) == 5:
                elements[-1][2].append((words[4], words[2], words[3]))
            else:
                elements[-1][2].append((words[2], None, words[1]))
    if fmt is None:
        raise AssetError(path, "corrupt PLY header: no 'format' line")
    if fmt == "ascii":
        _check_ply_ascii_faces(path, elements, body, data[:body_start + 1].count(b"\n"))
    elif fmt in PLY_BYTE_ORDERS:
        _check_ply_binary_faces(path, elements, body, PLY_BYTE_ORDERS[fmt])

    def least(props: list, unit) -> int:
        # a face list holds at least 3 items; other lists may be empty
        return sum(unit(kind) if counted is None else unit(counted) + (3 * unit(kind) if name in PLY_FACE_LISTS else 0)
                   for name, counted, kind in props)

    declared = ", ".join(f"{count} '{name}'" for name, count, _ in elements) + " elements"
    if fmt == "ascii":
        values, needed = len(body.split()), sum(count * least(props, lambda kind: 1) for _, count, props in elements)
        if values < needed:
            raise AssetError(
                path, f"truncated file: header declares {declared}; the data ends after {values} of at least {needed} values"
            )
    else:
        size = lambda kind: np.dtype(PLY_TYPES[kind]).itemsize if kind in PLY_TYPES else 0  # noqa: E731
        needed = sum(count * least(props, size) for _, count, props in elements)
        if len(body) < needed:
            raise AssetError(
                path, f"truncated file: header declares {declared}; the data ends after {len(body)} of at least {needed} bytes"
            )


def _face_layout(elements: list) -> tuple[int, list, int] | None:
    """Where the face lists are: (index of the 'face' element, its properties, the position of its
    vertex-index list among them), or None when the file has no such list, the list is not the
    element's only list, or a property's type is unknown (trimesh refuses those itself)."""
    for e, (name, _, props) in enumerate(elements):
        lists = [i for i, (prop, counted, _) in enumerate(props) if counted is not None]
        if name == "face" and lists and props[lists[0]][0] in PLY_FACE_LISTS:
            known = all(kind in PLY_TYPES and (counted is None or counted in PLY_TYPES) for _, counted, kind in props)
            return (e, props, lists[0]) if len(lists) == 1 and known else None
    return None


def _check_face_lists(path: str, lengths: np.ndarray, where) -> None:
    """Refuse the first face whose list holds fewer than 3 vertices; `where(k)` names face k."""
    short = np.flatnonzero(lengths < 3)
    if len(short):
        k = int(short[0])
        raise AssetError(path, f"{where(k)} has {int(lengths[k])} vertices; a face needs at least 3")


def _check_face_indices(path: str, values: np.ndarray, kind: str, shown, face_of, where,
                        what: str = "face index") -> None:
    """Refuse the first face index that is not a whole number or does not fit the list's value type
    (trimesh's cast would turn NaN or 1e30 into -2147483648).

    Parameters
    ----------
    values : (n,) float64
        The face indices as read.
    kind : str
        The list's PLY value type.
    shown : callable
        Position in `values` → the value as the file writes it.
    face_of : callable
        Positions (k,) int64 → the faces (k,) int64 they belong to; `where(face)` names a face.
    what : str
        What the values are, for the message.
    """
    whole = np.isfinite(values) & (np.floor(values) == values)
    bad = np.flatnonzero(~whole)
    if len(bad):
        i = int(bad[0])
        raise AssetError(path, f"{what} {shown(i)} on {where(int(face_of(bad[:1])[0]))} is not a whole number")
    limits = np.iinfo(PLY_TYPES[kind]) if np.dtype(PLY_TYPES[kind]).kind in "iu" else np.iinfo(np.int64)
    bad = np.flatnonzero((values < limits.min) | (values > limits.max))
    if len(bad):
        i = int(bad[0])
        raise AssetError(path, f"{what} {shown(i)} on {where(int(face_of(bad[:1])[0]))} does not fit the "
                               f"face list's {kind} type")


def _check_ply_ascii_faces(path: str, elements: list, body: bytes, header_lines: int) -> None:
    """Check an ASCII PLY's face lists, one face per line as trimesh reads them; vectorised over the
    face lines' tokens. A line too short to hold its list is left to the truncation check."""
    layout = _face_layout(elements)
    if layout is None:
        return
    e, props, at = layout
    first_line = sum(count for _, count, _ in elements[:e])
    faces = elements[e][1]
    text = np.frombuffer(body, np.uint8)
    newlines = np.flatnonzero(text == ord("\n"))
    if first_line > len(newlines) or not faces:
        return
    start = 0 if first_line == 0 else int(newlines[first_line - 1]) + 1
    stop = int(newlines[first_line + faces - 1]) if first_line + faces - 1 < len(newlines) else len(body)
    block = text[start:stop]
    tokens = body[start:stop].split()
    try:
        numbers = np.array(tokens, dtype=np.float64)
    except ValueError:
        return  # a word that is no number: trimesh's parser refuses the file itself
    # bytes.split's whitespace: a token starts where a non-space byte follows a space or the block's start
    space = np.isin(block, np.frombuffer(b" \t\n\r\x0b\x0c", np.uint8))
    starts = np.flatnonzero(~space & np.append(True, space[:-1]))
    line_breaks = np.flatnonzero(block == ord("\n"))
    per_line = np.bincount(np.searchsorted(line_breaks, starts), minlength=faces)[:faces]
    first_token = np.cumsum(per_line) - per_line
    if (per_line <= at).any():
        return
    lengths = numbers[first_token + at]
    where = lambda k: f"face {k} (line {header_lines + first_line + k + 1})"  # noqa: E731
    _check_face_indices(path, lengths, props[at][1], lambda i: repr(tokens[first_token[i] + at].decode()),
                        lambda i: i, where, "vertex count")
    lengths = lengths.astype(np.int64)
    _check_face_lists(path, lengths, where)
    if (lengths > per_line - at - 1).any():
        return
    face = np.repeat(np.arange(faces), lengths)
    positions = first_token[face] + at + 1 + np.arange(len(face)) - np.repeat(np.cumsum(lengths) - lengths, lengths)
    _check_face_indices(path, numbers[positions], props[at][2], lambda i: repr(tokens[positions[i]].decode()),
                        lambda i: face[i], where)


def _check_ply_binary_faces(path: str, elements: list, body: bytes, order: str) -> None:
    """Check a binary PLY's face lists as trimesh reads them: every list as long as the first one
    (vectorised); the first face whose count differs is named."""
    layout = _face_layout(elements)
    if layout is None:
        return
    e, props, at = layout
    kinds = [k for _, _, element_props in elements[:e + 1] for _, _, k in element_props] + [props[at][1]]
    if any(k not in PLY_TYPES for k in kinds):
        return  # a type PLY does not have: trimesh's to report
    dtype = lambda kind: np.dtype(PLY_TYPES[kind]).newbyteorder(order)  # noqa: E731
    start = 0
    for _, count, element_props in elements[:e]:
        if any(counted is not None for _, counted, _ in element_props):
            return  # lists before the faces: their lengths are trimesh's to read
        start += count * sum(dtype(kind).itemsize for _, _, kind in element_props)
    counted, kind = dtype(props[at][1]), dtype(props[at][2])
    before = sum(dtype(k).itemsize for _, _, k in props[:at])
    after = sum(dtype(k).itemsize for _, _, k in props[at + 1:])
    text = np.frombuffer(body, np.uint8)
    faces = elements[e][1]

    def read(positions: np.ndarray, of: np.dtype) -> np.ndarray:
        return text[positions[:, None] + np.arange(of.itemsize)].view(of).reshape(-1).astype(np.float64)

    first = start + before
    if not faces or first + counted.itemsize > len(body):
        return
    length = int(read(np.array([first]), counted)[0])
    stride = before + counted.itemsize + max(length, 0) * kind.itemsize + after
    fits = max(0, min(faces, (len(body) - first - counted.itemsize) // stride + 1))
    lengths = read(first + stride * np.arange(fits), counted)
    differs = np.flatnonzero(lengths != length)
    where = lambda k: f"face {k}"  # noqa: E731
    _check_face_lists(path, lengths[: differs[0] + 1 if len(differs) else fits].astype(np.int64), where)
    if len(differs):
        k = int(differs[0])
        raise AssetError(path, f"face {k} has {int(lengths[k])} vertices and face 0 has {length}: a binary PLY's faces "
                               "must all have one vertex count here (triangulate it)")
    if kind.kind == "f":
        whole = (len(body) - first - counted.itemsize - length * kind.itemsize) // stride + 1
        items = np.arange(min(fits, max(whole, 0)) * length)
        positions = first + counted.itemsize + stride * (items // length) + kind.itemsize * (items % length)
        values = read(positions, kind)
        _check_face_indices(path, values, props[at][2], lambda i: repr(float(values[i])), lambda i: i // length, where)


def _check_stl(path: str, data: bytes) -> None:
    """Raise `AssetError` for an STL whose data does not match its triangle count.

    A binary STL whose file holds more than its header's count is refused rather than read:
    either count could be the wrong one (a writer that never filled the count in, or data
    appended to the file), and reading by the header silently drops triangles.
    """
    count = int(np.frombuffer(data, "<u4", 1, 80)[0]) if len(data) >= 84 else None
    if count is not None and 84 + 50 * count == len(data):
        return
    # A binary STL's header may start with "solid" too, but its records hold NUL bytes and no keywords;
    # a text file with a stray NUL is still text when it has them.
    if data.lstrip()[:5].lower() == b"solid" and (b"\0" not in data or re.search(rb"\b(?:facet|endsolid)\b", data)):
        nul = data.find(b"\0")
        if nul >= 0:
            line = data.count(b"\n", 0, nul) + 1
            raise AssetError(path, f"ASCII STL holds a NUL byte on line {line}: "
                                   "the text is damaged; re-export the file")
        if data.rfind(b"endsolid") < 0:
            raise AssetError(path, "truncated file: ASCII STL without 'endsolid'")
        return
    if count is None:
        raise AssetError(path, f"truncated file: {len(data)} bytes, shorter than the 84-byte binary STL header")
    declared = f"header declares {count} triangle{'s' if count != 1 else ''} ({84 + 50 * count} bytes)"
    if 84 + 50 * count > len(data):
        raise AssetError(path, f"truncated file: {declared}, the file has {len(data)} bytes")
    held, extra = divmod(len(data) - 84, 50)
    rest = f" and {extra} more bytes" if extra else ""
    raise AssetError(path, f"{declared} but the file holds {held} triangles{rest} ({len(data)} bytes); "
                           "fix the count at byte 80 or re-export the file")
