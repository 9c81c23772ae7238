"""Stage generalize: the coarser bands of the tile hierarchy, each with its error measured.

Runs after the tiles stage, whose quadtree decides which buildings share a coarse tile. Levels and their
tolerances come from one SQL function, gen.tolerance(gen_level) (10 m at level 0, halving per level):

1. footprints (level 2): every building (an outline with its parts) gets its outline simplified at
   gen.tolerance(2) by vertex importance and the Sester–Brenner short-edge rules (etl/generalize/simplify.py), with
   vertices on touching neighbours pinned so shared walls stay shared; it is extruded flat to the
   area-weighted height of its parts -> gen.footprint, gen.building_mesh (gen_level 2).
2. decimation (level 3): LOD2 meshes of at least gen_decimate_min_triangles triangles are decimated with
   fast-simplification, all of a batch in one call (etl/generalize/decimate.py); a result is kept only when it is
   closed and within gen.tolerance(3) -> gen.building_mesh (gen_level 3; every feature has a row).
3. blocks (levels 1 and 0): in every tile of those bands, the unprotected buildings below it closer than
   gen.tolerance(level) are clustered (ST_ClusterDBSCAN), merged by buffer-union-unbuffer, simplified at the
   same tolerance and extruded flat to the members' area-weighted height -> gen.block with its members, a tile
   at a time, each block named by its smallest member and its tile's level (block_ids).
   Tiles above those (levels -1 .. -4 of a large city) merge their children's blocks and buildings the
   same way at 20 m, 40 m, 80 m, 160 m, level by level upwards, so a coarse tile's content stays about as
   large as a fine tile's instead of repeating every 10 m block of the city.
   Selection: a block (of any of these bands) that lies within its band's tolerance of a single point (the
   centre of its members' bounding circle at ground level: sqrt(radius² + height²) <= gen.tolerance) is marked
   omitted and its tile does not draw it, as OpenMapTiles drops small blocks and PLATEAU small features per
   level; its members are drawn again in the tiles below, and the coarser bands still merge it. Once the
   hierarchy has its errors (4.), a block whose omission error is within its tile's geometric error is omitted
   too (tiles.omit_within_error): the tile already claims that error, so it stays true, and a coarse tile
   shown from kilometres away no longer draws thousands of blocks a few pixels big.
4. the hierarchy: tiles.finish_hierarchy counts each tile's content and derives its geometric error from the
   measured errors; region_box gives the ECEF boxes api.lod_for_view measures distances to.

The footprint and decimation batches are pure work on arrays (footprint_batch, decimation_batch): they run as
Dask tasks (core/workers.py; settings.gen_workers) while this process reads the next batch and COPYs the last.
A batch is a whole subtree of the tile quadtree (gen.batch_units: the largest holding at most
gen_batch_features features), so what a batch computes depends on the buildings of one place only. Every run
records per batch the fingerprint of what it read (its rows, LOD2 meshes, settings and code: an md5 of the rows
and meshes the database computes for every unit in one statement, gen.footprint_unit_digests and
gen.decimation_unit_digests, so only the units to compute are read here) and what it counted
(gen.unit_input); an update (run with keep) leaves the rows of every batch whose fingerprint is the same where
they are, computes the others and replaces their rows, and deletes those of buildings no batch has any more, which
gives the rows a full run gives while writing only what changed. Blocks the same way, a block tile being the unit
(block_digests: the buildings below it, hashed up the quadtree), and in a tile made again a block whose cluster
has the same input digest stays too.
A batch whose worker hung or died on every attempt loses no building: a footprint batch's buildings are kept as
mapped (outline unchanged, their LOD2 meshes as the level-2 mesh, error 0; kept_as_mapped), a decimation batch
keeps its LOD2 meshes, each saying why in its status ("kept_original: generalize hung ...").

Every generalized object stores error_m, the Hausdorff distance to what it replaces, and total_error_m, a
bound on its distance to the full-detail LOD3 model: its own error plus that of its sources, plus the
LOD2-to-LOD3 step (the openings stand FacadeParams.depth out of the walls, by construction). Simplified
buildings and decimated meshes are measured on the meshes (etl/generalize/hausdorff.py, sampled surfaces, exact
point-triangle distances). A block and its members are flat prisms, so their distance is bounded by
sqrt(h² + dz²): h the larger of the outlines' Hausdorff distance (GEOS) and half the merge distance (the
gaps the merge filled are at most that far from a member), dz the largest change of roof height. An omitted
block's error is that of the omission, sqrt(radius² + height²).
"""

from __future__ import annotations

import collections
import itertools
import os
import time
from collections.abc import Iterator
from dataclasses import dataclass, field
from typing import Any, LiteralString

import numpy as np
import psycopg
import shapely
from psycopg.rows import dict_row
from psycopg.types.json import Jsonb

from core.changes import Changes, reach, tile_arrays
from core.db import analyze, connect, thread_map, working_srid
from core.fingerprint import run_seed
from core.geodesy import region_box
from core.progress import Balance, Progress, summary
from core.reuse import decide, fingerprint, plan
from core.settings import Settings
from core.stage import Context, Result
from core.wkb import decode_triangles, encode_triangles_batch
from core.workers import Lost, imap_isolated, worker_count
from etl.generalize.decimate import decimate
from etl.generalize.hausdorff import hausdorff, outline_hausdorff
from etl.generalize.simplify import PIN_DISTANCE, simplify_footprints
from etl.geom.extrude import Extrusion, extrude
from etl.geom.facade import FacadeParams

BATCH = 2000  # rows per fetch of the blocks' cursors
OPENING_DEPTH = FacadeParams().depth  # LOD3 = LOD2 + openings this far out of the walls

# The stage's queries are functions in sql/gen and sql/tiles (gen.footprint_input, gen.group_lod2_meshes,
# gen.decimation_input, gen.block_clusters, gen.coarse_block_clusters, gen.coarse_bands, tiles.set_boxes,
# tiles.band_summary), read by column name. The set-returning ones are inlined SQL functions, so the cursors
# below stream them exactly as they streamed the queries inline.
_MESH_COLUMNS = (
    "building_id",
    "gen_level",
    "geom",
    "semantics",
    "n_triangles",
    "n_triangles_in",
    "min_height",
    "height",
    "error_m",
    "total_error_m",
    "status",
)
_MESH_TYPES = ("int8", "int2", "bytea", "bytea", "int4", "int4", "float4", "float4", "float4", "float4", "text")
_FOOTPRINT_COLUMNS = (
    "building_id",
    "geom",
    "tolerance_m",
    "n_vertices_in",
    "n_vertices_out",
    "area_in_m2",
    "area_out_m2",
    "error_m",
    "status",
)
_BLOCK_COLUMNS = (
    "block_id",
    "level",
    "x",
    "y",
    "gen_level",
    "members",
    "n_members",
    "footprint",
    "geom",
    "semantics",
    "n_triangles",
    "height",
    "error_m",
    "total_error_m",
    "omitted",
    "collapse_m",
    "input_digest",
)


