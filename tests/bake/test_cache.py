import dataclasses
import errno
import hashlib
import io
import json
import math
import os
import pickle
from pathlib import Path

import numpy as np
import pytest
from generate import generate
from gltf_corpus import write_corpus
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra import numpy as hnp

from sssbake.pipeline.bake import cache as cache_module
from sssbake.pipeline.bake.asset import bake_asset
from sssbake.pipeline.bake.cache import MAGIC, StageCache, stage_key, temporaries
from sssbake.pipeline.bake.cache_codec import CacheFormatError, dumps, loads
from sssbake.pipeline.bake.os_errors import os_error_line
from sssbake.pipeline.bake.stages import StageRunner
from sssbake.pipeline.core.materials import preset
from sssbake.pipeline.mesh.digest import file_digest
from sssbake.pipeline.mesh.scene import Image, TextureTransform
from sssbake.pipeline.options import BakeOptions


def test_keys_depend_on_every_input():
    base = stage_key("abc", "atlas", 1, {"resolution": 512})
    assert base == stage_key("abc", "atlas", 1, {"resolution": 512})
    assert base != stage_key("abd", "atlas", 1, {"resolution": 512})
    assert base != stage_key("abc", "atlas", 2, {"resolution": 512})
    assert base != stage_key("abc", "atlas", 1, {"resolution": 256})
    assert base != stage_key("abc", "thickness", 1, {"resolution": 512})


def test_file_digest_sees_content(tmp_path):
    a, b = tmp_path / "a", tmp_path / "b"
    a.write_bytes(b"x" * 3_000_000)
    b.write_bytes(b"x" * 2_999_999 + b"y")
    assert file_digest(a) != file_digest(b)


@dataclasses.dataclass(frozen=True)
class Count:
    n: int


@dataclasses.dataclass(frozen=True)
class Grid:
    n: int
    spacing: float
    material: object = None


def test_typed_params_make_the_key_with_their_type_and_exact_values():
    base = stage_key("up", "stage", 1, Grid(4, 0.1))
    assert base == stage_key("up", "stage", 1, Grid(4, 0.1))
    assert base != stage_key("up", "stage", 1, Grid(4, 0.1 + 2**-56))  # floats exactly, not as printed
    assert base != stage_key("up", "stage", 1, Count(4))
    assert stage_key("up", "stage", 1, Count(4)) != stage_key("up", "stage", 1, {"n": 4})  # the type is keyed
    # nested dataclasses and arrays (a Material's) are keyed by value
    skin = Grid(4, 0.1, preset("skin1"))
    assert stage_key("up", "s", 1, skin) == stage_key("up", "s", 1, Grid(4, 0.1, preset("skin1")))
    assert stage_key("up", "s", 1, skin) != stage_key("up", "s", 1, Grid(4, 0.1, preset("marble")))
    assert stage_key("up", "s", 1, Grid(1, 0.5, np.array([1.0, 2.0]))) != stage_key(
        "up", "s", 1, Grid(1, 0.5, np.array([1.0, 2.0 + 2**-51])))
    with pytest.raises(TypeError, match="a stage key cannot hold a set"):
        stage_key("up", "s", 1, Grid(1, 0.5, {1}))


def test_runner_serves_second_run_from_cache(tmp_path):
    calls = []

    def work(scale, params: Count):  # the stage reads its options from the object its key is made of
        calls.append(params.n)
        return scale * np.arange(params.n, dtype=np.float64)

    runner = StageRunner(StageCache(tmp_path))
    first, key = runner.run("stage", 1, "up", Count(5), work, 2.0)
    again, key2 = StageRunner(StageCache(tmp_path)).run("stage", 1, "up", Count(5), work, 2.0)
    assert calls == [5] and key == key2 == stage_key("up", "stage", 1, Count(5))
    np.testing.assert_array_equal(first, again)
    np.testing.assert_array_equal(first, 2.0 * np.arange(5))
    StageRunner(StageCache(tmp_path)).run("stage", 2, "up", Count(5), work, 2.0)
    StageRunner(StageCache(tmp_path)).run("stage", 1, "up", Count(6), work, 2.0)
    assert calls == [5, 5, 6]
    assert runner.records["stage"].runs == 1 and runner.records["stage"].cached == 0


def test_corrupt_entry_is_recomputed(tmp_path):
    cache = StageCache(tmp_path)
    key = stage_key("u", "s", 1, {})
    cache.put(key, 42)
    path = next(tmp_path.rglob("*.entry"))
    path.write_bytes(b"\x80\x05garbage")
    assert cache.get(key) is None
    assert not list(tmp_path.rglob("*.tmp"))


