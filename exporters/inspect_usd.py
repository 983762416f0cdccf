"""What sssbake data a USD file holds: schema version, ``primvars:sss:*`` and technique tables with
their bytes, material ``sss:`` attributes. Every table is read and checked (`usd.technique_tables`),
so a file whose sssbake data another tool broke is refused, as verify and the readers refuse it."""

from __future__ import annotations

import json
import os
from pathlib import Path

import numpy as np
from pxr import Usd, UsdGeom, UsdShade

from sssbake.exporters.gltf import table_dtype
from sssbake.exporters.usd import SSS, check_schema, technique_tables
from sssbake.pipeline.core.errors import AssetError

_PRIMVAR_PREFIX = "primvars:" + SSS


def inspect_usdc(path: str | os.PathLike, required: bool = False) -> dict:
    """Summarise the sssbake content of a .usd/.usda/.usdc file.

    Parameters
    ----------
    path : str or os.PathLike
    required : bool
        Refuse a stage whose default prim has no ``sss:schemaVersion`` (never baked by sssbake,
        or its ``sss:`` data dropped by another tool).

    Returns
    -------
    dict
        ``path``, ``bytes`` (file size), ``creator`` (customLayerData), ``defaultPrim``,
        ``upAxis``, ``metersPerUnit``, ``schemaVersion`` (the default prim's
        ``sss:schemaVersion``, None if absent), ``extras`` (its ``sss:extras`` JSON, parsed),
        ``meshes``: per Mesh prim ``path``, ``vertices`` (points), ``faces``, ``scaleMm``,
        ``material`` (bound material path or None), ``extras`` (its ``sss:extras`` JSON, parsed,
        or None), ``techniques`` {technique (``prt``, ``kernels``, ...): {``bytes`` (all its
        tables), ``tables`` {key: {``attribute``, ``type``, ``dtype`` (as a .glb stores the
        baked table: `gltf.table_dtype`), ``shape``, ``count`` (array elements), ``bytes`` (count ×
        that dtype's size)}}}}, ``primvars`` {``primvars:sss:<key>``:
        {``type``, ``interpolation``, ``elementSize``, ``count`` (array elements), ``bytes``
        (count × value bytes, as loaded), ``bytesPerVertex``, ``unit``, ``description``,
        ``encoding`` (glTF's), ``components`` (values per vertex), ``packedBits`` (bits per
        component packed into one int, or None)}} and
        ``bytesPerVertex`` (all ``primvars:sss:*``); ``materials``: per Material prim with
        ``sss:`` attributes its ``path``, ``sss`` {attribute name without ``sss:``: value, but
        ``sss:extras`` and the technique tables}, ``extras`` (its ``sss:extras`` JSON, parsed, or
        None) and ``techniques`` (as a mesh's: the screen tables);
        ``bytesPerVertex``: {``primvars:sss:<key>``: bytes / vertices of the meshes carrying it,
        ``total``: all ``primvars:sss:*`` bytes / all vertices}.

    Raises
    ------
    pxr.Tf.ErrorException
        The file cannot be opened as a USD stage.
    StaleDataError
        Written by another major schema, or a table no longer matches its reference.
    AssetError
        (`required`) No sssbake schema version.
    """
    path = Path(path)
    stage = Usd.Stage.Open(str(path))
    check_schema(stage)
    time = Usd.TimeCode.EarliestTime()
    default = stage.GetDefaultPrim()
    root = default if default else stage.GetPseudoRoot()
    version = root.GetAttribute(SSS + "schemaVersion").Get() if default else None
    if required and version is None:
        raise AssetError(path, f"no {SSS}schemaVersion on its default prim: not a file sssbake baked (bake the "
                               f"asset with sssbake), or one a tool dropped its {SSS} data from")

    meshes = []
    attr_bytes: dict[str, int] = {}
    attr_vertices: dict[str, int] = {}
    total_vertices = 0
    materials = []
    for prim in Usd.PrimRange(root):
        if prim.IsA(UsdShade.Material):
            extras = prim.GetAttribute(SSS + "extras").Get()
            extras = json.loads(extras) if extras else None
            techniques = _techniques(prim, extras)
            # the technique tables are summarised, not listed value by value
            tabled = {t["attribute"] for block in techniques.values() for t in block["tables"].values()}
            values = _sss_values(prim, tabled | {SSS + "extras"})
            if values or extras:
                materials.append({"path": str(prim.GetPath()), "sss": values, "extras": extras,
                                  "techniques": techniques})
        if not prim.IsA(UsdGeom.Mesh):
            continue
        mesh = UsdGeom.Mesh(prim)
        points = mesh.GetPointsAttr().Get(time)
        n = len(points) if points is not None else 0
        counts = mesh.GetFaceVertexCountsAttr().Get(time)
        total_vertices += n
        primvars = {}
        for pv in UsdGeom.PrimvarsAPI(mesh).GetPrimvarsWithAuthoredValues():
            name = pv.GetName()
            if not name.startswith(_PRIMVAR_PREFIX):
                continue
            value = pv.Get(time)
            array = np.asarray(value) if value is not None else np.zeros(0, np.float32)
            count = len(value) if value is not None else 0
            data = pv.GetAttr().GetCustomData()
            primvars[name] = {
                "type": str(pv.GetTypeName()),
                "interpolation": pv.GetInterpolation(),
                "elementSize": pv.GetElementSize(),
                "count": count,
                "bytes": int(array.nbytes),
                "bytesPerVertex": array.nbytes / n if n else 0.0,
                "unit": data.get("unit", ""),
                "description": data.get("description", ""),
                "encoding": data.get("encoding"),
                "components": data.get("components"),
                "packedBits": data.get("packedBits"),
            }
            attr_bytes[name] = attr_bytes.get(name, 0) + int(array.nbytes)
            attr_vertices[name] = attr_vertices.get(name, 0) + n
        material = UsdShade.MaterialBindingAPI(prim).GetDirectBinding().GetMaterial()
        mesh_extras = prim.GetAttribute(SSS + "extras").Get()
        mesh_extras = json.loads(mesh_extras) if mesh_extras else None
        meshes.append({
            "path": str(prim.GetPath()),
            "vertices": n,
            "faces": len(counts) if counts is not None else 0,
            "scaleMm": prim.GetAttribute(SSS + "scaleMm").Get(),
            "material": str(material.GetPath()) if material else None,
            "extras": mesh_extras,
            "techniques": _techniques(prim, mesh_extras),
            "primvars": primvars,
            "bytesPerVertex": sum(p["bytes"] for p in primvars.values()) / n if n else 0.0,
        })

    per_vertex = {name: attr_bytes[name] / attr_vertices[name] for name in attr_bytes if attr_vertices[name]}
    per_vertex["total"] = sum(attr_bytes.values()) / total_vertices if total_vertices else 0.0
    extras = root.GetAttribute(SSS + "extras").Get() if default else None
    return {
        "path": str(path),
        "bytes": path.stat().st_size,
        "creator": stage.GetRootLayer().customLayerData.get("creator"),
        "defaultPrim": str(default.GetPath()) if default else None,
        "upAxis": UsdGeom.GetStageUpAxis(stage),
        "metersPerUnit": UsdGeom.GetStageMetersPerUnit(stage),
        "schemaVersion": version,
        "extras": json.loads(extras) if extras else None,
        "meshes": meshes,
        "materials": materials,
        "bytesPerVertex": per_vertex,
    }


