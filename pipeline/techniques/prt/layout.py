"""How `PrtData` is laid out in the exported files, and how it is read back.

Per render vertex (glTF attribute / USD primvar, from `VertexAttribute` keys):

- 8-bit weights (``weightBits`` 8): ``sss:prt:ref`` → ``_SSS_PRT_REF`` / ``primvars:sss:prt:ref``:
  VEC4 uint8, the vertex's reference triangle ``x + 256 · y`` and the codes of w_0, w_1 plus 128
  (``w = weightScale · code / 127``), one 4-byte attribute;
- 16-bit weights: ``sss:prt:ref`` → ``_SSS_PRT_REF``: VEC2 uint16, the reference triangle
  ``lo + 65536 · hi``, and ``sss:prt:w`` → ``_SSS_PRT_W``: VEC2 snorm16, w_0 and w_1 divided by
  ``weightScale``;
- ``sss:prt:dq<i>`` → ``_SSS_PRT_DQ<i>``: VEC4 snorm8; the (3, C) Δq codes of the vertex flattened
  channel-major (index c·C + i) and cut into groups of four, the last one zero-padded.

Per mesh, under ``extras.sssbake.prt`` (glTF: accessors; USD: table attributes on the Mesh prim),
see `prt_tables`. Reading back (`prt_from_layout`) gives exactly the in-memory codes and tables.
"""

from __future__ import annotations

import numpy as np

from sssbake.pipeline.mesh.baked import VertexAttribute, index_table
from sssbake.pipeline.techniques.prt.data import PrtData

REF_KEY, WEIGHT_KEY, DQ_KEY = "sss:prt:ref", "sss:prt:w", "sss:prt:dq"


def dq_attribute_count(sh_order: int) -> int:
    """How many VEC4 snorm8 attributes hold 3·sh_order² Δq codes."""
    return -(-3 * sh_order * sh_order // 4)


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
    tri = prt.vertex_triangle[vertices].astype(np.int64)
    codes = prt.weight_codes[vertices].astype(np.float64)
    if prt.weight_bits == 8:
        if len(tri) and tri.max() >= 65536:
            raise ValueError("prt layout: 8-bit weights address at most 65536 reference triangles; "
                             "compress with weight_bits=16")
        packed = np.column_stack([tri % 256, tri // 256, codes + 128.0])
        out = [VertexAttribute(REF_KEY, packed, "", "uint8", "reference triangle x + 256 y; codes of the "
                               "weights w0, w1 plus 128 (w = weightScale * code / 127, w2 = 1 - w0 - w1)")]
    else:
        ref = np.column_stack([tri % 65536, tri // 65536]).astype(np.float64)
        out = [
            VertexAttribute(REF_KEY, ref, "", "uint16", "reference triangle of the vertex: lo + 65536 * hi"),
            VertexAttribute(WEIGHT_KEY, codes / 32767.0, "", "snorm16", "weights w0, w1 of the reference "
                            "points divided by weightScale; w2 = 1 - w0 - w1"),
        ]
    c = prt.dq_codes.shape[2]
    if c:
        flat = prt.dq_codes[vertices].reshape(len(vertices), -1).astype(np.float64) / 127.0
        groups = dq_attribute_count(prt.sh_order)
        padded = np.zeros((len(vertices), 4 * groups))
        padded[:, : flat.shape[1]] = flat
        for g in range(groups):
            out.append(VertexAttribute(f"{DQ_KEY}{g}", padded[:, 4 * g: 4 * g + 4], "", "snorm8",
                                       f"Δq SH codes {4 * g}..{4 * g + 3} (channel-major c*C+i) / 127"))
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
        "attributes": {"ref": "_SSS_PRT_REF", **({} if prt.weight_bits == 8 else {"weights": "_SSS_PRT_W"}),
                       "dq": [f"_SSS_PRT_DQ{g}" for g in range(dq_attribute_count(prt.sh_order))]},
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


def prt_from_layout(tables: dict, per_vertex: dict[str, np.ndarray]) -> PrtData:
    """Rebuild `PrtData` over render vertices from what a file holds.

    Parameters
    ----------
    tables : dict
        ``extras.sssbake.prt`` with every table already read into a numpy array.
    per_vertex : dict
        Attribute name (``_SSS_PRT_REF``, ...) -> (n, k) stored values as floats or integers
        (snorm values as stored codes / MAX, as glTF and USD both give them).

    Returns
    -------
    PrtData
        ``ref_vertices`` is empty: surface vertex ids do not survive export.
    """
    k = int(tables["directionCount"])
    order = int(tables["shOrder"])
    lookup = int(tables["lookupSize"])
    bits = int(tables["weightBits"])
    ref = np.rint(np.asarray(per_vertex["_SSS_PRT_REF"], dtype=np.float64)).astype(np.int64)
    n = len(ref)
    if bits == 8:
        triangle = ref[:, 0] + 256 * ref[:, 1]
        weights = (ref[:, 2:4] - 128).astype(np.int16)
    else:
        triangle = ref[:, 0] + 65536 * ref[:, 1]
        weights = np.rint(np.asarray(per_vertex["_SSS_PRT_W"], dtype=np.float64) * 32767.0).astype(np.int16)
    c = order * order
    if c:
        flat = np.concatenate([np.asarray(per_vertex[name], dtype=np.float64).reshape(n, 4)
                               for name in tables["attributes"]["dq"]], axis=1)
        dq = np.rint(flat[:, : 3 * c] * 127.0).astype(np.int8).reshape(n, 3, c)
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
