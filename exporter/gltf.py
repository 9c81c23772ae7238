"""GLB writer for building tiles: triangle primitives with per-feature ids and a property table.

Pure: arrays in, bytes out. An untextured tile is one primitive with POSITION, NORMAL, COLOR_0 and
``_FEATURE_ID_0``; the feature ids index an ``EXT_structural_metadata`` property table (one row per building
or part) through ``EXT_mesh_features``, which is what CesiumJS reads when a feature is picked or styled.
A textured tile (the textures stage's atlas pages) has one primitive per page, with TEXCOORD_0 instead of
COLOR_0 and one material whose baseColorTexture is the page (KTX2 through KHR_texture_basisu or WebP through
EXT_texture_webp, required: no fallback image), plus the vertex-coloured primitive for what has no texture;
every primitive carries the feature ids of its own vertices against the one property table.
Spec notes honoured here: bufferViews start on 8-byte boundaries (metadata requirement), vertex attributes are
4-byte aligned (feature ids as FLOAT, exact up to 2^24), POSITION carries min/max, normals are unit length.

Compact geometry (``compact=True``; the plain path above is unchanged byte for byte):
* KHR_mesh_quantization. Positions are SHORT ``round((p - origin) / step)`` with one uniform step per tile and
  an origin (whole metres, the middle of the tile's bounding box); the node's matrix is
  ``node_matrix @ T(origin) @ S(step)``. **Error bound**: rounding moves each coordinate at most step/2, so a
  vertex at most step * sqrt(3) / 2 (Euclidean) from its float64 input once the node's matrix is applied; step
  is chosen so that this is the tile's bound: 1 cm at leaves, max(1 cm, 1 % of the geometric error) in inner
  tiles (export.position_error_m), which CesiumJS draws only while that error is a few pixels, so 1 % of it is
  far below a pixel. A tile wider than int16 reaches at that step (32767 steps from the origin: 378 m at 1 cm)
  keeps FLOAT positions rounded to a power-of-two step within the same bound and stored through meshopt's
  EXPONENTIAL filter with one shared exponent (24-bit mantissas: the repeated exponent byte costs nothing), so
  every tile is one mesh and one node (plan_quantization). Uniform scale and rigid tile transforms let a custom
  shader recover the scale as length(czm_model[0].xyz): CesiumJS gives shaders POSITION as stored (positionMC).
* Normals BYTE normalized (4-byte stride: CesiumJS draws primitives without normals unlit, so they stay), through
  meshopt's OCTAHEDRAL filter at 8 bits (two varying bytes compress better; 1.2 degrees at worst),
  texcoords UNSIGNED_SHORT integers in quarter texels of their page, scaled back by the material's
  KHR_texture_transform (a texcoord moves at most 1/8 texel; normalized [0, 1] when the page's size is unknown,
  FLOAT outside [0, 1]), feature ids UNSIGNED_BYTE/SHORT (4-byte stride; FLOAT past 65536 rows), colours as
  given (16-bit linear).
* Vertex and index data of every primitive pooled: one view per (semantic, stride, filter), one per index
  width, accessors into them by byteOffset (a TRIANGLES view is decoded as one index buffer; each accessor's
  range is whole triangles), so a glb has a handful of geometry views whatever its primitives.
* KHR_meshopt_compression with vertex codec version 1 (default) or EXT_meshopt_compression with version 0
  (``meshopt_extension``; exporter/meshopt.py): every vertex and index view, and with ``compress_tables`` every
  property-table view (those a whole number of 4-byte groups long: a padded column breaks CesiumJS's table;
  by default tables stay plain, for metadata readers without a meshopt decoder) whose compressed stream plus its JSON
  is smaller than the view is stored compressed in buffer 0 (the BIN chunk) and decoded into
  buffer 1, the fallback buffer (no uri, ``fallback: true``), at 8-byte aligned offsets.
"""

from __future__ import annotations

import json
import struct
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any, Protocol

import numpy as np

from exporter import ATTRIBUTION, __version__, meshopt

BYTE, SHORT = 5120, 5122
FLOAT, UNSIGNED_BYTE, UNSIGNED_SHORT, UNSIGNED_INT = 5126, 5121, 5123, 5125
ARRAY_BUFFER, ELEMENT_ARRAY_BUFFER = 34962, 34963

