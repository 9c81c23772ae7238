"""``python -m benchmarks.report_generalization``: the thesis' Table 3.1 (vertices and polygons before and after
generalization, with the reduction), measured on the real extracts at three thresholds each.

For each extract a database ``citylod_gen_<extract>`` is created in the cluster the pipeline uses (DATABASE_URL
when set, else the local cluster under var/pg), migrated, and filled by ``python -m etl ingest`` and ``lod`` as
child processes, exactly as ``make`` (and benchmarks/bench.py, whose helpers this reuses) runs them. Then, all
streamed in batches from server-side cursors:

* footprints: the building outlines (osm.building.geom_local, ``parent_id IS NULL``)
    - *simplified* by etl.generalize.simplify.simplify_footprints at each tolerance, vertices on touching neighbours
      pinned and the area limit from settings, as the generalize stage makes gen.footprint;
    - *aggregated* as gen.block is made: the simplified outlines closer than the tolerance are clustered
      (ST_ClusterDBSCAN over the whole extract instead of per coarse tile), merged by buffer-union-unbuffer
      with mitred joins, and the merged outlines simplified again at the tolerance;
  error: the symmetric Hausdorff distance between the outlines (every ring), new against old (for a block,
  against the outline of the union of its members' original footprints);
* 3D models: the LOD2 meshes (lod.building_mesh, lod = 2) decimated by etl.generalize.decimate.decimate at each
  target reduction, with a low ``min_triangles`` so that nearly every mesh takes part and ``max_error = inf`` so
  that no result is refused for its error; the error is the measured surface Hausdorff distance.

Writes ``generalization.md``, ``generalization.json`` and ``generalization.png`` into ``--out``. Progress goes to
stderr; the children's output to <out>/logs/<extract>/. When a far view fidelity run (make bench, or
``python -m benchmarks.fidelity_bench``) left its results under build/bench/fidelity/, the report also carries
them: per extract and camera the IoU and drawn-area ratio, and the masks side by side (streamed | full detail |
difference), copied to <out>/fidelity/<extract>/.
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import sys
import time
from collections import Counter
from collections.abc import Iterable, Sequence
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import psycopg
import shapely

from benchmarks.common import (
    OUT_ROOT,
    SHARED_OSM,
    drop_db,
    extract_name,
    machine,
    machine_section,
    markdown_table,
    recreate_db,
    run_child,
)
from core import cluster
from core.settings import REPO, Settings
from core.wkb import decode_triangles
from etl.fetch import DEMO_OSM
from etl.generalize.decimate import decimate
from etl.generalize.hausdorff import hausdorff
from etl.generalize.simplify import PIN_DISTANCE, simplify_footprints
from etl.geom.check import weld as weld_rows

EXTRACTS = {
    "munich": SHARED_OSM / "munich_altstadt.osm.pbf",
    "london": SHARED_OSM / "london_city.osm.pbf",
    "liechtenstein": SHARED_OSM / "liechtenstein_2022-07-24.osm.pbf",
    "malta": SHARED_OSM / "malta_2018-08-27.osm.pbf",
    "helsinki": DEMO_OSM,
}
DEFAULT_EXTRACTS = ("munich", "london", "liechtenstein")
DEFAULT_OUT = Path("build/reports")
DB_PREFIX = "citylod_gen_"
#: where benchmarks/fidelity_bench.py leaves <extract>/fidelity.json and its side-by-side pictures
FIDELITY_DIR = OUT_ROOT / "fidelity"

#: Footprint tolerances (m): simplification tolerance, and aggregation distance for the blocks.
TOLERANCES_M = (1.0, 2.5, 5.0)
#: Decimation target reductions (share of the triangles to remove, over each batch).
REDUCTIONS = (0.25, 0.5, 0.75)
#: Meshes with fewer triangles are left alone by decimate(); 8 takes in the 12-triangle boxes.
MIN_TRIANGLES = 8
BATCH = 2000
#: Hausdorff distances are measured within this much (m) below the truth (etl.generalize.hausdorff): outlines ...
SPACING_FOOTPRINT_M = 0.05
#: ... and meshes (whose decimation errors are metres; this halves the measuring time).
SPACING_MESH_M = 0.1
#: Welding grid (m) when counting the distinct vertices of a mesh.
WELD_M = 1e-3

KIND_SIMPLIFIED = "footprints simplified"
KIND_AGGREGATED = "footprints aggregated"
KIND_DECIMATED = "LOD2 decimated"
KINDS = (KIND_SIMPLIFIED, KIND_AGGREGATED, KIND_DECIMATED)


def log(msg: str) -> None:
    print(f"[report-generalization {time.strftime('%H:%M:%S')}] {msg}", file=sys.stderr, flush=True)


# --- pure helpers (tested in tests/unit/test_bench_report_generalization.py) ----------------------------------------


def reduction_pct(before: float, after: float) -> float:
    """Share removed, in percent (0 when there was nothing)."""
    return 100.0 * (before - after) / before if before else 0.0


def distinct_vertices(tri: np.ndarray, owner: np.ndarray, n: int, weld: float = WELD_M) -> np.ndarray:
    """(n,) distinct vertices of each owner's triangles, corners closer than ``weld`` on a grid relative to the
    owner's first corner counted once."""
    p = np.asarray(tri, dtype=np.float64).reshape(-1, 3)
    po = np.repeat(np.asarray(owner, dtype=np.int64).reshape(-1), 3)
    if not len(p):
        return np.zeros(n, dtype=np.int64)
    order = np.argsort(po, kind="stable")
    p, po = p[order], po[order]
    first = np.unique(po, return_index=True)
    origin = np.zeros((n, 3))
    origin[first[0]] = p[first[1]]
    _, first = weld_rows(np.rint((p - origin[po]) / weld).astype(np.int64), po)
    return np.bincount(po[first], minlength=n)


