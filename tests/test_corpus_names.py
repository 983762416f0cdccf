"""File names a POSIX folder may hold: a newline, bytes that are not UTF-8, 244 and 255 bytes. Each
bakes (the outputs named after it, the USD's textures found by the name it references) or fails on
one line naming the file; every line the command prints is one line; nothing is left behind.
And a Python module a loader lacks is named as missing, not blamed on the file."""

import json
import os
import sys
from pathlib import Path

import pytest
import trimesh
from fixtures import FAST_DEFAULTS
from pxr import Usd, UsdShade

from sssbake.pipeline.bake.batch import run_batch
from sssbake.pipeline.cli import main
from sssbake.pipeline.config import load_config

NEWLINE = "nl\nname"
NOT_UTF8 = os.fsdecode(b"\xff\xfe")  # os.fsdecode's surrogate escapes, as os.listdir gives the name
LONG = "a" * 240  # with ".obj", 244 bytes: the temporary names passed 255
LONGEST = "b" * 251  # with ".obj", 255 bytes: its ".usdc" would be 256
GARBAGE = "bad\nx"  # fails to load: its line must stay one line


def test_hostile_names_bake_or_fail_on_one_line(tmp_path, capsys):
    if os.pathconf(tmp_path, "PC_NAME_MAX") != 255:
        pytest.skip("the long names are sized for the common 255-byte limit")
    src, out = tmp_path / "in", tmp_path / "out"
    src.mkdir()
    sphere = trimesh.creation.icosphere(subdivisions=1, radius=5.0).export(file_type="obj").encode()
    for stem in ("good", NEWLINE, NOT_UTF8, LONG, LONGEST):
        (src / f"{stem}.obj").write_bytes(sphere)
    (src / f"{GARBAGE}.obj").write_bytes(b"garbage\n")
    config = tmp_path / "c.toml"
    config.write_text(FAST_DEFAULTS)
    assert main(["bake", str(src), "-o", str(out), "--config", str(config)]) == 1
    printed = capsys.readouterr()
    # every line is one line: the names' newlines and undecodable bytes written as escapes
    garbage, longest = sorted(line for line in printed.err.splitlines() if line.startswith("error:"))
    assert garbage == f"error: {src}/bad\\nx.obj: no triangles: the file has no geometry"
    # the .mtlx, as long a name as the .usdc's, is written first
    assert longest.startswith(f"error: {src / LONGEST}.obj: {out}/") and longest.endswith(
        f"/{LONGEST}.mtlx: File name too long (256 bytes; this folder allows 255): give the asset a shorter name")
    lines = printed.out.splitlines()
    assert sorted(line.split("  (")[0] for line in lines[:-1]) == sorted(
        f"        ok  {src}/{stem}.obj" for stem in ("good", "nl\\nname", "\\xff\\xfe", LONG))
    assert lines[-1].startswith("4 baked, 2 failed")
    batch = json.loads((out / "batch.json").read_text())  # surrogates as JSON escapes: read back as written
    status = {Path(r["asset"]).name: r["status"] for r in batch["assets"]}
    assert status == {"good.obj": "ok", f"{NEWLINE}.obj": "ok", f"{NOT_UTF8}.obj": "ok", f"{LONG}.obj": "ok",
                      f"{LONGEST}.obj": "failed", f"{GARBAGE}.obj": "failed"}
    # USD asset paths hold no control characters nor bytes that are not UTF-8: those textures are
    # named with %XX, and the .usdc finds them
    textures = {"good": "good", NEWLINE: "nl%0Aname", NOT_UTF8: "%FF%FE", LONG: LONG}
    expected = [".sssbake.lock", "batch.json"]
    for stem, texture in textures.items():
        expected += [f"{stem}.glb", f"{stem}.materials.json", f"{stem}.report.json", f"{texture}.thickness0.png",
                     f"{texture}.mtlx", f"{stem}.usdc"]
        stage = Usd.Stage.Open(os.fsencode(out / f"{stem}.usdc"))
        files = [UsdShade.Shader(p).GetInput("file").Get() for p in stage.Traverse()
                 if p.GetName() == "ThicknessTexture"]
        assert [(f.path, f.resolvedPath) for f in files] == [(f"./{texture}.thickness0.png",
                                                              str(out / f"{texture}.thickness0.png"))]
        documents = {p.GetAttribute("sss:materialx").Get() for p in stage.Traverse() if p.HasAttribute("sss:materialx")}
        assert [(d.path, d.resolvedPath) for d in documents] == [(f"./{texture}.mtlx", str(out / f"{texture}.mtlx"))]
    assert sorted(p.name for p in out.iterdir() if p.name != ".sssbake-cache") == sorted(expected)


def test_a_missing_module_is_named_not_blamed_on_the_file(tmp_path, monkeypatch):
    """trimesh imports charset_normalizer for an OBJ that is not UTF-8 text."""
    src, out = tmp_path / "in", tmp_path / "out"
    src.mkdir()
    sphere = trimesh.creation.icosphere(subdivisions=1, radius=5.0).export(file_type="obj").encode()
    (src / "good.obj").write_bytes(sphere)
    (src / "latin1.obj").write_bytes(b"# caf\xe9\n" + sphere)
    monkeypatch.setitem(sys.modules, "charset_normalizer", None)  # its import fails
    config = tmp_path / "c.toml"
    config.write_text(FAST_DEFAULTS)
    summary = run_batch([src], out, load_config(config), {}, cache_dir=None, progress=False, isolate=False)
    by_name = {Path(r["asset"]).name: r for r in summary["assets"]}
    assert by_name["good.obj"]["status"] == "ok"
    assert by_name["latin1.obj"]["error"] == (
        f"{src / 'latin1.obj'}: needs the Python module charset_normalizer (import of charset_normalizer halted; "
        "None in sys.modules): pip install charset-normalizer")
    assert sorted(p.name for p in out.iterdir()) == [".sssbake.lock", "batch.json", "good.glb",
                                                    "good.materials.json", "good.mtlx", "good.report.json",
                                                    "good.thickness0.png", "good.usdc"]
