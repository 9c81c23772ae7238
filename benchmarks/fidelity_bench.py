"""``python -m benchmarks.fidelity_bench``: how much of the city a streaming client draws, far to near (issue 18).

A tileset is served (``python -m exporter serve``) to the citylod viewer in headless Chromium
(benchmarks/fidelity_view.mjs) and drawn as a *building mask* (every building fragment white and unlit, the rest
black) at a set of cameras, twice each: *streamed* (maximumScreenSpaceError 16, the plain traversal a client
uses) and *full* (maximumScreenSpaceError 0: every tile refines to its leaves, the city at full detail). Per
camera, from the two masks (numpy):

* **IoU**: building pixels drawn in both / in either;
* **drawn-area ratio**: building pixels streamed / building pixels at full detail (below 1: holes; above: blocks
  wider than what they stand for);

with the triangles and the tiles of each pass (CesiumJS's tileset.statistics). The cameras (``camera_set``) go
far to near, scaled to the data's extent: the overview (straight down over the whole extract, view_bench's
``overview_camera``) and, at fractions of its height above the ground (the issue's figures: 7.7 km overview,
6.7, 4.9, 2.8 and 1.8 km on a city of ~12k buildings), straight down and oblique views of where the buildings
are (the median of their centroids). The mask pairs and a side-by-side picture per camera (streamed | full |
difference: red = drawn only at full detail, cyan = drawn only when streamed) go to build/bench/fidelity/<extract>/.

Beside it, the thesis' Table 3.1 per level of the tile tree (``level_figures``): the city as drawn if the
traversal stopped at level L (the tiles of level L and the leaves above it): features, vertices and triangles,
and their reduction against full detail (every leaf); vertices counted as benchmarks/report_generalization.py
counts them (distinct corners per mesh).

Targets (issue 18), judged, never failing the bench: IoU ≥ 0.90 at every camera, and the overview's streamed
triangles ≤ 1/20 of its full-detail ones. A camera, a pass or a part that fails is recorded with its reason.
``--osm FILE`` builds a database first (a fresh ``citylod_fidelity``, ingest .. textures, then export);
``--database-url`` measures an existing one (exported again unless ``--tiles DIR`` names its export). make bench
measures the database and export it built (benchmarks/bench.py).
"""

from __future__ import annotations

import argparse
import contextlib
import json
import math
import os
import shutil
import sys
import time
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np
import psycopg

from benchmarks import stream_bench, view_bench
from benchmarks.common import (
    LOG_DIR,
    OUT_ROOT,
    build_pipeline_db,
    db_name,
    drop_db,
    extract_name,
    log,
    markdown_table,
    pass_mark,
    run_child,
)
from benchmarks.report_generalization import distinct_vertices, reduction_pct
from core import cluster
from core.camera import Camera
from core.settings import REPO
from core.wkb import decode_triangles

FIDELITY_DB = "citylod_fidelity"
DRIVER = Path(__file__).resolve().parent / "fidelity_view.mjs"
FIDELITY_ROOT = OUT_ROOT / "fidelity"
PASSES = ("streamed", "full")
EARTH_R = view_bench.EARTH_R

# issue 18's targets; the bench reports them, it never fails on them
TARGET_IOU = 0.90
TARGET_OVERVIEW_TRIANGLES = 1 / 20  # the overview's streamed triangles / its full-detail ones

#: (name, height above the ground as a share of the overview's, pitch°), far to near: the issue's cameras (7.7 km
#: straight down, then 6.7, 4.9, 2.8, 1.8 km) as shares of its overview
CAMERAS: tuple[tuple[str, float, float], ...] = (
    ("overview", 1.0, -90.0),
    ("oblique-far", 6.7 / 7.7, -35.0),
    ("down-mid", 4.9 / 7.7, -90.0),
    ("down-near", 2.8 / 7.7, -90.0),
    ("oblique-mid", 2.8 / 7.7, -40.0),
    ("oblique-low", 1.8 / 7.7, -45.0),
)
MISSED = (255, 64, 64)  # side by side: drawn at full detail only
EXTRA = (0, 200, 255)  # ... drawn only when streamed


