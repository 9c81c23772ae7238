"""``python -m benchmarks.view_bench``: what api.lod_for_view costs and saves (issue 4), on real data.

Three measurements, each usable alone (``--help`` of each subcommand) and called by ``make bench``
(benchmarks/bench.py):

``triangles`` — triangles per view. The sum of ``n_triangles`` over the features api.lod_for_view returns for
    an *overview* camera (over the centre of the data, looking straight down, at the height where the whole
    extract fills a 60° / 1080 px / 16:9 view, max_sse 16) against the LOD3 triangles of every building (what a
    client without the hierarchy would draw). A *street* camera (80 m up, 150 m south of the median building of
    the densest leaf tile, looking north, pitch -20°) is reported for context. lod_for_view returns every feature
    of each tile it stops at, so the sum is taken
    over api.buildings_for_tile of the distinct tiles it returns (the same features, counted once), with
    ``cull_features => false``: a client draws whole tiles, their features outside the frustum too.

``latency`` — api.lod_for_view p50/p95/max on a database. A fixed, seeded set of navigation cameras (default
    200, seed 4): the position is uniform inside a leaf tile drawn with probability proportional to its
    features (people look where the buildings are), height above the data's base log-uniform in 50–3000 m,
    heading uniform, pitch uniform in [-90°, -15°], fov 60°, 1080 px, 16:9, max_sse 16. Each call is
    ``SELECT feature_kind, feature_id, lod, level, x, y FROM api.lod_for_view(...)`` as a server-side prepared
    statement on one warm connection (Unix socket), timed as *client wall time* of execute + fetch all rows,
    i.e. planning + execution + transferring the result, after one untimed warm-up pass over every camera. For
    the p95 and the slowest camera EXPLAIN (ANALYZE, TIMING OFF) splits that into planning and execution. A
    call over the timeout (30 s) is cancelled and counted at the timeout, so a percentile equal to it means
    "at least".

``scale`` — the latency at ~100k and ~1M buildings, on two bench-only databases built from one extract
    (Liechtenstein, 17.8k buildings) and cached between runs:

    * ``citylod_view_100k`` (6 copies, ~107k buildings) is built *for real*: ingest, then osm.building is
      replicated 5 times side by side on a 3 × 2 grid in the working CRS (ids and osm_ids offset by
      k·10¹⁰, geom_local translated with ST_Translate and geom re-derived from it with ST_Transform), then the
      lod, tiles and generalize stages run on it as ``make`` runs them (about 5 minutes).
    * ``citylod_view_1m`` (10 copies of that, ~1.07M buildings) is replicated *at the tile level*, because
      generalize at ~450 buildings/s would take 40 minutes: a copy of the 100k database (CREATE DATABASE …
      TEMPLATE) whose tile tree becomes copy 0 of 10 placed on a 4 × 4 grid of its root cell, every level
      moved down by 2 (tile (l, x, y) of copy (i, j) -> (l + 2, x + i·2ˡ, y + j·2ˡ), so the quadtree arithmetic
      of api.buildings_for_tile holds exactly). Copied with ids offset by k·10¹²: osm.building,
      lod.building_mesh (LOD2 and LOD3, the ones the API reads), gen.building_mesh, gen.footprint,
      tiles.building_tile, tiles.tile and gen.block, every geometry translated (cells, anchors, outlines,
      meshes, blocks); regions are the translated regions reprojected, boxes recomputed with
      core.geodesy.region_box. The 2 new upper levels (5 tiles) are built as the pipeline builds them:
      their band from height and width (gen.level_for_height), their blocks merged from their children's by
      the generalize stage's own code (generalize.coarse_blocks), their content listed in tiles.tile_content
      through api.buildings_for_tile, the geometric error the larger of their content's and their children's
      (tiles.finish_hierarchy's rule), regions the union of their children's.

    Each database carries a marker row (bench.build) with a hash of its inputs: the extract, the copies, the
    CITYLOD_* settings and the code that builds it (etl/, sql/, migrations/ and this file). When the marker
    matches, the database is reused; ``--rebuild`` forces it. Together they take ~13 GB of disk (1.3 GB + 12 GB).

Timings are wall clock on a shared machine; tests never assert them.
"""

from __future__ import annotations

import argparse
import contextlib
import hashlib
import inspect
import json
import math
import os
import random
import statistics
import sys
import time
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import psycopg
from psycopg import sql

from benchmarks.common import HEADLINE, LOG_DIR, SHARED_OSM, recreate_db, run_child
from core import cluster
from core.camera import Camera
from core.settings import REPO, Settings
from etl.generalize import stage as generalize
from etl.generalize.stage import store_boxes

MAX_SSE = 16.0
SEED = 4
N_CAMERAS = 200
TIMEOUT_S = 30.0  # a call slower than this is cancelled and counted at this value
HEIGHTS = (50.0, 3000.0)
PITCHES = (-90.0, -15.0)
EARTH_R = 6_371_008.8

