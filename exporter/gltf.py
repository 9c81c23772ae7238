"""GLB writer for building tiles: triangle primitives with per-feature ids and a property table.

Pure: arrays in, bytes out. An untextured tile is one primitive with POSITION, NORMAL, COLOR_0 and
``_FEATURE_ID_0``; the feature ids index an ``EXT_structural_metadata`` property table (one row per building
or part) through ``EXT_mesh_features``, which is what CesiumJS reads when a feature is picked or styled.
A textured tile (the textures stage's atlas pages) has one primitive per page, with TEXCOORD_0 instead of
COLOR_0 and one material whose baseColorTexture is the page (WebP through EXT_texture_webp, required: no
fallback image), plus the vertex-coloured primitive for what has no texture; every primitive carries the
feature ids of its own vertices against the one property table.
Spec notes honoured here: bufferViews start on 8-byte boundaries (metadata requirement), vertex attributes are
4-byte aligned (feature ids as FLOAT, exact up to 2^24), POSITION carries min/max, normals are unit length.
"""

from __future__ import annotations

import json
import struct
from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np

from . import ATTRIBUTION, __version__

FLOAT, UNSIGNED_BYTE, UNSIGNED_SHORT, UNSIGNED_INT = 5126, 5121, 5123, 5125
ARRAY_BUFFER, ELEMENT_ARRAY_BUFFER = 34962, 34963

#: Metadata component types -> numpy dtypes (EXT_structural_metadata SCALAR properties).
SCALAR_DTYPES = {
    "INT8": "<i1", "UINT8": "<u1", "INT16": "<i2", "UINT16": "<u2", "INT32": "<i4", "UINT32": "<u4",
    "INT64": "<i8", "UINT64": "<u8", "FLOAT32": "<f4", "FLOAT64": "<f8",
}


@dataclass(frozen=True)
class Property:
    """A column of the property table: a SCALAR (component_type given) or a STRING (component_type None)."""

    name: str
    values: Sequence[object] | np.ndarray
    component_type: str | None = None
    description: str = ""
    no_data: object | None = None
    required: bool = False


@dataclass
class Primitive:
    positions: np.ndarray  # (n, 3) float32, glTF frame (y up)
    normals: np.ndarray  # (n, 3) float32, unit length
    colors: np.ndarray  # (n, 4) linear RGBA, uint8 or uint16 (normalized)
    feature_ids: np.ndarray  # (n,) int, 0..features-1
    indices: np.ndarray  # (m * 3,) uint32
    properties: list[Property] = field(default_factory=list)
    feature_count: int = 0
    uvs: np.ndarray | None = None  # (n, 2) float32 TEXCOORD_0 ((0, 0) top left of the image): textured
    image: int | None = None  # with uvs: index into write_glb's images, shown as the base colour


@dataclass(frozen=True)
class Image:
    """An encoded texture image stored in the glb's buffer (an atlas page)."""

    data: bytes
    mime: str  # image/webp, image/png or image/jpeg


LINEAR, LINEAR_MIPMAP_LINEAR, CLAMP_TO_EDGE = 9729, 9987, 33071


class _Builder:
    def __init__(self) -> None:
        self.bin = bytearray()
        self.views: list[dict[str, object]] = []
        self.accessors: list[dict[str, object]] = []

    def view(self, data: bytes, target: int | None = None) -> int:
        pad = (-len(self.bin)) % 8
        self.bin.extend(b"\0" * pad)
        v: dict[str, object] = {"buffer": 0, "byteOffset": len(self.bin), "byteLength": len(data)}
        if target is not None:
            v["target"] = target
        self.bin.extend(data)
        self.views.append(v)
        return len(self.views) - 1

    def accessor(self, array: np.ndarray, component: int, kind: str, target: int | None,
                 normalized: bool = False, minmax: bool = False) -> int:
        view = self.view(np.ascontiguousarray(array).tobytes(), target)
        a: dict[str, object] = {"bufferView": view, "componentType": component, "count": int(len(array)),
                                "type": kind}
        if normalized:
            a["normalized"] = True
        if minmax:
            a["min"] = [float(v) for v in array.min(axis=0)]
            a["max"] = [float(v) for v in array.max(axis=0)]
        self.accessors.append(a)
        return len(self.accessors) - 1


