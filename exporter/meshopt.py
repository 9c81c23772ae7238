"""KHR_meshopt_compression / EXT_meshopt_compression through the meshoptimizer library (PyPI ``meshoptimizer``):
encode, decode, reorder, and the OCTAHEDRAL and EXPONENTIAL filters' encoders (numpy).

Pure: arrays in, bytes out. ATTRIBUTES streams (element size a multiple of 4, at most 256 bytes) use vertex codec
version 1 under KHR_meshopt_compression (its upgraded format: 11-29 % smaller streams here) and version 0 under
EXT_meshopt_compression, which allows no other; TRIANGLES streams index codec version 1 under both. The library
keeps the versions as process-wide state, so the vertex version is set and used under one lock. A stream the
library refuses raises ``CompressionError``; the caller writes that tile plain.
"""

from __future__ import annotations

import threading

import meshoptimizer as mo
import numpy as np

KHR, EXT = "KHR_meshopt_compression", "EXT_meshopt_compression"
#: the vertex codec version each extension is written with (EXT_meshopt_compression allows only 0)
VERTEX_VERSION = {KHR: 1, EXT: 0}
INDEX_VERSION = 1  # TRIANGLES streams may be version 1 (smaller) under both
mo.encode_index_version(INDEX_VERSION)
_version_lock = threading.Lock()
_vertex_version: list[int] = [-1]


class CompressionError(ValueError):
    """meshoptimizer refused a stream (its limits, or an element size it cannot encode)."""


