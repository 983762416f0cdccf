"""Headless Chromium for tests: a loopback static server and page screenshots.

Pages signal readiness with ``window.sssbakeReady = true`` (or another expression), failure with
``window.sssbakeError = "…"`` and may hand a JSON value back in ``window.sssbakeResult``. Chromium
runs WebGL 2 on the CPU through SwiftShader, driven by ``tests/js/screenshot.mjs`` (puppeteer-core).
"""

from __future__ import annotations

import contextlib
import functools
import http.server
import json
import shutil
import subprocess
import threading
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from PIL import Image

REPO = Path(__file__).resolve().parents[1]
_SCRIPT = REPO / "tests" / "js" / "screenshot.mjs"
_BROWSERS = ("chromium", "chromium-browser", "google-chrome")


class BrowserError(RuntimeError):
    """The page set ``window.sssbakeError`` (the message is its text) or never became ready."""


@dataclass(frozen=True)
class PageResult:
    """image : (h, w, 3) uint8; result : ``window.sssbakeResult``; logs : console lines."""
    image: np.ndarray
    result: object
    logs: list[str]


def chromium() -> str | None:
    """Path of a Chromium binary, or None."""
    return next((shutil.which(b) for b in _BROWSERS if shutil.which(b)), None)


def have_chromium() -> bool:
    """Chromium, node and puppeteer-core are all there (CI's .ci/setup installs them)."""
    return bool(chromium() and shutil.which("node") and (REPO / "node_modules" / "puppeteer-core").is_dir())


def open_page(url: str, out_png: str | Path, width: int, height: int, ready: str = "window.sssbakeReady === true",
              timeout_s: float = 120) -> PageResult:
    """Load `url`, wait until `ready` is true, screenshot the viewport to `out_png`."""
    proc = subprocess.run(
        ["node", str(_SCRIPT), url, str(out_png), str(width), str(height), ready, str(int(timeout_s * 1000)),
         chromium()],
        capture_output=True, text=True, timeout=timeout_s + 60, cwd=REPO,
    )
    lines = [line for line in proc.stdout.splitlines() if line.startswith("{")]
    if not lines:
        raise BrowserError(f"screenshot.mjs printed nothing (rc {proc.returncode}): {proc.stderr.strip()[-2000:]}")
    report = json.loads(lines[-1])
    if "error" in report:
        raise BrowserError(report["error"] + "".join(f"\n  {line}" for line in report["logs"][-20:]))
    with Image.open(out_png) as png:
        image = np.asarray(png.convert("RGB"))
    return PageResult(image=image, result=report["result"], logs=report["logs"])


def screenshot(url: str, out_png: str | Path, width: int, height: int, ready: str = "window.sssbakeReady === true",
               timeout_s: float = 120) -> np.ndarray:
    """`open_page`'s image: (h, w, 3) uint8."""
    return open_page(url, out_png, width, height, ready, timeout_s).image


class _Quiet(http.server.SimpleHTTPRequestHandler):
    extensions_map = {**http.server.SimpleHTTPRequestHandler.extensions_map,
                      ".js": "text/javascript", ".mjs": "text/javascript", ".glb": "model/gltf-binary",
                      ".glsl": "text/plain", ".vert": "text/plain", ".frag": "text/plain",
                      ".wasm": "application/wasm"}

    def log_message(self, *args):
        pass


@contextlib.contextmanager
def static_server(root: str | Path):
    """Serve `root` on 127.0.0.1 at a free port; yields the base URL (``http://127.0.0.1:N/``)."""
    handler = functools.partial(_Quiet, directory=str(root))
    server = http.server.ThreadingHTTPServer(("127.0.0.1", 0), handler)
    thread = threading.Thread(target=server.serve_forever, daemon=True)
    thread.start()
    try:
        yield f"http://127.0.0.1:{server.server_address[1]}/"
    finally:
        server.shutdown()
        server.server_close()