def _techniques(prim: Usd.Prim, extras: dict | None) -> dict:
    """The tables ({"attribute": name, "shape": [...], "crc32": ...} values) of each technique object
    in a Mesh or Material prim's ``sss:extras``, each checked by `technique_tables`."""
    out = {}
    for name, value in (extras or {}).items():
        if not isinstance(value, dict):
            continue
        technique_tables(prim, name)  # refuses stale tables
        tables = {}
        for key, ref in value.items():
            if isinstance(ref, dict) and "attribute" in ref:
                attribute = prim.GetAttribute(ref["attribute"])
                array = np.asarray(attribute.Get())
                # USD holds integer tables as int[] (compressed on disk); the dtype a .glb stores the
                # baked table at is what it costs a runtime, so both files give one figure
                dtype = table_dtype(str(attribute.GetCustomData().get("dtype", array.dtype.name)))
                tables[key] = {"attribute": ref["attribute"], "type": str(attribute.GetTypeName()),
                               "dtype": dtype.name, "shape": ref.get("shape"), "count": int(array.size),
                               "bytes": int(array.size) * dtype.itemsize}
        if tables:
            out[name] = {"bytes": sum(t["bytes"] for t in tables.values()), "tables": tables}
    return out


def _sss_values(prim: Usd.Prim, skip: set[str]) -> dict:
    """The ``sss:`` attributes of `prim` but those in `skip` as JSON values, keyed without the prefix."""
    out = {}
    for attribute in prim.GetAuthoredAttributes():
        name = attribute.GetName()
        if name.startswith(SSS) and name not in skip:
            value = attribute.Get()
            out[name.removeprefix(SSS)] = _json(value)
    return out


def _json(value):
    """Attribute values for JSON; float32 components as their shortest decimal (0.9, not 0.8999999761581421)."""
    if isinstance(value, (str, bool, int)) or value is None:
        return value
    if isinstance(value, float):
        return float(str(np.float32(value)))
    try:
        return [float(str(np.float32(c))) for c in value]
    except TypeError:
        return str(value)
