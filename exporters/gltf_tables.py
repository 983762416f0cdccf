"""Reading sssbake's data back from a .glb: the ``SSSBAKE_subsurface`` extension objects, their
tables found by name and checked, the ``_`` vertex attributes checked against what the file
declares, and stale data diagnosed with the tool that likely broke it.

The rules are those of ``exporters/schema/SSSBAKE_subsurface.md``: a table reference
``{"accessor", "name", "count", "type", "componentType", "crc32"}`` resolves to
``accessors[accessor]`` when that accessor bears ``name``, else to the one accessor that does;
its count, type, componentType and CRC-32 must then match. Anything else is stale data
(`StaleDataError`, one line naming the file, the table and the likely tool), never a silent read.
"""

from __future__ import annotations

import os
from collections.abc import Callable, Iterator
from dataclasses import dataclass

import numpy as np

from sssbake.exporters.gltf import (
    ENCODINGS,
    EXTENSION,
    accessor_elements,
    dequantize,
    element_array,
    table_crc32,
)
from sssbake.pipeline.core.errors import AssetError, StaleDataError
from sssbake.pipeline.mesh.baked import SCHEMA_VERSION
from sssbake.pipeline.mesh.confine import Confinement
from sssbake.pipeline.mesh.load_gltf import GltfObject, load_buffers, read_gltf_file

SCHEMA_MAJOR = SCHEMA_VERSION.split(".")[0]
#: The keys of a table reference, all required.
REFERENCE_KEYS = frozenset({"accessor", "name", "count", "type", "componentType", "crc32"})

#: ``asset.generator`` substring -> the tool named in stale-data errors, and the fix.
_TOOLS = (
    ("glTF-Transform", "glTF-Transform",
     "run it with sssbake's extension class (--config js/gltf-transform/sssbake.config.mjs) on the baked file"),
    ("gltfpack", "gltfpack", "gltfpack drops _ attributes and unknown extensions; use glTF-Transform with "
     "js/gltf-transform/sssbake.config.mjs instead, on the baked file"),
    ("Khronos glTF Blender I/O", "Blender (Khronos glTF Blender I/O)",
     "Blender's exporter keeps no vendor extension; bake its export again"),
)
_OTHER_FIX = f"bake the asset again, or process the file only with tools that keep the {EXTENSION} extension"


def likely_tool(gltf: GltfObject) -> tuple[str, str]:
    """Which tool most likely broke a file's sssbake data, from its ``asset.generator``, and what
    to do about it."""
    generator = _generator(gltf)
    for needle, tool, fix in _TOOLS:
        if needle in generator:
            return tool, fix
    return f"a tool that did not keep the {EXTENSION} extension", _OTHER_FIX


def _generator(gltf: GltfObject) -> str:
    """``asset.generator``, or ``""`` where the file has none (or something other than a string)."""
    generator = gltf.asset.generator if gltf.asset else None
    return generator if isinstance(generator, str) else ""


