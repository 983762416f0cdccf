"""How `PrtData` is laid out in the exported files, and how it is read back.

Per render vertex (glTF attribute / USD primvar, from `VertexAttribute` keys), VEC3 float32 like
every sssbake attribute (`baked.ATTRIBUTE_WIDTH`: what Blender, Bevy and Godot keep exactly):

- ``sss:prt:ref`` → ``_SSS_PRT_REF`` / ``primvars:sss:prt:ref``: the vertex's reference triangle
  and the codes of w_0, w_1 (``w = weightScale · code / M``, M = 127 with ``weightBits`` 8, 32767
  with 16; w_2 = 1 - w_0 - w_1), all integers;
- ``sss:prt:dq<i>`` → ``_SSS_PRT_DQ<i>``, i < C = shOrder²: the Δq codes of SH coefficient i in
  R, G, B (integers in [-127, 127]; ``Δq_c,i = code · dqScale[i][c] / 127``).

Per mesh, under ``extras.sssbake.prt`` (glTF: accessors; USD: table attributes on the Mesh prim),
see `prt_tables`. Reading back (`prt_from_layout`) gives exactly the in-memory codes and tables.
"""

from __future__ import annotations

import numpy as np

from sssbake.pipeline.mesh.baked import ATTRIBUTE_WIDTH, FLOAT_INTEGERS, VertexAttribute, index_table
from sssbake.pipeline.techniques.prt.data import PrtData

REF_KEY, DQ_KEY = "sss:prt:ref", "sss:prt:dq"
#: The weight codes' M (``w = weightScale · code / M``) per ``weightBits``.
WEIGHT_MAX = {8: 127, 16: 32767}


def dq_attribute_count(sh_order: int) -> int:
    """How many attributes hold the 3·sh_order² Δq codes: one RGB triple per SH coefficient."""
    return sh_order * sh_order


def prt_vertex_attributes(prt: PrtData, vertices: np.ndarray) -> tuple[VertexAttribute, ...]:
    """The per-vertex attributes of one primitive.

    Parameters
    ----------
    prt : PrtData
        Over the mesh's welded surface vertices.
    vertices : (p,) int64
        The surface vertex of each render vertex of the primitive (``Surface.weld[j]``).

    Returns
    -------
    tuple of VertexAttribute
    """
    tri = prt.vertex_triangle[vertices].astype(np.float64)
    if len(tri) and tri.max() >= FLOAT_INTEGERS:
        raise ValueError(f"prt layout: float32 attributes address {FLOAT_INTEGERS} reference triangles at most")
    ref = np.column_stack([tri, prt.weight_codes[vertices].astype(np.float64)])
    m = WEIGHT_MAX[prt.weight_bits]
    out = [VertexAttribute(REF_KEY, ref, "", "float32", f"reference triangle of the vertex; codes of the weights "
                           f"w0, w1 (w = weightScale * code / {m}, w2 = 1 - w0 - w1)")]
    dq = prt.dq_codes[vertices].astype(np.float64)  # (p, 3, C)
    for i in range(prt.dq_codes.shape[2]):
        out.append(VertexAttribute(f"{DQ_KEY}{i}", dq[:, :, i], "", "float32",
                                   f"Δq codes of SH coefficient {i} in R, G, B (Δq = code * dqScale / 127)"))
    return tuple(out)


def detail_rows(prt: PrtData) -> np.ndarray:
    """(R, D + 3) int8: per reference point its detail colour codes, then its SH codes (the
    layout of ``refDetail`` and of the runtime's detail texture)."""
    return np.concatenate([prt.detail_colour, prt.detail_codes], axis=1).astype(np.int8)


def prt_tables(prt: PrtData) -> dict:
    """The per-mesh tables and parameters, JSON-able with numpy arrays for the binary tables."""
    k = len(prt.directions)
    channels = int(prt.ref_codes.shape[2])
    out = {
        "technique": "prt",
        "directionCount": k,
        "shOrder": int(prt.sh_order),
        "weightScale": float(prt.weight_scale),
        "weightBits": int(prt.weight_bits),
        "eta": float(prt.eta),
        "referencePointCount": int(len(prt.ref_codes)),
        "tableChannels": channels,
        "lookupSize": int(prt.direction_lookup.shape[0]),
        "directions": prt.directions.astype(np.float32),
        "directionTriangles": index_table(prt.direction_triangles),
        # Row-major 3x3 inverses, one VEC3 row per element: glTF MAT3 would mean column-major.
        "directionInverse": prt.direction_inverse.astype(np.float32).reshape(-1, 3),
        "directionLookup": index_table(prt.direction_lookup).reshape(-1),
        "directionNeighbours": index_table(prt.direction_neighbours),
        "lut": np.ascontiguousarray(prt.lut.T.astype(np.float32)),
        "attributes": {"ref": "_SSS_PRT_REF",
                       "dq": [f"_SSS_PRT_DQ{i}" for i in range(dq_attribute_count(prt.sh_order))]},
        "units": "q: radiance per unit irradiance (1/sr)",
    }
    if len(prt.ref_codes):
        out["refCodes"] = prt.ref_codes.reshape(-1, channels)
        out["refTriangles"] = index_table(prt.ref_triangles)
        if channels == 1:
            out["refScale"] = prt.ref_scale.astype(np.float32)
        if prt.detail_order:
            out["detailOrder"] = int(prt.detail_order)
            out["refDetail"] = detail_rows(prt).reshape(-1)
            out["detailScale"] = prt.detail_scale.astype(np.float32)
    if prt.sh_order:
        out["dqScale"] = np.ascontiguousarray(prt.dq_scale.T.astype(np.float32))
    return out


