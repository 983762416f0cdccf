"""Fuzzing the readers (hypothesis): byte mutants of valid GLB, OBJ, PLY and STL files.

Every mutant either loads and cleans into a scene that passes `check_scene` with finite arrays, or
fails with an `AssetError` whose message is one line naming the file; any other exception is a
traceback a user would see, and so is a parser failure the readers' net turns into one line when it
was raised in sssbake's own code. Each example runs under a wall-clock alarm (a hang in Python code
fails the test; one inside a single C call only when that call returns) and an address-space limit
(a runaway allocation becomes a MemoryError, which fails it too, instead of taking the machine down).

Examples: ``FUZZ_EXAMPLES`` (default 240, about 40 per seed file; derandomized, so CI sees the same
mutants every run). ``FUZZ_EXAMPLES=5000 python3 -m pytest -q tests/mesh/test_fuzz_inputs.py`` fuzzes longer.
"""

from __future__ import annotations

import contextlib
import functools
import json
import os
import random
import resource
import signal
import tempfile
import traceback
from pathlib import Path

import numpy as np
import pytest
from fuzz_seeds import glb_chunks, mutate, ops_for, pack_glb, random_ops, seed_files
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

import sssbake.exporters
import sssbake.pipeline
from sssbake.pipeline.cli import main
from sssbake.pipeline.core.errors import AssetError
from sssbake.pipeline.mesh.clean import clean_scene
from sssbake.pipeline.mesh.load import check_scene, load_scene

EXAMPLES = int(os.environ.get("FUZZ_EXAMPLES", "240"))
#: Per-example wall-clock bound: the seeds load in milliseconds, so this is a hang, not a slow mutant.
EXAMPLE_SECONDS = 10
#: Address space a mutant may add on top of what the test process already maps.
EXTRA_ADDRESS_SPACE = 4 << 30
#: sssbake's own source: an exception raised here and caught by `load_scene`'s net is a bug, not a bad file.
OWN_SOURCE = tuple(Path(m.__file__).resolve().parent for m in (sssbake.pipeline, sssbake.exporters))


class ExampleTimeout(BaseException):
    """Raised by the alarm; a BaseException so the loaders' ``except Exception`` nets cannot swallow it."""


@functools.cache
def _seeds() -> dict[str, bytes]:
    return seed_files()


@contextlib.contextmanager
def _bounded(seconds: float):
    """Interrupt the body with `ExampleTimeout` after `seconds` and cap its address space."""

    def alarm(signum, frame):
        raise ExampleTimeout

    soft, hard = resource.getrlimit(resource.RLIMIT_AS)
    mapped = int(Path("/proc/self/statm").read_text().split()[0]) * resource.getpagesize()
    limit = mapped + EXTRA_ADDRESS_SPACE
    if hard != resource.RLIM_INFINITY:
        limit = min(limit, hard)
    previous = signal.signal(signal.SIGALRM, alarm)
    signal.setitimer(signal.ITIMER_REAL, seconds)
    resource.setrlimit(resource.RLIMIT_AS, (limit, hard))
    try:
        yield
    finally:
        signal.setitimer(signal.ITIMER_REAL, 0)
        signal.signal(signal.SIGALRM, previous)
        resource.setrlimit(resource.RLIMIT_AS, (soft, hard))


def _non_finite(cleaned) -> list[str]:
    """Names of the cleaned scene's arrays that hold NaN or Inf (empty when all are finite)."""
    bad = []
    for i, mesh in enumerate(cleaned.scene.meshes):
        for j, p in enumerate(mesh.primitives):
            arrays = {"positions": p.positions, "normals": p.normals, "colors": p.colors, "tangents": p.tangents}
            arrays.update({f"uvs[{k}]": uv for k, uv in enumerate(p.uvs)})
            bad += [f"mesh {i} primitive {j} {k}" for k, a in arrays.items() if a is not None and not np.isfinite(a).all()]
    for i, s in enumerate(cleaned.surfaces):
        for k in ("positions", "normals", "vertex_areas"):
            if not np.isfinite(getattr(s, k)).all():
                bad.append(f"surface {i} {k}")
    bad += [f"node {n.name!r} matrix" for n in cleaned.scene.nodes if not np.isfinite(n.matrix).all()]
    return bad