def _ewkb(geoms: np.ndarray, srid: int) -> list[bytes]:
    return list(shapely.to_wkb(shapely.set_srid(geoms, srid), include_srid=True))


def _triangles(wkbs: list[bytes], owners: list[int]) -> tuple[np.ndarray, np.ndarray]:
    tris = [decode_triangles(w) for w in wkbs]
    counts = [len(t) for t in tris]
    return (np.concatenate(tris) if tris else np.zeros((0, 3, 3)), np.repeat(np.asarray(owners, np.int64), counts))


def _solids(footprints: np.ndarray, bottom: np.ndarray, top: np.ndarray) -> tuple[Extrusion, np.ndarray]:
    """Extrude; a footprint whose caps cannot be triangulated falls back to its minimum rotated rectangle."""
    ex = extrude(footprints, bottom, top)
    bad = ~ex.ok
    if bad.any():
        fixed = footprints.copy()
        fixed[bad] = [shapely.MultiPolygon([shapely.oriented_envelope(g)]) for g in footprints[bad]]
        ex = extrude(fixed, bottom, top)
    return ex, bad


@dataclass
class _Out:
    """A batch's rows for gen.footprint (text COPY) and gen.building_mesh (binary COPY), and its figures."""

    footprints: list[tuple] = field(default_factory=list)
    meshes: list[tuple] = field(default_factory=list)
    stats: dict[str, float] = field(default_factory=dict)


def footprint_batch(
    rows: list[dict[str, Any]], meshes: list[tuple[int, bytes]], tol: float, max_area_change: float, srid: int
) -> _Out:
    """Level 2 of a batch of buildings (gen.footprint_input rows, their LOD2 meshes from
    gen.group_lod2_meshes): simplified outlines, flat solids, and each one's Hausdorff distance to the LOD2
    meshes it replaces. Pure: no database, so it runs in a Dask worker as well as here."""
    ids = np.array([r["group_id"] for r in rows], np.int64)
    geoms = shapely.from_wkb([r["footprint"] for r in rows])
    top = np.array([r["top"] for r in rows], float)
    bottom = np.array([r["bottom"] for r in rows], float)
    openings = np.array([bool(r["openings"]) for r in rows])
    fixed = np.array([shapely.from_wkb(r["pinned"]) if r["pinned"] is not None else None for r in rows], dtype=object)
    s = simplify_footprints(geoms, tol, max_area_change=max_area_change, fixed=fixed)
    ex, rect = _solids(s.geoms, bottom, top)
    n = len(rows)
    index = {int(g): k for k, g in enumerate(ids)}
    b_tri, b_own = _triangles([mesh for _, mesh in meshes], [index[int(g)] for g, _ in meshes])
    a_own = np.repeat(np.arange(n), ex.counts)
    err = hausdorff(ex.triangles, a_own, b_tri, b_own, n, spacing=tol / 4)
    err = np.nan_to_num(err, nan=0.0)
    total = err + np.where(openings, OPENING_DEPTH, 0.0)
    status = np.where(rect, "footprint not triangulable: minimum rotated rectangle", s.status)
    wkbs = encode_triangles_batch(ex.triangles, ex.offsets, srid)
    sem = ex.semantics.tobytes()
    offs = ex.offsets.tolist()
    out = _Out()
    out.footprints = list(
        zip(
            ids.tolist(),
            [w.hex() for w in _ewkb(s.geoms, srid)],
            [tol] * n,
            s.n_vertices_in.tolist(),
            s.n_vertices_out.tolist(),
            s.area_in.tolist(),
            s.area_out.tolist(),
            s.hausdorff.tolist(),
            s.status.tolist(),
            strict=True,
        )
    )
    out.meshes = [
        (
            int(ids[j]),
            2,
            wkbs[j],
            sem[offs[j] : offs[j + 1]],
            int(ex.counts[j]),
            int(rows[j]["n_triangles_in"] or 0),
            float(bottom[j]),
            float(top[j]),
            float(err[j]),
            float(total[j]),
            str(status[j]),
        )
        for j in range(n)
    ]
    out.stats = {
        "buildings": n,
        "vertices_in": int(s.n_vertices_in.sum()),
        "vertices_out": int(s.n_vertices_out.sum()),
        "kept_original": int(sum(str(x).startswith("kept_original") for x in s.status)),
        "max_error_m": float(err.max(initial=0.0)),
        "triangles_in": int(sum(r["n_triangles_in"] or 0 for r in rows)),
        "triangles_out": int(ex.counts.sum()),
    }
    return out


def _facing(tri: np.ndarray) -> bytes:
    """Per-triangle semantics of a mesh that has none of its own: roof (2) where a triangle faces up, floor (0)
    where it faces down, wall (1) otherwise."""
    nz = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    norm = np.linalg.norm(nz, axis=1)
    return np.where(nz[:, 2] > 0.3 * norm, 2, np.where(nz[:, 2] < -0.9 * norm, 0, 1)).astype(np.uint8).tobytes()


def _add(stats: dict[str, float], more: dict[str, float]) -> None:
    """A batch's figures into the stage's: sums, and the largest error."""
    for k, v in more.items():
        stats[k] = max(stats[k], v) if k == "max_error_m" else stats[k] + v


def kept_as_mapped(
    rows: list[dict[str, Any]], meshes: list[tuple[int, bytes]], tol: float, srid: int, status: str
) -> _Out:
    """Level 2 of a footprint batch that its worker hung or died on: each building as mapped, its outline
    unchanged and its LOD2 meshes together as its level-2 mesh (error 0: it is what the band replaces; roof
    where a triangle faces up), ``status`` saying why. Nothing but decoding and encoding, so every building of
    the batch stays in the coarse bands."""
    ids = [int(r["group_id"]) for r in rows]
    index = {g: k for k, g in enumerate(ids)}
    order = sorted(range(len(meshes)), key=lambda i: index[int(meshes[i][0])])  # grouped by building, stable
    tri, own = _triangles([meshes[i][1] for i in order], [index[int(meshes[i][0])] for i in order])
    counts = np.bincount(own, minlength=len(rows))
    offsets = np.concatenate([[0], np.cumsum(counts)])
    wkbs = encode_triangles_batch(tri, offsets, srid)
    sem = _facing(tri)
    geoms = shapely.from_wkb([r["footprint"] for r in rows])
    n_vertices = shapely.get_num_coordinates(geoms).tolist()
    area = shapely.area(geoms).tolist()
    fps = _ewkb(geoms, srid)
    out = _Out()
    for j, r in enumerate(rows):
        opening = OPENING_DEPTH if r["openings"] else 0.0
        out.footprints.append((ids[j], fps[j].hex(), tol, n_vertices[j], n_vertices[j], area[j], area[j], 0.0, status))
        out.meshes.append(
            (
                ids[j],
                2,
                wkbs[j],
                sem[offsets[j] : offsets[j + 1]],
                int(counts[j]),
                int(r["n_triangles_in"] or 0),
                float(r["bottom"]),
                float(r["top"]),
                0.0,
                opening,
                status,
            )
        )
    out.stats = {
        "buildings": len(rows),
        "vertices_in": sum(n_vertices),
        "vertices_out": sum(n_vertices),
        "kept_original": len(rows),
        "triangles_in": int(sum(r["n_triangles_in"] or 0 for r in rows)),
        "triangles_out": int(counts.sum()),
    }
    return out


