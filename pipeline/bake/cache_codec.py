"""Serialisation of stage results for the stage cache that runs no code from the bytes it reads.

A shared cache folder may hold entries someone else wrote, so reading one must not be able to
call anything (pickle calls whatever the payload names). A payload here is::

    <n: 8-byte little-endian length> <n bytes of UTF-8 JSON> <k arrays, each a .npy file>

The JSON is ``{"arrays": k, "value": NODE}``. A NODE is ``null``, ``true``/``false``, an int, a
finite float or a string standing for itself, or an object with one key that says what it is:

- ``{"f": "nan" | "inf" | "-inf"}``: a float that is not finite (the JSON stays standard);
- ``{"t": [NODE, ...]}`` a tuple, ``{"l": [NODE, ...]}`` a list;
- ``{"d": [[KEY NODE, VALUE NODE], ...]}``: a dict, in order; keys keep their type (int, tuple...);
- ``{"a": i}`` the i-th array; ``{"n": i}`` a numpy scalar, the i-th array's only element;
  ``{"b": i}`` bytes, the i-th array (uint8, 1-D);
- ``{"c": [module, qualname, {field: NODE, ...}]}``: an instance of a dataclass defined in a
  ``sssbake.`` module, every one of its fields in order.

Arrays are written as .npy files (a `numpy.lib.format` header, then the array's own bytes, not
copied: a stage's result can be gigabytes; object and structured dtypes are refused) and read as
views of the payload after their header's size is checked against the bytes left (a writable
payload, as `StageCache` reads it, gives writable arrays without a copy). An array that occurs several times in a value is
written once and read back as one object. A dataclass is looked up by module and qualified name
only in modules named ``sssbake.…``; it must be a dataclass defined there under that name, with
exactly the stored fields; it is rebuilt as pickle does (no ``__init__``, no ``__post_init__``).
Anything else (another class, an unknown tag, a wrong index, data cut short or left over) makes
`loads` raise `CacheFormatError`; `dumps` raises TypeError for a value it cannot store exactly.
"""

from __future__ import annotations

import dataclasses
import functools
import importlib
import io
import json
import math
import re

import numpy as np
from numpy.lib import format as npy

from sssbake.pipeline.core.errors import SssbakeError

_MODULE = re.compile(r"sssbake(\.[A-Za-z][A-Za-z0-9_]*)+")
_QUALNAME = re.compile(r"[A-Za-z][A-Za-z0-9_]*(\.[A-Za-z][A-Za-z0-9_]*)*")
_NON_FINITE = {"nan": math.nan, "inf": math.inf, "-inf": -math.inf}
_LENGTH = 8  # bytes of the JSON length prefix


class CacheFormatError(SssbakeError, ValueError):
    """A payload `loads` refuses: malformed, cut short, or naming something it will not build."""


@functools.cache
def _dataclass(module: str, qualname: str) -> type:
    """The dataclass `qualname` defined in the sssbake module `module`; CacheFormatError otherwise."""
    if not (_MODULE.fullmatch(module) and _QUALNAME.fullmatch(qualname)):
        raise CacheFormatError(f"{module}.{qualname} is not an sssbake class")
    try:
        found = importlib.import_module(module)
    except Exception as e:  # whatever stops the import, the entry cannot be read
        raise CacheFormatError(f"module {module} does not import ({type(e).__name__})") from e
    for part in qualname.split("."):
        found = getattr(found, part, None)
    if not (isinstance(found, type) and dataclasses.is_dataclass(found)
            and found.__module__ == module and found.__qualname__ == qualname):
        raise CacheFormatError(f"{module}.{qualname} is not a dataclass of sssbake")
    return found


class _Refused(TypeError):
    """A value `dumps` cannot store; `path` collects where it sits, innermost first."""

    def __init__(self, what: str):
        super().__init__(what)
        self.path: list[str] = []


