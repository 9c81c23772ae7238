"""Whether the content of an implicit tileset lies in the volumes a client computes from its root alone.

A client that ignores the subtrees' TILE_BOUNDING_REGION / TILE_GEOMETRIC_ERROR metadata (3DTilesRendererJS,
loaders.gl) takes tile (level, x, y)'s region to be the root region halved ``level`` times in longitude and
latitude (tileset.implicit_region) and its geometric error to be the root's / 2^level. Content outside that
volume is culled while it is in view; a tile whose error such a client underrates is drawn too near. 3D Tiles
allows a building that straddles a cell edge to stick out (its tile is drawn whenever any of it is in view);
``measure`` counts, per extract, the buildings (with their parts, every LOD) and blocks outside their tile's
computed volume, those further out than their own half-extent, the worst overhang in metres, and the tiles
whose computed error is below their measured error. The database is read; nothing is written.
"""

from __future__ import annotations

from typing import Any

import numpy as np
import psycopg

from core.geodesy import metres_per_radian

# below 5 cm is the reprojection's, not an overhang: a building's anchor is the centre of its working-CRS box,
# which lies a centimetre or so off the centre of its lon/lat extent on a 100 m building
_EPS_M = 0.05

# every building with its parts: its leaf and the extent (degrees) of every LOD mesh of every member
_GROUPS = """
    SELECT bt.level, bt.x, bt.y, ST_XMin(e), ST_YMin(e), ST_XMax(e), ST_YMax(e)
    FROM (SELECT bt.group_id, bt.level, bt.x, bt.y, ST_Extent(m.envelope_4326) AS e
          FROM tiles.building_tile bt JOIN lod.building_mesh m ON m.building_id = bt.building_id
          GROUP BY 1, 2, 3, 4) bt
"""
# every block: its tile, its extent, and the largest half-extent (degrees, lon and lat) of its members' buildings
# (with their parts)
_BLOCKS = """
    WITH g AS (
        SELECT bt.group_id, ST_Extent(m.envelope_4326) AS e
        FROM tiles.building_tile bt JOIN lod.building_mesh m ON m.building_id = bt.building_id
        GROUP BY 1
    ), member AS (
        SELECT b.block_id, max((ST_XMax(g.e) - ST_XMin(g.e)) / 2) AS hx, max((ST_YMax(g.e) - ST_YMin(g.e)) / 2) AS hy
        FROM gen.block b CROSS JOIN LATERAL unnest(b.members) AS u(building_id)
        JOIN osm.building o ON o.id = u.building_id
        JOIN g ON g.group_id = coalesce(o.parent_id, o.id)  -- an outline drawn by its parts has no mesh of its own
        GROUP BY 1
    )
    SELECT b.level, b.x, b.y, ST_XMin(e), ST_YMin(e), ST_XMax(e), ST_YMax(e), coalesce(m.hx, 0), coalesce(m.hy, 0)
    FROM gen.block b
    CROSS JOIN LATERAL (SELECT ST_Transform(ST_Envelope(b.footprint), 4326)::box2d AS e) x
    LEFT JOIN member m ON m.block_id = b.block_id
"""


def root_volume(conn: psycopg.Connection) -> tuple[float, float, float, float]:
    """The root region the exporter writes for the implicit root (api.quadtree_root); a database whose grid has
    no region (tiles built before migration 0047) gets the root tile's own region, as its exports wrote."""
    row = conn.execute("SELECT west, south, east, north FROM api.quadtree_root()").fetchone()
    if row is None or row[0] is None:
        row = conn.execute(
            "SELECT region[1], region[2], region[3], region[4] FROM tiles.tile WHERE level = 0"
        ).fetchone()
    if row is None:
        raise ValueError("no quadtree: run the tiles stage first")
    return (float(row[0]), float(row[1]), float(row[2]), float(row[3]))