def decimation_batch(rows: list[dict[str, Any]], tol: float, reduction: float, min_triangles: int, srid: int) -> _Out:
    """Level 3 of a batch of features (gen.decimation_input rows): every LOD2 mesh of at least min_triangles
    decimated in one call, kept where closed and within ``tol``; a row per feature. Pure, as footprint_batch."""
    stats = {"features": len(rows), "decimated": 0, "triangles_in": 0, "triangles_out": 0, "max_error_m": 0.0}
    step = np.array([OPENING_DEPTH if r["openings"] else 0.0 for r in rows])
    big = [k for k, r in enumerate(rows) if r["mesh"] is not None]
    done: dict[int, tuple[bytes | None, bytes | None, int, float, str]] = {}
    if big:
        tri, own = _triangles([rows[k]["mesh"] for k in big], list(range(len(big))))
        d = decimate(tri, own, len(big), reduction, min_triangles=min_triangles, max_error=tol, spacing=tol / 4)
        counts = np.bincount(d.owner, minlength=len(big))
        offsets = np.concatenate([[0], np.cumsum(counts)])
        wkbs = encode_triangles_batch(d.triangles, offsets, srid)
        for j, k in enumerate(big):
            if not d.decimated[j]:
                done[k] = (None, None, 0, 0.0, str(d.status[j]))
                continue
            # a decimated surface has no per-triangle semantics of its own
            facing = _facing(d.triangles[offsets[j] : offsets[j + 1]])
            done[k] = (wkbs[j], facing, int(counts[j]), float(d.error[j]), "decimated")
            stats["decimated"] += 1
            stats["max_error_m"] = max(stats["max_error_m"], float(d.error[j]))
    out = _Out(stats=stats)
    for k, r in enumerate(rows):
        geom, sem, n_out, err, status = done.get(k, (None, None, 0, 0.0, "too small to decimate"))
        n_in = int(r["n_triangles"])
        n_out = n_out if geom is not None else n_in
        out.meshes.append(
            (
                int(r["building_id"]),
                3,
                geom,
                sem,
                n_out,
                n_in,
                float(r["min_height"]),
                float(r["height"]),
                err,
                err + float(step[k]),
                status,
            )
        )
        stats["triangles_in"] += n_in
        stats["triangles_out"] += n_out
    return out


def _task(item: tuple[str, tuple]) -> _Out:
    """One batch as a Dask task (a module-level function, as core/workers.py needs)."""
    kind, args = item
    return footprint_batch(*args) if kind == "footprints" else decimation_batch(*args)


def _mapped(items: Iterator[tuple[Any, tuple[str, tuple]]], settings: Settings) -> Iterator[tuple[Any, _Out | Lost]]:
    """(the caller's context, its batch's _Out or Lost) for every (context, task), in order: here with one
    worker, else as Dask tasks (core/workers.py) a few batches in flight, a batch whose worker hung or died coming
    back as a Lost."""
    workers = worker_count(settings.gen_workers, min(4, os.cpu_count() or 1))
    if workers <= 1:
        for context, task in items:
            yield context, _task(task)
        return
    flight: collections.deque[Any] = collections.deque()

    def tasks() -> Iterator[tuple[str, tuple]]:
        for context, task in items:
            flight.append(context)
            yield task

    for out in imap_isolated(_task, tasks(), workers, settings.gen_batch_timeout_s, window=2 * workers):
        yield flight.popleft(), out


Unit = tuple[int, int, int]
#: the last run's batches, for an update: (step, unit) -> (fingerprint, rows written, figures)
Kept = dict[tuple[str, Unit], tuple[str, int, dict[str, float]]]


@dataclass
class _Units:
    """One step's batches: the gen.unit_input rows of this run and the batches whose rows stay as they are."""

    step: str
    records: list[tuple] = field(default_factory=list)
    kept: list[tuple[Unit, tuple[str, int, dict[str, float]]]] = field(default_factory=list)
    computed: list[int] = field(default_factory=list)  # an update: the buildings of the batches computed again

    @property
    def level(self) -> int:
        """The gen.building_mesh level the step writes."""
        return 2 if self.step == "footprints" else 3


def _unit_rows(src: psycopg.Cursor[dict[str, Any]], size: int) -> Iterator[tuple[Unit, list[dict[str, Any]]]]:
    """The rows of a cursor ordered by batch unit (gen.batch_units), one unit at a time."""
    rows = itertools.chain.from_iterable(iter(lambda: src.fetchmany(size), []))
    for unit, group in itertools.groupby(rows, key=lambda r: (r["unit_level"], r["unit_x"], r["unit_y"])):
        yield unit, list(group)


def _whole(cur: psycopg.Cursor, units: _Units, ids: dict[Unit, list[int]]) -> set[Unit]:
    """The units whose rows of the last run are all still in gen.* (a stage above may have deleted some): one
    query for all of them."""
    flat = [(u, i) for u, b in ids.items() for i in b]
    footprints = units.step == "footprints"  # the decimation step writes meshes only
    got = cur.execute(
        "SELECT t.l, t.x, t.y, count(f.building_id), count(m.building_id) "
        "FROM unnest(%(l)s::int2[], %(x)s::int4[], %(y)s::int4[], %(i)s::int8[]) AS t(l, x, y, id) "
        "LEFT JOIN gen.footprint f ON %(fp)s AND f.building_id = t.id "
        "LEFT JOIN gen.building_mesh m ON m.building_id = t.id AND m.gen_level = %(g)s GROUP BY 1, 2, 3",
        {
            "l": [u[0] for u, _ in flat],
            "x": [u[1] for u, _ in flat],
            "y": [u[2] for u, _ in flat],
            "i": [i for _, i in flat],
            "fp": footprints,
            "g": units.level,
        },
    ).fetchall()
    whole = set()
    for lv, x, y, fp, mesh in got:
        u = (int(lv), int(x), int(y))
        if mesh == len(ids[u]) and (not footprints or fp == len(ids[u])):
            whole.add(u)
    return whole