def test_disabled_cache_never_stores(tmp_path):
    cache = StageCache(None)
    cache.put("k", 1)
    assert cache.get("k") is None


def test_a_flipped_bit_is_detected_reported_and_recomputed(tmp_path):
    calls = []

    def work():
        calls.append(1)
        return np.linspace(0.0, 1.0, 1000)

    StageRunner(StageCache(tmp_path)).run("stage", 1, "up", None, work)
    path = next(tmp_path.rglob("*.entry"))
    data = bytearray(path.read_bytes())
    data[-100] ^= 0x10  # inside a float of the array: still a readable entry, a wrong value
    path.write_bytes(bytes(data))
    runner = StageRunner(StageCache(tmp_path))
    value, _ = runner.run("stage", 1, "up", None, work)
    assert calls == [1, 1] and runner.records["stage"].corrupt == 1 and runner.records["stage"].cached == 0
    np.testing.assert_array_equal(value, np.linspace(0.0, 1.0, 1000))
    assert runner.to_json()["stage"]["corrupt_cache_entries"] == 1
    # the rewritten entry is whole again: the next run is a plain hit
    again = StageRunner(StageCache(tmp_path))
    again.run("stage", 1, "up", None, work)
    assert calls == [1, 1] and again.records["stage"].cached == 1 and again.records["stage"].corrupt == 0


# --- the codec: exact round trips -------------------------------------------------------------


def assert_identical(a, b, seen: set | None = None, where: str = "value") -> None:
    """`b` is `a` rebuilt exactly: same types all the way down, arrays bit for bit (dtype, byte
    order, shape), floats to the bit (NaN, -0.0), dict keys in order; records the types in `seen`."""
    assert type(a) is type(b), f"{where}: {type(a)} became {type(b)}"
    if seen is not None:
        seen.add(type(a))
    if isinstance(a, np.ndarray):
        assert a.dtype == b.dtype and a.dtype.byteorder == b.dtype.byteorder and a.shape == b.shape, where
        assert a.tobytes() == b.tobytes(), where
    elif isinstance(a, np.generic):
        assert a.dtype == b.dtype and a.tobytes() == b.tobytes(), where
    elif isinstance(a, float):
        assert (math.isnan(a) and math.isnan(b)) or (a == b and math.copysign(1, a) == math.copysign(1, b)), where
    elif isinstance(a, (tuple, list)):
        assert len(a) == len(b), where
        for i, (x, y) in enumerate(zip(a, b)):
            assert_identical(x, y, seen, f"{where}[{i}]")
    elif isinstance(a, dict):
        assert len(a) == len(b), where
        for (ka, va), (kb, vb) in zip(a.items(), b.items()):
            assert_identical(ka, kb, seen, f"{where} key")
            assert_identical(va, vb, seen, f"{where}[{ka!r}]")
    elif dataclasses.is_dataclass(a):
        for f in dataclasses.fields(a):
            assert_identical(getattr(a, f.name), getattr(b, f.name), seen, f"{where}.{f.name}")
    else:
        assert a == b, where


def round_trip(value):
    return loads(b"".join(dumps(value)))


class RecordingCache(StageCache):
    """A StageCache that keeps every value it is given, as the stage made it."""

    def __init__(self, folder):
        super().__init__(folder)
        self.values: list[tuple[str, object]] = []

    def put(self, key, value):
        self.values.append((key, value))
        super().put(key, value)


@pytest.fixture(scope="module")
def real_bake(tmp_path_factory):
    """The cache folder and every (key, value) real bakes stored: a sphere with every technique,
    one through the budget pilot, and a textured glTF with KHR_texture_transform."""
    root = tmp_path_factory.mktemp("bake")
    generate(root / "in")
    write_corpus(root / "gltf")
    cache = RecordingCache(root / "cache")
    (root / "out").mkdir()
    sphere, textured = root / "in" / "sphere.obj", root / "gltf" / "texture_transform.glb"
    every = BakeOptions(scale_mm=1.0, atlas_resolution=64, validate=False,
                        techniques=("prt", "kernels", "spectral", "screen", "lpv"), spectral_basis=True)
    bake_asset(sphere, every, root / "out" / "every", cache)
    bake_asset(sphere, BakeOptions(scale_mm=1.0, atlas_resolution=64, validate=False, budget_rmse=0.05),
               root / "out" / "pilot", cache)
    bake_asset(textured, BakeOptions(atlas_resolution=64, validate=False, techniques=()), root / "out" / "textured", cache)
    return root, cache.values, every


