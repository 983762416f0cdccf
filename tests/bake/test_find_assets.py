"""Walking the input folders: symlink loops end with a line naming the link, entries that are not
regular files (a FIFO, a socket, a device, a dangling symlink) fail on one line each without being
opened, one real file is one job, and the good neighbour bakes."""

import json
import os
import shutil
import socket
import subprocess
import sys
from pathlib import Path

import pytest
import trimesh
from fixtures import FAST_DEFAULTS

from sssbake.pipeline.bake.batch import find_assets


def _good(path: Path) -> Path:
    path.parent.mkdir(parents=True, exist_ok=True)
    trimesh.creation.icosphere(subdivisions=1, radius=5.0).export(path)
    return path


def _hostile_tree(tmp_path: Path) -> tuple[Path, dict[str, str]]:
    """An input folder with one good asset, a linked library and every walking hazard; returns it
    and, per entry that must fail, its one-line error."""
    src, lib = tmp_path / "in", tmp_path / "lib"
    _good(src / "good.obj")
    _good(lib / "shelf.obj")
    (src / "x").mkdir()
    (src / "y").mkdir()
    links = {
        "loop": ".",  # a folder that holds itself: 41 jobs of one file, with os.walk
        "x/up": "../..",  # a link to the folder above the input root: it holds the link too
        "x/to_y": "../y",  # x and y link to each other: an endless walk, with os.walk
        "y/to_x": "../x",
        "lib1": "../lib",  # a linked library, linked twice: walked once
        "lib2": "../lib",
        "alias.obj": "good.obj",  # another name for good.obj: baked once, as good.obj
        "a": "b",  # a loop of file links, of no extension and of a supported one
        "b": "a",
        "c.obj": "d.obj",
        "d.obj": "c.obj",
        "gone.glb": "missing.glb",
        "null.ply": os.devnull,
    }
    for name, target in links.items():
        os.symlink(target, src / name)
    os.mkfifo(src / "fifo.obj")  # opened, it would block the batch for ever
    server = socket.socket(socket.AF_UNIX)
    server.bind(str(src / "sock.stl"))
    server.close()
    expected = {
        "x/up": f"{src / 'x/up'}: a symlink loop: it points to {tmp_path.resolve()}, a folder that holds it; "
                "not followed",
        "a": f"{src / 'a'}: a symlink loop (a -> b -> a)",
        "b": f"{src / 'b'}: a symlink loop (b -> a -> b)",
        "c.obj": f"{src / 'c.obj'}: a symlink loop (c.obj -> d.obj -> c.obj)",
        "d.obj": f"{src / 'd.obj'}: a symlink loop (d.obj -> c.obj -> d.obj)",
        "gone.glb": f"{src / 'gone.glb'}: a symlink to a missing file (gone.glb -> missing.glb)",
        "null.ply": f"{src / 'null.ply'}: not a regular file (a character device)",
        "fifo.obj": f"{src / 'fifo.obj'}: not a regular file (a FIFO)",
        "sock.stl": f"{src / 'sock.stl'}: not a regular file (a socket)",
    }
    # other names of what is walked: not followed, said once each (the folder `loop` holds itself)
    same = {"loop": src, "lib2": src / "lib1", "y/to_x": src / "x", "x/to_y": src / "y", "alias.obj": src / "good.obj"}
    return src, expected, same


