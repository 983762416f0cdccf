"""How `KernelsData` is laid out in the exported files, and how it is read back.

Per render vertex (glTF attribute / USD primvar): ``sss:kernels:vertex`` → ``_SSS_KERNELS_VERTEX``
/ ``primvars:sss:kernels:vertex``, the welded surface vertex of the render vertex: VEC3 float32
``(vertex, 0, 0)`` (`baked.welded_vertex_attribute`: what every importer keeps).

Per mesh, under ``extras.sssbake.kernels`` (glTF: accessors; USD: table attributes on each Mesh
prim of the mesh), see `kernels_tables`: one atlas per mesh, shared by its primitives. Kernels are
stored as 8- or 16-bit codes with a float32 scale per covered texel and channel, ``value = scale ·
code / (2^(bits-1) - 1)``; everything else as it is in memory (float32, and indices as uint16 when
they fit, else uint32). Tables with no rows (no border texels, an empty F) are left out: a glTF
accessor cannot be empty; the counts say they are empty.
"""

from __future__ import annotations

import numpy as np

from sssbake.pipeline.mesh.baked import ATTRIBUTE_WIDTH, VertexAttribute, index_table, welded_vertex_attribute
from sssbake.pipeline.techniques.kernels.data import KernelsData, KernelsDataError
from sssbake.pipeline.techniques.kernels.options import KERNEL_BITS

VERTEX_KEY = "sss:kernels:vertex"
VERTEX_ATTRIBUTE = VertexAttribute(VERTEX_KEY, np.zeros(0)).gltf_name

#: Byte-count block -> the tables that make it up (see `kernels_bytes`).
BLOCKS = {
    "kernels": ("kernelCodes",),
    "kernelScales": ("kernelScales",),
    "texels": ("texels",),
    "distribution": ("texelVertices", "texelDual", "texelDirect"),
    "f": ("fIndptr", "fIndices", "fValues"),
    "border": ("borderTexels", "borderVertices", "borderBarycentric"),
    "surface": ("surfaceGlobal", "surfaceWeights"),
}

#: Texels encoded at a time: bounds the float64 temporaries of `encode_kernels`.
_ENCODE_CHUNK = 1 << 15


def _code_dtype(bits: int) -> type:
    if bits not in KERNEL_BITS:
        raise ValueError(f"kernels layout: kernel_bits must be 8 or 16, got {bits}")
    return np.int8 if bits == 8 else np.int16


def _code_max(bits: int) -> int:
    """M = 2^(bits-1) - 1, the code of the scale itself."""
    return int(np.iinfo(_code_dtype(bits)).max)


def encode_kernels(kernels: np.ndarray, bits: int) -> tuple[np.ndarray, np.ndarray]:
    """Signed codes and per-texel, per-channel scales of the kernels.

    Parameters
    ----------
    kernels : (S, k², 3) float32
    bits : int
        8 or 16.

    Returns
    -------
    codes : (S, k², 3) int8 (bits 8) or int16 (bits 16)
        ``rint(kernel / scale · M)``, M = 2^(bits-1) - 1; 0 where the scale is 0.
    scales : (S, 3) float32
        Largest absolute kernel value of each texel and channel (the value of code M).
    """
    top = _code_max(bits)
    scales = np.abs(kernels).max(axis=1).astype(np.float32)
    # in float64: M / a subnormal float32 scale overflows float32, and inf · 0 made NaN codes
    factor = np.divide(top, scales.astype(np.float64), out=np.zeros(scales.shape), where=scales > 0)
    codes = np.empty(kernels.shape, dtype=_code_dtype(bits))
    for lo in range(0, len(kernels), _ENCODE_CHUNK):
        hi = lo + _ENCODE_CHUNK
        # float64 so that the rounding, and hence the error bound, is exact
        codes[lo:hi] = np.clip(np.rint(kernels[lo:hi].astype(np.float64) * factor[lo:hi, None, :]), -top, top)
    return codes, scales


def decode_kernels(codes: np.ndarray, scales: np.ndarray, bits: int) -> np.ndarray:
    """The kernels the codes stand for, ``scale · code / (2^(bits-1) - 1)`` rounded to float32.

    Parameters
    ----------
    codes : (S, k², 3) integers
    scales : (S, 3) float
    bits : int

    Returns
    -------
    (S, k², 3) float32
    """
    top = _code_max(bits)
    return (np.asarray(codes, dtype=np.float64) * (np.asarray(scales, dtype=np.float64) / top)[:, None, :]
            ).astype(np.float32)


