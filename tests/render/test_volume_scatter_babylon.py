"""Babylon.js maps sssbake's draft KHR_materials_volume_scatter (``--khr-materials-volume-scatter``).

samples/thin_slab.stl (skin1, 2 mm; its fallback has transmission and diffuse transmission > 0, which
Babylon's loader needs before it reads the draft) is baked by the ``sssbake bake`` CLI with and
without the flag, and each .glb is loaded by Babylon's glTF loader in headless Chromium
(tests/js/volume_scatter_babylon.html), with ``useOpenPBR: true`` (OpenPBRMaterial) and with the
default PBRMaterial. The page reports the material values the loader set; they are checked against
closed forms from the file and sssbake's own `Material`, not against Babylon's code:

- OpenPBR: subsurfaceColor = the file's multiscatterColorFactor; subsurfaceRadius ×
  subsurfaceRadiusScale = 1/σ'_t in file units = ℓ / mm_per_unit per channel (ℓ =
  `Material.mean_free_path_mm`); subsurfaceScatterAnisotropy = 0 (the file's scatterAnisotropy).
- Controls: the same sample baked without the flag, and the flagged file with only the draft
  extension removed, leave subsurfaceColor, subsurfaceRadius and subsurfaceRadiusScale at
  OpenPBRMaterial's defaults: the draft, nothing else in the file, sets them.
- PBRMaterial (no sub-surface colour or radius of its own): the adapter writes the draft's
  extinction into subSurface.diffusionDistance, checked against its closed form too.

``python -m pytest -s`` prints what the page reported.
"""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
import tomllib
from pathlib import Path

import numpy as np
import pygltflib
import pytest

from sssbake.pipeline.core.engine_materials import khr_materials_volume_scatter
from sssbake.pipeline.core.materials import Material, preset
from tests.browser import have_chromium, open_page, static_server
from tests.render.test_fallback_engines import glb_materials

REPO = Path(__file__).resolve().parents[2]
NODE_MODULES = REPO / "node_modules"
MOUNTS = {"babylon-core": "@babylonjs/core", "babylon-loaders": "@babylonjs/loaders"}
PAGE = "volume_scatter_babylon.html"
DRAFT = "KHR_materials_volume_scatter"
#: float32's relative precision: what "the same colour" means for a value a GPU material holds
F32 = float(np.finfo(np.float32).eps)

pytestmark = [
    pytest.mark.skipif(not have_chromium(), reason="needs Chromium, node and puppeteer-core (.ci/setup)"),
    pytest.mark.skipif(not all((NODE_MODULES / p).is_dir() for p in MOUNTS.values()),
                       reason=f"npm packages missing: {', '.join(MOUNTS.values())} (npm ci)"),
]


def bake(src: Path, out: Path, *flags: str) -> Path:
    """thin_slab.stl in `src` baked by the CLI into `out` (no technique: only the material matters)."""
    run = subprocess.run(
        [sys.executable, "-m", "sssbake.pipeline.cli", "bake", str(src), "-o", str(out), "--config",
         str(REPO / "samples" / "sssbake.toml"), "--techniques", "none", "--no-cache", "-q", *flags],
        capture_output=True, text=True, timeout=600)
    assert run.returncode == 0, run.stdout + run.stderr
    return out / "thin_slab.glb"


def without_draft(path: Path, out: Path) -> None:
    """`path` with the draft extension taken off every material (and ``extensionsUsed``), all else as written."""
    gltf = pygltflib.GLTF2.load(str(path))
    for m in gltf.materials:
        m.extensions.pop(DRAFT, None)
    gltf.extensionsUsed = [e for e in gltf.extensionsUsed if e != DRAFT]
    gltf.save_binary(str(out))


def mm_per_unit(path: Path) -> float:
    """The asset's scale as the .glb records it (its root SSSBAKE_subsurface)."""
    return float(pygltflib.GLTF2.load(str(path)).extensions["SSSBAKE_subsurface"]["scaleMmPerUnit"])


@pytest.fixture(scope="module")
def loaded(tmp_path_factory):
    """(the flagged file's material, its scale, the page's report) with the page's cases:
    {draft, plain, stripped} × {openpbr, pbr}."""
    root = tmp_path_factory.mktemp("volume_scatter_babylon")
    src, site = root / "in", root / "site"
    src.mkdir()
    site.mkdir()
    shutil.copy(REPO / "samples" / "thin_slab.stl", src / "thin_slab.stl")
    shutil.copy(bake(src, root / "draft", "--khr-materials-volume-scatter"), site / "draft.glb")
    shutil.copy(bake(src, root / "plain"), site / "plain.glb")
    without_draft(site / "draft.glb", site / "stripped.glb")
    shutil.copy(REPO / "tests" / "js" / "fallback_page.mjs", site / "fallback_page.mjs")
    shutil.copy(REPO / "tests" / "js" / PAGE, site / PAGE)
    for folder, package in MOUNTS.items():
        os.symlink(NODE_MODULES / package, site / folder)
    cases = [{"name": f"{stem}_{mode}", "glb": f"{stem}.glb", "useOpenPBR": mode == "openpbr"}
             for stem in ("draft", "plain", "stripped") for mode in ("openpbr", "pbr")]
    (site / "cases.json").write_text(json.dumps({"cases": cases}))
    with static_server(site) as base_url:
        # a window under ~100 px makes Chromium's screenshot hang (measured: 16² timed out, 160² took 5 s)
        page = open_page(f"{base_url}{PAGE}?config=cases.json", site / "page.png", 160, 160, timeout_s=300)
    print("\nBabylon.js loaded (tests/js/volume_scatter_babylon.html):")
    print(json.dumps(page.result, indent=1))
    (material,) = glb_materials(site / "draft.glb")
    return material, mm_per_unit(site / "draft.glb"), page.result


