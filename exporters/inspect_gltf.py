"""What sssbake data a .glb holds: schema version, ``_`` attributes and technique tables with their
bytes, extensions."""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np
import pygltflib as g

from sssbake.exporters.gltf import COMPONENT_DTYPES, COMPONENT_NAMES, TYPE_SIZES


def inspect_glb(path: str | os.PathLike) -> dict:
    """Summarise the sssbake content of a .glb (or .gltf) file.

    Returns
    -------
    dict
        ``path``, ``bytes`` (file size), ``generator``, ``schemaVersion`` (of the root
        ``extras.sssbake``, None if absent), ``extensionsUsed``, ``extensionsRequired``,
        ``asset`` (the root ``extras.sssbake`` object or None), ``meshes``: per mesh ``name``,
        ``sssbake`` (mesh ``extras.sssbake`` or None), ``techniques`` {technique (``prt``,
        ``kernels``, ...): {``bytes`` (all its tables), ``tables`` {key: {``accessor``,
        ``count``, ``type``, ``componentType``, ``normalized``, ``bytes``}}}} and
        ``primitives``: per primitive
        ``vertices``, ``material``, ``attributes`` {``_NAME``: {``count``, ``type``,
        ``componentType`` (name), ``normalized``, ``bytes``, ``bytesPerVertex``}} and
        ``bytesPerVertex`` (all ``_`` attributes); ``materials``: per material with
        ``extras.sssbake`` its ``index``, ``name``, ``extensions`` (names), ``sssbake`` and
        ``techniques`` (as a mesh's: the screen tables);
        ``bytesPerVertex``: {``_NAME``: bytes / vertices of the primitives carrying it,
        ``total``: all ``_`` attribute bytes / all vertices}.

        Bytes are ``count × byteStride`` (or × element size without a stride): what the file
        spends on the attribute, alignment padding included.
    """
    path = Path(path)
    gltf = g.GLTF2.load(str(path))
    root = (gltf.extras or {}).get("sssbake")

    meshes = []
    attr_bytes: dict[str, int] = {}
    attr_vertices: dict[str, int] = {}
    total_vertices = 0
    for mesh in gltf.meshes:
        prims = []
        for prim in mesh.primitives:
            attributes = {k: v for k, v in vars(prim.attributes).items() if v is not None}
            n = gltf.accessors[attributes["POSITION"]].count if "POSITION" in attributes else 0
            total_vertices += n
            custom = {}
            for name, index in sorted(attributes.items()):
                if not name.startswith("_"):
                    continue
                info = _accessor_info(gltf, index)
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
        sssbake = (mesh.extras or {}).get("sssbake")
        meshes.append({"name": mesh.name, "sssbake": sssbake, "techniques": _techniques(gltf, sssbake),
                       "primitives": prims})

    materials = [
        {
            "index": i,
            "name": m.name,
            "extensions": sorted(m.extensions or {}),
            "sssbake": m.extras["sssbake"],
            "techniques": _techniques(gltf, m.extras["sssbake"]),
        }
        for i, m in enumerate(gltf.materials)
        if "sssbake" in (m.extras or {})
    ]
    per_vertex = {name: attr_bytes[name] / attr_vertices[name] for name in attr_bytes if attr_vertices[name]}
    per_vertex["total"] = sum(attr_bytes.values()) / total_vertices if total_vertices else 0.0
    return {
        "path": str(path),
        "bytes": path.stat().st_size,
        "generator": gltf.asset.generator,
        "schemaVersion": root.get("schemaVersion") if root else None,
        "extensionsUsed": list(gltf.extensionsUsed or []),
        "extensionsRequired": list(gltf.extensionsRequired or []),
        "asset": root,
        "meshes": meshes,
        "materials": materials,
        "bytesPerVertex": per_vertex,
    }


def _techniques(gltf: g.GLTF2, sssbake: dict | None) -> dict:
    """The tables ({"accessor": i} values) of each technique object in a mesh's ``extras.sssbake``."""
    out = {}
    for name, value in (sssbake or {}).items():
        if not isinstance(value, dict):
            continue
        tables = {key: _accessor_info(gltf, ref["accessor"]) for key, ref in value.items()
                  if isinstance(ref, dict) and "accessor" in ref}
        if tables:
            out[name] = {"bytes": sum(t["bytes"] for t in tables.values()), "tables": tables}
    return out


def _accessor_info(gltf: g.GLTF2, index: int) -> dict:
    acc = gltf.accessors[index]
    element = np.dtype(COMPONENT_DTYPES[acc.componentType]).itemsize * TYPE_SIZES[acc.type]
    stride = element
    if acc.bufferView is not None:
        stride = gltf.bufferViews[acc.bufferView].byteStride or element
    return {
        "accessor": index,
        "count": acc.count,
        "type": acc.type,
        "componentType": COMPONENT_NAMES[acc.componentType],
        "normalized": bool(acc.normalized),
        "bytes": acc.count * stride,
    }
