"""atomic_path: the final file appears complete or not at all, and no temporary file is left; any name
the folder allows is written, its temporary known as its."""

import errno
import os
from pathlib import Path

import pytest

from sssbake.exporters.atomic import atomic_path, is_temporary, temporary_of, temporary_target


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


@pytest.mark.parametrize("final", ["a" * 240 + ".usdc", "é" * 121 + ".glb", "b" * 255])
def test_a_long_name_gets_a_temporary_that_fits_and_is_known_as_its(tmp_path, final):
    """A name of up to 255 bytes is written: the temporary (and the one USD's save writes on its way
    to it, 7 bytes longer) is named after its start and a digest, which `temporary_of` checks."""
    with atomic_path(tmp_path / final) as tmp:
        suffix = Path(final).suffix
        assert len(os.fsencode(tmp.name)) + max(0, 7 - len(suffix)) <= 255 and tmp.name.endswith(".tmp" + suffix)
        assert temporary_of(tmp.name, final) and is_temporary(tmp.name) and temporary_target(tmp.name) is None
        assert not temporary_of(tmp.name, f"{final[:-2]}Z{final[-1]}")  # the same start, another name
        if suffix:
            assert temporary_of(tmp.with_suffix(".Ab3dE9").name, final)  # USD's save name
        tmp.write_bytes(b"x")
    assert [p.name for p in tmp_path.iterdir()] == [final]


def test_a_name_too_long_for_the_folder_is_refused_naming_it(tmp_path):
    final = tmp_path / ("c" * 252 + ".usdc")
    with pytest.raises(OSError) as caught:
        with atomic_path(final):
            pass
    assert caught.value.errno == errno.ENAMETOOLONG and caught.value.filename == str(final)
    assert caught.value.strerror.startswith("File name too long (257 bytes; this folder allows 255)")
    assert list(tmp_path.iterdir()) == []


def test_names_with_a_newline_or_bytes_not_utf8_are_temporaries_too(tmp_path):
    for final in ("a\nb.glb", os.fsdecode(b"\xff.usdc")):
        with atomic_path(tmp_path / final) as tmp:
            assert temporary_target(tmp.name) == final and is_temporary(tmp.name)
            tmp.write_bytes(b"x")
    assert sorted(p.name for p in tmp_path.iterdir()) == sorted(["a\nb.glb", os.fsdecode(b"\xff.usdc")])