@dataclass(frozen=True)
class SssbakeGltf:
    """A .glb loaded for reading sssbake data.

    Attributes
    ----------
    path : str
    gltf : GltfObject
        The root object, its properties readable as attributes (`load_gltf.GltfObject`).
    blob : bytes or memoryview
        The binary chunk (a .gltf's buffers joined, `load_sssbake_gltf`).
    root : dict or None
        The root's ``SSSBAKE_subsurface`` object; None for a file sssbake never wrote.
    """

    path: str
    gltf: GltfObject
    blob: bytes | memoryview
    root: dict | None

    def stale(self, problem: str) -> StaleDataError:
        """`StaleDataError` for `problem`, with the tool that likely caused it."""
        generator = _generator(self.gltf)
        tool, fix = likely_tool(self.gltf)
        return StaleDataError(self.path, f"{problem}; likely broken by {tool} (asset.generator {generator!r}): {fix}")

    def extension(self, obj: GltfObject) -> dict | None:
        """`obj`'s ``SSSBAKE_subsurface`` object, or None."""
        ext = (obj.extensions or {}).get(EXTENSION)
        if ext is not None and (self.root is None or not isinstance(ext, dict)):
            raise self.stale(f"a {EXTENSION} object outside a file whose root has a valid one")
        return ext

    def resolve(self, ref, where: str) -> np.ndarray:
        """The table a reference points at, checked (`check_table`), in `read_accessor`'s shape:
        (count,), (count, k) or (count, k, k) of the component dtype."""
        index, elements = self.check_table(ref, where)
        return element_array(elements, self.gltf.accessors[index].type)

    def accessor(self, index, where: str) -> GltfObject:
        """``accessors[index]``; `stale` when `index` (named `where`) is not one of them."""
        accessors = self.gltf.accessors
        if not (isinstance(index, int) and not isinstance(index, bool) and 0 <= index < len(accessors)):
            raise self.stale(f"{where} names accessor {index!r}, not one of the file's {len(accessors)}")
        return accessors[index]

    def check_table(self, ref, where: str) -> tuple[int, np.ndarray]:
        """The accessor a table reference points at, and its elements, checked.

        Parameters
        ----------
        ref : dict
            A table reference.
        where : str
            Its JSON path, for messages (``meshes[0].extensions.SSSBAKE_subsurface.prt.lut``).

        Returns
        -------
        index : int
            The accessor bearing the reference's name.
        elements : (count, k) array of the component dtype
            `accessor_elements`.

        Raises
        ------
        StaleDataError
            No accessor or several bear the name, or count, type, componentType or CRC-32 differ.
        """
        if not isinstance(ref, dict) or set(ref) != REFERENCE_KEYS:
            raise self.stale(f"{where} is not a table reference {{{', '.join(sorted(REFERENCE_KEYS))}}}: {ref!r}")
        name, accessors = ref["name"], self.gltf.accessors
        index = ref["accessor"]
        if not (isinstance(index, int) and 0 <= index < len(accessors) and accessors[index].name == name):
            named = [i for i, acc in enumerate(accessors) if acc.name == name]
            if len(named) != 1:
                found = "no accessor" if not named else f"{len(named)} accessors ({named})"
                raise self.stale(f"sssbake table {name!r} ({where}): {found} bears its name")
            index = named[0]
        acc = accessors[index]
        for key, have in (("count", acc.count), ("type", acc.type), ("componentType", acc.componentType)):
            if have != ref[key]:
                raise self.stale(f"sssbake table {name!r} ({where}): accessor {index} has {key} {have!r}, "
                                 f"the reference {ref[key]!r}")
        try:
            elements = accessor_elements(self.gltf, index, self.blob)
        except (ValueError, IndexError, KeyError) as error:
            raise self.stale(f"sssbake table {name!r} ({where}): accessor {index} is unreadable ({error})") from None
        crc = table_crc32(elements)
        if crc != ref["crc32"]:
            raise self.stale(f"sssbake table {name!r} ({where}): accessor {index}'s data has CRC-32 {crc}, "
                             f"the reference {ref['crc32']}")
        return index, elements

    def resolved(self, value, where: str):
        """`value` (JSON from an extension object) with every table reference read into its array."""
        if isinstance(value, dict):
            if "accessor" in value:
                return self.resolve(value, where)
            return {k: self.resolved(v, f"{where}.{k}") for k, v in value.items()}
        if isinstance(value, list):
            return [self.resolved(v, f"{where}[{i}]") for i, v in enumerate(value)]
        return value

    def attribute(self, mesh: int, primitive: int, name: str) -> np.ndarray:
        """Vertex attribute `name` of a primitive, checked against the file's declaration and
        decoded (float64, glTF's normalized-integer decoding).

        Returns
        -------
        (p,) or (p, k) float64
            p the primitive's POSITION count.

        Raises
        ------
        StaleDataError
            Undeclared, missing, or with another componentType, normalized flag, type or count.
        """
        where = f"mesh {mesh} primitive {primitive}"
        listed = self.root.get("attributes", [])
        declared = {a["name"]: a.get("encoding") for a in (listed if isinstance(listed, list) else ())
                    if isinstance(a, dict) and isinstance(a.get("name"), str)}
        encoding = declared.get(name) if isinstance(name, str) else None
        if not isinstance(encoding, str) or encoding not in ENCODINGS:
            raise self.stale(f"{where}: attribute {name} is not declared in the root's {EXTENSION}.attributes")
        prim = self.gltf.meshes[mesh].primitives[primitive]
        index = getattr(prim.attributes, name, None)
        if index is None:
            raise self.stale(f"{where} lacks vertex attribute {name}")
        acc = self.accessor(index, f"{where}: attribute {name}")
        component, _, normalized = ENCODINGS[encoding]
        types = (self.extension(self.gltf.meshes[mesh]) or {}).get("attributeTypes", {})
        if not isinstance(types, dict):
            raise self.stale(f"mesh {mesh}: {EXTENSION}.attributeTypes is {types!r}, not an object")
        n = self.accessor(prim.attributes.POSITION, f"{where}: POSITION").count
        expected = (component, normalized, types.get(name, acc.type), n)
        have = (acc.componentType, bool(acc.normalized), acc.type, acc.count)
        if have != expected:
            raise self.stale(f"{where}: attribute {name} is componentType {have[0]}, normalized {have[1]}, {have[2]} "
                             f"x {have[3]}; declared {expected[0]}, {expected[1]}, {expected[2]} x {n} (POSITION)")
        try:
            elements = accessor_elements(self.gltf, index, self.blob)
        except (ValueError, IndexError, KeyError) as error:
            raise self.stale(f"{where}: attribute {name} (accessor {index}) is unreadable ({error})") from None
        return dequantize(element_array(elements, acc.type), normalized)