def _codes(values: np.ndarray, name: str) -> np.ndarray:
    """(n, 3) int64 of a stored (n, 3) attribute that must hold integers (float32 codes and ids)."""
    values = np.asarray(values, dtype=np.float64)
    values = values.reshape(len(values), -1)
    if values.shape[1] != ATTRIBUTE_WIDTH or np.any(values != np.rint(values)):
        raise ValueError(f"prt: {name} must hold {ATTRIBUTE_WIDTH} integers per vertex")
    return values.astype(np.int64)


def prt_from_layout(tables: dict, per_vertex: dict[str, np.ndarray]) -> PrtData:
    """Rebuild `PrtData` over render vertices from what a file holds.

    Parameters
    ----------
    tables : dict
        ``extras.sssbake.prt`` with every table already read into a numpy array.
    per_vertex : dict
        Attribute name (``_SSS_PRT_REF``, ``_SSS_PRT_DQ<i>``) -> (n, 3) stored values.

    Returns
    -------
    PrtData
        ``ref_vertices`` is empty: surface vertex ids do not survive export.
    """
    k = int(tables["directionCount"])
    order = int(tables["shOrder"])
    lookup = int(tables["lookupSize"])
    bits = int(tables["weightBits"])
    ref = _codes(per_vertex["_SSS_PRT_REF"], "_SSS_PRT_REF")
    n = len(ref)
    triangle = ref[:, 0]
    if np.any(np.abs(ref[:, 1:]) > WEIGHT_MAX[bits]):
        raise ValueError(f"prt: weight codes beyond ±{WEIGHT_MAX[bits]} in _SSS_PRT_REF")
    weights = ref[:, 1:].astype(np.int16)
    c = order * order
    if c:
        dq = np.stack([_codes(per_vertex[name], name) for name in tables["attributes"]["dq"]], axis=2)
        if dq.shape != (n, 3, c) or np.any(np.abs(dq) > 127):
            raise ValueError(f"prt: {c} Δq attributes of codes in [-127, 127] expected")
        dq = dq.astype(np.int8)
        dq_scale = np.asarray(tables["dqScale"], dtype=np.float32).reshape(c, 3).T
    else:
        dq = np.zeros((n, 3, 0), dtype=np.int8)
        dq_scale = np.zeros((3, 0), dtype=np.float32)
    r = int(tables["referencePointCount"])
    channels = int(tables["tableChannels"])
    ref_scale = np.zeros((0, 3), dtype=np.float32)
    detail_order = int(tables.get("detailOrder", 0))
    d = detail_order * detail_order
    detail = np.zeros((0, d + 3), dtype=np.int8)
    detail_scale = np.zeros(d, dtype=np.float32)
    if detail_order:
        detail = np.rint(np.asarray(tables["refDetail"], dtype=np.float64)).astype(np.int8).reshape(r, d + 3)
        detail_scale = np.asarray(tables["detailScale"], dtype=np.float32).reshape(d)
    if r:
        ref_codes = np.asarray(tables["refCodes"], dtype=np.uint8).reshape(r, k, channels)
        ref_triangles = np.asarray(tables["refTriangles"]).astype(np.int32).reshape(-1, 3)
        if channels == 1:
            ref_scale = np.asarray(tables["refScale"], dtype=np.float32).reshape(r, 3)
    else:
        ref_codes = np.zeros((0, k, channels), dtype=np.uint8)
        ref_triangles = np.zeros((0, 3), dtype=np.int32)
    return PrtData(
        directions=np.asarray(tables["directions"], dtype=np.float32).reshape(k, 3),
        direction_triangles=np.asarray(tables["directionTriangles"]).astype(np.int32).reshape(-1, 3),
        direction_inverse=np.asarray(tables["directionInverse"], dtype=np.float32).reshape(-1, 3, 3),
        direction_lookup=np.asarray(tables["directionLookup"]).astype(np.int32).reshape(lookup, lookup),
        direction_neighbours=np.asarray(tables["directionNeighbours"]).astype(np.int32).reshape(-1, 3),
        lut=np.ascontiguousarray(np.asarray(tables["lut"], dtype=np.float32).reshape(-1, 3).T),
        ref_vertices=np.zeros(0, dtype=np.int64),
        ref_codes=ref_codes,
        ref_scale=ref_scale,
        ref_triangles=ref_triangles,
        vertex_triangle=triangle.astype(np.int32),
        weight_codes=weights,
        weight_scale=float(tables["weightScale"]),
        weight_bits=bits,
        dq_codes=dq,
        dq_scale=dq_scale,
        sh_order=order,
        eta=float(tables["eta"]),
        detail_order=detail_order,
        detail_codes=np.ascontiguousarray(detail[:, 3:]),
        detail_colour=np.ascontiguousarray(detail[:, :3]),
        detail_scale=detail_scale,
    )