def outline_walls(geoms: np.ndarray, height: float = 1.0) -> tuple[np.ndarray, np.ndarray]:
    """Every ring edge of each (Multi)Polygon as a vertical wall of two triangles from z = 0 to ``height``:
    (m, 3, 3) triangles and their owner (index into geoms). The surface Hausdorff distance between two such wall
    sets of the same height is the 2D Hausdorff distance between the outlines (the nearest point of a wall to a
    point of the other lies at the same height)."""
    geoms = np.asarray(geoms, dtype=object)
    polys, poly_owner = shapely.get_parts(geoms, return_index=True)
    rings, ring_poly = shapely.get_rings(polys, return_index=True)
    xy, xy_ring = shapely.get_coordinates(rings, return_index=True)
    if len(xy) < 2:
        return np.zeros((0, 3, 3)), np.zeros(0, dtype=np.int64)
    seg = np.flatnonzero(xy_ring[:-1] == xy_ring[1:])  # ring coordinates are closed: consecutive pairs
    a, b = xy[seg], xy[seg + 1]
    keep = np.any(a != b, axis=1)
    a, b, own = a[keep], b[keep], poly_owner[ring_poly[xy_ring[seg[keep]]]]
    z0, z1 = np.zeros((len(a), 1)), np.full((len(a), 1), height)
    a0, b0, a1, b1 = np.hstack([a, z0]), np.hstack([b, z0]), np.hstack([a, z1]), np.hstack([b, z1])
    tri = np.concatenate([np.stack([a0, b0, b1], axis=1), np.stack([a0, b1, a1], axis=1)])
    return tri, np.concatenate([own, own]).astype(np.int64)


def outline_hausdorff(a: np.ndarray, b: np.ndarray, spacing: float = SPACING_FOOTPRINT_M) -> np.ndarray:
    """(n,) symmetric Hausdorff distance (m) between the outlines (all rings) of a[i] and b[i], within ``spacing``
    below the truth; NaN where either is empty."""
    ta, oa = outline_walls(a)
    tb, ob = outline_walls(b)
    return hausdorff(ta, oa, tb, ob, len(a), spacing)


# --- accumulating one table row -------------------------------------------------------------------------------


@dataclass
class Row:
    """One line of the table: one kind of generalization at one threshold, over a whole extract."""

    kind: str
    threshold: float
    unit: str  # 'm' (tolerance) or 'target' (share of triangles to remove)
    features_in: int = 0  # footprints / meshes in
    features_out: int = 0  # footprints / blocks / meshes out
    changed: int = 0  # output features that differ from their input (the error statistics are over these)
    vertices_before: int = 0
    vertices_after: int = 0
    polygons_before: int = 0  # polygons of the footprints, triangles of the meshes
    polygons_after: int = 0
    max_error_m: float = 0.0
    sum_error_m: float = 0.0
    status: Counter = field(default_factory=Counter)
    batches: int = 0  # decimation batches (LOD2 only)
    over_threshold: int = 0  # simplified outlines measured farther than the tolerance from the original ...
    over_threshold_holes: int = 0  # ... of which had a hole below tolerance² dropped (simplified only)

    def add(
        self,
        *,
        features_in: int,
        features_out: int,
        vertices_before: int,
        vertices_after: int,
        polygons_before: int,
        polygons_after: int,
        errors: np.ndarray,
        status: Iterable[str],
    ) -> None:
        self.features_in += features_in
        self.features_out += features_out
        self.vertices_before += vertices_before
        self.vertices_after += vertices_after
        self.polygons_before += polygons_before
        self.polygons_after += polygons_after
        errors = np.asarray(errors, dtype=np.float64)
        self.changed += len(errors)
        if len(errors):
            self.max_error_m = max(self.max_error_m, float(errors.max()))
            self.sum_error_m += float(errors.sum())
        self.status.update(status)

    @property
    def mean_error_m(self) -> float:
        return self.sum_error_m / self.changed if self.changed else 0.0

    def as_dict(self) -> dict[str, Any]:
        d = asdict(self)
        d.pop("sum_error_m")
        d["status"] = dict(sorted(self.status.items(), key=lambda kv: -kv[1]))
        d["mean_error_m"] = self.mean_error_m
        d["vertex_reduction_pct"] = reduction_pct(self.vertices_before, self.vertices_after)
        d["polygon_reduction_pct"] = reduction_pct(self.polygons_before, self.polygons_after)
        return d