def _plan(
    cur: psycopg.Cursor, units: _Units, kept: Kept | None, seed: str, digests: list[tuple]
) -> tuple[dict[Unit, str], dict[Unit, list[int]]]:
    """(the fingerprint of every unit to compute, every unit's ids) from the step's gen.*_unit_digests rows
    (unit, ids, digest), through core/reuse.py. A unit whose fingerprint and row count are the last run's and
    whose rows are all there is noted in ``units.kept`` instead: its rows stay as they are. In an update every
    unit's ids are noted in _gen_seen (_drop_unseen)."""
    ids = {(int(lv), int(x), int(y)): [int(i) for i in members] for lv, x, y, members, _ in digests}
    digest = {(int(lv), int(x), int(y)): d for lv, x, y, _, d in digests}
    recorded = None
    if kept is not None:
        with cur.copy("COPY _gen_seen (building_id) FROM STDIN") as copy:
            for b in ids.values():
                for i in b:
                    copy.write_row((i,))
        recorded = {u: old[0] for u in ids if (old := kept.get((units.step, u))) is not None and old[1] == len(ids[u])}
    p = plan(
        list(ids),
        seed,
        recorded,
        lambda us: {u: (digest[u],) for u in us},
        whole=lambda same: _whole(cur, units, {u: ids[u] for u in same}),
    )
    if kept is not None:
        units.kept += [(u, kept[(units.step, u)]) for u in p.keep]
        units.computed += [i for u in p.make for i in ids[u]]
    return {u: p.prints[u] for u in p.make}, ids


def _todo_rows(
    src: psycopg.Cursor[dict[str, Any]], todo: dict[Unit, str], ids: dict[Unit, list[int]], key: str, size: int
) -> Iterator[tuple[Unit, str, list[dict[str, Any]]]]:
    """(unit, its fingerprint, its rows) of the units to compute, from a cursor over their input; checked against
    the ids their digests were made from."""
    for unit, rows in _unit_rows(src, size):
        got = [int(r[key]) for r in rows]
        if unit not in todo or got != ids[unit]:
            raise RuntimeError(f"generalize: batch unit {unit} read {len(got)} rows, not those of its digest")
        yield unit, todo[unit], rows


def _todo_ids(todo: dict[Unit, str], ids: dict[Unit, list[int]], kept: Kept | None) -> list[int] | None:
    """The buildings of the units to compute, for a step's input function to read only those (None in a full
    run: every unit is computed)."""
    return None if kept is None else [i for u in todo for i in ids[u]]


def _drop_unseen(cur: psycopg.Cursor, units: _Units) -> None:
    """An update: delete the rows of buildings (or features) that no batch of this run has any more (deleted,
    now a part or a landmark), so the step's rows are what a full run writes; then forget them for the next
    step."""
    cur.execute("ANALYZE _gen_seen")
    if units.step == "footprints":
        cur.execute(
            "DELETE FROM gen.footprint f WHERE NOT EXISTS (SELECT 1 FROM _gen_seen s "
            "WHERE s.building_id = f.building_id)"
        )
    cur.execute(
        "DELETE FROM gen.building_mesh m WHERE m.gen_level = %s AND NOT EXISTS (SELECT 1 FROM _gen_seen s "
        "WHERE s.building_id = m.building_id)",
        (units.level,),
    )
    cur.execute("TRUNCATE _gen_seen")


def _written(units: _Units) -> int:
    """The rows the step wrote: those of its batches computed (not kept), for core.db.analyze."""
    kept = {u for u, _ in units.kept}
    return sum(int(r[5]) for r in units.records if tuple(r[1:4]) not in kept)


def _count_kept(units: _Units, stats: dict[str, float]) -> None:
    """The kept batches' figures (as the last run counted them) into the step's, and their gen.unit_input rows."""
    for unit, (print_, n, figures) in units.kept:
        _add(stats, figures)
        units.records.append((units.step, *unit, print_, n, Jsonb(figures)))


def _footprints(
    conn: psycopg.Connection,
    reader: psycopg.Connection,
    settings: Settings,
    srid: int,
    tol: float,
    progress: Progress,
    seed: str,
    kept: Kept | None,
) -> tuple[dict[str, float], _Units]:
    stats = {
        "buildings": 0,
        "vertices_in": 0,
        "vertices_out": 0,
        "kept_original": 0,
        "max_error_m": 0.0,
        "triangles_in": 0,
        "triangles_out": 0,
        "lost": 0,
    }
    units = _Units("footprints")
    with reader.cursor(name="gen_groups", row_factory=dict_row) as src, conn.cursor() as cur:
        todo, ids = _plan(
            cur,
            units,
            kept,
            seed,
            cur.execute(
                "SELECT unit_level, unit_x, unit_y, group_ids, digest FROM gen.footprint_unit_digests(%s, %s)",
                (PIN_DISTANCE, settings.gen_batch_features),
            ).fetchall(),
        )
        progress.update(sum(len(ids[u]) for u, _ in units.kept))
        src.itersize = settings.gen_batch_features
        src.execute(
            "SELECT * FROM gen.footprint_input(%s, %s, %s::int8[])",
            (PIN_DISTANCE, settings.gen_batch_features, _todo_ids(todo, ids, kept)),
        )

        def items() -> Iterator[
            tuple[tuple[Unit, str, list[dict[str, Any]], list[tuple[int, bytes]]], tuple[str, tuple]]
        ]:
            for unit, print_, rows in _todo_rows(src, todo, ids, "group_id", settings.gen_batch_features):
                # measured against what the band replaces: the LOD2 meshes of the building and its parts
                meshes = cur.execute("SELECT group_id, mesh FROM gen.group_lod2_meshes(%s)", (ids[unit],)).fetchall()
                yield (
                    (unit, print_, rows, meshes),
                    ("footprints", (rows, meshes, tol, settings.gen_max_area_change, srid)),
                )

        for (unit, print_, rows, meshes), out in _mapped(items(), settings):
            if isinstance(out, Lost):
                out = kept_as_mapped(
                    rows,
                    meshes,
                    tol,
                    srid,
                    f"kept_original: generalize {out.reason} (its batch of {len(rows)} buildings: {out.detail})",
                )
                stats["lost"] += len(rows)
                print_ = None  # never kept: computed again next time
            _copy(cur, out, replace=kept is not None)
            _add(stats, out.stats)
            units.records.append((units.step, *unit, print_, len(rows), Jsonb(out.stats)))
            progress.update(len(rows))
        _count_kept(units, stats)
        if kept is not None:
            _drop_unseen(cur, units)
    return stats, units


def _copy(cur: psycopg.Cursor, out: _Out, replace: bool = False) -> None:
    """Write a batch's rows; ``replace`` (an update): first delete the rows its buildings had."""
    if replace:
        if out.footprints:
            cur.execute("DELETE FROM gen.footprint WHERE building_id = ANY(%s)", ([r[0] for r in out.footprints],))
        if out.meshes:
            cur.execute(
                "DELETE FROM gen.building_mesh WHERE building_id = ANY(%s) AND gen_level = %s",
                ([r[0] for r in out.meshes], out.meshes[0][1]),
            )
    if out.footprints:
        with cur.copy(f"COPY gen.footprint ({', '.join(_FOOTPRINT_COLUMNS)}) FROM STDIN") as copy:
            for row in out.footprints:
                copy.write_row(row)
    if out.meshes:
        with cur.copy(f"COPY gen.building_mesh ({', '.join(_MESH_COLUMNS)}) FROM STDIN (FORMAT BINARY)") as copy:
            copy.set_types(list(_MESH_TYPES))
            for row in out.meshes:
                copy.write_row(row)


