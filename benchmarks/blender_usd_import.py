"""Which sssbake primvars survive Blender's USD importer, with which values.

    python benchmarks/blender_usd_import.py OUT/*.usdc [--python BPY_PYTHON]

Imports each .usdc with ``bpy.ops.wm.usd_import`` (Blender as a Python module, ``bpy`` from PyPI)
in a fresh process, reads every ``sss:`` attribute back from ``mesh.attributes`` and compares it
with what the file holds (`exporters.usd.primvar_values`, the values a glTF reader gets; packed
codes as the int the file holds, which `primvar_values` would unpack). Prints one
row per (file, mesh, primvar): its USD type, the Blender type it became, and ``exact``, ``lost``
or the largest absolute error.

``--python`` (default: ``$SSSBAKE_BPY_PYTHON``, else the repository's ``.bpy/bin/python``, as
`blender_import.py` sets it up) names the bpy interpreter. The Blender side (`dump`) needs bpy
alone, no numpy (bpy 4.5 is built against numpy 1.x).
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np

#: Blender attribute type -> (foreach_get property, components).
_BLENDER_TYPES = {"FLOAT": ("value", 1), "INT": ("value", 1), "INT8": ("value", 1), "FLOAT2": ("vector", 2),
                  "FLOAT_VECTOR": ("vector", 3), "FLOAT_COLOR": ("color", 4), "BYTE_COLOR": ("color", 4),
                  "QUATERNION": ("value", 4)}


def dump(usdc: str, out: str) -> None:
    """(Runs under bpy.) Import `usdc` into an empty scene and write every ``sss:`` attribute of every
    mesh to `out` (JSON: [{object, attribute, type, domain, components, values (flat), corners (the
    point of each corner, for CORNER-domain attributes: Blender makes float2[] primvars UV maps)}])."""
    import bpy

    bpy.ops.wm.read_factory_settings(use_empty=True)
    bpy.ops.wm.usd_import(filepath=usdc)
    rows = []
    for obj in bpy.data.objects:
        if obj.type != "MESH":
            continue
        for attribute in obj.data.attributes:
            if not attribute.name.startswith("sss:") or attribute.data_type not in _BLENDER_TYPES:
                continue
            prop, k = _BLENDER_TYPES[attribute.data_type]
            values = [0.0] * (len(attribute.data) * k)
            attribute.data.foreach_get(prop, values)
            corners = [0] * len(obj.data.loops)
            obj.data.loops.foreach_get("vertex_index", corners)
            rows.append({"object": obj.name, "attribute": attribute.name, "type": attribute.data_type,
                         "domain": attribute.domain, "components": k, "values": values,
                         "corners": corners if attribute.domain == "CORNER" else None})
    Path(out).write_text(json.dumps(rows))


def compare(usdc: Path, python: str) -> list[dict]:
    """One row per sss primvar of each Mesh prim: ``mesh``, ``primvar``, ``usdType``, ``blender``
    (type or None), ``result`` (``exact``, ``lost``, ``wrong`` and ``maxError``)."""
    from pxr import Usd, UsdGeom

    from sssbake.exporters.usd import primvar_values

    with tempfile.TemporaryDirectory() as tmp:
        out = Path(tmp) / "dump.json"
        subprocess.run([python, __file__, "--dump", str(usdc), str(out)], check=True, capture_output=True)
        dumped = json.loads(out.read_text())
    stage = Usd.Stage.Open(str(usdc))
    rows = []
    for prim in stage.Traverse():
        if not prim.IsA(UsdGeom.Mesh):
            continue
        for primvar in UsdGeom.PrimvarsAPI(prim).GetPrimvarsWithAuthoredValues():
            name = primvar.GetPrimvarName()
            if not name.startswith("sss:"):
                continue
            # packed codes are compared as the int Blender holds; everything else as decoded values
            packed = "packedBits" in primvar.GetAttr().GetCustomData()
            want = np.asarray(primvar.Get(), dtype=np.float64)[:, None] if packed else primvar_values(primvar)
            # Blender names an object after the Xform above a single mesh, or after the mesh itself
            found = [d for d in dumped if d["attribute"] == name and d["object"] in (prim.GetName(),
                                                                                     prim.GetParent().GetName())]
            row = {"file": usdc.name, "mesh": str(prim.GetPath()), "primvar": name,
                   "usdType": str(primvar.GetTypeName()), "blender": found[0]["type"] if found else None}
            if not found:
                row["result"] = "lost"
            else:
                d = found[0]
                got = np.asarray(d["values"], dtype=np.float64).reshape(-1, d["components"])[:, :want.shape[1]]
                if d["type"] == "INT8":  # Blender's int8 holds uchar[] bytes as signed
                    got %= 256
                expected = want[d["corners"]] if d["corners"] is not None else want
                error = float(np.abs(got - expected).max()) if want.size and len(got) == len(expected) else np.inf
                row["blender"] += f"/{d['domain']}"
                row["result"], row["maxError"] = ("exact" if error == 0.0 else "wrong"), error
            rows.append(row)
    return rows


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("files", nargs="*", type=Path)
    parser.add_argument("--python", default=None, help="the bpy interpreter")
    parser.add_argument("--dump", nargs=2, metavar=("USDC", "OUT"), help=argparse.SUPPRESS)
    args = parser.parse_args(argv)
    if args.dump:
        dump(*args.dump)
        return 0
    sys.path.insert(0, str(Path(__file__).resolve().parent))
    from blender_import import default_python

    python = args.python or default_python()
    if python is None:
        print("no bpy interpreter: pass --python or set SSSBAKE_BPY_PYTHON", file=sys.stderr)
        return 2
    bad = 0
    for usdc in args.files:
        for row in compare(usdc, python):
            bad += row["result"] != "exact"
            error = f"  max error {row['maxError']:.3g}" if row["result"] == "wrong" else ""
            print(f"{row['file']:20s} {row['mesh']:40s} {row['primvar']:24s} {row['usdType']:10s} "
                  f"-> {str(row['blender']):13s} {row['result']}{error}")
    return 1 if bad else 0


if __name__ == "__main__":
    sys.exit(main())