def test_every_value_a_real_bake_caches_round_trips_exactly(real_bake):
    root, values, _ = real_bake
    seen: set[type] = set()
    for key, value in values:
        assert_identical(value, StageCache(root / "cache").get(key), seen, type(value).__name__)
    stages = {type(v).__name__ for _, v in values}
    assert stages >= {"Scene", "CleanScene", "Atlas", "ThicknessResult", "ThicknessMap", "TechniqueBake", "Pilot"}, stages
    nested = {t.__name__ for t in seen}
    assert nested >= {"Image", "TextureTransform", "Primitive", "Surface", "AtlasPart", "PrtData", "KernelsData",
                      "Candidate", "ndarray", "bytes", "tuple", "list", "dict", "NoneType", "bool", "int", "float"}, nested


def test_a_rebake_from_the_cache_is_byte_identical(real_bake, tmp_path):
    root, _, every = real_bake
    sphere = root / "in" / "sphere.obj"
    result = bake_asset(sphere, every, tmp_path / "every", StageCache(root / "cache"))
    stages = result.report["stages"]
    for name in ("load", "clean", "atlas", "thickness", "thickness_map", "prt", "kernels", "spectral", "screen", "lpv"):
        assert stages[name]["cached"] == stages[name]["runs"] >= 1, (name, stages[name])
        assert "corrupt_cache_entries" not in stages[name]
    for suffix in (".glb", ".usdc"):
        rebaked, first = (tmp_path / "every").with_suffix(suffix), (root / "out" / "every").with_suffix(suffix)
        assert rebaked.read_bytes() == first.read_bytes()


_floats = st.floats(allow_nan=True, allow_infinity=True, allow_subnormal=True, width=64)
_dtypes = (hnp.scalar_dtypes() | hnp.integer_dtypes(endianness=">") | hnp.floating_dtypes(endianness=">")
           | hnp.unicode_string_dtypes(max_len=3) | hnp.byte_string_dtypes(max_len=3))
_arrays = hnp.arrays(_dtypes, hnp.array_shapes(min_dims=0, max_dims=3, min_side=0, max_side=3))
_leaves = (st.none() | st.booleans() | st.integers() | _floats | st.text(max_size=5) | st.binary(max_size=8) | _arrays
           | hnp.arrays(hnp.scalar_dtypes(), ()).map(lambda a: a[()]))  # numpy scalars
_keys = st.none() | st.booleans() | st.integers() | st.text(max_size=4) | st.tuples(st.integers(), st.text(max_size=2))
_values = st.recursive(
    _leaves,
    lambda kids: (st.lists(kids, max_size=4) | st.lists(kids, max_size=4).map(tuple)
                  | st.dictionaries(_keys, kids, max_size=4)
                  | st.builds(Image, kids, kids, kids)  # an sssbake dataclass holding anything
                  | st.builds(TextureTransform, st.tuples(_floats, _floats), _floats, st.tuples(_floats, _floats),
                              st.none() | st.integers(0, 3))),
    max_leaves=24,
)


@settings(max_examples=300, deadline=None)
@given(_values)
def test_the_codec_rebuilds_random_nested_values_exactly(value):
    assert_identical(value, round_trip(value))


def test_an_array_met_twice_is_stored_once_and_read_back_as_one():
    a = np.arange(10_000, dtype=np.float64)
    payload = b"".join(dumps((a, {"again": a})))
    assert len(payload) < 1.1 * a.nbytes
    back = loads(payload)
    assert back[0] is back[1]["again"] and back[0].flags.writeable
    np.testing.assert_array_equal(back[0], a)


@dataclasses.dataclass(frozen=True)
class NotOurs:
    x: int


def with_extra_attribute(image: Image) -> Image:
    object.__setattr__(image, "cached", 1)
    return image


@pytest.mark.parametrize("value, message", [
    ({"a": [1, {2, 3}]}, r"cannot store builtins\.set at dict\['a'\]\[1\]"),
    ((NotOurs(1),), r"test_cache\.NotOurs \(only dataclasses of sssbake modules are stored\) at tuple\[0\]"),
    ([np.array([None, 1], dtype=object)], r"dtype object .* at list\[0\]"),
    (Image("a", "image/png", bytearray(b"png")), r"builtins\.bytearray at Image\.data"),
    ({1: with_extra_attribute(Image("a", "image/png", b""))},
     r"Image with attributes outside its fields \['cached'\] at dict\[1\]"),
])
def test_put_refuses_what_it_cannot_store_exactly_and_writes_nothing(tmp_path, value, message):
    with pytest.raises(TypeError, match=message):
        StageCache(tmp_path).put(stage_key("u", "s", 1, {}), value)
    assert not list(tmp_path.rglob("*"))


