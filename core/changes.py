"""What an update's stages changed, handed from stage to stage (meta.run_dirty, migration 0043).

Each stage of an update returns, with its counts, the buildings whose rows it changed and the tiles it changed
when it knows them whole (core/stage.py ``Result.changed``), and its run records them (``record``): ingest the
buildings of osm.building_change, lod none of its own (it draws those), landmarks the buildings whose level,
landmark flag, LOD2 band or exaggeration role changed, tiles the tiles and placements that changed, generalize
the buildings of the batches it computed again and the block tiles it made again, textures the tiles it
textured again. A stage after them gets, as ``ctx.changed``, what the runs of the stages it reads changed since
its own last run began (``since``); the tiles those reach (``reach``) are every tile that draws one of those
buildings (its leaf and the leaf's ancestors: every tile above a building stands for it) and every tile they
changed, with its ancestors. Generalize measures the hierarchy of those tiles alone, textures fingerprints those
alone, and the export fingerprints those alone (exporter/reuse.py); the other tiles' content is what it was, and
so are their measures, textures and glbs.

Only an update records; a run without a row (a full run, one that died, one from before migration 0043) may
have changed anything, and a stage after it reads every tile (``since`` gives None). Recording after the stage's
commit (etl/runner.py) is safe for that reason: a process that dies in between leaves a run without a row.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import psycopg

from .pipeline import GRAPH, producers

Key = tuple[int, int, int]

#: the stages whose runs change what each stage reads (derived from the stage graph)
PRODUCERS = {s: producers(s) for s in GRAPH}


@dataclass
class Changes:
    """What runs changed: buildings (osm.building ids, an outline or a part) and tiles."""

    buildings: list[int] = field(default_factory=list)
    tiles: list[Key] = field(default_factory=list)

    def arrays(self) -> dict[str, list[int]]:
        """As meta.run_dirty holds it: building ids, and the tiles as levels, xs and ys."""
        return {"ids": sorted(set(self.buildings)), **tile_arrays(self.tiles)}


def tile_arrays(tiles: list[Key]) -> dict[str, list[int]]:
    """Tiles as the three arrays the SQL functions take (levels, xs, ys)."""
    return {"levels": [t[0] for t in tiles], "xs": [t[1] for t in tiles], "ys": [t[2] for t in tiles]}


def record(conn: psycopg.Connection, run_id: int, changes: Changes) -> None:
    conn.execute(
        "INSERT INTO meta.run_dirty (run_id, building_ids, levels, xs, ys) "
        "VALUES (%(run)s, %(ids)s, %(levels)s, %(xs)s, %(ys)s)",
        {"run": run_id, **changes.arrays()},
    )


def reach(conn: psycopg.Connection, changes: Changes) -> set[Key]:
    """The tiles ``changes`` reaches: its tiles and its buildings' leaves, with their ancestors
    (tiles.reached)."""
    return {
        (int(lv), int(x), int(y))
        for lv, x, y in conn.execute(
            "SELECT level, x, y FROM tiles.reached(%(ids)s, %(levels)s, %(xs)s, %(ys)s)", changes.arrays()
        )
    }


def since(conn: psycopg.Connection, stage: str, run_id: int | None) -> Changes | None:
    """What the runs of ``stage``'s producers changed since run ``run_id`` began (meta.changes_since); None
    when there is no such run or any of those runs recorded no change set (it may have changed anything)."""
    if run_id is None:
        return None
    rows = conn.execute(
        "SELECT recorded, building_ids, levels, xs, ys FROM meta.changes_since(%s, %s)",
        (run_id, list(PRODUCERS[stage])),
    ).fetchall()
    if not all(recorded for recorded, *_ in rows):
        return None
    return Changes([i for r in rows for i in r[1]], [t for r in rows for t in zip(r[2], r[3], r[4], strict=True)])


def last_ok_run(conn: psycopg.Connection, stage: str) -> int | None:
    """The stage's last successful run."""
    row = conn.execute(
        "SELECT max(run_id) FROM meta.pipeline_run WHERE stage = %s AND status = 'ok'", (stage,)
    ).fetchone()
    return None if row is None or row[0] is None else int(row[0])


def differing(query: str, was: str) -> str:
    """A statement giving the rows of ``query`` (a constant SELECT, no values in it) that temporary table ``was``
    (made from it before a change) does not hold, and those of ``was`` it does not give: what the change made
    differ."""
    return f"(({query}) EXCEPT SELECT * FROM {was}) UNION ALL (SELECT * FROM {was} EXCEPT ({query}))"
