"""Exported material names are the asset's: ``<stem>_<source name>`` in the .glb, the .usdc and the
.mtlx, so engines that share materials by name (Godot) never merge two assets' materials; the config's
rules, the plan and the report keep the source names."""

import json

import MaterialX as mx
import pygltflib
from fixtures import FAST_DEFAULTS
from gltf_corpus import GltfBuilder, _material, _mesh, _scene, box24, uv_sphere
from pxr import Usd, UsdShade

from sssbake.pipeline.cli import main


def _skin_and_bare(path) -> None:
    """A .glb of a sphere with material ``Skin`` and a box with none (the bake's default material)."""
    b = GltfBuilder()
    _material(b, "Skin")
    _mesh(b, uv_sphere())
    _mesh(b, box24(), material=None)
    b.doc["meshes"][0]["name"], b.doc["meshes"][1]["name"] = "Ball", "Box"
    _scene(b, [{"name": "Ball", "mesh": 0}, {"name": "Box", "mesh": 1, "translation": [2.0, 0.0, 0.0]}])
    path.write_bytes(b.glb())


def test_two_assets_of_the_same_material_names_export_distinct_names(tmp_path):
    src, out = tmp_path / "in", tmp_path / "out"
    src.mkdir()
    for stem in ("apple", "pear"):
        _skin_and_bare(src / f"{stem}.glb")
    config = tmp_path / "c.toml"
    # the rule names the source material: it matches before the export renames it
    config.write_text(FAST_DEFAULTS + '\n[materials]\n"skin" = "skin1"\n')
    assert main(["bake", str(src), "-o", str(out), "--config", str(config), "-q"]) == 0
    exported = {}
    for stem in ("apple", "pear"):
        report = json.loads((out / f"{stem}.report.json").read_text())
        assert report["materials"]["Skin"]["scattering"]["name"] == "skin1"
        assert report["materials"]["Skin"]["reason"] == "material name matches rule 'skin'"
        assert report["materials"]["sssbake_default"]["scattering"]["name"] == "marble"
        assert str(out / f"{stem}.mtlx") in report["outputs"]
        gltf = pygltflib.GLTF2().load(str(out / f"{stem}.glb"))
        names = [m.name for m in gltf.materials]
        assert names == [f"{stem}_Skin", f"{stem}_sssbake_default"]
        # the extension keeps the source name
        assert gltf.materials[0].extensions["SSSBAKE_subsurface"]["sourceName"] == "Skin"
        stage = Usd.Stage.Open(str(out / f"{stem}.usdc"))
        prims = [p for p in stage.Traverse() if p.IsA(UsdShade.Material)]
        assert [p.GetName() for p in prims] == names
        assert [p.GetAttribute("sss:materialx:material").Get() for p in prims] == names
        doc = mx.createDocument()
        mx.readFromXmlFile(doc, str(out / f"{stem}.mtlx"))
        assert [m.getName() for m in doc.getMaterialNodes()] == names
        exported[stem] = set(names)
    assert not exported["apple"] & exported["pear"]
