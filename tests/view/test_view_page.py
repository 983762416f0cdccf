"""`sssbake view`'s page in headless Chromium: a baked sample draws in every mode the file holds
(each a real picture, the techniques unlike plain Lambert), the light moves the picture, and a
file whose table bytes changed after the bake gets the plugin's one-line error instead of pixels."""

import json
import struct
import subprocess
from pathlib import Path

import numpy as np
import pytest

from sssbake.pipeline.cli import main
from sssbake.pipeline.view.serve import ViewServer, served_folders
from tests.browser import BrowserError, chromium, have_chromium, open_page

REPO = Path(__file__).resolve().parents[2]
#: Once the page is ready and `{before}` (JS through its API) is true, every mode's frame handed back
#: (window.sssbakeViewer.frames).
FRAMES = ("window.sssbakeReady === true && ({before}) && "
          "!!(window.sssbakeResult = window.sssbakeViewer.frames({width}))")

pytestmark = pytest.mark.skipif(not have_chromium(), reason="needs chromium, node and puppeteer-core (.ci/setup)")


@pytest.fixture(scope="module")
def baked(tmp_path_factory) -> Path:
    """samples/sphere.obj baked with every technique the three.js runtime draws."""
    out = tmp_path_factory.mktemp("view_baked")
    assert main(["bake", str(REPO / "samples" / "sphere.obj"), "-o", str(out), "--scale-mm", "1", "--material",
                 "marble", "--techniques", "prt,spectral,screen", "--atlas-resolution", "64", "--no-validate",
                 "--no-cache", "-q"]) == 0
    return out / "sphere.glb"


def _frames(url: str, png: Path, before: str = "true", width: int = 96) -> dict[str, np.ndarray]:
    """Each mode's frame from the page's API after `before`: {mode: (h, w, 3) float in 0..255}."""
    page = open_page(url, png, 320, 240, ready=FRAMES.format(before=before, width=width))
    return {m: np.asarray(f["rgb"], float).reshape(f["height"], f["width"], 3) for m, f in page.result.items()}


def test_every_mode_draws_and_the_techniques_differ_from_plain(baked, tmp_path):
    with ViewServer(baked) as server:
        frames = _frames(server.url, tmp_path / "page.png")
        # the light from behind-left, low: the lit side moves
        moved = _frames(server.url, tmp_path / "moved.png", "(window.sssbakeViewer.setLight(-120, 10), true)")
    assert list(frames) == ["prt", "spectral", "screen", "fallback", "plain"]
    background = frames["plain"][0, 0]
    # the object's pixels: those unlike the corner's background in any mode
    mask = np.any([np.abs(f - background).max(axis=2) > 8 for f in frames.values()], axis=0)
    assert 0.05 < mask.mean() < 0.6, mask.mean()
    for mode, frame in frames.items():
        lit = np.abs(frame - background).max(axis=2)[mask]
        assert (lit > 8).mean() > 0.5, f"{mode} is blank on {(lit <= 8).mean():.0%} of the object"
        assert frame[mask].std() > 5, f"{mode} is flat"
    # spectral's low-pass filtered normals are a sphere's own normals: only prt and screen must differ here
    for technique in ("prt", "screen"):
        diff = np.abs(frames[technique] - frames["plain"])[mask].mean()
        assert diff > 4.0, f"{technique} draws like plain Lambert (mean |difference| {diff:.2f} / 255)"
    for mode in frames:
        diff = np.abs(moved[mode] - frames[mode])[mask].mean()
        assert diff > 5.0, f"{mode}: moving the light changed little (mean |difference| {diff:.2f} / 255)"


def test_a_stale_file_shows_the_error_not_pixels(baked, tmp_path, capsys):
    """One byte of a prt table changed after the bake (as a tool rewriting buffers would): the
    CRC-32 no longer matches; the command refuses it in one line, and when served anyway the plugin
    refuses the load and the page says so in one line."""
    data = bytearray(baked.read_bytes())
    json_length = struct.unpack_from("<I", data, 12)[0]
    gltf = json.loads(data[20:20 + json_length])
    ref = gltf["meshes"][0]["extensions"]["SSSBAKE_subsurface"]["prt"]["directions"]
    accessor = gltf["accessors"][ref["accessor"]]
    view = gltf["bufferViews"][accessor["bufferView"]]
    data[20 + json_length + 8 + view.get("byteOffset", 0) + accessor.get("byteOffset", 0)] ^= 0x40
    stale = tmp_path / "stale.glb"
    stale.write_bytes(bytes(data))
    assert main(["view", str(stale), "--no-open"]) == 1
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and err.startswith(f"error: {stale}: ") and ref["name"] in err and "CRC-32" in err, err
    with ViewServer(stale) as server, pytest.raises(BrowserError) as error:
        open_page(server.url, tmp_path / "stale.png", 320, 240)
    message = str(error.value).splitlines()[0]
    assert "stale.glb" in message and ref["name"] in message and "CRC" in message.upper(), message


def test_a_missing_runtime_module_is_a_page_error(baked, tmp_path):
    folders = served_folders()
    folders["runtime_three/"] = tmp_path  # no sssbake-three.js: the module graph fails to load
    with ViewServer(baked, folders=folders) as server, \
            pytest.raises(BrowserError, match="cannot load the viewer's modules"):
        open_page(server.url, tmp_path / "page.png", 320, 240)


def test_a_resized_window_gets_a_new_runtime(baked, tmp_path):
    # the runtime's targets have the canvas' size: after a resize the page rebuilds it (150 ms
    # after the last resize event) and the frames keep the new size and still show the object
    shrink = ("(window.shrunk ??= (document.getElementById('view').style.width = '160px', "
              "window.dispatchEvent(new Event('resize')), true)) && window.sssbakeViewer.state.rebuilds === 1")
    with ViewServer(baked) as server:
        frames = _frames(server.url + "?mode=screen", tmp_path / "page.png", shrink, width=80)
    assert {f.shape for f in frames.values()} == {(120, 80, 3)}  # 160 x 240 CSS pixels
    for mode, frame in frames.items():
        assert (np.abs(frame - frames["plain"][0, 0]).max(axis=2) > 8).mean() > 0.05, f"{mode} is blank"


def test_drag_orbits_shift_drag_moves_the_light_buttons_switch(baked):
    with ViewServer(baked) as server:
        proc = subprocess.run(["node", str(Path(__file__).parent / "interact.mjs"), server.url, chromium()],
                              capture_output=True, text=True, timeout=180, cwd=REPO)
    report = json.loads(proc.stdout.splitlines()[-1])
    assert "error" not in report and report["logs"] == [], report
    start, orbited, moved, plain = (report["states"][k] for k in ("start", "orbited", "lightMoved", "plain"))
    assert start["mode"] == "prt" and start["light"] == [42, 53]
    # a plain drag turns the camera about the model and leaves the light alone
    assert np.linalg.norm(np.subtract(orbited["camera"], start["camera"])) > 0.1 * np.linalg.norm(start["camera"])
    assert orbited["light"] == start["light"]
    # a shift-drag moves the light (0.5 degree per pixel: 60 right, 40 up) and leaves the camera alone
    assert moved["light"] == [72, 73] and moved["camera"] == orbited["camera"]
    assert plain["mode"] == "plain"
