"""Which sssbake vertex attributes survive Blender's glTF importer, with which values.

    python benchmarks/blender_import.py OUT/*.glb [--python BPY_PYTHON] [--seeds 0-5]
    python benchmarks/blender_import.py --encodings [--python BPY_PYTHON] [--seeds 0-5]

Imports each .glb with ``bpy.ops.import_scene.gltf`` (Blender as a Python module, ``bpy`` from
PyPI) in a fresh process per ``PYTHONHASHSEED`` (the importer keeps custom attributes in a Python
``set``, so what it does can change with the seed), reads every ``_`` attribute back from
``mesh.attributes`` and compares it with the values the file holds (glTF's dequantisation:
normalized integers as code / MAX). Prints one row per (file, attribute): encoding, the Blender
type it became, whether it was kept with exact values under every seed, the largest absolute
error, and per seed ``ok`` / ``lost`` / ``wrong`` / ``crash``. ``--encodings`` surveys instead a
file written for the purpose (`encodings_asset`): every encoding sssbake's glTF writer offers at
every width, one attribute per mesh, and one mesh with two float attributes of different widths.

``bpy`` 4.5 is built against numpy 1.x, so it lives in its own virtual environment:
``python3 -m venv .bpy && .bpy/bin/pip install 'numpy<2' bpy==4.5.15``; ``--python`` (default:
``$SSSBAKE_BPY_PYTHON``, else ``.bpy/bin/python``) names its interpreter. The Blender side
(`dump`) imports only bpy and numpy; the comparison runs here with pygltflib.
"""

from __future__ import annotations

import argparse
import json
import os
import re
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np

#: Blender attribute type -> (foreach_get property, components, numpy dtype).
_BLENDER_TYPES = {
    "FLOAT": ("value", 1, np.float32), "INT": ("value", 1, np.int32), "INT8": ("value", 1, np.int32),
    "FLOAT2": ("vector", 2, np.float32), "INT32_2D": ("value", 2, np.int32),
    "FLOAT_VECTOR": ("vector", 3, np.float32), "FLOAT_COLOR": ("color", 4, np.float32),
    "BYTE_COLOR": ("color", 4, np.float32), "QUATERNION": ("value", 4, np.float32),
    "FLOAT4X4": ("value", 16, np.float32),
}
_COMPONENTS = {"SCALAR": 1, "VEC2": 2, "VEC3": 3, "VEC4": 4}
_COMPONENT_NAMES = {5120: "int8", 5121: "uint8", 5122: "int16", 5123: "uint16", 5125: "uint32", 5126: "float32"}


def default_python() -> str | None:
    """The bpy interpreter: ``$SSSBAKE_BPY_PYTHON``, else the repository's ``.bpy/bin/python``,
    else None."""
    env = os.environ.get("SSSBAKE_BPY_PYTHON")
    if env:
        return env
    local = Path(__file__).resolve().parent.parent / ".bpy" / "bin" / "python"
    return str(local) if local.exists() else None


def dump(glb: str, out: str) -> None:
    """(Runs under bpy.) Import `glb` into an empty scene and save every ``_`` attribute of every
    mesh to `out` (.npz: ``a<i>`` arrays (n, k), ``meta`` JSON [mesh, attribute, type, domain])."""
    import bpy

    bpy.ops.wm.read_factory_settings(use_empty=True)
    bpy.ops.import_scene.gltf(filepath=glb)
    meta, arrays = [], {}
    for mesh in bpy.data.meshes:
        for attr in mesh.attributes:
            if not attr.name.startswith("_"):
                continue
            prop, k, dtype = _BLENDER_TYPES[attr.data_type]
            values = np.empty(len(attr.data) * k, dtype=dtype)
            attr.data.foreach_get(prop, values)
            arrays[f"a{len(meta)}"] = values.reshape(-1, k)
            meta.append([mesh.name, attr.name, attr.data_type, attr.domain])
    np.savez(out, meta=np.array(json.dumps(meta)), **arrays)


