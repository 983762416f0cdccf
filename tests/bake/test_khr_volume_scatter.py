"""``sssbake bake --khr-materials-volume-scatter``: the draft extension in the .glb, off by default,
in the job key, valid, and read back on a re-bake."""

import json
import struct

import numpy as np
import trimesh

from sssbake.exporters.gltf import EXTENSION, VOLUME_SCATTER
from sssbake.pipeline.bake.asset import job_key
from sssbake.pipeline.cli import main
from sssbake.pipeline.core.materials import preset
from sssbake.pipeline.options import BAKE_DEFAULTS

MARBLE = preset("marble")  # the default material


def _glb_json(path) -> tuple[dict, bytes]:
    """The GLB's JSON chunk, and the rest of the file (its BIN chunk)."""
    data = path.read_bytes()
    (length,) = struct.unpack("<I", data[12:16])
    return json.loads(data[20:20 + length]), data[20 + length:]


def _without_sssbake(path, to) -> None:
    """Write `path`'s GLB to `to` without any SSSBAKE_subsurface object (its tables stay, unreferenced)."""
    doc, rest = _glb_json(path)
    for owner in (doc, *doc["materials"], *doc["meshes"]):
        owner.get("extensions", {}).pop(EXTENSION, None)
    doc["extensionsUsed"].remove(EXTENSION)
    text = json.dumps(doc).encode()
    text += b" " * (-len(text) % 4)
    to.write_bytes(struct.pack("<III", 0x46546C67, 2, 20 + len(text) + len(rest))
                   + struct.pack("<II", len(text), 0x4E4F534A) + text + rest)


def _bake(asset, out, *flags) -> dict:
    assert main(["bake", str(asset), "-o", str(out), "--scale-mm", "1", "--techniques", "none",
                 "--atlas-resolution", "32", "-q", *flags]) == 0
    return json.loads((out / f"{asset.stem}.report.json").read_text())


def test_flag_writes_the_materials_json_numbers_and_rebakes(tmp_path):
    ball = tmp_path / "ball.obj"
    trimesh.creation.icosphere(subdivisions=2, radius=10.0).export(ball)
    out, glb = tmp_path / "out", tmp_path / "out" / "ball.glb"
    _bake(ball, out)
    off = glb.read_bytes()
    doc, _ = _glb_json(glb)
    assert VOLUME_SCATTER not in doc["extensionsUsed"]
    assert all(VOLUME_SCATTER not in m.get("extensions", {}) for m in doc["materials"])

    # the option is in the job key: the same folder is baked again, not served the file without it
    report = _bake(ball, out, "--khr-materials-volume-scatter")
    on, _ = _glb_json(glb)
    (material,) = on["materials"]
    (record,) = json.loads((out / "ball.materials.json").read_text())["materials"].values()
    khr = record["khrMaterialsVolumeScatter"]
    assert material["extensions"][VOLUME_SCATTER] == {"multiscatterColor": khr["multiscatterColor"],
                                                       "multiscatterColorFactor": khr["multiscatterColor"],
                                                       "scatterAnisotropy": 0.0}
    volume = material["extensions"]["KHR_materials_volume"]
    assert (volume["attenuationColor"], volume["attenuationDistance"]) == (khr["attenuationColor"],
                                                                          khr["attenuationDistance"])
    sigma_t = -np.log(volume["attenuationColor"]) / volume["attenuationDistance"] / 1.0  # 1 mm per unit
    np.testing.assert_allclose(sigma_t, MARBLE.sigma_t_prime, rtol=1e-9)
    assert np.all(np.isfinite(material["extensions"][VOLUME_SCATTER]["multiscatterColor"]))
    assert VOLUME_SCATTER in on["extensionsUsed"] and VOLUME_SCATTER not in on.get("extensionsRequired", [])
    # the validator, where there is one, says it does not know the draft (an information) and nothing worse
    gltf = report["validation"]["gltf"]
    assert gltf.get("skipped") or (gltf["errors"], gltf["warnings"]) == (0, 0), gltf

    # off again: the very bytes of the first bake, also when a config sets it false
    (tmp_path / "off.toml").write_text("[defaults]\nkhr_materials_volume_scatter = false\n")
    _bake(ball, out, "--config", str(tmp_path / "off.toml"))
    assert glb.read_bytes() == off
    # and a config turns it on as the flag does
    (tmp_path / "on.toml").write_text("[defaults]\nkhr_materials_volume_scatter = true\n")
    _bake(ball, out, "--config", str(tmp_path / "on.toml"))
    assert _glb_json(glb)[0] == on

    # re-baked without SSSBAKE_subsurface (read only by sssbake's runtimes): the medium comes back
    # from the draft and the attenuation, not from --material nor from the fallback's reading
    _without_sssbake(glb, tmp_path / "plain.glb")
    again = _bake(tmp_path / "plain.glb", tmp_path / "again", "--material", "skin1")
    (entry,) = again["materials"].values()
    assert "KHR_materials_volume_scatter" in entry["reason"]
    np.testing.assert_allclose(entry["scattering"]["sigma_s_prime"], MARBLE.sigma_s_prime, rtol=1e-6)
    np.testing.assert_allclose(entry["scattering"]["sigma_a"], MARBLE.sigma_a, rtol=1e-6)
    assert entry["scattering"]["eta"] == MARBLE.eta


def test_job_key_follows_the_option():
    on = BAKE_DEFAULTS.merged({"khr_materials_volume_scatter": True})
    assert BAKE_DEFAULTS.khr_materials_volume_scatter is False
    assert job_key("d" * 64, on) != job_key("d" * 64, BAKE_DEFAULTS)
