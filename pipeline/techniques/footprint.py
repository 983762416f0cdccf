"""Bytes per vertex of a written file: the one definition that ``sssbake inspect``, verify's
``bytes_per_vertex`` and the report's column share.

A technique's bytes are those of its vertex attributes (each technique's `Technique.vertex_keys`)
and of its tables (its objects on meshes and materials: prt's and kernels' per-mesh tables, lpv's
grids, screen's per-material tables); both are divided by the render vertices it covers, the
POSITION counts of the primitives that carry its attributes, belong to a mesh holding its tables or
use a material holding them. Bytes are as `inspect_gltf` / `inspect_usd` count them: what the file
spends, element by element.
"""

from __future__ import annotations

from sssbake.pipeline.techniques.registry import TECHNIQUES

#: Where a vertex attribute none of the techniques owns is counted (the standard fallback's thickness).
FALLBACK = "fallback"


def footprint(info: dict) -> dict:
    """Bytes per render vertex of each technique in a file, per mesh and over the file.

    Parameters
    ----------
    info : dict
        `inspect_gltf.inspect_glb`'s or `inspect_usd.inspect_usdc`'s summary of the file.

    Returns
    -------
    dict
        ``techniques``: {technique: figures} over the whole file, each table counted once;
        ``meshes``: per mesh of `info` (a glTF mesh, a USD Mesh prim), in its order, ``name``,
        ``vertices`` and ``techniques`` {technique: figures}, a material's tables counted whole
        in each mesh that uses it (what the mesh needs drawn alone); ``file``: figures over all
        render vertices of the file, every ``_`` attribute (the fallback's included) and table.
        Figures are ``vertices`` (those covered), ``attributeBytes``, ``tableBytes``, and per
        covered vertex ``attributes``, ``tables`` and ``total``. Techniques appear in the
        registry's order; `FALLBACK` holds the attributes no technique owns (``tables`` 0).
    """
    meshes, material_tables = _normalised(info)
    whole: dict[str, dict] = {}
    covered: dict[str, set] = {}
    rows, everything = [], [0, 0, 0]
    counted_materials: set = set()
    for name, prims, mesh_tables in meshes:
        row: dict[str, dict] = {}
        used = {m for _, m, _ in prims if m in material_tables}
        for prim_id, (vertices, material, attributes) in enumerate(prims):
            everything[0] += vertices
            everything[1] += sum(attributes.values())
            holders = set(mesh_tables) | set(material_tables.get(material, {}))
            owned: dict[str, int] = {}
            for attribute, size in attributes.items():
                owner = _owner(attribute)
                owned[owner] = owned.get(owner, 0) + size
            for technique in holders | set(owned):
                for figures in (row.setdefault(technique, [0, 0, 0]), whole.setdefault(technique, [0, 0, 0])):
                    figures[0] += vertices
                    figures[1] += owned.get(technique, 0)
                covered.setdefault(technique, set()).add((name, prim_id))
        own_tables = dict(mesh_tables)
        for material in used:
            for technique, size in material_tables[material].items():
                own_tables[technique] = own_tables.get(technique, 0) + size
        for technique, size in own_tables.items():
            row.setdefault(technique, [0, 0, 0])[2] += size
        for technique, size in mesh_tables.items():
            whole.setdefault(technique, [0, 0, 0])[2] += size
        everything[2] += sum(mesh_tables.values())
        for material in used - counted_materials:
            for technique, size in material_tables[material].items():
                whole.setdefault(technique, [0, 0, 0])[2] += size
            everything[2] += sum(material_tables[material].values())
        counted_materials |= used
        rows.append({"name": name, "vertices": sum(v for v, _, _ in prims), "techniques": _ordered(row)})
    return {"techniques": _ordered(whole), "meshes": rows, "file": _figures(everything)}


def _normalised(info: dict) -> tuple[list, dict]:
    """`info` as ``[(mesh name, [(vertices, material key, {attribute: bytes})], {technique: table
    bytes})]`` and ``{material key: {technique: table bytes}}``, for glTF and USD alike."""
    if "generator" in info:  # inspect_glb's (inspect_usdc's has a "creator")
        materials = {m["index"]: _table_bytes(m) for m in info["materials"]}
        meshes = [(m["name"] if m["name"] is not None else f"mesh {i}",
                   [(p["vertices"], p["material"], {a: v["bytes"] for a, v in p["attributes"].items()})
                    for p in m["primitives"]], _table_bytes(m)) for i, m in enumerate(info["meshes"])]
    else:  # inspect_usdc's: a Mesh prim is one render primitive
        materials = {m["path"]: _table_bytes(m) for m in info["materials"]}
        meshes = [(m["path"], [(m["vertices"], m["material"], {a: v["bytes"] for a, v in m["primvars"].items()})],
                   _table_bytes(m)) for m in info["meshes"]]
    return meshes, materials


def _table_bytes(owner: dict) -> dict[str, int]:
    return {technique: block["bytes"] for technique, block in owner["techniques"].items()}


def _owner(attribute: str) -> str:
    """The technique a glTF ``_`` attribute or USD ``primvars:sss:`` primvar belongs to, by its key
    (`baked.VertexAttribute`: ``sss:prt:ref`` is ``_SSS_PRT_REF`` and ``primvars:sss:prt:ref``)."""
    for technique in TECHNIQUES:
        for key in technique.vertex_keys:
            if attribute.startswith(("_" + key.upper().replace(":", "_"), "primvars:sss:" + key.removeprefix("sss:"))):
                return technique.name
    return FALLBACK


def _ordered(figures: dict[str, list]) -> dict[str, dict]:
    order = [t.name for t in TECHNIQUES] + [FALLBACK]
    rank = {t: i for i, t in enumerate(order)}
    return {t: _figures(figures[t]) for t in sorted(figures, key=lambda t: rank.get(t, len(order)))}


def _figures(counts: list) -> dict:
    """[vertices, attribute bytes, table bytes] as the figures of `footprint`."""
    vertices, attributes, tables = counts
    per = (lambda b: b / vertices) if vertices else (lambda b: 0.0)
    return {"vertices": vertices, "attributeBytes": attributes, "tableBytes": tables,
            "attributes": per(attributes), "tables": per(tables), "total": per(attributes + tables)}
