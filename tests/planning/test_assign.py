import numpy as np
import pytest

from sssbake.pipeline.bake.fallback import make_fallback
from sssbake.pipeline.core.materials import MaterialError, preset
from sssbake.pipeline.mesh.scene import Mesh, Node, Primitive, Scene, SourceMaterial
from sssbake.pipeline.options import BakeOptions
from sssbake.pipeline.planning.assign import DEFAULT_MATERIAL_NAME, assign_materials, material_from_khr_volume

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