def _status_key(s: str) -> str:
    """Statuses without their per-feature numbers, so they can be counted."""
    s = str(s)
    if s.startswith("kept_original: area changed"):
        return "kept_original: area changed beyond the limit"
    if s.startswith("kept_original: invalid result"):
        return "kept_original: invalid result"
    if "; dropped" in s:
        return s.split(";")[0] + " (holes dropped)"
    return s


# --- footprints ------------------------------------------------------------------------------------------------

_OUTLINES = """
SELECT o.id, ST_AsBinary(o.geom_local), ST_AsBinary(nb.fixed)
FROM osm.building o
LEFT JOIN LATERAL (
    SELECT ST_Collect(ST_Boundary(n.geom_local)) AS fixed
    FROM osm.building n
    WHERE %(pin)s AND n.geom_local && ST_Expand(o.geom_local, %(d)s) AND n.id <> o.id AND n.parent_id IS NULL
      AND ST_DWithin(n.geom_local, o.geom_local, %(d)s)
) nb ON true
WHERE o.parent_id IS NULL
ORDER BY o.id
"""
# gen.block's aggregation (sql/gen/block_clusters.sql) over the whole extract: the simplified outlines
# closer than the tolerance clustered and merged by buffer-union-unbuffer with mitred joins; protected
# buildings (landmarks) are never merged, and a lone building keeps its simplified outline. Returned with what
# the block replaces: its members' vertex and polygon counts and the union of their original outlines.
_AGGREGATE = """
WITH f AS (
    SELECT s.id, s.geom, s.n_vertices, s.n_polygons, o.protected
    FROM _simplified s JOIN osm.building o ON o.id = s.id
    WHERE s.k = %(k)s
), c AS (
    SELECT id, geom, n_vertices, n_polygons,
           ST_ClusterDBSCAN(geom, eps := %(d)s, minpoints := 1) OVER ()::bigint AS cid
    FROM f WHERE NOT protected
    UNION ALL
    SELECT id, geom, n_vertices, n_polygons, -row_number() OVER () FROM f WHERE protected
)
SELECT count(*), sum(c.n_vertices), sum(c.n_polygons),
       ST_AsBinary(CASE WHEN count(*) = 1 THEN ST_Multi((array_agg(c.geom))[1])
                   ELSE ST_Multi(ST_CollectionExtract(ST_MakeValid(ST_Buffer(
                            ST_Union(ST_Buffer(c.geom, %(d)s / 2, 'join=mitre mitre_limit=3')),
                            -%(d)s / 2, 'join=mitre mitre_limit=3')), 3)) END),
       ST_AsBinary(ST_Union(o.geom_local))
FROM c JOIN osm.building o ON o.id = c.id
GROUP BY c.cid
ORDER BY min(c.id)
"""


def _parts(geoms: np.ndarray) -> np.ndarray:
    g = np.asarray(geoms, dtype=object)
    return np.where(shapely.is_empty(g), 0, shapely.get_num_geometries(g))


def measure_footprints(url: str, settings: Settings, tolerances: Sequence[float], pin: bool) -> list[Row]:
    simplified = [Row(KIND_SIMPLIFIED, t, "m") for t in tolerances]
    aggregated = [Row(KIND_AGGREGATED, t, "m") for t in tolerances]
    with psycopg.connect(url) as reader, psycopg.connect(url) as work:
        reader.execute("SET cursor_tuple_fraction = 1.0")
        work.execute("SET cursor_tuple_fraction = 1.0")
        work.execute(
            "CREATE TEMP TABLE _simplified (k smallint, id bigint, geom geometry, n_vertices integer,"
            " n_polygons integer)"
        )
        done = 0
        with reader.cursor(name="report_outlines") as src, work.cursor() as cur:
            src.itersize = BATCH
            src.execute(_OUTLINES, {"pin": pin, "d": PIN_DISTANCE})
            while rows := src.fetchmany(BATCH):
                ids = [int(r[0]) for r in rows]
                geoms = shapely.from_wkb([r[1] for r in rows])
                fixed = np.array([shapely.from_wkb(r[2]) if r[2] is not None else None for r in rows], dtype=object)
                parts_in = _parts(geoms)
                for k, t in enumerate(tolerances):
                    s = simplify_footprints(geoms, t, max_area_change=settings.gen_max_area_change, fixed=fixed)
                    ch = np.flatnonzero(s.status.astype(str) != "unchanged")
                    ch = ch[~np.array([str(x).startswith("kept_original") for x in s.status[ch]], dtype=bool)]
                    err = np.nan_to_num(outline_hausdorff(geoms[ch], s.geoms[ch]), nan=0.0)
                    simplified[k].add(
                        features_in=len(rows),
                        features_out=len(rows),
                        vertices_before=int(s.n_vertices_in.sum()),
                        vertices_after=int(s.n_vertices_out.sum()),
                        polygons_before=int(parts_in.sum()),
                        polygons_after=int(_parts(s.geoms).sum()),
                        errors=err,
                        status=map(_status_key, s.status),
                    )
                    over = err > t
                    simplified[k].over_threshold += int(over.sum())
                    simplified[k].over_threshold_holes += sum("dropped" in str(x) for x in s.status[ch[over]])
                    # what aggregation counts "before" is the original outline: its counts go with the geometry
                    ewkb = shapely.to_wkb(s.geoms, hex=True, include_srid=False)
                    with cur.copy("COPY _simplified (k, id, geom, n_vertices, n_polygons) FROM STDIN") as copy:
                        for row in zip(
                            [k] * len(rows), ids, ewkb, s.n_vertices_in.tolist(), parts_in.tolist(), strict=True
                        ):
                            copy.write_row(row)
                done += len(rows)
        log(f"  footprints simplified: {done:,} outlines x {len(tolerances)} tolerances")
        work.commit()
        for k, t in enumerate(tolerances):
            with work.cursor(name=f"report_blocks_{k}") as src:
                src.itersize = BATCH
                src.execute(_AGGREGATE, {"k": k, "d": t})
                while rows := src.fetchmany(BATCH):
                    merged = shapely.from_wkb([r[3] for r in rows])
                    members = shapely.from_wkb([r[4] for r in rows])
                    s = simplify_footprints(merged, t, max_area_change=settings.gen_max_area_change)
                    n_members = np.array([int(r[0]) for r in rows])
                    err = np.nan_to_num(outline_hausdorff(members, s.geoms), nan=0.0)
                    status = np.where(n_members > 1, "merged", "alone")
                    aggregated[k].add(
                        features_in=int(n_members.sum()),
                        features_out=len(rows),
                        vertices_before=sum(int(r[1]) for r in rows),
                        vertices_after=int(s.n_vertices_out.sum()),
                        polygons_before=sum(int(r[2]) for r in rows),
                        polygons_after=int(_parts(s.geoms).sum()),
                        errors=err[err > 0],
                        status=status.tolist(),
                    )
            log(
                f"  footprints aggregated at {t:g} m: {aggregated[k].features_in:,} outlines -> "
                f"{aggregated[k].features_out:,} blocks"
            )
        work.rollback()
    return [r for pair in zip(simplified, aggregated, strict=True) for r in pair]