# --- pure parts ---------------------------------------------------------------------------------------------


def mask_of(rgb: np.ndarray) -> np.ndarray:
    """(h, w) bool: the building pixels of a mask picture (any colour channel above half)."""
    a = np.asarray(rgb)
    if a.ndim != 3 or a.shape[2] < 3:
        raise ValueError(f"not an RGB(A) picture: {a.shape}")
    return (a[..., :3] > 127).any(axis=2)


def grey_share(rgb: np.ndarray) -> float:
    """Share of pixels with a colour channel neither 0 nor 255: 0 for a binary mask (anti-aliasing, lighting or
    fog would make grey pixels)."""
    c = np.asarray(rgb)[..., :3]
    return float(((c != 0) & (c != 255)).any(axis=2).mean())


def iou(a: np.ndarray, b: np.ndarray) -> float:
    """|a ∧ b| / |a ∨ b| of two boolean masks of the same shape; 1.0 when both are empty (nothing differs)."""
    if a.shape != b.shape:
        raise ValueError(f"masks of different sizes: {a.shape} vs {b.shape}")
    union = int(np.count_nonzero(a | b))
    return float(np.count_nonzero(a & b)) / union if union else 1.0


def area_ratio(streamed: np.ndarray, full: np.ndarray) -> float | None:
    """Building pixels streamed / building pixels at full detail (None when the full view has none)."""
    n = int(np.count_nonzero(full))
    return float(np.count_nonzero(streamed)) / n if n else None


def compare_masks(streamed_rgb: np.ndarray, full_rgb: np.ndarray) -> dict[str, Any]:
    """IoU, drawn-area ratio, building pixels and grey shares of a camera's two mask pictures."""
    s, f = mask_of(streamed_rgb), mask_of(full_rgb)
    return {
        "iou": round(iou(s, f), 4),
        "area_ratio": None if (r := area_ratio(s, f)) is None else round(r, 4),
        "pixels": int(s.size),
        "streamed_px": int(np.count_nonzero(s)),
        "full_px": int(np.count_nonzero(f)),
        "missed_px": int(np.count_nonzero(f & ~s)),
        "extra_px": int(np.count_nonzero(s & ~f)),
        "grey": {"streamed": grey_share(streamed_rgb), "full": grey_share(full_rgb)},
    }


def side_by_side(streamed_rgb: np.ndarray, full_rgb: np.ndarray, gap: int = 8) -> np.ndarray:
    """(h, 3w + 2·gap, 3) uint8: the streamed mask, the full-detail mask and their difference (white: both,
    red: full detail only, cyan: streamed only), on grey gaps."""
    s, f = mask_of(streamed_rgb), mask_of(full_rgb)
    h, w = s.shape
    diff = np.zeros((h, w, 3), np.uint8)
    diff[s & f] = 255
    diff[f & ~s] = MISSED
    diff[s & ~f] = EXTRA
    sep = np.full((h, gap, 3), 96, np.uint8)
    white = [np.repeat(m[..., None], 3, axis=2).astype(np.uint8) * 255 for m in (s, f)]
    return np.concatenate([white[0], sep, white[1], sep, diff], axis=1)


def camera_set(
    overview: Camera, target: tuple[float, float], ground: float, spec: Sequence[tuple[str, float, float]] = CAMERAS
) -> list[tuple[str, Camera]]:
    """The cameras of ``spec``, far to near: the first (share 1, straight down) is ``overview`` itself; the others
    are at ``share`` × the overview's height above ``ground`` (m above the ellipsoid) and look north at ``target``
    (lon, lat in degrees): straight down over it, or from the south at ``pitch`` so that it is in the middle of
    the view. The overview's field of view, viewport and aspect are kept."""
    lon, lat = target
    above = overview.height - ground
    out = []
    for name, share, pitch in spec:
        if share == 1.0 and pitch == overview.pitch:
            out.append((name, overview))
            continue
        h = share * above
        back = 0.0 if pitch <= -89.999 else h / math.tan(math.radians(-pitch))  # metres south of the target
        out.append(
            (
                name,
                Camera(
                    lon,
                    lat - math.degrees(back / EARTH_R),
                    ground + h,
                    0.0,
                    pitch,
                    overview.fov,
                    overview.viewport_height,
                    overview.aspect,
                ),
            )
        )
    return out


