"""A corpus of small glTF 2.0 files, one per feature real assets use, written by code (raw JSON + BIN)
so the repository ships no binaries.

`write_corpus(folder)` writes every file and returns, per file name, a `CorpusFile`: what the
loader must do with it (bake, or refuse with a message containing `refuse`) and the values the
tests compare against the baked output. The meshes are tiny: a 24-vertex textured box (as the
Khronos BoxTextured sample) and a small UV sphere.
"""

from __future__ import annotations

import base64
import io
import json
import struct
import zlib
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from PIL import Image as PILImage
from PIL import ImageCms

FLOAT, BYTE, UNSIGNED_BYTE, SHORT, UNSIGNED_SHORT, UNSIGNED_INT = 5126, 5120, 5121, 5122, 5123, 5125
ARRAY_BUFFER, ELEMENT_ARRAY_BUFFER = 34962, 34963
COMPONENTS = {np.dtype(np.float32): FLOAT, np.dtype(np.int8): BYTE, np.dtype(np.uint8): UNSIGNED_BYTE,
              np.dtype(np.int16): SHORT, np.dtype(np.uint16): UNSIGNED_SHORT, np.dtype(np.uint32): UNSIGNED_INT}
TYPES = {1: "SCALAR", 2: "VEC2", 3: "VEC3", 4: "VEC4", 16: "MAT4"}
DRACO = "KHR_draco_mesh_compression"
MESHOPT = "EXT_meshopt_compression"


@dataclass
class CorpusFile:
    """What one corpus file is for.

    Attributes
    ----------
    feature : str
        The glTF feature it exercises, in words.
    refuse : str or None
        None: the file must bake. Otherwise a substring of the one-line error it must be refused with.
    values : dict
        Arrays and numbers the tests compare the load and the bake against.
    technique : str or None
        A technique to bake it with (None: the fallback only).
    """

    feature: str
    refuse: str | None = None
    values: dict = field(default_factory=dict)
    technique: str | None = None