# --- 3D models -------------------------------------------------------------------------------------------------

_MESHES = "SELECT building_id, ST_AsBinary(geom) FROM lod.building_mesh WHERE lod = 2 ORDER BY building_id"


def measure_meshes(url: str, reductions: Sequence[float], min_triangles: int) -> list[Row]:
    rows_out = [Row(KIND_DECIMATED, r, "target") for r in reductions]
    done = 0
    with psycopg.connect(url) as reader, reader.cursor(name="report_meshes") as src:
        src.itersize = BATCH
        src.execute(_MESHES)
        while rows := src.fetchmany(BATCH):
            tris = [decode_triangles(r[1]) for r in rows]
            n = len(tris)
            counts = np.array([len(t) for t in tris], dtype=np.int64)
            tri = np.concatenate(tris)
            own = np.repeat(np.arange(n), counts)
            v_in = distinct_vertices(tri, own, n)
            for k, r in enumerate(reductions):
                d = decimate(tri, own, n, r, min_triangles=min_triangles, max_error=np.inf, spacing=SPACING_MESH_M)
                out_tri, out_own, decimated, error = d.triangles, d.owner, d.decimated, d.error
                status = [str(x) for x in d.status]
                c_out = np.bincount(out_own, minlength=n)
                v_out = distinct_vertices(out_tri, out_own, n)
                rows_out[k].add(
                    features_in=n,
                    features_out=n,
                    vertices_before=int(v_in.sum()),
                    vertices_after=int(v_out.sum()),
                    polygons_before=int(counts.sum()),
                    polygons_after=int(c_out.sum()),
                    errors=error[decimated],
                    status=status,
                )
                rows_out[k].batches += 1
            done += n
            log(f"  LOD2 meshes decimated: {done:,}")
    return rows_out


# --- one extract -----------------------------------------------------------------------------------------------


@dataclass
class ExtractReport:
    key: str
    name: str
    path: str
    outlines: int = 0
    meshes: int = 0
    build_s: float = 0.0
    footprints_s: float = 0.0
    meshes_s: float = 0.0
    rows: list[Row] = field(default_factory=list)

    def as_dict(self) -> dict[str, Any]:
        return {
            "key": self.key,
            "name": self.name,
            "path": self.path,
            "outlines": self.outlines,
            "meshes": self.meshes,
            "seconds": {
                "build": round(self.build_s, 2),
                "footprints": round(self.footprints_s, 2),
                "meshes": round(self.meshes_s, 2),
            },
            "rows": [r.as_dict() for r in self.rows],
        }


def _db_ready(admin_url: str, name: str) -> bool:
    with psycopg.connect(admin_url, autocommit=True) as conn:
        if conn.execute("SELECT 1 FROM pg_database WHERE datname = %s", (name,)).fetchone() is None:
            return False
    try:
        with psycopg.connect(cluster.database_url(name)) as conn:
            row = conn.execute("SELECT EXISTS (SELECT 1 FROM lod.building_mesh WHERE lod = 2)").fetchone()
    except psycopg.Error:
        return False
    return bool(row and row[0])