# --- hostile and stale entries ---------------------------------------------------------------


class Touch:
    """Pickles as a call that creates `path`: what a crafted pickle entry would run."""

    def __init__(self, path: Path):
        self.path = path

    def __reduce__(self):
        return Path.touch, (self.path,)


def payload(node, arrays: tuple[bytes, ...] = ()) -> bytes:
    """A payload written by hand after cache_codec's documented layout."""
    text = json.dumps({"arrays": len(arrays), "value": node}).encode()
    return len(text).to_bytes(8, "little") + text + b"".join(arrays)


def npy(array: np.ndarray) -> bytes:
    buf = io.BytesIO()
    np.save(buf, array, allow_pickle=True)
    return buf.getvalue()


def huge_npy() -> bytes:
    """A .npy whose header claims 8 TB of float64 and holds 80 bytes."""
    buf = io.BytesIO()
    header = np.lib.format.header_data_from_array_1_0(np.zeros(10))
    np.lib.format.write_array_header_1_0(buf, {**header, "shape": (10**12,)})
    return buf.getvalue() + np.zeros(10).tobytes()


def write_entry(folder: Path, key: str, data: bytes, magic: bytes = MAGIC, suffix: str = ".entry") -> Path:
    """An entry with a valid checksum, as anyone with write access to a shared cache can make."""
    path = folder / key[:2] / f"{key}{suffix}"
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_bytes(magic + hashlib.sha256(data).digest() + data)
    return path


def test_the_hostile_payloads_below_really_run_code_through_pickle(tmp_path):
    marker = tmp_path / "ran"
    np.load(io.BytesIO(npy(np.array([Touch(marker)], dtype=object))), allow_pickle=True)
    assert marker.exists()
    marker.unlink()
    pickle.loads(pickle.dumps(Touch(marker)))
    assert marker.exists()


HOSTILE = {
    "os.system": lambda m: payload({"c": ["os", "system", {"command": f"touch {m}"}]}),
    "subprocess.Popen": lambda m: payload({"c": ["subprocess", "Popen", {"args": {"l": ["touch", str(m)]}}]}),
    "another package's class": lambda m: payload({"c": ["pathlib", "Path", {}]}),
    "another package's dataclass": lambda m: payload({"c": [NotOurs.__module__, NotOurs.__qualname__, {"x": 1}]}),
    "an sssbake class that is not a dataclass": lambda m: payload(
        {"c": ["sssbake.pipeline.bake.cache", "StageCache", {"folder": str(m), "corrupt": {"l": []}}]}),
    "an sssbake function": lambda m: payload({"c": ["sssbake.pipeline.cli", "main", {}]}),
    "a function reached through a module attribute": lambda m: payload(
        {"c": ["sssbake.pipeline.bake.cache_codec", "dataclasses.dataclass", {}]}),
    "an sssbake dataclass with other fields": lambda m: payload({"c": ["sssbake.pipeline.mesh.scene", "Image", {"name": "x"}]}),
    "a relative module name": lambda m: payload({"c": ["sssbake..pipeline.scene", "Image", {}]}),
    "an object array": lambda m: payload({"a": 0}, (npy(np.array([Touch(m)], dtype=object)),)),
    "an array header claiming 8 TB": lambda m: payload({"a": 0}, (huge_npy(),)),
    "an array index out of range": lambda m: payload({"a": 1}, (npy(np.zeros(3)),)),
    "bytes from a float array": lambda m: payload({"b": 0}, (npy(np.zeros(3)),)),
    "an unknown tag": lambda m: payload({"x": 1}),
    "NaN spelled as a JSON constant": lambda m: payload(math.nan),  # json.dumps writes NaN
    "data after the last array": lambda m: payload({"a": 0}, (npy(np.zeros(3)),)) + b"\0",
    "a JSON length past the end": lambda m: (10**6).to_bytes(8, "little") + b"{}",
}


@pytest.mark.parametrize("case", sorted(HOSTILE))
def test_a_crafted_entry_with_a_valid_checksum_is_refused_recomputed_and_runs_nothing(tmp_path, case):
    marker = tmp_path / "ran"
    key = stage_key("up", "stage", 1, None)
    data = HOSTILE[case](marker)
    with pytest.raises(CacheFormatError):
        loads(data)
    write_entry(tmp_path / "cache", key, data)
    runner = StageRunner(StageCache(tmp_path / "cache"))
    value, _ = runner.run("stage", 1, "up", None, lambda: (1.5, "fresh"))
    assert value == (1.5, "fresh") and not marker.exists()
    assert runner.records["stage"].corrupt == 1 and runner.records["stage"].cached == 0
    again = StageRunner(StageCache(tmp_path / "cache"))
    assert again.run("stage", 1, "up", None, lambda: pytest.fail("recomputed"))[0] == (1.5, "fresh")


