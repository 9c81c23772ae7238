"""Stage generalize: the coarser bands of the tile hierarchy, each with its error measured.

Runs after the tiles stage, whose quadtree decides which buildings share a coarse tile. Levels and their
tolerances come from one SQL function, gen.tolerance(gen_level) (10 m at level 0, halving per level):

1. footprints (level 2): every building (an outline with its parts) gets its outline simplified at
   gen.tolerance(2) by vertex importance and the Sester–Brenner short-edge rules (etl/geom/simplify.py), with
   vertices on touching neighbours pinned so shared walls stay shared; it is extruded flat to the
   area-weighted height of its parts -> gen.footprint, gen.building_mesh (gen_level 2).
2. decimation (level 3): LOD2 meshes of at least gen_decimate_min_triangles triangles are decimated with
   fast-simplification, all of a batch in one call (etl/geom/decimate.py); a result is kept only when it is
   closed and within gen.tolerance(3) -> gen.building_mesh (gen_level 3; every feature has a row).
3. blocks (levels 1 and 0): in every tile of those bands, the unprotected buildings below it closer than
   gen.tolerance(level) are clustered (ST_ClusterDBSCAN), merged by buffer-union-unbuffer, simplified at the
   same tolerance and extruded flat to the members' area-weighted height -> gen.block with its members.
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

Every generalized object stores error_m, the Hausdorff distance to what it replaces, and total_error_m, a
bound on its distance to the full-detail LOD3 model: its own error plus that of its sources, plus the
LOD2-to-LOD3 step (the openings stand FacadeParams.depth out of the walls, by construction). Simplified
buildings and decimated meshes are measured on the meshes (etl/geom/hausdorff.py, sampled surfaces, exact
point-triangle distances). A block and its members are flat prisms, so their distance is bounded by
sqrt(h² + dz²): h the larger of the outlines' Hausdorff distance (GEOS) and half the merge distance (the
gaps the merge filled are at most that far from a member), dz the largest change of roof height. An omitted
block's error is that of the omission, sqrt(radius² + height²).
"""

from __future__ import annotations

import time

import numpy as np
import psycopg
import shapely

from core.db import connect, working_srid
from core.geodesy import region_box
from core.progress import Progress, summary
from core.settings import Settings
from core.wkb import decode_triangles, encode_triangles_batch

from ..geom.decimate import decimate
from ..geom.extrude import extrude
from ..geom.facade import FacadeParams
from ..geom.hausdorff import hausdorff, outline_hausdorff
from ..geom.simplify import PIN_DISTANCE, simplify_footprints

BATCH = 2000
OPENING_DEPTH = FacadeParams().depth  # LOD3 = LOD2 + openings this far out of the walls

