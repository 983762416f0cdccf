"""The confinement rule every loader applies to the files an asset references."""

import os

import pytest

from sssbake.pipeline.core.errors import AssetError
from sssbake.pipeline.mesh.confine import Confinement


@pytest.fixture
def tree(tmp_path):
    """``lib/asset/a.gltf`` with a texture beside it, a secret outside, and a shared texture root."""
    asset_dir = tmp_path / "lib" / "asset"
    asset_dir.mkdir(parents=True)
    (asset_dir / "a.gltf").write_text("{}")
    (asset_dir / "tex.png").write_bytes(b"png")
    (tmp_path / "secret").write_bytes(b"secret")
    shared = tmp_path / "shared_textures"
    shared.mkdir()
    (shared / "wood.png").write_bytes(b"png")
    return tmp_path


def test_files_in_the_assets_folder_are_allowed(tree):
    c = Confinement.for_asset(tree / "lib" / "asset" / "a.gltf")
    assert c.check(tree / "lib" / "asset" / "tex.png", "image 0") == (tree / "lib" / "asset" / "tex.png").resolve()


@pytest.mark.parametrize("ref", ["../../secret", "../../shared_textures/wood.png"])
def test_a_relative_path_out_of_the_folder_is_refused_with_the_fix(tree, ref):
    asset = tree / "lib" / "asset" / "a.gltf"
    with pytest.raises(AssetError) as e:
        Confinement.for_asset(asset).check(asset.parent / ref, f"image 0 URI '{ref}'")
    message = str(e.value)
    assert message.startswith(f"{asset}: image 0 URI '{ref}' resolves to ")
    assert "outside the asset's folder" in message and "--allow-root" in message and "\n" not in message


def test_a_symlink_inside_the_folder_pointing_out_is_refused(tree):
    asset = tree / "lib" / "asset" / "a.gltf"
    os.symlink(tree / "secret", asset.parent / "innocent.png")
    c = Confinement.for_asset(asset)
    assert not c.allows(asset.parent / "innocent.png")
    with pytest.raises(AssetError, match="secret, outside the asset's folder"):
        c.check(asset.parent / "innocent.png", "image 0 URI 'innocent.png'")


def test_allowed_roots_let_their_files_through_and_nothing_else(tree):
    asset = tree / "lib" / "asset" / "a.gltf"
    c = Confinement.for_asset(asset, [str(tree / "shared_textures")])
    assert c.check(tree / "shared_textures" / "wood.png", "image 1") == (tree / "shared_textures" / "wood.png").resolve()
    assert not c.allows(tree / "secret")
    # a sibling whose name merely starts with the root's is not inside it
    (tree / "shared_textures_evil").mkdir()
    assert not c.allows(tree / "shared_textures_evil" / "x.png")


def test_a_symlinked_asset_may_read_beside_its_link_and_beside_its_real_file(tree):
    library = tree / "library"
    library.mkdir()
    (library / "real.obj").write_text("v 0 0 0\n")
    (library / "real.mtl").write_text("")
    linked = tree / "lib" / "asset" / "linked.obj"
    os.symlink(library / "real.obj", linked)
    c = Confinement.for_asset(linked)
    assert c.allows(library / "real.mtl") and c.allows(tree / "lib" / "asset" / "tex.png")
    assert not c.allows(tree / "secret")


def test_a_fifo_or_folder_is_refused_and_a_missing_file_is_left_to_the_reader(tree):
    asset = tree / "lib" / "asset" / "a.gltf"
    os.mkfifo(asset.parent / "pipe.bin")  # opening it would block the loader forever
    c = Confinement.for_asset(asset)
    with pytest.raises(AssetError, match="not a regular file"):
        c.check(asset.parent / "pipe.bin", "buffer 0 URI 'pipe.bin'")
    with pytest.raises(AssetError, match="not a regular file"):
        c.check(asset.parent, "buffer 0 URI '.'")
    assert c.check(asset.parent / "missing.bin", "buffer 0") == (asset.parent / "missing.bin").resolve()


def test_allow_roots_must_name_folders_in_configs_and_flags(tree, tmp_path, capsys):
    from sssbake.pipeline.cli import main
    from sssbake.pipeline.config import BatchConfig, ConfigError

    assert BatchConfig({"allow_roots": [str(tree / "shared_textures")]}, (), ()).options_for(
        "a.obj", {}).allow_roots == (str(tree / "shared_textures"),)
    for bad, needle in (([str(tree / "nowhere")], "is not a folder"), (str(tree), "must be a list"), ([3], "must be a list")):
        with pytest.raises(ConfigError, match=needle):
            BatchConfig({"allow_roots": bad}, (), ()).options_for("a.obj", {})
    with pytest.raises(SystemExit) as e:
        main(["bake", str(tree), "-o", str(tmp_path / "out"), "--allow-root", str(tree / "nowhere")])
    assert e.value.code == 2 and "is not a folder" in capsys.readouterr().err
