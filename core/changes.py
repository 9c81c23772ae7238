"""What an update's stages changed, handed from stage to stage (meta.run_dirty, migration 0043).

Each stage of an update records, with its run, the buildings whose rows it changed and the tiles it changed
(``record``): ingest the buildings of osm.building_change, lod none of its own (it draws those), landmarks the
buildings whose level, landmark flag, LOD2 band or exaggeration role changed, tiles the tiles and placements
that changed, generalize the buildings of the batches it computed again and the block tiles it made again. A
stage after them asks which tiles the runs since its own last one reached (``tiles_since``): every tile that
draws one of those buildings (its leaf and the leaf's ancestors: every tile above a building stands for it) and
every tile they changed, with its ancestors. Generalize measures the hierarchy of those tiles alone, textures
fingerprints those alone (and records the tiles it textured again), and the export fingerprints those alone
since the run that published the live generation (exporter/reuse.py); the other tiles' content is what it was,
and so are their measures, textures and glbs.

Only an update records; a run without a row (a full run, one that died, one from before migration 0043) may
have changed anything, and a stage after it reads every tile, as before (``None``). Recording after the stage's
commit (cmd_stage) is safe for that reason: a process that dies in between leaves a run without a row.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import psycopg

Key = tuple[int, int, int]

#: the stages whose runs change what each consumer reads
PRODUCERS = {
    "generalize": ("ingest", "lod", "landmarks", "tiles"),
    "textures": ("ingest", "lod", "landmarks", "tiles", "generalize"),
    "export": ("ingest", "lod", "landmarks", "tiles", "generalize", "textures"),
}


@dataclass
class Dirty:
    """What a run changed: buildings (osm.building ids, an outline or a part) and tiles."""

    buildings: list[int] = field(default_factory=list)
    tiles: list[Key] = field(default_factory=list)

    def arrays(self) -> dict[str, list[int]]:
        """As meta.run_dirty holds it: building ids, and the tiles as levels, xs and ys."""
        return {"ids": sorted(set(self.buildings)), **tile_arrays(self.tiles)}


def tile_arrays(tiles: list[Key]) -> dict[str, list[int]]:
    """Tiles as the three arrays the SQL functions take (levels, xs, ys)."""
    return {"levels": [t[0] for t in tiles], "xs": [t[1] for t in tiles], "ys": [t[2] for t in tiles]}


def differing(query: str, was: str) -> str:
    """A statement giving the rows of ``query`` (a constant SELECT) that temporary table ``was`` (made from it
    before a change) does not hold, and those of ``was`` it does not give: what the change made differ."""
    return f"(({query}) EXCEPT SELECT * FROM {was}) UNION ALL (SELECT * FROM {was} EXCEPT ({query}))"


def record(conn: psycopg.Connection, run_id: int, dirty: Dirty) -> None:
    conn.execute("INSERT INTO meta.run_dirty (run_id, building_ids, levels, xs, ys) "
                 "VALUES (%(run)s, %(ids)s, %(levels)s, %(xs)s, %(ys)s)", {"run": run_id, **dirty.arrays()})


#: the tiles reached by buildings and tiles: those tiles and the leaves of those buildings (placed by
#: tiles.building_tile as it is now: a building that moved or went is in the tiles stage's run as the tiles it
#: left), each with its ancestors that exist
_REACHED = """
    WITH b AS (SELECT unnest(%(ids)s::int8[]) AS id),
    leaf AS (
        SELECT bt.level, bt.x, bt.y FROM tiles.building_tile bt WHERE bt.building_id IN (SELECT id FROM b)
        UNION
        SELECT bt.level, bt.x, bt.y FROM tiles.building_tile bt WHERE bt.group_id IN (SELECT id FROM b)
        UNION
        SELECT * FROM unnest(%(levels)s::int4[], %(xs)s::int4[], %(ys)s::int4[])
    )
    SELECT DISTINCT l.level - k, l.x >> k, l.y >> k
    FROM leaf l CROSS JOIN LATERAL generate_series(0, l.level) k
    JOIN tiles.tile t ON (t.level, t.x, t.y) = (l.level - k, l.x >> k, l.y >> k)"""


def reach(conn: psycopg.Connection, dirty: Dirty) -> set[Key]:
    """The tiles ``dirty`` reaches: its tiles and its buildings' leaves, with their ancestors."""
    return {(int(lv), int(x), int(y)) for lv, x, y in conn.execute(_REACHED, dirty.arrays())}


def tiles_since(conn: psycopg.Connection, stage: str, run_id: int | None = None) -> set[Key] | None:
    """The tiles the runs of ``stage``'s producers reached since ``stage``'s last successful run began (or run
    ``run_id``: the export's, that published a generation), that is every such run that ended after that or has
    not ended, with their ancestors; None when any of those runs recorded no change set (it may have changed
    anything) or there is no such last run."""
    if run_id is None:
        row = conn.execute("SELECT started_at FROM meta.pipeline_run WHERE stage = %s AND status = 'ok' "
                           "ORDER BY run_id DESC LIMIT 1", (stage,)).fetchone()
    else:
        row = conn.execute("SELECT started_at FROM meta.pipeline_run WHERE run_id = %s AND status = 'ok'",
                           (run_id,)).fetchone()
    if row is None:
        return None
    runs = conn.execute(
        "SELECT d.run_id IS NOT NULL, d.building_ids, d.levels, d.xs, d.ys "
        "FROM meta.pipeline_run r LEFT JOIN meta.run_dirty d USING (run_id) "
        "WHERE r.stage = ANY(%s) AND (r.finished_at IS NULL OR r.finished_at >= %s)",
        (list(PRODUCERS[stage]), row[0])).fetchall()
    if not all(recorded for recorded, *_ in runs):
        return None
    return reach(conn, Dirty([i for r in runs for i in r[1]],
                             [t for r in runs for t in zip(r[2], r[3], r[4], strict=True)]))
