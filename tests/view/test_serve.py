"""`sssbake view`'s server: loopback only, the page and the one .glb, nothing else from the disk;
the command's one-line errors."""

import contextlib
import http.client
import json
import re
import signal
import struct
import subprocess
import sys
import urllib.request
from pathlib import Path

import pytest

from sssbake.pipeline.cli import main
from sssbake.pipeline.core.errors import AssetError
from sssbake.pipeline.view.serve import PAGE, THREE, ViewError, ViewServer, check_glb, served_folders


def _glb(path, gltf: dict, bin_chunk: bytes = b""):
    """Write a .glb holding `gltf` (and a BIN chunk when given)."""
    body = json.dumps(gltf).encode()
    body += b" " * (-len(body) % 4)
    chunks = struct.pack("<II", len(body), 0x4E4F534A) + body
    if bin_chunk:
        bin_chunk += b"\0" * (-len(bin_chunk) % 4)
        chunks += struct.pack("<II", len(bin_chunk), 0x004E4942) + bin_chunk
    path.write_bytes(b"glTF" + struct.pack("<II", 2, 12 + len(chunks)) + chunks)
    return path


_SSS = {"asset": {"version": "2.0"}, "extensionsUsed": ["SSSBAKE_subsurface"],
        "extensions": {"SSSBAKE_subsurface": {"schemaVersion": "2.0.0"}}}


@pytest.fixture
def served(tmp_path):
    """A server on a small .glb with stand-in folders, and a file beside them it must never serve."""
    (tmp_path / "secret.js").write_text("secret")
    folders = {}
    for prefix, name in (("runtime_three/", "sssbake-three.js"), ("runtime_shaders/", "prt.vert"),
                         ("three/build/", "three.module.js")):
        folder = tmp_path / "served" / prefix
        folder.mkdir(parents=True)
        (folder / name).write_text(f"// {prefix}{name}")
        folders[prefix] = folder
    (folders["runtime_shaders/"] / "__init__.py").write_text("")
    (folders["three/build/"] / "sub").mkdir()
    (folders["three/build/"] / "sub" / "a.js").write_text("// nested")
    (tmp_path / "model dir").mkdir()
    glb = _glb(tmp_path / "model dir" / "x.glb", _SSS, b"\1\2\3")
    with ViewServer(glb, folders=folders) as server:
        yield server, glb, folders


def _get(server, path: str, host: str | None = None, method: str = "GET"):
    port = int(server.url.rsplit(":", 1)[1].strip("/"))
    conn = http.client.HTTPConnection("127.0.0.1", port, timeout=10)
    # raw request line: http.client sends the path as given, so '..' and '%2e' reach the server untouched
    conn.putrequest(method, path, skip_host=True)
    conn.putheader("Host", host or f"127.0.0.1:{port}")
    conn.endheaders()
    response = conn.getresponse()
    body = response.read()
    conn.close()
    return response.status, response.getheader("Content-Type"), body


def test_listens_on_loopback_only(served):
    server, _, _ = served
    assert server._server.server_address[0] == "127.0.0.1"
    assert server.url.startswith("http://127.0.0.1:")


def test_serves_the_page_the_glb_and_the_runtime_folders(served):
    server, glb, folders = served
    assert _get(server, "/") == (200, "text/html; charset=utf-8", (PAGE / "index.html").read_bytes())
    assert _get(server, "/index.html")[2] == (PAGE / "index.html").read_bytes()
    assert _get(server, "/viewer.js")[:2] == (200, "text/javascript; charset=utf-8")
    assert _get(server, "/model.glb") == (200, "model/gltf-binary", glb.read_bytes())
    assert _get(server, "/model.glb?t=1")[2] == glb.read_bytes()
    assert _get(server, "/runtime_three/sssbake-three.js")[2] == b"// runtime_three/sssbake-three.js"
    assert _get(server, "/runtime_shaders/prt.vert")[:2] == (200, "text/plain; charset=utf-8")
    assert _get(server, "/three/build/sub/a.js")[2] == b"// nested"
    status, _, body = _get(server, "/model.glb", method="HEAD")
    assert (status, body) == (200, b"")


@pytest.mark.parametrize("path", [
    "/x.glb", "/model%20dir/x.glb", "/secret.js", "/../secret.js", "/%2e%2e/secret.js",
    "/served/runtime_three/sssbake-three.js",
    "/three/build/../../secret.js", "/three/build/%2e%2e/%2e%2e/secret.js", "/three/build/..%2f..%2fsecret.js",
    "/three/build/sub/../../../secret.js", "/three/build//etc/passwd", "/three/build/./three.module.js",
    "/three/build/", "/three/build/sub", "/three/build/sub/", "/runtime_shaders/", "/runtime_shaders/__init__.py",
    "/three/build/..\\..\\secret.js", "/model.glb/..", "/etc/passwd", "//etc/passwd", "/three/", "/viewer.js/x",
    "/runtime_three/sssbake-three.js%00.js",
])
def test_anything_else_is_404(served, path):
    status, _, body = _get(served[0], path)
    assert status == 404 and b"secret" not in body


def test_other_host_names_are_refused(served):
    # a page whose DNS name was rebound to 127.0.0.1 still sends its own name
    assert _get(served[0], "/model.glb", host="attacker.example")[0] == 403
    port = served[0].url.rsplit(":", 1)[1].strip("/")
    assert _get(served[0], "/model.glb", host=f"localhost:{port}")[0] == 200


