"""``sssbake inspect``'s text: what a .glb or .usdc holds, per mesh, for a reader (``--json`` prints
the summaries themselves)."""

from __future__ import annotations


def summary_lines(info: dict, footprint: dict) -> list[str]:
    """Lines describing one file.

    Parameters
    ----------
    info : dict
        `inspect_gltf.inspect_glb`'s or `inspect_usd.inspect_usdc`'s summary.
    footprint : dict
        `techniques.footprint.footprint` of `info`.

    Returns
    -------
    list of str
        The file (schema, meshes, render vertices, size); per mesh its vertices and scale, per
        scattering material its preset and what the standard fallback carries, and per
        technique its bytes per vertex, attributes alone and with its tables; last the file's
        bytes per vertex over all its render vertices.
    """
    gltf = "generator" in info
    meshes = info["meshes"]
    whole = footprint["file"]
    lines = [f"{info['path']}: sssbake schema {info['schemaVersion']}, {len(meshes)} mesh{'es' * (len(meshes) != 1)}, "
             f"{whole['vertices']} render vertices, {info['bytes']} bytes"]
    materials = {m["index"] if gltf else m["path"]: m for m in info["materials"]}
    for mesh, figures in zip(meshes, footprint["meshes"]):
        scale = (mesh["sssbake"] or {}).get("scaleMm") if gltf else mesh["scaleMm"]
        lines.append(f"mesh {figures['name']}: {figures['vertices']} vertices"
                     + (f", {scale:g} mm per unit" if isinstance(scale, (int, float)) else ", no sssbake data"))
        used = ({p["material"] for p in mesh["primitives"]} if gltf else {mesh["material"]}) & set(materials)
        for key in sorted(used, key=str):
            lines.append("  " + _material_line(materials[key], gltf))
        for technique, f in figures["techniques"].items():
            lines.append(f"  {technique:<9} {f['attributes']:.1f} B/vertex attributes, {f['total']:.1f} with tables")
    lines.append(f"file: {whole['attributes']:.1f} B/vertex attributes, {whole['total']:.1f} with tables "
                 f"({whole['attributeBytes']} bytes of attributes, {whole['tableBytes']} of tables)")
    return lines


def _material_line(material: dict, gltf: bool) -> str:
    """A scattering material: its name, preset and the standard fallback it carries."""
    if gltf:
        name, preset = material["name"], (material["sssbake"].get("material") or {}).get("name")
        fallback = [e for e in material["extensions"] if e.startswith("KHR_materials_")]
        fallback += ["thickness texture"] if material["thicknessTexture"] else []
    else:
        name, preset = material["path"], material["sss"].get("materialName")
        fallback = sorted(k.removeprefix("fallback:") for k in material["sss"] if k.startswith("fallback:"))
    return f"material {name} ({preset or 'no preset'}): fallback {', '.join(fallback) or 'none'}"
