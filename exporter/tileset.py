"""tileset.json from the tile quadtree. Pure: tile records in, a 3D Tiles 1.1 tileset dict out.

* Bounding volumes are regions (radians, metres above the WGS84 ellipsoid), which need no transform and nest
  exactly: a parent's region is the union of its children's.
* Frames: the root carries the transform from the root region's east-north-up frame (origin at its centre, on
  the ellipsoid) to ECEF, and no other tile has a transform (implicit tiling has none). Each glb stores its
  mesh in its own tile's east-north-up frame (y up) and its node carries the matrix from that frame to the
  root's (``node_matrix``), so a glb is the same bytes whatever the tiling.
* Tiling (``build``): ``explicit`` writes every tile into tileset.json; ``implicit`` writes a 3D Tiles 1.1
  implicit quadtree (the root with ``implicitTiling``, a content URI template and subtree files, subtree.py).
  The quadtree is cut on the implicit subdivision of its root region (tiles.grid, ``root_volume``): a tile's
  cell is the root region halved ``level`` times in longitude and latitude, which is the volume a client that
  ignores subtree metadata computes, and its content stays inside it but for buildings straddling its edges
  (by at most their half-extent; exporter/volumes.py measures it). The implicit root's geometric error is
  ``implicit_root_error``: the error such a client computes for level L, root / 2^L, is never below what a
  tile of that level measured. Each tile's real region (the extent of its meshes) and geometric error travel
  as subtree tile metadata (semantics TILE_BOUNDING_REGION, TILE_GEOMETRIC_ERROR; the class ``TILE_SCHEMA``
  in tileset.json) for the clients that read it, which are exact. Our (level, x, y) are the implicit
  coordinates: x east, y north, children (2x + i, 2y + j), and content/{level}/{x}/{y}.glb is the template.
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

from core.geodesy import Y_UP_TO_Z_UP, Z_UP_TO_Y_UP, column_major, enu_to_ecef, geodetic_to_ecef
from exporter import ATTRIBUTION, __version__
from exporter.subtree import choose_subtree_levels, subtree_roots, write_subtree

Refine = Literal["ADD", "REPLACE"]
Tiling = Literal["implicit", "explicit"]

CONTENT_TEMPLATE = "content/{level}/{x}/{y}.glb"
SUBTREE_TEMPLATE = "subtrees/{level}/{x}/{y}.subtree"
#: The subtree tile metadata: each tile's real bounding region and geometric error (FLOAT64: a region in
#: radians needs it, 1e-7 rad of FLOAT32 is 60 cm on the ground).
TILE_SCHEMA: dict[str, Any] = {
    "id": "citylod_tiles",
    "classes": {
        "tile": {
            "description": "a tile of the citylod quadtree: its real bounding region and geometric error",
            "properties": {
                "region": {
                    "type": "SCALAR",
                    "componentType": "FLOAT64",
                    "array": True,
                    "count": 6,
                    "semantic": "TILE_BOUNDING_REGION",
                    "description": "west, south, east, north (rad), "
                    "minimum and maximum height (m above the WGS84 ellipsoid) of the tile's meshes",
                },
                "geometric_error": {
                    "type": "SCALAR",
                    "componentType": "FLOAT64",
                    "semantic": "TILE_GEOMETRIC_ERROR",
                    "description": "metres (tiles.tile.geometric_error)",
                },
            },
        }
    },
}
_ROW_BYTES = 7 * 8  # one tile's metadata


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
    implicitTiling: dict[str, Any]


class Tileset(TypedDict, total=False):
    asset: dict[str, str]
    geometricError: float
    root: Tile
    schema: dict[str, Any]
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


def node_matrix(region: tuple[float, ...] | list[float], root_region: tuple[float, ...] | list[float]) -> list[float]:
    """The glTF node matrix (16 numbers, column-major) of a tile's glb: from the tile's frame (its
    ``leaf_frame``, y up) to the root's (y up). A client places the glb with root transform @ (y-up to z-up)
    @ node matrix, which is the tile's own frame @ (y-up to z-up): the old per-tile transform."""
    rel = np.linalg.solve(leaf_frame(root_region), leaf_frame(region))
    z_to_y, y_to_z = np.eye(4), np.eye(4)
    z_to_y[:3, :3], y_to_z[:3, :3] = Z_UP_TO_Y_UP, Y_UP_TO_Z_UP
    return column_major(z_to_y @ rel @ y_to_z)


