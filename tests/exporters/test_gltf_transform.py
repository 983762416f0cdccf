"""sssbake's data through glTF-Transform and gltfpack, with the real CLIs on a real bake.

With ``js/gltf-transform/sssbake.config.mjs`` (the ``SSSBAKE_subsurface`` extension class), weld,
prune, dedup, reorder and the recipe's optimize keep every table equal and every vertex equal
(after matching vertices, whose order reorder changes); transforms that change what the tables
index make the CLI fail. Without the config, and after gltfpack, sssbake refuses the output with
one line naming the tool, never reading wrong data.
"""

from __future__ import annotations

import shutil
import subprocess
from pathlib import Path

import numpy as np
import pygltflib as g
import pytest

from sssbake.exporters.gltf import EXTENSION, read_accessor
from sssbake.exporters.gltf_tables import SssbakeGltf, load_sssbake_gltf
from sssbake.exporters.gltf_validator import validate_many
from sssbake.exporters.inspect_gltf import inspect_glb
from sssbake.pipeline.cli import main
from sssbake.pipeline.core.errors import StaleDataError
from sssbake.pipeline.verify.verify import verify_file

REPO = Path(__file__).resolve().parents[2]
BIN = REPO / "node_modules" / ".bin"
CONFIG = REPO / "js" / "gltf-transform" / "sssbake.config.mjs"
#: The recipe's optimize: compression and quantization re-encode the vertices (the extension refuses
#: to write them), simplification changes the geometry the data was baked for; palette and join merge
#: materials and meshes.
OPTIMIZE = ["optimize", "--compress", "false", "--texture-compress", "false", "--simplify", "false",
            "--palette", "false", "--join", "false"]
#: Name -> the commands run one after the other. optimize's `sparse` leaves all-zero tables (lpv's
#: `g`) without a buffer view, which the second command must read back.
KEPT = {"weld": [["weld"]], "prune": [["prune"]], "dedup": [["dedup"]], "reorder": [["reorder"]],
        "optimize": [OPTIMIZE], "optimize+reorder": [OPTIMIZE, ["reorder"]]}

pytestmark = pytest.mark.skipif(shutil.which("node") is None or not (BIN / "gltf-transform").exists(),
                                reason="node or @gltf-transform/cli missing (npm ci)")


def gltf_transform(args: list[str], src: Path, dst: Path, config: bool = True) -> subprocess.CompletedProcess:
    """Run ``gltf-transform COMMAND src dst [OPTIONS]`` (args[0] is the command)."""
    cmd = [str(BIN / "gltf-transform"), args[0], str(src), str(dst), *args[1:]]
    return subprocess.run(cmd + (["--config", str(CONFIG)] if config else []), capture_output=True, text=True,
                          timeout=120, cwd=REPO)


@pytest.fixture(scope="module")
def baked(tmp_path_factory) -> Path:
    """The candle sample (two meshes, two materials) with all five techniques, small tables."""
    out = tmp_path_factory.mktemp("bake")
    assert main(["bake", str(REPO / "samples" / "candle.glb"), "-o", str(out), "--config",
                 str(REPO / "samples" / "sssbake.toml"), "--techniques", "prt,kernels,spectral,screen,lpv",
                 "--atlas-resolution", "64", "--lpv-resolution", "8", "--spectral-basis", "--no-validate",
                 "-q"]) == 0
    return out / "candle.glb"


@pytest.fixture(scope="module")
def processed(baked, tmp_path_factory) -> dict[str, Path]:
    """Each of `KEPT`'s commands run with the config on the bake."""
    out = tmp_path_factory.mktemp("processed")
    paths = {}
    for name, commands in KEPT.items():
        src = baked
        for k, args in enumerate(commands):
            paths[name] = out / f"{name}.{k}.glb"
            proc = gltf_transform(args, src, paths[name])
            assert proc.returncode == 0, proc.stdout + proc.stderr
            src = paths[name]
    return paths


def _by_name(items: list) -> dict[str, int]:
    names = [item.name for item in items]
    assert len(set(names)) == len(names), names
    return {name: i for i, name in enumerate(names)}