DB_100K = "citylod_view_100k"
DB_1M = "citylod_view_1m"
COPIES_100K = 6  # 3 × 2 copies of the extract, built for real
COPIES_1M = 10  # tile-level copies of the 100k database on a 4 × 4 grid
OFF_100K = 10**10  # id offset per copy at the first step
OFF_1M = 10**12  # ... and at the second
GAP_M = 500.0  # between the side-by-side copies of the 100k step

_VIEW = """SELECT feature_kind, feature_id, lod, level, x, y
FROM api.lod_for_view(ST_SetSRID(ST_MakePoint(%s, %s, %s), 4326), %s, %s, %s, %s, %s, %s)"""
# what a client loads and draws: whole tiles, their features outside the frustum included
_VIEW_TILES = _VIEW.removesuffix(")") + ", cull_features => false)"


def log(msg: str) -> None:
    print(f"[view_bench {time.strftime('%H:%M:%S')}] {msg}", file=sys.stderr, flush=True)


def _params(cam: Camera, max_sse: float = MAX_SSE) -> tuple[Any, ...]:
    return (cam.lon, cam.lat, cam.height, cam.heading, cam.pitch, cam.fov, cam.viewport_height, max_sse, cam.aspect)


def _cam_dict(cam: Camera) -> dict[str, float]:
    return {
        "lon": round(cam.lon, 6),
        "lat": round(cam.lat, 6),
        "height": round(cam.height, 1),
        "heading": round(cam.heading, 1),
        "pitch": round(cam.pitch, 1),
        "fov": cam.fov,
        "viewport_height": cam.viewport_height,
    }


# --- cameras ------------------------------------------------------------------------------------------------


def overview_camera(
    conn: psycopg.Connection,
    pitch: float = -90.0,
    fov: float = 60.0,
    viewport_height: int = 1080,
    aspect: float = 16 / 9,
) -> Camera:
    """Over the centre of the root tile's region, north up, at the height where the region fills the view
    (its north-south extent the vertical field of view or its east-west extent the horizontal one)."""
    w, s, e, n, _lo, hi = conn.execute("SELECT region FROM tiles.tile WHERE level = 0").fetchone()[0]  # type: ignore[index]
    lat = (s + n) / 2
    ns_m, ew_m = (n - s) * EARTH_R, (e - w) * EARTH_R * math.cos(lat)
    tv = math.radians(fov) / 2
    th = math.atan(aspect * math.tan(tv))
    height = hi + max(ns_m / (2 * math.tan(tv)), ew_m / (2 * math.tan(th)))
    return Camera(math.degrees((w + e) / 2), math.degrees(lat), height, 0.0, pitch, fov, viewport_height, aspect)


STREET_HEIGHT_M, STREET_BACK_M, STREET_PITCH = 80.0, 150.0, -20.0


def street_camera(conn: psycopg.Connection) -> Camera:
    """A view into the densest streets: 80 m above the lowest point of the leaf tile with the most features,
    150 m south of the median position of its buildings (the median longitude and latitude of their
    centroids), looking north, 20° down. (The centre of that tile can be a field: a camera there saw few
    buildings.)"""
    w, s, e, n, lo, _hi = conn.execute(
        "SELECT region FROM tiles.tile WHERE is_leaf ORDER BY n_features DESC, level, x, y LIMIT 1"
    ).fetchone()[0]  # type: ignore[index]
    lon, lat = conn.execute(
        "SELECT percentile_disc(0.5) WITHIN GROUP (ORDER BY ST_X(c)),"
        "       percentile_disc(0.5) WITHIN GROUP (ORDER BY ST_Y(c))"
        " FROM (SELECT ST_Centroid(geom) AS c FROM osm.building"
        "       WHERE geom && ST_MakeEnvelope(%s, %s, %s, %s, 4326)) b",
        [math.degrees(v) for v in (w, s, e, n)],
    ).fetchone()  # type: ignore[misc]
    if lon is None:
        lon, lat = math.degrees((w + e) / 2), math.degrees((s + n) / 2)
    lat -= math.degrees(STREET_BACK_M / EARTH_R)
    return Camera(lon, lat, lo + STREET_HEIGHT_M, 0.0, STREET_PITCH)


def navigation_cameras(conn: psycopg.Connection, n: int = N_CAMERAS, seed: int = SEED) -> list[Camera]:
    """``n`` seeded navigation cameras over the data (see the module docstring)."""
    leaves = conn.execute("SELECT region, n_features FROM tiles.tile WHERE is_leaf ORDER BY level, x, y").fetchall()
    rng = random.Random(seed)
    weights = [float(f) for _, f in leaves]
    cams = []
    for _ in range(n):
        (w, s, e, nn, lo, _hi), _f = rng.choices(leaves, weights=weights)[0]
        lon, lat = rng.uniform(w, e), rng.uniform(s, nn)
        h = math.exp(rng.uniform(math.log(HEIGHTS[0]), math.log(HEIGHTS[1])))
        cams.append(Camera(math.degrees(lon), math.degrees(lat), lo + h, rng.uniform(0, 360), rng.uniform(*PITCHES)))
    return cams