def blender_attributes(glb: Path, python: str, seed: int, timeout_s: float = 300.0) -> dict | str:
    """What Blender imported from `glb` under ``PYTHONHASHSEED=seed``.

    Returns
    -------
    dict or str
        ``(mesh name, attribute) -> (blender type, domain, (n, k) values)``, or the last line of
        the importer's error when it failed.
    """
    with tempfile.TemporaryDirectory() as tmp:
        out = Path(tmp) / "attrs.npz"
        code = f"import sys; sys.path.insert(0, {str(Path(__file__).parent)!r}); import blender_import; " \
               f"blender_import.dump({str(glb)!r}, {str(out)!r})"
        env = {**os.environ, "PYTHONHASHSEED": str(seed)}
        run = subprocess.run([python, "-c", code], env=env, capture_output=True, text=True, timeout=timeout_s)
        if run.returncode != 0 or not out.exists():
            lines = [line for line in (run.stderr + run.stdout).splitlines() if line.strip()]
            # Blender wraps the importer's exception in "Error: Python: Traceback ..." lines
            errors = [line for line in lines if re.match(r"\w+(Error|Exception): (?!Error: Python)", line)]
            return (errors or lines or [f"exit status {run.returncode}"])[-1]
        with np.load(out) as data:
            meta = json.loads(str(data["meta"]))
            return {(m, a): (t, d, data[f"a{i}"]) for i, (m, a, t, d) in enumerate(meta)}


def expected_attributes(glb: Path) -> dict:
    """What an exact importer gives for every ``_`` attribute of `glb`, in Blender's vertex order.

    Blender's importer (merge_vertices off) makes one mesh per glTF mesh, with each primitive's
    vertices that faces use (``np.unique`` of its indices) in turn, and zeros for a primitive
    without an attribute another primitive has.

    Returns
    -------
    dict
        ``(glTF mesh name, attribute) -> (encoding, (n, k) float64 values)``; the encoding as
        ``"<type> <component>[ normalized]"``.
    """
    import pygltflib

    from sssbake.exporters.gltf import dequantize, read_accessor

    gltf = pygltflib.GLTF2().load(str(glb))
    blob = gltf.binary_blob()
    out = {}
    for mi, mesh in enumerate(gltf.meshes):
        name = mesh.name or f"Mesh_{mi}"
        prims = [p for p in mesh.primitives if p.attributes.POSITION is not None]
        # pygltflib keeps attributes it does not know as plain instance attributes
        attrs = {k: v for p in prims for k, v in vars(p.attributes).items() if k.startswith("_") and v is not None}
        for attr, first in attrs.items():
            acc = gltf.accessors[first]
            k = _COMPONENTS[acc.type]
            parts = []
            for p in prims:
                used = np.unique(read_accessor(gltf, p.indices, blob).reshape(-1))
                index = getattr(p.attributes, attr, None)
                if index is None:
                    parts.append(np.zeros((len(used), k)))
                else:
                    a = gltf.accessors[index]
                    values = dequantize(read_accessor(gltf, index, blob), bool(a.normalized))
                    parts.append(values.reshape(-1, k)[used])
            encoding = f"{acc.type} {_COMPONENT_NAMES[acc.componentType]}{' normalized' if acc.normalized else ''}"
            out[(name, attr)] = (encoding, np.concatenate(parts))
    return out


def compare(expected: dict, imported: dict | str) -> dict:
    """Per (mesh, attribute) of `expected`: ``(status, blender type, max abs error)``, status
    ``ok`` (exact values), ``lost`` (absent), ``wrong`` (other values or shape), ``crash`` (the
    import failed)."""
    out = {}
    for key, (_, values) in expected.items():
        if isinstance(imported, str):
            out[key] = ("crash", "", np.inf)
            continue
        found = imported.get(key)
        if found is None:
            out[key] = ("lost", "", np.inf)
            continue
        kind, _, got = found
        if got.shape != values.shape:
            out[key] = ("wrong", kind, np.inf)
            continue
        # Blender stores float32: an exact importer gives the file's value rounded to float32.
        error = float(np.abs(got.astype(np.float64) - values.astype(np.float32)).max(initial=0.0))
        out[key] = ("ok" if error == 0.0 else "wrong", kind, error)
    return out


def survey(glbs: list[Path], python: str, seeds: list[int]) -> list[dict]:
    """One row per (file, mesh, attribute): ``file``, ``mesh``, ``attribute``, ``encoding``,
    ``blender`` (type it became), ``kept`` (exact under every seed), ``error`` (largest absolute
    error over the seeds; inf when lost), ``seeds`` (status per seed), ``crash`` (one failure
    message, or "")."""
    rows = []
    for glb in glbs:
        expected = expected_attributes(glb)
        results, crash = [], ""
        for seed in seeds:
            imported = blender_attributes(glb, python, seed)
            crash = crash or (imported if isinstance(imported, str) else "")
            results.append(compare(expected, imported))
        for key, (encoding, _) in expected.items():
            per_seed = [r[key] for r in results]
            rows.append({"file": glb.name, "mesh": key[0], "attribute": key[1], "encoding": encoding,
                         "blender": next((kind for _, kind, _ in per_seed if kind), "-"),
                         "kept": all(status == "ok" for status, _, _ in per_seed),
                         "error": max(error for _, _, error in per_seed),
                         "seeds": [status for status, _, _ in per_seed], "crash": crash})
    return rows