def kernel_error_bound(scales: np.ndarray, bits: int) -> np.ndarray:
    """(S, 3) float64: the largest ``|decoded - original|`` of any kernel entry of each texel and
    channel, ``scale / (2 (2^(bits-1) - 1))`` (half a code step), before the decoded value is rounded
    to float32 (a further relative 2^-24)."""
    return np.asarray(scales, dtype=np.float64) / (2.0 * _code_max(bits))


def kernels_vertex_attributes(data: KernelsData, vertices: np.ndarray) -> tuple[VertexAttribute, ...]:
    """The per-vertex attribute of one primitive.

    Parameters
    ----------
    data : KernelsData
        Over the mesh's welded surface vertices.
    vertices : (p,) int64
        The welded vertex of each render vertex of the primitive (``Surface.weld[j][vmapping]``).

    Returns
    -------
    tuple of VertexAttribute
        ``sss:kernels:vertex`` (`welded_vertex_attribute`).
    """
    return (welded_vertex_attribute(VERTEX_KEY, vertices, data.surface_vertex_count,
                                    "welded surface vertex of the render vertex (kernels tables); components 1, 2 "
                                    "are 0"),)


def _plain_tables(data: KernelsData) -> dict[str, np.ndarray]:
    """Every table but the kernel codes and scales, as stored, empty ones included."""
    # copy=False: F's values (the largest table, already float32) are not copied
    return {
        "texels": data.texels.astype(np.uint32),
        "texelVertices": index_table(data.texel_vertices),
        "texelDual": data.texel_dual.astype(np.float32, copy=False),
        # Row s·3 + a, column c: glTF MAT3 would mean column-major and padded columns.
        "texelDirect": data.texel_direct.astype(np.float32, copy=False).reshape(-1, 3),
        "fIndptr": data.f_indptr.astype(np.uint32),
        "fIndices": index_table(data.f_indices),
        "fValues": data.f_values.astype(np.float32, copy=False),
        "borderTexels": data.border_texels.astype(np.uint32),
        "borderVertices": index_table(data.border_vertices),
        "borderBarycentric": data.border_barycentric.astype(np.float32, copy=False),
        "surfaceGlobal": index_table(data.surface_global),
        "surfaceWeights": data.surface_weights.astype(np.float32, copy=False),
    }


def kernels_tables(data: KernelsData, kernel_bits: int = 16) -> dict:
    """The per-mesh tables and parameters, JSON-able with numpy arrays for the binary tables.

    Parameters
    ----------
    data : KernelsData
    kernel_bits : int
        8 (int8 codes) or 16 (int16 codes).

    Returns
    -------
    dict
        Parameters ``technique`` ("kernels"), ``width``, ``height``, ``kernelSize`` (k),
        ``kernelBits``, ``vertexCount`` (n, global vertices), ``surfaceVertexCount`` (welded surface
        vertices), ``texelCount`` (S), ``nnz``, ``borderCount`` (b),
        ``attributes`` {``vertex``: ``_SSS_KERNELS_VERTEX``}, ``units``; tables ``texels`` (S,)
        uint32, ``kernelCodes`` (S·k², 3) int8/int16 (row s·k² + o), ``kernelScales`` (S, 3)
        float32, ``texelVertices`` (S, 3) uint16/int64, ``texelDual`` (S, 3) float32,
        ``texelDirect`` (S·3, 3) float32 (row s·3 + a), ``fIndptr`` (n + 1,) uint32, ``fIndices``
        (nnz,) uint16/int64, ``fValues`` (nnz, 3) float32, ``borderTexels`` (b,) uint32,
        ``borderVertices`` (b, 3) uint16/int64, ``borderBarycentric`` (b, 3) float32,
        ``surfaceGlobal`` (surfaceVertexCount, 3) uint16/int64, ``surfaceWeights`` (surfaceVertexCount,
        3) float32; tables with
        no rows are left out. int64 index tables are stored as uint32.
    """
    data.check()
    codes, scales = encode_kernels(data.kernels, kernel_bits)
    out = {
        "technique": "kernels",
        "width": int(data.width),
        "height": int(data.height),
        "kernelSize": int(data.kernel_size),
        "kernelBits": int(kernel_bits),
        "vertexCount": int(data.vertex_count),
        "surfaceVertexCount": int(data.surface_vertex_count),
        "texelCount": int(len(data.texels)),
        "nnz": data.nnz,
        "borderCount": int(len(data.border_texels)),
        "attributes": {"vertex": VERTEX_ATTRIBUTE},
        "units": "q: radiance per unit irradiance (1/sr); kernels, texelDual, texelDirect, fValues: unitless "
                 "weights",
    }
    tables = {"kernelCodes": codes.reshape(-1, 3), "kernelScales": scales, **_plain_tables(data)}
    out.update({name: table for name, table in tables.items() if table.size})
    return out