# Buildings (outline + parts, grouped in tiles.building_tile) with the area-weighted height of their LOD2
# meshes, whether LOD3 put openings on them, and the boundaries of touching neighbours.
_GROUPS = """
SELECT o.id, ST_AsBinary(o.geom_local), coalesce(s.height, s.hmax), s.min_height, s.n_in, s.openings,
       ST_AsBinary(nb.fixed)
FROM (
    SELECT bt.group_id,
           sum(m.height * m.ground_area_m2) FILTER (WHERE m.lod = 2)
               / nullif(sum(m.ground_area_m2) FILTER (WHERE m.lod = 2), 0) AS height,
           max(m.height) AS hmax, min(m.min_height) AS min_height,
           sum(m.n_triangles) FILTER (WHERE m.lod = 2) AS n_in,
           bool_or(m.n_windows + m.n_doors > 0) FILTER (WHERE m.lod = 3) AS openings
    FROM tiles.building_tile bt
    JOIN lod.building_mesh m ON m.building_id = bt.building_id AND m.lod IN (2, 3)
    GROUP BY bt.group_id
) s
JOIN osm.building o ON o.id = s.group_id
LEFT JOIN LATERAL (
    SELECT ST_Collect(ST_Boundary(n.geom_local)) AS fixed
    FROM osm.building n
    WHERE n.geom_local && ST_Expand(o.geom_local, %(pin)s) AND n.id <> o.id AND n.parent_id IS NULL
      AND ST_DWithin(n.geom_local, o.geom_local, %(pin)s)
) nb ON true
ORDER BY o.id
"""
_GROUP_LOD2 = """
SELECT bt.group_id, ST_AsBinary(m.geom)
FROM tiles.building_tile bt JOIN lod.building_mesh m ON m.building_id = bt.building_id AND m.lod = 2
WHERE bt.group_id = ANY(%s)
"""
_FEATURES = """
SELECT m.building_id, m.n_triangles, m.min_height, m.height,
       CASE WHEN m.n_triangles >= %(min)s THEN ST_AsBinary(m.geom) END,
       CASE WHEN m.n_triangles >= %(min)s THEN m.semantics END,
       m3.n_windows + m3.n_doors > 0
FROM tiles.building_tile bt
JOIN lod.building_mesh m ON m.building_id = bt.building_id AND m.lod = 2
JOIN lod.building_mesh m3 ON m3.building_id = bt.building_id AND m3.lod = 3
ORDER BY m.building_id
"""
# Per block-band tile: its unprotected buildings clustered at the band's distance and merged (closing with
# mitred joins keeps right angles); a lone building keeps its simplified footprint.
_BLOCKS = """
WITH t AS (
    SELECT level, x, y, gen_level, gen.tolerance(gen_level) AS d FROM tiles.tile WHERE gen_level IN (0, 1)
), m AS (
    SELECT t.level, t.x, t.y, t.gen_level, t.d, f.building_id, f.geom, g.height, g.total_error_m,
           ST_Area(f.geom) AS area
    FROM t
    CROSS JOIN LATERAL (SELECT DISTINCT b.group_id FROM tiles.building_tiles_below(t.level, t.x, t.y) b) bt
    JOIN osm.building o ON o.id = bt.group_id AND NOT o.protected
    JOIN gen.footprint f ON f.building_id = bt.group_id
    JOIN gen.building_mesh g ON g.building_id = bt.group_id AND g.gen_level = 2
), c AS (
    SELECT m.*, ST_ClusterDBSCAN(geom, eps := d, minpoints := 1) OVER (PARTITION BY level, x, y) AS cid FROM m
)
SELECT level, x, y, gen_level, d, members, height, hmax, err,
       ST_AsBinary(CASE WHEN closed IS NULL OR ST_IsEmpty(closed) THEN joined ELSE closed END),
       ST_AsBinary(joined), hmin, n_in
FROM (
    SELECT level, x, y, gen_level, d, cid, count(*) AS n_in, array_agg(building_id ORDER BY building_id) AS members,
           (sum(height * area) / nullif(sum(area), 0))::real AS height, max(height) AS hmax,
           min(height) AS hmin, max(total_error_m) AS err, ST_Multi(ST_Union(geom)) AS joined,
           CASE WHEN count(*) > 1 THEN ST_Multi(ST_CollectionExtract(ST_MakeValid(ST_Buffer(
               ST_Buffer(ST_Collect(geom), d / 2, 'join=mitre mitre_limit=3'),
               -d / 2, 'join=mitre mitre_limit=3')), 3)) END AS closed
    FROM c
    GROUP BY level, x, y, gen_level, d, cid
) a
ORDER BY level, x, y, cid
"""
# Per tile of a coarser band (gen_level < 0, the tiles above height 4): what its children draw in their
# place, i.e. their blocks and, for a child in a finer band, its unprotected buildings' simplified footprints,
# clustered at the band's distance and merged the same way. Built band by band upwards, so the children's
# blocks exist; a block's members are the union of its inputs' members.
_COARSE_BLOCKS = """
WITH t AS (
    SELECT level, x, y, gen_level, gen.tolerance(gen_level) AS d FROM tiles.tile
    WHERE gen_level = %(g)s AND level = %(level)s
), ch AS (
    SELECT t.level, t.x, t.y, t.gen_level, t.d, c.level AS cl, c.x AS cx, c.y AS cy, c.gen_level AS cg
    FROM t JOIN tiles.tile c ON c.level = t.level + 1 AND c.x BETWEEN 2 * t.x AND 2 * t.x + 1
                           AND c.y BETWEEN 2 * t.y AND 2 * t.y + 1
), m AS (
    SELECT ch.level, ch.x, ch.y, ch.gen_level, ch.d, k.members, k.footprint AS geom, k.height::float8 AS height,
           k.total_error_m
    FROM ch JOIN gen.block k ON k.level = ch.cl AND k.x = ch.cx AND k.y = ch.cy
    WHERE ch.cg <= 1
    UNION ALL
    SELECT ch.level, ch.x, ch.y, ch.gen_level, ch.d, ARRAY[f.building_id], f.geom, g.height, g.total_error_m
    FROM ch
    CROSS JOIN LATERAL (SELECT DISTINCT b.group_id FROM tiles.building_tiles_below(ch.cl, ch.cx, ch.cy) b) bt
    JOIN osm.building o ON o.id = bt.group_id AND NOT o.protected
    JOIN gen.footprint f ON f.building_id = bt.group_id
    JOIN gen.building_mesh g ON g.building_id = bt.group_id AND g.gen_level = 2
    WHERE ch.cg > 1
), c AS MATERIALIZED (
    SELECT m.*,
           ST_ClusterDBSCAN(geom, eps := d, minpoints := 1) OVER (PARTITION BY level, x, y) AS cid
    FROM m
), mem AS (
    -- the height is the members' area-weighted height, as in bands 0 and 1, not the inputs' (whose outlines
    -- were simplified and closed)
    SELECT c.level, c.x, c.y, c.cid, array_agg(u ORDER BY u) AS members,
           (sum(g.height * ST_Area(f.geom)) / nullif(sum(ST_Area(f.geom)), 0))::real AS height
    FROM c CROSS JOIN LATERAL unnest(c.members) u
    JOIN gen.footprint f ON f.building_id = u
    JOIN gen.building_mesh g ON g.building_id = u AND g.gen_level = 2
    GROUP BY 1, 2, 3, 4
)
SELECT a.level, a.x, a.y, gen_level, d, mem.members, mem.height, hmax, err,
       ST_AsBinary(CASE WHEN closed IS NULL OR ST_IsEmpty(closed) THEN joined ELSE closed END),
       ST_AsBinary(joined), hmin, n_in
FROM (
    SELECT level, x, y, gen_level, d, cid, count(*) AS n_in, max(height) AS hmax,
           min(height) AS hmin, max(total_error_m) AS err, ST_Multi(ST_Union(geom)) AS joined,
           -- inputs simplified at d / 4 first: the closing's cost grows steeply with vertices and distance
           CASE WHEN count(*) > 1 THEN ST_Multi(ST_CollectionExtract(ST_MakeValid(ST_Buffer(
               ST_Buffer(ST_Collect(ST_SimplifyPreserveTopology(geom, d / 4)), d / 2, 'join=mitre mitre_limit=3'),
               -d / 2, 'join=mitre mitre_limit=3')), 3)) END AS closed
    FROM c
    GROUP BY level, x, y, gen_level, d, cid
) a
JOIN mem ON (mem.level, mem.x, mem.y, mem.cid) = (a.level, a.x, a.y, a.cid)
ORDER BY a.level, a.x, a.y, a.cid
"""
_MESH_COLUMNS = ("building_id", "gen_level", "geom", "semantics", "n_triangles", "n_triangles_in", "min_height",
                 "height", "error_m", "total_error_m", "status")
