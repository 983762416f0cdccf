"""Hostile glTF structure in every command that reads glTF (bake, inspect, verify, view): JSON nested
past `MAX_JSON_DEPTH`, GLB files cut short anywhere, length fields past the file's end, node graphs
that are no forest, and node chains far past Python's recursion limit. Each is one line naming the
file, the command's exit code, the good neighbour baked and nothing left behind."""

import base64
import json
import struct
from pathlib import Path

import numpy as np
import pytest
from bad_inputs import (
    TRIANGLE,
    TRIANGLE_FACES,
    _glb,
    _glb_plus,
    _gltf,
    bad_node_graphs,
    deep_json_gltf,
    glb_truncations,
    node_chain_gltf,
)
from fixtures import FAST_DEFAULTS

from sssbake.exporters.gltf_validator import MAX_NODE_DEPTH, ValidatorLimit, ValidatorUnavailable, node_depth, \
    validate_many
from sssbake.pipeline.cli import main
from sssbake.pipeline.core.errors import AssetError
from sssbake.pipeline.mesh.load import load_scene
from sssbake.pipeline.mesh.load_gltf import MAX_JSON_DEPTH

OUTPUT_SUFFIXES = (".glb", ".usdc", ".mtlx", ".materials.json", ".report.json", ".thickness0.png")


def _bake(src: Path, out: Path, capsys) -> tuple[int, list[str]]:
    """`sssbake bake src -o out` with the fast defaults, in process: its exit code and stderr lines."""
    config = out.parent / f"{out.name}.toml"
    config.write_text(FAST_DEFAULTS)
    capsys.readouterr()
    code = main(["bake", str(src), "-o", str(out), "--config", str(config), "--no-validate", "-q"])
    return code, capsys.readouterr().err.splitlines()


def _outputs(out: Path) -> list[str]:
    """Every file the batch left in `out`, its cache and lock aside."""
    return sorted(str(p.relative_to(out)) for p in out.rglob("*")
                  if p.is_file() and ".sssbake-cache" not in p.parts and p.name != ".sssbake.lock")


def _assert_batch(code: int, lines: list[str], out: Path, failed: dict[Path, str], good: str) -> None:
    """A batch with the `failed` files (path -> problem) and the one good neighbour `good` (a stem):
    one line each, rc 1, the neighbour's outputs and nothing else."""
    assert code == 1
    assert sorted(lines[:-1]) == sorted(f"error: {path}: {problem}" for path, problem in failed.items())
    assert lines[-1].startswith(f"1 baked, {len(failed)} failed")
    assert _outputs(out) == sorted(["batch.json", *(good + suffix for suffix in OUTPUT_SUFFIXES)])


def _command_line(argv: list[str], capsys) -> tuple[int, str]:
    """Exit code and the one stderr line of `sssbake argv` (nothing on stdout, no second line)."""
    capsys.readouterr()
    code = main(argv)
    captured = capsys.readouterr()
    assert captured.out == "" and captured.err.count("\n") == 1, (argv, captured)
    return code, captured.err.rstrip("\n")


def _every_reader(path: Path, problem: str, capsys) -> None:
    """inspect, verify and view each refuse `path` with exit code 1 and the line
    ``error: <path>: <problem>``, as does the loader of bake."""
    for argv in (["inspect", str(path)], ["verify", str(path)], ["view", str(path), "--no-open"]):
        assert _command_line(argv, capsys) == (1, f"error: {path}: {problem}"), argv
    with pytest.raises(AssetError) as raised:
        load_scene(path)
    assert str(raised.value) == f"{path}: {problem}"


def _glb_text(text: str) -> bytes:
    """A GLB holding JSON `text` and no BIN chunk."""
    body = text.encode() + b" " * (-len(text.encode()) % 4)
    return struct.pack("<4sII", b"glTF", 2, 20 + len(body)) + struct.pack("<II", len(body), 0x4E4F534A) + body


