"""What a glTF viewer draws of the standard fallback under verify's lobe."""

import numpy as np
import pygltflib

from sssbake.pipeline.verify.fallback_radiance import FallbackLook
from sssbake.pipeline.verify.volpath import Lobe


def test_fallback_lobes_follow_the_gltf_bsdf():
    """Light on the lit side reflects (1 - t)(1 - f) base E/π, light from behind transmits
    (1 - t) f c E/π with no shadow test, and the lobe's irradiance on a surface facing it is 1."""
    directions, weights = Lobe((0.0, 0.0, 1.0)).quadrature()
    look = FallbackLook((0.8, 0.6, 0.4), 0.25, 0.5, (1.0, 0.5, 0.25))
    normals = np.array([[0.0, 0.0, 1.0], [0.0, 0.0, -1.0], [1.0, 0.0, 0.0]])
    visible = np.ones((3, len(directions)), dtype=bool)
    got = look.radiance(normals, directions, weights, visible)
    assert np.allclose(got[0], 0.75 * 0.5 * np.array([0.8, 0.6, 0.4]) / np.pi)
    assert np.allclose(got[1], 0.75 * 0.5 * np.array([1.0, 0.5, 0.25]) / np.pi)
    # a side face: the lobe's half on its side reflects, the other half comes through
    lit, through = (np.clip(s * directions @ normals[2], 0, None) @ weights for s in (1.0, -1.0))
    assert lit > 0.1 and through > 0.1
    assert np.allclose(got[2], 0.75 * 0.5 * (lit * np.array([0.8, 0.6, 0.4]) + through * np.array([1.0, 0.5, 0.25]))
                       / np.pi)
    visible[0] = False  # shadowed on its own side: only what comes through (nothing, here)
    assert np.allclose(look.radiance(normals, directions, weights, visible)[0], 0.0)


def test_fallback_look_reads_the_exported_material():
    material = pygltflib.Material(
        pbrMetallicRoughness=pygltflib.PbrMetallicRoughness(baseColorFactor=[0.7, 0.5, 0.3, 1.0]),
        extensions={"KHR_materials_transmission": {"transmissionFactor": 0.2},
                    "KHR_materials_diffuse_transmission": {"diffuseTransmissionFactor": 0.4,
                                                           "diffuseTransmissionColorFactor": [0.9, 0.8, 0.7]}})
    assert FallbackLook.of(material) == FallbackLook((0.7, 0.5, 0.3), 0.2, 0.4, (0.9, 0.8, 0.7))
    material.pbrMetallicRoughness.baseColorTexture = pygltflib.TextureInfo(index=0)
    assert FallbackLook.of(material) is None
