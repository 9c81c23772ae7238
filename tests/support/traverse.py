"""What a 3D Tiles client draws for a camera, read from tileset.json alone. Pure.

The reference api.lod_for_view is checked against: the traversal of the 3D Tiles 1.1 specification for a
perspective camera, as CesiumJS does it with dynamic and foveated screen-space error switched off. From the
root, a tile inside the view frustum is refined while its screen-space error
    geometricError × viewport height / (distance × 2 tan(fov / 2))
exceeds the maximum; with REPLACE its visible children are drawn instead of it, with ADD in addition to it.
Distances and frustum tests use the east-north-up box around each tile's region (geodesy.region_box), the
same numbers api.lod_for_view reads from tiles.tile.box. An implicit tileset is traversed as the explicit tree
it stands for (core/tiles3d.expand: its subtrees through ``read``).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from core.camera import Camera
from core.geodesy import box_distance, box_visible, region_box
from core.tiles3d import Read, expand


@dataclass(frozen=True)
class Drawn:
    uri: str
    distance: float
    sse: float


def select(tileset: dict[str, Any], camera: Camera, max_sse: float = 16.0, read: Read | None = None) -> list[Drawn]:
    """The content a client draws for ``camera``, in traversal order (``read``: an implicit tileset's files)."""
    if "implicitTiling" in tileset["root"]:
        if read is None:
            raise ValueError("an implicit tileset: pass read to reach its subtrees")
        tileset = expand(tileset, read)
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
