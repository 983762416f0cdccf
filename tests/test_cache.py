import numpy as np

from sssbake.pipeline.cache import StageCache, file_digest, stage_key
from sssbake.pipeline.stages import StageRunner


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


def test_runner_serves_second_run_from_cache(tmp_path):
    calls = []

    def work(n):
        calls.append(n)
        return np.arange(n, dtype=np.float64)

    runner = StageRunner(StageCache(tmp_path))
    first, key = runner.run("stage", 1, "up", {"n": 5}, work, 5)
    again, key2 = StageRunner(StageCache(tmp_path)).run("stage", 1, "up", {"n": 5}, work, 5)
    assert calls == [5] and key == key2
    np.testing.assert_array_equal(first, again)
    StageRunner(StageCache(tmp_path)).run("stage", 2, "up", {"n": 5}, work, 5)
    assert calls == [5, 5]
    assert runner.records["stage"].runs == 1 and runner.records["stage"].cached == 0


def test_corrupt_entry_is_recomputed(tmp_path):
    cache = StageCache(tmp_path)
    key = stage_key("u", "s", 1, {})
    cache.put(key, 42)
    path = next(tmp_path.rglob("*.pkl"))
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

    StageRunner(StageCache(tmp_path)).run("stage", 1, "up", {}, work)
    path = next(tmp_path.rglob("*.pkl"))
    data = bytearray(path.read_bytes())
    data[-100] ^= 0x10  # inside a float of the payload: still a loadable pickle, a wrong value
    path.write_bytes(bytes(data))
    runner = StageRunner(StageCache(tmp_path))
    value, _ = runner.run("stage", 1, "up", {}, work)
    assert calls == [1, 1] and runner.records["stage"].corrupt == 1 and runner.records["stage"].cached == 0
    np.testing.assert_array_equal(value, np.linspace(0.0, 1.0, 1000))
    assert runner.to_json()["stage"]["corrupt_cache_entries"] == 1
    # the rewritten entry is whole again: the next run is a plain hit
    again = StageRunner(StageCache(tmp_path))
    again.run("stage", 1, "up", {}, work)
    assert calls == [1, 1] and again.records["stage"].cached == 1 and again.records["stage"].corrupt == 0