def check_mutant(path: Path) -> str:
    """Load and clean `path`; ``"ok"`` or ``"error"``, asserting the contract (see the module docstring)."""
    try:
        with _bounded(EXAMPLE_SECONDS):
            cleaned = clean_scene(load_scene(path))
    except ExampleTimeout:
        raise AssertionError(f"{path.name}: load and clean ran past {EXAMPLE_SECONDS} s") from None
    except AssetError as e:
        message = str(e)
        assert "\n" not in message and message.startswith(f"{path}: "), message
        assert "MemoryError" not in message, message  # the address-space cap was hit: the reader over-allocates
        cause = e.__cause__
        if cause is not None and not isinstance(cause, (AssetError, OSError)):
            # The net turns any parser failure into one line; one raised in our own code is a bug.
            frame = traceback.extract_tb(cause.__traceback__)[-1]
            assert not set(OWN_SOURCE) & set(Path(frame.filename).resolve().parents), (
                f"{message} (raised at {Path(frame.filename).name}:{frame.lineno})")
        return "error"
    check_scene(cleaned.scene)
    non_finite = _non_finite(cleaned)
    assert not non_finite, non_finite
    return "ok"


def _operations(name: str):
    """One to three mutations of seed `name` (`fuzz_seeds.mutate`'s ``(kind, a, b, c)``)."""
    return st.lists(
        st.tuples(st.sampled_from(ops_for(name)), st.integers(0, 2**20), st.integers(0, 2**10), st.integers(0, 2**10)),
        min_size=1, max_size=3,
    ).map(lambda ops: (name, ops))


def test_seeds_are_valid():
    """Every seed loads as the 80-triangle sphere it was written from (else the mutants test nothing)."""
    with tempfile.TemporaryDirectory() as folder:
        for name, data in _seeds().items():
            path = Path(folder) / name
            path.write_bytes(data)
            cleaned = clean_scene(load_scene(path))
            prim = cleaned.scene.meshes[0].primitives[0]
            assert prim.faces.shape == (80, 3), name
            assert np.allclose(np.linalg.norm(prim.positions, axis=1), 10.0, atol=1e-5), name
            assert (len(prim.uvs) == 1) == name.endswith((".glb", ".obj")), name


@settings(max_examples=EXAMPLES, derandomize=True, deadline=None, database=None,
          suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large])
@given(mutant=st.sampled_from(sorted(_seeds())).flatmap(_operations))
def test_mutants_load_or_fail_with_one_line(mutant):
    """A mutant loads into a valid, finite scene or fails with a one-line AssetError naming the file."""
    name, ops = mutant
    data = mutate(name, _seeds()[name], ops)
    with tempfile.TemporaryDirectory() as folder:
        path = Path(folder) / name
        path.write_bytes(data)
        check_mutant(path)


def _edited_glb(edit) -> bytes:
    """The GLB seed with `edit` applied to its parsed JSON (in place), repacked."""
    text, blob = glb_chunks(_seeds()["seed.glb"])
    gltf = json.loads(text)
    edit(gltf)
    return pack_glb(json.dumps(gltf).encode(), blob)


def _obj_lines(edit) -> bytes:
    """The OBJ seed with `edit` applied to each line."""
    return "".join(edit(line) for line in _seeds()["seed.obj"].decode().splitlines(keepends=True)).encode()


def _huge_index(line: str, plain: bool) -> str:
    """An OBJ line with its face corners cut to vertex indices if `plain`, the first face's third one 2**64."""
    if not line.startswith("f "):
        return line
    corners = [c.split("/")[0] if plain else c for c in line.split()[1:]]
    if line.startswith("f 1/1/1 "):
        corners[2] = "18446744073709551616"
    return "f " + " ".join(corners) + "\n"


# Classes the fuzzer found, one small file each: (file name, bytes, the message's problem part).
FOUND = {
    "null_accessor": ("null.glb", lambda: _edited_glb(lambda g: g["accessors"].__setitem__(1, None)),
                      "invalid glTF: accessors[1] is null (glTF 2.0 allows null nowhere outside extras)"),
    "null_array": ("null_meshes.glb", lambda: _edited_glb(lambda g: g.__setitem__("meshes", None)),
                   "invalid glTF: meshes is null (glTF 2.0 allows null nowhere outside extras)"),
    "attributes_list": ("attributes.glb",
                        lambda: _edited_glb(lambda g: g["meshes"][0]["primitives"][0].__setitem__("attributes", [])),
                        "mesh 0 primitive 0: attributes is [], not an object"),
    # Plain "f a b c" lines reach trimesh's fast parser, v/vt/vn corners its fallback: both overflowed.
    "index_past_int64": ("huge_index.obj", lambda: _obj_lines(lambda line: _huge_index(line, plain=True)),
                         "face index 18446744073709551616 out of range for 42 vertices"),
    "index_past_int64_vt_vn": ("huge_index_vt_vn.obj", lambda: _obj_lines(lambda line: _huge_index(line, plain=False)),
                               "face index 18446744073709551616 out of range for 42 vertices"),
    "nan_uv_obj": ("nan_uv.obj", lambda: _obj_lines(lambda line: "vt nan 0.5\n" if line.startswith("vt 0.838") else line),
                   "non-finite texture coordinates (UV set 0) (1 of 42 vertices) in mesh"),
}