class GltfBuilder:
    """glTF JSON plus one binary buffer; every buffer view starts on a 4-byte boundary."""

    def __init__(self):
        self.doc: dict = {"asset": {"version": "2.0", "generator": "sssbake test corpus"}}
        self.blob = bytearray()

    def add(self, key: str, obj: dict) -> int:
        items = self.doc.setdefault(key, [])
        items.append(obj)
        return len(items) - 1

    def uses(self, extension: str, required: bool = False) -> None:
        for key in ("extensionsUsed",) + (("extensionsRequired",) if required else ()):
            if extension not in self.doc.setdefault(key, []):
                self.doc[key].append(extension)

    def raw(self, data: bytes) -> int:
        """Append `data` (4-byte aligned) outside any buffer view; returns its byte offset."""
        self.blob += b"\0" * (-len(self.blob) % 4)
        start = len(self.blob)
        self.blob += data
        return start

    def view(self, data: bytes, *, target: int | None = None, stride: int | None = None, buffer: int = 0) -> int:
        self.blob += b"\0" * (-len(self.blob) % 4)
        view = {"buffer": buffer, "byteOffset": len(self.blob), "byteLength": len(data)}
        if stride is not None:
            view["byteStride"] = stride
        if target is not None:
            view["target"] = target
        self.blob += data
        return self.add("bufferViews", view)

    def accessor(self, values: np.ndarray | None, *, kind: str | None = None, normalized: bool = False,
                 minmax: bool = False, target: int | None = ARRAY_BUFFER, view: int | None = None, offset: int = 0,
                 count: int | None = None, component: int | None = None) -> int:
        """An accessor of `values` ((n,) or (n, k), already in the stored dtype) in a new buffer view, or in
        `view` at `offset`; `values` None with `count`, `kind` and `component`: an accessor with no data."""
        acc: dict = {}
        if values is not None:
            values = np.asarray(values)
            flat = values.reshape(len(values), -1)
            kind = kind or TYPES[flat.shape[1]]
            component = COMPONENTS[values.dtype]
            count = len(values)
            if view is None:
                stride = None
                if target == ARRAY_BUFFER and flat.shape[1] * values.dtype.itemsize % 4:
                    stride = -(-flat.shape[1] * values.dtype.itemsize // 4) * 4
                    padded = np.zeros((count, stride), np.uint8)
                    padded[:, : flat.shape[1] * values.dtype.itemsize] = flat.view(np.uint8).reshape(count, -1)
                    data = padded.tobytes()
                else:
                    data = np.ascontiguousarray(flat).tobytes()
                view = self.view(data, target=target, stride=stride)
            if minmax:
                acc["min"] = flat.min(axis=0).astype(np.float64).tolist()
                acc["max"] = flat.max(axis=0).astype(np.float64).tolist()
        if view is not None:
            acc["bufferView"] = view
            if offset:
                acc["byteOffset"] = offset
        acc.update(componentType=component, count=count, type=kind)
        if normalized:
            acc["normalized"] = True
        return self.add("accessors", acc)

    def finish(self) -> tuple[dict, bytes]:
        doc = json.loads(json.dumps(self.doc))
        blob = bytes(self.blob) + b"\0" * (-len(self.blob) % 4)
        if blob:
            doc.setdefault("buffers", []).insert(0, {"byteLength": len(blob)})
        return doc, blob

    def glb(self) -> bytes:
        doc, blob = self.finish()
        text = json.dumps(doc, separators=(",", ":")).encode()
        text += b" " * (-len(text) % 4)
        body = struct.pack("<I4s", len(text), b"JSON") + text
        if blob:
            body += struct.pack("<I4s", len(blob), b"BIN\0") + blob
        return struct.pack("<4sII", b"glTF", 2, 12 + len(body)) + body

    def gltf(self, bin_uri: str | None = None) -> tuple[str, bytes]:
        """.gltf text with the buffer as a data: URI (`bin_uri` None) or the external file `bin_uri`."""
        doc, blob = self.finish()
        doc["buffers"][0]["uri"] = bin_uri or "data:application/octet-stream;base64," + base64.b64encode(blob).decode()
        return json.dumps(doc, indent=1), blob


# --- meshes -------------------------------------------------------------------------------------

def box24(size: float = 1.0) -> dict[str, np.ndarray]:
    """The BoxTextured layout: 4 vertices per face (24), outward normals, a 0..1 UV square per face."""
    positions, normals, uvs, faces = [], [], [], []
    for axis in range(3):
        for sign in (1.0, -1.0):
            n = np.zeros(3)
            n[axis] = sign
            u = np.roll([0.0, 1.0, 0.0], axis) if axis != 1 else np.array([1.0, 0.0, 0.0])
            u = u * sign if axis != 1 else u
            v = np.cross(n, u)
            base = len(positions)
            for du, dv in ((-1, -1), (1, -1), (1, 1), (-1, 1)):
                positions.append(0.5 * size * (n + du * u + dv * v))
                normals.append(n)
                uvs.append([(du + 1) / 2, 1 - (dv + 1) / 2])
            faces += [[base, base + 1, base + 2], [base, base + 2, base + 3]]
    out = {"positions": np.array(positions, np.float32), "normals": np.array(normals, np.float32),
           "uvs": np.array(uvs, np.float32), "faces": np.array(faces, np.uint16)}
    return _outward(out)


def uv_sphere(rings: int = 8, segments: int = 12, radius: float = 0.5) -> dict[str, np.ndarray]:
    """A UV sphere with a seam column (uv u = 1 duplicates u = 0) and pole rows."""
    theta = np.linspace(0.0, np.pi, rings + 1)
    phi = np.linspace(0.0, 2 * np.pi, segments + 1)
    t, p = np.meshgrid(theta, phi, indexing="ij")
    normals = np.stack([np.sin(t) * np.cos(p), np.cos(t), np.sin(t) * np.sin(p)], axis=-1).reshape(-1, 3)
    uvs = np.stack([p / (2 * np.pi), t / np.pi], axis=-1).reshape(-1, 2)
    faces = []
    for r in range(rings):
        for s in range(segments):
            a, b = r * (segments + 1) + s, (r + 1) * (segments + 1) + s
            if r != 0:
                faces.append([a, a + 1, b])
            if r != rings - 1:
                faces.append([a + 1, b + 1, b])
    out = {"positions": (normals * radius).astype(np.float32), "normals": normals.astype(np.float32),
           "uvs": uvs.astype(np.float32), "faces": np.array(faces, np.uint16)}
    used = np.unique(out["faces"])  # pole rows keep one vertex per segment that no face uses
    remap = np.full(len(normals), -1)
    remap[used] = np.arange(len(used))
    out = {k: (v[used] if k != "faces" else remap[v].astype(np.uint16)) for k, v in out.items()}
    return _outward(out)


def _outward(mesh: dict) -> dict:
    p = mesh["positions"].astype(np.float64)[mesh["faces"]]
    volume = np.einsum("ij,ij->i", p[:, 0], np.cross(p[:, 1], p[:, 2])).sum()
    if volume < 0:
        mesh["faces"] = mesh["faces"][:, ::-1].copy()
    return mesh


# --- images -------------------------------------------------------------------------------------

def gradient(w: int = 8, h: int = 8) -> np.ndarray:
    x, y = np.meshgrid(np.arange(w), np.arange(h))
    return np.stack([x * 255 // (w - 1), y * 255 // (h - 1), np.full_like(x, 128)], axis=-1).astype(np.uint8)


def _png_chunk(kind: bytes, data: bytes) -> bytes:
    return struct.pack(">I", len(data)) + kind + data + struct.pack(">I", zlib.crc32(kind + data))


def png(pixels: np.ndarray, colour_chunks: bool = False) -> bytes:
    """PNG bytes; `colour_chunks` adds sRGB, gAMA, cHRM and iCCP (an sRGB ICC profile) after IHDR, as
    image editors write them (glTF-Validator: IMAGE_FEATURES_UNSUPPORTED)."""
    buf = io.BytesIO()
    PILImage.fromarray(pixels).save(buf, format="PNG")
    data = buf.getvalue()
    if not colour_chunks:
        return data
    icc = ImageCms.ImageCmsProfile(ImageCms.createProfile("sRGB")).tobytes()
    # glTF-Validator reads the chunks in order: sRGB, gAMA 45455 and the sRGB cHRM are sRGB; the ICC
    # profile after them makes the colour space "custom" (the Warning).
    extra = (_png_chunk(b"sRGB", b"\0")
             + _png_chunk(b"gAMA", struct.pack(">I", 45455))
             + _png_chunk(b"cHRM", struct.pack(">8I", 31270, 32900, 64000, 33000, 30000, 60000, 15000, 6000))
             + _png_chunk(b"iCCP", b"sRGB\0\0" + zlib.compress(icc)))
    ihdr_end = 8 + 8 + 13 + 4
    assert data[12:16] == b"IHDR"
    return data[:ihdr_end] + extra + data[ihdr_end:]


def encoded(pixels: np.ndarray, fmt: str) -> bytes:
    buf = io.BytesIO()
    PILImage.fromarray(pixels).save(buf, format=fmt, quality=95)
    return buf.getvalue()


# --- meshopt (EXT_meshopt_compression bitstreams, the simplest valid encoding) ------------------

def meshopt_attributes(data: np.ndarray) -> bytes:
    """Mode 0 (ATTRIBUTES) stream of `data` ((count, stride) uint8 rows, stride % 4 == 0): every group of
    16 byte deltas stored as raw bytes (header bits 3), the baseline element (the first one) in the tail."""
    count, stride = data.shape
    out = bytearray(b"\xa0")
    block = min((8192 // stride) & ~15, 256)
    previous = data[0].astype(np.int16)
    for start in range(0, count, block):
        rows = data[start : start + block].astype(np.int16)
        deltas = (np.diff(np.vstack([previous, rows]), axis=0) & 0xFF).astype(np.uint8)
        previous = rows[-1]
        zigzag = np.where(deltas & 0x80, ~(deltas.astype(np.uint16) << 1) & 0xFF, deltas.astype(np.uint16) << 1)
        groups = -(-len(rows) // 16)
        padded = np.zeros((groups * 16, stride), np.uint8)
        padded[: len(rows)] = zigzag
        for k in range(stride):
            out += bytes([0xFF] * (groups // 4)) + (bytes([(1 << 2 * (groups % 4)) - 1]) if groups % 4 else b"")
            out += padded[:, k].tobytes()
    out += b"\0" * max(32 - stride, 0) + data[0].tobytes()
    return bytes(out)


def meshopt_indices(indices: np.ndarray) -> bytes:
    """Mode 2 (INDICES) stream: one baseline, each index a zigzag varint delta from the previous one."""
    out = bytearray(b"\xd1")
    last = 0
    for i in indices.astype(np.int64):
        delta = int(i) - last
        last = int(i)
        v = ((delta << 1) ^ (delta >> 63)) & 0xFFFFFFFF
        v = (v << 1) & 0xFFFFFFFF  # baseline 0
        while True:
            byte = v & 0x7F
            v >>= 7
            out.append(byte | (0x80 if v else 0))
            if not v:
                break
    return bytes(out) + b"\0\0\0\0"


# --- the corpus ---------------------------------------------------------------------------------

def _material(b: GltfBuilder, name: str = "Wax", texture: int | None = None, transform: dict | None = None,
              tex_coord: int = 0) -> int:
    pbr: dict = {"baseColorFactor": [0.9, 0.85, 0.8, 1.0], "metallicFactor": 0.0, "roughnessFactor": 0.5}
    if texture is not None:
        info: dict = {"index": texture}
        if tex_coord:
            info["texCoord"] = tex_coord
        if transform is not None:
            info["extensions"] = {"KHR_texture_transform": transform}
        pbr["baseColorTexture"] = info
    return b.add("materials", {"name": name, "pbrMetallicRoughness": pbr})


def _texture(b: GltfBuilder, data: bytes, mime: str, uri: str | None = None) -> int:
    image = {"uri": uri} if uri is not None else {"bufferView": b.view(data), "mimeType": mime}
    image_index = b.add("images", image)
    sampler = b.add("samplers", {"magFilter": 9729, "minFilter": 9987, "wrapS": 10497, "wrapT": 10497})
    return b.add("textures", {"sampler": sampler, "source": image_index})


def _mesh(b: GltfBuilder, mesh: dict, material: int | None = 0, **extra_attributes) -> int:
    attributes = {
        "POSITION": b.accessor(mesh["positions"], minmax=True),
        "NORMAL": b.accessor(mesh["normals"]),
        "TEXCOORD_0": b.accessor(mesh["uvs"]),
        **extra_attributes,
    }
    indices = b.accessor(mesh["faces"].reshape(-1), target=ELEMENT_ARRAY_BUFFER)
    prim = {"attributes": attributes, "indices": indices}
    if material is not None:
        prim["material"] = material
    return b.add("meshes", {"name": "Box", "primitives": [prim]})


def _scene(b: GltfBuilder, nodes: list[dict]) -> None:
    first = len(b.doc.get("nodes", []))
    for n in nodes:
        b.add("nodes", n)
    b.doc["scenes"] = [{"nodes": list(range(first, first + len(nodes)))}]
    b.doc["scene"] = 0


def _textured_box(image: bytes, mime: str) -> GltfBuilder:
    b = GltfBuilder()
    _material(b, texture=_texture(b, image, mime))
    _mesh(b, box24())
    _scene(b, [{"name": "Box", "mesh": 0}])
    return b


def _gpu_instanced(required: bool) -> tuple[GltfBuilder, dict]:
    b = GltfBuilder()
    _material(b)
    _mesh(b, box24())
    translations = np.array([[0.0, 0.0, 0.0], [2.0, 0.0, 0.0], [0.0, 0.0, 3.0]], np.float32)
    half = np.sqrt(0.5)
    rotations = np.array([[0, 0, 0, 1], [0, half, 0, half], [0, 0, 0, 1]], np.float32)
    scales = np.ones((3, 3), np.float32)
    attributes = {"TRANSLATION": b.accessor(translations, target=None),
                  "ROTATION": b.accessor(rotations, target=None),
                  "SCALE": b.accessor(scales, target=None)}
    b.uses("EXT_mesh_gpu_instancing", required)
    _scene(b, [{"name": "Crates", "mesh": 0, "translation": [0.0, 1.0, 0.0],
                "extensions": {"EXT_mesh_gpu_instancing": {"attributes": attributes}}}])
    return b, {"translations": translations, "rotations": rotations, "node_translation": [0.0, 1.0, 0.0]}


def _draco(required: bool) -> tuple[GltfBuilder, dict]:
    import DracoPy

    mesh = box24()
    stream = DracoPy.encode(mesh["positions"], mesh["faces"].astype(np.uint32), quantization_bits=14,
                            normals=mesh["normals"].astype(np.float64), tex_coord=mesh["uvs"].astype(np.float64))
    decoded = DracoPy.decode(stream)
    ids = {0: "POSITION", 1: "NORMAL", 3: "TEXCOORD_0"}
    draco_ids = {ids[a["attribute_type"]]: a["unique_id"] for a in decoded.attributes if a["attribute_type"] in ids}
    b = GltfBuilder()
    _material(b)
    n, m = len(decoded.points), decoded.faces.size
    if required:
        attributes = {
            "POSITION": b.accessor(None, kind="VEC3", component=FLOAT, count=n),
            "NORMAL": b.accessor(None, kind="VEC3", component=FLOAT, count=n),
            "TEXCOORD_0": b.accessor(None, kind="VEC2", component=FLOAT, count=n),
        }
        b.doc["accessors"][attributes["POSITION"]].update(min=decoded.points.min(0).astype(float).tolist(),
                                                         max=decoded.points.max(0).astype(float).tolist())
        indices = b.accessor(None, kind="SCALAR", component=UNSIGNED_SHORT, count=m)
    else:  # the uncompressed fallback: the mesh as Draco decodes it (same vertex order and count)
        attributes = {
            "POSITION": b.accessor(decoded.points.astype(np.float32), minmax=True),
            "NORMAL": b.accessor(decoded.normals.astype(np.float32)),
            "TEXCOORD_0": b.accessor(decoded.tex_coord.astype(np.float32)),
        }
        indices = b.accessor(decoded.faces.reshape(-1).astype(np.uint16), target=ELEMENT_ARRAY_BUFFER)
    view = b.view(stream)
    b.add("meshes", {"name": "Box", "primitives": [{
        "attributes": attributes, "indices": indices, "material": 0,
        "extensions": {DRACO: {"bufferView": view, "attributes": draco_ids}}}]})
    b.uses(DRACO, required)
    _scene(b, [{"name": "Box", "mesh": 0}])
    return b, {"positions": mesh["positions"], "faces": mesh["faces"], "uvs": mesh["uvs"],
               "decoded_positions": decoded.points.astype(np.float32)}


def _meshopt(required: bool) -> tuple[GltfBuilder, dict]:
    """POSITION+NORMAL interleaved (stride 24) and indices, each view meshopt-compressed."""
    mesh = box24()
    vertices = np.hstack([mesh["positions"], mesh["normals"]]).astype(np.float32)
    rows = vertices.view(np.uint8).reshape(len(vertices), -1)
    indices = mesh["faces"].reshape(-1).astype(np.uint16)
    b = GltfBuilder()
    _material(b)
    vertex_stream, index_stream = meshopt_attributes(rows), meshopt_indices(indices)
    streams = [(b.raw(stream), len(stream)) for stream in (vertex_stream, index_stream)]
    if required:  # placeholder buffer 1 (no uri) holds the uncompressed layout
        b.doc["buffers"] = [{"byteLength": rows.nbytes + indices.nbytes + 4,
                             "extensions": {MESHOPT: {"fallback": True}}}]
        vertex_view = b.add("bufferViews", {"buffer": 1, "byteOffset": 0, "byteLength": rows.nbytes,
                                            "byteStride": 24, "target": ARRAY_BUFFER})
        index_view = b.add("bufferViews", {"buffer": 1, "byteOffset": rows.nbytes, "byteLength": indices.nbytes,
                                           "target": ELEMENT_ARRAY_BUFFER})
    else:
        vertex_view = b.view(rows.tobytes(), target=ARRAY_BUFFER, stride=24)
        index_view = b.view(indices.tobytes(), target=ELEMENT_ARRAY_BUFFER)
    for view, (start, length), stride, count, mode in ((vertex_view, streams[0], 24, len(rows), "ATTRIBUTES"),
                                                       (index_view, streams[1], 2, len(indices), "INDICES")):
        b.doc["bufferViews"][view]["extensions"] = {MESHOPT: {
            "buffer": 0, "byteOffset": start, "byteLength": length, "byteStride": stride, "count": count, "mode": mode}}
    position = b.accessor(None, kind="VEC3", component=FLOAT, count=len(rows), view=vertex_view)
    b.doc["accessors"][position].update(min=mesh["positions"].min(0).tolist(), max=mesh["positions"].max(0).tolist())
    normal = b.accessor(None, kind="VEC3", component=FLOAT, count=len(rows), view=vertex_view, offset=12)
    index = b.accessor(None, kind="SCALAR", component=UNSIGNED_SHORT, count=len(indices), view=index_view)
    b.add("meshes", {"name": "Box", "primitives": [{"attributes": {"POSITION": position, "NORMAL": normal},
                                                    "indices": index, "material": 0}]})
    b.uses(MESHOPT, required)
    _scene(b, [{"name": "Box", "mesh": 0}])
    return b, {"positions": mesh["positions"], "normals": mesh["normals"], "faces": mesh["faces"],
               "vertex_stream": vertex_stream, "index_stream": index_stream, "rows": rows, "indices": indices}


def write_corpus(folder: Path) -> dict[str, CorpusFile]:
    """Write the corpus into `folder` (created if missing); returns file name -> `CorpusFile`."""
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    files: dict[str, CorpusFile] = {}
    pixels = gradient()

    def put(name: str, builder: GltfBuilder, spec: CorpusFile) -> None:
        (folder / name).write_bytes(builder.glb())
        files[name] = spec

    # Textures: a PNG with colour-space chunks (as BoxTextured.glb), a JPEG.
    coloured = png(pixels, colour_chunks=True)
    put("box_textured_colorspace.glb", _textured_box(coloured, "image/png"),
        CorpusFile("textured box, PNG with iCCP/sRGB/gAMA/cHRM chunks", values={"image": coloured}, technique="screen"))
    jpeg = encoded(pixels, "JPEG")
    put("box_textured_jpeg.glb", _textured_box(jpeg, "image/jpeg"),
        CorpusFile("textured box, JPEG base colour", values={"image": jpeg}))
    # Input errors: a JPEG declared as image/png (IMAGE_MIME_TYPE_INVALID; the copy is labelled by its
    # bytes), and a PNG cut short (IMAGE_UNEXPECTED_EOS: copied as it is, an inherited error).
    put("mislabelled_jpeg.glb", _textured_box(jpeg, "image/png"),
        CorpusFile("JPEG declared image/png (an input error the copy fixes)", values={"image": jpeg}))
    truncated = png(pixels)[:20]
    put("truncated_png.glb", _textured_box(truncated, "image/png"),
        CorpusFile("PNG cut short (an input error the copy inherits)", values={"image": truncated}))

    # KHR_texture_transform on the base colour, overriding the UV set.
    b = GltfBuilder()
    box = box24()
    transform = {"offset": [0.25, 0.5], "rotation": 0.5, "scale": [2.0, 3.0], "texCoord": 1}
    _material(b, texture=_texture(b, png(pixels), "image/png"), transform=transform)
    _mesh(b, box, TEXCOORD_1=b.accessor((box["uvs"] * 0.5).astype(np.float32)))
    b.uses("KHR_texture_transform")
    _scene(b, [{"name": "Box", "mesh": 0}])
    put("texture_transform.glb", b, CorpusFile("KHR_texture_transform (used), texCoord override",
                                               values={"transform": transform}))

    # Sparse accessors: a substitution over a buffer view, and one with no buffer view at all.
    b = GltfBuilder()
    box = box24()
    _material(b)
    moved = np.array([2, 5, 17], np.uint16)
    moved_to = box["positions"][moved] * 1.5
    expected = box["positions"].copy()
    expected[moved] = moved_to
    attrs = _mesh(b, box)
    pos = b.doc["meshes"][attrs]["primitives"][0]["attributes"]["POSITION"]
    b.doc["accessors"][pos].update(min=expected.min(0).tolist(), max=expected.max(0).tolist(), sparse={
        "count": len(moved), "indices": {"bufferView": b.view(moved.tobytes()), "componentType": UNSIGNED_SHORT},
        "values": {"bufferView": b.view(moved_to.astype(np.float32).tobytes())}})
    _scene(b, [{"name": "Box", "mesh": 0}])
    put("sparse_substitution.glb", b, CorpusFile("sparse POSITION substitution", values={"positions": expected}))

    b = GltfBuilder()
    sphere = uv_sphere()
    _material(b)
    n = len(sphere["positions"])
    order = np.random.default_rng(7).permutation(n).astype(np.uint16)
    order.sort()  # sparse indices must increase
    pos = b.accessor(None, kind="VEC3", component=FLOAT, count=n)
    b.doc["accessors"][pos].update(min=sphere["positions"].min(0).tolist(), max=sphere["positions"].max(0).tolist(),
                                   sparse={"count": n,
                                           "indices": {"bufferView": b.view(order.tobytes()),
                                                       "componentType": UNSIGNED_SHORT},
                                           "values": {"bufferView": b.view(sphere["positions"][order].tobytes())}})
    # COLOR_0 all zeros but for a sparse few: the rest of a sparse accessor without a view is 0.
    lit = np.array([0, 7, 11], np.uint8)
    colour = b.accessor(None, kind="VEC3", component=FLOAT, count=n)
    b.doc["accessors"][colour]["sparse"] = {
        "count": 3, "indices": {"bufferView": b.view(lit.tobytes()), "componentType": UNSIGNED_BYTE},
        "values": {"bufferView": b.view(np.full((3, 3), 0.5, np.float32).tobytes())}}
    b.add("meshes", {"name": "Sphere", "primitives": [{
        "attributes": {"POSITION": pos, "NORMAL": b.accessor(sphere["normals"]), "COLOR_0": colour},
        "indices": b.accessor(sphere["faces"].reshape(-1), target=ELEMENT_ARRAY_BUFFER), "material": 0}]})
    _scene(b, [{"name": "Sphere", "mesh": 0}])
    colours = np.zeros((n, 3))
    colours[lit] = 0.5
    put("sparse_no_bufferview.glb", b, CorpusFile("sparse accessors with no buffer view (POSITION, COLOR_0)",
                                                  values={"positions": sphere["positions"], "colors": colours}))

    # Two UV sets, both normalized integers (core glTF allows unsigned byte/short normalized UVs).
    b = GltfBuilder()
    box = box24()
    _material(b, texture=_texture(b, png(pixels), "image/png"), tex_coord=1)
    uv0 = np.round(box["uvs"] * 255).astype(np.uint8)
    uv1 = np.round(box["uvs"][::-1] * 65535 * 0.75).astype(np.uint16)
    mesh = b.add("meshes", {"name": "Box", "primitives": [{"attributes": {
        "POSITION": b.accessor(box["positions"], minmax=True), "NORMAL": b.accessor(box["normals"]),
        "TEXCOORD_0": b.accessor(uv0, normalized=True), "TEXCOORD_1": b.accessor(uv1, normalized=True)},
        "indices": b.accessor(box["faces"].reshape(-1), target=ELEMENT_ARRAY_BUFFER), "material": 0}]})
    _scene(b, [{"name": "Box", "mesh": mesh}])
    put("uv_sets_normalized.glb", b, CorpusFile("TEXCOORD_0 unorm8 + TEXCOORD_1 unorm16",
                                                values={"uv0": uv0 / 255.0, "uv1": uv1 / 65535.0}))

    # Vertex colours: float VEC3 on one primitive, unorm8 and unorm16 VEC4 on two more.
    b = GltfBuilder()
    sphere = uv_sphere()
    _material(b)
    n = len(sphere["positions"])
    rgb = (0.5 + 0.5 * sphere["normals"]).astype(np.float32)
    rgba8 = np.column_stack([np.round(rgb * 255), np.full(n, 200)]).astype(np.uint8)
    rgba16 = np.column_stack([np.round(rgb[:, ::-1] * 65535), np.full(n, 40000)]).astype(np.uint16)
    prims = []
    for k, colours in enumerate((b.accessor(rgb), b.accessor(rgba8, normalized=True),
                                 b.accessor(rgba16, normalized=True))):
        shifted = sphere["positions"] + np.float32(1.5 * k) * np.array([1, 0, 0], np.float32)
        prims.append({"attributes": {"POSITION": b.accessor(shifted, minmax=True),
                                     "NORMAL": b.accessor(sphere["normals"]), "COLOR_0": colours},
                      "indices": b.accessor(sphere["faces"].reshape(-1), target=ELEMENT_ARRAY_BUFFER), "material": 0})
    b.add("meshes", {"name": "Spheres", "primitives": prims})
    _scene(b, [{"name": "Spheres", "mesh": 0}])
    put("vertex_colors.glb", b, CorpusFile("COLOR_0 float VEC3, unorm8 VEC4, unorm16 VEC4", values={
        "colors": [np.column_stack([rgb, np.ones(n)]), rgba8 / 255.0, rgba16 / 65535.0]}))

    # Skin: JOINTS_0 / WEIGHTS_0, two joints, inverse bind matrices.
    b = GltfBuilder()
    box = box24()
    _material(b)
    n = len(box["positions"])
    weight = (box["positions"][:, 1] + 0.5).astype(np.float32)
    weights = np.column_stack([1 - weight, weight, np.zeros(n), np.zeros(n)]).astype(np.float32)
    joints = np.where(weights > 0, np.array([0, 1, 0, 0]), 0).astype(np.uint8)  # zero weight: joint 0
    ibm = np.stack([np.eye(4), np.eye(4)]).astype(np.float32)
    ibm[1, 1, 3] = -0.5  # joint 1 sits at y = 0.5
    _mesh(b, box, JOINTS_0=b.accessor(joints), WEIGHTS_0=b.accessor(weights))
    b.doc["skins"] = [{"joints": [1, 2], "inverseBindMatrices": b.accessor(
        ibm.transpose(0, 2, 1).reshape(2, 16).copy(), kind="MAT4", target=None)}]
    _scene(b, [{"name": "Skinned", "mesh": 0, "skin": 0}, {"name": "Root", "children": [2]}])
    b.add("nodes", {"name": "Tip", "translation": [0.0, 0.5, 0.0]})
    b.doc["scenes"][0]["nodes"] = [0, 1]
    put("skinned.glb", b, CorpusFile("skin: JOINTS_0/WEIGHTS_0, inverseBindMatrices", values={"deforming": True}))

    # Morph targets: POSITION and NORMAL deltas, default weights.
    b = GltfBuilder()
    box = box24()
    _material(b)
    mesh = _mesh(b, box)
    delta = (box["positions"] * np.array([0.0, 0.3, 0.0], np.float32)).astype(np.float32)
    b.doc["meshes"][mesh]["primitives"][0]["targets"] = [
        {"POSITION": b.accessor(delta, minmax=True), "NORMAL": b.accessor(np.zeros_like(box["normals"]))}]
    b.doc["meshes"][mesh]["weights"] = [0.0]
    _scene(b, [{"name": "Box", "mesh": 0}])
    put("morph_targets.glb", b, CorpusFile("morph target (POSITION, NORMAL deltas)", values={"deforming": True}))

    # One mesh on two nodes.
    b = GltfBuilder()
    _material(b)
    _mesh(b, box24())
    _scene(b, [{"name": "Left", "mesh": 0, "translation": [-1.0, 0.0, 0.0]},
               {"name": "Right", "mesh": 0, "translation": [1.0, 0.0, 0.0]}])
    put("instanced_nodes.glb", b, CorpusFile("one mesh instanced by two nodes",
                                             values={"translations": [[-1.0, 0.0, 0.0], [1.0, 0.0, 0.0]]}))

    for required in (False, True):
        b, values = _gpu_instanced(required)
        put(f"gpu_instancing_{'required' if required else 'used'}.glb", b,
            CorpusFile(f"EXT_mesh_gpu_instancing ({'required' if required else 'used, not required'})", values=values))

    # Interleaved POSITION/NORMAL/TEXCOORD_0 in one buffer view with byteStride 32.
    b = GltfBuilder()
    sphere = uv_sphere()
    _material(b)
    n = len(sphere["positions"])
    vertex = np.zeros(n, dtype=[("p", "<f4", 3), ("n", "<f4", 3), ("uv", "<f4", 2)])
    vertex["p"], vertex["n"], vertex["uv"] = sphere["positions"], sphere["normals"], sphere["uvs"]
    view = b.view(vertex.tobytes(), target=ARRAY_BUFFER, stride=32)
    pos = b.accessor(None, kind="VEC3", component=FLOAT, count=n, view=view)
    b.doc["accessors"][pos].update(min=sphere["positions"].min(0).tolist(), max=sphere["positions"].max(0).tolist())
    b.add("meshes", {"name": "Sphere", "primitives": [{"attributes": {
        "POSITION": pos, "NORMAL": b.accessor(None, kind="VEC3", component=FLOAT, count=n, view=view, offset=12),
        "TEXCOORD_0": b.accessor(None, kind="VEC2", component=FLOAT, count=n, view=view, offset=24)},
        "indices": b.accessor(sphere["faces"].reshape(-1), target=ELEMENT_ARRAY_BUFFER), "material": 0}]})
    _scene(b, [{"name": "Sphere", "mesh": 0}])
    put("interleaved.glb", b, CorpusFile("interleaved vertex buffer view, byteStride 32",
                                         values={"positions": sphere["positions"], "uvs": sphere["uvs"]}))

    # .gltf with an external .bin and an external PNG; .gltf with data: URIs for both.
    image = png(pixels)
    b = GltfBuilder()
    _material(b, texture=_texture(b, image, "image/png", uri="external%20color.png"))
    _mesh(b, box24())
    _scene(b, [{"name": "Box", "mesh": 0}])
    text, blob = b.gltf("external.bin")
    (folder / "external.gltf").write_text(text)
    (folder / "external.bin").write_bytes(blob)
    (folder / "external color.png").write_bytes(image)
    files["external.gltf"] = CorpusFile(".gltf, external .bin and PNG (URI with an escaped space)",
                                        values={"image": image})
    b = GltfBuilder()
    _material(b, texture=_texture(b, image, "image/png",
                                  uri="data:image/png;base64," + base64.b64encode(image).decode()))
    _mesh(b, box24())
    _scene(b, [{"name": "Box", "mesh": 0}])
    (folder / "data_uri.gltf").write_text(b.gltf()[0])
    files["data_uri.gltf"] = CorpusFile(".gltf, buffer and image as data: URIs", values={"image": image},
                                        technique="screen")

    # Compressed geometry: Draco and meshopt, each required and used with an uncompressed fallback.
    for required in (True, False):
        b, values = _draco(required)
        put(f"draco_{'required' if required else 'fallback'}.glb", b,
            CorpusFile(f"{DRACO} ({'required' if required else 'used, uncompressed fallback'})", values=values))
        b, values = _meshopt(required)
        put(f"meshopt_{'required' if required else 'fallback'}.glb", b, CorpusFile(
            f"{MESHOPT} ({'required' if required else 'used, uncompressed fallback'})", values=values,
            refuse=f"{MESHOPT} is required and not supported" if required else None))

    # A required extension sssbake does not implement: WebP-only textures.
    b = GltfBuilder()
    webp = encoded(pixels, "WEBP")
    image_index = b.add("images", {"bufferView": b.view(webp), "mimeType": "image/webp"})
    texture = b.add("textures", {"extensions": {"EXT_texture_webp": {"source": image_index}}})
    _material(b, texture=texture)
    _mesh(b, box24())
    b.uses("EXT_texture_webp", required=True)
    _scene(b, [{"name": "Box", "mesh": 0}])
    put("webp_required.glb", b, CorpusFile("EXT_texture_webp required (not implemented)",
                                           refuse="EXT_texture_webp is required and not supported"))
    # ... and used, with a PNG fallback: the PNG is the texture's source.
    b = GltfBuilder()
    fallback = png(pixels)
    sources = [b.add("images", {"bufferView": b.view(data), "mimeType": mime})
               for data, mime in ((fallback, "image/png"), (webp, "image/webp"))]
    texture = b.add("textures", {"source": sources[0], "extensions": {"EXT_texture_webp": {"source": sources[1]}}})
    _material(b, texture=texture)
    _mesh(b, box24())
    b.uses("EXT_texture_webp")
    _scene(b, [{"name": "Box", "mesh": 0}])
    put("webp_fallback.glb", b, CorpusFile("EXT_texture_webp used, PNG fallback", values={"image": fallback}))
    return files