_MESH_TYPES = ("int8", "int2", "bytea", "bytea", "int4", "int4", "float4", "float4", "float4", "float4", "text")
_FOOTPRINT_COLUMNS = ("building_id", "geom", "tolerance_m", "n_vertices_in", "n_vertices_out", "area_in_m2",
                      "area_out_m2", "error_m", "status")
_BLOCK_COLUMNS = ("level", "x", "y", "gen_level", "members", "n_members", "footprint", "geom", "semantics",
                  "n_triangles", "height", "error_m", "total_error_m", "omitted", "collapse_m")


def _ewkb(geoms: np.ndarray, srid: int) -> list[bytes]:
    return list(shapely.to_wkb(shapely.set_srid(geoms, srid), include_srid=True))


def _triangles(wkbs: list[bytes], owners: list[int]) -> tuple[np.ndarray, np.ndarray]:
    tris = [decode_triangles(w) for w in wkbs]
    counts = [len(t) for t in tris]
    return (np.concatenate(tris) if tris else np.zeros((0, 3, 3)),
            np.repeat(np.asarray(owners, np.int64), counts))


def _solids(footprints: np.ndarray, bottom: np.ndarray, top: np.ndarray) -> tuple[object, np.ndarray]:
    """Extrude; a footprint whose caps cannot be triangulated falls back to its minimum rotated rectangle."""
    ex = extrude(footprints, bottom, top)
    bad = ~ex.ok
    if bad.any():
        fixed = footprints.copy()
        fixed[bad] = [shapely.MultiPolygon([shapely.oriented_envelope(g)]) for g in footprints[bad]]
        ex = extrude(fixed, bottom, top)
    return ex, bad