def build_db(key: str, path: Path, admin_url: str, logs: Path, reuse: bool) -> tuple[str, float]:
    """A database with ``path`` ingested and run through lod; returns its URL and the seconds it took."""
    name = DB_PREFIX + key
    url = cluster.database_url(name)
    if reuse and _db_ready(admin_url, name):
        log(f"{key}: reusing {name}")
        return url, 0.0
    t0 = time.perf_counter()
    env = {**os.environ, "DATABASE_URL": url}
    log(f"{key}: fresh database {name}, migrate, ingest, lod")
    recreate_db(admin_url, name)
    run_child([sys.executable, "-m", "etl", "migrate"], env, logs / "migrate.log")
    run_child([sys.executable, "-m", "etl", "ingest", "--osm", str(path)], env, logs / "ingest.log")
    run_child([sys.executable, "-m", "etl", "lod"], env, logs / "lod.log")
    return url, time.perf_counter() - t0


def report_extract(
    key: str, path: Path, admin_url: str, out: Path, settings: Settings, pin: bool, reuse: bool
) -> ExtractReport:
    rep = ExtractReport(key=key, name=extract_name(path), path=str(path))
    url, rep.build_s = build_db(key, path, admin_url, out / "logs" / key, reuse)
    with psycopg.connect(url) as conn:
        rep.outlines = conn.execute("SELECT count(*) FROM osm.building WHERE parent_id IS NULL").fetchone()[0]  # type: ignore[index]
        rep.meshes = conn.execute("SELECT count(*) FROM lod.building_mesh WHERE lod = 2").fetchone()[0]  # type: ignore[index]
    log(f"{key}: {rep.outlines:,} outlines, {rep.meshes:,} LOD2 meshes")
    t0 = time.perf_counter()
    rows = measure_footprints(url, settings, TOLERANCES_M, pin)
    rep.footprints_s = time.perf_counter() - t0
    t0 = time.perf_counter()
    rows += measure_meshes(url, REDUCTIONS, MIN_TRIANGLES)
    rep.meshes_s = time.perf_counter() - t0
    rep.rows = rows
    log(f"{key}: footprints {rep.footprints_s:.1f} s, meshes {rep.meshes_s:.1f} s")
    return rep


# --- report ----------------------------------------------------------------------------------------------------


def threshold_label(row: dict[str, Any]) -> str:
    return f"{row['threshold']:g} m" if row["unit"] == "m" else f"{row['threshold']:.0%} of triangles"


def _f(x: float, digits: int = 2) -> str:
    return f"{x:.{digits}f}"


def render_markdown(report: dict[str, Any]) -> str:
    """generalization.md from the generalization.json structure."""
    p = report["parameters"]
    lines = [
        "# Generalization: the thesis' Table 3.1, measured",
        "",
        "Generated by `make report-generalization`, i.e.",
        "",
        "```bash",
        report["command"],
        "```",
        "",
        "Regenerated in full on every run; do not edit by hand. The numbers are also in `generalization.json`, "
        "the curves in `generalization.png`. Code: `benchmarks/report_generalization.py`.",
        "",
        "## What is measured",
        "",
        "The thesis (section 3.3, Table 3.1) compares vertex and polygon numbers of footprints and 3D models "
        "before and after generalization, with the reduction, at different thresholds. Here, on each extract "
        "after `python -m etl ingest` and `lod`:",
        "",
        f"* **footprints simplified**: every building outline (`osm.building`, `parent_id IS NULL`) simplified by "
        f"`simplify_footprints` (Sester–Brenner short edges, then vertex importance) at tolerances "
        f"{', '.join(f'{t:g}' for t in p['tolerances_m'])} m, as the generalize stage makes `gen.footprint`: "
        f"vertices on touching neighbours {'pinned' if p['pin'] else 'NOT pinned (--no-pin)'}, results changing the "
        f"area by more than {p['max_area_change']:.0%} kept as they were. *Polygons* are the polygons of the "
        "outlines (a multipolygon outline counts each part), so simplification leaves them as they are.",
        "* **footprints aggregated**: as `gen.block` is made, at the same thresholds used as aggregation distance "
        "and tolerance: the simplified outlines closer than the threshold clustered (`ST_ClusterDBSCAN`, over the "
        "whole extract rather than per coarse tile), merged by buffer-union-unbuffer with mitred joins, and the "
        "merged outlines simplified again at the threshold. *Before* is the original outlines, *after* the blocks.",
        f"* **LOD2 decimated**: every LOD2 mesh (`lod.building_mesh`, lod = 2; buildings and parts) decimated by "
        f"`decimate` (fast-simplification quadric edge collapse, batches of {p['batch']:,} meshes, the target "
        f"reduction spent over each batch where it costs least) at target reductions "
        f"{', '.join(f'{r:.0%}' for r in p['reductions'])}, min_triangles = {p['min_triangles']}, max_error = inf "
        "(no result refused for its error; one that is not closed or is inside out is still refused and the "
        f"mesh kept). *Vertices* are distinct corners per mesh (welded at {p['weld_m'] * 1000:g} mm), *polygons* "
        "are triangles.",
        "",
        "*changed / features*: output features (outlines, blocks, meshes) and how many of them differ from what "
        "they replace; the Hausdorff columns are the largest and the mean over the changed ones. Errors are "
        "symmetric Hausdorff distances measured by `etl/generalize/hausdorff.py`, never above the truth and at most "
        f"{p['spacing_footprint_m']:g} m (footprints) / {p['spacing_mesh_m']:g} m (meshes) below it: for "
        "footprints between the outlines (every ring), a block against the outline of the union of its members' "
        "original outlines; for LOD2 between the mesh surfaces. Reduction = (before − after) / before.",
        "",
        "How to read it:",
        "",
        "* A simplified outline stays within the tolerance except where `simplify_footprints` dropped a hole "
        "smaller than tolerance²: the hole's full distance to the rest of the outline then counts.",
        "* A block's outline error counts the walls that vanished inside it (the facing walls of merged "
        "neighbours, across alleys and courtyards), so it is about half the depth of the merged buildings, "
        "not the aggregation distance: that is what disappears from view. By construction the merged ground plan "
        "lies within half the aggregation distance of its members (the closing buffers by that much; mitred "
        "corners a little more) before its final simplification.",
        "* Decimation spends the target over a whole batch where it costs least, so many meshes lose nothing and "
        "others collapse; with max_error = inf the error of a decimated mesh is only measured, never limited. A "
        "mesh that collapses to nothing, or comes out open or inside out, keeps its original (listed under each "
        "table).",
        "",
    ]
    for ex in report["extracts"]:
        s = ex["seconds"]
        lines += [
            f"## {ex['name']}",
            "",
            f"{ex['outlines']:,} outlines, {ex['meshes']:,} LOD2 meshes. "
            + (f"Database built in {s['build']:.1f} s; " if s["build"] else "Database reused; ")
            + f"measured in {s['footprints']:.1f} s (footprints) + {s['meshes']:.1f} s (meshes).",
            "",
        ]
        rows = []
        for r in ex["rows"]:
            rows.append(
                [
                    r["kind"],
                    threshold_label(r),
                    f"{r['changed']:,} / {r['features_out']:,}",
                    f"{r['vertices_before']:,}",
                    f"{r['vertices_after']:,}",
                    f"{r['vertex_reduction_pct']:.1f} %",
                    f"{r['polygons_before']:,}",
                    f"{r['polygons_after']:,}",
                    f"{r['polygon_reduction_pct']:.1f} %",
                    _f(r["max_error_m"]),
                    _f(r["mean_error_m"], 3),
                ]
            )
        header = [
            "generalization",
            "threshold",
            "changed / features",
            "vertices before",
            "vertices after",
            "vertex reduction",
            "polygons before",
            "polygons after",
            "polygon reduction",
            "max Hausdorff m",
            "mean Hausdorff m",
        ]
        lines += markdown_table(header, rows, "llrrrrrrrrr")
        lines += [""]
        notes = _status_notes(ex)
        if notes:
            lines += notes + [""]
    lines += fidelity_lines(report.get("fidelity") or [])
    lines += machine_section(report["machine"])
    lines += [
        "",
        f"Total run time {report['seconds']:.0f} s.",
        "",
        "![reduction and error against threshold](generalization.png)",
        "",
    ]
    return "\n".join(lines)