# --- triangles per view -------------------------------------------------------------------------------------


def view_triangles(conn: psycopg.Connection, cam: Camera, max_sse: float = MAX_SSE) -> dict[str, Any]:
    """Tiles, features and triangles api.lod_for_view draws for ``cam``, with the split by LOD."""
    rows = conn.execute(
        f"""WITH v AS (SELECT DISTINCT level, x, y FROM ({_VIEW_TILES}) q)
            SELECT f.lod, count(DISTINCT (v.level, v.x, v.y)), count(*), sum(f.n_triangles)
            FROM v CROSS JOIN LATERAL api.buildings_for_tile(v.level, v.x, v.y) f GROUP BY f.lod ORDER BY 1""",
        _params(cam, max_sse),
    ).fetchall()
    n_rows = conn.execute(
        f"SELECT count(*), count(DISTINCT (level, x, y)) FROM ({_VIEW_TILES}) q", _params(cam, max_sse)
    ).fetchone()
    out = {
        "camera": _cam_dict(cam),
        "tiles": int(n_rows[1]) if n_rows else 0,
        "features": sum(int(r[2]) for r in rows),
        "triangles": sum(int(r[3] or 0) for r in rows),
        "by_lod": {int(r[0]): {"features": int(r[2]), "triangles": int(r[3] or 0)} for r in rows},
    }
    if n_rows and int(n_rows[0]) != out["features"]:
        raise RuntimeError(f"lod_for_view returned {n_rows[0]} features, its tiles hold {out['features']}")
    return out


def triangles_per_view(url: str, max_sse: float = MAX_SSE) -> dict[str, Any]:
    """Overview and street cameras against all buildings at LOD3 (the issue-4 target: overview ≥ 5× fewer)."""
    with psycopg.connect(url, autocommit=True) as conn:
        lod3_f, lod3_t = conn.execute(
            "SELECT count(*), coalesce(sum(n_triangles), 0) FROM lod.building_mesh WHERE lod = 3"
        ).fetchone()  # type: ignore[misc]
        over = view_triangles(conn, overview_camera(conn), max_sse)
        street = view_triangles(conn, street_camera(conn), max_sse)
    ratio = lod3_t / over["triangles"] if over["triangles"] else float("inf")
    return {
        "all_lod3": {"features": int(lod3_f), "triangles": int(lod3_t)},
        "overview": over,
        "street": street,
        "overview_reduction": round(ratio, 2),
        "target_reduction": 5.0,
        "pass": ratio >= 5.0,
        "max_sse": max_sse,
    }


# --- latency ------------------------------------------------------------------------------------------------


def _pct(sorted_vals: Sequence[float], q: float) -> float:
    return sorted_vals[min(len(sorted_vals) - 1, max(0, math.ceil(q * len(sorted_vals)) - 1))]


def _explain(conn: psycopg.Connection, cam: Camera) -> dict[str, Any]:
    plan = conn.execute(f"EXPLAIN (ANALYZE, TIMING OFF, FORMAT JSON) {_VIEW}", _params(cam)).fetchone()[0]  # type: ignore[index]
    top = plan[0] if isinstance(plan, list) else json.loads(plan)[0]
    return {
        "planning_ms": round(top["Planning Time"], 2),
        "execution_ms": round(top["Execution Time"], 2),
        "rows": top["Plan"].get("Actual Rows"),
    }