def _footprints(conn: psycopg.Connection, reader: psycopg.Connection, settings: Settings, srid: int,
                tol: float, progress: Progress) -> dict[str, float]:
    stats = {"buildings": 0, "vertices_in": 0, "vertices_out": 0, "kept_original": 0, "max_error_m": 0.0,
             "triangles_in": 0, "triangles_out": 0}
    with reader.cursor(name="gen_groups") as src, conn.cursor() as cur:
        src.itersize = BATCH
        src.execute(_GROUPS, {"pin": PIN_DISTANCE})
        while rows := src.fetchmany(BATCH):
            ids = np.array([r[0] for r in rows], np.int64)
            geoms = shapely.from_wkb([r[1] for r in rows])
            top = np.array([r[2] for r in rows], float)
            bottom = np.array([r[3] for r in rows], float)
            openings = np.array([bool(r[5]) for r in rows])
            fixed = np.array([shapely.from_wkb(r[6]) if r[6] is not None else None for r in rows], dtype=object)
            s = simplify_footprints(geoms, tol, max_area_change=settings.gen_max_area_change, fixed=fixed)
            ex, rect = _solids(s.geoms, bottom, top)
            n = len(rows)
            # measured against what the band replaces: the LOD2 meshes of the building and its parts
            src_rows = cur.execute(_GROUP_LOD2, (ids.tolist(),)).fetchall()
            index = {int(g): k for k, g in enumerate(ids)}
            b_tri, b_own = _triangles([r[1] for r in src_rows], [index[int(r[0])] for r in src_rows])
            a_own = np.repeat(np.arange(n), ex.counts)
            err = hausdorff(ex.triangles, a_own, b_tri, b_own, n, spacing=tol / 4)
            err = np.nan_to_num(err, nan=0.0)
            total = err + np.where(openings, OPENING_DEPTH, 0.0)
            status = np.where(rect, "footprint not triangulable: minimum rotated rectangle", s.status)
            wkbs = encode_triangles_batch(ex.triangles, ex.offsets, srid)
            sem = ex.semantics.tobytes()
            offs = ex.offsets.tolist()
            with cur.copy(f"COPY gen.footprint ({', '.join(_FOOTPRINT_COLUMNS)}) FROM STDIN") as copy:
                for row in zip(ids.tolist(), [w.hex() for w in _ewkb(s.geoms, srid)], [tol] * n,
                               s.n_vertices_in.tolist(), s.n_vertices_out.tolist(), s.area_in.tolist(),
                               s.area_out.tolist(), s.hausdorff.tolist(), s.status.tolist(), strict=True):
                    copy.write_row(row)
            with cur.copy(f"COPY gen.building_mesh ({', '.join(_MESH_COLUMNS)}) FROM STDIN (FORMAT BINARY)") as copy:
                copy.set_types(list(_MESH_TYPES))
                for j in range(n):
                    copy.write_row((int(ids[j]), 2, wkbs[j], sem[offs[j]:offs[j + 1]], int(ex.counts[j]),
                                    int(rows[j][4] or 0), float(bottom[j]), float(top[j]), float(err[j]),
                                    float(total[j]), str(status[j])))
            stats["buildings"] += n
            stats["vertices_in"] += int(s.n_vertices_in.sum())
            stats["vertices_out"] += int(s.n_vertices_out.sum())
            stats["kept_original"] += int(sum(str(x).startswith("kept_original") for x in s.status))
            stats["max_error_m"] = max(stats["max_error_m"], float(err.max(initial=0.0)))
            stats["triangles_in"] += int(sum(r[4] or 0 for r in rows))
            stats["triangles_out"] += int(ex.counts.sum())
            progress.update(n)
    return stats


