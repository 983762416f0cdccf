"""What sssbake data a .glb holds: schema version, ``_`` attributes and technique tables with their
bytes, extensions. Every table and ``_`` attribute is checked as the readers check them
(`gltf_tables`): a file whose sssbake data another tool broke is refused, not summarised."""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from sssbake.exporters.gltf import COMPONENT_DTYPES, COMPONENT_NAMES, EXTENSION, TYPE_SIZES
from sssbake.exporters.gltf_tables import SssbakeGltf, load_sssbake_gltf
from sssbake.pipeline.core.errors import AssetError
from sssbake.pipeline.mesh.load_gltf import GltfObject


def inspect_glb(path: str | os.PathLike, required: bool = False) -> dict:
    """Summarise the sssbake content of a .glb file.

    Parameters
    ----------
    path : str or os.PathLike
    required : bool
        Refuse a file without sssbake data, as verify and the readers do (`load_sssbake_gltf`).

    Returns
    -------
    dict
        ``path``, ``bytes`` (file size), ``generator``, ``schemaVersion`` (of the root
        ``SSSBAKE_subsurface`` object, None if absent), ``extensionsUsed``, ``extensionsRequired``,
        ``asset`` (the root ``SSSBAKE_subsurface`` object or None), ``meshes``: per mesh ``name``,
        ``sssbake`` (its ``SSSBAKE_subsurface`` object or None), ``vertexCountsMatch`` (POSITION
        counts equal the baked ``vertexCounts``; None without them), ``techniques`` {technique
        (``prt``, ``kernels``, ...): {``bytes`` (all its tables), ``tables`` {key path:
        {``accessor``, ``name``, ``crc32``, ``count``, ``type``, ``componentType``, ``normalized``,
        ``bytes``}}}} and ``primitives``: per primitive ``vertices``, ``material``, ``attributes``
        {``_NAME``: {``accessor``, ``count``, ``type``, ``componentType`` (name), ``normalized``,
        ``bytes``, ``bytesPerVertex``}} and ``bytesPerVertex`` (all ``_`` attributes);
        ``materials``: per material with a ``SSSBAKE_subsurface`` object its ``index``, ``name``,
        ``extensions`` (names), ``thicknessTexture`` (the fallback's ``KHR_materials_volume``
        has one), ``sssbake`` and ``techniques`` (as a mesh's: the screen tables);
        ``bytesPerVertex``: {``_NAME``: bytes / vertices of the primitives carrying it,
        ``total``: all ``_`` attribute bytes / all vertices}.

        Bytes are ``count × byteStride`` (or × element size without a stride; an interleaved
        view's element size rounded up to 4 bytes): what the file
        spends on the attribute, alignment padding included.

    Raises
    ------
    AssetError
        The file is not glTF sssbake reads (`gltf_tables.load_sssbake_gltf`), holds no sssbake
        data (`required`), or an accessor it summarises is malformed.
    StaleDataError
        Schema 1.x data, or a table or ``_`` attribute that no longer matches its reference.
    """
    path = Path(path)
    data = load_sssbake_gltf(path, required)
    gltf = data.gltf

    meshes = []
    attr_bytes: dict[str, int] = {}
    attr_vertices: dict[str, int] = {}
    total_vertices = 0
    for i, mesh in enumerate(gltf.meshes):
        sssbake = data.extension(mesh) if data.root is not None else None
        prims = []
        for j, prim in enumerate(mesh.primitives):
            attributes = dict(prim.attributes or {})
            where = f"mesh {i} primitive {j}"
            n = _accessor(data, attributes["POSITION"], f"{where} POSITION").count if "POSITION" in attributes else 0
            total_vertices += n
            custom = {}
            for name, index in sorted(attributes.items()):
                if not name.startswith("_"):
                    continue
                if data.root is not None:
                    data.attribute(i, j, name)  # refuses stale attributes
                info = _accessor_info(data, index, f"{where} {name}")
                info["bytesPerVertex"] = info["bytes"] / n if n else 0.0
                custom[name] = info
                attr_bytes[name] = attr_bytes.get(name, 0) + info["bytes"]
                attr_vertices[name] = attr_vertices.get(name, 0) + n
            prims.append({
                "vertices": n,
                "material": prim.material,
                "attributes": custom,
                "bytesPerVertex": sum(a["bytes"] for a in custom.values()) / n if n else 0.0,
            })
        counts = (sssbake or {}).get("vertexCounts")
        meshes.append({"name": mesh.name, "sssbake": sssbake,
                       "vertexCountsMatch": None if counts is None else counts == [p["vertices"] for p in prims],
                       "techniques": _techniques(data, sssbake, f"meshes[{i}]"), "primitives": prims})

    materials = []
    for i, m in enumerate(gltf.materials):
        sssbake = data.extension(m) if data.root is not None else None
        if sssbake is not None:
            volume = (m.extensions or {}).get("KHR_materials_volume")
            materials.append({"index": i, "name": m.name, "extensions": sorted(m.extensions or {}),
                              "thicknessTexture": isinstance(volume, dict) and "thicknessTexture" in volume,
                              "sssbake": sssbake, "techniques": _techniques(data, sssbake, f"materials[{i}]")})
    per_vertex = {name: attr_bytes[name] / attr_vertices[name] for name in attr_bytes if attr_vertices[name]}
    per_vertex["total"] = sum(attr_bytes.values()) / total_vertices if total_vertices else 0.0
    return {
        "path": str(path),
        "bytes": path.stat().st_size,
        "generator": gltf.asset.generator,
        "schemaVersion": data.root.get("schemaVersion") if data.root else None,
        "extensionsUsed": list(gltf.extensionsUsed or []),
        "extensionsRequired": list(gltf.extensionsRequired or []),
        "asset": data.root,
        "meshes": meshes,
        "materials": materials,
        "bytesPerVertex": per_vertex,
    }


