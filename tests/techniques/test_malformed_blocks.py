"""A baked .glb whose technique blocks another tool rewrote: every field of every block (prt's table
references and attributes one level down too) swapped for each JSON type, or deleted. The readers
`verify` uses refuse with one line (prt's naming the field) or read on, never with another exception
or a warning; `verify` and `inspect` exit 1 with one line, never a traceback."""

import copy
import json
import struct
import warnings
from pathlib import Path

import pytest
from fixtures import bake_screen_sphere

from sssbake.exporters.gltf import EXTENSION
from sssbake.pipeline.cli import main
from sssbake.pipeline.core.errors import SssbakeError
from sssbake.pipeline.techniques.registry import BY_NAME

#: Each JSON type, and numbers no field holds (2^64: past int64; 1e300: past float32).
TYPE_SWAPS = (None, True, -1, 2.5, 1e300, 2**64, "x", [], [1, 2], {}, {"a": 1})
DELETED = "deleted"
#: prt fields a reader has no use for: any value reads.
PRT_UNREAD = ("technique", "units")


@pytest.fixture(scope="module")
def baked(tmp_path_factory) -> tuple[dict, bytes]:
    """A small ball baked with every technique that writes a block (prt, kernels and lpv on the mesh,
    screen on the material), cheaply: its GLB's JSON and what follows the JSON chunk."""
    folder = tmp_path_factory.mktemp("blocks")
    bake_screen_sphere(folder, techniques=("prt", "kernels", "screen", "lpv"), prt_directions=16, prt_sh_order=1,
                       lpv_resolution=8)
    data = (folder / "ball.glb").read_bytes()
    (length,) = struct.unpack_from("<I", data, 12)
    return json.loads(data[20:20 + length]), data[20 + length:]


def _glb(doc: dict, rest: bytes) -> bytes:
    text = json.dumps(doc).encode()
    text += b" " * (-len(text) % 4)
    body = struct.pack("<II", len(text), 0x4E4F534A) + text + rest
    return struct.pack("<4sII", b"glTF", 2, 12 + len(body)) + body


def _mutations(doc: dict):
    """(technique, field path, value or DELETED, the document so changed) for each technique block."""
    for kind in ("meshes", "materials"):
        for i, owner in enumerate(doc[kind]):
            extension = owner.get("extensions", {}).get(EXTENSION, {})
            for technique in BY_NAME:
                block = extension.get(technique)
                if block is None:
                    continue
                paths = [()] + [(key,) for key in block]
                if technique == "prt":
                    paths += [(key, sub) for key, value in block.items() if isinstance(value, dict) for sub in value]
                for path in paths:
                    for value in (*TYPE_SWAPS, DELETED):
                        changed = copy.deepcopy(doc)
                        parent = changed[kind][i]["extensions"][EXTENSION]
                        for key in (technique, *path)[:-1]:
                            parent = parent[key]
                        last = (technique, *path)[-1]
                        if value == DELETED:
                            del parent[last]
                        else:
                            parent[last] = value
                        yield technique, path, value, changed


def test_every_field_of_every_block_swapped_or_deleted_is_read_or_refused_in_one_line(baked, tmp_path):
    doc, rest = baked
    wrong, refused, seen = [], set(), set()
    for n, (technique, path, value, changed) in enumerate(_mutations(doc)):
        seen.add(technique)
        glb = tmp_path / f"m{n}.glb"
        glb.write_bytes(_glb(changed, rest))
        case = f"{technique} {'.'.join(path) or '(the block)'} = {value!r}"
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            try:
                BY_NAME[technique].read(glb)
            except (SssbakeError, ValueError) as e:  # verify's one line for a ValueError names the file
                message = str(e)
                refused.add((technique, path, repr(value)))
                # null: the glTF reader's own refusal, naming the whole JSON path
                named = len(path) != 1 or value is None or technique != "prt" or path[0] in message
                if "\n" in message or not named:
                    wrong.append(f"{case}: {type(e).__name__}: {message}")
            except Exception as e:  # noqa: BLE001 - what the test looks for
                wrong.append(f"{case}: {type(e).__name__}: {e}")
        wrong += [f"{case}: warned {w.message}" for w in caught]
        glb.unlink()
    assert not wrong, "\n".join(wrong[:20])
    assert seen == {"prt", "kernels", "screen", "lpv"}
    # prt reads every field but two: a string in any other is refused
    unread = [key for key in doc["meshes"][0]["extensions"][EXTENSION]["prt"]
              if key not in PRT_UNREAD and ("prt", (key,), "'x'") not in refused]
    assert not unread


def test_verify_and_inspect_of_a_malformed_prt_block_say_one_line(baked, tmp_path, capsys):
    """Each top-level prt field swapped or deleted (``directionCount: []`` gave verify a TypeError
    traceback): where the reader refuses it, verify exits 1 with one line naming the file once and the
    field; inspect, which lists the tables, exits 0, or 1 with one line."""
    doc, rest = baked
    wrong, verified = [], 0
    for n, (technique, path, value, changed) in enumerate(_mutations(doc)):
        if technique != "prt" or len(path) != 1:
            continue
        glb = tmp_path / f"m{n}.glb"
        glb.write_bytes(_glb(changed, rest))
        case = f"{path[0]} = {value!r}"
        capsys.readouterr()
        code = main(["inspect", str(glb)])
        err = capsys.readouterr().err.splitlines()
        if (code, len(err)) not in ((0, 0), (1, 1)):
            wrong.append(f"{case}: inspect exited {code}: {err}")
        try:
            BY_NAME["prt"].read(glb)
        except (SssbakeError, ValueError):  # refused: verify stops there (a file the reader takes, it would render)
            verified += 1
            code = main(["verify", str(glb), "--technique", "prt", "--size", "16", "--frames", "1"])
            err = capsys.readouterr().err.splitlines()
            named = value is None or path[0] in err[0]  # null: the glTF reader's refusal names the JSON path
            if code != 1 or len(err) != 1 or not err[0].startswith(f"error: {glb}: ") or err[0].count(str(glb)) != 1 \
                    or not named:
                wrong.append(f"{case}: verify exited {code}: {err}")
        glb.unlink()
    assert not wrong, "\n".join(wrong[:20])
    assert verified > 200
