"""``python -m benchmarks.bench``: time every pipeline stage on the real extracts, next to osm2pgsql.

For each extract a fresh database ``citylod_bench`` is created in the same cluster the pipeline uses
(DATABASE_URL when set, else the local cluster under var/pg) and migrated. Then ingest, lod, landmarks, tiles,
generalize, textures and export run as separate ``python -m etl`` processes, exactly as ``make`` runs them,
``--repeat`` times. For each one the wall-clock seconds and the child's peak RSS (from ``os.wait4``) are
measured; the building counts come from the ``meta.pipeline_run`` row that the stage wrote. osm2pgsql loads
the same file with a flex style (benchmarks/osm2pgsql/buildings.lua) into ``citylod_bench_o2p`` as the
reference loader.

On the generalized database of the last repeat: triangles per view (overview and street cameras against every
building at LOD3, benchmarks/view_bench.py), the texture atlases (benchmarks/report_textures.py ``measure``:
utilization, pages and bytes per band, draw calls against one texture per building, shelf against xatlas) and
the stream (benchmarks/stream_bench.py ``measure``: the compact stream against today's, both exported again
from that database: bytes, export seconds, CesiumJS memory and screenshots at the street and overview cameras)
and the far view fidelity (benchmarks/fidelity_bench.py ``measure``: the last repeat's export drawn as building
masks in CesiumJS, streamed at SSE 16 against full detail, far to near; vertices and triangles per tree level)
for every extract, and for the benchmark extract the tile server under 64 concurrent clients, cold and warm cache
(benchmarks/serve_bench.py ``measure_db``). Last, the latency of api.lod_for_view at ~100k and ~1M buildings
on two cached bench-only databases replicated from the benchmark extract (``view_bench.scale``; built once,
~15 minutes, then reused while the code is unchanged).

``--write BENCHMARKS.md`` regenerates that file from scratch. Progress goes to stderr; the children's output
goes to build/bench/logs/.
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import psycopg

from benchmarks import fidelity_bench, report_textures, scale_bench, soak_bench, stream_bench, update_bench, view_bench
from benchmarks.common import (
    HEADLINE,
    LOG_DIR,
    O2P_DB,
    OUT_ROOT,
    SHARED_OSM,
    drop_db,
    extract_name,
    last_run,
    log,
    machine,
    machine_section,
    markdown_table,
    osm2pgsql_cmd,
    pass_mark,
    recreate_db,
    run_child,
)
from core import cluster
from core.settings import REPO, Settings
from etl.fetch import DEMO_OSM
from exporter import volumes

# Liechtenstein first: it is the benchmark extract the headline figures quote.
DEFAULT_EXTRACTS = (
    "liechtenstein_2022-07-24.osm.pbf",
    "malta_2018-08-27.osm.pbf",
    "munich_altstadt.osm.pbf",
    "london_city.osm.pbf",
)
BENCH_DB = "citylod_bench"
STAGES = ("ingest", "lod", "landmarks", "tiles", "generalize", "textures", "export")
# Which pipeline_run count is "the buildings this stage handled".
BUILDINGS_KEY = {
    "ingest": "in",
    "lod": "in",
    "landmarks": "buildings",
    "tiles": "features",
    "generalize": "buildings",
    "textures": "buildings",
    "export": "buildings",
}
SERVER_TARGET = 1000.0  # warm tiles/s with 64 clients (issue 4)
# serve --db before and after exporter/serve.py (http.server, a hand-written pool) became exporter/serve/
# (Starlette on uvicorn, psycopg_pool), issue 16. make bench measures only the code it runs, so both are recorded
# here: `python -m benchmarks.serve_bench --database-url URL` run from a checkout of each commit, alternately
# (after, before, after, ...), on one Liechtenstein database built by the pipeline (ingest .. textures), the
# same client; medians of 5 runs each, on 2026-11-25 while other test suites loaded the machine (load 4-32).
SERVER_SPLIT = {
    "runs": 5,
    "before": {
        "commit": "40af573",
        "stack": "http.server, hand-written pool",
        "cold": {
            "requests": 133,
            "tiles_per_s": 6.8,
            "p50_ms": 8689.8,
            "p99_ms": 12551.3,
            "max_ms": 13741.0,
            "bytes": 113132583,
            "errors": 0,
        },
        "warm": {
            "requests": 42880,
            "tiles_per_s": 1485.0,
            "p50_ms": 29.8,
            "p99_ms": 221.5,
            "max_ms": 816.9,
            "bytes": 36210195840,
            "errors": 0,
        },
    },
    "after": {
        "commit": "775e741",
        "stack": "Starlette on uvicorn, psycopg_pool",
        "cold": {
            "requests": 133,
            "tiles_per_s": 7.1,
            "p50_ms": 8453.0,
            "p99_ms": 10250.7,
            "max_ms": 11459.2,
            "bytes": 113132583,
            "errors": 0,
        },
        "warm": {
            "requests": 42880,
            "tiles_per_s": 1716.1,
            "p50_ms": 35.7,
            "p99_ms": 99.6,
            "max_ms": 1126.8,
            "bytes": 36210195840,
            "errors": 0,
        },
    },
}
# Counts that legitimately differ between repeats of the same input (at any depth: textures has them per band).
VOLATILE_COUNTS = frozenset({"seconds", "directory", "seconds_by_step", "buildings_per_s"})


# --- measuring one child process ----------------------------------------------------------------------------


@dataclass
class Sample:
    seconds: float  # wall clock of the whole process, interpreter start-up included
    rss_mib: float  # peak resident set of the child (and of any children it reaped)
    counts: dict[str, Any] = field(default_factory=dict)
    stage_s: float | None = None  # duration_s the stage recorded itself (excludes start-up and imports)


# --- databases ----------------------------------------------------------------------------------------------


def measure_server(url: str, logfile: Path) -> dict[str, Any]:
    """serve_bench.measure_db(url), run in a child process: its 64 client threads neither share this process's
    GIL nor inflate its memory, which every later child would inherit in its peak RSS."""
    logfile.parent.mkdir(parents=True, exist_ok=True)
    with logfile.open("wb") as err:
        out = subprocess.run(
            [sys.executable, "-m", "benchmarks.serve_bench", "--database-url", url],
            cwd=REPO,
            stdout=subprocess.PIPE,
            stderr=err,
            check=True,
        ).stdout
    return json.loads(out)


# --- one extract --------------------------------------------------------------------------------------------


@dataclass
class ExtractResult:
    path: Path
    stages: dict[str, list[Sample]] = field(default_factory=lambda: {s: [] for s in STAGES})
    o2p: list[Sample] = field(default_factory=list)
    o2p_rows: dict[str, int] = field(default_factory=dict)
    views: dict[str, Any] | None = None  # view_bench.triangles_per_view
    server: dict[str, Any] | None = None  # serve_bench.measure_db (benchmark extract only)
    textures: dict[str, Any] | None = None  # report_textures.measure
    stream: dict[str, Any] | None = None  # stream_bench.measure
    fidelity: dict[str, Any] | None = None  # fidelity_bench.measure
    volumes: dict[str, Any] | None = None  # exporter.volumes.measure of the exported tileset

    @property
    def name(self) -> str:
        return extract_name(self.path)

    def counts(self, stage: str) -> dict[str, Any]:
        return self.stages[stage][-1].counts  # the same on every repeat unless the code changed: see drift()

    def buildings(self, stage: str) -> int:
        return int(self.counts(stage).get(BUILDINGS_KEY[stage], 0))

    def median_s(self, stage: str) -> float:
        return statistics.median(s.seconds for s in self.stages[stage])

    def median_stage_s(self, stage: str) -> float | None:
        vals = [s.stage_s for s in self.stages[stage] if s.stage_s is not None]
        return statistics.median(vals) if vals else None

    def peak_rss(self, stage: str) -> float:
        return max(s.rss_mib for s in self.stages[stage])

    def end_to_end(self) -> float:
        # Median over whole-chain runs, so the figure is one real run rather than a sum of per-stage medians.
        runs = len(self.stages["ingest"])
        per_repeat = [sum(self.stages[st][i].seconds for st in STAGES) for i in range(runs)]
        return statistics.median(per_repeat)

    def drift(self) -> list[str]:
        """Stages whose counts changed between repeats: the pipeline code (or its input) changed while the
        benchmark ran, so the runs did not measure the same work."""

        def stable(c: Any) -> Any:
            if isinstance(c, dict):
                return {k: stable(v) for k, v in c.items() if k not in VOLATILE_COUNTS}
            return [stable(v) for v in c] if isinstance(c, list) else c

        def key(c: dict[str, Any]) -> str:
            return json.dumps(stable(c), sort_keys=True)

        return [st for st in STAGES if len({key(s.counts) for s in self.stages[st]}) > 1]

    def o2p_median(self) -> float:
        return statistics.median(s.seconds for s in self.o2p)


def bench_extract(
    path: Path, repeat: int, admin_url: str, server: bool = True, stream: bool = True, fidelity: bool = True
) -> ExtractResult:
    res = ExtractResult(path=path)
    url = cluster.database_url(BENCH_DB)
    o2p_url = cluster.database_url(O2P_DB)
    env = {**os.environ, "DATABASE_URL": url}
    logs = LOG_DIR / res.name

    log(f"{res.name}: fresh databases {BENCH_DB} + {O2P_DB}, migrate")
    recreate_db(admin_url, BENCH_DB)
    run_child([sys.executable, "-m", "etl", "migrate"], env, logs / "migrate.log")
    recreate_db(admin_url, O2P_DB)
    with psycopg.connect(o2p_url, autocommit=True) as conn:
        conn.execute("CREATE EXTENSION IF NOT EXISTS postgis")

    o2p_cmd, o2p_env = osm2pgsql_cmd(o2p_url, path)
    for r in range(1, repeat + 1):
        # Every repeat reruns the whole chain: ingest truncates the derived tables, so each repeat measures
        # the same work as a first run on a migrated database.
        for stage in STAGES:
            extra = {"ingest": ["--osm", str(path)], "export": ["--out", str(OUT_ROOT / res.name)]}
            args = extra.get(stage, [])
            cmd = [sys.executable, "-m", "etl", stage, *args]
            seconds, rss = run_child(cmd, env, logs / f"{stage}-{r}.log")
            counts, stage_s = last_run(url, stage)
            res.stages[stage].append(Sample(seconds, rss, counts, stage_s))
            log(
                f"{res.name} #{r} {stage:<6} {seconds:7.2f} s  {rss:6.0f} MiB  "
                f"{int(counts.get(BUILDINGS_KEY[stage], 0)):,} buildings"
            )
        # osm2pgsql interleaved with citylod, so a noisy neighbour on the shared machine hits both alike.
        seconds, rss = run_child(o2p_cmd, o2p_env, logs / f"osm2pgsql-{r}.log")
        res.o2p.append(Sample(seconds, rss))
        log(f"{res.name} #{r} osm2pgsql {seconds:7.2f} s  {rss:6.0f} MiB")

    with psycopg.connect(o2p_url) as conn:
        rows = conn.execute("SELECT kind, count(*) FROM buildings GROUP BY kind").fetchall()
    res.o2p_rows = {k: int(n) for k, n in rows}

    with psycopg.connect(url) as conn:
        res.volumes = volumes.measure(conn, json.loads((OUT_ROOT / res.name / "tileset.json").read_text()))
    b = res.volumes["buildings"]
    log(f"{res.name} implicit volumes: {b['beyond_half_extent']} of {b['n']} buildings beyond their half-extent")
    res.views = view_bench.triangles_per_view(url)
    log(
        f"{res.name} triangles per view: overview {res.views['overview']['triangles']:,} vs all LOD3 "
        f"{res.views['all_lod3']['triangles']:,} ({res.views['overview_reduction']}x fewer)"
    )
    res.textures = report_textures.measure(url)
    log(
        f"{res.name} textures: utilization {res.textures['totals']['utilization']}, overview "
        f"{res.textures['views']['overview']['draw_call_ratio']}x fewer draw calls than one texture per building"
    )
    if stream:
        # the database this run built, exported again per stream (interleaved, `repeat` times)
        try:
            res.stream = stream_bench.measure(url, res.name, repeat=repeat)
        except Exception as e:  # noqa: BLE001 - reported in the Stream table, the bench goes on
            res.stream = stream_bench.failed(str(e))
            log(f"{res.name} stream: FAILED {e}")
    if fidelity:
        # the database this run built and the export its last repeat wrote, as a client streams it and at full detail
        try:
            res.fidelity = fidelity_bench.measure(url, res.name, tiles=OUT_ROOT / res.name)
        except Exception as e:  # noqa: BLE001 - reported in the fidelity table, the bench goes on
            res.fidelity = fidelity_bench.failed(str(e))
            log(f"{res.name} fidelity: FAILED {e}")
    if server and res.name == HEADLINE:
        res.server = measure_server(url, logs / "serve_bench.log")
        w, c = res.server["warm"], res.server["cold"]
        log(
            f"{res.name} serve --db, 64 clients: warm {w['tiles_per_s']:,.0f} tiles/s p99 {w['p99_ms']} ms, "
            f"cold {c['tiles_per_s']:,.0f} tiles/s p99 {c['p99_ms']} ms"
        )
    if drift := res.drift():
        log(f"WARNING {res.name}: counts of {', '.join(drift)} changed between repeats (code edited?)")
    return res


def _rate(n: float, s: float) -> str:
    return f"{n / s:,.0f}" if s > 0 else "–"


STAGES_NOTE = (
    "Wall seconds of the `python -m etl <stage>` process (median of {n}), start-up included. "
    "*in-stage s* is the `duration_s` the stage recorded itself in meta.pipeline_run (median); the "
    "difference is interpreter start-up and imports. Peak RSS is the client process only (max of the "
    "runs); the PostgreSQL backend's memory is not included."
)
O2P_NOTE = (
    "The same file loaded by osm2pgsql 1.8 with benchmarks/osm2pgsql/buildings.lua (buildings and "
    "building:parts from closed ways and multipolygon relations, tags as jsonb, multipolygon 4326). "
    "*ratio* = citylod ingest seconds / osm2pgsql seconds (medians of whole processes). citylod also "
    "parses and validates the Simple 3D Buildings tags, repairs geometries, rejects broken ones and links "
    "building relations, so the row counts differ a little."
)
OUTPUT_NOTE = (
    "From the export stage's counts. *buildings* are the meshes of the leaves (buildings and parts at LOD3; an "
    "outline drawn by its parts is not one); *features* and *triangles* count every tile's content, every "
    "band (blocks, LOD1, LOD2, LOD3) included. MB = 10⁶ bytes: the glb files plus tileset.json."
)
HOW_TO_READ = [
    "* Timings are medians of {n} on a shared {cores}-core machine where other work may be running; "
    "treat differences under ~20 % as noise. Tests never assert timings.",
    "* buildings/s = buildings the stage handled (ingest: OSM candidates read; lod: buildings and parts "
    "in; tiles, export: features; generalize: buildings, an outline with its parts counting once) / median "
    "wall seconds of the stage's process.",
    "* Each stage is a fresh Python process, so its seconds include interpreter start-up and imports "
    "(compare *in-stage s*); on the small extracts that overhead is a large share.",
    "* The extracts are real OSM data, © OpenStreetMap contributors, ODbL 1.0 "
    "(../shared/data/PROVENANCE.md). Only the api.lod_for_view latency at scale uses replicated copies of "
    "the benchmark extract (see that section); every other figure is one real extract, unscaled.",
]
GEN_NOTE = (
    "The generalize stage's own timing of its steps (meta.pipeline_run counts.seconds_by_step, last run): "
    "footprints (simplify, extrude, measure against LOD2), decimation (LOD2 band), blocks (cluster, merge, "
    "extrude the two block bands), hierarchy (tile content, measured geometric errors, boxes, coverage check)."
)
SERVER_NOTE = (
    "`python -m etl serve --db` on the benchmark extract's generalized bench database, loaded by 64 concurrent "
    "keep-alive HTTP/1.1 clients on loopback (benchmarks/serve_bench.py `measure_db`; Python threads in one "
    "process on the same machine, so on a small machine a lower bound). *cold*: a fresh server, every tile "
    "fetched once, each glb built from the database on its first request; *warm*: every client fetches "
    "tileset.json and every tile {rounds} times from the server's cache. Target: at least {target:,.0f} warm "
    "tiles/s."
)
VIEW_NOTE = (
    "Sum of n_triangles over the features api.lod_for_view returns (what a 3D Tiles client draws with REPLACE "
    "refinement, max_sse 16, fov 60°, 1080 px, 16:9) against the LOD3 triangles of every building (a client "
    "without the hierarchy). *overview*: over the centre of the data looking straight down, at the height "
    "where the root tile's region fills the view; *street*: 80 m up, 150 m south of the median building of "
    "the leaf tile with the most features, looking north 20° down (for context; it is not a target). "
    "Target, on the benchmark extract: overview at least 5× fewer triangles than all-LOD3. "
    "A small extract's quadtree is only a few "
    "levels deep, so its root is already a fine band and a view of the whole extract refines to its leaves."
)
TEXTURES_NOTE = (
    "The textures stage's atlases on the generalized database of the last repeat (benchmarks/report_textures.py "
    "`measure`; `make report-textures` writes the same for one database). *utilization*: chart texels / page "
    "texels over every page; *draw calls/tile*: glTF primitives the exporter writes (one per atlas page plus the "
    "vertex-coloured one where a feature has no texture); *one texture per building*: every textured feature its "
    "own material, texture and draw call, at the near (street) and overview cameras of *Triangles per view*, "
    "the whole tiles a client loads. Shelf / xatlas: the stage's chart sizes of the 20 tiles with the most "
    "charts packed again by each packer."
)
SCALE_NOTE = (
    "api.lod_for_view on two bench-only databases built from the benchmark extract and cached between runs "
    "(benchmarks/view_bench.py explains both): *~100k* = 6 copies of the extract side by side (osm.building "
    "replicated with ids offset and geometries translated), then lod, tiles and generalize run for real; "
    "*~1M* = 10 copies of the ~100k database at the tile level (tile tree, buildings, meshes, blocks copied "
    "with ids offset and geometries, regions and boxes translated/recomputed) under 2 new upper levels built "
    "as the pipeline builds them (their blocks merged from their children's by generalize.coarse_blocks, "
    "their content in tiles.tile_content, geometric error from content and children). "
    "{n} seeded navigation cameras (seed {seed}): positioned in leaf tiles drawn by their feature count, "
    "height 50–3000 m log-uniform, heading uniform, pitch −15° to −90°, fov 60°, 1080 px, max_sse 16. Each "
    "figure is the *client wall time* of one call (prepared statement, warm connection on the Unix socket, "
    "execute and fetch all rows: planning + execution + transfer), after one untimed warm-up pass over every "
    "camera. A call over the time limit (30 s) is cancelled and counted at the limit, so a figure marked ≥ "
    "is a lower bound. Target: p95 ≤ 10 ms at ~1M buildings."
)


def _headline(r: ExtractResult) -> str:
    rates = ", ".join(f"{st} {_rate(r.buildings(st), r.median_s(st))}/s" for st in STAGES)
    ec = r.counts("export")
    text = (
        f"**Headline ({r.name}):** {r.buildings('ingest'):,} buildings end to end in {r.end_to_end():.1f} s; "
        f"buildings/s per stage: {rates}. Peak RSS {max(r.peak_rss(st) for st in STAGES):.0f} MiB. "
        f"Tileset {ec.get('bytes', 0) / 1e6:.2f} MB, {ec.get('bytes_per_building', 0):,.0f} bytes/building. "
        f"citylod ingest takes {r.median_s('ingest') / r.o2p_median():.1f}× as long as osm2pgsql."
    )
    if r.views:
        text += (
            f" An overview camera draws {r.views['overview']['triangles']:,} triangles, "
            f"{r.views['overview_reduction']:.1f}× fewer than all buildings at LOD3."
        )
    if r.server:
        w = r.server["warm"]
        text += (
            f" serve --db: {w['tiles_per_s']:,.0f} warm tiles/s, p99 {w['p99_ms']:.0f} ms with {w['clients']} clients."
        )
    return text


def _generalize_section(results: list[ExtractResult], head: ExtractResult | None) -> list[str]:
    rows = []
    for r in results:
        gc = r.counts("generalize")
        st = gc.get("seconds_by_step", {})
        rows.append(
            [
                r.name,
                f"{r.buildings('generalize'):,}",
                f"{r.median_s('generalize'):.2f}",
                _rate(r.buildings("generalize"), r.median_s("generalize")),
                " / ".join(f"{st.get(k, 0):.2f}" for k in ("footprints", "decimation", "blocks", "hierarchy")),
                f"{int(gc.get('blocks', {}).get('blocks', 0)):,}",
                f"{int(gc.get('decimation', {}).get('decimated', 0)):,}",
            ]
        )
    header = [
        "extract",
        "buildings",
        f"seconds (median of {len(results[0].stages['generalize'])})",
        "buildings/s",
        "s in footprints / decimation / blocks / hierarchy (last run)",
        "blocks",
        "LOD2 meshes decimated",
    ]
    out = ["### generalize by step", "", GEN_NOTE, "", *markdown_table(header, rows, "lrrrrrr"), ""]
    if head is not None:
        bands = head.counts("generalize").get("bands", [])
        names = {
            0: "blocks 10 m",
            1: "blocks 5 m",
            2: "LOD1, footprints 2.5 m",
            3: "LOD2, decimated ≤ 1.25 m",
            4: "LOD3 (leaves)",
        }
        names.update({b["gen_level"]: f"blocks {10 * 2 ** -b['gen_level']:g} m" for b in bands if b["gen_level"] < 0})
        rows = [
            [
                f"{b['gen_level']} ({names.get(b['gen_level'], '?')})",
                f"{b['tiles']:,}",
                f"{b['features']:,}",
                f"{b['triangles']:,}",
                f"{b['max_geometric_error_m']:.2f}",
            ]
            for b in bands
        ]
        out += [
            f"### generalize bands ({head.name})",
            "",
            "Per generalization band (gen_level) of the tile hierarchy: tiles, the features and triangles "
            "of their content, and the largest measured geometric error (m) of a tile in the band.",
            "",
            *markdown_table(["band", "tiles", "features", "triangles", "max geometric error m"], rows, "lrrrr"),
            "",
        ]
    return out


def _views_section(results: list[ExtractResult]) -> list[str]:
    rows = []
    for r in results:
        v = r.views
        if not v:
            continue
        o, st = v["overview"], v["street"]
        rows.append(
            [
                r.name,
                f"{v['all_lod3']['triangles']:,}",
                f"{o['triangles']:,} ({o['features']:,} features, {o['tiles']} tiles, "
                f"{o['camera']['height'] / 1000:.1f} km up)",
                f"{v['overview_reduction']:.1f}×" + (f" {pass_mark(v['pass'])}" if r.name == HEADLINE else ""),
                f"{st['triangles']:,} ({st['features']:,} features, LOD "
                + "/".join(str(k) for k in sorted(st["by_lod"]))
                + ")",
            ]
        )
    if not rows:
        return []
    header = ["extract", "all buildings at LOD3", "overview camera", "fewer (target ≥ 5×)", "street camera"]
    return ["", "## Triangles per view", "", VIEW_NOTE, "", *markdown_table(header, rows, "lrrrr")]


VOLUMES_NOTE = (
    "What a 3D Tiles client that ignores the subtrees' metadata (3DTilesRendererJS, loaders.gl) computes from the "
    "implicit root alone (exporter/volumes.py, over the exported tileset.json and the database): each tile's volume "
    "the root region halved per level, its error the root's / 2^level. A building (with its parts, every LOD) or "
    "block outside its tile's volume is culled while in view; one that straddles a cell edge may stick out by its "
    "own half-extent (target: none beyond it). Errors below the measured: tiles whose computed error is below "
    "their own (target 0)."
)


def _volumes_section(results: list[ExtractResult]) -> list[str]:
    rows = []
    for r in results:
        v = r.volumes
        if not v:
            continue
        b, k = v["buildings"], v["blocks"]
        rows.append(
            [
                r.name,
                f"{b['n']:,}",
                f"{b['outside']:,}",
                f"{b['beyond_half_extent']:,} {pass_mark(b['beyond_half_extent'] == 0)}",
                f"{b['worst_m']:.0f}",
                f"{k['outside']:,} of {k['n']:,}",
                f"{k['beyond_half_extent']:,} {pass_mark(k['beyond_half_extent'] == 0)}",
                f"{v['tiles']:,}",
                f"{v['root_error']:.1f} ({v['measured_root_error']:.1f})",
                f"{v['error_shortfalls']} {pass_mark(v['error_shortfalls'] == 0)}",
            ]
        )
    if not rows:
        return []
    header = [
        "extract",
        "buildings",
        "outside their tile's volume",
        "beyond their half-extent",
        "worst overhang m",
        "blocks outside",
        "blocks beyond their members'",
        "tiles",
        "root error (root tile's own)",
        "errors below the measured",
    ]
    return ["", "## Implicit volumes", "", VOLUMES_NOTE, "", *markdown_table(header, rows, "lrrrrrrrrr")]


def _textures_section(results: list[ExtractResult], head: ExtractResult | None) -> list[str]:
    """Atlases of every extract in one table, then the benchmark extract's tables (report_textures)."""
    rows = []
    for r in results:
        t = r.textures
        if not t:
            continue
        tt, near, over, pk = t["totals"], t["views"]["near"], t["views"]["overview"], t["packers"]["totals"]
        util, ratio = f"{100 * (tt['utilization'] or 0):.1f} %", f"({over['draw_call_ratio']}×)"
        if r.name == HEADLINE:
            util, ratio = f"{util} {pass_mark(t['utilization_pass'])}", f"{ratio} {pass_mark(t['draw_call_pass'])}"
        rows.append(
            [
                r.name,
                f"{tt['textured_tiles']}",
                f"{tt['pages']:,}",
                f"{tt['bytes'] / 1e6:.1f}",
                util,
                f"{tt['draw_calls_per_tile']:.1f}",
                f"{near['atlas']['draw_calls']:,} vs {near['per_building']['draw_calls']:,}",
                f"{over['atlas']['draw_calls']:,} vs {over['per_building']['draw_calls']:,} {ratio}",
                " / ".join(f"{100 * (pk[p]['utilization'] or 0):.1f} %" for p in ("shelf", "xatlas")),
            ]
        )
    if not rows:
        return []
    header = [
        "extract",
        "textured tiles",
        "pages",
        "MB",
        "utilization (target ≥ 80 %)",
        "draw calls/tile",
        "near: draw calls atlases vs one texture per building",
        "overview (target ≥ 10× fewer)",
        "shelf / xatlas utilization (largest tiles)",
    ]
    out = ["", "## Textures", "", TEXTURES_NOTE, "", *markdown_table(header, rows, "lrrrrrrrr")]
    if head is not None and head.textures:
        out += ["", f"Per band, per view and per packer on {head.name}:", ""]
        out += report_textures.section_lines(head.textures, "###")
    return out


