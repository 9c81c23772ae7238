"""EXT_meshopt_compression through the meshoptimizer library (PyPI ``meshoptimizer``): encode, decode, reorder.

Pure: arrays in, bytes out. The extension allows vertex codec version 0 only for ATTRIBUTES streams (element
size a multiple of 4, at most 256 bytes) and index codec version 1 for TRIANGLES; both versions are set here,
once, because the library keeps them as process-wide state (setting the same value from several threads is
harmless). A stream the library refuses raises ``CompressionError``; the caller writes that tile plain.
"""

from __future__ import annotations

import meshoptimizer as mo
import numpy as np

VERTEX_VERSION = 0  # EXT_meshopt_compression: ATTRIBUTES streams must be version 0
INDEX_VERSION = 1  # TRIANGLES streams may be version 1 (smaller)
mo.encode_vertex_version(VERTEX_VERSION)
mo.encode_index_version(INDEX_VERSION)


class CompressionError(ValueError):
    """meshoptimizer refused a stream (its limits, or an element size it cannot encode)."""


def encode_attributes(data: bytes | np.ndarray, stride: int) -> bytes:
    """An ATTRIBUTES stream of ``len(data) // stride`` elements of ``stride`` bytes (a multiple of 4, <= 256)."""
    raw = np.frombuffer(bytes(data), np.uint8) if not isinstance(data, np.ndarray) else data.view(np.uint8).ravel()
    if stride % 4 or not 0 < stride <= 256 or len(raw) % stride or not len(raw):
        raise CompressionError(f"an ATTRIBUTES stream needs whole elements of 4..256 bytes (4k), not {len(raw)} "
                               f"bytes of stride {stride}")
    try:
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


def decode(source: bytes, count: int, stride: int, mode: str, filter_: str = "NONE") -> bytes:
    """The ``count * stride`` bytes an EXT_meshopt_compression stream decodes to (ATTRIBUTES or TRIANGLES; the
    OCTAHEDRAL filter applied to ATTRIBUTES)."""
    if filter_ not in ("NONE", "OCTAHEDRAL") or (filter_ != "NONE" and mode != "ATTRIBUTES"):
        raise ValueError(f"meshopt filter {filter_} ({mode}) is not written by citylod")
    buf = np.frombuffer(source, np.uint8)
    if mode == "ATTRIBUTES":
        raw = mo.decode_vertex_buffer(count, stride, buf).view(np.uint8).tobytes()
        return decode_oct(raw, count, stride) if filter_ == "OCTAHEDRAL" else raw
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