def _extensions(data: SssbakeGltf) -> dict:
    """Root, meshes and materials (by name: transforms may reorder them) with every table read."""
    out = {"root": data.resolved(data.root, "root")}
    for owner in ("meshes", "materials"):
        items = getattr(data.gltf, owner)
        for name, i in _by_name(items).items():
            ext = data.extension(items[i])
            out[f"{owner}/{name}"] = None if ext is None else data.resolved(ext, f"{owner}[{i}]")
    return out


def _assert_same(a, b, where: str = "") -> None:
    if isinstance(a, np.ndarray):
        assert isinstance(b, np.ndarray) and a.dtype == b.dtype and a.shape == b.shape, where
        assert np.array_equal(a, b), where
    elif isinstance(a, dict):
        assert isinstance(b, dict) and a.keys() == b.keys(), where
        for k in a:
            _assert_same(a[k], b[k], f"{where}/{k}")
    else:
        assert a == b, where


def _vertices(data: SssbakeGltf, mesh: int, prim: int) -> tuple[np.ndarray, np.ndarray]:
    """(n, c) float64 rows of every attribute of a primitive (`_` ones through the checked reader)
    and its (t, 3) triangles."""
    p = data.gltf.meshes[mesh].primitives[prim]
    cols = []
    for name, index in sorted((k, v) for k, v in p.attributes.items() if v is not None):
        if name.startswith("_"):
            values = data.attribute(mesh, prim, name)
        else:
            values = read_accessor(data.gltf, index, data.blob).astype(np.float64)
        cols.append(values.reshape(len(values), -1))
    return np.hstack(cols), read_accessor(data.gltf, p.indices, data.blob).reshape(-1, 3).astype(np.int64)


