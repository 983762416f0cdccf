import resource

import numpy as np
import pytest
import trimesh
import xatlas

from sssbake.pipeline.mesh.atlas import BLOCK, DIAGONAL, AtlasError, compute_atlas
from sssbake.pipeline.mesh.atlas_worker import CRASH_ENV


@pytest.fixture(scope="module")
def parts():
    sphere = trimesh.creation.icosphere(2)
    box = trimesh.creation.box(extents=(1.0, 2.0, 0.5))
    return [
        (np.asarray(sphere.vertices), np.asarray(sphere.faces, dtype=np.int64)),
        (np.asarray(box.vertices) + 3.0, np.asarray(box.faces, dtype=np.int64)),
    ]


@pytest.fixture(scope="module")
def atlas(parts):
    return compute_atlas(parts, resolution=128, padding=2)


def test_parts_index_back_into_their_input(parts, atlas):
    assert len(atlas.parts) == 2
    for (positions, faces), part in zip(parts, atlas.parts):
        assert part.vmapping.dtype == np.int64 and part.faces.dtype == np.int64
        assert part.uvs.dtype == np.float64 and part.uvs.shape == (len(part.vmapping), 2)
        assert part.vmapping.min() >= 0 and part.vmapping.max() < len(positions)
        # Same triangles, same order: only seam vertices are duplicated.
        np.testing.assert_array_equal(part.vmapping[part.faces], faces)


def test_uvs_in_unit_square_and_size(atlas):
    for part in atlas.parts:
        assert part.uvs.min() >= 0.0 and part.uvs.max() <= 1.0
    assert atlas.width > 0 and atlas.height > 0
    assert atlas.chart_count >= 2 and not atlas.jittered


def test_worker_reports_its_own_peak_memory(atlas):
    # A Python child with numpy and xatlas loaded holds tens of MB, far below the parent's pages.
    parent_mb = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0
    assert 10.0 < atlas.worker_peak_rss_mb < max(parent_mb, 200.0)