def _server_section(results: list[ExtractResult]) -> list[str]:
    r = next((x for x in results if x.server), None)
    if r is None or r.server is None:
        return []

    def rate(m: dict[str, Any]) -> str:
        x = m["tiles_per_s"]
        return f"{x:,.1f}" if x < 100 else f"{x:,.0f}"

    def row(cache: str, server: str, m: dict[str, Any]) -> list[str]:
        return [
            cache,
            server,
            f"{m['requests']:,}",
            rate(m),
            f"{m['p50_ms']:.1f}",
            f"{m['p99_ms']:.1f}",
            f"{m['max_ms']:.1f}",
            f"{m['bytes'] / 1e6:.1f}",
            str(m["errors"]),
        ]

    rows = [row(key, "this run", r.server[key]) for key in ("cold", "warm")]
    for side in ("before", "after"):
        rec = SERVER_SPLIT[side]
        rows += [
            row(key, f"{rec['commit']} {rec['stack']} (recorded, {side} the split)", rec[key])
            for key in ("cold", "warm")
        ]
    bw, aw = SERVER_SPLIT["before"]["warm"], SERVER_SPLIT["after"]["warm"]
    bc, ac = SERVER_SPLIT["before"]["cold"], SERVER_SPLIT["after"]["cold"]
    warm = r.server["warm"]["tiles_per_s"]
    return [
        "",
        f"## Server ({r.name}, {r.server['tiles']} tiles)",
        "",
        SERVER_NOTE.format(rounds=5, target=SERVER_TARGET),
        "",
        *markdown_table(
            ["cache", "server", "requests", "tiles/s", "p50 ms", "p99 ms", "max ms", "MB sent", "errors"],
            rows,
            "llrrrrrrr",
        ),
        "",
        f"Warm: {warm:,.0f} tiles/s against the target of {SERVER_TARGET:,.0f}: {pass_mark(warm >= SERVER_TARGET)}.",
        "",
        "Before and after the server moved from http.server to Starlette on uvicorn (exporter/serve/, issue "
        f"16): the recorded rows, medians of {SERVER_SPLIT['runs']} alternating runs each of "
        "`python -m benchmarks.serve_bench --database-url URL` from a checkout of each commit on the same "
        "database (a busy machine: compare them with each other, not with this run): "
        f"warm {rate(bw)} → {rate(aw)} tiles/s, p99 {bw['p99_ms']:.0f} → {aw['p99_ms']:.0f} ms; "
        f"cold {rate(bc)} → {rate(ac)} tiles/s.",
    ]


