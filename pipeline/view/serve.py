"""The ``sssbake view`` server: one .glb, the viewer page, the three.js runtime, the shaders, three.js.

It listens on 127.0.0.1 only and serves a fixed set of URLs; nothing else on the user's disk is
reachable (no directory listings, no ``..``). URLs:

``/`` (the page), ``/viewer.js``, ``/model.glb`` (the one file), ``/runtime_three/…`` (the ES module
runtime), ``/runtime_shaders/…`` (the GLSL it compiles), ``/three/build/…`` and
``/three/examples/jsm/…`` (three.js: the files the page and the runtime import, vendored in the
package's ``three/`` folder, so that an installed wheel needs no ``node_modules`` and ``npm ci``
never changes a running viewer under the browser).
"""

from __future__ import annotations

import http.server
import os
import threading
import urllib.parse
from pathlib import Path

import sssbake.runtime_shaders
import sssbake.runtime_three
from sssbake.exporters.gltf_tables import load_sssbake_gltf
from sssbake.pipeline.core.errors import AssetError, SssbakeError

PAGE = Path(__file__).resolve().parent / "page"
#: three.js as vendored from npm's ``three`` (the version in its ``VERSION``, the pin in package.json;
#: ``README.md`` there says which files and how to refresh them), in npm's layout.
THREE = Path(__file__).resolve().parent / "three"
EXTENSION = "SSSBAKE_subsurface"

#: Served types; a file with another suffix is a 404 even inside a served folder.
_TYPES = {
    ".html": "text/html; charset=utf-8", ".js": "text/javascript; charset=utf-8",
    ".mjs": "text/javascript; charset=utf-8", ".glsl": "text/plain; charset=utf-8",
    ".vert": "text/plain; charset=utf-8", ".frag": "text/plain; charset=utf-8",
    ".json": "application/json", ".glb": "model/gltf-binary",
}


class ViewError(SssbakeError):
    """The viewer cannot start: the install lacks three.js or the runtime, or the port is taken."""

    exit_code = 2


def check_glb(path: str | os.PathLike) -> dict:
    """The glTF JSON of a .glb that holds sssbake data; one-line `AssetError` otherwise.

    The container and the JSON are checked as every command checks them (`load_sssbake_gltf`: each
    GLB length field against the file's size, the JSON's nesting and shape); whether its tables are
    intact is the runtime's check, shown on the page, so that a stale file never renders.
    """
    path = Path(path)
    if not path.is_file():
        raise AssetError(path, "no such file")
    if path.suffix.lower() != ".glb":
        raise AssetError(path, "view shows the .glb files sssbake bake writes")
    data = load_sssbake_gltf(path)  # names the tool when it dropped the extension but kept sssbake's attributes
    if data.root is None:
        raise AssetError(path, f"no sssbake data (no {EXTENSION} extension); bake it with sssbake bake")
    return data.gltf


def served_folders() -> dict[str, Path]:
    """URL prefix -> folder for the runtime, the shaders and three.js, all inside the installed
    package; `ViewError` naming the file when an install lacks one (the page would only say that a
    module failed to load)."""
    folders = {
        "runtime_three/": Path(sssbake.runtime_three.__file__).resolve().parent,
        "runtime_shaders/": Path(sssbake.runtime_shaders.__file__).resolve().parent,
        "three/build/": THREE / "build",
        "three/examples/jsm/": THREE / "examples" / "jsm",
    }
    for needed in (folders["runtime_three/"] / "sssbake-three.js", folders["three/build/"] / "three.module.js"):
        if not needed.is_file():
            raise ViewError(f"{needed}: missing from the installed sssbake package; reinstall it "
                            "(pip install --force-reinstall sssbake, or pip install -e . in a checkout)")
    return folders


