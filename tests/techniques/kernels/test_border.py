"""Border texels: the surface across a seam lands in the gutter, next to the seam, in the chart's
own frame; the atlas-to-surface map finds the seam edges."""

import numpy as np
from kernels_planes import flat_surface, split_atlas

from sssbake.pipeline.mesh.atlas_surface import atlas_surface
from sssbake.pipeline.mesh.texels import rasterize_atlas
from sssbake.pipeline.techniques.kernels import border
from sssbake.pipeline.techniques.kernels.border import border_texels


def test_seam_edges_are_the_cut_and_borders_mirror_the_other_half():
    s = flat_surface(1.0, 8)
    atlas = split_atlas(s, 96, gap=12)
    layout = atlas_surface(atlas, s)
    assert layout.face_chart.max() == 1
    seam = layout.seam(np.arange(len(s.faces)))
    f, k = np.nonzero(seam)
    a, b = s.faces[f, k], s.faces[f, (k + 1) % 3]
    assert np.all(np.abs(s.positions[a, 0]) < 1e-9) and np.all(np.abs(s.positions[b, 0]) < 1e-9)
    assert len(f) == 2 * 16  # 16 edges along the cut, seen from both sides

    part = atlas.parts[0]
    tx = rasterize_atlas([(part.uvs, part.faces, s.positions[part.vmapping], s.normals[part.vmapping])],
                         atlas.width, atlas.height)
    face = layout.part_face_offset[tx.part] + tx.face
    reach = 4
    border = border_texels(layout, s, tx.rows * atlas.width + tx.cols, layout.face_chart[face], reach)
    assert len(border.pixels) > 0
    point = np.einsum("bk,bkd->bd", border.barycentric, s.positions[s.faces[border.faces]])
    left = border.chart == layout.face_chart[np.flatnonzero(s.positions[s.faces][:, :, 0].mean(axis=1) < 0)[0]]
    # the left chart's border holds the right half's surface and vice versa, within reach of the cut
    texel = 16.0 / (96 - 12 - 12)  # mm per texel of split_atlas
    assert np.all(point[left, 0] > 0) and np.all(point[~left, 0] < 0)
    assert np.all(np.abs(point[:, 0]) <= (reach + 1) * texel)
    # and where it lies in the atlas matches the surface distance from the seam
    col = border.pixels % atlas.width + 0.5
    seam_col = np.where(left, 6 + 8.0 / texel, 6 + 12 + 8.0 / texel)  # u of x = 0 in each chart
    np.testing.assert_allclose(np.abs(col - seam_col) * texel, np.abs(point[:, 0]), atol=0.6 * texel)


def test_rasterising_in_batches_gives_what_one_rasterisation_gives(monkeypatch):
    # Small batches, so that triangles of different batches claim the same texels (a centre on a
    # shared edge, overlapping unfolded rings): the earlier triangle must keep it, as in one pass.
    s = flat_surface(0.5, 16)
    atlas = split_atlas(s, 96, gap=12)
    layout = atlas_surface(atlas, s)
    part = atlas.parts[0]
    tx = rasterize_atlas([(part.uvs, part.faces, s.positions[part.vmapping], s.normals[part.vmapping])],
                         atlas.width, atlas.height)
    args = (layout, s, tx.rows * atlas.width + tx.cols, layout.face_chart[layout.part_face_offset[tx.part] + tx.face], 4)
    whole = border_texels(*args)
    claimed = []

    def counted(*a, **k):
        out = rasterize_atlas(*a, **k)
        claimed.append(len(out.rows))
        return out

    monkeypatch.setattr(border, "BATCH", 7)
    monkeypatch.setattr(border, "rasterize_atlas", counted)
    batched = border_texels(*args)
    assert len(claimed) > 10 and sum(claimed) > len(batched.pixels)  # batches did compete for texels
    for name in ("pixels", "faces", "barycentric", "chart", "areas"):
        np.testing.assert_array_equal(getattr(batched, name), getattr(whole, name))
    assert batched.triangles == whole.triangles