def _checked(records: Iterable[TileRecord], single_lod: bool) -> dict[tuple[int, int, int], TileRecord]:
    by_key = {(r.level, r.x, r.y): r for r in records}
    if (0, 0, 0) not in by_key:
        raise ValueError("no root tile (0, 0, 0): run the tiles stage first")
    for key, r in by_key.items():
        if r.geometric_error is None:
            raise ValueError(f"tile {key} has no geometric error: run the generalize stage")
        if (r.is_leaf or not single_lod) and not r.content_uri:
            raise ValueError(f"tile {key} has no content")
    return by_key


def _top(root: Tile, root_region: tuple[float, ...], tileset_version: str) -> Tileset:
    top_error = max(region_diagonal(root_region), float(root["geometricError"]))
    asset = {"version": "1.1", "generator": f"citylod {__version__}"}
    if tileset_version:
        asset["tilesetVersion"] = tileset_version
    return {"asset": asset, "geometricError": math.ceil(top_error), "root": root, "extras": {"copyright": ATTRIBUTION}}


def build_tileset(records: Iterable[TileRecord], tileset_version: str = "", single_lod: bool = False) -> Tileset:
    """The explicit tileset: every tile in the JSON tree."""
    by_key = _checked(records, single_lod)
    children: dict[tuple[int, int, int], list[tuple[int, int, int]]] = {k: [] for k in by_key}
    for lvl, x, y in sorted(by_key):
        if lvl == 0:
            continue
        # the parent is the nearest existing ancestor (levels can only be skipped by a leaf's ancestors being
        # inner tiles, which always exist; this is a guard, not a code path)
        for up in range(1, lvl + 1):
            parent = (lvl - up, x >> up, y >> up)
            if parent in by_key:
                children[parent].append((lvl, x, y))
                break

    def tile(key: tuple[int, int, int]) -> Tile:
        r = by_key[key]
        assert r.geometric_error is not None  # _checked refuses a tile without one
        t: Tile = {
            "boundingVolume": {"region": [float(v) for v in r.region]},
            "geometricError": float(r.geometric_error),
        }
        if r.is_leaf or not single_lod:
            assert r.content_uri is not None  # _checked refuses such a tile without content
            t["content"] = {"uri": r.content_uri}
        if children[key]:
            t["children"] = [tile(k) for k in children[key]]
        return t

    root = tile((0, 0, 0))
    root_region = by_key[(0, 0, 0)].region
    root["refine"] = "ADD" if single_lod else "REPLACE"
    root["transform"] = column_major(leaf_frame(root_region))
    return _top(root, root_region, tileset_version)


def implicit_root_error(records: Iterable[TileRecord]) -> float:
    """The implicit root's geometric error: the least e with e / 2^level >= every tile's measured error, so a
    client that halves the root's error per level (ignoring TILE_GEOMETRIC_ERROR) never refines later than
    the tiles' own errors allow."""
    return max(float(r.geometric_error or 0.0) * 2.0**r.level for r in records)


