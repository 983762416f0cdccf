"""atomic_path: the final file appears complete or not at all, and no temporary file is left."""

import os

import pytest

from sssbake.exporters.atomic import atomic_path


def test_success_replaces_the_file_and_leaves_no_temp(tmp_path):
    final = tmp_path / "out.glb"
    final.write_bytes(b"old")
    with atomic_path(final) as tmp:
        assert tmp.parent == tmp_path and tmp.suffix == ".glb" and tmp != final
        assert not tmp.exists()
        tmp.write_bytes(b"new")
        assert final.read_bytes() == b"old"
    assert final.read_bytes() == b"new"
    assert [p.name for p in tmp_path.iterdir()] == ["out.glb"]


def test_new_file_gets_ordinary_permissions(tmp_path):
    final = tmp_path / "out.usdc"
    with atomic_path(final) as tmp:
        tmp.write_bytes(b"x")
    umask = os.umask(0)
    os.umask(umask)
    assert final.stat().st_mode & 0o777 == 0o666 & ~umask


@pytest.mark.parametrize("existing", [False, True])
def test_exception_midway_leaves_nothing_behind(tmp_path, existing):
    final = tmp_path / "out.glb"
    if existing:
        final.write_bytes(b"old")
    with pytest.raises(RuntimeError, match="midway"):
        with atomic_path(final) as tmp:
            with open(tmp, "wb") as f:
                f.write(b"partial")
            raise RuntimeError("midway")
    assert [p.name for p in tmp_path.iterdir()] == (["out.glb"] if existing else [])
    if existing:
        assert final.read_bytes() == b"old"


def test_nothing_written_is_an_error(tmp_path):
    with pytest.raises(FileNotFoundError, match="nothing was written"):
        with atomic_path(tmp_path / "out.glb"):
            pass
    assert list(tmp_path.iterdir()) == []