def measure_latency(
    url: str, n: int = N_CAMERAS, seed: int = SEED, warmup: int | None = None, timeout_s: float = TIMEOUT_S
) -> dict[str, Any]:
    """p50/p95/max client wall time (ms) of api.lod_for_view over the seeded navigation cameras, the mean
    features returned, and EXPLAIN's planning/execution split for the p95 and the slowest camera. ``warmup``
    cameras (default all) are called once untimed first. A call over ``timeout_s`` is cancelled
    (statement_timeout) and counts as ``timeout_s`` in the percentiles; ``timeouts`` says how many."""
    with psycopg.connect(url, autocommit=True) as conn:
        conn.execute("SELECT set_config('statement_timeout', %s, false)", (str(int(timeout_s * 1000)),))
        buildings = int(conn.execute("SELECT count(*) FROM tiles.building_tile").fetchone()[0])  # type: ignore[index]
        tiles = int(conn.execute("SELECT count(*) FROM tiles.tile").fetchone()[0])  # type: ignore[index]
        cams = navigation_cameras(conn, n, seed)
        t_warm = time.perf_counter()
        for cam in cams[: len(cams) if warmup is None else warmup]:
            with contextlib.suppress(psycopg.errors.QueryCanceled):
                conn.execute(_VIEW, _params(cam), prepare=True).fetchall()
        t_warm = time.perf_counter() - t_warm
        ms: list[float] = []
        feats: list[int | None] = []  # None: cancelled at the time limit
        for cam in cams:
            t0 = time.perf_counter()
            try:
                n_rows: int | None = len(conn.execute(_VIEW, _params(cam), prepare=True).fetchall())
            except psycopg.errors.QueryCanceled:
                n_rows = None
            ms.append((time.perf_counter() - t0) * 1e3)
            feats.append(n_rows)
        conn.execute("SET statement_timeout = 0")
        order = sorted(range(len(ms)), key=ms.__getitem__)
        worst = cams[order[-1]]
        p95cam = cams[order[min(len(order) - 1, max(0, math.ceil(0.95 * len(order)) - 1))]]
        prof = {
            "slowest": {**_explain(conn, worst), "camera": _cam_dict(worst), "features": feats[order[-1]]},
            "p95": {**_explain(conn, p95cam), "camera": _cam_dict(p95cam)},
        }
    s = sorted(ms)
    done = [f for f in feats if f is not None]
    timeouts = len(feats) - len(done)
    return {
        "buildings": buildings,
        "tiles": tiles,
        "cameras": len(cams),
        "seed": seed,
        "p50_ms": round(_pct(s, 0.5), 2),
        "p95_ms": round(_pct(s, 0.95), 2),
        "max_ms": round(s[-1], 2),
        "mean_ms": round(statistics.fmean(s), 2),
        "mean_features": round(statistics.fmean(done), 1) if done else None,  # over the completed calls
        "max_features": max(done, default=None),
        "warmup_s": round(t_warm, 1),
        "profile": prof,
        "timeouts": timeouts,
        "timeout_s": timeout_s,
        "warmup_cameras": len(cams) if warmup is None else warmup,
        "target_p95_ms": 10.0,
        "pass": _pct(s, 0.95) <= 10.0,
    }


# --- the scaled databases -----------------------------------------------------------------------------------


def _code_hash(builders: Sequence[Any]) -> str:
    """The pipeline's code (etl/, sql/, migrations/) and the source of the functions that build the database."""
    h = hashlib.sha256()
    files = sorted(
        [*(REPO / "etl").rglob("*.py"), *(REPO / "sql").rglob("*.sql"), *(REPO / "migrations").glob("*.sql")]
    )
    for f in files:
        h.update(str(f.relative_to(REPO)).encode())
        h.update(f.read_bytes())
    for fn in builders:
        h.update(inspect.getsource(fn).encode())
    return h.hexdigest()


def _file_hash(path: Path) -> str:
    h = hashlib.sha256()
    with path.open("rb") as fh:
        while chunk := fh.read(1 << 20):
            h.update(chunk)
    return h.hexdigest()


def _inputs(osm: Path, step: str) -> dict[str, Any]:
    builders = (
        [build_100k] if step == "100k" else [build_100k, build_1m, _stack_levels, _copy_sql, _grid_table, _columns]
    )
    return {
        "step": step,
        "osm": osm.name,
        "osm_sha256": _file_hash(osm),
        "copies_100k": COPIES_100K,
        "copies_1m": COPIES_1M,
        "offsets": [OFF_100K, OFF_1M, GAP_M],
        "code": _code_hash(builders),
        "settings": {k: v for k, v in sorted(os.environ.items()) if k.startswith("CITYLOD_")},
    }


def _marker_ok(url: str, inputs: dict[str, Any]) -> bool:
    try:
        with psycopg.connect(url) as conn:
            row = conn.execute("SELECT inputs FROM bench.build ORDER BY built_at DESC LIMIT 1").fetchone()
    except psycopg.Error:
        return False
    return row is not None and row[0] == inputs


def _write_marker(url: str, inputs: dict[str, Any], seconds: float) -> None:
    with psycopg.connect(url, autocommit=True) as conn:
        conn.execute("CREATE SCHEMA IF NOT EXISTS bench")
        conn.execute(
            "CREATE TABLE IF NOT EXISTS bench.build (built_at timestamptz DEFAULT now(), inputs jsonb,"
            " seconds double precision)"
        )
        conn.execute("DELETE FROM bench.build")
        conn.execute(
            "INSERT INTO bench.build (inputs, seconds) VALUES (%s, %s)", (json.dumps(inputs), round(seconds, 1))
        )


def _columns(conn: psycopg.Connection, table: str) -> list[str]:
    schema, name = table.split(".")
    return [
        r[0]
        for r in conn.execute(
            """SELECT column_name FROM information_schema.columns WHERE table_schema = %s AND table_name = %s
           ORDER BY ordinal_position""",
            (schema, name),
        )
    ]