def _decimation_digests(conn: psycopg.Connection, settings: Settings) -> list[tuple]:
    """The decimation units' digests (gen.decimation_unit_digests). run() reads them beside the footprint step (a
    thread_map of one): they read only what the stages before generalize committed (LOD2 and LOD3 meshes, the
    tiles' buildings), so PostgreSQL computes them while the footprint batches are computed (on the benchmark
    extract 0.19 s alone, 0.36 s in an update's statement log: every update reads every unit's digest)."""
    return conn.execute(
        "SELECT unit_level, unit_x, unit_y, building_ids, digest FROM gen.decimation_unit_digests(%s, %s)",
        (settings.gen_decimate_min_triangles, settings.gen_batch_features),
    ).fetchall()


def _decimation(
    conn: psycopg.Connection,
    reader: psycopg.Connection,
    settings: Settings,
    srid: int,
    tol: float,
    seed: str,
    kept: Kept | None,
    digests: list[tuple],
) -> tuple[dict[str, float], _Units]:
    stats = {"features": 0, "decimated": 0, "triangles_in": 0, "triangles_out": 0, "max_error_m": 0.0, "lost": 0}
    units = _Units("decimation")
    with reader.cursor(name="gen_features", row_factory=dict_row) as src, conn.cursor() as cur:
        todo, ids = _plan(cur, units, kept, seed, digests)
        src.itersize = settings.gen_batch_features
        src.execute(
            "SELECT * FROM gen.decimation_input(%s, %s, %s::int8[])",
            (settings.gen_decimate_min_triangles, settings.gen_batch_features, _todo_ids(todo, ids, kept)),
        )
        args = (tol, settings.gen_decimate_reduction, settings.gen_decimate_min_triangles, srid)

        def items() -> Iterator[tuple[tuple[Unit, str, list[dict[str, Any]]], tuple[str, tuple]]]:
            for unit, print_, rows in _todo_rows(src, todo, ids, "building_id", settings.gen_batch_features):
                yield (unit, print_, rows), ("decimation", (rows, *args))

        for (unit, print_, rows), out in _mapped(items(), settings):
            if isinstance(out, Lost):
                # the batch keeps its LOD2 meshes as they are (a row with no mesh of its own), saying why
                detail = f"kept: decimation {out.reason} ({out.detail})"
                lost = [{**r, "mesh": None} for r in rows]
                out = decimation_batch(lost, *args)
                out.meshes = [(*m[:-1], detail) for m in out.meshes]
                stats["lost"] += len(rows)
                print_ = None
            _copy(cur, out, replace=kept is not None)
            _add(stats, out.stats)
            units.records.append((units.step, *unit, print_, len(rows), Jsonb(out.stats)))
        _count_kept(units, stats)
        if kept is not None:
            _drop_unseen(cur, units)
    return stats, units


def block_ids(rows: list[dict[str, Any]]) -> list[int]:
    """gen.block.block_id: the block's smallest member and its tile's level, packed as (2m, or -2m + 1 for a
    relation's negative id) * 32 + level. A building is below one tile per level and a tile's blocks never share
    a member, so the pair is unique; it is the same whenever the block is made, so a change elsewhere does not
    renumber it (an identity would: every block written after the change, in every glb that draws one); and it
    stays below 2^53, which a JavaScript client reads exactly (a 63-bit hash came back from loaders.gl as a
    string)."""
    out = []
    for r in rows:
        m, level = int(min(r["members"])), int(r["level"])
        if not 0 <= level < 32:
            raise ValueError(f"tile level {level} does not fit a block id (0 .. 31)")
        out.append((2 * m if m >= 0 else -2 * m + 1) * 32 + level)
    return out


@dataclass
class _BlockReuse:
    """The block tiles' fingerprints of this run (block_digests), the last run's (an update: else None), the
    gen.unit_input rows this run makes and the tiles it keeps (step blocks, a tile per unit), the run's seed (in
    every block's input_digest) and the blocks kept one at a time in the tiles made again."""

    digests: dict[Unit, str]
    kept: Kept | None
    seed: str
    units: _Units = field(default_factory=lambda: _Units("blocks"))
    blocks_kept: int = 0
    written: int = 0  # blocks made (written) so far
    made: list[Unit] = field(default_factory=list)  # an update: the block tiles made again


def block_digests(conn: psycopg.Connection, seed: str) -> dict[Unit, str]:
    """Per tile of the block bands (gen_level <= 1), a fingerprint of everything its blocks are made from: the
    buildings below it as the blocks read them (gen.leaf_block_input), hashed up the quadtree with each tile's
    place and band, so a tile's covers its children's blocks (made from the same buildings) as well."""
    tiles = conn.execute("SELECT level, x, y, gen_level, is_leaf FROM tiles.tile ORDER BY level DESC, x, y").fetchall()
    leaf = {(int(lv), int(x), int(y)): d for lv, x, y, d in conn.execute("SELECT * FROM gen.leaf_block_input()")}
    below: dict[Unit, list[str]] = collections.defaultdict(list)
    out: dict[Unit, str] = {}
    for lv, x, y, g, is_leaf in tiles:  # children (deeper levels) first
        key = (int(lv), int(x), int(y))
        out[key] = fingerprint(seed, (key, g, is_leaf, leaf.get(key)), *sorted(below.pop(key, [])))
        if lv > 0:
            below[(lv - 1, x >> 1, y >> 1)].append(out[key])
    band = {(int(lv), int(x), int(y)): g for lv, x, y, g, _ in tiles}
    return {k: d for k, d in out.items() if band[k] is not None and band[k] <= 1}


def _block_tiles(cur: psycopg.Cursor, reuse: _BlockReuse, tiles: list[Unit]) -> tuple[list[Unit], list[Unit]]:
    """(tiles to make, tiles whose blocks stay as they are), through core/reuse.py: a tile is kept when the last
    run recorded its fingerprint and gen.block still holds every block it made."""
    if reuse.kept is None:
        return tiles, []
    recorded = {t: old for t in tiles if (old := reuse.kept.get(("blocks", t))) is not None}

    def whole(same: list[Unit]) -> set[Unit]:
        counts = {
            (int(lv), int(x), int(y)): int(n)
            for lv, x, y, n in cur.execute(
                "SELECT level, x, y, count(*) FROM gen.block WHERE (level, x, y) IN "
                "(SELECT * FROM unnest(%s::int2[], %s::int4[], %s::int4[])) GROUP BY 1, 2, 3",
                ([t[0] for t in same], [t[1] for t in same], [t[2] for t in same]),
            )
        }
        return {t for t in same if counts.get(t, 0) == recorded[t][1]}

    keep, make = decide(tiles, reuse.digests, {t: old[0] for t, old in recorded.items()}, whole)
    return make, keep


def _keep_blocks(reuse: _BlockReuse, tiles: list[Unit], stats: dict[str, float]) -> None:
    """The figures the last run counted for the blocks of the kept tiles, which stay in gen.block as made."""
    if not tiles:
        return
    assert reuse.kept is not None  # only an update keeps tiles
    for t in tiles:
        print_, n, figures = reuse.kept[("blocks", t)]
        _add(stats, figures)
        reuse.units.kept.append((t, (print_, n, figures)))
        reuse.units.records.append(("blocks", *t, print_, n, Jsonb(figures)))