def _decimation(conn: psycopg.Connection, reader: psycopg.Connection, settings: Settings, srid: int,
                tol: float) -> dict[str, float]:
    stats = {"features": 0, "decimated": 0, "triangles_in": 0, "triangles_out": 0, "max_error_m": 0.0}
    with reader.cursor(name="gen_features") as src, conn.cursor() as cur:
        src.itersize = BATCH
        src.execute(_FEATURES, {"min": settings.gen_decimate_min_triangles})
        while rows := src.fetchmany(BATCH):
            step = np.array([OPENING_DEPTH if r[6] else 0.0 for r in rows])
            big = [k for k, r in enumerate(rows) if r[4] is not None]
            out: dict[int, tuple[bytes, bytes, int, float, str]] = {}
            if big:
                tri, own = _triangles([rows[k][4] for k in big], list(range(len(big))))
                d = decimate(tri, own, len(big), settings.gen_decimate_reduction,
                             min_triangles=settings.gen_decimate_min_triangles, max_error=tol, spacing=tol / 4)
                counts = np.bincount(d.owner, minlength=len(big))
                offsets = np.concatenate([[0], np.cumsum(counts)])
                wkbs = encode_triangles_batch(d.triangles, offsets, srid)
                for j, k in enumerate(big):
                    if not d.decimated[j]:
                        out[k] = (None, None, 0, 0.0, str(d.status[j]))  # type: ignore[assignment]
                        continue
                    # a decimated surface has no per-triangle semantics of its own: roof where it faces up
                    t = d.triangles[offsets[j]:offsets[j + 1]]
                    nz = np.cross(t[:, 1] - t[:, 0], t[:, 2] - t[:, 0])
                    up = nz[:, 2] > 0.3 * np.linalg.norm(nz, axis=1)
                    down = nz[:, 2] < -0.9 * np.linalg.norm(nz, axis=1)
                    sem = np.where(up, 2, np.where(down, 0, 1)).astype(np.uint8).tobytes()
                    out[k] = (wkbs[j], sem, int(counts[j]), float(d.error[j]), "decimated")
                    stats["decimated"] += 1
                    stats["max_error_m"] = max(stats["max_error_m"], float(d.error[j]))
            with cur.copy(f"COPY gen.building_mesh ({', '.join(_MESH_COLUMNS)}) FROM STDIN (FORMAT BINARY)") as copy:
                copy.set_types(list(_MESH_TYPES))
                for k, r in enumerate(rows):
                    geom, sem, n_out, err, status = out.get(k, (None, None, 0, 0.0, "too small to decimate"))
                    n_out = n_out if geom is not None else int(r[1])
                    copy.write_row((int(r[0]), 3, geom, sem, n_out, int(r[1]), float(r[2]), float(r[3]), err,
                                    err + float(step[k]), status))
                    stats["triangles_in"] += int(r[1])
                    stats["triangles_out"] += n_out
            stats["features"] += len(rows)
    return stats