class _Encoder:
    """One `dumps`: the JSON node of a value (`node`), collecting its arrays in `arrays`."""

    def __init__(self):
        self.arrays: list[np.ndarray] = []
        # id of each array-backed object -> its index; `kept` holds the objects so ids stay unique
        self.index: dict[int, int] = {}
        self.kept: list = []

    def array(self, original, array: np.ndarray) -> int:
        i = self.index.get(id(original))
        if i is None:
            if array.dtype.hasobject or array.dtype.fields is not None:
                raise _Refused(f"an array of dtype {array.dtype} (object and structured dtypes are not stored)")
            i = self.index[id(original)] = len(self.arrays)
            self.arrays.append(array)
            self.kept.append(original)
        return i

    def child(self, value, label: str):
        try:
            return self.node(value)
        except _Refused as e:
            e.path.append(label)
            raise

    def node(self, v):
        t = type(v)
        if v is None or t is bool or t is int or t is str:
            return v
        if t is float:
            return v if math.isfinite(v) else {"f": repr(v)}
        if t is np.ndarray:
            return {"a": self.array(v, v)}
        if isinstance(v, np.generic):  # np.float64 subclasses float: the exact `t is float` above let it by
            return {"n": self.array(v, np.asarray(v))}
        if t is bytes:
            return {"b": self.array(v, np.frombuffer(v, np.uint8))}
        if t is tuple or t is list:
            return {"t" if t is tuple else "l": [self.child(x, f"[{i}]") for i, x in enumerate(v)]}
        if t is dict:
            return {"d": [[self.child(k, f"[key {k!r}]"), self.child(x, f"[{k!r}]")] for k, x in v.items()]}
        if dataclasses.is_dataclass(v):
            try:
                allowed = _dataclass(t.__module__, t.__qualname__) is t
            except CacheFormatError:
                allowed = False
            if not allowed:
                raise _Refused(f"{t.__module__}.{t.__qualname__} (only dataclasses of sssbake modules are stored)")
            names = [f.name for f in dataclasses.fields(v)]
            extra = sorted(vars(v).keys() - set(names)) if hasattr(v, "__dict__") else []
            if extra:  # set after __init__; pickle would keep them, a rebuilt value would lack them
                raise _Refused(f"{t.__qualname__} with attributes outside its fields {extra}")
            return {"c": [t.__module__, t.__qualname__, {n: self.child(getattr(v, n), f".{n}") for n in names}]}
        raise _Refused(f"{t.__module__}.{t.__qualname__}")


def dumps(value) -> list:
    """The payload of `value`: bytes-like pieces to be written one after another.

    Raises
    ------
    TypeError
        Naming the first value it cannot store exactly and where it sits in `value`.
    """
    enc = _Encoder()
    try:
        node = enc.node(value)
    except _Refused as e:
        where = "".join(reversed(e.path))
        raise TypeError(f"stage cache cannot store {e}{f' at {type(value).__qualname__}{where}' if where else ''}") from None
    text = json.dumps({"arrays": len(enc.arrays), "value": node}, allow_nan=False, separators=(",", ":")).encode()
    pieces = [len(text).to_bytes(_LENGTH, "little"), text]
    for a in enc.arrays:
        a = a if a.flags.c_contiguous else a.copy(order="C")  # (not ascontiguousarray: it makes 0-d 1-d)
        header = io.BytesIO()
        npy.write_array_header_2_0(header, npy.header_data_from_array_1_0(a))
        pieces += [header.getvalue(), a.reshape(-1).view(np.uint8).data]
    return pieces


def _reject_constant(name: str):
    raise CacheFormatError(f"JSON constant {name}")  # our writer spells non-finite floats as {"f": ...}


class _Reader:
    """`read(n)` over a buffer without copying what it does not return (numpy's header readers)."""

    def __init__(self, buffer: memoryview):
        self.buffer, self.pos = buffer, 0

    def read(self, n: int) -> bytes:
        out = bytes(self.buffer[self.pos:self.pos + n])
        self.pos += len(out)
        return out