def _techniques(data: SssbakeGltf, sssbake: dict | None, owner: str) -> dict:
    """The tables of each technique object in an extension object, each resolved and checked."""
    out = {}
    for technique, value in (sssbake or {}).items():
        if not isinstance(value, dict):
            continue
        tables = {}
        for key, ref in _references(value, ""):
            where = f"{owner}.extensions.{EXTENSION}.{technique}.{key}"
            index, _ = data.check_table(ref, where)
            tables[key] = {**_accessor_info(data, index, where), "name": ref["name"], "crc32": ref["crc32"]}
        if tables:
            out[technique] = {"bytes": sum(t["bytes"] for t in tables.values()), "tables": tables}
    return out


def _references(value, prefix: str):
    """(key path, table reference) of every table reference nested in `value`."""
    if isinstance(value, dict) and "accessor" in value:
        yield prefix, value
    elif isinstance(value, dict):
        for key, item in value.items():
            yield from _references(item, f"{prefix}.{key}" if prefix else str(key))
    elif isinstance(value, list):
        for i, item in enumerate(value):
            yield from _references(item, f"{prefix}[{i}]")


def _accessor(data: SssbakeGltf, index, where: str) -> GltfObject:
    """Accessor `index`, refused in one line unless its index, componentType, type, count and buffer
    view (with its byteStride) are of the kinds glTF 2.0 gives them: inspect summarises any file."""
    accessors, views = data.gltf.accessors, data.gltf.bufferViews
    if not (isinstance(index, int) and 0 <= index < len(accessors)):
        raise AssetError(data.path, f"{where}: accessor index {index!r} out of range ({len(accessors)} accessors)")
    acc = accessors[index]
    view, count = acc.bufferView, acc.count
    stride = views[view].byteStride if isinstance(view, int) and 0 <= view < len(views) else None
    if not (isinstance(acc.componentType, int) and acc.componentType in COMPONENT_NAMES
            and isinstance(acc.type, str) and acc.type in TYPE_SIZES and isinstance(count, int) and count >= 0
            and (view is None or (isinstance(view, int) and 0 <= view < len(views)))
            and (stride is None or isinstance(stride, int))):
        raise AssetError(data.path, f"{where}: accessor {index} is malformed (componentType {acc.componentType!r}, "
                                    f"type {acc.type!r}, count {count!r}, bufferView {view!r}, byteStride {stride!r})")
    return acc


def _accessor_info(data: SssbakeGltf, index: int, where: str) -> dict:
    gltf = data.gltf
    acc = _accessor(data, index, where)
    element = np.dtype(COMPONENT_DTYPES[acc.componentType]).itemsize * TYPE_SIZES[acc.type]
    stride = element
    if acc.bufferView is not None and gltf.bufferViews[acc.bufferView].byteStride:
        # its own 4-byte-aligned slot, not an interleaved view's whole stride (glTF-Transform interleaves)
        stride = min(gltf.bufferViews[acc.bufferView].byteStride, -(-element // 4) * 4)
    return {
        "accessor": index,
        "count": acc.count,
        "type": acc.type,
        "componentType": COMPONENT_NAMES[acc.componentType],
        "normalized": bool(acc.normalized),
        "bytes": acc.count * stride,
    }
