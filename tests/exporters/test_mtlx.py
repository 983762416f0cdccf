"""The OpenPBR MaterialX document next to the .usdc: valid against MaterialX's standard libraries,
its values read back as written (float32), named from the .usdc's Material prims."""

from dataclasses import replace

import MaterialX as mx
import numpy as np
import pytest
from fixtures import FALLBACK
from pxr import Usd
from test_usd import icosphere_asset

from sssbake.exporters import mtlx
from sssbake.exporters.mtlx import OPENPBR_NODEDEF, validate_document, write_mtlx
from sssbake.exporters.usd import materialx_file, write_usdc
from sssbake.exporters.usd_validator import validate_usd
from sssbake.pipeline.core.engine_materials import openpbr_subsurface
from sssbake.pipeline.core.materials import preset


def _read(path) -> mx.Document:
    doc = mx.createDocument()
    mx.readFromXmlFile(doc, str(path))
    return doc


def _inputs(doc: mx.Document, material: str) -> dict:
    """The values of the open_pbr_surface behind surfacematerial `material`, as MaterialX reads them."""
    shader = doc.getNode(material).getConnectedNode("surfaceshader")
    assert shader.getCategory() == "open_pbr_surface" and shader.getNodeDefString() == OPENPBR_NODEDEF
    return {i.getName(): i.getValue() for i in shader.getInputs()}


def _f32(values) -> list[float]:
    return np.float32(np.atleast_1d(values)).astype(np.float64).tolist()


def test_document_validates_and_reads_back_what_was_written(tmp_path):
    asset = icosphere_asset()
    summary = write_mtlx(asset, tmp_path / "m.mtlx")
    assert summary["materials"] == ["Marble", "Steel"] and summary["bytes"] == (tmp_path / "m.mtlx").stat().st_size
    doc = _read(tmp_path / "m.mtlx")
    library = mx.createDocument()
    mx.loadLibraries(mx.getDefaultDataLibraryFolders(), mx.getDefaultDataSearchPath(), library)
    checked = doc.copy()
    checked.importLibrary(library)
    assert checked.validate() == (True, "")
    assert [m.getName() for m in doc.getMaterialNodes()] == ["Marble", "Steel"]

    marble = _inputs(doc, "Marble")
    # icosphere_asset: 10 mm per file unit (scale_mm, metersPerUnit 0.01)
    expected = openpbr_subsurface(preset("marble"), 10.0)
    assert set(expected) < set(marble)
    for name, value in expected.items():
        assert _f32(marble[name] if name.endswith("_color") or name.endswith("_scale") else [marble[name]]) \
            == _f32(value), name
    assert _f32(marble["base_color"]) == _f32(FALLBACK.base_color) and marble["specular_ior"] == np.float32(1.5)
    assert marble["geometry_opacity"] == 1.0 and marble["specular_roughness"] == np.float32(0.3)

    steel = _inputs(doc, "Steel")  # opaque: its factors, no subsurface
    assert not any(name.startswith("subsurface") for name in steel)
    assert _f32(steel["base_color"]) == [0.5, 0.5, 0.5] and steel["base_metalness"] == 1.0
    assert steel["geometry_opacity"] == np.float32(0.8) and steel["specular_ior"] == np.float32(1.4)


def test_usd_names_the_document_and_passes_usd_validation(tmp_path):
    asset = icosphere_asset()
    write_mtlx(asset, tmp_path / materialx_file("m"))
    write_usdc(asset, tmp_path / "m.usdc", materialx_file("m"))
    assert validate_usd(tmp_path / "m.usdc").errors == ()
    stage = Usd.Stage.Open(str(tmp_path / "m.usdc"))
    doc = _read(tmp_path / "m.mtlx")
    for name in ("Marble", "Steel"):
        prim = stage.GetPrimAtPath(f"/m/Materials/{name}")
        document = prim.GetAttribute("sss:materialx").Get()
        assert document.path == "./m.mtlx" and document.resolvedPath == str(tmp_path / "m.mtlx")
        assert doc.getNode(prim.GetAttribute("sss:materialx:material").Get()).getType() == "material"
    # the .usdc's OpenPBR attributes and the document's inputs are the same numbers
    marble = _inputs(doc, "Marble")
    prim = stage.GetPrimAtPath("/m/Materials/Marble")
    assert prim.GetAttribute("sss:openpbr:subsurfaceRadius").Get() == marble["subsurface_radius"]
    assert _f32(prim.GetAttribute("sss:openpbr:subsurfaceRadiusScale").Get()) == _f32(marble["subsurface_radius_scale"])

    # a .usdc naming a document that is not there fails USD's validation (MissingReferenceValidator)
    write_usdc(asset, tmp_path / "lost.usdc", "lost.mtlx")
    assert any("lost.mtlx" in e for e in validate_usd(tmp_path / "lost.usdc").errors)
    # without a document no Material prim names one
    write_usdc(asset, tmp_path / "plain.usdc")
    plain = Usd.Stage.Open(str(tmp_path / "plain.usdc"))
    assert not any(p.HasAttribute("sss:materialx") for p in plain.Traverse())


def test_names_repeat_and_clash_with_shader_names_yet_stay_unique(tmp_path):
    asset = icosphere_asset()
    a, b = asset.scene.materials
    scene = replace(asset.scene, materials=(replace(a, name="1 a"), replace(b, name="SR__1_a"),
                                            replace(b, name="1 a")))
    summary = write_mtlx(replace(asset, scene=scene), tmp_path / "n.mtlx")
    doc = _read(tmp_path / "n.mtlx")
    # the .usdc's prim names (`material_prim_names`), each with its own shader
    assert summary["materials"] == ["_1_a", "SR__1_a", "_1_a_1"]
    shaders = [doc.getNode(m).getConnectedNode("surfaceshader").getName() for m in summary["materials"]]
    assert shaders == ["SR__1_a_1", "SR_SR__1_a", "SR__1_a_1_1"]
    assert "subsurface_weight" in _inputs(doc, "_1_a") and "subsurface_weight" not in _inputs(doc, "_1_a_1")


def test_an_invalid_document_is_refused_and_nothing_written(tmp_path, monkeypatch):
    doc = mx.createDocument()
    shader = doc.addNode("open_pbr_surface", "SR_x", "surfaceshader")
    shader.addInput("subsurface_radius", "color3").setValueString("1, 2, 3")  # a float input
    doc.addMaterialNode("x", shader)
    with pytest.raises(ValueError, match="MaterialX document is invalid: .*subsurface_radius"):
        validate_document(doc)
    monkeypatch.setattr(mtlx, "to_document", lambda asset: doc)
    with pytest.raises(ValueError, match="invalid"):
        write_mtlx(icosphere_asset(), tmp_path / "x.mtlx")
    assert list(tmp_path.iterdir()) == []


def test_non_finite_factors_are_refused(tmp_path):
    asset = icosphere_asset()
    steel = replace(asset.scene.materials[1], roughness_factor=float("nan"))
    asset = replace(asset, scene=replace(asset.scene, materials=(asset.scene.materials[0], steel)))
    with pytest.raises(ValueError, match="Steel.*specular_roughness"):
        write_mtlx(asset, tmp_path / "x.mtlx")
    assert list(tmp_path.iterdir()) == []