def _status_notes(ex: dict[str, Any]) -> list[str]:
    """One line per row whose features were not all generalized as asked: why they were kept."""
    out = []
    for r in ex["rows"]:
        if r["kind"] == KIND_AGGREGATED:
            continue
        kept = {
            k: v
            for k, v in r["status"].items()
            if k not in ("simplified", "simplified (holes dropped)", "decimated", "unchanged")
        }
        if kept:
            why = ", ".join(f"{v:,} {k}" for k, v in kept.items())
            out.append(f"* {r['kind']} at {threshold_label(r)}: {why}.")
        n, holes = r.get("over_threshold", 0), r.get("over_threshold_holes", 0)
        if r["kind"] == KIND_SIMPLIFIED and n:
            out.append(
                f"* {r['kind']} at {threshold_label(r)}: {n:,} outline{'s' if n != 1 else ''} measured "
                f"farther than the tolerance from the original, {holes:,} of them where a hole below "
                "tolerance² was dropped."
            )
    return out


def collect_fidelity(src: Path, out: Path) -> list[dict[str, Any]]:
    """The far view fidelity runs under ``src`` (<extract>/fidelity.json, written by benchmarks/fidelity_bench.py),
    their side-by-side pictures copied to <out>/fidelity/<extract>/: per extract its cameras with IoU, drawn-area
    ratio, triangles of both passes and the picture's path relative to ``out`` (None when missing)."""
    found = []
    for f in sorted(src.glob("*/fidelity.json")):
        try:
            res = json.loads(f.read_text())
        except (OSError, ValueError):
            continue
        cams = {c.get("name"): c for c in res.get("cameras", [])}
        rows = []
        for name, v in (res.get("views") or {}).items():
            m = v.get("masks") or {}
            passes = v.get("passes") or {}
            pic = Path(v["side_by_side"]) if v.get("side_by_side") else None
            rel = None
            if pic is not None and pic.is_file():
                dest = out / "fidelity" / f.parent.name / pic.name
                dest.parent.mkdir(parents=True, exist_ok=True)
                shutil.copyfile(pic, dest)
                rel = str(dest.relative_to(out))
            rows.append(
                {
                    "camera": name,
                    "height": cams.get(name, {}).get("height"),
                    "pitch": cams.get(name, {}).get("pitch"),
                    "iou": m.get("iou"),
                    "area_ratio": m.get("area_ratio"),
                    "error": v.get("error") or m.get("error"),
                    "triangles": [passes.get(p, {}).get("trianglesSelected") for p in ("streamed", "full")],
                    "picture": rel,
                }
            )
        found.append({"name": res.get("name", f.parent.name), "cameras": rows, "error": res.get("error")})
    return found