def _blocks(conn: psycopg.Connection, settings: Settings, srid: int, progress: Progress,
            coarse: tuple[int, int] | None = None) -> dict[str, float]:
    """Blocks of the 10 m and 5 m bands (from the buildings), or of the tiles of coarser band and level
    ``coarse`` = (gen_level < 0, level) (from the children's content, which must be in gen.block already)."""
    stats = {"blocks": 0, "omitted": 0, "members": 0, "max_error_m": 0.0}
    # reads the footprints this transaction wrote, so on the writing connection (another one would wait for
    # the TRUNCATE's lock), a batch at a time between the COPYs
    conn.execute("SET LOCAL cursor_tuple_fraction = 1.0")
    with conn.cursor(name="gen_blocks") as src, conn.cursor() as cur:
        src.itersize = BATCH
        if coarse is None:
            src.execute(_BLOCKS)
        else:
            src.execute(_COARSE_BLOCKS, {"g": coarse[0], "level": coarse[1]})
        while rows := src.fetchmany(BATCH):
            n = len(rows)
            tol = np.array([r[4] for r in rows], float)
            merged = shapely.from_wkb([r[9] for r in rows])
            s = simplify_footprints(merged, tol, max_area_change=settings.gen_max_area_change)
            geoms = np.where(shapely.is_empty(s.geoms), merged, s.geoms)
            top = np.array([r[6] if r[6] is not None else r[7] for r in rows], float)
            ex, _ = _solids(geoms, np.zeros(n), top)
            members = [list(r[5]) for r in rows]
            # prisms against prisms: the outlines' Hausdorff distance, the gaps the merge filled (at most half
            # the distance) and the largest roof height change bound the distance between the solids
            joined = shapely.from_wkb([r[10] for r in rows])
            hmax = np.array([r[7] for r in rows], float)
            outline = outline_hausdorff(geoms, joined, tol / 4)
            gap = np.where(np.array([r[12] for r in rows]) > 1, tol / 2, 0.0)  # only merges fill gaps
            dz = np.maximum(hmax - top, top - np.array([r[11] for r in rows], float))
            err = np.hypot(np.maximum(outline, gap), np.maximum(dz, 0.0))
            # selection: a block that fits within the band's tolerance of one point (the centre of its members'
            # bounding circle, at ground level) is omitted from its tile; that collapse is then its error
            collapse = np.hypot(shapely.minimum_bounding_radius(joined), hmax)
            omitted = collapse <= tol
            err = np.where(omitted, collapse, err)
            total = err + np.array([float(r[8]) for r in rows])
            wkbs = encode_triangles_batch(ex.triangles, ex.offsets, srid)
            fps = _ewkb(geoms, srid)
            sem = ex.semantics.tobytes()
            offs = ex.offsets.tolist()
            with cur.copy(f"COPY gen.block ({', '.join(_BLOCK_COLUMNS)}) FROM STDIN") as copy:
                for j, r in enumerate(rows):
                    copy.write_row((r[0], r[1], r[2], r[3], members[j], len(members[j]), fps[j].hex(),
                                    wkbs[j].hex(), sem[offs[j]:offs[j + 1]], int(ex.counts[j]), float(top[j]),
                                    float(err[j]), float(total[j]), bool(omitted[j]), float(collapse[j])))
            stats["blocks"] += n
            stats["omitted"] += int(omitted.sum())
            stats["members"] += sum(len(m) for m in members)
            stats["max_error_m"] = max(stats["max_error_m"], float(err.max(initial=0.0)))
            progress.update(n)
    return stats


def coarse_blocks(conn: psycopg.Connection, settings: Settings, srid: int, max_level: int | None = None
                  ) -> dict[str, float]:
    """The coarser bands (gen_level < 0; only tiles at levels <= ``max_level`` if given), finest band and
    deepest level first: each tile is built from its children's content (the top tiles share band -4, so a
    band runs level by level). Returns the blocks and the omitted ones of each band ({"coarse_blocks": {g: n},
    "coarse_omitted": {g: n}})."""
    pairs = [(int(g), int(lv)) for g, lv in conn.execute(
        """SELECT DISTINCT gen_level, level FROM tiles.tile WHERE gen_level < 0 AND level <= %s
           ORDER BY 1 DESC, 2 DESC""", (1 << 15 if max_level is None else max_level,))]
    out: dict[int, int] = {}
    omitted: dict[int, int] = {}
    for g, lv in pairs:
        conn.execute("ANALYZE gen.block")  # the level below was just written (see run)
        st = _blocks(conn, settings, srid, Progress("generalize", f"blocks {g} (level {lv})"), (g, lv))
        out[g] = out.get(g, 0) + int(st["blocks"])
        omitted[g] = omitted.get(g, 0) + int(st["omitted"])
    return {"coarse_blocks": out, "coarse_omitted": omitted}  # type: ignore[dict-item]


