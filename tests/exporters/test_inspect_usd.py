"""inspect_usdc: the sssbake content of a .usdc, with bytes per vertex."""


import pytest
from test_usd import icosphere_asset

from sssbake.exporters.inspect_usd import inspect_usdc
from sssbake.exporters.usd import write_usdc
from sssbake.pipeline.mesh.baked import SCHEMA_VERSION


def test_inspect_our_output(tmp_path):
    write_usdc(icosphere_asset(), tmp_path / "ico.usdc")
    info = inspect_usdc(tmp_path / "ico.usdc")
    assert info["schemaVersion"] == SCHEMA_VERSION and info["defaultPrim"] == "/ico"
    assert info["creator"].startswith("sssbake ") and info["upAxis"] == "Y" and info["metersPerUnit"] == 0.01
    assert info["extras"] == {"scaleSource": "test", "thickness": {"unit": "mm"}}
    assert info["bytes"] == (tmp_path / "ico.usdc").stat().st_size

    sphere, plate = info["meshes"]
    n = 42
    assert sphere["path"] == "/ico/root/sphere" and sphere["vertices"] == n and sphere["faces"] == 80
    assert sphere["scaleMm"] == 10.0 and sphere["material"] == "/ico/Materials/Marble"
    thickness = sphere["primvars"]["primvars:sss:thickness"]
    assert thickness == {"type": "float[]", "interpolation": "vertex", "elementSize": 1, "count": n, "bytes": 4 * n,
                         "bytesPerVertex": 4.0, "unit": "mm", "description": "thickness along -n",
                         "encoding": "float32", "components": 1, "packedBits": None}
    direction = sphere["primvars"]["primvars:sss:direction"]  # snorm8 x 3 packed into one int
    assert direction["type"] == "int[]" and direction["elementSize"] == 1 and direction["count"] == n
    assert direction["bytesPerVertex"] == 4.0 and direction["packedBits"] == 8 and direction["components"] == 3
    assert sphere["bytesPerVertex"] == 8.0
    assert plate["primvars"] == {} and plate["material"] == "/ico/Materials/Steel"
    assert info["bytesPerVertex"] == {"primvars:sss:thickness": 4.0, "primvars:sss:direction": 4.0,
                                      "total": pytest.approx(8 * n / (n + 3))}

    (marble,) = info["materials"]
    assert marble["path"] == "/ico/Materials/Marble"
    sss = marble["sss"]
    assert sss["schemaVersion"] == SCHEMA_VERSION and sss["units"] == "1/mm" and sss["materialName"] == "marble"
    assert sss["sigmaSPrime"] == [2.19, 2.62, 3.0] and sss["sigmaA"] == [0.0021, 0.0041, 0.0071]
    assert sss["fallback:attenuationColor"] == [0.9, 0.8, 0.7] and sss["fallback:thicknessFactor"] == 2.0


def test_inspect_plain_usd_without_sssbake_data(tmp_path):
    path = tmp_path / "plain.usda"
    path.write_text('#usda 1.0\ndef Mesh "M"\n{\n    point3f[] points = [(0, 0, 0), (1, 0, 0), (0, 1, 0)]\n'
                    '    int[] faceVertexCounts = [3]\n    int[] faceVertexIndices = [0, 1, 2]\n}\n')
    info = inspect_usdc(path)
    assert info["schemaVersion"] is None and info["extras"] is None and info["materials"] == []
    assert info["meshes"][0]["primvars"] == {} and info["bytesPerVertex"] == {"total": 0.0}