def fidelity_lines(fidelity: Sequence[dict[str, Any]]) -> list[str]:
    """The report's far view fidelity section (see collect_fidelity); nothing when no run was found."""
    if not fidelity:
        return []
    out = [
        "## Far view fidelity",
        "",
        "From the last far view fidelity run (make bench or `python -m benchmarks.fidelity_bench`, "
        "`benchmarks/fidelity_bench.py`): CesiumJS draws the export as a building mask at cameras far to "
        "near, once as a client streams it (maximumScreenSpaceError 16) and once at full detail; *IoU* = "
        "building pixels in both / in either, *area* = streamed / full. Pictures: streamed | full detail | "
        "difference (red: only at full detail, cyan: only streamed). Target (issue 18): IoU ≥ 0.90.",
        "",
    ]
    for ex in fidelity:
        out += [f"### {ex['name']}", ""]
        if ex.get("error") and not ex["cameras"]:
            out += [f"failed: {ex['error']}", ""]
            continue
        rows = []
        for c in ex["cameras"]:
            where = "–" if c["height"] is None else f"{c['height']:,.0f} m, {c['pitch']:.0f}°"
            if c["iou"] is None:
                rows.append([c["camera"], where, f"failed: {c['error'] or 'not measured'}", "–", "–"])
                continue
            tri = " / ".join("–" if t is None else f"{t:,}" for t in c["triangles"])
            rows.append(
                [
                    c["camera"],
                    where,
                    f"{c['iou']:.3f}",
                    "–" if c["area_ratio"] is None else f"{c['area_ratio']:.3f}",
                    tri,
                ]
            )
        out += markdown_table(["camera", "height, pitch", "IoU", "area", "triangles streamed / full"], rows, "llrrr")
        out += [""]
        out += [
            f"{c['camera']}:\n\n![{ex['name']} {c['camera']}]({c['picture']})\n" for c in ex["cameras"] if c["picture"]
        ]
    return out