def test_json_nested_past_the_limit_is_one_line_in_every_command(tmp_path, capsys):
    src, out = tmp_path / "in", tmp_path / "out"
    src.mkdir()
    problem = f"JSON nested deeper than {MAX_JSON_DEPTH} levels"
    # 200,000 levels: past Python's own parser (a RecursionError before); one level past the limit: parsed, refused
    files = {"deep.gltf": deep_json_gltf(200_000), "over.gltf": deep_json_gltf(MAX_JSON_DEPTH + 1)}
    for name, text in files.items():
        (src / name).write_text(text)
    (src / "deep.glb").write_bytes(_glb_text(files["deep.gltf"]))
    # the neighbour nests its extras exactly as deep as the limit allows: it bakes
    good = _gltf(TRIANGLE, TRIANGLE_FACES)
    good["extras"] = json.loads(deep_json_gltf(MAX_JSON_DEPTH))["extras"]
    (src / "good.gltf").write_text(json.dumps(good))
    code, lines = _bake(src, out, capsys)
    _assert_batch(code, lines, out, {src / name: problem for name in ("deep.gltf", "deep.glb", "over.gltf")}, "good")
    _every_reader(src / "deep.glb", problem, capsys)
    (src / "over.glb").write_bytes(_glb_text(files["over.gltf"]))
    _every_reader(src / "over.glb", problem, capsys)


@pytest.fixture(scope="module")
def baked(tmp_path_factory) -> Path:
    """A small baked .glb, as sssbake writes it (a JSON and a BIN chunk, the SSSBAKE_subsurface extension)."""
    src = tmp_path_factory.mktemp("src")
    (src / "quad.gltf").write_text(json.dumps(_gltf(TRIANGLE, TRIANGLE_FACES)))
    out = src / "out"
    (src / "c.toml").write_text(FAST_DEFAULTS)
    assert main(["bake", str(src / "quad.gltf"), "-o", str(out), "--config", str(src / "c.toml"), "--no-validate",
                 "-q"]) == 0
    return out / "quad.glb"


def test_a_glb_cut_short_anywhere_is_one_line_in_every_command(baked, tmp_path, capsys):
    """Every cut of a baked GLB (each length through the header, then spread over both chunks; as cut, and
    with its length fields shrunk to match): inspect, verify and view refuse it in one line with exit
    code 1, bake's loader with an `AssetError`, never a traceback; a batch of a sample of them fails
    each alone and bakes the neighbour."""
    src = tmp_path / "in"
    src.mkdir()
    cuts = glb_truncations(baked.read_bytes())
    assert len(cuts) > 100
    problems = {}
    for name, data in cuts.items():
        path = src / f"{name}.glb"
        path.write_bytes(data)
        with pytest.raises(AssetError) as raised:
            load_scene(path)
        problems[path] = str(raised.value).removeprefix(f"{path}: ")
        assert "\n" not in problems[path] and not problems[path].startswith("corrupt GLB file ("), problems[path]
        for argv in (["inspect", str(path)], ["verify", str(path)], ["view", str(path), "--no-open"]):
            code, line = _command_line(argv, capsys)
            assert code == 1 and line.startswith(f"error: {path}: "), (argv, line)
    assert {problems[src / "cut_10.glb"], problems[src / "cut_0.glb"]} == {
        "truncated file: 10 bytes, shorter than the 12-byte GLB header", "empty file (0 bytes)"}
    assert any(p.startswith("truncated buffer 0") for p in problems.values())  # cuts in the BIN chunk reach it
    batch = tmp_path / "batch"
    batch.mkdir()
    sample = sorted(problems, key=lambda p: p.name)[::12]
    for path in sample:
        (batch / path.name).write_bytes(path.read_bytes())
    (batch / "good.gltf").write_text(json.dumps(_gltf(TRIANGLE, TRIANGLE_FACES)))
    code, lines = _bake(batch, tmp_path / "out", capsys)
    _assert_batch(code, lines, tmp_path / "out", {batch / p.name: problems[p] for p in sample}, "good")