def test_an_old_pickle_entry_is_never_loaded_and_is_recomputed(tmp_path):
    marker = tmp_path / "ran"
    key = stage_key("up", "stage", 1, None)
    hostile = pickle.dumps(Touch(marker))
    # where sssbake before this format kept it: not read at all; an older sssbake sharing the
    # folder keeps its own entry
    old = write_entry(tmp_path / "cache", key, hostile, magic=b"sssbake-cache-1\n", suffix=".pkl")
    runner = StageRunner(StageCache(tmp_path / "cache"))
    assert runner.run("stage", 1, "up", None, lambda: "fresh")[0] == "fresh"
    assert runner.records["stage"].corrupt == 0 and runner.records["stage"].runs == 1 and not marker.exists()
    assert old.read_bytes()[:16] == b"sssbake-cache-1\n"
    # the same bytes under the current name: a header that is not ours, deleted and recomputed
    write_entry(tmp_path / "cache", key, hostile, magic=b"sssbake-cache-1\n")
    runner = StageRunner(StageCache(tmp_path / "cache"))
    assert runner.run("stage", 1, "up", None, lambda: "again")[0] == "again"
    assert runner.records["stage"].corrupt == 1 and not marker.exists()
    assert StageCache(tmp_path / "cache").get(key) == "again"


# --- a cache folder that cannot take an entry ---------------------------------------------------------


class FailingTempfile:
    """A `tempfile` for the cache module whose mkstemp gives a file every write to fails with ENOSPC
    (/dev/full), or fails itself with `code`; `tries` counts its calls."""

    def __init__(self, code: int):
        self.code, self.tries = code, 0

    def mkstemp(self, dir, prefix, suffix):
        self.tries += 1
        if self.code == errno.ENOSPC:
            return os.open("/dev/full", os.O_WRONLY), str(Path(dir) / f"{prefix}full1234{suffix}")
        raise OSError(self.code, os.strerror(self.code), str(Path(dir) / f"{prefix}denied12{suffix}"))


@pytest.mark.parametrize("code, problem", [
    (errno.ENOSPC,
     "No space left on device; free some space or give --cache-dir a folder on another disk, or --no-cache"),
    (errno.EACCES, "{file}: Permission denied; give --cache-dir a folder you may write, or --no-cache"),
])
def test_a_cache_that_cannot_take_an_entry_is_warned_of_once_and_the_stages_go_on(tmp_path, monkeypatch, code, problem):
    if not os.path.exists("/dev/full"):
        pytest.skip("no /dev/full")
    failing = FailingTempfile(code)
    monkeypatch.setattr(cache_module, "tempfile", failing)
    runner = StageRunner(StageCache(tmp_path))
    assert runner.run("first", 1, "up", None, lambda: 1.5)[0] == 1.5
    assert runner.run("second", 1, "up", None, lambda: 2.5)[0] == 2.5
    assert failing.tries == 1  # not tried again for this bake
    shard = tmp_path / stage_key("up", "first", 1, None)[:2]
    assert runner.warnings == [f"stage cache: first and the stages after it not stored: {tmp_path}: "
                               + problem.format(file=shard / "tmpdenied12.tmp")]
    assert not list(temporaries(tmp_path)) and not list(tmp_path.rglob("*.entry"))


def test_os_error_lines_name_the_option_of_the_folder():
    full = OSError(errno.ENOSPC, "No space left on device")
    denied = OSError(errno.EROFS, "Read-only file system", "/c/x")
    assert os_error_line(Path("/o"), full) == (
        "/o: No space left on device; free some space or give -o a folder on another disk")
    assert os_error_line(Path("/c"), denied, "--cache-dir") == (
        "/c: /c/x: Read-only file system; give --cache-dir a folder you may write, or --no-cache")
    # a bake's staging folder, and a temporary in it, are named as the folder and the output they are for
    staged = "/o/.sssbake-staging.ab_d1234"
    assert os_error_line(Path("/a.obj"), OSError(errno.EACCES, "Permission denied", staged)) == (
        "/a.obj: /o: Permission denied; give -o a folder you may write")
    assert os_error_line(Path("/a.obj"), OSError(errno.ENOSPC, "No space left on device",
                                                 f"{staged}/.a.glb.k2_9xq0a.tmp.glb")) == (
        "/a.obj: /o/a.glb: No space left on device; free some space or give -o a folder on another disk")