#: Metadata component types -> numpy dtypes (EXT_structural_metadata SCALAR properties).
SCALAR_DTYPES = {
    "INT8": "<i1",
    "UINT8": "<u1",
    "INT16": "<i2",
    "UINT16": "<u2",
    "INT32": "<i4",
    "UINT32": "<u4",
    "INT64": "<i8",
    "UINT64": "<u8",
    "FLOAT32": "<f4",
    "FLOAT64": "<f8",
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
    mime: str  # image/ktx2 (KHR_texture_basisu), image/webp (EXT_texture_webp), image/png or image/jpeg


#: images that glTF core does not know: the extension that carries each, required (no fallback image)
IMAGE_EXTENSIONS = {"image/webp": "EXT_texture_webp", "image/ktx2": "KHR_texture_basisu"}


LINEAR, LINEAR_MIPMAP_LINEAR, CLAMP_TO_EDGE = 9729, 9987, 33071


#: about what a compressed view's JSON (its extension object and the fallback view) adds to a glb
MESHOPT_JSON_BYTES = 160


class _Builder:
    def __init__(
        self, compact: bool = False, meshopt_extension: str = meshopt.KHR, compress_tables: bool = False
    ) -> None:
        self.bin = bytearray()
        self.compress_tables = compress_tables
        self.views: list[dict[str, object]] = []
        self.accessors: list[dict[str, object]] = []
        self.compact = compact
        if meshopt_extension not in meshopt.VERTEX_VERSION:
            raise ValueError(f"meshopt extension must be one of {', '.join(meshopt.VERTEX_VERSION)}")
        self.ext = meshopt_extension
        self.fallback = 0  # bytes of buffer 1, the decoded views (compact only)
        # compact: vertex and index data pooled by (semantic, stride, filter), one view each (flush): fewer views
        # and one longer meshopt stream per kind; accessors point into them by byteOffset
        self.pools: dict[tuple[str, int, str], list[bytes]] = {}
        self.pool_len: dict[tuple[str, int, str], int] = {}
        self.pooled: list[tuple[dict[str, object], tuple[str, int, str]]] = []
        # compact: property-table columns with the same bytes share one view (column)
        self.columns: dict[tuple[bytes, int], int] = {}

    def pool(self, key: tuple[str, int, str], data: bytes, accessor: dict[str, object]) -> None:
        """Append ``data`` to pool ``key``; ``accessor`` gets its bufferView and byteOffset at flush."""
        at = self.pool_len.get(key, 0)
        self.pools.setdefault(key, []).append(data)
        self.pool_len[key] = at + len(data)
        if at:
            accessor["byteOffset"] = at
        self.pooled.append((accessor, key))

    def flush(self) -> None:
        """One view per pool: vertex pools ATTRIBUTES (byteStride: several accessors share them), index pools one
        TRIANGLES stream (every accessor's range is whole triangles; the decoder decodes the view as a whole)."""
        views: dict[tuple[str, int, str], int] = {}
        for key, parts in self.pools.items():
            data = b"".join(parts)
            name, stride, filter_ = key
            if name == "indices":
                top = int(np.frombuffer(data, "<u2" if stride == 2 else "<u4").max()) + 1
                views[key] = self.packed(data, stride, ELEMENT_ARRAY_BUFFER, triangles=top)
            else:
                views[key] = self.packed(data, stride, ARRAY_BUFFER, vertex_stride=True, filter_=filter_)
        for acc, key in self.pooled:
            acc["bufferView"] = views[key]
        self.pools, self.pool_len, self.pooled = {}, {}, []

    def column(self, data: bytes, itemsize: int) -> int:
        """The view of a property-table column of ``itemsize``-byte values."""
        # With ``compress_tables``, property-table columns compress as ATTRIBUTES too (CesiumJS and loaders.gl
        # decode any view): 4- and 8-byte values as themselves, narrower ones and string bytes in 4-byte groups
        # when they fill them exactly. Never padded: CesiumJS counts a column's values by its view's length and
        # drops the whole table (custom shaders lose their metadata) when that differs from the table's count.
        # By default they stay plain: a reader of metadata without a meshopt decoder (the CesiumGS
        # 3d-tiles-validator) reads a compressed view's bytes as the table.
        stride = itemsize if itemsize % 4 == 0 else 4
        if not self.compact:
            return self.view(data)
        # columns with the same bytes share one view (the landmark columns of tiles without landmarks, ...)
        key = (data, stride)
        if key not in self.columns:
            plain = len(data) % stride or not self.compress_tables
            self.columns[key] = self.view(data) if plain else self.packed(data, stride)
        return self.columns[key]

    def view(self, data: bytes, target: int | None = None) -> int:
        pad = (-len(self.bin)) % 8
        self.bin.extend(b"\0" * pad)
        v: dict[str, object] = {"buffer": 0, "byteOffset": len(self.bin), "byteLength": len(data)}
        if target is not None:
            v["target"] = target
        self.bin.extend(data)
        self.views.append(v)
        return len(self.views) - 1

    def packed(
        self,
        data: bytes,
        stride: int,
        target: int | None = None,
        vertex_stride: bool = False,
        triangles: int = 0,
        filter_: str = "NONE",
    ) -> int:
        """A view stored meshopt-compressed in buffer 0 and decoded into buffer 1 (the fallback buffer, 8-byte
        aligned views: the metadata's requirement): ATTRIBUTES of ``stride``-byte elements, or with
        ``triangles`` (the vertex count) a TRIANGLES index stream of ``stride``-byte indices; ``filter_``
        OCTAHEDRAL or EXPONENTIAL: ``data`` is meshopt.encode_oct's / encode_exp's, the view holds what the filter
        decodes it to. Plain: a view."""
        if not self.compact:
            return self.view(data, target)
        count = len(data) // stride
        if triangles:
            enc = meshopt.encode_triangles(np.frombuffer(data, "<u2" if stride == 2 else "<u4"), triangles)
        else:
            enc = meshopt.encode_attributes(data, stride, meshopt.VERTEX_VERSION[self.ext])
        if len(enc) + MESHOPT_JSON_BYTES >= len(data):
            # a small view the extension's JSON would outweigh: stored as is, decoded (still 8-byte aligned)
            unfilter = meshopt.FILTERS[filter_]
            at = self.view(unfilter(data, count, stride) if unfilter is not None else data, target)
            if vertex_stride:
                self.views[at]["byteStride"] = stride
            return at
        at = self.view(enc)
        src = self.views[at]
        self.fallback += (-self.fallback) % 8
        v: dict[str, object] = {"buffer": 1, "byteOffset": self.fallback, "byteLength": count * stride}
        if vertex_stride:
            v["byteStride"] = stride
        if target is not None:
            v["target"] = target
        compression: dict[str, object] = {
            "buffer": 0,
            "byteOffset": src["byteOffset"],
            "byteLength": src["byteLength"],
            "byteStride": stride,
            "count": count,
            "mode": "TRIANGLES" if triangles else "ATTRIBUTES",
        }
        if filter_ != "NONE":
            compression["filter"] = filter_
        v["extensions"] = {self.ext: compression}
        self.fallback += count * stride
        self.views[at] = v
        return at

    def vertex(
        self,
        array: np.ndarray,
        component: int,
        kind: str,
        semantic: str,
        normalized: bool = False,
        minmax: bool = False,
        filter_: str = "NONE",
        decoded: np.ndarray | None = None,
    ) -> int:
        """A compact vertex attribute: elements padded to a multiple of 4 bytes (meshopt's unit and glTF's
        vertex alignment), pooled with the ``semantic``'s others of that stride and filter (compressed at flush);
        the accessor reads the first ``kind`` components of each. With a filter, ``array`` is the filter's input
        and ``decoded`` what it decodes to (for min/max)."""
        arr = np.ascontiguousarray(array)
        arr2 = arr.reshape(len(arr), -1)
        size = arr2.shape[1] * arr2.dtype.itemsize
        stride = size + (-size) % 4
        rows = np.zeros((len(arr2), stride), np.uint8)
        rows[:, :size] = arr2.view(np.uint8).reshape(len(arr2), size)
        a: dict[str, object] = {"componentType": component, "count": int(len(arr)), "type": kind}
        self.pool((semantic, stride, filter_), rows.tobytes(), a)
        return self._add(a, arr2 if decoded is None else decoded.reshape(len(arr), -1), normalized, minmax)

    def accessor(
        self,
        array: np.ndarray,
        component: int,
        kind: str,
        target: int | None,
        normalized: bool = False,
        minmax: bool = False,
    ) -> int:
        view = self.view(np.ascontiguousarray(array).tobytes(), target)
        a: dict[str, object] = {"bufferView": view, "componentType": component, "count": int(len(array)), "type": kind}
        return self._add(a, array, normalized, minmax)

    def _add(self, a: dict[str, object], values: np.ndarray, normalized: bool, minmax: bool) -> int:
        """Append accessor ``a`` with its normalized flag and the min/max of ``values`` (rows: elements)."""
        if normalized:
            a["normalized"] = True
        if minmax:
            # integers as integers (quantized positions): the same numbers, shorter JSON
            num = int if values.dtype.kind in "iu" else float
            a["min"] = [num(v) for v in values.min(axis=0)]
            a["max"] = [num(v) for v in values.max(axis=0)]
        self.accessors.append(a)
        return len(self.accessors) - 1


def _string_column(values: Sequence[object] | np.ndarray, no_data: str) -> tuple[bytes, bytes]:
    encoded = [(no_data if v is None else str(v)).encode("utf-8") for v in values]
    offsets = np.zeros(len(encoded) + 1, dtype="<u4")
    np.cumsum([len(e) for e in encoded], out=offsets[1:])
    return b"".join(encoded), offsets.tobytes()


@dataclass(frozen=True)
class Quantization:
    """How compact positions are stored, around ``origin`` (whole metres, the positions' frame), within a bound:

    * ``exponent`` None: KHR_mesh_quantization SHORT ``round((p - origin) / step)``; the node's matrix gets
      ``T(origin) @ S(step)``;
    * ``exponent`` e: FLOAT through meshopt's EXPONENTIAL filter with one shared exponent, i.e. ``p - origin``
      rounded to multiples of ``step`` = 2^e (24-bit mantissas: 2^23 steps each way, 97 km at 1 cm), for a mesh
      wider than SHORT reaches at its bound; the node's matrix gets ``T(origin)`` only (positions in metres)."""

    origin: tuple[float, float, float]  # in the positions' frame (m), whole metres
    step: float  # m per unit (SHORT) or the rounding step 2^exponent (FLOAT)
    exponent: int | None = None

    @property
    def scale(self) -> float:
        """The node matrix's scale: the step for SHORT positions, 1 for FLOAT ones (stored in metres)."""
        return self.step if self.exponent is None else 1.0


QMAX = 32767  # SHORT positions in [-32767, 32767]


def _bounds(positions: Sequence[np.ndarray]) -> tuple[np.ndarray, np.ndarray] | None:
    pts = [np.asarray(p, np.float64).reshape(-1, 3) for p in positions if len(p)]
    if not pts:
        return None
    return np.min([p.min(axis=0) for p in pts], axis=0), np.max([p.max(axis=0) for p in pts], axis=0)


def quantization(positions: Sequence[np.ndarray], error_m: float) -> Quantization | None:
    """The coarsest int16 quantization whose positions are within ``error_m`` (Euclidean) of ``positions``
    (rounding each coordinate moves a point at most step/2 per axis, so step = 2 error / sqrt(3)); origin the
    middle of their bounding box. None when the extent needs a finer step than int16 holds."""
    bounds = _bounds(positions)
    if bounds is None:
        return Quantization((0.0, 0.0, 0.0), 1.0)
    lo, hi = bounds
    origin = np.round((lo + hi) / 2.0)
    step = 2.0 * error_m / np.sqrt(3.0)
    reach = float(np.max(np.maximum(hi - origin, origin - lo)))
    if reach / step > QMAX - 0.5:
        return None
    return Quantization((float(origin[0]), float(origin[1]), float(origin[2])), float(step))


def exponential_quantization(positions: Sequence[np.ndarray], error_m: float) -> Quantization:
    """FLOAT positions within ``error_m`` through the EXPONENTIAL filter: the largest power-of-two step at most
    2 error / sqrt(3) (the same bound as SHORT's), coarser only where 24-bit mantissas could not reach the
    extent (beyond 97 km from the origin at 1 cm, where float32 itself is coarser)."""
    bounds = _bounds(positions)
    lo, hi = bounds if bounds is not None else (np.zeros(3), np.zeros(3))
    origin = np.round((lo + hi) / 2.0)
    reach = float(np.max(np.maximum(hi - origin, origin - lo)))
    e = int(np.floor(np.log2(2.0 * error_m / np.sqrt(3.0))))
    while reach / 2.0**e > meshopt.MANTISSA_MAX - 0.5:
        e += 1
    e = min(max(e, meshopt.EXP_MIN), meshopt.EXP_MAX)
    return Quantization((float(origin[0]), float(origin[1]), float(origin[2])), 2.0**e, e)


class Positioned(Protocol):
    """Anything with vertex positions: a Primitive, or content arrays before they become one."""

    @property
    def positions(self) -> np.ndarray: ...


def plan_quantization(prims: Sequence[Positioned], error_m: float) -> Quantization:
    """One quantization for a tile's meshes within ``error_m``: SHORT when int16 reaches its extent at that
    bound, else FLOAT through the EXPONENTIAL filter (one mesh either way: no chunks, so no extra primitives)."""
    positions = [np.asarray(p.positions) for p in prims]
    return quantization(positions, error_m) or exponential_quantization(positions, error_m)


def _compact_primitive(
    b: _Builder,
    prim: Primitive,
    material: int,
    feature_count: int,
    table_count: int,
    q: Quantization | None,
    uv_units: tuple[int, int] | None = None,
) -> dict[str, object]:
    """The primitive with quantized attributes (KHR_mesh_quantization) in meshopt-compressed views: positions
    SHORT or FLOAT through the EXPONENTIAL filter (``q``; plain FLOAT when None), normals BYTE normalized,
    texcoords UNSIGNED_SHORT in ``uv_units`` per page side (their material scales them back with
    KHR_texture_transform; normalized when None), feature ids UNSIGNED_BYTE/SHORT (FLOAT past 65535 rows),
    colours as given; vertices and triangles reordered for the vertex cache first (meshoptimizer), which also
    makes the codecs' deltas small."""
    n = len(prim.positions)
    idx, order = meshopt.reorder(np.asarray(prim.indices), n)
    pos = np.asarray(prim.positions, np.float64)[order]
    if q is None:
        attrs = {"POSITION": b.vertex(pos.astype(np.float32), FLOAT, "VEC3", "POSITION", minmax=True)}
    elif q.exponent is not None:
        packed = meshopt.encode_exp(pos - np.asarray(q.origin), q.exponent)
        decoded = np.frombuffer(meshopt.decode_exp(packed.tobytes(), len(pos), 12), "<f4").reshape(-1, 3)
        attrs = {
            "POSITION": b.vertex(packed, FLOAT, "VEC3", "POSITION", minmax=True, filter_="EXPONENTIAL", decoded=decoded)
        }
    else:
        qpos = np.round((pos - np.asarray(q.origin)) / q.step).astype(np.int16)
        attrs = {"POSITION": b.vertex(qpos, SHORT, "VEC3", "POSITION", minmax=True)}
    nrm = np.asarray(prim.normals, np.float64)[order]
    # octahedral (meshopt's filter, 8 bits as gltfpack's default): 1.2 degrees at worst, 0.4 as plain BYTE
    attrs["NORMAL"] = b.vertex(meshopt.encode_oct(nrm), BYTE, "VEC3", "NORMAL", normalized=True, filter_="OCTAHEDRAL")
    if prim.uvs is not None:
        uv = np.asarray(prim.uvs, np.float64)[order]
        if uv.size and (uv.min() < 0.0 or uv.max() > 1.0):
            attrs["TEXCOORD_0"] = b.vertex(uv.astype(np.float32), FLOAT, "VEC2", "TEXCOORD_0")  # outside [0, 1]: as is
        elif uv_units is not None:
            attrs["TEXCOORD_0"] = b.vertex(
                np.round(uv * uv_units).astype(np.uint16), UNSIGNED_SHORT, "VEC2", "TEXCOORD_0"
            )
        else:
            attrs["TEXCOORD_0"] = b.vertex(
                np.round(uv * 65535.0).astype(np.uint16), UNSIGNED_SHORT, "VEC2", "TEXCOORD_0", normalized=True
            )
    else:
        colors = np.asarray(prim.colors)[order]
        attrs["COLOR_0"] = b.vertex(
            colors if colors.dtype == np.uint16 else colors.astype(np.uint8),
            UNSIGNED_SHORT if colors.dtype == np.uint16 else UNSIGNED_BYTE,
            "VEC4",
            "COLOR_0",
            normalized=True,
        )
    fids = np.asarray(prim.feature_ids)[order]
    if table_count <= 0x100:
        attrs["_FEATURE_ID_0"] = b.vertex(fids.astype(np.uint8), UNSIGNED_BYTE, "SCALAR", "_FEATURE_ID_0")
    elif table_count <= 0x10000:
        attrs["_FEATURE_ID_0"] = b.vertex(fids.astype(np.uint16), UNSIGNED_SHORT, "SCALAR", "_FEATURE_ID_0")
    else:
        attrs["_FEATURE_ID_0"] = b.vertex(fids.astype(np.float32), FLOAT, "SCALAR", "_FEATURE_ID_0")
    small = len(order) <= 0xFFFF
    acc: dict[str, object] = {
        "componentType": UNSIGNED_SHORT if small else UNSIGNED_INT,
        "count": int(len(idx)),
        "type": "SCALAR",
    }
    b.pool(("indices", 2 if small else 4, "NONE"), idx.astype(np.uint16 if small else np.uint32).tobytes(), acc)
    b.accessors.append(acc)
    return {
        "attributes": attrs,
        "indices": len(b.accessors) - 1,
        "material": material,
        "mode": 4,
        "extensions": {
            "EXT_mesh_features": {
                "featureIds": [{"featureCount": int(feature_count), "attribute": 0, "propertyTable": 0}]
            }
        },
    }


def _check_lengths(prim: Primitive) -> None:
    n = len(prim.positions)
    textured = prim.uvs is not None
    if (
        not (len(prim.normals) == len(prim.feature_ids) == n)
        or (len(prim.colors) != n and not textured)
        or (prim.uvs is not None and len(prim.uvs) != n)
    ):
        raise ValueError("vertex attribute arrays must have the same length")
    if len(prim.indices) % 3:
        raise ValueError("indices must describe whole triangles")


def _primitive(b: _Builder, prim: Primitive, material: int, feature_count: int) -> dict[str, object]:
    _check_lengths(prim)
    n = len(prim.positions)
    textured = prim.uvs is not None
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
        attrs["COLOR_0"] = b.accessor(
            colors if colors.dtype == np.uint16 else colors.astype(np.uint8),
            UNSIGNED_SHORT if colors.dtype == np.uint16 else UNSIGNED_BYTE,
            "VEC4",
            ARRAY_BUFFER,
            normalized=True,
        )
    attrs["_FEATURE_ID_0"] = b.accessor(np.asarray(prim.feature_ids, dtype=np.float32), FLOAT, "SCALAR", ARRAY_BUFFER)
    # 16-bit indices whenever the vertices fit: half the index bytes for almost every tile
    small = n <= 0xFFFF
    idx = b.accessor(
        np.asarray(prim.indices, dtype=np.uint16 if small else np.uint32),
        UNSIGNED_SHORT if small else UNSIGNED_INT,
        "SCALAR",
        ELEMENT_ARRAY_BUFFER,
    )
    return {
        "attributes": attrs,
        "indices": idx,
        "material": material,
        "mode": 4,
        "extensions": {
            "EXT_mesh_features": {
                "featureIds": [{"featureCount": int(feature_count), "attribute": 0, "propertyTable": 0}]
            }
        },
    }


def write_glb(
    prim: Primitive,
    class_name: str = "building",
    class_description: str = "",
    textured: Sequence[Primitive] = (),
    images: Sequence[Image] = (),
    node_matrix: Sequence[float] | None = None,
    compact: bool = False,
    quantization: Quantization | None = None,
    meshopt_extension: str = meshopt.KHR,
    compress_tables: bool = False,
) -> bytes:
    """The glb of ``prim`` (vertex colours; its properties make the property table), plus the ``textured``
    primitives (uvs and image set) with ``images``. Without textured primitives the output is the single
    vertex-coloured primitive; with them an empty ``prim`` is left out.
    ``node_matrix``: 16 floats, column-major, the glTF node transform from the mesh's metric frame (the
    positions given) to the frame the tileset places the content in; None = identity.
    ``compact``: KHR_mesh_quantization + ``meshopt_extension`` (KHR_meshopt_compression, vertex codec 1, or
    EXT_meshopt_compression, codec 0; ``quantization`` for SHORT or EXPONENTIAL-filtered positions, None for
    plain FLOAT ones); the node's matrix becomes ``node_matrix @ T(origin) @ S(scale)``, and texcoords are
    integers in quarter texels of their page (KHR_texture_transform scales them back). Raises
    meshopt.CompressionError when meshoptimizer refuses a stream (the caller writes the tile plain).
    ``compress_tables`` (compact only) meshopt-compresses the property tables' views too; by default they stay
    plain, readable by tools that read metadata without a meshopt decoder (the 3D Tiles validator)."""
    if quantization is not None and not compact:
        raise ValueError("quantization needs compact=True")
    b = _Builder(compact, meshopt_extension, compress_tables)
    materials, primitives, transformed = _meshes(b, prim, textured, images, quantization)
    b.flush()
    class_props, table_props = _table_columns(b, prim, class_name, class_description)
    # the images go last into the buffer (when there are textured primitives)
    image_views = [b.view(im.data) for im in images] if textured else []

    gltf: dict[str, Any] = {
        "asset": {"version": "2.0", "generator": f"citylod {__version__}", "copyright": ATTRIBUTION},
        "extensionsUsed": ["EXT_mesh_features", "EXT_structural_metadata"],
        "scene": 0,
        "scenes": [{"nodes": [0]}],
        "nodes": [_node(0, _compose(node_matrix, quantization))],
        "materials": materials,
        "meshes": [{"primitives": primitives}],
        "extensions": {
            "EXT_structural_metadata": {
                "schema": {
                    "id": "citylod",
                    "classes": {
                        class_name: {
                            **class_schema((), class_name, class_description, descriptions=not compact),
                            "properties": class_props,
                        }
                    },
                },
                "propertyTables": [{"class": class_name, "count": int(prim.feature_count), "properties": table_props}],
            }
        },
        "accessors": b.accessors,
        "bufferViews": b.views,
        "buffers": [{"byteLength": len(b.bin)}],
    }
    if textured:
        _add_images(gltf, images, image_views)
    if compact:
        _add_compact_extensions(gltf, b, transformed, meshopt_extension)
    return _pack(gltf, bytes(b.bin))


def _meshes(
    b: _Builder, prim: Primitive, textured: Sequence[Primitive], images: Sequence[Image], q: Quantization | None
) -> tuple[list[dict[str, object]], list[dict[str, object]], bool]:
    """(materials, primitives, whether some texcoords need KHR_texture_transform) of write_glb: the
    vertex-coloured ``prim`` (left out when empty next to textured ones), then one per ``textured`` primitive
    with its atlas page's material."""
    primitives: list[dict[str, object]] = []
    materials: list[dict[str, object]] = []
    if not textured or len(prim.indices):
        materials.append(
            {
                "name": "building",
                "pbrMetallicRoughness": {
                    "baseColorFactor": [1, 1, 1, 1],
                    "metallicFactor": 0.0,
                    "roughnessFactor": 1.0,
                },
            }
        )
        # one primitive: every feature has vertices in it (featureCount = the table's); with textured ones
        # next to it, featureCount counts the features of its own vertices (EXT_mesh_features)
        count = prim.feature_count if not textured else len(np.unique(np.asarray(prim.feature_ids)))
        primitives.append(_any_primitive(b, prim, 0, count, prim.feature_count, q))
    transformed = False
    for tp in textured:
        if tp.uvs is None or tp.image is None or not 0 <= tp.image < len(images):
            raise ValueError("a textured primitive needs uvs and the index of one of the images")
        units = _uv_units(tp.uvs, images[tp.image]) if b.compact else None
        info: dict[str, object] = {"index": tp.image}
        if units is not None:
            info["extensions"] = {"KHR_texture_transform": {"scale": [1.0 / units[0], 1.0 / units[1]]}}
            transformed = True
        materials.append(
            {
                "name": f"atlas page {tp.image}",
                "pbrMetallicRoughness": {"baseColorTexture": info, "metallicFactor": 0.0, "roughnessFactor": 1.0},
            }
        )
        count = len(np.unique(np.asarray(tp.feature_ids)))
        primitives.append(_any_primitive(b, tp, len(materials) - 1, count, prim.feature_count, q, units))
    return materials, primitives, transformed


def _any_primitive(
    b: _Builder,
    p: Primitive,
    material: int,
    count: int,
    table_count: int,
    q: Quantization | None,
    uv_units: tuple[int, int] | None = None,
) -> dict[str, object]:
    """The plain primitive, or with a compact builder the quantized one."""
    if not b.compact:
        return _primitive(b, p, material, count)
    _check_lengths(p)
    return _compact_primitive(b, p, material, count, table_count, q, uv_units)


def _table_columns(
    b: _Builder, prim: Primitive, class_name: str, class_description: str
) -> tuple[dict[str, object], dict[str, object]]:
    """(class properties, property-table columns) of ``prim``'s properties, the columns' views added to ``b``.
    A column whose every value is noData is left out of the table (its class property stays): strings that
    are not required, and in compact glbs optional scalars."""
    compact = b.compact
    # compact: the descriptions are in tileset.json's schema (exporter/export.py), not repeated in every glb
    specs = class_schema(prim.properties, class_name, class_description, descriptions=not compact)["properties"]
    class_props: dict[str, object] = {}
    table_props: dict[str, object] = {}
    for p in prim.properties:
        if len(p.values) != prim.feature_count:
            raise ValueError(f"property {p.name} has {len(p.values)} values for {prim.feature_count} features")
        spec = specs[p.name]
        if p.component_type is None:
            no_data = "" if p.no_data is None else str(p.no_data)
            data, offsets = _string_column(p.values, no_data)
            if not data and not p.required:
                class_props[p.name] = spec  # every value is noData: the column may be omitted from the table
                continue
            # bufferViews must not be empty; a spare byte past the last offset is never read
            table_props[p.name] = {
                "values": b.column(data or b"\0", 1),
                "stringOffsets": b.column(offsets, 4),
                "stringOffsetType": "UINT32",
            }
        else:
            dtype = np.dtype(SCALAR_DTYPES[p.component_type])
            vals = np.array([p.no_data if v is None else v for v in p.values], dtype=dtype)
            if compact and "noData" in spec and np.all(vals == np.array(p.no_data, dtype)):
                class_props[p.name] = spec  # optional and every value noData: omitted, like such strings
                continue
            table_props[p.name] = {"values": b.column(vals.tobytes(), dtype.itemsize)}
        class_props[p.name] = spec
    return class_props, table_props


def _add_images(gltf: dict[str, Any], images: Sequence[Image], image_views: Sequence[int]) -> None:
    """The atlas pages' images, their sampler and textures, and the image extensions they need."""
    # WebP and KTX2 only through their extensions, required: the pages exist in no other format (no fallback)
    image_ext = [IMAGE_EXTENSIONS.get(im.mime) for im in images]
    gltf["images"] = [{"bufferView": v, "mimeType": im.mime} for v, im in zip(image_views, images, strict=True)]
    # KTX2 pages carry their full mip chain; WebP pages get theirs from the client (CesiumJS generates them)
    gltf["samplers"] = [
        {"magFilter": LINEAR, "minFilter": LINEAR_MIPMAP_LINEAR, "wrapS": CLAMP_TO_EDGE, "wrapT": CLAMP_TO_EDGE}
    ]
    gltf["textures"] = [
        {"sampler": 0, "extensions": {e: {"source": i}}} if e else {"sampler": 0, "source": i}
        for i, e in enumerate(image_ext)
    ]
    used = sorted({e for e in image_ext if e})
    if used:
        gltf["extensionsUsed"] = [*gltf["extensionsUsed"], *used]
        gltf["extensionsRequired"] = used


def _add_compact_extensions(gltf: dict[str, Any], b: _Builder, transformed: bool, meshopt_extension: str) -> None:
    """The extensions compact geometry needs (required), and the fallback buffer when some view is compressed."""
    ext = ["KHR_mesh_quantization"]  # always: normals are BYTE
    if transformed:  # integer texcoords mean nothing without their scale
        ext.append("KHR_texture_transform")
    if b.fallback:  # some view is compressed (a tiny glb may have none worth it)
        gltf["buffers"] = [
            {"byteLength": len(b.bin)},
            {"byteLength": b.fallback, "extensions": {meshopt_extension: {"fallback": True}}},
        ]
        ext.append(meshopt_extension)
    gltf["extensionsUsed"] = [*gltf["extensionsUsed"], *ext]
    gltf["extensionsRequired"] = [*gltf.get("extensionsRequired", []), *ext]


def class_schema(
    properties: Sequence[Property], class_name: str = "building", class_description: str = "", descriptions: bool = True
) -> dict[str, Any]:
    """The EXT_structural_metadata / 3D Tiles 1.1 schema class of ``properties`` (their values unused): type,
    componentType, noData (optional ones), required, and with ``descriptions`` the words."""
    cls: dict[str, Any] = {"name": class_name.capitalize()}
    if descriptions:
        cls["description"] = class_description
    props: dict[str, object] = {}
    for p in properties:
        spec: dict[str, object] = {"description": p.description} if p.description and descriptions else {}
        if p.component_type is None:
            spec["type"] = "STRING"
            if not p.required:
                spec["noData"] = "" if p.no_data is None else str(p.no_data)
        else:
            spec["type"] = "SCALAR"
            spec["componentType"] = p.component_type
            if p.no_data is not None and not p.required:
                spec["noData"] = p.no_data
        if p.required:
            spec["required"] = True
        props[p.name] = spec
    cls["properties"] = props
    return cls


#: compact texcoords are integers in 1/UV_SUBTEXEL of a texel: a texcoord moves at most 1/(2 UV_SUBTEXEL) texel
UV_SUBTEXEL = 4


def _uv_units(uvs: np.ndarray, image: Image) -> tuple[int, int] | None:
    """(units across, units down) of an image for integer texcoords (UV_SUBTEXEL per texel), or None when
    they cannot be used: uvs outside [0, 1], an image whose size its header does not give, or one too large
    for UNSIGNED_SHORT."""
    uv = np.asarray(uvs)
    size = image_size(image)
    if size is None or (uv.size and (uv.min() < 0.0 or uv.max() > 1.0)):
        return None
    units = (size[0] * UV_SUBTEXEL, size[1] * UV_SUBTEXEL)
    return units if max(units) <= 0xFFFF else None


def image_size(image: Image) -> tuple[int, int] | None:
    """(width, height) in pixels from an encoded image's header (KTX2, WebP, PNG), None when it is not one."""
    d = image.data
    if d[:12] == b"\xabKTX 20\xbb\r\n\x1a\n" and len(d) >= 28:
        w, h = struct.unpack_from("<II", d, 20)
        return (w, h) if w and h else None
    if d[:4] == b"RIFF" and d[8:12] == b"WEBP" and len(d) >= 30:
        chunk = d[12:16]
        if chunk == b"VP8 " and d[23:26] == b"\x9d\x01\x2a":
            w, h = struct.unpack_from("<HH", d, 26)
            return w & 0x3FFF, h & 0x3FFF
        if chunk == b"VP8L" and d[20] == 0x2F:
            bits = int.from_bytes(d[21:25], "little")
            return (bits & 0x3FFF) + 1, ((bits >> 14) & 0x3FFF) + 1
        if chunk == b"VP8X":
            return int.from_bytes(d[24:27], "little") + 1, int.from_bytes(d[27:30], "little") + 1
        return None
    if d[:8] == b"\x89PNG\r\n\x1a\n" and len(d) >= 24:
        return struct.unpack_from(">II", d, 16)
    return None


def _compose(node_matrix: Sequence[float] | None, q: Quantization | None) -> list[float] | None:
    """node_matrix @ T(origin) @ S(scale) (column-major), or node_matrix itself without quantization."""
    if q is None:
        return None if node_matrix is None else list(node_matrix)
    m = np.eye(4) if node_matrix is None else np.asarray(node_matrix, np.float64).reshape(4, 4).T
    if m.shape != (4, 4):
        raise ValueError("node_matrix must have 16 values (column-major 4x4)")
    ts = np.diag([q.scale, q.scale, q.scale, 1.0])
    ts[:3, 3] = q.origin
    return (m @ ts).T.ravel().tolist()


def _node(mesh: int, matrix: Sequence[float] | None) -> dict[str, object]:
    if matrix is None:
        return {"mesh": mesh}
    m = [float(v) for v in matrix]
    if len(m) != 16:
        raise ValueError(f"node_matrix must have 16 values (column-major 4x4), not {len(m)}")
    return {"mesh": mesh, "matrix": m}


def _pack(gltf: dict[str, object], binary: bytes) -> bytes:
    js = json.dumps(gltf, separators=(",", ":"), ensure_ascii=False).encode("utf-8")
    js += b" " * ((-len(js)) % 4)
    binary += b"\0" * ((-len(binary)) % 4)
    total = 12 + 8 + len(js) + 8 + len(binary)
    return b"".join(
        [
            struct.pack("<4sII", b"glTF", 2, total),
            struct.pack("<I4s", len(js), b"JSON"),
            js,
            struct.pack("<I4s", len(binary), b"BIN\0"),
            binary,
        ]
    )


def read_glb(data: bytes) -> tuple[dict[str, Any], bytes]:
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


def view_bytes(gltf: dict, binary: bytes, index: int) -> bytes:
    """The bytes of bufferView ``index``: straight from the BIN chunk, or decoded from its
    KHR_/EXT_meshopt_compression stream (the view then lies in the fallback buffer, which has no bytes of its own)."""
    view = gltf["bufferViews"][index]
    exts = view.get("extensions", {})
    ext = exts.get(meshopt.KHR, exts.get(meshopt.EXT))
    if ext is None:
        start = view.get("byteOffset", 0)
        return binary[start : start + view["byteLength"]]
    if ext["buffer"] != 0:
        raise ValueError("compressed data outside the GLB's BIN chunk")
    src = binary[ext.get("byteOffset", 0) : ext.get("byteOffset", 0) + ext["byteLength"]]
    return meshopt.decode(src, ext["count"], ext["byteStride"], ext["mode"], ext.get("filter", "NONE"))


def accessor_array(gltf: dict, binary: bytes, index: int) -> np.ndarray:
    """Accessor ``index`` as stored (meshopt decoded, strided views unpacked; quantized values stay integers:
    see node_positions / mesh_positions for metres) in a numpy array."""
    acc = gltf["accessors"][index]
    view = gltf["bufferViews"][acc["bufferView"]]
    data = view_bytes(gltf, binary, acc["bufferView"])
    width = _WIDTH[acc["type"]]
    dtype = np.dtype(_NP[acc["componentType"]])
    stride = view.get("byteStride", width * dtype.itemsize)
    count, start = acc["count"], acc.get("byteOffset", 0)
    rows = np.frombuffer(
        data, np.uint8, count=(count - 1) * stride + width * dtype.itemsize if count else 0, offset=start
    )
    if count:
        rows = np.lib.stride_tricks.as_strided(rows, (count, width * dtype.itemsize), (stride, 1))
    arr = np.ascontiguousarray(rows).view(dtype).reshape(count, width)
    return arr if width > 1 else arr.reshape(count)


def _node_matrix(gltf: dict, index: int) -> np.ndarray:
    """The matrix (row-major 4x4; identity when absent) of the node whose mesh holds POSITION accessor ``index``."""
    mesh = next(
        i for i, m in enumerate(gltf["meshes"]) for p in m["primitives"] if p["attributes"].get("POSITION") == index
    )
    node = next(n for n in gltf.get("nodes", []) if n.get("mesh") == mesh)
    return np.asarray(node.get("matrix", np.eye(4).ravel()), np.float64).reshape(4, 4).T


def feature_vertices(gltf: dict, binary: bytes, frame: str = "node") -> tuple[np.ndarray, np.ndarray]:
    """(positions (n, 3) in metres, feature ids (n,)) of every primitive of every mesh; ``frame`` node
    (node_positions) or mesh (mesh_positions)."""
    read = node_positions if frame == "node" else mesh_positions
    parts = [
        (
            read(gltf, binary, p["attributes"]["POSITION"]),
            accessor_array(gltf, binary, p["attributes"]["_FEATURE_ID_0"]).astype(np.int64),
        )
        for m in gltf["meshes"]
        for p in m["primitives"]
    ]
    return np.concatenate([q for q, _ in parts]), np.concatenate([f for _, f in parts])


def node_positions(gltf: dict, binary: bytes, index: int) -> np.ndarray:
    """POSITION accessor ``index`` in metres in the frame the node places the mesh in (its matrix applied:
    the tile's frame in a tileset whose tile transforms place the content), float64."""
    m = _node_matrix(gltf, index)
    pos = accessor_array(gltf, binary, index).astype(np.float64)
    return pos @ m[:3, :3].T + m[:3, 3]


def mesh_positions(gltf: dict, binary: bytes, index: int) -> np.ndarray:
    """POSITION accessor ``index`` in metres in the mesh's own frame, the frame of the landmark metadata
    (lm_centre_*, lm_dir_*): the stored values times the node's scale (|column 0| of its matrix; 1 for FLOAT
    positions without a node matrix), before its rotation and translation."""
    scale = float(np.linalg.norm(_node_matrix(gltf, index)[:3, 0]))
    return accessor_array(gltf, binary, index).astype(np.float64) * scale


def property_table(gltf: dict, binary: bytes, fill_no_data: bool = False) -> dict[str, list[object]]:
    """The first EXT_structural_metadata property table as {property: values}: its stored columns, and with
    ``fill_no_data`` also the optional class properties it omits (every value noData) as their noData."""
    meta = gltf["extensions"]["EXT_structural_metadata"]
    table = meta["propertyTables"][0]
    cls = meta["schema"]["classes"][table["class"]]["properties"]
    count = table["count"]
    out: dict[str, list[object]] = {}
    for name, col in table["properties"].items():
        spec = cls[name]
        raw = view_bytes(gltf, binary, col["values"])
        if spec["type"] == "STRING":
            offs = np.frombuffer(view_bytes(gltf, binary, col["stringOffsets"]), "<u4", count=count + 1)
            out[name] = [raw[offs[i] : offs[i + 1]].decode("utf-8") for i in range(count)]
        else:
            out[name] = np.frombuffer(raw, SCALAR_DTYPES[spec["componentType"]], count=count).tolist()
    if fill_no_data:
        for name, spec in cls.items():
            if name not in out and "noData" in spec:
                out[name] = [spec["noData"]] * count
    return out
