"""The perspective camera and the screen-space-error rule, shared by every part that reasons about a view. Pure.

One rule, as 3D Tiles clients apply it: a length of ``l`` metres at distance ``d`` from a camera with vertical
field of view ``fov`` on a viewport ``H`` pixels high spans ``l × H / (d × 2 tan(fov / 2))`` pixels. A tile's
screen-space error is its geometric error measured that way; the tile traversal (tests/support/traverse.py), the
texture resolution (etl/textures/stage.py, etl/textures/atlas.py), the landmark intervals and the view saliency
use the functions below, and SQL has the same rule once, ``tiles.screen_space_error``
(sql/tiles/screen_space_error.sql), which ``api.lod_for_view`` uses; tests/db/test_camera_sql.py holds the
two against each other.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from core.geodesy import enu_rotation, geodetic_to_ecef

#: Distances are clamped here, so a camera inside a box gives a large finite error instead of a division by 0.
MIN_DISTANCE_M = 1e-7


def pixels_per_metre(distance: float | np.ndarray, fov_rad: float, viewport_height: float) -> float | np.ndarray:
    """Pixels one metre spans at ``distance`` (m) across the view direction."""
    d = np.maximum(distance, MIN_DISTANCE_M)
    out = viewport_height / (d * 2 * math.tan(fov_rad / 2))  # fov is one number: libm's tan, as PostgreSQL's
    return float(out) if np.ndim(out) == 0 else out


def screen_space_error(
    geometric_error: float | np.ndarray, distance: float | np.ndarray, fov_rad: float, viewport_height: float
) -> float | np.ndarray:
    """Pixels a geometric error (m) spans at ``distance`` (m): what a client compares with its maximum."""
    return geometric_error * pixels_per_metre(distance, fov_rad, viewport_height)


def distance_for_pixels(
    length_m: float | np.ndarray, pixels: float, fov_rad: float, viewport_height: float
) -> float | np.ndarray:
    """The distance at which ``length_m`` spans exactly ``pixels``: screen_space_error's inverse (a tile of
    geometric error e is drawn from ``distance_for_pixels(e, max_sse, ...)`` on)."""
    out = length_m * viewport_height / (2 * math.tan(fov_rad / 2) * pixels)
    return float(out) if np.ndim(out) == 0 else out


@dataclass(frozen=True)
class Camera:
    """A perspective camera as CesiumJS describes it: position in degrees and metres above the ellipsoid,
    heading clockwise from north and pitch up from the horizon in degrees (no roll), vertical field of view
    in degrees, viewport height in pixels and width / height."""

    lon: float
    lat: float
    height: float
    heading: float
    pitch: float
    fov: float = 60.0
    viewport_height: int = 1080
    aspect: float = 16.0 / 9.0

    def position(self) -> np.ndarray:
        return geodetic_to_ecef(math.radians(self.lon), math.radians(self.lat), self.height)

    def axes(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(direction, right, up) unit vectors in ECEF."""
        enu = enu_rotation(math.radians(self.lon), math.radians(self.lat))
        east, north, up = enu[:, 0], enu[:, 1], enu[:, 2]
        h, p = math.radians(self.heading), math.radians(self.pitch)
        d = math.cos(p) * math.sin(h) * east + math.cos(p) * math.cos(h) * north + math.sin(p) * up
        r = math.cos(h) * east - math.sin(h) * north
        return d, r, np.cross(r, d)

    def planes(self) -> np.ndarray:
        """(5, 3) inward unit normals of the left, right, bottom, top and near planes (through the camera)."""
        d, r, u = self.axes()
        tv = math.radians(self.fov) / 2
        th = math.atan(self.aspect * math.tan(tv))
        return np.array(
            [
                math.cos(th) * r + math.sin(th) * d,
                -math.cos(th) * r + math.sin(th) * d,
                math.cos(tv) * u + math.sin(tv) * d,
                -math.cos(tv) * u + math.sin(tv) * d,
                d,
            ]
        )

    def focal_px(self) -> float:
        """Focal length in pixels: a length l at depth z spans l × focal / z pixels."""
        return float(pixels_per_metre(1.0, math.radians(self.fov), self.viewport_height))

    def sse(self, geometric_error: float, distance: float) -> float:
        return float(screen_space_error(geometric_error, distance, math.radians(self.fov), self.viewport_height))