def _copy_sql(
    conn: psycopg.Connection,
    table: str,
    src: str,
    exprs: dict[str, str],
    grid: str,
    where: str = "true",
    overriding: bool = False,
    order: str = "",
    lateral: str = "",
) -> sql.Composed:
    """INSERT INTO table SELECT <every column, or its expression> FROM src CROSS JOIN (grid) g
    [CROSS JOIN LATERAL (lateral) m] WHERE ... [ORDER BY order]; the expressions may use the grid's k (copy),
    dx, dy (metres), i, j (cell), and m's columns (a value several columns share, computed once a row)."""
    cols = _columns(conn, table)
    select = [sql.SQL(exprs[c]) if c in exprs else sql.SQL("s.") + sql.Identifier(c) for c in cols]
    return sql.SQL("INSERT INTO {} ({}) {} SELECT {} FROM {} s CROSS JOIN ({}) g {} WHERE {} {}").format(
        sql.SQL(table),
        sql.SQL(", ").join(map(sql.Identifier, cols)),
        sql.SQL("OVERRIDING SYSTEM VALUE" if overriding else ""),
        sql.SQL(", ").join(select),
        sql.SQL(src),
        sql.SQL(grid),
        sql.SQL(f"CROSS JOIN LATERAL ({lateral}) m" if lateral else ""),
        sql.SQL(where),
        sql.SQL("ORDER BY " + order if order else ""),
    )


def _grid_table(
    conn: psycopg.Connection,
    name: str,
    cells: Sequence[tuple[int, int, int, float, float]],
    off: int,
    up: int = 0,
    srid: int = 0,
) -> str:
    """A temp table ``name`` (k copy, i, j cell, dx, dy metres, off = k × ``off`` id offset, up levels added,
    srid), filled with bind parameters; returns the SELECT the copy statements join as ``g``."""
    conn.execute(
        sql.SQL(
            "CREATE TEMP TABLE {} (k int, i int, j int, dx float8, dy float8, off bigint, up int, srid int)"
        ).format(sql.Identifier(name))
    )
    with conn.cursor() as cur:
        cur.executemany(
            sql.SQL("INSERT INTO {} VALUES (%s, %s, %s, %s, %s, %s, %s, %s)").format(sql.Identifier(name)),
            [(k, i, j, dx, dy, k * off, up, srid) for k, i, j, dx, dy in cells],
        )
    return f"SELECT * FROM {name}"