def _make_blocks(
    cur: psycopg.Cursor, rows: list[dict[str, Any]], settings: Settings, srid: int
) -> tuple[list[float], list[bool], int]:
    """Simplify, extrude and measure the clusters ``rows`` (of gen.block_clusters or gen.coarse_block_clusters),
    write them to gen.block, and return their errors (as stored: real), omissions and member count. Each
    block's figures depend on its own row alone (outline_hausdorff measures a batch's pairs apart), so a block
    made in another batch, as an update copies it, is the same block."""
    if not rows:
        return [], [], 0
    n = len(rows)
    tol = np.array([r["tolerance"] for r in rows], float)
    merged = shapely.from_wkb([r["merged"] for r in rows])
    s = simplify_footprints(merged, tol, max_area_change=settings.gen_max_area_change)
    geoms = np.where(shapely.is_empty(s.geoms), merged, s.geoms)
    top = np.array([r["height"] if r["height"] is not None else r["hmax"] for r in rows], float)
    ex, _ = _solids(geoms, np.zeros(n), top)
    members = [list(r["members"]) for r in rows]
    # prisms against prisms: the outlines' Hausdorff distance, the gaps the merge filled (at most half
    # the distance) and the largest roof height change bound the distance between the solids
    joined = shapely.from_wkb([r["joined"] for r in rows])
    hmax = np.array([r["hmax"] for r in rows], float)
    outline = outline_hausdorff(geoms, joined, tol / 4)
    gap = np.where(np.array([r["n_in"] for r in rows]) > 1, tol / 2, 0.0)  # only merges fill gaps
    dz = np.maximum(hmax - top, top - np.array([r["hmin"] for r in rows], float))
    err = np.hypot(np.maximum(outline, gap), np.maximum(dz, 0.0))
    # selection: a block that fits within the band's tolerance of one point (the centre of its members'
    # bounding circle, at ground level) is omitted from its tile; that collapse is then its error
    collapse = np.hypot(shapely.minimum_bounding_radius(joined), hmax)
    omitted = collapse <= tol
    err = np.where(omitted, collapse, err)
    total = err + np.array([float(r["members_error_m"]) for r in rows])
    wkbs = encode_triangles_batch(ex.triangles, ex.offsets, srid)
    fps = _ewkb(geoms, srid)
    sem = ex.semantics.tobytes()
    offs = ex.offsets.tolist()
    ids = block_ids(rows)
    with cur.copy(f"COPY gen.block ({', '.join(_BLOCK_COLUMNS)}) FROM STDIN") as copy:
        for j, r in enumerate(rows):
            copy.write_row(
                (
                    ids[j],
                    r["level"],
                    r["x"],
                    r["y"],
                    r["gen_level"],
                    members[j],
                    len(members[j]),
                    fps[j].hex(),
                    wkbs[j].hex(),
                    sem[offs[j] : offs[j + 1]],
                    int(ex.counts[j]),
                    float(top[j]),
                    float(err[j]),
                    float(total[j]),
                    bool(omitted[j]),
                    float(collapse[j]),
                    r["input_digest"],
                )
            )
    # the errors as stored (real), so that kept blocks count alike
    errs = [float(e) for e in err.astype(np.float32)]
    omits = [bool(o) for o in omitted]
    n_members = sum(len(m) for m in members)
    return errs, omits, n_members


def _blocks(
    conn: psycopg.Connection,
    settings: Settings,
    srid: int,
    progress: Progress,
    reuse: _BlockReuse,
    coarse: tuple[int, int] | None = None,
) -> dict[str, float]:
    """Blocks of the 10 m and 5 m bands (from the buildings), or of the tiles of coarser band and level
    ``coarse`` = (gen_level < 0, level) (from the children's content, which must be in gen.block already).
    Every tile is recorded in ``reuse`` with its fingerprint; in an update the blocks of the tiles whose
    fingerprint is the last run's stay as they are, and so do, in the others, the blocks whose cluster has the
    same input digest; a tile's other blocks are replaced."""
    stats = {"blocks": 0, "omitted": 0, "members": 0, "max_error_m": 0.0}
    # reads the footprints this transaction wrote, so on the writing connection (another one would read the
    # rows of before), a batch at a time between the COPYs
    conn.execute("SET LOCAL cursor_tuple_fraction = 1.0")
    with conn.cursor(name="gen_blocks", row_factory=dict_row) as src, conn.cursor() as cur:
        src.itersize = BATCH
        here = [
            (int(lv), int(x), int(y))
            for lv, x, y in cur.execute(
                "SELECT level, x, y FROM tiles.tile WHERE CASE WHEN %(g)s::int IS NULL THEN gen_level IN (0, 1) "
                "ELSE gen_level = %(g)s AND level = %(lv)s END ORDER BY level, x, y",
                {"g": coarse[0] if coarse else None, "lv": coarse[1] if coarse else None},
            )
        ]
        make, keep = _block_tiles(cur, reuse, here)
        _keep_blocks(reuse, keep, stats)
        reuse.made += make
        lvs, xs, ys = ([t[i] for t in make] for i in range(3))
        skip = _kept_clusters(cur, reuse, make)
        if coarse is None:
            src.execute(
                "SELECT * FROM gen.block_clusters(%s::int2[], %s::int4[], %s::int4[], %s, %s::text[])",
                (lvs, xs, ys, reuse.seed, skip),
            )
        else:
            src.execute(
                "SELECT * FROM gen.coarse_block_clusters(%s, %s, %s::int4[], %s::int4[], %s, %s::text[])",
                (*coarse, xs, ys, reuse.seed, skip),
            )
        made: set[Unit] = set()
        # a tile's blocks are one batch (a block depends on its own cluster alone: _make_blocks); the clusters
        # in skip come back unmade, and their blocks stay
        for tile, tile_rows in itertools.groupby(
            itertools.chain.from_iterable(iter(lambda: src.fetchmany(BATCH), [])),
            key=lambda r: (int(r["level"]), int(r["x"]), int(r["y"])),
        ):
            figures = _block_tile(cur, tile, list(tile_rows), settings, srid, reuse)
            _add(stats, figures)
            reuse.units.records.append(("blocks", *tile, reuse.digests.get(tile), figures["blocks"], Jsonb(figures)))
            made.add(tile)
            progress.update(int(figures["blocks"]))
        _no_blocks(cur, reuse, [t for t in make if t not in made])
    return stats


def _kept_clusters(cur: psycopg.Cursor, reuse: _BlockReuse, make: list[Unit]) -> list[str] | None:
    """In an update, the input digests of the blocks of the tiles made again: a cluster made of the same inputs
    keeps its block, not made again."""
    if reuse.kept is None or not make:
        return None
    return [
        d
        for (d,) in cur.execute(
            "SELECT input_digest FROM gen.block WHERE input_digest IS NOT NULL "
            "AND (level, x, y) IN (SELECT * FROM unnest(%s::int2[], %s::int4[], %s::int4[]))",
            ([t[0] for t in make], [t[1] for t in make], [t[2] for t in make]),
        )
    ]