def _string_column(values: Sequence[object], no_data: str) -> tuple[bytes, bytes]:
    encoded = [(no_data if v is None else str(v)).encode("utf-8") for v in values]
    offsets = np.zeros(len(encoded) + 1, dtype="<u4")
    np.cumsum([len(e) for e in encoded], out=offsets[1:])
    return b"".join(encoded), offsets.tobytes()


def _primitive(b: _Builder, prim: Primitive, material: int, feature_count: int) -> dict[str, object]:
    n = len(prim.positions)
    textured = prim.uvs is not None
    if not (len(prim.normals) == len(prim.feature_ids) == n) or (len(prim.colors) != n and not textured) \
            or (textured and len(prim.uvs) != n):  # type: ignore[arg-type]
        raise ValueError("vertex attribute arrays must have the same length")
    if len(prim.indices) % 3:
        raise ValueError("indices must describe whole triangles")
    pos = np.asarray(prim.positions, dtype=np.float32)
    attrs = {
        "POSITION": b.accessor(pos, FLOAT, "VEC3", ARRAY_BUFFER, minmax=True),
        "NORMAL": b.accessor(np.asarray(prim.normals, dtype=np.float32), FLOAT, "VEC3", ARRAY_BUFFER),
    }
    if textured:
        attrs["TEXCOORD_0"] = b.accessor(np.asarray(prim.uvs, dtype=np.float32), FLOAT, "VEC2", ARRAY_BUFFER)
    else:
        colors = np.asarray(prim.colors)
        # 16-bit linear colours as they come; anything else is 8-bit
        attrs["COLOR_0"] = b.accessor(colors if colors.dtype == np.uint16 else colors.astype(np.uint8),
                                      UNSIGNED_SHORT if colors.dtype == np.uint16 else UNSIGNED_BYTE, "VEC4",
                                      ARRAY_BUFFER, normalized=True)
    attrs["_FEATURE_ID_0"] = b.accessor(np.asarray(prim.feature_ids, dtype=np.float32), FLOAT, "SCALAR",
                                        ARRAY_BUFFER)
    # 16-bit indices whenever the vertices fit: half the index bytes for almost every tile
    small = n <= 0xFFFF
    idx = b.accessor(np.asarray(prim.indices, dtype=np.uint16 if small else np.uint32),
                     UNSIGNED_SHORT if small else UNSIGNED_INT, "SCALAR", ELEMENT_ARRAY_BUFFER)
    return {
        "attributes": attrs,
        "indices": idx,
        "material": material,
        "mode": 4,
        "extensions": {"EXT_mesh_features": {"featureIds": [
            {"featureCount": int(feature_count), "attribute": 0, "propertyTable": 0}
        ]}},
    }


