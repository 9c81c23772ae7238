"""Triangle meshes as POLYHEDRALSURFACE Z (E)WKB, encoded and decoded with numpy record arrays.

A mesh is stored as a polyhedral surface whose faces are triangles (one closed ring of 4 points each), so
every face is a fixed-size 109-byte record after the header and no per-triangle Python loop is needed either
way. PolyhedralSurface rather than TIN because SFCGAL (ST_MakeSolid, ST_Volume, ST_IsClosed) accepts it;
SFCGAL 1.4 reports a volume of 0 for a solid made from a TIN. Decoding also accepts TIN Z.
"""

from __future__ import annotations

import numpy as np

WKB_POLYGON = 3
WKB_POLYHEDRALSURFACE = 15
WKB_TIN = 16
WKB_TRIANGLE = 17
EWKB_Z = 0x80000000
EWKB_SRID = 0x20000000
ISO_Z = 1000

_TRIANGLE = np.dtype([("order", "u1"), ("type", "<u4"), ("nrings", "<u4"), ("npoints", "<u4"), ("xyz", "<f8", (4, 3))])
assert _TRIANGLE.itemsize == 109


def encode_triangles(triangles: np.ndarray, srid: int | None = None) -> bytes:
    """EWKB of a POLYHEDRALSURFACE Z from (m, 3, 3) triangles; little-endian, SRID embedded when given."""
    t = np.asarray(triangles, dtype=np.float64)
    if t.ndim != 3 or t.shape[1:] != (3, 3):
        raise ValueError(f"expected (m, 3, 3) triangles, got {t.shape}")
    return encode_triangles_batch(t, np.array([0, len(t)]), srid)[0]


def encode_triangles_batch(triangles: np.ndarray, offsets: np.ndarray, srid: int | None = None) -> list[bytes]:
    """EWKB per group: group k is triangles[offsets[k]:offsets[k+1]]; one record array for the whole batch."""
    t = np.asarray(triangles, dtype=np.float64)
    rec = np.empty(len(t), dtype=_TRIANGLE)
    rec["order"] = 1
    rec["type"] = WKB_POLYGON | EWKB_Z
    rec["nrings"] = 1
    rec["npoints"] = 4
    rec["xyz"][:, :3] = t
    rec["xyz"][:, 3] = t[:, 0]
    body = rec.tobytes()
    gtype = WKB_POLYHEDRALSURFACE | EWKB_Z | (EWKB_SRID if srid is not None else 0)
    prefix = b"\x01" + np.uint32(gtype).tobytes() + (np.uint32(srid).tobytes() if srid is not None else b"")
    size = _TRIANGLE.itemsize
    return [
        prefix + np.uint32(hi - lo).tobytes() + body[lo * size : hi * size]
        for lo, hi in zip(offsets[:-1].tolist(), offsets[1:].tolist(), strict=True)
    ]


def decode_triangles(data: bytes | memoryview) -> np.ndarray:
    """(m, 3, 3) triangles from ISO WKB (ST_AsBinary) or EWKB of a POLYHEDRALSURFACE Z or TIN Z whose faces
    are triangles."""
    buf = memoryview(data)
    if buf[0] != 1:
        raise ValueError("only little-endian WKB is supported")
    gtype = int(np.frombuffer(buf[1:5], "<u4")[0])
    pos = 5
    if gtype & EWKB_SRID:
        pos += 4
    base = gtype & 0x0FFFFFFF
    has_z = bool(gtype & EWKB_Z) or base // 1000 in (1, 3)
    if base % 1000 not in (WKB_POLYHEDRALSURFACE, WKB_TIN) or not has_z:
        raise ValueError(f"not a POLYHEDRALSURFACE Z or TIN Z (WKB type {gtype:#x})")
    n = int(np.frombuffer(buf[pos : pos + 4], "<u4")[0])
    pos += 4
    rec = np.frombuffer(buf[pos : pos + n * _TRIANGLE.itemsize], dtype=_TRIANGLE, count=n)
    if n and (np.any(rec["nrings"] != 1) or np.any(rec["npoints"] != 4)):
        raise ValueError("faces must be triangles: one ring of 4 points")
    return np.array(rec["xyz"][:, :3])