@pytest.mark.parametrize("case", sorted(FOUND))
def test_found_classes_fail_with_their_cause(tmp_path, case):
    """Each failure class the fuzzer found (each a traceback or non-finite data before the fix) is one
    line naming the file and the cause."""
    name, data, problem = FOUND[case]
    path = tmp_path / name
    path.write_bytes(data())
    with pytest.raises(AssetError) as raised:
        load_scene(path)
    assert str(raised.value).startswith(f"{path}: {problem}")
    assert check_mutant(path) == "error"


def test_obj_texture_coordinates_with_only_u(tmp_path):
    """``vt u`` lines (one value; the fuzzer found a traceback) leave v at 0, which is 1 in glTF's
    flipped convention; u is kept."""
    path = tmp_path / "u_only.obj"
    path.write_bytes(_obj_lines(lambda line: " ".join(line.split()[:2]) + "\n" if line.startswith("vt ") else line))
    prim = load_scene(path).meshes[0].primitives[0]
    seed = tmp_path / "seed.obj"
    seed.write_bytes(_seeds()["seed.obj"])
    full = load_scene(seed).meshes[0].primitives[0]
    assert prim.uvs[0].shape == (42, 2)
    assert np.array_equal(prim.uvs[0][:, 1], np.ones(42))
    assert np.allclose(prim.uvs[0][:, 0], full.uvs[0][:, 0])
    assert check_mutant(path) == "ok"


def test_parsers_say_nothing_on_stderr(tmp_path, capfd):
    """A broken normal in an ASCII STL (trimesh logs a traceback and goes on) and "nan" as a PLY face
    index (numpy warns of an invalid cast) print nothing: the user's one line comes from the readers."""
    stl = tmp_path / "normal.stl"
    stl.write_bytes(_seeds()["ascii.stl"].replace(b"facet normal ", b"facet normal zz ", 1))
    ply = tmp_path / "nan_index.ply"
    header, body = _seeds()["ascii.ply"].split(b"end_header\n")
    ply.write_bytes(header + b"end_header\n" + body.replace(b"\n3 0 ", b"\n3 nan ", 1))
    assert load_scene(stl).meshes[0].primitives[0].faces.shape == (80, 3)
    with pytest.raises(AssetError, match="face index"):
        load_scene(ply)
    assert capfd.readouterr().err == ""


def test_mutants_fail_alone_in_a_batch(tmp_path):
    """Ten fixed mutants beside a good asset through `sssbake bake`: each fails with one line naming its
    file (never "internal error") or bakes; the good neighbour bakes; no temporaries are left."""
    rng = random.Random(19)
    assets = tmp_path / "in"
    assets.mkdir()
    names = sorted(_seeds())
    (assets / "good.obj").write_bytes(_seeds()["seed.obj"])
    for k in range(10):
        name = names[k % len(names)]
        (assets / f"mutant{k}_{name}").write_bytes(mutate(name, _seeds()[name], random_ops(rng, name, 2)))
    out = tmp_path / "out"
    code = main(["bake", str(assets), "-o", str(out), "--scale-mm", "1", "--techniques", "none", "-q", "--no-validate"])
    records = {Path(r["asset"]).name: r for r in json.loads((out / "batch.json").read_text())["assets"]}
    assert len(records) == 11
    assert records["good.obj"]["status"] == "ok"
    failed = {n: r for n, r in records.items() if r["status"] == "failed"}
    assert code == (1 if failed else 0)
    for n, r in failed.items():
        assert "\n" not in r["error"] and r["error"].startswith(f"{assets / n}: "), r["error"]
        assert not r["error"].startswith(f"{assets / n}: internal error"), r["error"]
        assert not list(out.glob(f"{Path(n).stem}.*")), n  # a failed asset leaves no output behind
    for n, r in records.items():
        if r["status"] == "ok":
            assert (out / f"{Path(n).stem}.glb").is_file() and (out / f"{Path(n).stem}.usdc").is_file(), n
    leftovers = [p.name for p in out.rglob("*") if ".tmp" in p.name]
    assert not leftovers, leftovers
    assert failed, "every mutant baked: the mutations are too mild to test the failure path"