def write_glb(prim: Primitive, class_name: str = "building", class_description: str = "",
              textured: Sequence[Primitive] = (), images: Sequence[Image] = (),
              node_matrix: Sequence[float] | None = None) -> bytes:
    """The glb of ``prim`` (vertex colours; its properties make the property table), plus the ``textured``
    primitives (uvs and image set) with ``images``. Without textured primitives the output is the single
    vertex-coloured primitive; with them an empty ``prim`` is left out.
    ``node_matrix``: 16 floats, column-major, the glTF node transform from the mesh's metric frame (the
    positions given) to the frame the tileset places the content in; None = identity."""
    b = _Builder()
    materials: list[dict[str, object]] = []
    primitives: list[dict[str, object]] = []
    if not textured or len(prim.indices):
        materials.append({
            "name": "building",
            "pbrMetallicRoughness": {"baseColorFactor": [1, 1, 1, 1], "metallicFactor": 0.0, "roughnessFactor": 1.0},
        })
        # one primitive: every feature has vertices in it (featureCount = the table's); with textured ones
        # next to it, featureCount counts the features of its own vertices (EXT_mesh_features)
        count = prim.feature_count if not textured else len(np.unique(np.asarray(prim.feature_ids)))
        primitives.append(_primitive(b, prim, 0, count))
    for tp in textured:
        if tp.uvs is None or tp.image is None or not 0 <= tp.image < len(images):
            raise ValueError("a textured primitive needs uvs and the index of one of the images")
        materials.append({
            "name": f"atlas page {tp.image}",
            "pbrMetallicRoughness": {"baseColorTexture": {"index": tp.image}, "metallicFactor": 0.0,
                                     "roughnessFactor": 1.0},
        })
        primitives.append(_primitive(b, tp, len(materials) - 1, len(np.unique(np.asarray(tp.feature_ids)))))

    class_props: dict[str, object] = {}
    table_props: dict[str, object] = {}
    for p in prim.properties:
        if len(p.values) != prim.feature_count:
            raise ValueError(f"property {p.name} has {len(p.values)} values for {prim.feature_count} features")
        spec: dict[str, object] = {"description": p.description} if p.description else {}
        if p.component_type is None:
            spec["type"] = "STRING"
            no_data = "" if p.no_data is None else str(p.no_data)
            data, offsets = _string_column(p.values, no_data)
            if not p.required:
                spec["noData"] = no_data
            if not data and not p.required:
                class_props[p.name] = spec  # every value is noData: the column may be omitted from the table
                continue
            # bufferViews must not be empty; a spare byte past the last offset is never read
            table_props[p.name] = {"values": b.view(data or b"\0"), "stringOffsets": b.view(offsets),
                                   "stringOffsetType": "UINT32"}
        else:
            spec["type"] = "SCALAR"
            spec["componentType"] = p.component_type
            dtype = np.dtype(SCALAR_DTYPES[p.component_type])
            vals = np.array([p.no_data if v is None else v for v in p.values], dtype=dtype)
            table_props[p.name] = {"values": b.view(vals.tobytes())}
            if p.no_data is not None and not p.required:
                spec["noData"] = p.no_data
        if p.required:
            spec["required"] = True
        class_props[p.name] = spec
    # the images go last into the buffer (when there are textured primitives)
    image_views = [b.view(im.data) for im in images] if textured else []

    gltf: dict[str, object] = {
        "asset": {"version": "2.0", "generator": f"citylod {__version__}", "copyright": ATTRIBUTION},
        "extensionsUsed": ["EXT_mesh_features", "EXT_structural_metadata"],
        "scene": 0,
        "scenes": [{"nodes": [0]}],
        "nodes": [_node(node_matrix)],
        "materials": materials,
        "meshes": [{"primitives": primitives}],
        "extensions": {"EXT_structural_metadata": {
            "schema": {"id": "citylod", "classes": {class_name: {
                "name": class_name.capitalize(), "description": class_description, "properties": class_props}}},
            "propertyTables": [{"class": class_name, "count": int(prim.feature_count), "properties": table_props}],
        }},
        "accessors": b.accessors,
        "bufferViews": b.views,
        "buffers": [{"byteLength": len(b.bin)}],
    }
    if textured:
        # WebP only through EXT_texture_webp, required: the pages exist in no other format (no fallback)
        webp = [im.mime == "image/webp" for im in images]
        gltf["images"] = [{"bufferView": v, "mimeType": im.mime} for v, im in zip(image_views, images, strict=True)]
        gltf["samplers"] = [{"magFilter": LINEAR, "minFilter": LINEAR_MIPMAP_LINEAR, "wrapS": CLAMP_TO_EDGE,
                             "wrapT": CLAMP_TO_EDGE}]
        gltf["textures"] = [{"sampler": 0, "extensions": {"EXT_texture_webp": {"source": i}}} if w
                            else {"sampler": 0, "source": i} for i, w in enumerate(webp)]
        if any(webp):
            gltf["extensionsUsed"] = [*gltf["extensionsUsed"], "EXT_texture_webp"]  # type: ignore[misc]
            gltf["extensionsRequired"] = ["EXT_texture_webp"]
    return _pack(gltf, bytes(b.bin))