def the_material(result: dict, case: str, class_name: str) -> dict:
    (m,) = result["cases"][case]
    assert m["className"] == class_name, m
    return m


def medium(material: dict) -> Material:
    """The medium sssbake baked (the file's SSSBAKE_subsurface material record)."""
    return Material.from_json(material["extensions"]["SSSBAKE_subsurface"]["material"])


def test_file_carries_skin1_draft(loaded):
    """What the closed forms below stand on: the file's draft and volume are sssbake's skin1 medium."""
    material, scale, _ = loaded
    ext = material["extensions"]
    med = medium(material)
    assert med.name == "skin1"
    np.testing.assert_allclose(med.mean_free_path_mm, preset("skin1").mean_free_path_mm, rtol=1e-12)
    record = khr_materials_volume_scatter(med, scale)
    assert ext[DRAFT]["multiscatterColorFactor"] == pytest.approx(record["multiscatterColor"], rel=1e-12)
    assert ext[DRAFT]["scatterAnisotropy"] == 0.0
    # Babylon reads the draft only where transmission or diffuse transmission is > 0
    assert ext["KHR_materials_transmission"]["transmissionFactor"] > 0
    assert ext["KHR_materials_diffuse_transmission"]["diffuseTransmissionFactor"] > 0
    # the draft's extinction −ln(attenuationColor)/attenuationDistance is σ'_t in file units
    volume = ext["KHR_materials_volume"]
    sigma = -np.log(volume["attenuationColor"]) / volume["attenuationDistance"]
    np.testing.assert_allclose(1 / sigma, med.mean_free_path_mm / scale, rtol=1e-12)


def test_openpbr_maps_the_draft(loaded):
    material, scale, result = loaded
    ext = material["extensions"]
    m = the_material(result, "draft_openpbr", "OpenPBRMaterial")
    # the precondition Babylon checks, as the other extensions set it
    assert m["transmissionWeight"] == pytest.approx(ext["KHR_materials_transmission"]["transmissionFactor"], rel=1e-6)
    assert m["subsurfaceWeight"] == pytest.approx(
        ext["KHR_materials_diffuse_transmission"]["diffuseTransmissionFactor"], rel=1e-6)
    assert not m["geometryThinWalled"]
    # subsurface_color = the draft's multiscatter colour
    assert m["subsurfaceColor"] == pytest.approx(ext[DRAFT]["multiscatterColorFactor"], rel=F32)
    # radius × radius scale = the mean free path per channel, 1/σ'_t = ℓ / mm_per_unit in file units
    mfp_units = medium(material).mean_free_path_mm / scale
    np.testing.assert_allclose(m["subsurfaceRadius"] * np.asarray(m["subsurfaceRadiusScale"]), mfp_units, rtol=1e-5)
    assert m["subsurfaceRadius"] == pytest.approx(mfp_units.max(), rel=1e-5)
    assert m["subsurfaceScatterAnisotropy"] == ext[DRAFT]["scatterAnisotropy"] == 0.0


@pytest.mark.parametrize("case", ["plain_openpbr", "stripped_openpbr"])
def test_openpbr_without_the_draft_keeps_defaults(loaded, case):
    """Without the flag (plain), or with the flag's file less the draft alone (stripped: the same
    σ'_t attenuation), Babylon leaves OpenPBR's sub-surface colour and radius at their defaults."""
    material, _, result = loaded
    m = the_material(result, case, "OpenPBRMaterial")
    default = result["defaults"]["OpenPBRMaterial"]
    assert m["subsurfaceWeight"] > 0  # the diffuse transmission is still there
    for key in ("subsurfaceColor", "subsurfaceRadius", "subsurfaceRadiusScale"):
        assert m[key] == default[key], (case, key, m[key], default[key])
    assert m["subsurfaceColor"] != pytest.approx(material["extensions"][DRAFT]["multiscatterColorFactor"], rel=1e-3)
    # KHR_materials_diffuse_transmission alone sets a forward-scattering slab (Babylon's
    # configureSubsurface); the draft's 0 replaces it
    assert m["subsurfaceScatterAnisotropy"] == 1.0


def test_pbr_material_maps_the_draft(loaded):
    """The default PBRMaterial has no sub-surface colour or radius: Babylon's adapter writes the
    draft's extinction into subSurface.diffusionDistance = exp(−σ'_t / max σ'_t) = exp(−min ℓ / ℓ)
    (its subsurfaceColor setter; the colour itself is not used) and the radius scale ℓ / max ℓ into
    subSurface.scatteringDiffusionProfile, whose setter does nothing without the pre-pass renderer
    (null here, as without the draft). isScatteringEnabled stays off, so neither changes the
    picture unless the application turns it on."""
    material, _, result = loaded
    mfp = medium(material).mean_free_path_mm
    m = the_material(result, "draft_pbr", "PBRMaterial")
    np.testing.assert_allclose(m["diffusionDistance"], np.exp(-mfp.min() / mfp), rtol=1e-5)
    if m["scatteringDiffusionProfile"] is not None:
        np.testing.assert_allclose(m["scatteringDiffusionProfile"], mfp / mfp.max(), rtol=1e-5)
    assert not m["isScatteringEnabled"]
    default = result["defaults"]["PBRMaterial"]
    for case in ("plain_pbr", "stripped_pbr"):
        c = the_material(result, case, "PBRMaterial")
        assert c["diffusionDistance"] == default["diffusionDistance"], (case, c)
        assert c["scatteringDiffusionProfile"] == default["scatteringDiffusionProfile"], (case, c)