def test_hostile_tree_ends_with_one_line_per_problem_and_bakes_the_rest(tmp_path):
    src, expected, same = _hostile_tree(tmp_path)
    out = tmp_path / "out"
    config = tmp_path / "c.toml"
    config.write_text(FAST_DEFAULTS)
    # a subprocess: the old walk never ended on this tree, and an opened FIFO blocks (the limit only
    # stops a hang; it is no measure)
    run = subprocess.run([sys.executable, "-m", "sssbake.pipeline.cli", "bake", str(src), "-o", str(out),
                          "--config", str(config)], capture_output=True, text=True, timeout=600)
    assert run.returncode == 1, run.stderr
    errors = [line for line in run.stderr.splitlines() if line.startswith("error: ")]  # not tqdm's bar
    assert "Traceback" not in run.stderr
    assert sorted(errors) == sorted(f"error: {line}" for line in expected.values())
    assert f"2 baked, {len(expected)} failed" in run.stdout
    for name, first in same.items():
        assert f" same-file  {src / name}  (another name of {first}, baked once under that name)" in run.stdout
    batch = json.loads((out / "batch.json").read_text())
    status = {os.path.relpath(r["asset"], src): r["status"] for r in batch["assets"]}
    assert status == {"good.obj": "ok", "lib1/shelf.obj": "ok", **{name: "failed" for name in expected},
                      **{name: "same-file" for name in same}}
    files = sorted(str(p.relative_to(out)) for p in out.rglob("*") if p.is_file() and ".sssbake-cache" not in p.parts)
    assert files == [".sssbake.lock", "batch.json", "good.glb", "good.materials.json", "good.mtlx", "good.report.json",
                     "good.thickness0.png", "good.usdc", "lib1/shelf.glb", "lib1/shelf.materials.json",
                     "lib1/shelf.mtlx", "lib1/shelf.report.json", "lib1/shelf.thickness0.png", "lib1/shelf.usdc"]


def test_one_real_file_is_one_job_under_its_first_name(tmp_path):
    src = tmp_path / "in"
    good = _good(src / "sub" / "good.obj")
    os.link(good, src / "a_hard.obj")  # sorts first: the one name of the two
    os.symlink("sub/good.obj", src / "0_alias.obj")  # sorts first, but a symlink: after every real name
    os.symlink("sub", src / "0_sub")  # a symlinked folder: after the real ones
    jobs = find_assets([src, src / "sub", good, src / "0_alias.obj"], tmp_path / "out")
    # each root's jobs in sorted order; every other name says which it is
    assert [(j.rel, j.problem, j.same_as) for j in jobs] == [
        ("0_alias.obj", None, src / "a_hard.obj"), ("0_sub", None, src / "sub"), ("a_hard.obj", None, None),
        ("sub/good.obj", None, src / "a_hard.obj"), ("sub", None, src / "sub"), ("good.obj", None, src / "a_hard.obj"),
        ("0_alias.obj", None, src / "a_hard.obj")]


def test_outputs_are_no_inputs(tmp_path):
    src = tmp_path / "in"
    _good(src / "good.obj")
    _good(src / "out" / "good.glb")  # a former batch's output, inside the input folder
    os.symlink("out/good.glb", src / "old.glb")
    assert [j.rel for j in find_assets([src], src / "out")] == ["good.obj"]


_FIND = """
import json, sys
from pathlib import Path
from sssbake.pipeline.bake.batch import find_assets
print(json.dumps([[j.rel, j.problem] for j in find_assets([Path(sys.argv[1])], Path(sys.argv[2]))]))
"""


def test_what_may_not_be_read_is_named(tmp_path):
    """A file and a folder we may not read; as root, without the capabilities that read anything."""
    src = tmp_path / "in"
    _good(src / "good.obj")
    _good(src / "secret.obj").chmod(0)
    _good(src / "closed" / "inside.obj")
    (src / "closed").chmod(0)
    limited = []
    if os.geteuid() == 0:
        limited = ["setpriv", "--bounding-set", "-dac_override,-dac_read_search"]
        if shutil.which("setpriv") is None or subprocess.run([*limited, "true"]).returncode != 0:
            pytest.skip("root, and setpriv(1) cannot drop the capabilities that read anything")
    try:
        run = subprocess.run([*limited, sys.executable, "-c", _FIND, str(src), str(tmp_path / "out")],
                             capture_output=True, text=True, timeout=600)
    finally:
        (src / "closed").chmod(0o755)
    assert run.returncode == 0, run.stderr
    assert json.loads(run.stdout) == [
        ["closed", f"{src / 'closed'}: cannot read this folder: Permission denied"],
        ["good.obj", None],
        ["secret.obj", f"{src / 'secret.obj'}: cannot read: permission denied"],
    ]