def level_rows(
    level: np.ndarray,
    leaf: np.ndarray,
    members: np.ndarray,
    vertices: np.ndarray,
    triangles: np.ndarray,
    tile_level: np.ndarray,
    tile_leaf: np.ndarray,
) -> list[dict[str, Any]]:
    """The city per level of the tile tree, from one row per feature of every tile's content (its tile's level
    and leaf flag, the buildings it stands for, its vertices and triangles) and one row per tile: at level L the
    tiles of level L and the leaves above it (where the traversal stopping at L draws from). The deepest level is
    full detail (every leaf); reductions are against it."""
    level, leaf = np.asarray(level), np.asarray(leaf, dtype=bool)
    tile_level, tile_leaf = np.asarray(tile_level), np.asarray(tile_leaf, dtype=bool)
    if not len(tile_level):
        return []
    rows = []
    for lv in range(int(tile_level.max()) + 1):
        f = (level == lv) | (leaf & (level < lv))
        t = (tile_level == lv) | (tile_leaf & (tile_level < lv))
        rows.append(
            {
                "level": lv,
                "tiles": int(t.sum()),
                "features": int(f.sum()),
                "members": int(np.asarray(members)[f].sum()),
                "vertices": int(np.asarray(vertices)[f].sum()),
                "triangles": int(np.asarray(triangles)[f].sum()),
            }
        )
    full = rows[-1]
    for r in rows:
        r["vertex_reduction_pct"] = round(reduction_pct(full["vertices"], r["vertices"]), 2)
        r["triangle_reduction_pct"] = round(reduction_pct(full["triangles"], r["triangles"]), 2)
    return rows


def failed(reason: str) -> dict[str, Any]:
    """A measurement that could not be made at all, as section_lines shows it."""
    return {"error": _error(RuntimeError(reason))}


def _error(e: BaseException) -> str:
    return (str(e).strip().splitlines() or [type(e).__name__])[-1][:300]


def _pass(view: dict[str, Any], name: str) -> dict[str, Any]:
    return (view.get("passes") or {}).get(name) or {}


def triangle_share(view: dict[str, Any]) -> float | None:
    """The streamed pass's triangles / the full-detail pass's."""
    s, f = _pass(view, "streamed").get("trianglesSelected"), _pass(view, "full").get("trianglesSelected")
    return s / f if s is not None and f else None


def judge(res: dict[str, Any]) -> dict[str, dict[str, bool | None]]:
    """Per camera the targets of issue 18: {"iou": IoU ≥ 0.90, "triangles": (overview only) streamed
    triangles ≤ 1/20 of full detail}; None: not measured."""
    out: dict[str, dict[str, bool | None]] = {}
    for name, v in (res.get("views") or {}).items():
        i = (v.get("masks") or {}).get("iou")
        ok: dict[str, bool | None] = {"iou": None if i is None else i >= TARGET_IOU}
        if name == "overview":
            share = triangle_share(v)
            ok["triangles"] = None if share is None else share <= TARGET_OVERVIEW_TRIANGLES
        out[name] = ok
    return out


#: the fewest triangles a building outline can be drawn with standing on its own: a 4-corner prism without its
#: floor (8 wall triangles, 2 roof)
MIN_PRISM_TRIANGLES = 10


