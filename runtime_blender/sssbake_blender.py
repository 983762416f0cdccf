"""Import an sssbake .glb into Blender with subsurface scattering on its translucent materials.

Blender's glTF importer (4.5) maps KHR_materials_transmission to the Principled BSDF's
Transmission Weight and KHR_materials_volume to a Volume Absorption node on the material output,
and drops KHR_materials_diffuse_transmission and the SSSBAKE_subsurface extension: the standard
fallback alone looks nearly opaque there. `import_glb` imports the file as usual, reads each
material's ``SSSBAKE_subsurface.material`` back from the file and sets its Principled BSDF's
subsurface: weight 1, radius the mean free path per channel ``1 / (σ_s' + σ_a)`` in the file's
units (``scaleMmPerUnit`` of the root extension), scale 1 (the IOR η comes from
KHR_materials_ior, which the importer maps).

Run inside Blender, or with Blender's Python module (``bpy`` from PyPI)::

    import sssbake_blender
    sssbake_blender.import_glb("OUT/sphere.glb")

    blender --python runtime_blender/sssbake_blender.py -- OUT/sphere.glb

Needs only bpy and the standard library.
"""

from __future__ import annotations

import json
import struct
import sys

EXTENSION = "SSSBAKE_subsurface"


def glb_json(path: str) -> dict:
    """The JSON chunk of a .glb file."""
    with open(path, "rb") as f:
        magic, _, _ = struct.unpack("<4sII", f.read(12))
        length, kind = struct.unpack("<II", f.read(8))
        if magic != b"glTF" or kind != 0x4E4F534A:
            raise ValueError(f"{path}: not a binary glTF file")
        return json.loads(f.read(length))


def subsurface_settings(gltf: dict) -> dict[int, dict]:
    """glTF material index -> Principled BSDF input values for each material with sssbake data.

    Returns
    -------
    dict
        ``{"Subsurface Weight": 1.0, "Subsurface Radius": (3,) mean free paths in file units,
        "Subsurface Scale": 1.0}`` per material.
    """
    root = gltf.get("extensions", {}).get(EXTENSION)
    if root is None:
        raise ValueError(f"no {EXTENSION} extension: not an sssbake 2.x file")
    mm_per_unit = float(root["scaleMmPerUnit"])
    out = {}
    for i, material in enumerate(gltf.get("materials", [])):
        data = material.get("extensions", {}).get(EXTENSION, {}).get("material")
        if data is None:
            continue
        sigma_t = [s + a for s, a in zip(data["sigma_s_prime"], data["sigma_a"])]  # 1/mm
        out[i] = {"Subsurface Weight": 1.0, "Subsurface Radius": tuple(1.0 / (t * mm_per_unit) for t in sigma_t),
                  "Subsurface Scale": 1.0}
    return out


def import_glb(path: str) -> dict[str, dict]:
    """Import `path` with ``bpy.ops.import_scene.gltf`` and set the subsurface of every material
    sssbake baked (`subsurface_settings`).

    Returns
    -------
    dict
        Blender material name -> the inputs set.
    """
    import bpy

    gltf = glb_json(path)
    settings = subsurface_settings(gltf)
    before = set(bpy.data.materials)
    bpy.ops.import_scene.gltf(filepath=str(path))
    created = [m for m in bpy.data.materials if m not in before]
    done = {}
    for index, values in settings.items():
        name = gltf["materials"][index].get("name", f"Material_{index}")
        # the importer names a material after the glTF one; copies (per vertex-colour use) get ".001"
        for material in (m for m in created if m.name == name or m.name.startswith(name + ".")):
            principled = next(n for n in material.node_tree.nodes if n.type == "BSDF_PRINCIPLED")
            principled.subsurface_method = "RANDOM_WALK"
            for key, value in values.items():
                principled.inputs[key].default_value = value
            done[material.name] = values
    return done


if __name__ == "__main__":
    args = sys.argv[sys.argv.index("--") + 1:] if "--" in sys.argv else sys.argv[1:]
    for glb in args:
        print(json.dumps(import_glb(glb)))