def overhangs(
    root: tuple[float, float, float, float], keys: np.ndarray, ext_deg: np.ndarray, half_deg: np.ndarray | None = None
) -> tuple[np.ndarray, np.ndarray]:
    """Per feature, (metres it sticks out of its tile's computed volume, metres beyond its half-extent): keys
    (n, 3) level, x, y; ext_deg (n, 4) west, south, east, north in degrees; half_deg (n, 2) the half-extent
    allowed in longitude and latitude (degrees), the feature's own when None."""
    west, south, east, north = root
    ext = np.radians(np.asarray(ext_deg, np.float64).reshape(-1, 4))
    lvl, x, y = (np.asarray(keys, np.int64).reshape(-1, 3)[:, i] for i in range(3))
    dlon, dlat = (east - west) / 2.0**lvl, (north - south) / 2.0**lvl
    cell = np.stack([west + x * dlon, south + y * dlat, west + (x + 1) * dlon, south + (y + 1) * dlat], axis=1)
    out = np.maximum.reduce([cell[:, 0] - ext[:, 0], ext[:, 2] - cell[:, 2], np.zeros(len(ext))])
    out_lat = np.maximum.reduce([cell[:, 1] - ext[:, 1], ext[:, 3] - cell[:, 3], np.zeros(len(ext))])
    half = (
        np.c_[(ext[:, 2] - ext[:, 0]) / 2, (ext[:, 3] - ext[:, 1]) / 2]
        if half_deg is None
        else np.radians(np.asarray(half_deg, np.float64).reshape(-1, 2))
    )
    me, mn = metres_per_radian((ext[:, 1] + ext[:, 3]) / 2)
    over = np.hypot(out * me, out_lat * mn)
    beyond = np.hypot(np.maximum(out - half[:, 0], 0) * me, np.maximum(out_lat - half[:, 1], 0) * mn)
    return over, beyond


def _summary(over: np.ndarray, beyond: np.ndarray) -> dict[str, Any]:
    return {
        "n": len(over),
        "outside": int((over > _EPS_M).sum()),
        "beyond_half_extent": int((beyond > _EPS_M).sum()),
        "worst_m": float(over.max(initial=0.0)),
        "worst_beyond_m": float(beyond.max(initial=0.0)),
    }


def measure(conn: psycopg.Connection, tileset: dict[str, Any] | None = None) -> dict[str, Any]:
    """Buildings and blocks outside their tile's computed volume (counts, worst metres) and the tiles whose
    computed error is below their measured one. The root region and error are those ``tileset`` (an implicit
    tileset.json's dict) writes; without one, those the exporter would write (api.quadtree_root, the
    implicit root error)."""
    g = np.array(conn.execute(_GROUPS).fetchall(), np.float64).reshape(-1, 7)
    b = np.array(conn.execute(_BLOCKS).fetchall(), np.float64).reshape(-1, 9)
    tiles = np.array(
        conn.execute("SELECT level, coalesce(geometric_error, 0) FROM tiles.tile").fetchall(), np.float64
    ).reshape(-1, 2)
    if tileset is not None:
        region = tileset["root"]["boundingVolume"]["region"]
        root = (float(region[0]), float(region[1]), float(region[2]), float(region[3]))
        root_error = float(tileset["root"]["geometricError"])
    else:
        root = root_volume(conn)
        root_error = float((tiles[:, 1] * 2.0 ** tiles[:, 0]).max(initial=0.0))
    return {
        "root": list(root),
        "buildings": _summary(*overhangs(root, g[:, :3], g[:, 3:7])),
        "blocks": _summary(*overhangs(root, b[:, :3], b[:, 3:7], b[:, 7:9])),
        "tiles": len(tiles),
        "root_error": root_error,
        "measured_root_error": float(tiles[tiles[:, 0] == 0, 1].max(initial=0.0)),
        "error_shortfalls": error_shortfalls(tiles[:, 0], tiles[:, 1], root_error),
    }


def error_shortfalls(levels: np.ndarray, errors: np.ndarray, root_error: float) -> int:
    """Tiles whose error as a metadata-blind client computes it (root_error / 2^level) is below their own."""
    return int((root_error / 2.0 ** np.asarray(levels, np.float64) < np.asarray(errors, np.float64) - 1e-9).sum())