def budget_bound(
    areas: np.ndarray,
    full_triangles: int,
    share: float = TARGET_OVERVIEW_TRIANGLES,
    per_outline: int = MIN_PRISM_TRIANGLES,
) -> dict[str, Any]:
    """The best footprint IoU any drawing of the city within ``share`` × ``full_triangles`` can reach without
    filling gaps between outlines: ``areas`` are the city's separate outlines (touching buildings unioned), each
    drawn costs at least ``per_outline`` triangles, so at most budget // per_outline of them fit; drawn exactly
    (a bound: most are not 4-corner prisms) the largest cover this share of the built area, which bounds the IoU.
    Filling gaps (one prism for several outlines) adds area the city does not cover instead (measured beside
    it: Liechtenstein's outlines closed over 10 m gaps and simplified at 3 m are at footprint IoU 0.85)."""
    a = np.sort(np.asarray(areas, dtype=np.float64))[::-1]
    budget = int(full_triangles * share)
    k = min(len(a), budget // per_outline)
    total = float(a.sum())
    return {
        "outlines": int(len(a)),
        "budget_triangles": budget,
        "outlines_in_budget": int(k),
        "min_triangles_all": int(len(a) * per_outline),
        "iou_bound": round(float(a[:k].sum()) / total, 4) if total > 0 else None,
    }


# --- measuring ----------------------------------------------------------------------------------------------


def cameras_of(url: str) -> list[tuple[str, Camera]]:
    """camera_set for a generalized database: the bench's overview camera, the median of the building
    centroids as the target, the lowest point of the root region as the ground."""
    with psycopg.connect(url) as conn:
        over = view_bench.overview_camera(conn)
        lo = conn.execute("SELECT region[5] FROM tiles.tile WHERE level = 0").fetchone()[0]  # type: ignore[index]
        lon, lat = conn.execute(
            "SELECT percentile_disc(0.5) WITHIN GROUP (ORDER BY ST_X(c)),"
            "       percentile_disc(0.5) WITHIN GROUP (ORDER BY ST_Y(c))"
            " FROM (SELECT ST_Centroid(geom) AS c FROM osm.building WHERE parent_id IS NULL) b"
        ).fetchone()  # type: ignore[misc]
    return camera_set(over, (float(lon), float(lat)), float(lo))


_LEVEL_FEATURES = """
SELECT t.level, t.is_leaf, f.n_members, ST_AsBinary(f.geom)
FROM tiles.tile t CROSS JOIN LATERAL api.buildings_for_tile(t.level, t.x, t.y) f
ORDER BY t.level, t.x, t.y
"""
BATCH = 2000


def level_figures(url: str) -> list[dict[str, Any]]:
    """level_rows of a generalized database: every tile's content read through api.buildings_for_tile (what the
    exporter writes), its distinct vertices per mesh counted as report_generalization counts them."""
    cols: dict[str, list[np.ndarray]] = {k: [] for k in ("level", "leaf", "members", "vertices", "triangles")}
    with psycopg.connect(url) as conn:
        tiles = conn.execute("SELECT level, is_leaf FROM tiles.tile").fetchall()
        with conn.cursor(name="fidelity_levels") as cur:
            cur.itersize = BATCH
            cur.execute(_LEVEL_FEATURES)
            while rows := cur.fetchmany(BATCH):
                tris = [decode_triangles(r[3]) for r in rows]
                counts = np.array([len(t) for t in tris], dtype=np.int64)
                tri = np.concatenate(tris) if len(tris) else np.zeros((0, 3, 3))
                own = np.repeat(np.arange(len(rows)), counts)
                cols["vertices"].append(distinct_vertices(tri, own, len(rows)))
                cols["triangles"].append(counts)
                cols["level"].append(np.array([r[0] for r in rows]))
                cols["leaf"].append(np.array([bool(r[1]) for r in rows]))
                cols["members"].append(np.array([int(r[2]) for r in rows]))
    cat = {k: np.concatenate(v) if v else np.zeros(0, dtype=np.int64) for k, v in cols.items()}
    return level_rows(
        cat["level"],
        cat["leaf"],
        cat["members"],
        cat["vertices"],
        cat["triangles"],
        np.array([t[0] for t in tiles]),
        np.array([bool(t[1]) for t in tiles]),
    )


_OUTLINES = """
SELECT sum(area) FROM (
    SELECT ST_ClusterDBSCAN(geom_local, eps := 0, minpoints := 1) OVER () AS cid, ST_Area(geom_local) AS area,
           geom_local
    FROM osm.building WHERE parent_id IS NULL AND id IN (SELECT building_id FROM tiles.building_tile)
) c GROUP BY cid
"""


_BOXES = """
WITH c AS (
    SELECT ST_ClusterDBSCAN(geom_local, eps := 0, minpoints := 1) OVER () AS cid, geom_local AS g
    FROM osm.building WHERE parent_id IS NULL AND id IN (SELECT building_id FROM tiles.building_tile)
), o AS (SELECT ST_Union(g) AS g FROM c GROUP BY cid
), r AS (SELECT g, ST_OrientedEnvelope(g) AS box, row_number() OVER (ORDER BY ST_Area(g) DESC) AS rn FROM o
), k AS (SELECT ST_Union(box) FILTER (WHERE rn <= %(k)s) AS boxes, ST_Union(g) AS city FROM r)
SELECT ST_Area(ST_Intersection(boxes, city)) / nullif(ST_Area(ST_Union(boxes, city)), 0) FROM k
"""


def outline_bound(url: str) -> dict[str, Any]:
    """budget_bound of a database: its buildings' separate outlines (clustered where they touch; a cluster's area
    is the sum of its buildings', which barely overlap) against its LOD3 triangles, the full-detail view; and
    ``iou_boxes``, the footprint IoU of one drawing within the budget: the largest outlines that fit, each as
    its oriented bounding box (10 triangles)."""
    with psycopg.connect(url) as conn:
        full = int(
            conn.execute("SELECT coalesce(sum(n_triangles), 0) FROM lod.building_mesh WHERE lod = 3").fetchone()[0]
        )  # type: ignore[index]
        areas = np.array([r[0] for r in conn.execute(_OUTLINES)], dtype=np.float64)
        out = {"full_triangles": full, **budget_bound(areas, full)}
        boxes = conn.execute(_BOXES, {"k": out["outlines_in_budget"]}).fetchone()[0]  # type: ignore[index]
    return {**out, "iou_boxes": None if boxes is None else round(float(boxes), 4)}


def compare_views(views: dict[str, dict[str, Any]], out: Path) -> None:
    """Each measured camera's masks compared (``masks``) and drawn side by side into <out>/<camera>.png; a
    comparison that fails is recorded as the camera's ``masks`` error."""
    from etl.textures.atlas import encode_image

    for name, v in views.items():
        if "error" in v:
            continue
        try:
            s, f = (stream_bench.read_rgb(Path(_pass(v, p)["mask"])) for p in PASSES)
            v["masks"] = compare_masks(s, f)
            png, _ = encode_image(side_by_side(s, f), "png")
            (out / f"{name}.png").write_bytes(png)
            v["side_by_side"] = str(out / f"{name}.png")
        except Exception as e:  # noqa: BLE001 - recorded, the other cameras are still compared
            v["masks"] = {"error": _error(e)}


def export(url: str, out: Path, logfile: Path) -> Path:
    """The database exported as make exports it (every band, the default stream) into ``out``."""
    run_child([sys.executable, "-m", "etl", "export", "--out", str(out)], {**os.environ, "DATABASE_URL": url}, logfile)
    return out


def measure(
    url: str, name: str, tiles: Path | None = None, client: bool = True, timeout_s: float = 3600.0
) -> dict[str, Any]:
    """The fidelity figures of one database (see the module docstring), its export at ``tiles`` (exported into
    build/bench/fidelity/<name>/tiles first when None); never raises for a failed part."""
    t0 = time.perf_counter()
    root = FIDELITY_ROOT / name
    logs = LOG_DIR / name / "fidelity"
    res: dict[str, Any] = {"views": {}}
    try:
        res["levels"] = level_figures(url)
    except Exception as e:  # noqa: BLE001 - recorded, the client part is still measured
        res["levels_error"] = _error(e)
    try:
        res["bound"] = outline_bound(url)
    except Exception as e:  # noqa: BLE001 - recorded, the client part is still measured
        res["bound_error"] = _error(e)
    if client:
        try:
            cams = cameras_of(url)
            res["cameras"] = [stream_bench.cesium_camera(c, n) for n, c in cams]
            if tiles is None:
                tiles = export(url, root / "tiles", logs / "export.log")
            masks = root / "masks"
            if masks.exists():
                shutil.rmtree(masks)
            c = stream_bench.browse(
                tiles, res["cameras"], masks, logs / "client.log", timeout_s=timeout_s, driver=DRIVER
            )
            if "error" in c:
                raise RuntimeError(c["error"])
            res["views"] = c["views"]
            res["problems"] = c.get("problems", [])
            compare_views(res["views"], root)
        except Exception as e:  # noqa: BLE001 - recorded in the section, the bench goes on
            res["error"] = _error(e)
        for n, v in res["views"].items():
            m = v.get("masks") or {}
            tri = [_pass(v, p).get("trianglesSelected", 0) for p in PASSES]
            log(
                f"fidelity {name} {n}: "
                + (
                    v.get("error")
                    or m.get("error")
                    or f"IoU {m['iou']:.3f}, area {m['area_ratio'] or 0:.3f}, triangles {tri[0]:,} / {tri[1]:,}"
                )
            )
    res["seconds"] = round(time.perf_counter() - t0, 1)
    # for make report-generalization, which carries the last run's pictures (report_generalization.FIDELITY_DIR)
    root.mkdir(parents=True, exist_ok=True)
    (root / "fidelity.json").write_text(json.dumps({"name": name, **res}, indent=1))
    return res


# --- report -------------------------------------------------------------------------------------------------

NOTE = (
    "How much of the city a streaming client draws (issue 18; benchmarks/fidelity_bench.py with its CesiumJS driver "
    "benchmarks/fidelity_view.mjs). CesiumJS {cesium} in headless Chromium draws the export as a building mask "
    "(every building fragment white and unlit, black elsewhere, no FXAA/MSAA), 1920×1080, vertical fov 60°, at "
    "each camera twice: *streamed* (maximumScreenSpaceError 16, the plain traversal: no dynamic/foveated SSE, no "
    "skipLevelOfDetail, a cache that never coarsens) and *full* (maximumScreenSpaceError 0: every tile refines to "
    "its leaves). *IoU* = building pixels in both masks / in either; *area* = building pixels streamed / at full "
    "detail. *triangles* = tileset.statistics' numberOfTrianglesSelected; *tiles*: drawn in one frame (of which "
    "leaves) / loaded with content (numberOfTilesWithContentReady: the plain traversal keeps the ancestors of "
    "what it draws), after the tiles the view does not need were unloaded. Cameras far to near, scaled to the "
    "extract: *overview* straight down over the whole extract (the *Triangles per view* camera), the others at "
    "shares of its height above the ground (the issue's 7.7 km, 6.7, 4.9, 2.8, 1.8 km), looking north at the "
    "median of the buildings, straight down (*down-*) or oblique (pitch in the table). Targets: IoU ≥ {iou:.2f} at "
    "every camera; the overview's streamed triangles ≤ 1/{tri:.0f} of its full-detail ones. Masks and a side-by-side "
    "picture per camera (streamed | full | difference: red only at full detail, cyan only streamed): "
    "build/bench/fidelity/<extract>/ (not committed)."
)
BOUND_NOTE = (
    "Why the overview's ≤ 1/20 target and IoU ≥ 0.90 do not hold together where buildings stand apart "
    "(fidelity_bench.budget_bound): the city's separate outlines (buildings that touch counted as one) each cost "
    "at least 10 triangles drawn on their own (a 4-corner prism without its floor). 1/20 of the full-detail "
    "triangles fits this many; drawn exactly, the largest of them cover the *IoU bound* share of the built area, "
    "the best footprint IoU any drawing within the budget can reach without filling the gaps between outlines "
    "(filling them adds area the city does not have: Liechtenstein's outlines closed over 10 m gaps and "
    "simplified at 3 m are at footprint IoU 0.85, over 20 m and at 5 m at 0.59). *… as oriented boxes*: the "
    "footprint IoU of one such drawing, those outlines as their oriented bounding boxes. On the aggregated "
    "tilesets of branch aggregate18, CesiumJS's IoU ran 0.03–0.04 below the footprint IoU (walls and roofs seen "
    "at the edges of the view)."
)
LEVELS_NOTE = (
    "The thesis' Table 3.1 per level of the tile tree, beside the fidelity above: the city as drawn if the "
    "traversal stopped at level L, i.e. the content of the tiles of level L and of the leaves above it "
    "(api.buildings_for_tile, what the export writes). *features*: buildings, parts and blocks (*stand for*: the "
    "buildings a block merges counted); *vertices*: distinct corners per mesh (welded at 1 mm, as "
    "benchmarks/report_generalization.py counts them); *polygons*: triangles. Reductions against the deepest "
    "level, full detail (every leaf)."
)


def _fail(e: str) -> str:
    return "failed: " + e.replace("|", "/")


def _mark(ok: bool | None) -> str:
    return "–" if ok is None else pass_mark(ok)


def _cesium_version() -> str:
    try:  # cesium is an npm package: its package.json says which
        return str(json.loads((REPO / "node_modules" / "cesium" / "package.json").read_text())["version"])
    except (OSError, ValueError, KeyError):
        return "?"


def section_lines(results: Sequence[tuple[str, dict[str, Any]]]) -> list[str]:
    """The ``## Far view fidelity`` section of BENCHMARKS.md for (extract, measure()) pairs."""
    results = [(n, r) for n, r in results if r]
    if not results:
        return []
    rows = []
    for name, r in results:
        if "error" in r and not r.get("views"):
            rows.append([name, _fail(r["error"])] + ["–"] * 9)
            continue
        ok = judge(r)
        cams = {c["name"]: c for c in r.get("cameras", [])}
        for cam, v in r.get("views", {}).items():
            c = cams.get(cam, {})
            where = f"{c['height']:,.0f} m, {c['pitch']:.0f}°" if c else "–"
            m = v.get("masks") or {}
            err = v.get("error") or m.get("error")
            if err and "iou" not in m:
                rows.append([name, cam, where, _fail(err)] + ["–"] * 7)
                continue
            s, f = _pass(v, "streamed"), _pass(v, "full")
            share = triangle_share(v)
            rows.append(
                [
                    name,
                    cam,
                    where,
                    f"{m['iou']:.3f}",
                    _mark(ok[cam]["iou"]),
                    "–" if m.get("area_ratio") is None else f"{m['area_ratio']:.3f}",
                    f"{s.get('trianglesSelected', 0):,} / {f.get('trianglesSelected', 0):,}",
                    "–" if share is None else f"1/{1 / share:,.1f}" if share else "0",
                    _mark(ok[cam].get("triangles")) if cam == "overview" else "–",
                    *(
                        f"{p.get('tilesDrawn', 0):,} ({p.get('leavesDrawn', 0):,}) / {p.get('tilesWithContent', 0):,}"
                        for p in (s, f)
                    ),
                ]
            )
    out = [
        "",
        "## Far view fidelity",
        "",
        NOTE.format(cesium=_cesium_version(), iou=TARGET_IOU, tri=1 / TARGET_OVERVIEW_TRIANGLES),
        "",
        *markdown_table(
            [
                "extract",
                "camera",
                "height, pitch",
                "IoU",
                f"≥ {TARGET_IOU:.2f}",
                "area",
                "triangles streamed / full",
                "streamed share",
                "≤ 1/20 (overview)",
                "tiles drawn (leaves) / loaded, streamed",
                "… full",
            ],
            rows,
            "lllrlrrrlrr",
        ),
    ]
    misses = [f"{name} {cam}" for name, r in results for cam, ok in judge(r).items() if False in ok.values()]
    if misses:
        out += ["", f"Targets missed: {', '.join(misses)}."]
    level_rows_out = []
    for name, r in results:
        if "levels_error" in r:
            level_rows_out.append([name, _fail(r["levels_error"])] + ["–"] * 6)
        for lv in r.get("levels", []):
            level_rows_out.append(
                [
                    name,
                    str(lv["level"]),
                    f"{lv['tiles']:,}",
                    f"{lv['features']:,} ({lv['members']:,})",
                    f"{lv['vertices']:,}",
                    f"{lv['vertex_reduction_pct']:.1f} %",
                    f"{lv['triangles']:,}",
                    f"{lv['triangle_reduction_pct']:.1f} %",
                ]
            )
    bound_rows = []
    for name, r in results:
        if "bound_error" in r:
            bound_rows.append([name, _fail(r["bound_error"])] + ["–"] * 4)
        elif b := r.get("bound"):
            bound_rows.append(
                [
                    name,
                    f"{b['outlines']:,}",
                    f"{b['min_triangles_all']:,}",
                    f"{b['budget_triangles']:,} ({b['outlines_in_budget']:,} outlines)",
                    "–" if b["iou_bound"] is None else f"{b['iou_bound']:.3f}",
                    "–" if b.get("iou_boxes") is None else f"{b['iou_boxes']:.3f}",
                ]
            )
    if bound_rows:
        out += [
            "",
            "### What 1/20 of the triangles can draw",
            "",
            BOUND_NOTE,
            "",
            *markdown_table(
                [
                    "extract",
                    "separate outlines",
                    "≥ triangles to draw each",
                    "1/20 of full detail (fits)",
                    "IoU bound within it",
                    "… as oriented boxes",
                ],
                bound_rows,
                "lrrrrr",
            ),
        ]
    if level_rows_out:
        out += [
            "",
            "### Vertices and polygons per level",
            "",
            LEVELS_NOTE,
            "",
            *markdown_table(
                [
                    "extract",
                    "level",
                    "tiles",
                    "features (stand for)",
                    "vertices",
                    "vertex reduction",
                    "polygons",
                    "polygon reduction",
                ],
                level_rows_out,
                "lrrrrrrr",
            ),
        ]
    return out


# --- main ---------------------------------------------------------------------------------------------------


def build_database(osm: Path, admin_url: str) -> str:
    """A fresh ``citylod_fidelity`` database with the pipeline run on ``osm`` up to textures."""
    return build_pipeline_db(osm, admin_url, FIDELITY_DB, "fidelity")


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="python -m benchmarks.fidelity_bench", description=__doc__.split("\n\n")[0])
    src = p.add_mutually_exclusive_group(required=True)
    src.add_argument("--osm", type=Path, help=f"build a fresh {FIDELITY_DB} database from this extract first")
    src.add_argument("--database-url", help="measure this database (the pipeline has run up to textures)")
    p.add_argument("--tiles", type=Path, help="the database's export (default: export it again)")
    p.add_argument(
        "--name",
        help="the extract's name in the report and under build/bench/fidelity/ "
        "(default: the --osm file's name, else the database's)",
    )
    p.add_argument("--no-client", action="store_true", help="only the per-level figures (no CesiumJS)")
    p.add_argument("--keep", action="store_true", help="keep the --osm database")
    p.add_argument("--json", type=Path, help="also write the measurement as JSON here")
    args = p.parse_args(argv)
    cluster.ensure()
    admin_url = cluster.database_url("postgres")
    if args.osm is not None:
        if not args.osm.exists():
            p.error(f"missing input: {args.osm}")
        name = args.name or extract_name(args.osm)
        url = build_database(args.osm.resolve(), admin_url)
    else:
        url = args.database_url
        name = args.name or db_name(url)
    try:
        res = measure(url, name, args.tiles.resolve() if args.tiles else None, client=not args.no_client)
    finally:
        if args.osm is not None and not args.keep:
            drop_db(admin_url, FIDELITY_DB)
    if args.json:
        args.json.parent.mkdir(parents=True, exist_ok=True)
        args.json.write_text(json.dumps(res, indent=1))
    with contextlib.suppress(BrokenPipeError):
        print("\n".join(section_lines([(name, res)])))
    return 0


if __name__ == "__main__":
    sys.exit(main())