def load_sssbake_gltf(path: str | os.PathLike, required: bool = False) -> SssbakeGltf:
    """Load a .glb (or .gltf) and check its root ``SSSBAKE_subsurface`` object.

    The container and the JSON are read and checked by `load_gltf.read_gltf_file`, the reader every
    command shares, the buffers by `load_gltf.load_buffers` (each as long as its byteLength; files
    beside the asset only); several become one blob, each buffer view rebased onto it, as in a GLB.

    Parameters
    ----------
    path : str or os.PathLike
    required : bool
        Refuse a file without the root object (readers of technique data: a tool such as gltfpack
        dropped it, with every ``_`` attribute); else such a file loads with ``root`` None.

    Raises
    ------
    AssetError
        The file is not glTF that `read_gltf_file` reads (a GLB length field past the file's end,
        invalid or too deeply nested JSON, ...), or a buffer is missing or shorter than its byteLength.
    StaleDataError
        The file holds schema 1.x data (``extras.sssbake``), data of another major schema version,
        ``_`` vertex attributes with the extension gone (a tool dropped it), or (`required`) no
        sssbake data at all from a tool known to strip it (gltfpack, Blender, ...).
    AssetError
        (`required`) No sssbake data, and no tool known to strip it wrote the file: a plain glTF.
    """
    path = os.fspath(path)
    file = read_gltf_file(path)
    gltf = file.gltf
    # each buffer checked against the bytes that hold it (a GLB's BIN chunk, a file, a data: URI)
    buffers = load_buffers(path, gltf, file.blob, Confinement.for_asset(path), [])
    data = SssbakeGltf(path, gltf, buffers[0] if len(buffers) == 1 else _one_blob(gltf, buffers), None)
    root = (gltf.extensions or {}).get(EXTENSION)
    if root is None:
        if "sssbake" in (gltf.extras or {}):
            raise StaleDataError(path, "written by sssbake schema 1.x (extras.sssbake); rebake it with this version")
        custom = sorted({name for mesh in gltf.meshes for prim in mesh.primitives
                         for name in (prim.attributes or {}) if name.startswith("_")})
        if any(name.startswith(("_SSS_", "_THICKNESS")) for name in custom):
            raise data.stale(f"sssbake vertex attributes {custom} without the root's {EXTENSION} object")
        if required and likely_tool(gltf)[1] == _OTHER_FIX:  # no tool known to strip it wrote this file
            raise AssetError(path, f"no {EXTENSION} data: not a file sssbake baked (bake the asset with sssbake), "
                                   "or one a tool stripped it from")
        if required:
            raise data.stale(f"no {EXTENSION} data (sssbake writes it into every file it bakes)")
        return data
    version = root.get("schemaVersion") if isinstance(root, dict) else None
    if not isinstance(version, str) or version.split(".")[0] != SCHEMA_MAJOR:
        raise StaleDataError(path, f"{EXTENSION} schemaVersion {version!r}: this sssbake reads {SCHEMA_MAJOR}.x; "
                                   "rebake it with this version")
    return SssbakeGltf(path, gltf, data.blob, root)


def _one_blob(gltf: GltfObject, buffers: tuple[bytes | memoryview, ...]) -> bytes:
    """`buffers` as one blob, each 4-byte aligned, every buffer view's byteOffset moved onto it and its
    buffer set to 0: the tables' readers address one blob, as in a GLB."""
    starts = np.cumsum([0] + [len(b) + -len(b) % 4 for b in buffers])
    for view in gltf.bufferViews:
        if isinstance(view.buffer, int) and 0 <= view.buffer < len(buffers):
            view.byteOffset = int(starts[view.buffer]) + (view.byteOffset or 0)
            view.buffer = 0
    return b"".join(bytes(b) + bytes(-len(b) % 4) for b in buffers)


def technique_tables(data: SssbakeGltf, owner: str, index: int, technique: str) -> dict | None:
    """``meshes[index]`` (`owner` ``"meshes"``) or ``materials[index]``'s `technique` object with
    every table reference read into its array (`SssbakeGltf.resolve`); None when it has none."""
    obj = getattr(data.gltf, owner)[index]
    tables = (data.extension(obj) or {}).get(technique)
    if tables is None:
        return None
    return data.resolved(tables, f"{owner}[{index}].extensions.{EXTENSION}.{technique}")


def technique_primitives(data: SssbakeGltf, technique: str, names: Callable[[dict], list[str]]
                         ) -> Iterator[tuple[int, dict, list[dict[str, np.ndarray]]]]:
    """Each mesh whose extension object has `technique`, as (mesh index, its `technique_tables`,
    per primitive {attribute name: float64 values}) for the attributes ``names(tables)`` lists,
    each checked by `SssbakeGltf.attribute`."""
    for i, mesh in enumerate(data.gltf.meshes):
        tables = technique_tables(data, "meshes", i, technique)
        if tables is None:
            continue
        wanted = names(tables)
        yield i, tables, [{name: data.attribute(i, j, name) for name in wanted} for j in range(len(mesh.primitives))]
