"""Stage tiles: the quadtree over the buildings (tiles.build_quadtree, set-based in SQL), its triangle budget
counted on LOD3, the largest mesh of each building, so a tileset exported at any LOD keeps to it."""

from __future__ import annotations

import time
from typing import Any, LiteralString

import psycopg

from core.changes import Changes, differing
from core.progress import Balance, summary
from core.stage import Context, Result

#: a tile's row as this stage writes it, and a building's placement, to compare before and after (the tiles and
#: placements that differ are what the run changed: core/changes.py)
_TILE_ROW = "SELECT * FROM tiles.tile_digests()"
_PLACED = "SELECT building_id, level, x, y, group_id FROM tiles.building_tile"


def _one(conn: psycopg.Connection[Any], query: LiteralString) -> tuple[Any, ...]:
    """The one row ``query`` returns."""
    row = conn.execute(query).fetchone()
    assert row is not None
    return row


def run(ctx: Context) -> Result:
    conn, settings = ctx.conn, ctx.settings
    t0 = time.perf_counter()
    with conn.transaction():
        conn.execute(f"CREATE TEMP TABLE _tile_was ON COMMIT DROP AS {_TILE_ROW}")
        conn.execute(f"CREATE TEMP TABLE _placed_was ON COMMIT DROP AS {_PLACED}")
        # in place (sql/tiles/build_quadtree.sql): the blocks and textures of the tiles that stay are kept until
        # their stages replace them
        conn.execute(
            "CALL tiles.build_quadtree(%s, %s, %s, %s, %s)",
            # budgeted on LOD3, the largest mesh of every building, so any exported LOD fits the triangle budget
            (
                3,
                settings.tile_max_features,
                settings.tile_max_triangles,
                settings.tile_max_level,
                settings.base_height_m,
            ),
        )
        n_tiles, n_leaves, depth = _one(
            conn, "SELECT count(*), count(*) FILTER (WHERE is_leaf), max(level) FROM tiles.tile"
        )
        n_features, max_leaf = _one(
            conn, "SELECT count(*), (SELECT max(n_features) FROM tiles.tile WHERE is_leaf) FROM tiles.building_tile"
        )
        (meshes,) = _one(conn, "SELECT count(*) FROM lod.building_mesh WHERE lod = 3")
        # every feature (a drawn building or part, its LOD3 mesh) in exactly one leaf; checked before commit
        balance = Balance("features", int(meshes), {"in leaf tiles": int(n_features)})
        changed = [
            (int(lv), int(x), int(y))
            for lv, x, y in conn.execute(
                f"SELECT level, x, y FROM ({differing(_TILE_ROW, '_tile_was')}) t "
                f"UNION SELECT level, x, y FROM ({differing(_PLACED, '_placed_was')}) p"
            )
        ]
    seconds = time.perf_counter() - t0
    summary(
        "tiles",
        balance,
        f"{n_leaves:,} leaf tiles ({n_tiles:,} tiles, depth {depth}, largest leaf {max_leaf:,} features)",
        seconds,
        n_features,
    )
    return Result(
        {
            **balance.counts(),
            "features": n_features,
            "tiles": n_tiles,
            "leaves": n_leaves,
            "depth": depth,
            "max_leaf_features": max_leaf,
            "seconds": round(seconds, 3),
        },
        Changes(tiles=changed),
    )