def _num(x: float | None) -> str:
    return "–" if x is None else f"{x:,.0f}"


def _scale_section(scale: dict[str, Any] | None) -> list[str]:
    if not scale:
        return []
    rows, first = [], None
    for key, label in (("100k", "~100k"), ("1m", "~1M")):
        m = scale.get(key)
        if not m:
            continue
        first = first or m
        cap = m.get("timeout_s", float("inf")) * 1e3

        def ms(x: float, cap: float = cap) -> str:
            return f"≥ {cap:,.0f}" if x >= cap else f"{x:,.1f}"

        rows.append(
            [
                label,
                f"{m['buildings']:,}",
                f"{m['tiles']:,}",
                ms(m["p50_ms"]),
                ms(m["p95_ms"]),
                ms(m["max_ms"]),
                _num(m.get("mean_features")),
                _num(m.get("max_features")),
                f"{m.get('timeouts', 0)}",
                pass_mark(m["pass"]) if key == "1m" else "–",
            ]
        )
    if first is None:
        return []
    header = [
        "database",
        "buildings (features)",
        "tiles",
        "p50 ms",
        "p95 ms",
        "max ms",
        "mean features/view (completed calls)",
        "max features/view",
        "calls over the time limit",
        "p95 ≤ 10 ms",
    ]
    out = [
        "",
        "## api.lod_for_view latency at scale",
        "",
        SCALE_NOTE.format(n=first["cameras"], seed=first["seed"]),
        "",
        *markdown_table(header, rows, "lrrrrrrrrl"),
        "",
    ]
    for key, label in (("100k", "~100k"), ("1m", "~1M")):
        m = scale.get(key)
        if not m:
            continue
        sl, p95 = m["profile"]["slowest"], m["profile"]["p95"]
        c = sl["camera"]
        out.append(
            f"* {label}: EXPLAIN (ANALYZE, TIMING OFF) of the p95 camera: planning {p95['planning_ms']:.1f} ms, "
            f"execution {p95['execution_ms']:.1f} ms; of the slowest ({c['height']:.0f} m, pitch "
            f"{c['pitch']:.0f}°, {_num(sl['features'] if sl['features'] is not None else sl.get('rows'))} features): "
            f"planning {sl['planning_ms']:.1f} ms, execution "
            f"{sl['execution_ms']:.1f} ms."
        )
    sizes = [
        (label, scale[key]["tileset"])
        for key, label in (("100k", "~100k"), ("1m", "~1M"))
        if scale.get(key) and "tileset" in scale[key]
    ]
    if sizes:
        out += [
            "",
            "tileset.json of each database's tile tree (benchmarks/tileset_size.py: the bytes the export "
            "writes, from the tile records alone). Target (issue 17): implicit ≤ 100 kB at ~1M.",
            "",
            *markdown_table(
                [
                    "database",
                    "tiles",
                    "levels",
                    "implicit tileset.json",
                    "explicit tileset.json",
                    "subtrees (files, bytes)",
                    "≤ 100 kB",
                ],
                [
                    [
                        label,
                        f"{t['tiles']:,}",
                        f"{t['levels']}",
                        f"{t['implicit_tileset_json_bytes']:,} B",
                        f"{t['explicit_tileset_json_bytes']:,} B",
                        f"{t['subtrees']}, {t['subtree_bytes']:,} B",
                        pass_mark(t["implicit_tileset_json_bytes"] <= 100_000) if label == "~1M" else "–",
                    ]
                    for label, t in sizes
                ],
                "lrrrrrl",
            ),
            "",
        ]
    if "build_s" in scale:
        out.append(
            f"* Databases built or reused in {scale['build_s']:.0f} s this run (cached between runs by a "
            "marker of their inputs and code)."
        )
    return out


