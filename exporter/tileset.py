"""tileset.json from the tile quadtree. Pure: tile records in, a 3D Tiles 1.1 tileset dict out.

* Bounding volumes are regions (radians, metres above the WGS84 ellipsoid), which need no transform and nest
  exactly: a parent's region is the union of its children's.
* Every tile with content carries the transform from its local east-north-up frame (origin at the centre of
  its region, on the ellipsoid) to its parent's frame (3D Tiles composes transforms down the tree), so each
  glb stores coordinates in its own tile's frame, y up.
* Geometric error: 0 for leaves; above, the value the generalize stage measured (tiles.tile.geometric_error:
  the largest error bound of the tile's content or its children's). The top-level geometricError is at
  least the diagonal of the root region: CesiumJS silently loads nothing when it is too small for the
  distance the tileset is viewed from.
* Refinement is REPLACE: every tile has content (blocks at the root down to LOD3 at the leaves), and children
  replace their parent, so a client never draws two versions of a building. A single-LOD tileset
  (``single_lod``) has content at the leaves only and refines by ADD.
"""

from __future__ import annotations

import math
from collections.abc import Iterable
from dataclasses import dataclass
from typing import Any, Literal, TypedDict

import numpy as np

from core.geodesy import column_major, enu_to_ecef, geodetic_to_ecef

from . import ATTRIBUTION, __version__

Refine = Literal["ADD", "REPLACE"]


class BoundingVolume(TypedDict, total=False):
    region: list[float]
    box: list[float]
    sphere: list[float]


class Content(TypedDict):
    uri: str


class Tile(TypedDict, total=False):
    boundingVolume: BoundingVolume
    geometricError: float
    refine: Refine
    content: Content
    children: list[Tile]
    transform: list[float]


class Tileset(TypedDict, total=False):
    asset: dict[str, str]
    geometricError: float
    root: Tile
    extras: dict[str, Any]


@dataclass(frozen=True)
class TileRecord:
    level: int
    x: int
    y: int
    is_leaf: bool
    region: tuple[float, float, float, float, float, float]
    geometric_error: float | None
    content_uri: str | None
    n_features: int = 0
    content_features: int | None = None


def region_centre(region: tuple[float, ...] | list[float]) -> tuple[float, float]:
    west, south, east, north = region[:4]
    return (west + east) / 2.0, (south + north) / 2.0


def region_diagonal(region: tuple[float, ...] | list[float]) -> float:
    """Straight-line distance in metres between opposite corners of a region."""
    west, south, east, north, lo, hi = region
    a = geodetic_to_ecef(west, south, lo)
    b = geodetic_to_ecef(east, north, hi)
    return float(np.linalg.norm(a - b))


def leaf_frame(region: tuple[float, ...] | list[float], base: float = 0.0) -> np.ndarray:
    """4×4 matrix from the tile's east-north-up frame (origin at its region's centre) to ECEF."""
    lon, lat = region_centre(region)
    return enu_to_ecef(lon, lat, base)


def build_tileset(records: Iterable[TileRecord], tileset_version: str = "", single_lod: bool = False) -> Tileset:
    by_key = {(r.level, r.x, r.y): r for r in records}
    if (0, 0, 0) not in by_key:
        raise ValueError("no root tile (0, 0, 0): run the tiles stage first")
    children: dict[tuple[int, int, int], list[tuple[int, int, int]]] = {k: [] for k in by_key}
    for (lvl, x, y) in sorted(by_key):
        if lvl == 0:
            continue
        # the parent is the nearest existing ancestor (levels can only be skipped by a leaf's ancestors being
        # inner tiles, which always exist; this is a guard, not a code path)
        for up in range(1, lvl + 1):
            parent = (lvl - up, x >> up, y >> up)
            if parent in by_key:
                children[parent].append((lvl, x, y))
                break

    def tile(key: tuple[int, int, int], parent_world: np.ndarray) -> Tile:
        r = by_key[key]
        if r.geometric_error is None:
            raise ValueError(f"tile {key} has no geometric error: run the generalize stage")
        t: Tile = {"boundingVolume": {"region": [float(v) for v in r.region]},
                   "geometricError": float(r.geometric_error)}
        world = parent_world
        if r.is_leaf or not single_lod:
            if not r.content_uri:
                raise ValueError(f"tile {key} has no content")
            t["content"] = {"uri": r.content_uri}
            world = leaf_frame(r.region)
            t["transform"] = column_major(np.linalg.solve(parent_world, world))
        kids = children[key]
        if kids:
            t["children"] = [tile(k, world) for k in kids]
        return t

    root = tile((0, 0, 0), np.eye(4))
    root["refine"] = "ADD" if single_lod else "REPLACE"
    root_region = by_key[(0, 0, 0)].region
    top_error = max(region_diagonal(root_region), float(root["geometricError"]))
    asset = {"version": "1.1", "generator": f"citylod {__version__}"}
    if tileset_version:
        asset["tilesetVersion"] = tileset_version
    return {
        "asset": asset,
        "geometricError": math.ceil(top_error),
        "root": root,
        "extras": {"copyright": ATTRIBUTION},
    }