def _stored_bytes(table: np.ndarray) -> int:
    # int64 index tables are stored as uint32; everything else as its dtype.
    return int(table.size * min(table.dtype.itemsize, 4))


def kernels_bytes(data: KernelsData, kernel_bits: int = 16) -> dict:
    """Bytes of the per-mesh tables as the glTF binary stores them (USD widens int16 and index tables to int[]).

    Returns
    -------
    dict
        One int per `BLOCKS` key (``kernels``, ``kernelScales``, ``texels``, ``distribution``,
        ``f``, ``border``, ``surface``), ``total`` (their sum), ``perVertex`` (total / welded surface
        vertices),
        ``perTexel`` (total / covered texels; 0 without any), and ``vertexIdsPerRenderVertex``: the
        bytes each render vertex spends on ``_SSS_KERNELS_VERTEX`` (12: VEC3 float32), not in
        ``total``.
    """
    k2 = data.kernel_size**2
    s = len(data.texels)
    sizes = {name: _stored_bytes(table) for name, table in _plain_tables(data).items()}
    sizes["kernelCodes"] = s * k2 * 3 * np.dtype(_code_dtype(kernel_bits)).itemsize
    sizes["kernelScales"] = s * 3 * 4
    out = {block: sum(sizes[name] for name in names) for block, names in BLOCKS.items()}
    total = sum(out.values())
    out.update(total=total, perVertex=total / data.surface_vertex_count, perTexel=total / s if s else 0.0,
               vertexIdsPerRenderVertex=4 * ATTRIBUTE_WIDTH)
    return out


def _table(tables: dict, name: str, shape: tuple[int, ...], dtype) -> np.ndarray:
    """Table `name` reshaped to `shape`; absent is only allowed (and read as empty) for no rows."""
    if name not in tables:
        if shape[0]:
            raise KernelsDataError(f"kernels: table {name} is missing")
        return np.zeros(shape, dtype=dtype)
    values = tables[name]
    if not isinstance(values, np.ndarray) or values.dtype.kind not in "fiu":
        # a number or list in the JSON instead of the reference to a table the exporters write
        raise KernelsDataError(f"kernels: {name} must be a table of numbers, got {type(values).__name__} "
                               f"{str(values)[:40]}")
    if values.size != int(np.prod(shape)):
        raise KernelsDataError(f"kernels: table {name} holds {values.size} values, expected shape {shape}")
    if np.dtype(dtype).kind in "iu" and values.dtype.kind == "f" and not np.all(values == np.rint(values)):
        raise KernelsDataError(f"kernels: table {name} must hold whole numbers")
    with np.errstate(over="ignore", invalid="ignore"):  # what does not fit is refused by `KernelsData.check`
        return values.reshape(shape).astype(dtype)


def _count(tables: dict, name: str) -> int:
    """``tables[name]``: a JSON number that is a whole number in [0, 2^31 - 1]."""
    if name not in tables:
        raise KernelsDataError(f"kernels: {name} is missing")
    value, top = tables[name], np.iinfo(np.int32).max
    # range first: it also refuses NaN and ±Inf, which int() cannot take
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not 0 <= value <= top or value != int(value):
        raise KernelsDataError(f"kernels: {name} must be a whole number in [0, {top}], got {str(value)[:40]}")
    return int(value)


def vertex_attribute_name(tables: dict) -> str:
    """The per-vertex attribute a kernels block names (``attributes.vertex``).

    Raises
    ------
    KernelsDataError
        The block is not a JSON object, or does not name the attribute with a string.
    """
    if not isinstance(tables, dict):
        raise KernelsDataError(f"kernels: the kernels block must be a JSON object, got {str(tables)[:40]}")
    names = tables.get("attributes")
    if not isinstance(names, dict) or not isinstance(names.get("vertex"), str):
        raise KernelsDataError(f"kernels: attributes must name the vertex attribute, got {str(names)[:60]}")
    return names["vertex"]