def build_implicit(
    records: Iterable[TileRecord],
    tileset_version: str = "",
    single_lod: bool = False,
    subtree_levels: int | None = None,
    root_volume: tuple[float, float, float, float] | None = None,
) -> tuple[Tileset, dict[str, bytes]]:
    """The implicit tileset and its subtree files by URI (subtree.py); ``subtree_levels`` chosen from the tree
    (subtree.choose_subtree_levels) when None. ``root_volume`` (west, south, east, north, radians: the
    quadtree's root, api.quadtree_root) is the root's region, with the root tile's heights; None takes the root
    tile's own region (a tree not cut on its subdivision, as in unit tests)."""
    by_key = _checked(records, single_lod)
    for key, r in by_key.items():
        if r.content_uri and r.content_uri != CONTENT_TEMPLATE.format(level=key[0], x=key[1], y=key[2]):
            raise ValueError(f"tile {key}: content {r.content_uri} does not follow {CONTENT_TEMPLATE}")
    recs = list(by_key.values())
    keys = np.array(list(by_key), np.int64).reshape(-1, 3)
    for lvl, x, y in by_key:
        if lvl and (lvl - 1, x >> 1, y >> 1) not in by_key:
            raise ValueError(f"tile {(lvl, x, y)} has no parent: implicit tiling needs every ancestor")
    levels = subtree_levels or choose_subtree_levels(keys, _ROW_BYTES)
    region = np.array([r.region for r in recs], np.float64).reshape(-1, 6)
    error = np.array([r.geometric_error for r in recs], np.float64)
    content = np.array([r.is_leaf or not single_lod for r in recs], bool)
    roots = subtree_roots(keys, levels)
    # each subtree's tiles (grouped by a sort), and the subtrees starting right below it
    uniq, inverse = np.unique(roots, axis=0, return_inverse=True)
    inverse = inverse.reshape(-1)
    by_sub = np.argsort(inverse, kind="stable")
    tile_bounds = np.searchsorted(inverse[by_sub], np.arange(len(uniq) + 1))
    parent_of = np.full(len(uniq), -1, np.int64)
    deep = np.flatnonzero(uniq[:, 0] > 0)
    if len(deep):
        up = subtree_roots(np.c_[uniq[deep, 0] - 1, uniq[deep, 1] >> 1, uniq[deep, 2] >> 1], levels)
        # the parent subtree's index in uniq (rows sorted lexicographically, as np.unique returns them)
        index = {k: i for i, k in enumerate(map(tuple, uniq.tolist()))}
        parent_of[deep] = [index[k] for k in map(tuple, up.tolist())]
    by_parent = np.argsort(parent_of, kind="stable")
    child_bounds = np.searchsorted(parent_of[by_parent], np.arange(len(uniq) + 1))
    files: dict[str, bytes] = {}
    for i, root_key in enumerate(uniq.tolist()):
        mine = by_sub[tile_bounds[i] : tile_bounds[i + 1]]
        below = uniq[by_parent[child_bounds[i] : child_bounds[i + 1]]]
        lvl, x, y = root_key
        files[SUBTREE_TEMPLATE.format(level=lvl, x=x, y=y)] = write_subtree(
            (lvl, x, y),
            levels,
            keys[mine],
            content[mine],
            below,
            [("region", region[mine]), ("geometric_error", error[mine])],
        )
    root_rec = by_key[(0, 0, 0)]
    assert root_rec.geometric_error is not None  # _checked refuses a tile without one
    root_region = (*root_volume, *root_rec.region[4:6]) if root_volume else root_rec.region
    root: Tile = {
        "boundingVolume": {"region": [float(v) for v in root_region]},
        "geometricError": implicit_root_error(recs),
        "refine": "ADD" if single_lod else "REPLACE",
        "transform": column_major(leaf_frame(root_rec.region)),
        "content": {"uri": CONTENT_TEMPLATE},
        "implicitTiling": {
            "subdivisionScheme": "QUADTREE",
            "subtreeLevels": levels,
            "availableLevels": int(keys[:, 0].max()) + 1,
            "subtrees": {"uri": SUBTREE_TEMPLATE},
        },
    }
    ts = _top(root, root_region, tileset_version)
    ts["schema"] = TILE_SCHEMA
    return ts, files


def build(
    records: Iterable[TileRecord],
    tileset_version: str = "",
    single_lod: bool = False,
    tiling: Tiling = "implicit",
    root_volume: tuple[float, float, float, float] | None = None,
) -> tuple[Tileset, dict[str, bytes]]:
    """(tileset.json's dict, the other files it needs by URI: subtrees, implicit only). ``root_volume``: the
    implicit root region (build_implicit); an explicit tileset lists every tile's own region."""
    if tiling == "explicit":
        return build_tileset(records, tileset_version, single_lod), {}
    if tiling == "implicit":
        return build_implicit(records, tileset_version, single_lod, root_volume=root_volume)
    raise ValueError(f"tiling must be implicit or explicit, not {tiling!r}")