def encode_attributes(data: bytes | np.ndarray, stride: int, version: int = VERTEX_VERSION[KHR]) -> bytes:
    """An ATTRIBUTES stream (vertex codec ``version``) of ``len(data) // stride`` elements of ``stride`` bytes (a
    multiple of 4, <= 256)."""
    raw = np.frombuffer(bytes(data), np.uint8) if not isinstance(data, np.ndarray) else data.view(np.uint8).ravel()
    if stride % 4 or not 0 < stride <= 256 or len(raw) % stride or not len(raw):
        raise CompressionError(
            f"an ATTRIBUTES stream needs whole elements of 4..256 bytes (4k), not {len(raw)} bytes of stride {stride}"
        )
    if version not in (0, 1):
        raise ValueError(f"vertex codec version {version} does not exist")
    try:
        with _version_lock:
            if _vertex_version[0] != version:
                mo.encode_vertex_version(version)
                _vertex_version[0] = version
            return mo.encode_vertex_buffer(raw.reshape(-1, stride), len(raw) // stride, stride)
    except (ValueError, RuntimeError) as e:
        raise CompressionError(f"meshoptimizer refused a vertex stream: {e}") from None


def encode_triangles(indices: np.ndarray, vertex_count: int) -> bytes:
    """A TRIANGLES stream of whole triangles (the decoder writes 2- or 4-byte indices, the view's choice)."""
    idx = np.ascontiguousarray(indices, dtype=np.uint32)
    if not len(idx) or len(idx) % 3:
        raise CompressionError(f"a TRIANGLES stream needs whole triangles, not {len(idx)} indices")
    try:
        return mo.encode_index_buffer(idx, len(idx), vertex_count)
    except (ValueError, RuntimeError) as e:
        raise CompressionError(f"meshoptimizer refused an index stream: {e}") from None


def encode_oct(normals: np.ndarray) -> np.ndarray:
    """(n, 3) unit vectors -> (n, 4) int8 for the OCTAHEDRAL filter at 8 bits (meshopt_encodeFilterOct: x, y the
    octahedral map, 127 = 1.0, 0): two varying bytes instead of three, so the stream compresses better; the
    decoder gives back BYTE normalized x, y, z of length 127."""
    n = np.asarray(normals, np.float64).reshape(-1, 3)
    n = n / np.maximum(np.abs(n).sum(axis=1, keepdims=True), 1e-30)
    x, y, z = n[:, 0], n[:, 1], n[:, 2]
    u = np.where(z >= 0, x, (1.0 - np.abs(y)) * np.where(x >= 0, 1.0, -1.0))
    v = np.where(z >= 0, y, (1.0 - np.abs(x)) * np.where(y >= 0, 1.0, -1.0))
    out = np.zeros((len(n), 4), np.int8)
    for k, a in enumerate((u, v)):  # meshopt_quantizeSnorm(a, 8): round half away from zero
        out[:, k] = np.trunc(np.clip(a, -1.0, 1.0) * 127.0 + np.where(a >= 0, 0.5, -0.5))
    out[:, 2] = 127
    return out


def decode_oct(data: bytes, count: int, stride: int) -> bytes:
    """The OCTAHEDRAL filter's output (BYTE x, y, z of length 127, w kept) of ``encode_oct``'s elements."""
    if stride != 4:
        raise ValueError(f"citylod writes OCTAHEDRAL normals of 4 bytes, not {stride}")
    buf = np.frombuffer(data, np.int8, count=count * 4).copy()
    return mo.decode_filter_oct(buf, count, stride).view(np.uint8).tobytes()


#: the exponent range the EXPONENTIAL filter allows
EXP_MIN, EXP_MAX = -100, 100
MANTISSA_MAX = (1 << 23) - 1


def encode_exp(values: np.ndarray, exponent: int) -> np.ndarray:
    """float64 values -> int32 elements for the EXPONENTIAL filter with one shared ``exponent``: mantissa
    round(v / 2^exponent) in the low 24 bits, the exponent in the high 8 (the byte that repeats, so it compresses
    to nothing), as meshopt_encodeFilterExp with a shared exponent does; decodes exactly to mantissa * 2^exponent."""
    if not EXP_MIN <= exponent <= EXP_MAX:
        raise ValueError(f"the EXPONENTIAL filter allows exponents {EXP_MIN}..{EXP_MAX}, not {exponent}")
    m = np.round(np.asarray(values, np.float64) / 2.0**exponent)
    if m.size and np.abs(m).max() > MANTISSA_MAX:
        raise ValueError(f"a value needs more than 24 bits of mantissa at exponent {exponent}")
    return ((m.astype(np.int64) & 0xFFFFFF) | ((exponent & 0xFF) << 24)).astype(np.uint32).view(np.int32)


def decode_exp(data: bytes, count: int, stride: int) -> bytes:
    """The EXPONENTIAL filter's output (float32 2^e * m) of ``count`` elements of ``stride`` bytes of int32s."""
    v = np.frombuffer(data, "<i4", count=count * stride // 4)
    m = (v << 8) >> 8
    return (m.astype(np.float64) * np.exp2((v >> 24).astype(np.float64))).astype("<f4").tobytes()


FILTERS = {"NONE": None, "OCTAHEDRAL": decode_oct, "EXPONENTIAL": decode_exp}


def decode(source: bytes, count: int, stride: int, mode: str, filter_: str = "NONE") -> bytes:
    """The ``count * stride`` bytes a KHR_/EXT_meshopt_compression stream decodes to (ATTRIBUTES in either vertex
    codec version, or TRIANGLES; the OCTAHEDRAL or EXPONENTIAL filter applied to ATTRIBUTES)."""
    if filter_ not in FILTERS or (filter_ != "NONE" and mode != "ATTRIBUTES"):
        raise ValueError(f"meshopt filter {filter_} ({mode}) is not written by citylod")
    buf = np.frombuffer(source, np.uint8)
    if mode == "ATTRIBUTES":
        raw = mo.decode_vertex_buffer(count, stride, buf).view(np.uint8).tobytes()
        unfilter = FILTERS[filter_]
        return unfilter(raw, count, stride) if unfilter is not None else raw
    if mode == "TRIANGLES":
        # the binding allocates uint32 whatever the index size: the C decoder wrote count * stride bytes at its start
        return mo.decode_index_buffer(count, stride, buf).view(np.uint8)[: count * stride].tobytes()
    raise ValueError(f"meshopt mode {mode} is not written by citylod")


def reorder(indices: np.ndarray, vertex_count: int) -> tuple[np.ndarray, np.ndarray]:
    """Triangles reordered for the GPU's vertex cache, vertices renumbered in first-use order (fetch locality,
    and smaller deltas for the codecs): (new indices, old vertex of each new vertex)."""
    idx = np.ascontiguousarray(indices, dtype=np.uint32)
    tri = np.zeros_like(idx)
    mo.optimize_vertex_cache(tri, idx, len(idx), vertex_count)
    remap = np.zeros(vertex_count, np.uint32)
    used = mo.optimize_vertex_fetch_remap(remap, tri, len(tri), vertex_count)
    order = np.empty(used, np.int64)
    keep = remap < used  # unused vertices map to ~0 and are dropped
    order[remap[keep]] = np.nonzero(keep)[0]
    return remap[tri].astype(np.uint32), order
