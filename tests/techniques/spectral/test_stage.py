"""The spectral stage: the precompute's normals, a JSON report with bytes per block, and export
tables that hold the spectrum exactly enough to filter again."""

import json

import numpy as np
import pytest
import trimesh

from sssbake.pipeline.core.materials import preset
from sssbake.pipeline.mesh.clean import weld_surface
from sssbake.pipeline.mesh.scene import Primitive
from sssbake.pipeline.techniques.spectral.normals import NormalSpectrum
from sssbake.pipeline.techniques.spectral.precompute import SpectralPrecomputeOptions, precompute_spectral
from sssbake.pipeline.techniques.spectral.stage import bake_spectral

OPTIONS = SpectralPrecomputeOptions(eigenpairs=30)


@pytest.fixture(scope="module")
def surface():
    mesh = trimesh.creation.icosphere(subdivisions=2, radius=5.0)
    prim = Primitive(np.asarray(mesh.vertices, float), np.asarray(mesh.faces, np.int64),
                     normals=np.asarray(mesh.vertex_normals, float), uvs=(), material=None)
    return weld_surface([prim], 1e-9)


def test_normals_and_report_are_the_precompute_s(surface):
    pre = precompute_spectral(surface, 2.0, preset("skin1"), OPTIONS)
    baked = bake_spectral(surface, 2.0, preset("skin1"), OPTIONS)
    np.testing.assert_array_equal(baked.normals, pre.normals)
    assert baked.tables is None
    report = json.loads(json.dumps(baked.report))  # JSON as it is: no numpy scalars
    assert report == baked.report
    assert report["eigenpairs"] == 30 and report["width_mm"] is None and report["basis"] is False
    assert report["widthMm"] == pytest.approx(pre.width_mm) and report["gamma"] == pytest.approx(pre.gamma)
    assert set(report["seconds"]) == set(pre.seconds) | {"total"}
    assert report["bytes"]["total"] == 0 and report["bytes"]["normalPerRenderVertex"] == 12
    assert report["bytes"]["vertexIdsPerRenderVertex"] == 0


def test_tables_hold_the_spectrum(surface):
    baked = bake_spectral(surface, 2.0, preset("skin1"), OPTIONS, with_basis=True)
    t = baked.tables
    n, m = len(surface.positions), t["eigenpairs"]
    assert t["technique"] == "spectral" and t["vertexCount"] == n and m == 30
    assert t["attributes"] == {"normal": "_SSS_NORMAL", "vertex": "_SSS_SPECTRAL_VERTEX"}
    shapes = {k: v.shape for k, v in t.items() if isinstance(v, np.ndarray)}
    assert shapes == {"values": (m,), "coefficients": (m, 3), "residual": (n, 3), "basis": (n * m,)}
    assert all(v.dtype == np.float32 for k, v in t.items() if k in shapes)
    assert np.all(np.diff(t["values"]) >= 0) and t["nyquist"] > 0
    basis = t["basis"].reshape(n, m).astype(np.float64)
    original = basis @ t["coefficients"] + t["residual"]
    np.testing.assert_allclose(original, surface.normals, atol=2e-6)
    # the tables filter to the baked normals again (float32 rounding aside)
    spectrum = NormalSpectrum(t["values"].astype(np.float64), t["nyquist"], t["coefficients"].astype(np.float64),
                              t["residual"].astype(np.float64), basis, original)
    normals, gamma = spectrum.filtered(t["widthMm"])
    assert gamma == pytest.approx(t["gamma"], rel=1e-6)
    np.testing.assert_allclose(normals, baked.normals, atol=1e-5)
    sizes = baked.report["bytes"]
    assert {k: sizes[k] for k in shapes} == {k: t[k].nbytes for k in shapes}
    assert sizes["total"] == sum(t[k].nbytes for k in shapes) and sizes["perVertex"] == sizes["total"] / n
    assert sizes["vertexIdsPerRenderVertex"] == 12


def test_bad_options_are_refused(surface):
    with pytest.raises(ValueError, match="eigenpairs"):
        bake_spectral(surface, 2.0, preset("skin1"), SpectralPrecomputeOptions(eigenpairs=0))
