"""What a 3D Tiles client draws for a camera, read from tileset.json alone. Pure.

The reference api.lod_for_view is checked against: the traversal of the 3D Tiles 1.1 specification for a
perspective camera, as CesiumJS does it with dynamic and foveated screen-space error switched off. From the
root, a tile inside the view frustum is refined while its screen-space error
    geometricError × viewport height / (distance × 2 tan(fov / 2))
exceeds the maximum; with REPLACE its visible children are drawn instead of it, with ADD in addition to it.
Distances and frustum tests use the east-north-up box around each tile's region (geodesy.region_box), the
same numbers api.lod_for_view reads from tiles.tile.box.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np

from .geodesy import box_distance, box_visible, enu_rotation, geodetic_to_ecef, region_box


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
        return np.array([
            math.cos(th) * r + math.sin(th) * d, -math.cos(th) * r + math.sin(th) * d,
            math.cos(tv) * u + math.sin(tv) * d, -math.cos(tv) * u + math.sin(tv) * d, d,
        ])

    def sse(self, geometric_error: float, distance: float) -> float:
        return geometric_error * self.viewport_height / (max(distance, 1e-7) * 2 * math.tan(math.radians(self.fov) / 2))


@dataclass(frozen=True)
class Drawn:
    uri: str
    distance: float
    sse: float


def select(tileset: dict[str, Any], camera: Camera, max_sse: float = 16.0) -> list[Drawn]:
    """The content a client draws for ``camera``, in traversal order."""
    pos, planes = camera.position(), camera.planes()
    drawn: list[Drawn] = []

    def visit(tile: dict[str, Any], refine: str) -> None:
        refine = tile.get("refine", refine)
        box = region_box(np.array([tile["boundingVolume"]["region"]]))[0]
        if not box_visible(box, pos, planes):
            return
        dist = box_distance(box, pos)
        sse = camera.sse(float(tile["geometricError"]), dist)
        kids = tile.get("children", [])
        refines = bool(kids) and sse > max_sse
        if "content" in tile and (not refines or refine == "ADD"):
            drawn.append(Drawn(tile["content"]["uri"], dist, sse))
        if refines:
            for k in kids:
                visit(k, refine)

    visit(tileset["root"], tileset["root"].get("refine", "REPLACE"))
    return drawn