def render(
    results: list[ExtractResult],
    mach: dict[str, str],
    repeat: int,
    command: str,
    scale: dict[str, Any] | None = None,
    scale_stages: dict[str, Any] | None = None,
) -> str:
    n = f"{repeat} run" + ("s" if repeat != 1 else "")
    lines = [
        "# citylod benchmarks",
        "",
        "Generated by `make bench`, i.e.",
        "",
        "```bash",
        command,
        "```",
        "",
        "Regenerated in full on every run; do not edit by hand. benchmarks/README.md explains the figures.",
        "",
    ]
    head = next((r for r in results if r.name == HEADLINE), results[0] if results else None)
    if head is not None:
        lines += [_headline(head), ""]
    lines += machine_section(mach)

    lines += ["", "## Stages", "", STAGES_NOTE.format(n=n), ""]
    for stage in STAGES:
        rows = []
        for r in results:
            inner = r.median_stage_s(stage)
            rows.append(
                [
                    r.name,
                    f"{r.buildings(stage):,}",
                    f"{r.median_s(stage):.2f}",
                    f"{inner:.2f}" if inner is not None else "–",
                    _rate(r.buildings(stage), r.median_s(stage)),
                    f"{r.peak_rss(stage):.0f}",
                ]
            )
        header = ["extract", "buildings", f"seconds (median of {repeat})", "in-stage s", "buildings/s", "peak RSS MiB"]
        lines += [f"### {stage}", "", *markdown_table(header, rows, "lrrrrr"), ""]

    rows = []
    for r in results:
        lc = r.counts("lod")
        steps = lc.get("seconds_by_step", {})
        rows.append(
            [
                r.name,
                f"{r.buildings('lod'):,}",
                f"{int(lc.get('pitched_roofs', 0)):,}",
                f"{lc.get('lod2_closed_pct', 0)}%",
                " / ".join(f"{lc.get(f'triangles_per_building_lod{k}', 0)}" for k in (1, 2, 3)),
                " / ".join(f"{steps.get(k, 0):.2f}" for k in ("lod1", "lod2", "lod3", "encode", "copy")),
                _rate(r.buildings("lod"), r.median_s("lod")),
            ]
        )
    header = [
        "extract",
        "buildings",
        "pitched roofs",
        "LOD2 closed",
        "triangles/building LOD1 / 2 / 3",
        "s in LOD1 / LOD2 / LOD3 / encode / COPY (last run)",
        "LOD1+2+3 buildings/s",
    ]
    lines += [
        "### lod by level of detail",
        "",
        "The lod stage builds all three LODs in one pass; the split is its own timing of each step (COPY "
        "runs in a second thread, overlapping the others). LOD3 openings: "
        f"{Settings.from_env().lod3_openings} (settings.lod3_openings).",
        "",
        *markdown_table(header, rows, "lrrrrrr"),
        "",
    ]

    rows = []
    for r in results:
        slowest = max(STAGES, key=r.median_s)
        rows.append(
            [
                r.name,
                f"{r.buildings('ingest'):,}",
                f"{r.end_to_end():.2f}",
                _rate(r.buildings("ingest"), r.end_to_end()),
                f"{slowest} ({r.median_s(slowest) / r.end_to_end():.0%})",
            ]
        )
    header = [
        "extract",
        "buildings (ingest in)",
        f"seconds (median of {repeat})",
        "buildings/s",
        "slowest stage (share)",
    ]
    lines += _generalize_section(results, head)
    lines += ["### end to end (" + " + ".join(STAGES) + ")", "", *markdown_table(header, rows, "lrrrl")]

    rows = []
    for r in results:
        ic = r.counts("ingest")
        rows.append(
            [
                r.name,
                f"{r.o2p_median():.2f}",
                f"{r.median_s('ingest'):.2f}",
                f"{r.median_s('ingest') / r.o2p_median():.1f}×",
                f"{sum(r.o2p_rows.values()):,} ({r.o2p_rows.get('building', 0):,} + {r.o2p_rows.get('part', 0):,})",
                f"{int(ic.get('loaded', 0)):,} ({int(ic.get('buildings', 0)):,} + {int(ic.get('parts', 0)):,}), "
                f"{int(ic.get('rejected', 0)):,} rejected",
            ]
        )
    header = [
        "extract",
        "osm2pgsql s",
        "citylod ingest s",
        "ratio",
        "osm2pgsql rows (buildings + parts)",
        "citylod rows (buildings + parts)",
    ]
    lines += ["", "## osm2pgsql side by side", "", O2P_NOTE, "", *markdown_table(header, rows, "lrrrrr")]

    rows = []
    for r in results:
        ec = r.counts("export")
        feats, tris, size = int(ec.get("features", 0)), int(ec.get("triangles", 0)), int(ec.get("bytes", 0))
        blds = int(ec.get("buildings", feats))
        rows.append(
            [
                r.name,
                f"{blds:,}",
                f"{feats:,}",
                f"{int(r.counts('tiles').get('tiles', 0)):,}",
                f"{int(ec.get('glb', 0)):,}",
                f"{tris:,}",
                f"{size / 1e6:.2f}",
                f"{size / max(blds, 1):,.0f}",
            ]
        )
    header = [
        "extract",
        "buildings",
        "features (all bands)",
        "tiles",
        "glb",
        "triangles (all bands)",
        "tileset MB",
        "bytes/building",
    ]
    lines += ["", "## Output", "", OUTPUT_NOTE, "", *markdown_table(header, rows, "lrrrrrrr")]
    lines += _views_section(results)
    lines += _volumes_section(results)
    lines += _textures_section(results, head)
    lines += stream_bench.section_lines([(r.name, r.stream) for r in results if r.stream])
    lines += fidelity_bench.section_lines([(r.name, r.fidelity) for r in results if r.fidelity])
    lines += _server_section(results)
    lines += scale_bench.section(scale_stages)
    lines += _scale_section(scale)

    drifted = [f"{r.name} ({', '.join(d)})" for r in results if (d := r.drift())]
    if drifted:
        lines += [
            "",
            "## Warning",
            "",
            "Stage counts changed between repeats for " + "; ".join(drifted) + ". The pipeline code "
            "changed while the benchmark ran, so those runs did not all do the same work; the tables "
            "use the last run's counts. Rerun `make bench` on a quiet tree.",
        ]
    lines += ["", "## How to read this", ""]
    lines += [line.format(n=n, cores=mach.get("cores", "?")) for line in HOW_TO_READ]
    return "\n".join(lines) + "\n"