def test_length_fields_past_the_end_of_the_file_are_refused_by_every_reader(tmp_path, capsys):
    good = _glb(_gltf(TRIANGLE, TRIANGLE_FACES))
    doc = _gltf(TRIANGLE, TRIANGLE_FACES)
    blob = base64.b64decode(doc["buffers"][0].pop("uri").split(",", 1)[1])  # the data URI's bytes, as a BIN chunk
    with_bin = _glb_plus(doc, (0x004E4942, blob))
    json_end = 20 + struct.unpack_from("<I", with_bin, 12)[0]
    cases = {
        # the BIN chunk claims 1e9 bytes: inspect summarised the file, rc 0, before
        "bin_past_end.glb": (with_bin[:json_end] + struct.pack("<I", 10**9) + with_bin[json_end + 4:],
                             f"truncated file: GLB chunk 1 declares 1000000000 bytes, only {len(blob)} remain"),
        "json_past_end.glb": (good[:12] + struct.pack("<I", 10**9) + good[16:],
                              f"truncated file: GLB chunk 0 declares 1000000000 bytes, only {len(good) - 20} remain"),
        "header_past_end.glb": (good[:8] + struct.pack("<I", 10**9) + good[12:],
                                f"truncated file: GLB header declares 1000000000 bytes, the file has {len(good)}"),
    }
    for name, (data, problem) in cases.items():
        (tmp_path / name).write_bytes(data)
        _every_reader(tmp_path / name, problem, capsys)


def test_a_node_chain_far_past_the_recursion_limit_loads_with_its_leaf_s_world_transform(tmp_path):
    """20,000 nodes, each the child of the one before (100,000 in benchmarks/bench_gltf_load.py): read
    without recursion, in linear time, and the mesh at its end placed by the sum of the chain's translations."""
    n = 20_000
    i = np.arange(n)
    translations = np.column_stack([i % 7 - 3.0, 0.25 * (i % 2), -0.5 * (i % 3)])
    path = tmp_path / "chain.gltf"
    path.write_text(json.dumps(node_chain_gltf(translations)))
    scene = load_scene(path)
    (world,) = scene.mesh_instances()[0]
    expected = np.eye(4)
    expected[:3, 3] = translations.sum(axis=0)
    np.testing.assert_allclose(world, expected, atol=1e-9)
    assert node_depth(path) == n


def test_node_graphs_that_are_no_forest_are_refused_naming_a_node(tmp_path, capsys):
    """A cycle of child links (in a scene, beside it, or in a file without scenes: that one baked "ok"
    before) and a node with two parents: one line naming the file and a node, rc 1, the neighbour baked."""
    src, out = tmp_path / "in", tmp_path / "out"
    src.mkdir()
    failed = {}
    for name, (doc, problem) in bad_node_graphs().items():
        (src / name).write_text(json.dumps(doc))
        failed[src / name] = problem + ("; glTF 2.0 nodes form disjoint trees" if "cycle" in problem else "")
    (src / "good.gltf").write_text(json.dumps(_gltf(TRIANGLE, TRIANGLE_FACES)))
    code, lines = _bake(src, out, capsys)
    _assert_batch(code, lines, out, failed, "good")


def test_the_validator_is_not_handed_a_hierarchy_deeper_than_it_checks(tmp_path):
    """gltf-validator recurses once per node level (a stack overflow between 5,000 and 8,000 levels, time
    quadratic in the depth): a deeper file is skipped with the reason, which the bake reports as a warning."""
    path = tmp_path / "chain.gltf"
    path.write_text(json.dumps(node_chain_gltf(np.zeros((MAX_NODE_DEPTH + 1, 3)))))
    assert node_depth(path) == MAX_NODE_DEPTH + 1
    with pytest.raises(ValidatorUnavailable) as raised:
        validate_many([path])
    if not isinstance(raised.value, ValidatorLimit):
        pytest.skip(f"gltf-validator is not installed: {raised.value}")
    assert str(raised.value) == (f"chain.gltf: a node hierarchy {MAX_NODE_DEPTH + 1} levels deep, past the "
                                 f"{MAX_NODE_DEPTH} that gltf-validator checks (it recurses per level, in time growing "
                                 "with its square)")