def plot(report: dict[str, Any], path: Path) -> None:
    """generalization.png: reduction (top) and error (bottom) against threshold, footprints left, LOD2 right."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.lines import Line2D

    fig, ax = plt.subplots(2, 2, figsize=(15, 9.5), layout="constrained")
    colours = plt.rcParams["axes.prop_cycle"].by_key()["color"]
    style = {KIND_SIMPLIFIED: "-", KIND_AGGREGATED: "--"}
    for i, ex in enumerate(report["extracts"]):
        c = colours[i % len(colours)]
        by_kind: dict[str, list[dict[str, Any]]] = {}
        for r in ex["rows"]:
            by_kind.setdefault(r["kind"], []).append(r)
        for kind, rows in by_kind.items():
            x = [r["threshold"] if r["unit"] == "m" else 100 * r["threshold"] for r in rows]
            vr = [r["vertex_reduction_pct"] for r in rows]
            pr = [r["polygon_reduction_pct"] for r in rows]
            mx = [r["max_error_m"] for r in rows]
            mean = [r["mean_error_m"] for r in rows]
            if kind == KIND_DECIMATED:
                ax[0, 1].plot(x, vr, "-o", color=c)
                ax[0, 1].plot(x, pr, ":s", color=c)
                ax[1, 1].plot(x, mx, "-o", color=c)
                ax[1, 1].plot(x, mean, ":s", color=c)
            else:
                ax[0, 0].plot(x, vr, style[kind] + "o", color=c)
                if kind == KIND_AGGREGATED:
                    ax[0, 0].plot(x, pr, ":s", color=c)
                ax[1, 0].plot(x, mx, style[kind] + "o", color=c)
                ax[1, 0].plot(x, mean, style[kind], color=c, alpha=0.45, marker="s", markersize=4)
    tol = report["parameters"]["tolerances_m"]
    ax[1, 0].plot(tol, tol, color="grey", lw=0.8, ls="-.")
    ax[0, 0].set(
        title="Footprints: reduction", xlabel="tolerance / aggregation distance (m)", ylabel="reduction (%)", xticks=tol
    )
    ax[0, 1].set(
        title="LOD2 meshes: reduction",
        xlabel="decimation target (% of triangles)",
        ylabel="reduction (%)",
        xticks=[100 * r for r in report["parameters"]["reductions"]],
    )
    ax[1, 0].set(
        title="Footprints: Hausdorff error of the changed outlines",
        xlabel="tolerance (m)",
        ylabel="Hausdorff distance (m)",
        xticks=tol,
        yscale="log",
    )
    ax[1, 1].set(
        title="LOD2 meshes: Hausdorff error of the decimated meshes",
        xlabel="decimation target (%)",
        ylabel="Hausdorff distance (m)",
        xticks=[100 * r for r in report["parameters"]["reductions"]],
        yscale="log",
    )
    for a in ax.flat:
        a.grid(True, alpha=0.3)
    names = [
        Line2D([], [], color=colours[i % len(colours)], lw=2, label=ex["name"])
        for i, ex in enumerate(report["extracts"])
    ]
    fig.legend(handles=names, loc="outside lower center", ncol=len(names), frameon=False)
    styles = {
        (0, 0): [
            Line2D([], [], color="k", ls="-", marker="o", label="simplified:\nvertices"),
            Line2D([], [], color="k", ls="--", marker="o", label="aggregated:\nvertices"),
            Line2D([], [], color="k", ls=":", marker="s", label="aggregated:\npolygons"),
        ],
        (0, 1): [
            Line2D([], [], color="k", ls="-", marker="o", label="vertices"),
            Line2D([], [], color="k", ls=":", marker="s", label="triangles"),
        ],
        (1, 0): [
            Line2D([], [], color="k", ls="-", marker="o", label="simplified:\nmax"),
            Line2D([], [], color="k", ls="--", marker="o", label="aggregated:\nmax"),
            Line2D([], [], color="k", alpha=0.45, marker="s", markersize=4, label="mean (faint,\nsame style)"),
            Line2D([], [], color="grey", ls="-.", lw=0.8, label="error =\ntolerance"),
        ],
        (1, 1): [
            Line2D([], [], color="k", ls="-", marker="o", label="max"),
            Line2D([], [], color="k", ls=":", marker="s", label="mean"),
        ],
    }
    for (i, j), handles in styles.items():
        ax[i, j].legend(handles=handles, fontsize=8, handlelength=3.5, loc="center left", bbox_to_anchor=(1.01, 0.5))
    fig.suptitle("citylod generalization (thesis Table 3.1, measured)", fontsize=14)
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=110)
    plt.close(fig)


# --- main ------------------------------------------------------------------------------------------------------


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="python -m benchmarks.report_generalization", description=__doc__.split("\n\n")[0])
    p.add_argument(
        "--extracts",
        default=",".join(DEFAULT_EXTRACTS),
        help=f"comma-separated, of {', '.join(EXTRACTS)} (default: {','.join(DEFAULT_EXTRACTS)})",
    )
    p.add_argument("--out", type=Path, default=DEFAULT_OUT, help=f"output directory (default: {DEFAULT_OUT})")
    p.add_argument("--keep", action="store_true", help=f"keep the {DB_PREFIX}<extract> databases afterwards")
    p.add_argument(
        "--reuse",
        action="store_true",
        help="use a kept database as it is instead of building it again (implies --keep)",
    )
    p.add_argument(
        "--no-pin", action="store_true", help="simplify footprints without pinning vertices on touching neighbours"
    )
    args = p.parse_args(argv)
    keys = [k.strip() for k in args.extracts.split(",") if k.strip()]
    unknown = [k for k in keys if k not in EXTRACTS]
    if unknown or not keys:
        p.error(f"unknown extract(s) {', '.join(unknown) or '(none given)'}; choose from {', '.join(EXTRACTS)}")
    missing = [str(EXTRACTS[k]) for k in keys if not EXTRACTS[k].exists()]
    if missing:
        p.error("missing input: " + ", ".join(missing))
    keep = args.keep or args.reuse
    out: Path = REPO / args.out  # an absolute --out stays as it is
    out.mkdir(parents=True, exist_ok=True)

    cluster.ensure()
    admin_url = cluster.database_url("postgres")
    settings = Settings.from_env()
    command = f"python -m benchmarks.report_generalization --extracts {','.join(keys)} --out {args.out}"
    for flag in ("no_pin", "keep", "reuse"):
        if getattr(args, flag):
            command += " --" + flag.replace("_", "-")
    t0 = time.perf_counter()
    reports: list[ExtractReport] = []
    mach: dict[str, str] = {}
    try:
        for k in keys:
            reports.append(report_extract(k, EXTRACTS[k], admin_url, out, settings, not args.no_pin, args.reuse))
            if not mach:
                mach = machine(cluster.database_url(DB_PREFIX + k), osm2pgsql=False)
    finally:
        if not keep:
            for k in keys:
                drop_db(admin_url, DB_PREFIX + k)
            log(f"dropped the {DB_PREFIX}* databases (use --keep to keep them)")

    report = {
        "command": command,
        "machine": mach,
        "parameters": {
            "tolerances_m": list(TOLERANCES_M),
            "reductions": list(REDUCTIONS),
            "min_triangles": MIN_TRIANGLES,
            "batch": BATCH,
            "spacing_footprint_m": SPACING_FOOTPRINT_M,
            "spacing_mesh_m": SPACING_MESH_M,
            "weld_m": WELD_M,
            "pin": not args.no_pin,
            "max_area_change": settings.gen_max_area_change,
        },
        "extracts": [r.as_dict() for r in reports],
        "fidelity": collect_fidelity(FIDELITY_DIR, out),
        "seconds": round(time.perf_counter() - t0, 1),
    }
    (out / "generalization.json").write_text(json.dumps(report, indent=1) + "\n")
    plot(report, out / "generalization.png")
    (out / "generalization.md").write_text(render_markdown(report))
    log(f"wrote {out}/generalization.md, .json, .png in {report['seconds']:.0f} s")
    return 0


if __name__ == "__main__":
    sys.exit(main())
