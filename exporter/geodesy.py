"""WGS84 geodesy for placing tiles on the globe: geodetic <-> ECEF and local east-north-up frames. Pure numpy."""

from __future__ import annotations

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
