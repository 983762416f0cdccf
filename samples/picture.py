"""Render docs/images/torus.png, the README's picture: the bundled jade torus lit from behind and to
the side, drawn plain (Lambert), with the standard glTF fallback, and with its baked prt data.

Run from the checkout (needs Chromium, node and puppeteer-core, as the browser tests do):
``python samples/picture.py``. It bakes samples/torus.ply into a temporary folder, serves it with
``sssbake view`` and screenshots each mode through tests/browser.py's headless Chromium.
"""

from __future__ import annotations

import subprocess
import sys
import tempfile
from pathlib import Path

from PIL import Image, ImageDraw

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO / "tests"))
from browser import open_page  # noqa: E402  (the tests' headless Chromium driver)

MODES = (("plain", "plain (Lambert)"), ("fallback", "glTF fallback"), ("prt", "sssbake prt"))
LIGHT = (140, 25)  # azimuth, elevation in degrees: behind and to the side, where scattering shows
CROP = (140, 108, 500, 420)  # the torus within the viewer's 640 x 480 page, below its panel


def main() -> int:
    with tempfile.TemporaryDirectory() as folder:
        out = Path(folder)
        subprocess.run([sys.executable, "-m", "sssbake.pipeline.cli", "bake", str(REPO / "samples" / "torus.ply"),
                        "-o", str(out), "--config", str(REPO / "samples" / "sssbake.toml"), "--techniques", "prt",
                        "-q"], check=True)
        view = subprocess.Popen([sys.executable, "-m", "sssbake.pipeline.cli", "view", str(out / "torus.glb"),
                                 "--no-open"], stdout=subprocess.PIPE, text=True)
        try:
            url = view.stdout.readline().split(" at ")[1].split()[0]
            panels = []
            for mode, label in MODES:
                ready = (f"window.sssbakeReady === true && (window.sssbakeViewer.setMode('{mode}'), "
                         f"window.sssbakeViewer.setLight({LIGHT[0]}, {LIGHT[1]}), true)")
                shot = out / f"{mode}.png"
                open_page(url, shot, 640, 480, ready=ready)
                panel = Image.open(shot).convert("RGB").crop(CROP)
                ImageDraw.Draw(panel).text((10, 8), label, fill=(230, 230, 230))
                panels.append(panel)
        finally:
            view.terminate()
            view.wait()
    width, height = panels[0].size
    picture = Image.new("RGB", (width * len(panels), height))
    for i, panel in enumerate(panels):
        picture.paste(panel, (i * width, 0))
    target = REPO / "docs" / "images" / "torus.png"
    picture.save(target, optimize=True)
    print(f"wrote {target.relative_to(REPO)} ({target.stat().st_size} bytes)")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