# --- main ---------------------------------------------------------------------------------------------------


def default_files() -> list[Path]:
    files = [SHARED_OSM / f for f in DEFAULT_EXTRACTS]
    if DEMO_OSM.exists():
        files.append(DEMO_OSM)
    return files


def _parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="python -m benchmarks.bench", description=__doc__.split("\n\n")[0])
    p.add_argument("--write", metavar="PATH", help="write the markdown report here (e.g. BENCHMARKS.md)")
    p.add_argument("--repeat", type=int, default=3, help="runs per stage; the median is reported (default 3)")
    p.add_argument("--files", nargs="+", type=Path, help="OSM extracts (default: ../shared/data/osm + demo)")
    p.add_argument("--keep", action="store_true", help=f"keep {BENCH_DB} and {O2P_DB} afterwards")
    p.add_argument("--no-server", action="store_true", help="skip the serve --db load test")
    p.add_argument(
        "--no-stream",
        action="store_true",
        help="skip the Stream section (compact vs plain exports, CesiumJS in headless Chromium)",
    )
    p.add_argument(
        "--no-fidelity",
        action="store_true",
        help="skip the Far view fidelity section (building masks streamed vs full detail in CesiumJS)",
    )
    p.add_argument(
        "--scale-json",
        type=Path,
        help="take the latency at scale from this output of `python -m benchmarks.view_bench scale` "
        "(a run on a quiet machine) instead of measuring it here",
    )
    p.add_argument(
        "--scale-stages-json",
        type=Path,
        help="take the Scale section (every stage on the extract and its replicas) from this output of "
        "`python -m benchmarks.scale_bench --json` (make bench-scale: with the ~1M replica)",
    )
    p.add_argument(
        "--soak-json",
        type=Path,
        help="take the Soak section from this output of `python -m benchmarks.soak_bench --json` "
        "(serve --db under 200 requests/s while the benchmark extract is rebuilt, ~6 min)",
    )
    p.add_argument("--no-soak", action="store_true", help="skip the Soak section")
    p.add_argument(
        "--update-json",
        type=Path,
        help="take the Updates section from this output of `python -m benchmarks.update_bench --json` "
        "(a 1 %% change file against the full rebuild of the benchmark extract, ~8 min)",
    )
    p.add_argument("--no-update", action="store_true", help="skip the Updates section")
    p.add_argument(
        "--no-scale-stages",
        action="store_true",
        help="skip the Scale section (the pipeline on the benchmark extract and its 6x replica, ~10 min)",
    )
    p.add_argument(
        "--no-scale",
        action="store_true",
        help="skip api.lod_for_view at ~100k/~1M buildings (its cached databases take ~15 min to build)",
    )
    return p