def _read_array(reader: _Reader) -> np.ndarray:
    version = npy.read_magic(reader)
    if version == (1, 0):
        shape, fortran, dtype = npy.read_array_header_1_0(reader)
    elif version == (2, 0):
        shape, fortran, dtype = npy.read_array_header_2_0(reader)
    else:
        raise CacheFormatError(f".npy version {version}")
    count = math.prod(shape)
    # a header may not claim more data than is there
    if dtype.hasobject or count * dtype.itemsize > len(reader.buffer) - reader.pos:
        raise CacheFormatError("array header claims more data than the entry holds")
    a = np.frombuffer(reader.buffer, dtype, count, reader.pos).reshape(shape, order="F" if fortran else "C")
    reader.pos += count * dtype.itemsize
    return a


class _Decoder:
    """One `loads`: the value of a JSON node (`node`), given the payload's `arrays`."""

    def __init__(self, arrays: list[np.ndarray]):
        self.arrays = arrays

    def array(self, i) -> np.ndarray:
        if type(i) is not int or not 0 <= i < len(self.arrays):
            raise CacheFormatError(f"array index {i!r}")
        return self.arrays[i]

    def node(self, node):
        if node is None or type(node) in (bool, int, float, str):
            return node
        if type(node) is not dict or len(node) != 1:
            raise CacheFormatError("node is not a value nor a one-key object")
        ((tag, body),) = node.items()
        if tag in ("t", "l") and type(body) is list:
            items = [self.node(x) for x in body]
            return tuple(items) if tag == "t" else items
        if tag == "d" and type(body) is list and all(type(p) is list and len(p) == 2 for p in body):
            return {self.node(k): self.node(x) for k, x in body}
        if tag == "a":
            return self.array(body)
        if tag == "n":
            a = self.array(body)
            if a.ndim != 0:
                raise CacheFormatError("numpy scalar from an array that is not 0-d")
            return a[()]
        if tag == "b":
            a = self.array(body)
            if a.dtype != np.uint8 or a.ndim != 1:
                raise CacheFormatError("bytes from an array that is not 1-d uint8")
            return a.tobytes()
        if tag == "f" and body in _NON_FINITE:
            return _NON_FINITE[body]
        if tag == "c" and type(body) is list and len(body) == 3 and type(body[0]) is str and type(body[1]) is str \
                and type(body[2]) is dict:
            module, qualname, fields = body
            cls = _dataclass(module, qualname)
            if list(fields) != [f.name for f in dataclasses.fields(cls)]:
                raise CacheFormatError(f"{qualname}'s stored fields are not its fields")
            obj = object.__new__(cls)
            for name, x in fields.items():
                object.__setattr__(obj, name, self.node(x))  # frozen dataclasses too, as pickle does
            return obj
        raise CacheFormatError(f"tag {tag!r} with a body of type {type(body).__name__}")


def loads(payload) -> object:
    """The value `dumps` wrote into `payload` (bytes-like).

    Raises
    ------
    CacheFormatError
        When the payload is not one `dumps` writes or names a class it will not build.
    """
    try:
        view = memoryview(payload).cast("B")
        if view.readonly:  # arrays of the cache are writable, as the stage made them
            view = memoryview(bytearray(view))
        reader = _Reader(view)
        n = int.from_bytes(reader.read(_LENGTH), "little")
        if n > len(view) - _LENGTH:
            raise CacheFormatError("JSON length past the end")
        head = json.loads(reader.read(n), parse_constant=_reject_constant)
        if type(head) is not dict or head.keys() != {"arrays", "value"} or type(head["arrays"]) is not int:
            raise CacheFormatError("not a stage cache payload")
        arrays = [_read_array(reader) for _ in range(head["arrays"])]
        if reader.pos != len(view):
            raise CacheFormatError("data after the last array")
        return _Decoder(arrays).node(head["value"])
    except CacheFormatError:
        raise
    # what malformed bytes raise on their way through json, numpy and the checks above
    except (ValueError, TypeError, KeyError, EOFError, OverflowError, RecursionError) as e:
        raise CacheFormatError(f"{type(e).__name__}: {e}") from e