def test_matches_xatlas_in_process(parts, atlas):
    # xatlas sees the mesh centred and scaled to a diagonal of DIAGONAL
    everything = np.concatenate([p for p, _ in parts])
    lo, hi = everything.min(axis=0), everything.max(axis=0)
    reference = xatlas.Atlas()
    for positions, faces in parts:
        normalised = (positions - (lo + hi) / 2) * (DIAGONAL / np.linalg.norm(hi - lo))
        reference.add_mesh(normalised.astype(np.float32), faces.astype(np.uint32))
    pack = xatlas.PackOptions()
    pack.resolution, pack.padding = 128, 2
    reference.generate(xatlas.ChartOptions(), pack)
    # xatlas' size rounded up to whole 4x4 blocks (154 x 154 here: not a multiple of 4 on its own)
    size = np.array([reference.width, reference.height])
    assert np.any(size % BLOCK) and (atlas.width, atlas.height) == tuple(-(-size // BLOCK) * BLOCK)
    for i, part in enumerate(atlas.parts):
        vmapping, _, uvs = reference[i]
        np.testing.assert_array_equal(part.vmapping, vmapping)
        # the same texel positions: uv · size in xatlas' atlas, in the padded one alike
        np.testing.assert_allclose(part.uvs * [atlas.width, atlas.height], uvs * size, rtol=0, atol=1e-9)


@pytest.mark.parametrize("size", [1e-9, 1e12, 1e30])
def test_the_atlas_is_the_same_at_any_size(parts, atlas, size):
    # before charting a normalised copy, a 1e-9 mesh got a 0 x 0 atlas and a 1e12 one never finished
    scaled = compute_atlas([(p * size, f) for p, f in parts], resolution=128, padding=2, timeout_s=60)
    assert (scaled.width, scaled.height, scaled.chart_count) == (atlas.width, atlas.height, atlas.chart_count)
    for part, reference in zip(scaled.parts, atlas.parts):
        np.testing.assert_array_equal(part.vmapping, reference.vmapping)
        np.testing.assert_allclose(part.uvs, reference.uvs, atol=1e-6)


def test_a_mesh_without_extent_is_refused(parts):
    positions, faces = parts[0]
    with pytest.raises(AtlasError, match=r"^atlas: the mesh's bounding-box diagonal is 0; it must be finite and > 0"):
        compute_atlas([(np.zeros_like(positions), faces)], resolution=64, padding=2)


def test_crash_is_retried_with_jitter(parts, monkeypatch):
    monkeypatch.setenv(CRASH_ENV, "1")
    retried = compute_atlas(parts[:1], resolution=64, padding=2)
    assert retried.jittered
    positions, faces = parts[0]
    np.testing.assert_array_equal(retried.parts[0].vmapping[retried.parts[0].faces], faces)


def test_two_crashes_raise_a_clear_error(parts, monkeypatch):
    monkeypatch.setenv(CRASH_ENV, "2")
    with pytest.raises(AtlasError, match=r"atlas: xatlas crashed twice on this mesh \(signal 11, SIGSEGV"):
        compute_atlas(parts[:1], resolution=64, padding=2)


def test_timeout_raises():
    sphere = trimesh.creation.icosphere(3)
    with pytest.raises(AtlasError, match="ran longer than"):
        compute_atlas([(sphere.vertices, sphere.faces)], timeout_s=0.01)


def test_bad_input_raises(parts):
    positions, faces = parts[0]
    with pytest.raises(ValueError, match="no parts"):
        compute_atlas([])
    with pytest.raises(AtlasError, match="part 0 face indices"):
        compute_atlas([(positions, faces + len(positions))])
    with pytest.raises(AtlasError, match="part 0 faces"):
        compute_atlas([(positions, faces[:0])])


def test_worker_error_is_reported(parts, monkeypatch):
    # A malformed hook value makes the worker exit with a Python error instead of a signal.
    monkeypatch.setenv(CRASH_ENV, "not-a-number")
    with pytest.raises(AtlasError, match=r"atlas: xatlas failed \(ValueError"):
        compute_atlas(parts[:1], resolution=64, padding=2)


def _covered_twice(part, width: int, height: int, samples: int = 4) -> int:
    """Sample points (`samples`² per texel) that lie strictly inside two or more UV triangles."""
    count = np.zeros((height * samples, width * samples), dtype=np.int32)
    corners = part.uvs[part.faces] * [width * samples, height * samples]  # (m, 3, 2) in sample units
    for tri in corners:
        (x0, y0), (x1, y1) = np.floor(tri.min(axis=0)).astype(int), np.ceil(tri.max(axis=0)).astype(int)
        xs, ys = np.meshgrid(np.arange(x0, x1) + 0.5, np.arange(y0, y1) + 0.5)
        a, b, c = tri
        d = [(q[0] - p[0]) * (ys - p[1]) - (q[1] - p[1]) * (xs - p[0]) for p, q in ((a, b), (b, c), (c, a))]
        inside = ((d[0] > 1e-9) & (d[1] > 1e-9) & (d[2] > 1e-9)) | ((d[0] < -1e-9) & (d[1] < -1e-9) & (d[2] < -1e-9))
        count[y0:y1, x0:x1] += inside
    return int((count > 1).sum())


def test_a_large_part_is_charted_in_pieces_into_one_atlas():
    sphere = trimesh.creation.icosphere(4)  # 5120 triangles: six pieces of at most 1000
    positions, faces = np.asarray(sphere.vertices), np.asarray(sphere.faces, dtype=np.int64)
    whole = compute_atlas([(positions, faces)], resolution=256, padding=2)
    cut = compute_atlas([(positions, faces)], resolution=256, padding=2, piece_faces=1000)
    part = cut.parts[0]
    # the same triangles in the same order, on vertices that copy the input's
    np.testing.assert_array_equal(part.vmapping[part.faces], faces)
    assert part.uvs.min() >= 0.0 and part.uvs.max() <= 1.0
    # a piece's border is a seam: more atlas vertices and at least one chart per piece
    assert cut.chart_count >= 6 and len(part.vmapping) > len(whole.parts[0].vmapping)
    # every triangle keeps its area in the atlas (no collapsed chart) and no two charts overlap
    uv = part.uvs[part.faces] * [cut.width, cut.height]
    e1, e2 = uv[:, 1] - uv[:, 0], uv[:, 2] - uv[:, 0]
    area = 0.5 * np.abs(e1[:, 0] * e2[:, 1] - e1[:, 1] * e2[:, 0])
    assert area.min() > 0.0
    assert _covered_twice(part, cut.width, cut.height) == 0 and _covered_twice(whole.parts[0], whole.width,
                                                                               whole.height) == 0