def _command(args: argparse.Namespace) -> str:
    """The command line the report names: how to measure it again."""
    command = "python -m benchmarks.bench" + (f" --write {args.write}" if args.write else "")
    if args.repeat != 3:
        command += f" --repeat {args.repeat}"
    if args.files:
        command += " --files " + " ".join(str(f) for f in args.files)
    for flag in ("no_server", "no_stream", "no_fidelity", "no_scale", "no_scale_stages", "no_soak", "no_update"):
        if getattr(args, flag):
            command += " --" + flag.replace("_", "-")
    if args.scale_stages_json:
        command += f" --scale-stages-json {args.scale_stages_json}"
    if args.scale_json:
        command += f" --scale-json {args.scale_json}  # from: python -m benchmarks.view_bench scale > {args.scale_json}"
    if args.soak_json:
        command += f" --soak-json {args.soak_json}"
    if args.update_json:
        command += f" --update-json {args.update_json}"
    return command


def _section(
    given: Path | None, skip: bool, head: Path | None, measure: Callable[[], dict[str, Any]]
) -> dict[str, Any] | None:
    """A section's figures: read from the JSON of a run elsewhere (``given``), measured on the headline extract,
    or none."""
    if given:
        return json.loads(given.read_text())
    return measure() if head is not None and not skip else None


