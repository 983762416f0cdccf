"""How `PrtData` is laid out in the exported files, and how it is read back.

Per render vertex (glTF attribute / USD primvar, from `VertexAttribute` keys), VEC3 float32 like
every sssbake attribute (`baked.ATTRIBUTE_WIDTH`: what Blender, Bevy and Godot keep exactly):

- ``sss:prt:ref`` → ``_SSS_PRT_REF`` / ``primvars:sss:prt:ref``: the vertex's reference triangle
  and the codes of w_0, w_1 (``w = weightScale · code / M``, M = 127 with ``weightBits`` 8, 32767
  with 16; w_2 = 1 - w_0 - w_1), all integers;
- ``sss:prt:dq<i>`` → ``_SSS_PRT_DQ<i>``, i < C = shOrder²: the Δq codes of SH coefficient i in
  R, G, B (integers in [-127, 127]; ``Δq_c,i = code · dqScale[i][c] / 127``).

Per mesh, under ``extras.sssbake.prt`` (glTF: accessors; USD: table attributes on the Mesh prim),
see `prt_tables`. Reading back (`prt_from_layout`) gives exactly the in-memory codes and tables,
and refuses a block another tool broke (a field missing, of the wrong JSON type or out of range, an
index past its table) in one line naming the field.
"""

from __future__ import annotations

import numpy as np

from sssbake.pipeline.core.sh import MAX_ORDER
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


def _codes(per_vertex: dict[str, np.ndarray], name: str) -> np.ndarray:
    """(n, 3) int64 of the stored (n, 3) attribute `name`, which must hold integers (float32 codes and ids)."""
    if name not in per_vertex:
        raise ValueError(f"prt: attribute {name} is missing")
    values = np.asarray(per_vertex[name], dtype=np.float64)
    values = values.reshape(len(values), -1)
    if values.shape[1] != ATTRIBUTE_WIDTH or not np.all(np.isfinite(values)) or np.any(values != np.rint(values)):
        raise ValueError(f"prt: {name} must hold {ATTRIBUTE_WIDTH} integers per vertex")
    return values.astype(np.int64)


def prt_attribute_names(tables: dict) -> list[str]:
    """The per-vertex attributes a prt block names (``attributes``: ``ref``, the optional ``weights``
    and the ``dq`` list), checked to be names.

    Raises
    ------
    ValueError
        ``attributes`` or one of its names is missing or not a string.
    """
    if not isinstance(tables, dict):
        raise ValueError(f"prt: the prt block must be a JSON object, got {str(tables)[:40]}")
    names = tables.get("attributes")
    if not isinstance(names, dict) or not isinstance(names.get("ref"), str) or not isinstance(names.get("dq"), list) \
            or not all(isinstance(n, str) for n in names["dq"]) or not isinstance(names.get("weights", ""), str):
        raise ValueError(f"prt: attributes must name the ref attribute and a dq list of attributes, got "
                         f"{str(names)[:60]}")
    return [names["ref"], *([names["weights"]] if "weights" in names else []), *names["dq"]]


def _whole(tables: dict, name: str, low: int, high: int) -> int:
    """``tables[name]``: a JSON number that is a whole number in [low, high]."""
    if name not in tables:
        raise ValueError(f"prt: {name} is missing")
    value = tables[name]
    # range first: it also refuses NaN and ±Inf, which int() cannot take
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not low <= value <= high \
            or value != int(value):
        raise ValueError(f"prt: {name} must be a whole number in [{low}, {high}], got {str(value)[:40]}")
    return int(value)


def _at_least_one(tables: dict, name: str) -> float:
    """``tables[name]``: a finite JSON number >= 1."""
    if name not in tables:
        raise ValueError(f"prt: {name} is missing")
    value = tables[name]
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not 1.0 <= value < np.inf:
        raise ValueError(f"prt: {name} must be a finite number >= 1, got {str(value)[:40]}")
    return float(value)


def _table(tables: dict, name: str, shape: tuple[int, ...]) -> np.ndarray:
    """``tables[name]``, a table read from the file, as a float64 array of `shape` (a first
    dimension of -1: any number of rows)."""
    if name not in tables:
        raise ValueError(f"prt: table {name} is missing")
    value = tables[name]
    if not isinstance(value, np.ndarray) or value.dtype.kind not in "fiu":
        # a number or list in the JSON instead of the reference to a table the exporters write
        raise ValueError(f"prt: {name} must be a table of numbers, got {type(value).__name__} {str(value)[:40]}")
    row = int(np.prod(shape[1:]))
    if (value.size != row * shape[0]) if shape[0] >= 0 else (value.size % row):
        raise ValueError(f"prt: table {name} holds {value.size} values, expected shape {list(shape)}")
    return value.astype(np.float64).reshape(shape)


def _floats(tables: dict, name: str, shape: tuple[int, ...]) -> np.ndarray:
    """A float table of `shape` as float32, refused when not finite there."""
    values = _table(tables, name, shape)
    with np.errstate(over="ignore"):
        out = values.astype(np.float32)
    if not np.all(np.isfinite(out)):
        raise ValueError(f"prt: table {name} holds NaN, Inf or values beyond float32")
    return out


def _integers(tables: dict, name: str, shape: tuple[int, ...], low: int, high: int, dtype) -> np.ndarray:
    """An integer table of `shape` as `dtype`, refused unless every value is a whole number in [low, high]."""
    values = _table(tables, name, shape)
    if values.size and (np.any(values != np.rint(values)) or values.min() < low or values.max() > high):
        raise ValueError(f"prt: table {name} must hold whole numbers in [{low}, {high}]")
    return values.astype(dtype)