def kernels_data_from_tables(tables: dict) -> KernelsData:
    """Rebuild the mesh's `KernelsData` from its tables (kernels decoded from the codes).

    Parameters
    ----------
    tables : dict
        ``extras.sssbake.kernels`` with every table already read into a numpy array (any shape
        with the right number of values; integer tables in any integer dtype).

    Returns
    -------
    KernelsData
        Checked; raises KernelsDataError when the tables do not form valid data (a parameter
        missing or not a count, a table missing, inline in the JSON, of the wrong size or values).
    """
    vertex_attribute_name(tables)  # a JSON object that names its attribute: the reader's first check
    k = _count(tables, "kernelSize")
    n, s = _count(tables, "vertexCount"), _count(tables, "texelCount")
    nnz, b = _count(tables, "nnz"), _count(tables, "borderCount")
    bits = _count(tables, "kernelBits")
    if bits not in KERNEL_BITS:
        raise KernelsDataError(f"kernels: kernelBits must be 8 or 16, got {bits}")
    surface = _count(tables, "surfaceVertexCount")
    codes = _table(tables, "kernelCodes", (s, k * k, 3), np.int64)
    scales = _table(tables, "kernelScales", (s, 3), np.float32)
    data = KernelsData(
        width=_count(tables, "width"),
        height=_count(tables, "height"),
        kernel_size=k,
        vertex_count=n,
        texels=_table(tables, "texels", (s,), np.int64),
        kernels=decode_kernels(codes, scales, bits),
        texel_vertices=_table(tables, "texelVertices", (s, 3), np.int64),
        texel_dual=_table(tables, "texelDual", (s, 3), np.float32),
        texel_direct=_table(tables, "texelDirect", (s, 3, 3), np.float32),
        f_indptr=_table(tables, "fIndptr", (n + 1,), np.int64),
        f_indices=_table(tables, "fIndices", (nnz,), np.int64),
        f_values=_table(tables, "fValues", (nnz, 3), np.float32),
        border_texels=_table(tables, "borderTexels", (b,), np.int64),
        border_vertices=_table(tables, "borderVertices", (b, 3), np.int64),
        border_barycentric=_table(tables, "borderBarycentric", (b, 3), np.float32),
        surface_vertex_count=surface,
        surface_global=_table(tables, "surfaceGlobal", (surface, 3), np.int64),
        surface_weights=_table(tables, "surfaceWeights", (surface, 3), np.float32),
    )
    data.check()
    return data


def vertex_ids_from_layout(tables: dict, per_vertex: dict[str, np.ndarray]) -> np.ndarray:
    """(p,) int64 welded vertex of each render vertex of one primitive.

    Parameters
    ----------
    tables : dict
        ``extras.sssbake.kernels`` (only its parameters are used).
    per_vertex : dict
        Attribute name (``_SSS_KERNELS_VERTEX``) -> (p, 3) stored values ``(vertex, 0, 0)``.
    """
    name = vertex_attribute_name(tables)
    if name not in per_vertex:
        raise KernelsDataError(f"kernels: attribute {name} is missing")
    stored = np.asarray(per_vertex[name], dtype=np.float64)
    stored = stored.reshape(len(stored), -1)
    n = _count(tables, "surfaceVertexCount")
    ids = stored[:, 0]
    if stored.shape[1] != ATTRIBUTE_WIDTH or np.any(stored[:, 1:] != 0.0) or np.any(ids != np.rint(ids)):
        raise KernelsDataError("kernels: vertex ids must be stored as (vertex, 0, 0) with integer vertices")
    if ids.size and (ids.min() < 0 or ids.max() >= n):
        raise KernelsDataError(f"kernels: vertex ids outside the {n} welded vertices")
    return ids.astype(np.int64)


def kernels_from_layout(tables: dict, per_vertex: dict[str, np.ndarray]) -> tuple[KernelsData, np.ndarray]:
    """Rebuild `KernelsData` and one primitive's vertex ids from what a file holds.

    Parameters
    ----------
    tables : dict
        ``extras.sssbake.kernels`` with every table already read into a numpy array.
    per_vertex : dict
        Attribute name (``_SSS_KERNELS_VERTEX``) -> stored values of the primitive.

    Returns
    -------
    data : KernelsData
        Kernels as `decode_kernels` gives them; every other array exactly as written.
    vertex_ids : (p,) int64
    """
    return kernels_data_from_tables(tables), vertex_ids_from_layout(tables, per_vertex)