def main(argv: list[str] | None = None) -> int:
    p = _parser()
    args = p.parse_args(argv)
    if args.repeat < 1:
        p.error("--repeat must be at least 1")

    files = [f.resolve() for f in args.files] if args.files else default_files()
    missing = [str(f) for f in files if not f.exists()]
    if missing:
        p.error("missing input: " + ", ".join(missing))

    cluster.ensure()  # starts the local cluster when DATABASE_URL is unset
    admin_url = cluster.database_url("postgres")
    command = _command(args)
    results: list[ExtractResult] = []
    t0 = time.perf_counter()
    try:
        for f in files:
            results.append(
                bench_extract(
                    f,
                    args.repeat,
                    admin_url,
                    server=not args.no_server,
                    stream=not args.no_stream,
                    fidelity=not args.no_fidelity,
                )
            )
        mach = machine(cluster.database_url(BENCH_DB))
        head = next((f for f in files if extract_name(f) == HEADLINE), None)
        scale_stages = _section(
            args.scale_stages_json, args.no_scale_stages, head, lambda: scale_bench.measure(head, [1, 6], admin_url)
        )
        soak = _section(args.soak_json, args.no_soak, head, lambda: soak_bench.measure(head, admin_url))
        update = _section(args.update_json, args.no_update, head, lambda: update_bench.measure(head, admin_url))
        scale = _section(args.scale_json, args.no_scale, head, lambda: view_bench.scale(admin_url, head))
    finally:
        if not args.keep:
            for db in (BENCH_DB, O2P_DB, soak_bench.SOAK_DB, update_bench.UPDATE_DB):
                drop_db(admin_url, db)
            log(f"dropped {BENCH_DB}, {O2P_DB} (use --keep to keep them)")

    report = render(results, mach, args.repeat, command, scale, scale_stages)
    extra = [*(update_bench.section(update) if update else []), *(soak_bench.section(soak) if soak else [])]
    if extra:
        before, sep, after = report.partition("## How to read")
        report = before + "\n".join(extra) + "\n" + sep + after
    if args.write:
        Path(args.write).write_text(report)
        log(f"wrote {args.write}")
    else:
        print(report)
    log(f"done in {time.perf_counter() - t0:.0f} s")
    return 0


if __name__ == "__main__":
    sys.exit(main())