def encodings_assets() -> dict:
    """Name -> `BakedAsset`: per (encoding, width) of `exporters.gltf.ENCODINGS` x 1..4 an asset
    ``<encoding>x<width>`` whose one mesh has one attribute of that name (upper case, ``_``
    first) of values in the encoding's range (integers for the integer encodings); and
    ``mixed_widths``, one mesh with ``_A`` (float32 x 1) and ``_B`` (float32 x 3). What Blender's
    importer does with each encoding on its own (a file each: some crash the whole import), and
    with two widths."""
    from sssbake.exporters.gltf import ENCODINGS
    from sssbake.pipeline.mesh.baked import BakedAsset, VertexAttribute
    from sssbake.pipeline.mesh.scene import Mesh, Node, Primitive, Scene

    rng = np.random.default_rng(0)
    grid = np.arange(64.0)
    positions = np.column_stack([grid % 8, grid // 8, np.zeros(64)])
    cells = np.array([[i + 8 * j, i + 1 + 8 * j, i + 9 + 8 * j] for j in range(7) for i in range(7)])
    prim = Primitive(positions, cells, normals=np.tile([0.0, 0.0, 1.0], (64, 1)))
    out = {}
    for encoding, (_, dtype, normalized) in ENCODINGS.items():
        for width in range(1, 5):
            if normalized:
                low = -1.0 if np.iinfo(dtype).min < 0 else 0.0
                values = rng.integers(int(low) * np.iinfo(dtype).max, np.iinfo(dtype).max + 1, (64, width))
                values = values / np.iinfo(dtype).max
            elif np.dtype(dtype).kind == "u":
                values = rng.integers(0, np.iinfo(dtype).max + 1, (64, width)).astype(np.float64)
            else:
                values = rng.normal(0.0, 100.0, (64, width))
            out[f"{encoding}x{width}"] = (VertexAttribute(f"{encoding}x{width}", values, "", encoding),)
    out["mixed_widths"] = (VertexAttribute("a", rng.normal(size=64)), VertexAttribute("b", rng.normal(size=(64, 3))))
    scene = Scene("memory", (Mesh("m", (prim,)),), (Node("m", np.eye(4), mesh=0),), (0,))
    return {name: BakedAsset(scene, {(0, 0): attrs}) for name, attrs in out.items()}


def _seeds(text: str) -> list[int]:
    lo, _, hi = text.partition("-")
    return list(range(int(lo), int(hi or lo) + 1))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("glbs", nargs="*", type=Path)
    parser.add_argument("--encodings", action="store_true", help="survey every encoding (see above)")
    parser.add_argument("--python", default=default_python(), help="an interpreter that imports bpy")
    parser.add_argument("--seeds", default="0-5", help="PYTHONHASHSEED values, e.g. 0-5")
    parser.add_argument("--json", type=Path, help="also write the rows here")
    args = parser.parse_args()
    if not args.python:
        sys.exit("no bpy interpreter: pass --python or set SSSBAKE_BPY_PYTHON (see --help)")
    glbs = list(args.glbs)
    tmp = tempfile.TemporaryDirectory()
    if args.encodings:
        from sssbake.exporters.gltf import write_glb

        for name, asset in encodings_assets().items():
            glbs.append(Path(tmp.name) / f"{name}.glb")
            write_glb(asset, glbs[-1])
    rows = survey(glbs, args.python, _seeds(args.seeds))
    print(f"{'file':<16} {'mesh':<12} {'attribute':<22} {'encoding':<24} {'blender':<13} kept  "
          f"{'max abs error':>13}  per seed")
    for r in rows:
        print(f"{r['file']:<16} {r['mesh'][:12]:<12} {r['attribute']:<22} {r['encoding']:<24} {r['blender']:<13} "
              f"{'yes' if r['kept'] else 'NO':<5} {r['error']:>13.3g}  {' '.join(r['seeds'])}")
    for file, crash in sorted({(r["file"], r["crash"]) for r in rows if r["crash"]}):
        print(f"{file}: import failed: {crash}")
    if args.json:
        args.json.write_text(json.dumps(rows, indent=1, default=float))


if __name__ == "__main__":
    main()