def prt_from_layout(tables: dict, per_vertex: dict[str, np.ndarray]) -> PrtData:
    """Rebuild `PrtData` over render vertices from what a file holds.

    Parameters
    ----------
    tables : dict
        ``extras.sssbake.prt`` with every table already read into a numpy array.
    per_vertex : dict
        Attribute name (``attributes.ref``, ``attributes.dq``: ``_SSS_PRT_REF``, ``_SSS_PRT_DQ<i>``)
        -> (n, 3) stored values.

    Returns
    -------
    PrtData
        ``ref_vertices`` is empty: surface vertex ids do not survive export.

    Raises
    ------
    ValueError
        One line naming the field: a parameter missing, not a number or out of range; a table
        missing, inline in the JSON rather than referenced, of the wrong size, not finite, or
        holding indices or codes out of range.
    """
    names = prt_attribute_names(tables)
    int32 = np.iinfo(np.int32).max
    k = _whole(tables, "directionCount", 1, int32)
    order = _whole(tables, "shOrder", 0, MAX_ORDER)
    lookup = _whole(tables, "lookupSize", 1, int32)
    bits = _whole(tables, "weightBits", 8, 16)
    if bits not in WEIGHT_MAX:
        raise ValueError(f"prt: weightBits must be 8 or 16, got {bits}")
    r = _whole(tables, "referencePointCount", 0, int32)
    channels = _whole(tables, "tableChannels", 1, 3)
    if channels == 2:
        raise ValueError("prt: tableChannels must be 1 or 3, got 2")
    detail_order = _whole(tables, "detailOrder", 0, MAX_ORDER) if "detailOrder" in tables else 0
    # both >= 1: a refractive index into air, and the weights' range (1 for barycentric weights, more for
    # least-squares ones: `compress.compress_prt`)
    weight_scale, eta = _at_least_one(tables, "weightScale"), _at_least_one(tables, "eta")

    directions = _floats(tables, "directions", (k, 3))
    direction_triangles = _integers(tables, "directionTriangles", (-1, 3), 0, k - 1, np.int32)
    t = len(direction_triangles)
    direction_inverse = _floats(tables, "directionInverse", (t, 3, 3))
    direction_lookup = _integers(tables, "directionLookup", (lookup, lookup), 0, t - 1, np.int32)
    direction_neighbours = _integers(tables, "directionNeighbours", (t, 3), 0, t - 1, np.int32)
    lut = np.ascontiguousarray(_floats(tables, "lut", (256, 3)).T)

    ref = _codes(per_vertex, names[0])
    n = len(ref)
    if np.any(np.abs(ref[:, 1:]) > WEIGHT_MAX[bits]):
        raise ValueError(f"prt: weight codes beyond ±{WEIGHT_MAX[bits]} in {names[0]}")
    weights = ref[:, 1:].astype(np.int16)
    c, dq_names = order * order, tables["attributes"]["dq"]
    if len(dq_names) != c:
        raise ValueError(f"prt: attributes.dq must name shOrder² = {c} attributes, got {len(dq_names)}")
    if c:
        dq = np.stack([_codes(per_vertex, name) for name in dq_names], axis=2)
        if dq.shape != (n, 3, c) or np.any(np.abs(dq) > 127):
            raise ValueError(f"prt: {c} Δq attributes of codes in [-127, 127] expected")
        dq = dq.astype(np.int8)
        dq_scale = np.ascontiguousarray(_floats(tables, "dqScale", (c, 3)).T)
    else:
        dq = np.zeros((n, 3, 0), dtype=np.int8)
        dq_scale = np.zeros((3, 0), dtype=np.float32)
    ref_scale = np.zeros((0, 3), dtype=np.float32)
    d = detail_order * detail_order
    detail = np.zeros((0, d + 3), dtype=np.int8)
    detail_scale = np.zeros(d, dtype=np.float32)
    if detail_order:
        detail = _integers(tables, "refDetail", (r, d + 3), -128, 127, np.int8)
        detail_scale = _floats(tables, "detailScale", (d,))
    if r:
        ref_codes = _integers(tables, "refCodes", (r, k, channels), 0, 255, np.uint8)
        ref_triangles = _integers(tables, "refTriangles", (-1, 3), 0, r - 1, np.int32)
        if channels == 1:
            ref_scale = _floats(tables, "refScale", (r, 3))
    else:
        ref_codes = np.zeros((0, k, channels), dtype=np.uint8)
        ref_triangles = np.zeros((0, 3), dtype=np.int32)
    triangle = ref[:, 0]
    # a vertex's reference triangle: 0 for every vertex of a mesh without reference points
    if n and (triangle.min() < 0 or triangle.max() >= max(len(ref_triangles), 1)):
        raise ValueError(f"prt: {names[0]} names reference triangles outside the {len(ref_triangles)} of refTriangles")
    return PrtData(
        directions=directions,
        direction_triangles=direction_triangles,
        direction_inverse=direction_inverse,
        direction_lookup=direction_lookup,
        direction_neighbours=direction_neighbours,
        lut=lut,
        ref_vertices=np.zeros(0, dtype=np.int64),
        ref_codes=ref_codes,
        ref_scale=ref_scale,
        ref_triangles=ref_triangles,
        vertex_triangle=triangle.astype(np.int32),
        weight_codes=weights,
        weight_scale=weight_scale,
        weight_bits=bits,
        dq_codes=dq,
        dq_scale=dq_scale,
        sh_order=order,
        eta=eta,
        detail_order=detail_order,
        detail_codes=np.ascontiguousarray(detail[:, 3:]),
        detail_colour=np.ascontiguousarray(detail[:, :3]),
        detail_scale=detail_scale,
    )
