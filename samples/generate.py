"""Writes the bundled samples: `python samples/generate.py [FOLDER]` (default: this folder).

Every sample is made here from closed forms, so the repository ships no third-party meshes:
- sphere.obj     icosphere, radius 10 units (the config says 1 mm per unit: a 20 mm marble ball)
- torus.ply      torus, radii 12 and 4 units
- thin_slab.stl  40 × 40 × 2 unit slab (thickness known exactly), skin
- blob.obj       bumpy closed blob, radius ≈ 15 units (baked as veined marble with the lpv technique)
- candle.glb     two meshes, two materials (translucent "Wax" body, opaque "Brass" holder), node
                 transforms, in metres as glTF declares
- sssbake.toml   the batch config that maps them to materials and scales
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import trimesh

from sssbake.exporters.gltf import write_glb
from sssbake.pipeline.mesh.baked import BakedAsset
from sssbake.pipeline.mesh.scene import Mesh, Node, Primitive, Scene, SourceMaterial

CONFIG = """\
# Batch config for the bundled samples: `sssbake bake samples/ -o out/ --config samples/sssbake.toml`
[defaults]
material = "marble"
scale_mm = 1.0            # OBJ/PLY/STL carry no unit: 1 file unit = 1 mm here

[[assets]]
glob = "thin_slab.stl"
material = "skin1"

[[assets]]
glob = "torus.ply"
material = { albedo = [0.55, 0.75, 0.6], mean_free_path_mm = [1.5, 2.5, 1.8], eta = 1.6 }  # jade-like

[[assets]]
glob = "candle.glb"
scale_mm = 1000.0         # glTF is in metres

[[assets]]
glob = "blob.obj"         # veined marble: an lpv grid whose absorption follows procedural veins
techniques = ["lpv"]
lpv_field = "marble"
lpv_vein_mm = 8.0

[materials]
"Wax*" = { albedo = [0.88, 0.8, 0.62], mean_free_path_mm = [2.0, 1.4, 0.8], eta = 1.45 }
"Brass" = "opaque"
"""


def blob(subdivisions: int = 4) -> trimesh.Trimesh:
    """A closed, star-shaped bumpy surface: r(θ, φ) = 15 (1 + 0.15 sin 3θ cos 2φ + 0.08 sin 5φ)."""
    ico = trimesh.creation.icosphere(subdivisions=subdivisions)
    v = ico.vertices
    theta = np.arccos(np.clip(v[:, 2], -1, 1))
    phi = np.arctan2(v[:, 1], v[:, 0])
    r = 15.0 * (1.0 + 0.15 * np.sin(3 * theta) * np.cos(2 * phi) + 0.08 * np.sin(5 * phi))
    return trimesh.Trimesh(v * r[:, None], ico.faces, process=False)


def slab() -> trimesh.Trimesh:
    """A 40 × 2 × 40 box, subdivided so most vertices sit inside the big faces (thickness 2)."""
    box = trimesh.creation.box(extents=(40.0, 2.0, 40.0))
    v, f = trimesh.remesh.subdivide_to_size(box.vertices, box.faces, max_edge=4.0)
    return trimesh.Trimesh(v, f, process=False)


def candle_scene() -> Scene:
    """Two meshes under a root node: a wax cylinder standing in a brass cup, in metres."""
    wax = trimesh.creation.cylinder(radius=0.02, height=0.08, sections=48)
    cup = trimesh.creation.annulus(r_min=0.021, r_max=0.028, height=0.02, sections=48)
    root_to_body = np.eye(4)
    root_to_body[:3, 3] = [0.0, 0.05, 0.0]
    upright = np.array([[1, 0, 0, 0], [0, 0, 1, 0], [0, -1, 0, 0], [0, 0, 0, 1]], dtype=np.float64)
    cup_at = upright.copy()
    cup_at[:3, 3] = [0.0, 0.01, 0.0]

    def prim(m: trimesh.Trimesh, material: int) -> Primitive:
        return Primitive(np.asarray(m.vertices, np.float64), np.asarray(m.faces, np.int64), material=material)

    return Scene(
        source="candle.glb",
        meshes=(Mesh("wax_body", (prim(wax, 0),)), Mesh("brass_cup", (prim(cup, 1),))),
        nodes=(
            Node("candle", np.eye(4), None, (1, 2)),
            Node("body", root_to_body @ upright, 0),
            Node("cup", cup_at, 1),
        ),
        roots=(0,),
        materials=(
            SourceMaterial("Wax", base_color_factor=(0.9, 0.85, 0.7, 1.0), roughness_factor=0.6),
            SourceMaterial("Brass", base_color_factor=(0.8, 0.6, 0.25, 1.0), metallic_factor=1.0, roughness_factor=0.35),
        ),
        meters_per_unit=1.0,
    )


def generate(folder: Path) -> list[Path]:
    """Write every sample into `folder`; returns the paths written."""
    folder.mkdir(parents=True, exist_ok=True)
    out = []
    meshes = {
        "sphere.obj": trimesh.creation.icosphere(subdivisions=3, radius=10.0),
        "torus.ply": trimesh.creation.torus(major_radius=12.0, minor_radius=4.0, major_sections=48, minor_sections=24),
        "thin_slab.stl": slab(),
        "blob.obj": blob(),
    }
    for name, mesh in meshes.items():
        path = folder / name
        mesh.export(path)
        out.append(path)
    write_glb(BakedAsset(candle_scene()), folder / "candle.glb")
    out.append(folder / "candle.glb")
    (folder / "sssbake.toml").write_text(CONFIG)
    out.append(folder / "sssbake.toml")
    return out


if __name__ == "__main__":
    target = Path(sys.argv[1]) if len(sys.argv) > 1 else Path(__file__).parent
    for p in generate(target):
        print(p)