def build_100k(admin_url: str, osm: Path, rebuild: bool = False) -> str:
    """``citylod_view_100k``: the extract ×6 side by side, through lod, tiles and generalize for real."""
    url = cluster.database_url(DB_100K)
    inputs = _inputs(osm, "100k")
    if not rebuild and _marker_ok(url, inputs):
        log(f"{DB_100K}: up to date (bench.build marker), reused")
        return url
    t0 = time.perf_counter()
    env = {**os.environ, "DATABASE_URL": url}
    logs = LOG_DIR / DB_100K
    log(f"{DB_100K}: building (ingest, ×{COPIES_100K}, lod, tiles, generalize: ~5 min)")
    recreate_db(admin_url, DB_100K)
    run_child([sys.executable, "-m", "etl", "migrate"], env, logs / "migrate.log")
    run_child([sys.executable, "-m", "etl", "ingest", "--osm", str(osm)], env, logs / "ingest.log")
    with psycopg.connect(url, autocommit=True) as conn:
        x0, y0, x1, y1 = conn.execute(
            """SELECT ST_XMin(e), ST_YMin(e), ST_XMax(e), ST_YMax(e)
               FROM (SELECT ST_Extent(geom_local) e FROM osm.building) s"""
        ).fetchone()  # type: ignore[misc]
        cols = 3
        cells = [
            (k, k % cols, k // cols, (k % cols) * (x1 - x0 + GAP_M), (k // cols) * (y1 - y0 + GAP_M))
            for k in range(1, COPIES_100K)
        ]
        moved = "ST_Translate(s.geom_local, g.dx, g.dy)"
        conn.execute(
            _copy_sql(
                conn,
                "osm.building",
                "osm.building",
                {
                    "id": "s.id + g.off",
                    "osm_id": "s.osm_id + g.off",
                    "parent_id": "s.parent_id + g.off",
                    "geom_local": moved,
                    "geom": f"ST_Transform({moved}, 4326)",
                },
                _grid_table(conn, "_grid", cells, OFF_100K),
            )
        )
        conn.execute("ANALYZE osm.building")
        n = conn.execute("SELECT count(*) FROM osm.building").fetchone()[0]  # type: ignore[index]
    log(f"{DB_100K}: {n:,} buildings and parts; lod, tiles, generalize")
    for stage in ("lod", "tiles", "generalize"):
        t = time.perf_counter()
        run_child([sys.executable, "-m", "etl", stage], env, logs / f"{stage}.log")
        log(f"{DB_100K}: {stage} {time.perf_counter() - t:.0f} s")
    _write_marker(url, inputs, time.perf_counter() - t0)
    log(f"{DB_100K}: built in {time.perf_counter() - t0:.0f} s")
    return url


def build_1m(admin_url: str, osm: Path, rebuild: bool = False) -> str:
    """``citylod_view_1m``: 10 tile-level copies of ``citylod_view_100k`` under 2 new levels (module docstring)."""
    url = cluster.database_url(DB_1M)
    inputs = _inputs(osm, "1m")
    with psycopg.connect(cluster.database_url(DB_100K)) as conn:  # rebuilt with it whenever the 100k one is
        inputs["from_100k_built_at"] = str(conn.execute("SELECT max(built_at) FROM bench.build").fetchone()[0])  # type: ignore[index]
    if not rebuild and _marker_ok(url, inputs):
        log(f"{DB_1M}: up to date (bench.build marker), reused")
        return url
    t0 = time.perf_counter()
    log(f"{DB_1M}: building from {DB_100K} (×{COPIES_1M} at the tile level)")
    with psycopg.connect(admin_url, autocommit=True) as conn:
        conn.execute(sql.SQL("DROP DATABASE IF EXISTS {} WITH (FORCE)").format(sql.Identifier(DB_1M)))
        conn.execute(
            sql.SQL("SELECT pg_terminate_backend(pid) FROM pg_stat_activity WHERE datname = {}").format(
                sql.Literal(DB_100K)
            )
        )
        conn.execute(sql.SQL("CREATE DATABASE {} TEMPLATE {}").format(sql.Identifier(DB_1M), sql.Identifier(DB_100K)))
    side = math.ceil(math.sqrt(COPIES_1M))
    up = math.ceil(math.log2(side))  # new levels above the copies' roots
    with psycopg.connect(url, autocommit=True) as conn:
        conn.execute("DELETE FROM bench.build")
        srid, size = conn.execute("SELECT srid, size FROM tiles.grid").fetchone()  # type: ignore[misc]
        cells = [(k, k % side, k // side, (k % side) * size, (k // side) * size) for k in range(COPIES_1M)]
        grid_all = _grid_table(conn, "_grid_all", cells, OFF_1M, up, int(srid))
        grid_new = _grid_table(conn, "_grid_new", cells[1:], OFF_1M, up, int(srid))
        off = "g.off"

        def step(what: str, q: sql.Composable | str) -> None:
            t = time.perf_counter()
            conn.execute(q)
            log(f"{DB_1M}: {what} {time.perf_counter() - t:.0f} s")

        # the rows of the building tables: copies 1..K-1 next to the original (copy 0 stays where it is)
        step(
            "osm.building",
            _copy_sql(
                conn,
                "osm.building",
                "osm.building",
                {
                    "id": f"s.id + {off}",
                    "osm_id": f"s.osm_id + {off}",
                    "parent_id": f"s.parent_id + {off}",
                    "geom_local": "ST_Translate(s.geom_local, g.dx, g.dy)",
                    "geom": "ST_Transform(ST_Translate(s.geom_local, g.dx, g.dy), 4326)",
                },
                grid_new,
            ),
        )
        step(
            "lod.building_mesh",
            _copy_sql(
                conn,
                "lod.building_mesh",
                "lod.building_mesh",
                {"building_id": f"s.building_id + {off}", "geom": "ST_Translate(s.geom, g.dx, g.dy, 0)"},
                grid_new,
                where="s.lod IN (2, 3)",
            ),
        )
        step(
            "gen.building_mesh",
            _copy_sql(
                conn,
                "gen.building_mesh",
                "gen.building_mesh",
                {"building_id": f"s.building_id + {off}", "geom": "ST_Translate(s.geom, g.dx, g.dy, 0)"},
                grid_new,
            ),
        )
        step(
            "gen.footprint",
            _copy_sql(
                conn,
                "gen.footprint",
                "gen.footprint",
                {"building_id": f"s.building_id + {off}", "geom": "ST_Translate(s.geom, g.dx, g.dy)"},
                grid_new,
            ),
        )
        # the tile tree: every copy (0 included) moved down `up` levels into its cell
        for t in ("tiles.tile", "tiles.building_tile", "gen.block", "tiles.tile_content"):
            conn.execute(
                sql.SQL("CREATE TEMP TABLE {} AS SELECT * FROM {}").format(
                    sql.Identifier("src_" + t.split(".")[1]), sql.Identifier(*t.split("."))
                )
            )
        conn.execute("TRUNCATE tiles.tile CASCADE")  # and tiles.building_tile, gen.block, tiles.tile_content
        shift = {"level": "s.level + g.up", "x": "s.x + (g.i << s.level)", "y": "s.y + (g.j << s.level)"}
        step(
            "tiles.tile",
            _copy_sql(
                conn,
                "tiles.tile",
                "src_tile",
                {
                    **shift,
                    "cell": "ST_Translate(s.cell, g.dx, g.dy)",
                    "content_uri": "format('content/%s/%s/%s.glb', s.level + g.up, s.x + (g.i << s.level), "
                    "s.y + (g.j << s.level))",
                    "region": """(SELECT ARRAY[radians(ST_XMin(e)), radians(ST_YMin(e)), radians(ST_XMax(e)),
                                       radians(ST_YMax(e)), s.region[5], s.region[6]]
                          FROM (SELECT ST_Transform(ST_Translate(ST_Transform(ST_Segmentize(ST_MakeEnvelope(
                                degrees(s.region[1]), degrees(s.region[2]), degrees(s.region[3]),
                                degrees(s.region[4]), 4326), 0.005), g.srid), g.dx, g.dy), 4326) AS e) r)""",
                    "box": "NULL",
                },
                grid_all,
            ),
        )
        step(
            "tiles.building_tile",
            _copy_sql(
                conn,
                "tiles.building_tile",
                "src_building_tile",
                {
                    **shift,
                    "building_id": f"s.building_id + {off}",
                    "group_id": f"s.group_id + {off}",
                    "anchor": "ST_Translate(s.anchor, g.dx, g.dy)",
                },
                grid_all,
            ),
        )
        step(
            "gen.block",
            _copy_sql(
                conn,
                "gen.block",
                "src_block",
                {
                    **shift,
                    "block_id": f"s.block_id + {off}",
                    "members": f"(SELECT array_agg(m + {off} ORDER BY m) FROM unnest(s.members) m)",
                    "footprint": "ST_Translate(s.footprint, g.dx, g.dy)",
                    "geom": "ST_Translate(s.geom, g.dx, g.dy, 0)",
                },
                grid_all,
                overriding=True,
            ),
        )
        # bounding spheres: the centre through the working CRS, translated there, and back to ECEF
        step(
            "tiles.tile_content",
            _copy_sql(
                conn,
                "tiles.tile_content",
                "src_tile_content",
                {
                    **shift,
                    "feature_id": f"s.feature_id + {off}",
                    "osm_id": f"s.osm_id + {off}",
                    "cx": "ST_X(m.c)",
                    "cy": "ST_Y(m.c)",
                    "cz": "ST_Z(m.c)",
                },
                grid_all,
                lateral="SELECT ST_Transform(ST_Translate(ST_Transform("
                "ST_SetSRID(ST_MakePoint(s.cx, s.cy, s.cz), 4978), g.srid), g.dx, g.dy, 0), 4978) AS c",
                order="1, 2, 3",
            ),
        )  # a tile's rows together on disk, as tiles.finish_hierarchy writes them
        t = time.perf_counter()
        _stack_levels(conn, up, size, int(srid))
        log(f"{DB_1M}: upper levels {time.perf_counter() - t:.0f} s")
        step("ANALYZE", "ANALYZE")
        n = conn.execute("SELECT count(*) FROM tiles.building_tile").fetchone()[0]  # type: ignore[index]
    _write_marker(url, inputs, time.perf_counter() - t0)
    log(f"{DB_1M}: {n:,} features, built in {time.perf_counter() - t0:.0f} s")
    return url


def _stack_levels(conn: psycopg.Connection, up: int, size: float, srid: int) -> None:
    """``up`` new levels above the copies' roots, built as the pipeline builds them: each tile's band from its
    height and width (gen.level_for_height), its blocks merged from its children's by the generalize stage's
    own code (generalize.coarse_blocks), its content listed in tiles.tile_content, its geometric error the
    larger of its content's and its children's, the blocks within it omitted (tiles.omit_within_error); then
    every tile's box from its region."""
    copy_band = conn.execute("SELECT min(gen_level) FROM tiles.tile WHERE level = %s", (up,)).fetchone()[0]  # type: ignore[index]
    if copy_band > 1:
        raise RuntimeError("the copies' roots are not in a block band: too few levels to stack")
    conn.execute("UPDATE tiles.grid SET size = size * %s", (2**up,))
    root_h = conn.execute("SELECT max(height) FROM tiles.tile WHERE level = %s", (up,)).fetchone()[0] + up  # type: ignore[index]
    for lvl in range(up - 1, -1, -1):
        cs = size * 2 ** (up - lvl)
        conn.execute(
            """
            INSERT INTO tiles.tile (level, x, y, is_leaf, n_features, n_triangles, cell, region, geometric_error,
                                    content_uri, height, gen_level, content_error_m)
            SELECT %(lvl)s, c.x >> 1, c.y >> 1, false, sum(c.n_features), sum(c.n_triangles),
                   ST_SetSRID(ST_Extent(c.cell)::geometry, %(srid)s),  -- cells are lon/lat: their children's box
                   ARRAY[min(c.region[1]), min(c.region[2]), max(c.region[3]), max(c.region[4]),
                         min(c.region[5]), max(c.region[6])],
                   max(c.geometric_error), format('content/%%s/%%s/%%s.glb', %(lvl)s, c.x >> 1, c.y >> 1),
                   max(c.height) + 1, gen.level_for_height(max(c.height) + 1, %(root_h)s, %(cs)s), 0
            FROM tiles.tile c WHERE c.level = %(child)s
            GROUP BY c.x >> 1, c.y >> 1""",
            {"lvl": lvl, "child": lvl + 1, "cs": cs, "srid": srid, "root_h": root_h},
        )
    with conn.transaction():
        generalize.coarse_blocks(conn, Settings(), srid, max_level=up - 1)
    conn.execute(
        """
        INSERT INTO tiles.tile_content (level, x, y, feature_kind, feature_id, osm_type, osm_id, lod, gen_level,
                                        n_members, n_triangles, error_m, cx, cy, cz, radius)
        SELECT t.level, t.x, t.y, f.feature_kind, f.building_id, f.osm_type, f.osm_id, f.lod, f.gen_level,
               f.n_members, f.n_triangles, f.error_m, b[1], b[2], b[3], b[4]
        FROM tiles.tile t CROSS JOIN LATERAL api.buildings_for_tile(t.level, t.x, t.y) f
        CROSS JOIN LATERAL (SELECT tiles.feature_sphere(Box3D(f.geom), ST_SRID(f.geom), %s) AS b) sp
        WHERE t.level < %s""",
        (Settings().base_height_m, up),
    )
    for lvl in range(up - 1, -1, -1):
        conn.execute(
            """
            UPDATE tiles.tile t SET content_features = k.n, content_triangles = k.tri, content_error_m = k.err,
                   geometric_error = greatest(k.err, t.geometric_error)
            FROM (SELECT level, x, y, count(*) AS n, sum(n_triangles) AS tri, max(error_m) AS err
                  FROM tiles.tile_content WHERE level = %s GROUP BY 1, 2, 3) k
            WHERE (t.level, t.x, t.y) = (k.level, k.x, k.y)""",
            (lvl,),
        )
        conn.execute(
            """
            UPDATE tiles.tile p SET geometric_error = greatest(p.geometric_error, k.ge)
            FROM (SELECT x >> 1 AS x, y >> 1 AS y, max(geometric_error) AS ge FROM tiles.tile
                  WHERE level = %s GROUP BY 1, 2) k
            WHERE p.level = %s AND (p.x, p.y) = (k.x, k.y)""",
            (lvl + 1, lvl),
        )
    # the selection on tile error, then boxes from the regions, as the generalize stage does
    with conn.transaction(), conn.cursor() as cur:
        cur.execute("CALL tiles.omit_within_error(%s, NULL)", (up - 1,))
        store_boxes(cur)


def scale(
    admin_url: str,
    osm: Path,
    n: int = N_CAMERAS,
    seed: int = SEED,
    rebuild: bool = False,
    only: Sequence[str] = ("100k", "1m"),
) -> dict[str, Any]:
    """Build (or reuse) the two databases and measure api.lod_for_view's latency on each."""
    out: dict[str, Any] = {"osm": osm.name, "copies_100k": COPIES_100K, "copies_1m": COPIES_1M}
    t0 = time.perf_counter()
    url100 = build_100k(admin_url, osm, rebuild)
    url1m = build_1m(admin_url, osm, rebuild) if "1m" in only else None
    out["build_s"] = round(time.perf_counter() - t0, 1)
    for key, url in (("100k", url100), ("1m", url1m)):
        if url is None or key not in only:
            continue
        t = time.perf_counter()
        out[key] = measure_latency(url, n, seed)
        out[key]["measure_s"] = round(time.perf_counter() - t, 1)
        # issue 17: tileset.json stays small at scale with implicit tiling (tile records only, no glb)
        from benchmarks.tileset_size import measure as tileset_size

        out[key]["tileset"] = tileset_size(url)
        log(
            f"{key}: p50 {out[key]['p50_ms']} ms, p95 {out[key]['p95_ms']} ms, max {out[key]['max_ms']} ms, "
            f"{out[key]['mean_features']} features per view ({out[key]['buildings']:,} buildings)"
        )
    return out


# --- main ---------------------------------------------------------------------------------------------------


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(
        prog="python -m benchmarks.view_bench",
        description=__doc__,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    sub = p.add_subparsers(dest="cmd", required=True)
    tri = sub.add_parser("triangles", help="triangles per view: overview and street cameras vs. all LOD3")
    lat = sub.add_parser("latency", help="api.lod_for_view p50/p95 over the seeded navigation cameras")
    for sp in (tri, lat):
        sp.add_argument("--database-url", help="a generalized database (default: DATABASE_URL / the local cluster)")
    sc = sub.add_parser("scale", help="build/reuse the ~100k and ~1M databases and measure the latency on both")
    sc.add_argument("--osm", type=Path, help="extract to replicate (default: the Liechtenstein benchmark extract)")
    sc.add_argument("--rebuild", action="store_true", help="rebuild the databases even when their marker matches")
    sc.add_argument("--only", choices=("100k", "1m"), help="build and measure only up to this size")
    for sp in (lat, sc):
        sp.add_argument("--cameras", type=int, default=N_CAMERAS)
        sp.add_argument("--seed", type=int, default=SEED)
    args = p.parse_args(argv)

    cluster.ensure()
    if args.cmd == "scale":
        osm = (args.osm or SHARED_OSM / f"{HEADLINE}.osm.pbf").resolve()
        only = ("100k",) if args.only == "100k" else ("100k", "1m")
        res = scale(cluster.database_url("postgres"), osm, args.cameras, args.seed, args.rebuild, only)
    else:
        url = args.database_url or os.environ.get("DATABASE_URL") or cluster.database_url("citylod")
        res = triangles_per_view(url) if args.cmd == "triangles" else measure_latency(url, args.cameras, args.seed)
    print(json.dumps(res, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