def _block_tile(
    cur: psycopg.Cursor,
    tile: Unit,
    everything: list[dict[str, Any]],
    settings: Settings,
    srid: int,
    reuse: _BlockReuse,
) -> dict[str, float]:
    """One tile's blocks made (its clusters with a merged outline) or kept (those in the skip list), and the
    tile's figures."""
    rows = [r for r in everything if r["merged"] is not None]
    same = [r["input_digest"] for r in everything if r["merged"] is None]  # in skip: kept
    if reuse.kept is not None:
        # the tile's other blocks go, and any stale one (of a tile not reached yet) whose id a new block
        # takes: its smallest member moved here
        cur.execute(
            "DELETE FROM gen.block WHERE (level, x, y) = (%s, %s, %s) "
            "AND (input_digest IS NULL OR NOT input_digest = ANY(%s))",
            (*tile, same),
        )
        cur.execute("DELETE FROM gen.block WHERE block_id = ANY(%s)", (block_ids(rows),))
    errs, omits, n_members = _make_blocks(cur, rows, settings, srid)
    reuse.written += len(rows)
    if same:
        # as made: omitted for its band alone, its own error (not the omission on tile error's)
        got = cur.execute(
            "SELECT omitted, error_m, n_members FROM gen.block_as_made WHERE (level, x, y) = "
            "(%s, %s, %s) AND input_digest = ANY(%s)",
            (*tile, same),
        ).fetchall()
        if len(got) != len(same):
            raise RuntimeError(f"tile {tile}: {len(same)} kept blocks, {len(got)} found")
        omits += [bool(o) for o, _, _ in got]
        errs += [float(np.float32(e)) for _, e, _ in got]  # a real read as text: its float32 again
        n_members += sum(int(k) for _, _, k in got)
        reuse.blocks_kept += len(got)
    return {
        "blocks": len(omits),
        "omitted": sum(omits),
        "members": n_members,
        "max_error_m": max(errs, default=0.0),
    }


def _no_blocks(cur: psycopg.Cursor, reuse: _BlockReuse, gone: list[Unit]) -> None:
    """Tiles that made no block (every building below a landmark) have their row too, and none of their old
    blocks."""
    empty = {"blocks": 0, "omitted": 0, "members": 0, "max_error_m": 0.0}
    reuse.units.records += [("blocks", *t, reuse.digests.get(t), 0, Jsonb(empty)) for t in gone]
    if gone and reuse.kept is not None:
        cur.execute(
            "DELETE FROM gen.block WHERE (level, x, y) IN (SELECT * FROM unnest(%s::int2[], %s::int4[], %s::int4[]))",
            ([t[0] for t in gone], [t[1] for t in gone], [t[2] for t in gone]),
        )


def coarse_blocks(
    conn: psycopg.Connection,
    settings: Settings,
    srid: int,
    reuse: _BlockReuse | None = None,
    max_level: int | None = None,
) -> dict[str, dict[int, int]]:
    """The coarser bands (gen_level < 0; only tiles at levels <= ``max_level`` if given), finest band and
    deepest level first: each tile is built from its children's content (the top tiles share band -4, so a
    band runs level by level). Returns the blocks and the omitted ones of each band ({"coarse_blocks": {g: n},
    "coarse_omitted": {g: n}})."""
    reuse = reuse or _BlockReuse({}, None, seed="")  # outside a run (benchmarks/view_bench.py): nothing recorded
    pairs = [
        (int(g), int(lv)) for g, lv in conn.execute("SELECT gen_level, level FROM gen.coarse_bands(%s)", (max_level,))
    ]
    out: dict[int, int] = {}
    omitted: dict[int, int] = {}
    for g, lv in pairs:
        with conn.cursor() as cur:  # the level below was just written (see run)
            analyze(cur, "gen.block", reuse.written if reuse.kept is not None else None)
        st = _blocks(conn, settings, srid, Progress("generalize", f"blocks {g} (level {lv})"), reuse, (g, lv))
        out[g] = out.get(g, 0) + int(st["blocks"])
        omitted[g] = omitted.get(g, 0) + int(st["omitted"])
    return {"coarse_blocks": out, "coarse_omitted": omitted}


def store_boxes(cur: psycopg.Cursor) -> None:
    """tiles.tile.box from each tile's region (region_box), all tiles in one call of tiles.set_boxes; inside the
    caller's transaction."""
    with cur.connection.cursor(row_factory=dict_row) as c:
        tiles = c.execute("SELECT level, x, y, region FROM tiles.tile ORDER BY level, x, y").fetchall()
    boxes = region_box(np.array([t["region"] for t in tiles], float))
    cur.execute(
        "CALL tiles.set_boxes(%s, %s, %s, %s)",
        ([t["level"] for t in tiles], [t["x"] for t in tiles], [t["y"] for t in tiles], boxes.ravel().tolist()),
    )


def _seed(settings: Settings, code: str, srid: int, tol: dict[int, float]) -> str:
    """What every batch fingerprint of this run starts from: the settings, the stage's code as etl/staleness.py
    records it (new code never copies old rows), the working CRS and the tolerances."""
    return run_seed(settings.as_dict(), code, srid, tol)


def _kept(conn: psycopg.Connection) -> Kept:
    return {
        (step, (int(lv), int(x), int(y))): (f, int(n), stats)
        for step, lv, x, y, f, n, stats in conn.execute(
            "SELECT step, level, x, y, fingerprint, n_rows, stats FROM gen.unit_input WHERE fingerprint IS NOT NULL"
        )
    }


def _scalar(conn: psycopg.Connection | psycopg.Cursor, query: LiteralString, params: tuple[Any, ...] = ()) -> Any:
    """The first column of the one row ``query`` returns."""
    row = conn.execute(query, params).fetchone()
    assert row is not None
    return row[0]


def _clear(cur: psycopg.Cursor, kept: Kept | None) -> None:
    """What the run writes again: every row in a full run; in an update the blocks of tiles no longer in a block
    band (the rest is replaced batch by batch). Not TRUNCATE: its lock would make every reader of these tables
    wait for the stage (seconds to minutes), and a reader's older snapshot would find them empty; deleted rows
    stay theirs until the commit."""
    if kept is None:
        cur.execute("DELETE FROM gen.block; DELETE FROM gen.building_mesh; DELETE FROM gen.footprint")
    else:
        # an update writes only what changed: the buildings each step has are noted here (_drop_unseen)
        cur.execute("CREATE TEMP TABLE _gen_seen (building_id bigint) ON COMMIT DROP")
        # The other tiles' omissions on tile error stay as the last run left them: what reads a block until the
        # hierarchy decides them again reads it as made (gen.block_as_made), and tiles.omit_within_error writes
        # the blocks whose omission changed (an update wrote every such block twice, back as made and omitted
        # again)
        cur.execute(
            "DELETE FROM gen.block k USING tiles.tile t WHERE (t.level, t.x, t.y) = (k.level, k.x, k.y) "
            "AND (t.gen_level IS NULL OR t.gen_level > 1)"
        )
    cur.execute("DELETE FROM gen.unit_input")