def store_boxes(cur: psycopg.Cursor) -> None:
    """tiles.tile.box from each tile's region (region_box), all tiles in one COPY and one UPDATE; inside the
    caller's transaction."""
    keys = cur.execute("SELECT level, x, y, region FROM tiles.tile ORDER BY level, x, y").fetchall()
    boxes = region_box(np.array([k[3] for k in keys], float))
    cur.execute("CREATE TEMP TABLE _box (level smallint, x integer, y integer, box float8[]) ON COMMIT DROP")
    with cur.copy("COPY _box (level, x, y, box) FROM STDIN") as copy:
        for k, b in zip(keys, boxes.tolist(), strict=True):
            copy.write_row((k[0], k[1], k[2], b))
    cur.execute("UPDATE tiles.tile t SET box = b.box FROM _box b WHERE (t.level, t.x, t.y) = (b.level, b.x, b.y)")


def run(conn: psycopg.Connection, url: str, settings: Settings) -> dict[str, object]:
    t0 = time.perf_counter()
    srid = working_srid(conn)
    if not conn.execute("SELECT EXISTS (SELECT 1 FROM tiles.tile)").fetchone()[0]:  # type: ignore[index]
        raise RuntimeError("no tiles: run the tiles stage first (make tiles)")
    tol = {g: float(conn.execute("SELECT gen.tolerance(%s)", (g,)).fetchone()[0]) for g in range(5)}  # type: ignore[index]
    seconds: dict[str, float] = {}
    n_groups = conn.execute("SELECT count(DISTINCT group_id) FROM tiles.building_tile").fetchone()[0]  # type: ignore[index]
    with connect(url) as reader, conn.transaction(), conn.cursor() as cur:
        # the inputs are read whole: plan for all rows, not the fast-start plans cursors get by default
        reader.execute("SET cursor_tuple_fraction = 1.0")
        cur.execute("TRUNCATE gen.block, gen.building_mesh, gen.footprint")
        step = time.perf_counter()
        fp = _footprints(conn, reader, settings, srid, tol[2], Progress("generalize", "buildings", total=n_groups))
        seconds["footprints"] = time.perf_counter() - step
        step = time.perf_counter()
        dec = _decimation(conn, reader, settings, srid, tol[3])
        seconds["decimation"] = time.perf_counter() - step
        step = time.perf_counter()
        # the blocks join the footprints and meshes just written: without statistics the planner takes the
        # TRUNCATEd tables for empty and scans them once per member (minutes at 100k buildings)
        cur.execute("ANALYZE gen.footprint")
        cur.execute("ANALYZE gen.building_mesh")
        blk = _blocks(conn, settings, srid, Progress("generalize", "blocks"))
        blk.update(coarse_blocks(conn, settings, srid))
        seconds["blocks"] = time.perf_counter() - step
        step = time.perf_counter()
        cur.execute("CALL tiles.finish_hierarchy(%s)", (settings.base_height_m,))
        blk["omitted_within_tile_error"] = cur.execute("CALL tiles.omit_within_error(NULL, NULL)").fetchone()[0]
        store_boxes(cur)
        seconds["hierarchy"] = time.perf_counter() - step
        bands = cur.execute(
            """SELECT gen_level, count(*), sum(content_features), sum(content_triangles), max(geometric_error)
               FROM tiles.tile GROUP BY gen_level ORDER BY gen_level"""
        ).fetchall()
        cur.execute("ANALYZE gen.footprint")
        cur.execute("ANALYZE gen.building_mesh")
        cur.execute("ANALYZE gen.block")
    wall = time.perf_counter() - t0
    result: dict[str, object] = {
        "buildings": n_groups, "tolerance_m": tol,
        "footprints": fp, "decimation": dec, "blocks": blk,
        "bands": [{"gen_level": b[0], "tiles": b[1], "features": int(b[2]), "triangles": int(b[3]),
                   "max_geometric_error_m": round(float(b[4]), 3)} for b in bands],
        "seconds": round(wall, 3), "seconds_by_step": {k: round(v, 3) for k, v in seconds.items()},
    }
    summary(
        "generalize",
        f"{n_groups:,} buildings: footprint vertices {fp['vertices_in']:,} -> {fp['vertices_out']:,}, "
        f"{dec['decimated']:,} LOD2 meshes decimated, {blk['blocks']:,} blocks of {blk['members']:,} buildings",
        wall,
        n_groups,
    )
    return result
