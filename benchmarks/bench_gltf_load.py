"""Reading glTF node graphs: `load_scene` (bake's reader, with the world transforms of every mesh
instance) and `load_sssbake_gltf` (inspect's, verify's and view's) on a chain of N nodes (node i's
only child is node i + 1, the mesh under the last) and on a wide scene of N sibling nodes that each
place the mesh; one line per document.

    python benchmarks/bench_gltf_load.py [--sizes 2000,8000,100000] [--pygltflib 8000] [--bake 8000,100000]

``--pygltflib N`` also times pygltflib's ``GLTF2.gltf_from_json`` on each document of up to N nodes:
what both readers decoded the JSON with before issue 32 (about 1.5 ms a node on the build machine).
``--bake SIZES`` also bakes the chain and the wide scene of each size with ``sssbake bake`` (the
fallback only, a 64² atlas, no cache, validated): wall time and the seconds of the stages that grow
with the node count (load, export_gltf, export_usd, validate), and the depth of the .usdc's node
hierarchy (`exporters.usd.MAX_USD_DEPTH`).
"""

from __future__ import annotations

import argparse
import json
import struct
import tempfile
import time
from pathlib import Path

import numpy as np
from pxr import Usd, UsdGeom

from sssbake.exporters.gltf_tables import load_sssbake_gltf
from sssbake.pipeline.cli import main as sssbake
from sssbake.pipeline.mesh.load import load_scene

# one quad: 4 float32 positions and 6 uint16 indices
POSITIONS = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [1, 1, 0]], "<f4").tobytes()
INDICES = np.array([0, 1, 2, 1, 3, 2], "<u2").tobytes()


def document(shape: str, n: int) -> dict:
    """A glTF of `n` nodes, each translated by (1, 0.5, 0): a ``chain`` or a ``wide`` scene."""
    doc = {
        "asset": {"version": "2.0"},
        "buffers": [{"byteLength": len(POSITIONS) + len(INDICES)}],
        "bufferViews": [{"buffer": 0, "byteLength": len(POSITIONS)},
                        {"buffer": 0, "byteOffset": len(POSITIONS), "byteLength": len(INDICES)}],
        "accessors": [{"bufferView": 0, "componentType": 5126, "count": 4, "type": "VEC3"},
                      {"bufferView": 1, "componentType": 5123, "count": 6, "type": "SCALAR"}],
        "meshes": [{"primitives": [{"attributes": {"POSITION": 0}, "indices": 1}]}],
        "scene": 0,
    }
    if shape == "chain":
        doc["nodes"] = [{"children": [i + 1], "translation": [1.0, 0.5, 0.0]} for i in range(n - 1)]
        doc["nodes"].append({"mesh": 0, "translation": [1.0, 0.5, 0.0]})
        doc["scenes"] = [{"nodes": [0]}]
    else:
        doc["nodes"] = [{"mesh": 0, "translation": [1.0, 0.5, 0.0]} for _ in range(n)]
        doc["scenes"] = [{"nodes": list(range(n))}]
    return doc


def glb(doc: dict) -> bytes:
    """`doc` as a GLB with the quad in its BIN chunk."""
    text = json.dumps(doc).encode()
    text += b" " * (-len(text) % 4)
    blob = POSITIONS + INDICES
    blob += bytes(-len(blob) % 4)
    chunks = struct.pack("<II", len(text), 0x4E4F534A) + text + struct.pack("<II", len(blob), 0x004E4942) + blob
    return struct.pack("<4sII", b"glTF", 2, 12 + len(chunks)) + chunks


def timed(call) -> tuple[float, object]:
    start = time.perf_counter()
    result = call()
    return time.perf_counter() - start, result


# the fallback only, small atlases: what is left grows with the node count
FAST_CONFIG = """\
[defaults]
material = "marble"
techniques = []
atlas_resolution = 64
"""


def bake(path: Path, out: Path) -> str:
    """`sssbake bake` of one document: what the line of `--bake` says after the document's name."""
    config = path.with_suffix(".toml")
    config.write_text(FAST_CONFIG)
    elapsed, code = timed(lambda: sssbake(["bake", str(path), "-o", str(out), "--config", str(config), "--no-cache",
                                           "-q"]))
    assert code == 0, f"sssbake bake {path} exited {code}"
    stages = json.loads((out / f"{path.stem}.report.json").read_text())["stages"]
    stage = Usd.Stage.Open(str(out / f"{path.stem}.usdc"))
    # levels of node Xforms under the root prim (the root is element 1 of a path)
    depth = max(p.GetPath().pathElementCount - 1 for p in stage.Traverse() if p.IsA(UsdGeom.Xform))
    seconds = ", ".join(f"{name} {stages[name]['seconds']:6.2f} s" for name in
                        ("load", "export_gltf", "export_usd", "validate"))
    return f"bake {elapsed:7.2f} s ({seconds}), .usdc {depth} node levels"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--sizes", default="2000,8000,100000", help="node counts (comma-separated)")
    parser.add_argument("--pygltflib", type=int, default=0, metavar="N",
                        help="also time pygltflib's decoding of documents of up to N nodes (default: none)")
    parser.add_argument("--bake", default="", metavar="SIZES",
                        help="also bake the documents of these node counts (comma-separated; default: none)")
    args = parser.parse_args()
    with tempfile.TemporaryDirectory(prefix="sssbake-bench-gltf-") as tmp:
        for shape in ("chain", "wide"):
            for n in (int(s) for s in args.sizes.split(",")):
                doc = document(shape, n)
                path = Path(tmp, f"{shape}{n}.glb")
                path.write_bytes(glb(doc))
                load, scene = timed(lambda: load_scene(path))
                worlds, instances = timed(lambda: scene.mesh_instances()[0])
                tables, _ = timed(lambda: load_sssbake_gltf(path))
                # the chain's leaf sits at n translations; the wide scene's nodes at one each
                expected = np.array([1.0, 0.5, 0.0]) * (n if shape == "chain" else 1)
                assert len(instances) == (1 if shape == "chain" else n) and np.allclose(instances[-1][:3, 3], expected)
                line = (f"{shape:>5} {n:>7} nodes, JSON {path.stat().st_size / 1e6:6.2f} MB: load_scene {load:7.2f} s "
                        f"(+ world transforms {worlds:5.2f} s), load_sssbake_gltf {tables:6.2f} s")
                if n <= args.pygltflib:
                    import pygltflib

                    text = json.dumps(doc)
                    before, _ = timed(lambda: pygltflib.GLTF2.gltf_from_json(text))
                    line += f"; pygltflib's decoding {before:7.2f} s"
                print(line, flush=True)
            for n in (int(s) for s in args.bake.split(",") if s):
                path = Path(tmp, f"{shape}{n}.glb")
                path.write_bytes(glb(document(shape, n)))
                print(f"{shape:>5} {n:>7} nodes: {bake(path, Path(tmp, f'out_{shape}{n}'))}", flush=True)


if __name__ == "__main__":
    main()