def resolve(url_path: str, glb: Path, folders: dict[str, Path]) -> Path | None:
    """The file a request path names, or None (404).

    Parameters
    ----------
    url_path : str
        The request's path, still percent-encoded, query removed.
    glb : Path
        The one model file, served as ``/model.glb``.
    folders : dict
        URL prefix (``"three/build/"``) -> folder, as `served_folders` gives.
    """
    path = urllib.parse.unquote(url_path)
    if not path.startswith("/") or "\\" in path or "\0" in path:
        return None
    path = path[1:]
    if path in ("", "index.html"):
        return PAGE / "index.html"
    if path == "viewer.js":
        return PAGE / "viewer.js"
    if path == "model.glb":
        return glb
    for prefix, folder in folders.items():
        if not path.startswith(prefix):
            continue
        parts = path[len(prefix):].split("/")
        # no empty, '.' or '..' segments: the path names a file below the folder and nothing else
        if any(p in ("", ".", "..") for p in parts) or Path(parts[-1]).suffix not in _TYPES:
            return None
        target = folder.joinpath(*parts).resolve()
        return target if target.is_relative_to(folder.resolve()) and target.is_file() else None
    return None


def _handler(glb: Path, folders: dict[str, Path], port_of) -> type[http.server.BaseHTTPRequestHandler]:
    class Handler(http.server.BaseHTTPRequestHandler):
        def do_GET(self):
            self._send(body=True)

        def do_HEAD(self):
            self._send(body=False)

        def _send(self, body: bool) -> None:
            # A page elsewhere that rebinds its DNS name to 127.0.0.1 sends its own Host: refuse it.
            port = port_of()
            if self.headers.get("Host") not in (f"127.0.0.1:{port}", f"localhost:{port}"):
                self.send_error(403, "view answers only http://127.0.0.1 and http://localhost")
                return
            target = resolve(urllib.parse.urlsplit(self.path).path, glb, folders)
            if target is None:
                self.send_error(404)
                return
            try:
                data = target.read_bytes()
            except OSError:
                self.send_error(404)
                return
            self.send_response(200)
            self.send_header("Content-Type", _TYPES.get(target.suffix.lower(), "application/octet-stream"))
            self.send_header("Content-Length", str(len(data)))
            self.send_header("Cache-Control", "no-store")
            self.send_header("X-Content-Type-Options", "nosniff")
            if target == glb:  # the page names the user's file in its title and errors
                self.send_header("Content-Disposition", f"inline; filename*=UTF-8''{urllib.parse.quote(glb.name)}")
            self.end_headers()
            if body:
                try:
                    self.wfile.write(data)
                except (BrokenPipeError, ConnectionResetError):  # the browser left (a reload): no traceback
                    pass

        def log_message(self, *args):  # a quiet terminal: the URL line is what the user needs
            pass

    return Handler


class ViewServer:
    """A running viewer: ``url``, and `close` to stop it (also a context manager).

    Parameters
    ----------
    glb : str or os.PathLike
        The .glb to show (checked by `check_glb`).
    port : int
        Loopback port; 0 for a free one.
    folders : dict, optional
        URL prefix -> folder (default `served_folders`'s).
    """

    def __init__(self, glb: str | os.PathLike, port: int = 0, folders: dict[str, Path] | None = None):
        check_glb(glb)  # before resolving: errors name the file as the user gave it
        self.glb = Path(glb).resolve()
        folders = served_folders() if folders is None else folders
        handler = _handler(self.glb, folders, lambda: self._server.server_address[1])
        try:
            self._server = http.server.ThreadingHTTPServer(("127.0.0.1", port), handler)
        except OSError as e:
            raise ViewError(f"cannot listen on 127.0.0.1:{port}: {e.strerror or e}") from None
        self._server.daemon_threads = True
        self._thread = threading.Thread(target=self._server.serve_forever, daemon=True)
        self._thread.start()

    @property
    def url(self) -> str:
        return f"http://127.0.0.1:{self._server.server_address[1]}/"

    def close(self) -> None:
        self._server.shutdown()
        self._server.server_close()
        self._thread.join()

    def __enter__(self) -> ViewServer:
        return self

    def __exit__(self, *exc) -> None:
        self.close()