def _hierarchy(
    conn: psycopg.Connection, cur: psycopg.Cursor, settings: Settings, since: set[Unit] | None, own: Changes
) -> tuple[list[Unit], int]:
    """The tile hierarchy finished (every tile, or those ``since`` and this run's changes reach) with the
    omissions within tile error and the tiles' boxes: (the tiles measured again, blocks omitted on error)."""
    scope: list[Unit] = []
    if since is None:
        cur.execute("CALL tiles.finish_hierarchy(%s)", (settings.base_height_m,))  # omits within tile error too
    else:
        scope = sorted(since | reach(conn, own))
        cur.execute(
            "CALL tiles.finish_hierarchy(%(base)s, %(levels)s, %(xs)s, %(ys)s)",
            {"base": settings.base_height_m, **tile_arrays(scope)},
        )
    omitted = int(_scalar(cur, "SELECT count(*) FROM gen.block_as_made WHERE omitted_on_error"))
    store_boxes(cur)
    return scope, omitted


def _balance(cur: psycopg.Cursor, n_groups: int) -> Balance:
    """Every building (an outline with its parts) has its generalized footprint and solid; before commit."""
    row = cur.execute(
        """SELECT count(*) FILTER (WHERE f.status LIKE 'simplified%%'),
                  count(*) FILTER (WHERE f.status NOT LIKE 'simplified%%')
           FROM gen.footprint f JOIN gen.building_mesh m ON m.building_id = f.building_id AND m.gen_level = 2
        """
    ).fetchone()
    assert row is not None
    return Balance("buildings", n_groups, {"simplified": row[0], "left as mapped": row[1]})


def run(ctx: Context) -> Result:
    """Generalize every tile; in an update, the rows of the batches and block tiles whose input did not change
    stay as they are, and only the others are computed and written again; when it knows what changed since the
    last run (``ctx.changed``), the hierarchy of the tiles that reaches alone is measured again, with those this
    run changed."""
    conn, url, settings, keep = ctx.conn, ctx.url, ctx.settings, ctx.update
    t0 = time.perf_counter()
    since = reach(conn, ctx.changed) if keep and ctx.changed is not None else None
    srid = working_srid(conn)
    if not _scalar(conn, "SELECT EXISTS (SELECT 1 FROM tiles.tile)"):
        raise RuntimeError("no tiles: run the tiles stage first (make tiles)")
    tol = {g: float(_scalar(conn, "SELECT gen.tolerance(%s)", (g,))) for g in range(5)}
    seconds: dict[str, float] = {}
    n_groups = int(_scalar(conn, "SELECT count(DISTINCT group_id) FROM tiles.building_tile"))
    if settings.gen_batch_features < 1:
        raise ValueError("gen_batch_features must be at least 1")
    seed = _seed(settings, ctx.code, srid, tol)
    kept = _kept(conn) if keep else None
    with connect(url) as reader, conn.transaction(), conn.cursor() as cur:
        # the inputs are read whole: plan for all rows, not the fast-start plans cursors get by default
        reader.execute("SET cursor_tuple_fraction = 1.0")
        _clear(cur, kept)
        step = time.perf_counter()
        # the decimation's digests computed meanwhile
        with thread_map(url, _decimation_digests, [settings], 1) as dec_digests:
            fp, fp_units = _footprints(
                conn, reader, settings, srid, tol[2], Progress("generalize", "buildings", total=n_groups), seed, kept
            )
            seconds["footprints"] = time.perf_counter() - step
            step = time.perf_counter()
            dec, dec_units = _decimation(conn, reader, settings, srid, tol[3], seed, kept, next(dec_digests))
            seconds["decimation"] = time.perf_counter() - step
        step = time.perf_counter()
        # the blocks join the footprints and meshes just written: without statistics the planner takes the
        # tables for what they held before (empty after a full lod) and scans them once per member (minutes at
        # 100k buildings)
        n_fp, n_dec = _written(fp_units), _written(dec_units)
        analyze(cur, "gen.footprint", n_fp if keep else None)
        analyze(cur, "gen.building_mesh", n_fp + n_dec if keep else None)
        reuse = _BlockReuse(block_digests(conn, seed), kept, seed=seed)
        blk: dict[str, object] = {**_blocks(conn, settings, srid, Progress("generalize", "blocks"), reuse)}
        blk.update(coarse_blocks(conn, settings, srid, reuse))
        with cur.copy("COPY gen.unit_input (step, level, x, y, fingerprint, n_rows, stats) FROM STDIN") as copy:
            for row in fp_units.records + dec_units.records + reuse.units.records:
                copy.write_row(row)
        seconds["blocks"] = time.perf_counter() - step
        step = time.perf_counter()
        own = Changes(fp_units.computed + dec_units.computed, reuse.made)
        scope, blk["omitted_within_tile_error"] = _hierarchy(conn, cur, settings, since, own)
        seconds["hierarchy"] = time.perf_counter() - step
        bands = conn.cursor(row_factory=dict_row).execute("SELECT * FROM tiles.band_summary()").fetchall()
        balance = _balance(cur, n_groups)
        # gen.footprint and gen.building_mesh were analyzed once written, before the blocks
        analyze(cur, "gen.block", reuse.written if keep else None)
    wall = time.perf_counter() - t0
    result: dict[str, object] = {
        **balance.counts(),
        "buildings": n_groups,
        "tolerance_m": tol,
        "footprints": fp,
        "decimation": dec,
        "blocks": blk,
        "batches": {
            u.step: {"computed": len(u.records) - len(u.kept), "kept": len(u.kept)}
            for u in (fp_units, dec_units, reuse.units)
        }
        | {"blocks_kept": reuse.blocks_kept},  # in the tiles made again, one cluster at a time
        "bands": [
            {
                **b,
                "features": int(b["features"]),
                "triangles": int(b["triangles"]),
                "max_geometric_error_m": round(float(b["max_geometric_error_m"]), 3),
            }
            for b in bands
        ],
        "seconds": round(wall, 3),
        "seconds_by_step": {k: round(v, 3) for k, v in seconds.items()},
        "hierarchy_tiles": None if since is None else len(scope),  # measured again (None: every tile)
    }
    kept_note = (
        f"; footprint batches kept {len(fp_units.kept):,} of {len(fp_units.records):,}, decimation "
        f"{len(dec_units.kept):,} of {len(dec_units.records):,}, block tiles {len(reuse.units.kept):,} of "
        f"{len(reuse.units.records):,} (and {reuse.blocks_kept:,} blocks of the others)"
    )
    summary(
        "generalize",
        balance,
        f"footprint vertices {fp['vertices_in']:,} -> {fp['vertices_out']:,}, {dec['decimated']:,} LOD2 meshes "
        f"decimated, {blk['blocks']:,} blocks of {blk['members']:,} buildings" + (kept_note if keep else ""),
        wall,
        n_groups,
    )
    return Result(result, None if since is None else own)