def test_check_glb_refuses_what_has_no_sssbake_data(tmp_path):
    assert check_glb(_glb(tmp_path / "ok.glb", _SSS))["extensions"]["SSSBAKE_subsurface"]["schemaVersion"] == "2.0.0"
    cases = {
        "missing.glb": (None, "no such file"),
        "model.gltf": (b"{}", "view shows the .glb files"),
        "text.glb": (b"hello, this is not a glb file", "not a GLB file: bad magic b'hell'"),
        "short.glb": (b"glTF", "truncated file: 4 bytes, shorter than the 12-byte GLB header"),
        "plain.glb": ({"asset": {"version": "2.0"}}, "no sssbake data (no SSSBAKE_subsurface extension)"),
        "old.glb": ({"asset": {"version": "2.0"}, "extras": {"sssbake": {"schemaVersion": "1.4.0"}}},
                    "written by sssbake schema 1.x (extras.sssbake); rebake it with this version"),
        "list.glb": ([1, 2], "not an object"),
        "stripped.glb": ({"asset": {"version": "2.0", "generator": "glTF-Transform v4.5.1"},
                          "meshes": [{"primitives": [{"attributes": {"POSITION": 0, "_THICKNESS": 1}}]}]},
                         "without the root's SSSBAKE_subsurface object; likely broken by glTF-Transform"),
    }
    for name, (content, message) in cases.items():
        path = tmp_path / name
        if isinstance(content, bytes):
            path.write_bytes(content)
        elif content is not None:
            _glb(path, content)
        with pytest.raises(AssetError, match=re.escape(message)) as e:
            check_glb(path)
        assert "\n" not in str(e.value) and str(e.value).startswith(str(path))


def test_cli_errors_are_one_line(tmp_path, capsys, monkeypatch):
    monkeypatch.chdir(tmp_path)
    _glb(tmp_path / "plain.glb", {"asset": {"version": "2.0"}})
    (tmp_path / "mesh.obj").write_text("v 0 0 0\n")
    for name, message in (("missing.glb", "no such file"), ("plain.glb", "no sssbake data"),
                          ("mesh.obj", "view shows the .glb files sssbake bake writes")):
        assert main(["view", name, "--no-open"]) == 1
        err = capsys.readouterr().err
        assert err.count("\n") == 1 and err.startswith(f"error: {name}: {message}"), err
    for bad in (["--port", "70000"], ["--port", "x"], ["--host", "0.0.0.0"]):
        with pytest.raises(SystemExit) as e:
            main(["view", "plain.glb", *bad])
        assert e.value.code == 2


def test_served_folders_are_the_package_s_and_a_taken_port(served):
    # three.js is the package's vendored copy: never a checkout's node_modules, which `npm ci` rewrites
    folders = served_folders()
    assert folders["three/build/"] == THREE / "build" and (THREE / "build" / "three.module.js").is_file()
    assert "node_modules" not in str(folders["three/examples/jsm/"])
    assert (folders["runtime_three/"] / "sssbake-three.js").is_file()
    server, glb, folders = served
    port = int(server.url.rsplit(":", 1)[1].strip("/"))
    with pytest.raises(ViewError, match=f"cannot listen on 127.0.0.1:{port}"):
        ViewServer(glb, port, folders=folders)


@contextlib.contextmanager
def _view_command(glb: Path):
    """`sssbake view glb --no-open` running: (process, its URL)."""
    # A runner started in the background ignores SIGINT and its children inherit that (Python keeps
    # an inherited ignore): handled here while the child starts, SIGINT is default in the child.
    previous = signal.signal(signal.SIGINT, signal.default_int_handler)
    try:
        # -X faulthandler: if it hangs, SIGABRT makes it print every thread's stack for the failure
        proc = subprocess.Popen([sys.executable, "-X", "faulthandler", "-m", "sssbake.pipeline.cli", "view", str(glb),
                                 "--no-open"], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    finally:
        signal.signal(signal.SIGINT, previous)
    try:
        yield proc, re.search(r"http://127\.0\.0\.1:\d+/", proc.stdout.readline()).group(0)
    finally:
        proc.kill()
        proc.wait()


def _ctrl_c(proc: subprocess.Popen) -> None:
    """Ctrl-C: it must exit 0 at once and print nothing."""
    proc.send_signal(signal.SIGINT)
    try:
        code = proc.wait(timeout=20)
    except subprocess.TimeoutExpired:
        proc.send_signal(signal.SIGABRT)
        raise AssertionError(f"view did not stop on Ctrl-C; its threads:\n{proc.communicate(timeout=20)[1]}") from None
    assert code == 0
    assert proc.stderr.read() == ""


def test_the_command_serves_until_ctrl_c(tmp_path):
    glb = _glb(tmp_path / "x.glb", _SSS, b"\7" * 8)
    with _view_command(glb) as (proc, url):
        with urllib.request.urlopen(url + "model.glb", timeout=10) as response:
            assert response.read() == glb.read_bytes()
            assert response.headers["Content-Disposition"] == "inline; filename*=UTF-8''x.glb"
        with urllib.request.urlopen(url + "three/build/three.core.js", timeout=10) as response:
            assert response.read() == (THREE / "build" / "three.core.js").read_bytes()
        _ctrl_c(proc)


def test_a_ctrl_c_as_the_url_is_printed_stops_it_cleanly(tmp_path):
    with _view_command(_glb(tmp_path / "x.glb", _SSS, b"\7" * 8)) as (proc, _):
        _ctrl_c(proc)
