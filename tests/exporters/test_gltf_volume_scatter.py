"""The draft KHR_materials_volume_scatter in the .glb: written only on request, with the numbers of
`engine_materials.khr_materials_volume_scatter` and the volume attenuation as the extinction σ'_t."""

import json
import struct
from dataclasses import replace

import numpy as np
import pygltflib
import pytest
from test_gltf import icosphere_asset

from sssbake.exporters.gltf import EXTENSION, VOLUME_SCATTER, to_glb
from sssbake.exporters.materials_json import khr_volume_scatter, materials_document
from sssbake.exporters.usd import mm_per_unit
from sssbake.pipeline.core.engine_materials import khr_materials_volume_scatter
from sssbake.pipeline.core.materials import preset


def _json(data: bytes) -> dict:
    """The GLB's JSON chunk."""
    (length,) = struct.unpack("<I", data[12:16])
    return json.loads(data[20:20 + length])


def test_off_writes_nothing_and_the_same_bytes():
    asset = icosphere_asset()
    plain, _ = to_glb(asset)
    assert to_glb(asset, None)[0] == plain and to_glb(asset, {})[0] == plain
    doc = _json(plain)
    assert VOLUME_SCATTER not in doc["extensionsUsed"]
    assert all(VOLUME_SCATTER not in m.get("extensions", {}) for m in doc["materials"])


def test_on_writes_the_records_and_sigma_t_prime():
    asset = icosphere_asset()
    records = khr_volume_scatter(asset)
    scale = mm_per_unit(asset)
    assert set(records) == {0} and scale == 10.0  # the asset's one scale, as .materials.json writes it
    plain, on = (_json(to_glb(asset, r)[0]) for r in (None, records))
    marble = on["materials"][0]["extensions"]
    expected = khr_materials_volume_scatter(preset("marble"), scale)
    # both spellings of the unsettled draft (glTF-Transform's, Babylon.js 9.28's), the same values
    assert marble[VOLUME_SCATTER] == {"multiscatterColor": expected["multiscatterColor"],
                                      "multiscatterColorFactor": expected["multiscatterColor"], "scatterAnisotropy": 0.0}
    # the same numbers as the asset's .materials.json
    (document,) = materials_document(asset, "a")["materials"].values()
    record = document["khrMaterialsVolumeScatter"]
    assert {"multiscatterColor": record["multiscatterColor"], "multiscatterColorFactor": record["multiscatterColor"],
            "scatterAnisotropy": record["scatterAnisotropy"]} == marble[VOLUME_SCATTER]
    volume = marble["KHR_materials_volume"]
    assert volume["attenuationColor"] == document["khrMaterialsVolumeScatter"]["attenuationColor"]
    assert volume["attenuationDistance"] == document["khrMaterialsVolumeScatter"]["attenuationDistance"]
    # closed form: −ln(colour) / distance is σ'_t in 1/file unit
    sigma_t = -np.log(volume["attenuationColor"]) / volume["attenuationDistance"] / scale
    np.testing.assert_allclose(sigma_t, preset("marble").sigma_t_prime, rtol=1e-9)
    # the thickness stays the fallback's; nothing else on the material changes
    fallback = plain["materials"][0]["extensions"]["KHR_materials_volume"]
    assert {k: volume[k] for k in ("thicknessFactor", "thicknessTexture")} == \
        {k: fallback[k] for k in ("thicknessFactor", "thicknessTexture")}
    assert {k: v for k, v in marble.items() if k not in (VOLUME_SCATTER, "KHR_materials_volume")} == \
        {k: v for k, v in plain["materials"][0]["extensions"].items() if k != "KHR_materials_volume"}
    assert on["materials"][1] == plain["materials"][1]  # the opaque one
    assert sorted(on["extensionsUsed"]) == sorted([*plain["extensionsUsed"], VOLUME_SCATTER])
    assert VOLUME_SCATTER not in on.get("extensionsRequired", [])  # a viewer without the draft keeps the rest
    assert EXTENSION in on["extensionsUsed"]


def test_the_file_stays_valid():
    from sssbake.exporters.gltf_validator import ValidatorUnavailable, validate_glb

    asset = icosphere_asset()
    data, _ = to_glb(asset, khr_volume_scatter(asset))
    pygltflib.GLTF2.load_from_bytes(data)
    try:
        report = validate_glb(data)
    except ValidatorUnavailable as exc:
        pytest.skip(str(exc))
    assert (report.num_errors, report.num_warnings) == (0, 0), report.to_json()
    # glTF-Validator 2.0.0-dev.3.10 does not know the draft: an information, as for any unknown extension
    assert any(m.code == "UNSUPPORTED_EXTENSION" and m.severity == "Information" and VOLUME_SCATTER in m.message
               for m in report.messages)


def test_records_only_for_scattering_materials_and_finite():
    asset = icosphere_asset()
    record = khr_volume_scatter(asset)[0]
    with pytest.raises(ValueError, match=r"KHR_materials_volume_scatter for materials \[1\]"):
        to_glb(asset, {1: record})
    with pytest.raises(ValueError, match="multiscatterColor has non-finite values"):
        to_glb(asset, {0: {**record, "multiscatterColor": [0.5, float("nan"), 0.5]}})
    with pytest.raises(ValueError, match="attenuationDistance is not finite"):
        to_glb(asset, {0: {**record, "attenuationDistance": float("inf")}})


def test_a_fallback_without_attenuation_gets_the_distance():
    # no absorption: the fallback omits attenuationDistance (+inf); the draft's σ'_t is finite
    asset = icosphere_asset()
    sm = asset.scattering[0]
    asset = replace(asset, scattering={0: replace(sm, fallback=replace(sm.fallback, attenuation_distance=float("inf")))})
    assert "attenuationDistance" not in _json(to_glb(asset)[0])["materials"][0]["extensions"]["KHR_materials_volume"]
    volume = _json(to_glb(asset, khr_volume_scatter(asset))[0])["materials"][0]["extensions"]["KHR_materials_volume"]
    assert volume["attenuationDistance"] == khr_volume_scatter(asset)[0]["attenuationDistance"]
