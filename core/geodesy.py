"""WGS84 geodesy for placing tiles on the globe: geodetic <-> ECEF and local east-north-up frames. Pure numpy."""

from __future__ import annotations

import math

import numpy as np

A = 6378137.0
F = 1.0 / 298.257223563
E2 = F * (2.0 - F)


def geodetic_to_ecef(lon: np.ndarray | float, lat: np.ndarray | float, h: np.ndarray | float) -> np.ndarray:
    """ECEF metres from longitude/latitude in radians and height above the ellipsoid in metres; (..., 3)."""
    lon, lat, h = np.asarray(lon, float), np.asarray(lat, float), np.asarray(h, float)
    n = A / np.sqrt(1.0 - E2 * np.sin(lat) ** 2)
    return np.stack(
        [(n + h) * np.cos(lat) * np.cos(lon), (n + h) * np.cos(lat) * np.sin(lon), (n * (1 - E2) + h) * np.sin(lat)],
        axis=-1,
    )


def metres_per_radian(lat: np.ndarray | float) -> tuple[np.ndarray, np.ndarray]:
    """Metres on the WGS84 ellipsoid per radian of longitude (N cos lat) and of latitude (M) at ``lat``: the
    radii of curvature tiles.build_quadtree squares the root region with."""
    s2 = np.sin(lat) ** 2
    return A * np.cos(lat) / np.sqrt(1.0 - E2 * s2), A * (1.0 - E2) / (1.0 - E2 * s2) ** 1.5


def ecef_to_geodetic(xyz: np.ndarray) -> np.ndarray:
    """(lon, lat, h) in radians/metres from ECEF (..., 3); Bowring's method, then two refinements."""
    xyz = np.asarray(xyz, float)
    x, y, z = xyz[..., 0], xyz[..., 1], xyz[..., 2]
    lon = np.arctan2(y, x)
    p = np.hypot(x, y)
    lat = np.arctan2(z, p * (1 - E2))
    for _ in range(5):
        n = A / np.sqrt(1 - E2 * np.sin(lat) ** 2)
        h = p / np.cos(lat) - n
        lat = np.arctan2(z, p * (1 - E2 * n / (n + h)))
    n = A / np.sqrt(1 - E2 * np.sin(lat) ** 2)
    h = p / np.cos(lat) - n
    return np.stack([lon, lat, h], axis=-1)


def enu_rotation(lon: float, lat: float) -> np.ndarray:
    """3×3 matrix whose columns are the east, north and up unit vectors in ECEF at (lon, lat) radians."""
    sl, cl, sp, cp = np.sin(lon), np.cos(lon), np.sin(lat), np.cos(lat)
    east = np.array([-sl, cl, 0.0])
    north = np.array([-sp * cl, -sp * sl, cp])
    up = np.array([cp * cl, cp * sl, sp])
    return np.stack([east, north, up], axis=1)


def enu_to_ecef(lon: float, lat: float, h: float) -> np.ndarray:
    """4×4 matrix taking local east-north-up coordinates at (lon, lat, h) to ECEF."""
    m = np.eye(4)
    m[:3, :3] = enu_rotation(lon, lat)
    m[:3, 3] = geodetic_to_ecef(lon, lat, h)
    return m


def column_major(m: np.ndarray) -> list[float]:
    """A 4×4 matrix as the 16 column-major numbers 3D Tiles and glTF use."""
    return [float(v) for v in np.asarray(m).T.reshape(-1)]


#: glTF is y-up; 3D Tiles content is z-up and clients rotate glTF by +90° about x. (E, N, U) -> (E, U, -N).
Z_UP_TO_Y_UP = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, 1.0], [0.0, -1.0, 0.0]])
Y_UP_TO_Z_UP = Z_UP_TO_Y_UP.T


def region_box(regions: np.ndarray, pad: float = 1.0) -> np.ndarray:
    """(n, 12) oriented boxes in ECEF (centre, then the three half-axis vectors east, north, up) enclosing 3D
    Tiles regions (n, 6: west, south, east, north in radians, min and max height in metres). Each box is
    aligned with the east-north-up frame at its region's centre and bounds a 5 × 5 × 2 grid of points on the
    region, padded by ``pad`` metres for the curvature between them (a few centimetres per kilometre)."""
    r = np.atleast_2d(np.asarray(regions, float))
    f = np.linspace(0.0, 1.0, 5)
    lon = r[:, 0, None] + (r[:, 2] - r[:, 0])[:, None] * f  # (n, 5)
    lat = r[:, 1, None] + (r[:, 3] - r[:, 1])[:, None] * f
    lo = np.broadcast_to(lon[:, :, None, None], (len(r), 5, 5, 2))
    la = np.broadcast_to(lat[:, None, :, None], (len(r), 5, 5, 2))
    hh = np.broadcast_to(r[:, None, None, 4:6], (len(r), 5, 5, 2))
    pts = geodetic_to_ecef(lo, la, hh).reshape(len(r), -1, 3)
    clon, clat = (r[:, 0] + r[:, 2]) / 2, (r[:, 1] + r[:, 3]) / 2
    sl, cl, sp, cp = np.sin(clon), np.cos(clon), np.sin(clat), np.cos(clat)
    axes = np.stack(
        [
            np.stack([-sl, cl, np.zeros_like(sl)], -1),
            np.stack([-sp * cl, -sp * sl, cp], -1),
            np.stack([cp * cl, cp * sl, sp], -1),
        ],
        axis=1,
    )  # (n, 3 axes, 3)
    origin = geodetic_to_ecef(clon, clat, np.zeros_like(clon))
    local = np.einsum("nij,npj->npi", axes, pts - origin[:, None, :])  # (n, p, 3) east/north/up
    lo_, hi_ = local.min(axis=1), local.max(axis=1)
    centre = origin + np.einsum("ni,nij->nj", (lo_ + hi_) / 2, axes)
    half = ((hi_ - lo_) / 2 + pad)[:, :, None] * axes
    return np.concatenate([centre, half.reshape(len(r), 9)], axis=1)


def box_distance(box: np.ndarray, point: np.ndarray) -> float:
    """Distance (m) from an ECEF point to a region_box box, 0 inside (tiles.box_distance in SQL)."""
    d = np.asarray(point, float) - box[:3]
    total = 0.0
    for i in range(3):
        axis = box[3 + 3 * i : 6 + 3 * i]
        length = max(float(np.linalg.norm(axis)), 1e-9)
        total += max(abs(float(d @ axis)) / length - length, 0.0) ** 2
    return math.sqrt(total)


def box_visible(box: np.ndarray, point: np.ndarray, planes: np.ndarray) -> bool:
    """False when the box lies wholly behind one of the planes (rows: inward unit normals through ``point``);
    tiles.box_visible in SQL."""
    c = box[:3] - np.asarray(point, float)
    half = box[3:].reshape(3, 3)
    s = planes @ c + np.abs(planes @ half.T).sum(axis=1)
    return bool(np.all(s >= 0))
