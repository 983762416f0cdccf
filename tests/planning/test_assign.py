from dataclasses import replace

import numpy as np
import pytest

from sssbake.pipeline.bake.fallback import make_fallback
from sssbake.pipeline.core.engine_materials import khr_materials_volume_scatter
from sssbake.pipeline.core.materials import COEFFICIENT, EXTINCTION, MaterialError, preset
from sssbake.pipeline.mesh.scene import Mesh, Node, Primitive, Scene, SourceMaterial
from sssbake.pipeline.options import BakeOptions
from sssbake.pipeline.planning.assign import (
    DEFAULT_MATERIAL_NAME,
    assign_materials,
    material_from_khr_volume,
    material_from_khr_volume_scatter,
)

TRI = (np.eye(3), np.array([[0, 1, 2]]))


def _scene(materials, prim_materials):
    prims = tuple(Primitive(*TRI, material=m) for m in prim_materials)
    return Scene("s.glb", (Mesh("m", prims),), (Node("n", np.eye(4), 0),), (0,), materials=tuple(materials))


def test_rules_then_khr_then_default():
    fb = make_fallback(preset("skin1"), 1.0, np.array([5.0]), None, 5.0)
    vol = SourceMaterial("Flesh", base_color_factor=(*fb.base_color, 1.0), ior=1.3,
                         volume={"attenuationColor": list(fb.attenuation_color), "attenuationDistance": fb.attenuation_distance})
    mats = [SourceMaterial("Wax.001"), SourceMaterial("Tyre"), vol, SourceMaterial("Other")]
    opts = BakeOptions(material="marble", materials=(("wax*", "cream"), ("Tyre", "opaque")))
    a = assign_materials(_scene(mats, [0, 1, 2, 3, None]), opts, mm_per_unit=1.0)
    assert a.materials[0] == preset("cream") and "wax*" in a.reasons[0]
    assert a.materials[1] is None
    assert a.materials[3] == preset("marble")
    # Primitives with no material get one, with the asset's material.
    assert a.scene.materials[4].name == DEFAULT_MATERIAL_NAME and a.materials[4] == preset("marble")
    assert a.scene.meshes[0].primitives[4].material == 4
    # KHR_materials_volume written by sssbake's own fallback maps back to the coefficients.
    back = a.materials[2]
    np.testing.assert_allclose(back.sigma_s_prime, preset("skin1").sigma_s_prime, rtol=1e-6)
    np.testing.assert_allclose(back.sigma_a, preset("skin1").sigma_a, rtol=1e-6)


def test_khr_volume_without_attenuation_is_not_a_material():
    assert material_from_khr_volume(SourceMaterial("g", volume={"thicknessFactor": 1.0}), 1.0) is None


def test_bad_rule_raises_material_error():
    with pytest.raises(MaterialError, match="unknown material preset"):
        assign_materials(_scene([SourceMaterial("A")], [0]), BakeOptions(material="granite"), 1.0)


def _scatter_material(name: str, record: dict, **volume) -> SourceMaterial:
    """A material carrying `record` (`khr_materials_volume_scatter`) as an sssbake bake writes it."""
    return SourceMaterial(name, ior=1.3, volume={"attenuationColor": record["attenuationColor"],
                                                 "attenuationDistance": record["attenuationDistance"], **volume},
                          volume_scatter={"multiscatterColor": record["multiscatterColor"],
                                          "scatterAnisotropy": record["scatterAnisotropy"]})


def test_khr_volume_scatter_gives_back_the_medium_before_the_fallback_volume():
    skin = preset("skin1")
    record = khr_materials_volume_scatter(skin, 2.0)
    src = _scatter_material("Flesh", record)
    back = material_from_khr_volume_scatter(src, 2.0)
    np.testing.assert_allclose(back.sigma_s_prime, skin.sigma_s_prime, rtol=1e-9)
    np.testing.assert_allclose(back.sigma_a, skin.sigma_a, rtol=1e-9)
    assert back.eta == 1.3 and back.profile == "montecarlo"
    a = assign_materials(_scene([src, SourceMaterial("Flesh.rule", volume_scatter={})], [0, 1]),
                         BakeOptions(materials=(("*.rule", "cream"),)), mm_per_unit=2.0)
    assert a.materials[0] == back and "KHR_materials_volume_scatter" in a.reasons[0]
    assert a.materials[1] == preset("cream")  # a rule still comes first
    # a Henyey-Greenstein g in the file: reduced by the similarity relation
    forward = material_from_khr_volume_scatter(replace(src, volume_scatter={**src.volume_scatter,
                                                                            "scatterAnisotropy": 0.5}), 2.0)
    np.testing.assert_allclose(forward.sigma_s_prime, 0.5 * skin.s, rtol=1e-9)
    np.testing.assert_allclose(forward.sigma_a, skin.sigma_a, rtol=1e-9)
    # Babylon.js' spelling of the colour is read first (an sssbake file carries both, equal)
    factor = replace(src, volume_scatter={"multiscatterColorFactor": record["multiscatterColor"],
                                          "multiscatterColor": [0.0, 0.0, 0.0], "scatterAnisotropy": 0.0})
    assert material_from_khr_volume_scatter(factor, 2.0) == back


def test_khr_volume_scatter_edges():
    record = khr_materials_volume_scatter(preset("marble"), 1.0)
    # no attenuation distance: the draft's medium never interacts; the base colour path has none either
    bare = SourceMaterial("Glass", volume={"thicknessFactor": 1.0}, volume_scatter={"multiscatterColor": [0.5] * 3})
    assert material_from_khr_volume_scatter(bare, 1.0) is None
    # a clear channel (colour 1) and an opaque one (colour 0) are held at the ends of what sssbake bakes
    ends = material_from_khr_volume_scatter(_scatter_material("Ends", {**record, "attenuationColor": [1.0, 0.0, 0.5]}),
                                            1.0)
    np.testing.assert_allclose(ends.s + ends.a, [EXTINCTION.low, COEFFICIENT.high, -np.log(0.5) / record["attenuationDistance"]])
    with pytest.raises(MaterialError, match="'Odd': KHR_materials_volume_scatter multiscatterColor must be 3 finite"):
        material_from_khr_volume_scatter(_scatter_material("Odd", {**record, "multiscatterColor": "white"}), 1.0)