def _node(matrix: Sequence[float] | None) -> dict[str, object]:
    if matrix is None:
        return {"mesh": 0}
    m = [float(v) for v in matrix]
    if len(m) != 16:
        raise ValueError(f"node_matrix must have 16 values (column-major 4x4), not {len(m)}")
    return {"mesh": 0, "matrix": m}


def _pack(gltf: dict[str, object], binary: bytes) -> bytes:
    js = json.dumps(gltf, separators=(",", ":"), ensure_ascii=False).encode("utf-8")
    js += b" " * ((-len(js)) % 4)
    binary += b"\0" * ((-len(binary)) % 4)
    total = 12 + 8 + len(js) + 8 + len(binary)
    return b"".join([
        struct.pack("<4sII", b"glTF", 2, total),
        struct.pack("<I4s", len(js), b"JSON"), js,
        struct.pack("<I4s", len(binary), b"BIN\0"), binary,
    ])


def read_glb(data: bytes) -> tuple[dict[str, object], bytes]:
    """(JSON, BIN chunk) of a GLB; raises ValueError on a malformed container."""
    if len(data) < 20:
        raise ValueError("too short to be a GLB")
    magic, version, total = struct.unpack_from("<4sII", data, 0)
    if magic != b"glTF" or version != 2:
        raise ValueError("not a GLB 2.0 file")
    if total != len(data):
        raise ValueError(f"header length {total} != file size {len(data)}")
    jlen, jtype = struct.unpack_from("<I4s", data, 12)
    if jtype != b"JSON":
        raise ValueError("first chunk is not JSON")
    try:
        gltf = json.loads(data[20 : 20 + jlen])
    except ValueError as e:
        raise ValueError(f"JSON chunk does not parse: {e}") from None
    off = 20 + jlen
    binary = b""
    if off < len(data):
        blen, btype = struct.unpack_from("<I4s", data, off)
        if btype != b"BIN\0":
            raise ValueError("second GLB chunk is not BIN")
        binary = data[off + 8 : off + 8 + blen]
    return gltf, binary


_NP = {5120: "<i1", 5121: "<u1", 5122: "<i2", 5123: "<u2", 5125: "<u4", 5126: "<f4"}
_WIDTH = {"SCALAR": 1, "VEC2": 2, "VEC3": 3, "VEC4": 4}


def accessor_array(gltf: dict, binary: bytes, index: int) -> np.ndarray:
    """Read accessor ``index`` (tightly packed) into a numpy array."""
    acc = gltf["accessors"][index]
    view = gltf["bufferViews"][acc["bufferView"]]
    start = view.get("byteOffset", 0) + acc.get("byteOffset", 0)
    width = _WIDTH[acc["type"]]
    arr = np.frombuffer(binary, dtype=_NP[acc["componentType"]], count=acc["count"] * width, offset=start)
    return arr.reshape(acc["count"], width) if width > 1 else arr


def property_table(gltf: dict, binary: bytes) -> dict[str, list[object]]:
    """The first EXT_structural_metadata property table as {property: values}."""
    meta = gltf["extensions"]["EXT_structural_metadata"]
    table = meta["propertyTables"][0]
    cls = meta["schema"]["classes"][table["class"]]["properties"]
    count = table["count"]
    out: dict[str, list[object]] = {}
    for name, col in table["properties"].items():
        spec = cls[name]
        vview = gltf["bufferViews"][col["values"]]
        vstart, vlen = vview.get("byteOffset", 0), vview["byteLength"]
        if spec["type"] == "STRING":
            oview = gltf["bufferViews"][col["stringOffsets"]]
            offs = np.frombuffer(binary, "<u4", count=count + 1, offset=oview.get("byteOffset", 0))
            raw = binary[vstart : vstart + vlen]
            out[name] = [raw[offs[i] : offs[i + 1]].decode("utf-8") for i in range(count)]
        else:
            out[name] = np.frombuffer(binary, SCALAR_DTYPES[spec["componentType"]], count=count,
                                      offset=vstart).tolist()
    return out