def _canonical(rows: np.ndarray, triangles: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The vertex rows sorted, and the triangles as sorted rows of sorted-vertex ranks, each rotated
    to start at its smallest (winding kept): equal for any vertex and triangle order."""
    unique, rank = np.unique(rows, axis=0, return_inverse=True)
    tri = rank.reshape(-1)[triangles]
    tri = np.array([np.roll(t, -int(np.argmin(t))) for t in tri])
    return unique, tri[np.lexsort(tri.T[::-1])]


@pytest.mark.parametrize("command", list(KEPT))
def test_config_keeps_tables_and_vertices(baked, processed, command):
    src, dst = load_sssbake_gltf(baked), load_sssbake_gltf(processed[command])
    assert dst.gltf.asset.generator.startswith("glTF-Transform")
    assert EXTENSION in dst.gltf.extensionsUsed and EXTENSION not in (dst.gltf.extensionsRequired or [])
    before, after = _extensions(src), _extensions(dst)
    tables = [v for v in before["meshes/wax_body"]["prt"].values() if isinstance(v, np.ndarray)]
    assert len(tables) >= 8  # prt's tables are really compared, not skipped
    _assert_same(before, after)
    # inspect counts each attribute's own bytes, not an interleaved view's whole stride
    assert inspect_glb(processed[command])["bytesPerVertex"] == inspect_glb(baked)["bytesPerVertex"]
    if command.startswith("optimize"):  # the zero-filled path is exercised
        assert any(a.bufferView is None for a in dst.gltf.accessors if (a.name or "").startswith("sssbake/"))
    dst_meshes = _by_name(dst.gltf.meshes)
    for name, i in _by_name(src.gltf.meshes).items():
        for p in range(len(src.gltf.meshes[i].primitives)):
            rows, tri = _canonical(*_vertices(src, i, p))
            rows2, tri2 = _canonical(*_vertices(dst, dst_meshes[name], p))
            assert np.array_equal(rows, rows2) and np.array_equal(tri, tri2), (command, name, p)


def test_processed_renders_as_baked(baked, processed, tmp_path):
    """The prt runtime draws the optimized and reordered file as it draws the bake."""
    base = verify_file(baked, "prt", size=96, frames=1, out_dir=tmp_path)
    got = verify_file(processed["optimize+reorder"], "prt", size=96, frames=1, out_dir=tmp_path)
    assert got["rmse_image"] == pytest.approx(base["rmse_image"], rel=1e-6, abs=1e-9)


def test_processed_files_validate(processed):
    for path, report in zip(processed.values(), validate_many(list(processed.values()))):
        assert report.codes("error") == [] and report.codes("warning") == [], (path.name, report.to_json())


@pytest.mark.parametrize("command", ["weld", "prune"])
def test_without_config_refused(baked, tmp_path, command, capsys):
    out = tmp_path / f"{command}.glb"
    assert gltf_transform([command], baked, out, config=False).returncode == 0
    with pytest.raises(StaleDataError) as err:
        load_sssbake_gltf(out)
    message = str(err.value)
    assert "\n" not in message and str(out) in message and "glTF-Transform" in message.replace(str(out), "")
    assert main(["verify", str(out)]) == 1
    line = capsys.readouterr().err.strip()
    assert "\n" not in line and "glTF-Transform" in line.replace(str(out), "")


def test_gltfpack_refused(baked, tmp_path, capsys):
    if not (BIN / "gltfpack").exists():
        pytest.skip("gltfpack missing (npm ci)")
    out = tmp_path / "packed.glb"
    # -kv keeps unused attributes, -noq keeps floats: gltfpack still drops `_` attributes and the extension.
    proc = subprocess.run([str(BIN / "gltfpack"), "-kv", "-noq", "-i", str(baked), "-o", str(out)],
                          capture_output=True, text=True, timeout=120)
    assert proc.returncode == 0, proc.stderr
    assert main(["verify", str(out)]) == 1
    line = capsys.readouterr().err.strip()
    assert "\n" not in line and "gltfpack" in line.replace(str(out), ""), line  # the path names the test


@pytest.mark.parametrize("args, why", [
    (["quantize"], "quantized positions"),
    (["draco"], "KHR_draco_mesh_compression re-encodes"),
    (["meshopt"], "EXT_meshopt_compression re-encodes"),
])
def test_transforms_that_change_vertices_fail(baked, tmp_path, args, why):
    out = tmp_path / "out.glb"
    proc = gltf_transform(args, baked, out)
    assert proc.returncode != 0 and not out.exists()
    assert f"{EXTENSION}: " in proc.stdout and why in proc.stdout, proc.stdout + proc.stderr


def _edit(src: Path, dst: Path, edit) -> None:
    gltf = g.GLTF2.load(str(src))
    edit(gltf.meshes[0].extensions[EXTENSION]["prt"])
    gltf.save_binary(str(dst))


def test_stale_input_refused_by_extension(baked, tmp_path):
    def corrupt(prt):
        prt["lut"]["crc32"] = f"{int(prt['lut']['crc32'], 16) ^ 1:08x}"
    _edit(baked, tmp_path / "stale.glb", corrupt)
    proc = gltf_transform(["copy"], tmp_path / "stale.glb", tmp_path / "out.glb")
    assert proc.returncode != 0 and not (tmp_path / "out.glb").exists()
    assert "table sssbake/mesh0/prt/lut is stale (crc32" in proc.stdout, proc.stdout + proc.stderr


def test_tables_found_by_name_not_index(baked, tmp_path):
    """References whose indices another tool swapped still resolve, by name, and come out fixed."""
    def swap(prt):
        prt["lut"]["accessor"], prt["directions"]["accessor"] = prt["directions"]["accessor"], prt["lut"]["accessor"]
    _edit(baked, tmp_path / "swapped.glb", swap)
    proc = gltf_transform(["copy"], tmp_path / "swapped.glb", tmp_path / "out.glb")
    assert proc.returncode == 0, proc.stderr
    out = load_sssbake_gltf(tmp_path / "out.glb")
    prt = out.gltf.meshes[0].extensions[EXTENSION]["prt"]
    assert out.gltf.accessors[prt["lut"]["accessor"]].name == prt["lut"]["name"]
    _assert_same(_extensions(load_sssbake_gltf(baked)), _extensions(out))
