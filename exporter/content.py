"""Tile content: ECEF triangles of a tile's features -> the arrays of one glTF primitive. Pure numpy.

Coordinates go ECEF -> the tile's local east-north-up frame (float64; plain glbs store float32: a tile spans at
most a few km, so float32 keeps millimetres; compact ones quantize from float64) -> glTF y-up.
Triangles are flat shaded: a vertex is shared only by
triangles with the same normal, colour and feature (np.unique over those keys), which keeps walls sharp.
Roof (up-facing) triangles take roof:colour, the others building:colour, else neutral defaults. Tag colours
are sRGB; glTF vertex colours are linear, so they are converted (16-bit, so dark colours keep their steps).
With the textures stage's per-corner UVs (tex.feature_uv), the page and UV join the key: corners share a vertex
only where they also share their atlas page and texture coordinate; export.py then splits the arrays by page.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from core.geodesy import Z_UP_TO_Y_UP, enu_rotation, geodetic_to_ecef
from core.semantics import SEM_DOOR, SEM_ROOF, SEM_UNKNOWN, SEM_WINDOW

DEFAULT_WALL = "#d8d2c4"
DEFAULT_ROOF = "#9c8f84"
UP_FACING = 0.7  # cos of the largest slope still coloured as roof


def hex_rgba(colour: str | None, default: str) -> tuple[int, int, int, int]:
    c = (colour or default).lstrip("#")
    if len(c) != 6:
        c = default.lstrip("#")
    return int(c[0:2], 16), int(c[2:4], 16), int(c[4:6], 16), 255


def srgb_to_linear16(rgba: np.ndarray) -> np.ndarray:
    """sRGB bytes (…, 4) -> linear RGB + linear alpha as normalized uint16, the glTF COLOR_0 encoding."""
    c = np.asarray(rgba, dtype=np.float64) / 255.0
    lin = np.where(c <= 0.04045, c / 12.92, ((c + 0.055) / 1.055) ** 2.4)
    lin[..., 3] = c[..., 3]  # alpha is already linear
    return np.round(lin * 65535.0).astype(np.uint16)


@dataclass(frozen=True)
class ContentArrays:
    positions: np.ndarray  # (n, 3) float64, glTF frame (plain glbs store float32; vertices are shared by those)
    normals: np.ndarray  # (n, 3) float32
    colors: np.ndarray  # (n, 4) uint16, linear
    feature_ids: np.ndarray  # (n,) uint32
    indices: np.ndarray  # (3m,) uint32
    dropped_degenerate: int
    uvs: np.ndarray | None = None  # (n, 2) float32 atlas page UV (textured tiles only)
    pages: np.ndarray | None = None  # (n,) int16 atlas page of the vertex, -1 = vertex colour only


WINDOW_RGBA = np.array([58, 74, 92, 255], dtype=np.uint8)  # dark blue-grey glass
DOOR_RGBA = np.array([101, 67, 33, 255], dtype=np.uint8)  # brown wood
_WINDOW_LINEAR = srgb_to_linear16(WINDOW_RGBA)
_DOOR_LINEAR = srgb_to_linear16(DOOR_RGBA)


def tile_arrays(
    triangles_ecef: np.ndarray,
    feature_of_triangle: np.ndarray,
    wall_rgba: np.ndarray,
    roof_rgba: np.ndarray,
    origin_lon: float,
    origin_lat: float,
    semantics: np.ndarray | None = None,
    tri_page: np.ndarray | None = None,
    tri_uv: np.ndarray | None = None,
) -> ContentArrays:
    """triangles_ecef (m, 3, 3); feature_of_triangle (m,); wall/roof_rgba (features, 4) sRGB uint8.
    The local frame's origin is on the ellipsoid at (origin_lon, origin_lat): the tile transform's.
    ``semantics`` (m,) lod.surface_type codes colour roofs, windows and doors; where it is missing (None, or
    SEM_UNKNOWN for a triangle) up-facing triangles take the roof colour.
    ``tri_page`` (m,) atlas page per triangle (-1: none) and ``tri_uv`` (m, 3, 2) its corners' page UVs
    (tex.feature_uv): a vertex is then also shared only by corners with the same page and UV."""
    origin = geodetic_to_ecef(origin_lon, origin_lat, 0.0)
    rot = enu_rotation(origin_lon, origin_lat)  # columns: E, N, U in ECEF
    enu = (np.asarray(triangles_ecef, dtype=np.float64) - origin) @ rot
    gl = enu @ Z_UP_TO_Y_UP.T  # (E, N, U) -> (E, U, -N)

    e1 = enu[:, 1] - enu[:, 0]
    e2 = enu[:, 2] - enu[:, 0]
    nrm = np.cross(e1, e2)
    length = np.linalg.norm(nrm, axis=1)
    keep = length > 1e-9  # zero-area triangles have no normal; they are invisible anyway
    gl, nrm, length = gl[keep], nrm[keep], length[keep]
    feat = np.asarray(feature_of_triangle)[keep]
    nrm = nrm / length[:, None]
    sem = np.full(len(feat), SEM_UNKNOWN, np.uint8) if semantics is None else np.asarray(semantics)[keep]
    up = (sem == SEM_ROOF) | ((sem == SEM_UNKNOWN) & (nrm[:, 2] > UP_FACING))
    colour = np.where(up[:, None], srgb_to_linear16(roof_rgba)[feat], srgb_to_linear16(wall_rgba)[feat])
    colour = np.where((sem == SEM_WINDOW)[:, None], _WINDOW_LINEAR, colour)
    colour = np.where((sem == SEM_DOOR)[:, None], _DOOR_LINEAR, colour)
    nrm_gl = nrm @ Z_UP_TO_Y_UP.T

    m = len(gl)
    pos64 = gl.reshape(-1, 3)  # the output keeps float64: compact geometry quantizes from it
    pos = pos64.astype(np.float32)
    normals = np.repeat(nrm_gl.astype(np.float32), 3, axis=0)
    textured = tri_page is not None and tri_uv is not None
    if textured:
        page = np.asarray(tri_page, np.int16)[keep]
        colour = np.where((page >= 0)[:, None], np.uint16(0), colour)  # unused where a texture is: more sharing
        pages = np.repeat(page, 3)
        uvs = np.asarray(tri_uv, np.float32)[keep].reshape(-1, 2)
    colors = np.repeat(colour, 3, axis=0)
    fids = np.repeat(feat.astype(np.uint32), 3)
    if m == 0:
        return ContentArrays(
            pos64,
            normals,
            colors,
            fids,
            np.zeros(0, np.uint32),
            int((~keep).sum()),
            uvs if textured else None,
            pages if textured else None,
        )
    # Coplanar triangles get normals equal up to rounding noise; round them for the key so they share vertices.
    nkey = np.round(normals, 4).astype(np.float32) + np.float32(0.0)  # + 0.0 folds -0.0 into 0.0
    parts = [pos.view(np.uint32), nkey.view(np.uint32), np.ascontiguousarray(colors).view(np.uint32), fids[:, None]]
    if textured:
        parts += [(uvs + np.float32(0.0)).view(np.uint32), pages.astype(np.uint32)[:, None]]
    key = np.concatenate(parts, axis=1)
    # Rows as opaque 36-byte records: sorting those is ~2.5x faster than np.unique(axis=0), same result.
    rows = np.ascontiguousarray(key).view(np.dtype((np.void, key.shape[1] * 4))).ravel()
    _, first, inverse = np.unique(rows, return_index=True, return_inverse=True)
    # Keep vertices in first-use order (better locality for the GPU vertex cache than sorted keys).
    order = np.argsort(first, kind="stable")
    rank = np.empty_like(order)
    rank[order] = np.arange(len(order))
    sel = first[order]
    return ContentArrays(
        positions=pos64[sel],
        normals=normals[sel],
        colors=colors[sel],
        feature_ids=fids[sel],
        indices=rank[inverse.reshape(-1)].astype(np.uint32),
        dropped_degenerate=int((~keep).sum()),
        uvs=uvs[sel] if textured else None,
        pages=pages[sel] if textured else None,
    )
