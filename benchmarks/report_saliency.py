"""``python -m benchmarks.report_saliency``: view saliency along a scripted camera path over a city (thesis
section 5.3), and how often each of the 10 most salient buildings is seen as itself, with and without the
landmark rule.

The path (benchmarks.view_saliency.camera_path, default 120 frames) circles the city once while its focus loops
over it, zooms twice from 150 m to beyond the distance at which the root tile alone satisfies the maximum
screen-space error (so every band of the tile hierarchy is drawn in some frames) and tilts between 12° and 75°
below the horizon. Per frame, one call of api.lod_for_view (60°, 1080 px, 16:9, max SSE 16) gives the
features a 3D Tiles client draws; parts count with their building, a block is one feature. For every drawn
feature inside the view the three metrics of the thesis are measured (normalized view distance, vertical view
angle, distance to the region of interest by jump flooding; see benchmarks/view_saliency.py), combined into its
interest, and its saliency = interest × (lod + 1) / 4 is painted into a per-frame saliency map.

*Visible* means: the building is drawn as itself (its own row, or a block whose only member it is), its screen
box overlaps the viewport and spans at least ``--min-px`` pixels. Occlusion is not modelled.

*Without the landmark rule* (osm.building.protected, set for lm.building.is_landmark): a landmark would be an
ordinary building. The tiles that draw it as itself in the block bands (gen_level <= 1) would instead merge it
with every building whose simplified footprint lies within the band's aggregation distance (gen.tolerance;
ST_DWithin on gen.footprint over the buildings below the tile, which is how ST_ClusterDBSCAN with minpoints 1
joins them), or, alone, draw it as a one-member block unless that block is omitted (sqrt(radius² + height²) <=
the tolerance, as the generalize stage selects). In band 2 it would be LOD1 instead of the LOD2 lm.lod2_band
gives it. So it is visible without the rule in a frame iff it is visible with it and the drawing tile is in
band >= 2, or in a block band where it has no neighbour within the tolerance and is not too small. The tile
walk itself is taken as is: without protection the block tiles' geometric errors (and so the walk) could
change a little. For coarser bands (gen_level < 0) the footprint test is a lower bound on merging. Buildings
that are not landmarks are the same with and without.

Writes into ``--out``: ``saliency.md``, ``saliency.json``, ``saliency.png`` (summary), ``saliency/frame_NNN.png``
(the per-frame saliency maps) and ``saliency/features.csv`` (per frame and visible feature, the metrics).
The database is only read.
"""

from __future__ import annotations

import argparse
import csv
import json
import math
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import psycopg

from benchmarks import view_saliency as vs
from benchmarks.common import db_name, machine, machine_section, markdown_table
from core import cluster
from core.camera import distance_for_pixels
from core.geodesy import enu_rotation
from core.settings import REPO

DEFAULT_OUT = Path("build/reports")
DEFAULT_FRAMES = 120
FOV = 60.0
VIEWPORT_H = 1080
ASPECT = 16.0 / 9.0
MAX_SSE = 16.0
#: Closest distance (m) of the camera to the point it looks at.
NEAR_M = 150.0
#: Radius (m) of the region of interest, a disc on the ground around the point the camera looks at.
ROI_M = 150.0
#: Smallest screen box (pixels of the 1080 px viewport) of a visible feature.
MIN_PX = 4.0
#: Columns of the saliency maps and of the jump-flooding grid (rows in proportion: 384 × 216).
GRID_W = 384
TOP = 10
#: Weights of view distance, vertical view angle and ROI distance in the interest.
WEIGHTS = (1.0, 1.0, 1.0)


def log(msg: str) -> None:
    print(f"[report-saliency {time.strftime('%H:%M:%S')}] {msg}", file=sys.stderr, flush=True)


# --- queries ---------------------------------------------------------------------------------------------------

# The city: centre of the scored buildings' extent (degrees), half its diagonal (m), the root's geometric error
# and the ground (the root region's lowest height above the ellipsoid).
_CITY = """
SELECT ST_X(c), ST_Y(c), r, (SELECT geometric_error FROM tiles.tile WHERE level = 0 AND x = 0 AND y = 0),
       (SELECT region[5] FROM tiles.tile WHERE level = 0 AND x = 0 AND y = 0), n
FROM (
    SELECT ST_Transform(ST_SetSRID(ST_MakePoint((ST_XMin(e) + ST_XMax(e)) / 2, (ST_YMin(e) + ST_YMax(e)) / 2),
                                   srid), 4326) AS c,
           sqrt((ST_XMax(e) - ST_XMin(e)) ^ 2 + (ST_YMax(e) - ST_YMin(e)) ^ 2) / 2 AS r, n
    FROM (SELECT ST_Extent(centroid) AS e, min(ST_SRID(centroid)) AS srid, count(*) AS n FROM lm.building) s
) s
"""
_TOP = """
SELECT l.rank, l.building_id, b.osm_type::text, b.osm_id, b.name, l.is_landmark, l.level, l.lod2_band, l.score,
       l.height_m
FROM lm.building l JOIN osm.building b ON b.id = l.building_id
WHERE l.rank <= %(top)s
ORDER BY l.rank
"""
# Without the rule, per landmark of the top and block-band tile above it: would it be merged with a neighbour
# (a simplified footprint within the band's tolerance, as ST_ClusterDBSCAN(eps, minpoints 1) joins them), and
# would it, alone, be omitted as too small (the generalize stage's selection)?
_WITHOUT = """
WITH top AS (
    SELECT building_id FROM lm.building WHERE rank <= %(top)s AND is_landmark
), t AS (
    SELECT level, x, y, gen.tolerance(gen_level) AS d FROM tiles.tile WHERE gen_level <= 1
)
SELECT top.building_id, t.level, t.x, t.y,
       EXISTS (SELECT FROM tiles.building_tiles_below(t.level, t.x, t.y) b
               JOIN gen.footprint n ON n.building_id = b.group_id
               WHERE b.group_id <> top.building_id AND ST_DWithin(n.geom, f.geom, t.d)) AS merged,
       sqrt((ST_MinimumBoundingRadius(f.geom)).radius ^ 2 + g.height ^ 2) <= t.d AS omitted
FROM t
JOIN top ON top.building_id IN (SELECT b.group_id FROM tiles.building_tiles_below(t.level, t.x, t.y) b)
JOIN gen.footprint f ON f.building_id = top.building_id
JOIN gen.building_mesh g ON g.building_id = top.building_id AND g.gen_level = 2
"""
# One frame: what api.lod_for_view draws, parts folded into their building, each feature with its tile's band,
# a point on its footprint (degrees), its height and the radius of a disc of its footprint's area (m; the
# covering circle would make a long building a square on screen), and for a one-member block its member.
_FRAME = """
WITH v AS (
    SELECT v.feature_kind = 'block' AS is_block,
           CASE WHEN v.feature_kind = 'block' THEN v.feature_id ELSE coalesce(o.parent_id, o.id) END AS fid,
           v.lod, v.level, v.x, v.y
    FROM api.lod_for_view(ST_SetSRID(ST_MakePoint(%(lon)s, %(lat)s, %(h)s), 4326), %(heading)s, %(pitch)s,
                          %(fov)s, %(vh)s, %(sse)s, %(aspect)s) v
    LEFT JOIN osm.building o ON v.feature_kind <> 'block' AND o.id = v.feature_id
), g AS (
    SELECT is_block, fid, max(lod) AS lod, min(level) AS level, min(x) AS x, min(y) AS y FROM v GROUP BY 1, 2
)
SELECT g.is_block, g.fid, g.lod, t.gen_level, g.level, g.x, g.y, ST_X(p.c), ST_Y(p.c), p.h, p.r, p.member
FROM g
JOIN tiles.tile t ON t.level = g.level AND t.x = g.x AND t.y = g.y
LEFT JOIN LATERAL (
    SELECT ST_Transform(l.centroid, 4326) AS c, l.height_m::float8 AS h, sqrt(l.area_m2 / pi()) AS r,
           g.fid AS member
    FROM lm.building l WHERE NOT g.is_block AND l.building_id = g.fid
    UNION ALL
    SELECT ST_Transform(ST_PointOnSurface(k.footprint), 4326), k.height::float8, sqrt(ST_Area(k.footprint) / pi()),
           CASE WHEN k.n_members = 1 THEN k.members[1] END
    FROM gen.block k
    WHERE g.is_block AND k.block_id = g.fid
) p ON true
ORDER BY g.is_block, g.fid
"""


@dataclass(frozen=True)
class City:
    lon: float
    lat: float
    radius_m: float
    root_error: float
    ground_h: float
    buildings: int


@dataclass
class Landmark:
    """One of the top buildings and its per-frame record."""

    rank: int
    building_id: int
    osm_type: str
    osm_id: int
    name: str | None
    is_landmark: bool
    level: int
    lod2_band: int | None
    score: float
    height_m: float
    with_rule: list[bool] = field(default_factory=list)
    without_rule: list[bool] = field(default_factory=list)
    saliency_with: list[float] = field(default_factory=list)  # NaN when not visible
    saliency_without: list[float] = field(default_factory=list)
    lod_with: list[int] = field(default_factory=list)  # -1 when not visible
    lod_without: list[int] = field(default_factory=list)

    def as_dict(self, frames: int) -> dict[str, Any]:
        w, wo = sum(self.with_rule), sum(self.without_rule)
        return {
            "rank": self.rank,
            "building_id": self.building_id,
            "osm": f"{self.osm_type}{self.osm_id}",
            "osm_type": self.osm_type,
            "osm_id": self.osm_id,
            "name": self.name,
            "is_landmark": self.is_landmark,
            "level": self.level,
            "lod2_band": self.lod2_band,
            "score": round(self.score, 4),
            "height_m": self.height_m,
            "frames_visible_with": w,
            "frames_visible_without": wo,
            "fraction_with": w / frames if frames else 0.0,
            "fraction_without": wo / frames if frames else 0.0,
            "mean_saliency_with": _nanmean(self.saliency_with),
            "mean_saliency_without": _nanmean(self.saliency_without),
            "mean_lod_with": _mean_lod(self.lod_with),
            "mean_lod_without": _mean_lod(self.lod_without),
        }


def _nanmean(v: list[float]) -> float | None:
    a = np.asarray(v, float)
    return round(float(np.nanmean(a)), 4) if np.isfinite(a).any() else None


def _mean_lod(v: list[int]) -> float | None:
    a = np.asarray(v, float)
    return round(float(a[a >= 0].mean()), 3) if (a >= 0).any() else None


def read_city(conn: psycopg.Connection) -> City:
    row = conn.execute(_CITY).fetchone()
    if row is None or not row[5]:
        raise SystemExit("lm.building is empty: run the landmarks, tiles and generalize stages first (make demo)")
    if row[3] is None:
        raise SystemExit("tiles.tile has no root with a geometric error: run the tiles and generalize stages first")
    return City(float(row[0]), float(row[1]), float(row[2]), float(row[3]), float(row[4] or 0.0), int(row[5]))


def read_top(conn: psycopg.Connection, top: int) -> list[Landmark]:
    return [
        Landmark(
            int(r[0]),
            int(r[1]),
            r[2],
            int(r[3]),
            r[4],
            bool(r[5]),
            int(r[6]),
            None if r[7] is None else int(r[7]),
            float(r[8]),
            float(r[9]),
        )
        for r in conn.execute(_TOP, {"top": top}).fetchall()
    ]


def read_without(conn: psycopg.Connection, top: int) -> dict[tuple[int, int, int, int], tuple[bool, bool]]:
    """(building_id, level, x, y) of a block-band tile -> (would be merged, would be omitted) without the rule."""
    return {
        (int(r[0]), int(r[1]), int(r[2]), int(r[3])): (bool(r[4]), bool(r[5]))
        for r in conn.execute(_WITHOUT, {"top": top}).fetchall()
    }


def far_distance(city: City, fov: float = FOV, viewport_height: int = VIEWPORT_H, max_sse: float = MAX_SSE) -> float:
    """How far the path zooms out: 1.25 × the distance at which the root tile alone meets max_sse, plus the
    city's half extent (distances are to the tile boxes, the path's to its focus)."""
    d_root = distance_for_pixels(city.root_error, max_sse, math.radians(fov), viewport_height)
    return max(1.25 * d_root + city.radius_m, 4.0 * city.radius_m, 2.0 * NEAR_M)


# --- per frame -------------------------------------------------------------------------------------------------


@dataclass
class Frame:
    """What one frame drew and measured (arrays over the drawn features)."""

    is_block: np.ndarray
    fid: np.ndarray
    lod: np.ndarray
    band: np.ndarray
    tile: np.ndarray  # (n, 3) level, x, y
    member: np.ndarray  # the building a feature shows as itself, -1 for a block of several
    metrics: vs.FrameMetrics
    saliency: np.ndarray
    unplaced: int


def measure_frame(
    cur: psycopg.Cursor, pf: vs.PathFrame, city: City, roi_m: float, grid_w: int, min_px: float, max_sse: float
) -> tuple[Frame, float]:
    cam = pf.camera
    t0 = time.perf_counter()
    rows = cur.execute(
        _FRAME,
        {
            "lon": cam.lon,
            "lat": cam.lat,
            "h": cam.height,
            "heading": cam.heading,
            "pitch": cam.pitch,
            "fov": cam.fov,
            "vh": cam.viewport_height,
            "sse": max_sse,
            "aspect": cam.aspect,
        },
    ).fetchall()
    query_s = time.perf_counter() - t0
    placed = [r for r in rows if r[7] is not None]
    n = len(placed)
    col = list(zip(*placed, strict=True)) if n else [()] * 12
    is_block = np.array(col[0], dtype=bool)
    fid = np.array(col[1], dtype=np.int64)
    lod = np.array(col[2], dtype=np.int64)
    band = np.array(col[3], dtype=np.int64)
    tile = np.array(list(zip(col[4], col[5], col[6], strict=True)), dtype=np.int64).reshape(n, 3)
    member = np.array([-1 if m is None else m for m in col[11]], dtype=np.int64)
    roi_centre = vs.ecef(pf.target_lon, pf.target_lat, pf.target_h)
    m = vs.frame_metrics(
        cam,
        np.array(col[7], float),
        np.array(col[8], float),
        city.ground_h,
        np.array(col[9], float),
        np.array(col[10], float),
        roi_centre,
        roi_m,
        grid_w,
        min_px,
        WEIGHTS,
    )
    return Frame(is_block, fid, lod, band, tile, member, m, m.interest * vs.lod_weight(lod), len(rows) - n), query_s


def record_top(frame: Frame, tops: list[Landmark], without: dict[tuple[int, int, int, int], tuple[bool, bool]]) -> None:
    """Append this frame's visibility, saliency and LOD of each top building, with and without the rule.

    Saliency and LOD are recorded for the frames in which it is visible with the rule (NaN / -1 otherwise), so
    both are averaged over the same frames; without the rule a building not seen as itself counts saliency 0,
    and LOD 0 in the block bands (inside a block, or a block of its own)."""
    for lm in tops:
        own = np.flatnonzero(frame.member == lm.building_id)
        vis = own[frame.metrics.visible[own]]
        if not len(vis):
            lm.with_rule.append(False)
            lm.without_rule.append(False)
            lm.saliency_with.append(math.nan)
            lm.saliency_without.append(math.nan)
            lm.lod_with.append(-1)
            lm.lod_without.append(-1)
            continue
        i = int(vis[0])
        lod, band = int(frame.lod[i]), int(frame.band[i])
        if not lm.is_landmark or band >= 3:
            seen, lod_wo = True, lod
        elif band == 2:
            seen, lod_wo = True, min(lod, 1)  # the simplified solid of band 2 instead of lm.lod2_band's LOD2
        else:
            # an unknown tile (cannot happen: every block tile above it is listed) counts as merged
            merged, omitted = without.get((lm.building_id, *map(int, frame.tile[i])), (True, False))
            seen, lod_wo = not (merged or omitted), 0
        lm.with_rule.append(True)
        lm.saliency_with.append(float(frame.saliency[i]))
        lm.lod_with.append(lod)
        lm.without_rule.append(seen)
        lm.saliency_without.append(float(frame.metrics.interest[i] * vs.lod_weight(lod_wo)) if seen else 0.0)
        lm.lod_without.append(lod_wo)


def frame_stats(k: int, pf: vs.PathFrame, frame: Frame, tops: list[Landmark], query_s: float) -> dict[str, Any]:
    cam, m, v = pf.camera, frame.metrics, frame.metrics.visible
    top_ids = np.array([t.building_id for t in tops], dtype=np.int64)
    is_top = np.isin(frame.member, top_ids)
    others = v & ~is_top

    def mean(a: np.ndarray) -> float | None:
        return round(float(a.mean()), 4) if a.size else None

    # the landmarks among the top, over those visible with the rule (0 without where not seen as themselves)
    sw = [t.saliency_with[-1] for t in tops if t.is_landmark and t.with_rule[-1]]
    swo = [t.saliency_without[-1] for t in tops if t.is_landmark and t.with_rule[-1]]
    return {
        "frame": k,
        "lon": round(cam.lon, 6),
        "lat": round(cam.lat, 6),
        "height_m": round(cam.height, 1),
        "heading": round(cam.heading, 2),
        "pitch": round(cam.pitch, 2),
        "distance_m": round(pf.distance_m, 1),
        "drawn": int(len(frame.fid)),
        "visible": int(v.sum()),
        "unplaced": frame.unplaced,
        "visible_by_lod": {str(lv): int((v & (frame.lod == lv)).sum()) for lv in range(4)},
        "bands": sorted({int(b) for b in frame.band}),
        "roi_on_screen": bool(m.roi_mask.any()),
        "mean_distance_n": mean(m.distance_n[v]),
        "mean_angle_deg": mean(m.angle_deg[v]),
        "mean_roi_n": mean(m.roi_n[v]),
        "mean_interest": mean(m.interest[v]),
        "mean_saliency_others": mean(frame.saliency[others]),
        "visible_others": int(others.sum()),
        "mean_saliency_landmarks_with": round(float(np.mean(sw)), 4) if sw else None,
        "mean_saliency_landmarks_without": round(float(np.mean(swo)), 4) if swo else None,
        "top_visible_with": int(sum(t.with_rule[-1] for t in tops)),
        "top_visible_without": int(sum(t.without_rule[-1] for t in tops)),
        "query_ms": round(1000 * query_s, 1),
    }


# --- output ----------------------------------------------------------------------------------------------------

_CSV_HEADER = [
    "frame",
    "kind",
    "id",
    "top_rank",
    "lod",
    "band",
    "distance_m",
    "distance_n",
    "angle_deg",
    "angle_n",
    "roi_px",
    "roi_n",
    "interest",
    "saliency",
]


def feature_rows(k: int, frame: Frame, rank_of: dict[int, int]) -> list[list[Any]]:
    """CSV rows of the frame's visible features (a block's id is its gen.block.block_id, a building's its
    osm.building.id)."""
    v = np.flatnonzero(frame.metrics.visible)
    m = frame.metrics
    ranks = [rank_of.get(int(b), "") for b in frame.member[v]]
    cols = [
        np.full(len(v), k),
        np.where(frame.is_block[v], "block", "building"),
        frame.fid[v],
        ranks,
        frame.lod[v],
        frame.band[v],
        np.round(m.distance_m[v], 1),
        np.round(m.distance_n[v], 4),
        np.round(m.angle_deg[v], 2),
        np.round(m.angle_n[v], 4),
        np.round(m.roi_px[v], 1),
        np.round(m.roi_n[v], 4),
        np.round(m.interest[v], 4),
        np.round(frame.saliency[v], 4),
    ]
    return [
        list(r) for r in zip(*[np.asarray(c).tolist() if not isinstance(c, list) else c for c in cols], strict=True)
    ]


def plot_frame(path: Path, k: int, pf: vs.PathFrame, frame: Frame, tops: list[Landmark]) -> None:
    """One frame's saliency map: each visible feature's saliency over its screen box (nearest wins), the ROI
    (cyan) with its jump-flooding distance map as grey contours, and the top buildings where they are visible
    (green circle; red cross: not seen as itself without the landmark rule)."""
    import matplotlib.pyplot as plt

    m = frame.metrics
    h, w = m.roi_mask.shape
    v = m.visible
    sal, _ = vs.splat(np.where(v[:, None], m.boxes, np.nan), m.depth, frame.saliency, w, h, m.scale)
    # no layout engine: a constrained layout doubles the time per frame
    fig = plt.figure(figsize=(8.4, 4.8), dpi=100)
    ax = fig.add_axes((0.01, 0.02, 0.86, 0.9))
    cax = fig.add_axes((0.89, 0.1, 0.02, 0.74))
    ax.set_facecolor("#20202a")
    im = ax.imshow(sal, cmap="inferno", vmin=0, vmax=1, interpolation="nearest", extent=(0, w, h, 0))
    if m.roi_mask.any() and not m.roi_mask.all():
        far = float(m.roi_distance[np.isfinite(m.roi_distance)].max())
        ax.contour(
            np.arange(w) + 0.5,
            np.arange(h) + 0.5,
            m.roi_distance,
            levels=np.linspace(0, far, 7)[1:-1],
            colors="0.75",
            linewidths=0.4,
            alpha=0.6,
        )
        ax.contour(
            np.arange(w) + 0.5,
            np.arange(h) + 0.5,
            m.roi_mask.astype(float),
            levels=[0.5],
            colors="cyan",
            linewidths=0.9,
        )
    for t in tops:
        if not t.with_rule[-1]:
            continue
        i = int(np.flatnonzero((frame.member == t.building_id) & v)[0])
        x = float(np.clip((m.boxes[i, 0] + m.boxes[i, 2]) / 2 * m.scale, 2, w - 2))
        y = float(np.clip(m.boxes[i, 1] * m.scale, 6, h - 2))
        colour = "lime" if t.without_rule[-1] else "red"
        ax.plot(x, y, "o" if t.without_rule[-1] else "x", ms=6, mfc="none", mec=colour, mew=1.4)
        ax.annotate(str(t.rank), (x, y), xytext=(3, 3), textcoords="offset points", fontsize=7, color=colour)
    ax.set_xlim(0, w)
    ax.set_ylim(h, 0)
    ax.set_xticks([])
    ax.set_yticks([])
    cam = pf.camera
    bands = ",".join(str(b) for b in sorted(set(frame.band.tolist())))
    ax.set_title(
        f"frame {k}: {cam.height:.0f} m up, pitch {cam.pitch:.0f}°, {pf.distance_m:.0f} m to the focus, "
        f"bands {bands}, {int(v.sum())} visible",
        fontsize=8,
    )
    fig.colorbar(im, cax=cax, label="saliency")
    fig.savefig(path)
    plt.close(fig)


def plot_summary(
    report: dict[str, Any],
    path_xy: np.ndarray,
    target_xy: np.ndarray,
    buildings_xy: np.ndarray,
    tops_xy: np.ndarray,
    path: Path,
) -> None:
    """saliency.png: the path over the city, its distance and pitch per frame, the mean saliency per frame,
    and the share of frames each top building is visible with and without the rule."""
    import matplotlib.pyplot as plt

    frames = report["frames"]
    k = np.array([f["frame"] for f in frames])
    fig, ax = plt.subplots(2, 2, figsize=(15, 10), layout="constrained")
    a = ax[0, 0]
    a.scatter(buildings_xy[:, 0], buildings_xy[:, 1], s=2, c="0.6", label="buildings")
    sc = a.scatter(path_xy[:, 0], path_xy[:, 1], s=14, c=k, cmap="viridis", label="camera")
    a.plot(target_xy[:, 0], target_xy[:, 1], "-", c="0.3", lw=0.8, label="focus (ROI centre)")
    for t, (x, y) in zip(report["top"], tops_xy, strict=True):
        a.plot(x, y, "o" if t["is_landmark"] else "s", ms=5, mfc="none", mec="red" if t["is_landmark"] else "blue")
        a.annotate(str(t["rank"]), (x, y), xytext=(3, 3), textcoords="offset points", fontsize=8)
    a.set(
        aspect="equal",
        title="Camera path (top buildings: red landmarks, blue others)",
        xlabel="east (m)",
        ylabel="north (m)",
    )
    a.legend(fontsize=8, loc="lower right")
    fig.colorbar(sc, ax=a, label="frame", shrink=0.8)

    a = ax[0, 1]
    a.semilogy(k, [f["distance_m"] for f in frames], "-", c="k", label="distance to focus")
    a.semilogy(k, [f["height_m"] for f in frames], "--", c="0.4", label="height")
    blocks = np.array([min(f["bands"]) <= 1 if f["bands"] else False for f in frames])
    for i in np.flatnonzero(blocks):
        a.axvspan(k[i] - 0.5, k[i] + 0.5, color="orange", alpha=0.25, lw=0)
    a.set(title="Path: distance and height (shaded: a block band is drawn)", xlabel="frame", ylabel="m")
    b = a.twinx()
    b.plot(k, [f["pitch"] for f in frames], ":", c="tab:blue", label="pitch")
    b.set_ylabel("pitch (°)", color="tab:blue")
    a.legend(fontsize=8, loc="upper left")

    a = ax[1, 0]

    def series(key: str) -> np.ndarray:
        return _column(frames, key)

    a.plot(k, series("mean_saliency_landmarks_with"), "-o", ms=3, c="tab:red", label="landmarks, with the rule")
    a.plot(
        k,
        series("mean_saliency_landmarks_without"),
        "--s",
        ms=3,
        c="tab:purple",
        label="landmarks, without (0 where not seen as itself)",
    )
    a.plot(k, series("mean_saliency_others"), "-", c="0.4", label="other visible features")
    a.set(title="Mean saliency per frame", xlabel="frame", ylabel="saliency", ylim=(0, 1))
    b = a.twinx()
    b.step(k, series("top_visible_with"), where="mid", c="tab:red", alpha=0.35, lw=1)
    b.step(k, series("top_visible_without"), where="mid", c="tab:purple", alpha=0.35, lw=1)
    b.set_ylabel(f"top {len(report['top'])} visible with / without the rule (steps)")
    b.set_ylim(0, len(report["top"]) + 0.5)
    a.legend(fontsize=8, loc="upper right")

    a = ax[1, 1]
    tops = report["top"]
    y = np.arange(len(tops))
    a.barh(y - 0.2, [t["fraction_with"] for t in tops], 0.4, color="tab:red", label="with the landmark rule")
    a.barh(y + 0.2, [t["fraction_without"] for t in tops], 0.4, color="tab:purple", label="without")
    a.set_yticks(
        y, [f"{t['rank']}. {(t['name'] or t['osm'])[:28]}{' *' if t['is_landmark'] else ''}" for t in tops], fontsize=8
    )
    a.invert_yaxis()
    a.set(title="Share of frames visible as itself (* landmark)", xlabel="fraction of frames", xlim=(0, 1))
    a.legend(fontsize=8, loc="lower right")
    for x in ax.flat:
        x.grid(True, alpha=0.3)
    fig.suptitle(f"citylod view saliency over {len(frames)} frames", fontsize=14)
    fig.savefig(path, dpi=100)
    plt.close(fig)


def _f(v: float | None, nd: int = 2) -> str:
    return "–" if v is None else f"{v:.{nd}f}"


def render_markdown(report: dict[str, Any]) -> str:
    p, c, s = report["parameters"], report["city"], report["summary"]
    lines = [
        "# View saliency and landmark visibility",
        "",
        f"`{report['command']}` on `{report['database']}` ({c['buildings']:,} scored buildings). Thesis section 5.3: "
        "for every frame of a scripted camera path and every visible feature, the normalized view distance, the "
        "vertical view angle and the distance to a region of interest by jump flooding; their combination as "
        "saliency maps; and how often the most salient buildings are seen as themselves with and without the "
        "landmark rule.",
        "",
        "## Method",
        "",
        f"* **Path** (benchmarks.view_saliency.camera_path): {p['frames']} frames. The camera circles the city once "
        f"while its focus loops over it (a 2:1 Lissajous figure of {0.45 * c['radius_m']:.0f} m), zooms twice from "
        f"{p['near_m']:.0f} m to {p['far_m']:.0f} m from the focus (log-spaced; the far end is 1.25 × the distance "
        "at which the root tile alone meets the maximum screen-space error, plus the city's half extent, so "
        "every band is drawn) and tilts three times between 12° and 75° below the horizon. Heights "
        f"{s['height_m'][0]:.0f}–{s['height_m'][1]:.0f} m, pitch {s['pitch'][0]:.0f}° to {s['pitch'][1]:.0f}°.",
        f"* **Drawn features**: one api.lod_for_view call per frame ({p['fov']:.0f}° vertical field of view, "
        f"{p['viewport'][0]}×{p['viewport'][1]} px, max SSE {p['max_sse']:.0f}); parts count with their building, "
        "a block is one feature. Each is a vertical cylinder on a point of its footprint (lm.building.centroid, "
        "ST_PointOnSurface of a block), as high as the feature and as wide as a disc of its footprint's area.",
        f"* **Visible**: its screen box overlaps the viewport, is in front of the camera and spans at least "
        f"{p['min_px']:.0f} px. Occlusion is not modelled.",
        "* **Metrics** per visible feature: *view distance* camera to the feature's centre at mid-height / the "
        "frame's largest; *vertical view angle* between the view ray and the horizontal at the feature, / 90° "
        f"(0 side-on, 1 from above); *ROI distance*: the ROI is a {p['roi_m']:.0f} m disc on the ground around "
        f"the focus, rasterized on a {p['grid'][0]}×{p['grid'][1]} grid over the viewport, its distance map "
        "computed by jump flooding (benchmarks/jfa.py, JFA+1) and read at the feature's ground point on screen, / the "
        "map's largest distance (1 when the ROI is off screen).",
        "* **Interest** = mean of (1 − metric) over the three (weights "
        f"{', '.join(f'{w:g}' for w in p['weights'])}); **saliency** = interest × (lod + 1) / 4 (block 0.25, "
        "simplified solid 0.5, roofs 0.75, facades 1: the detail a feature is drawn with stands in for the "
        "thesis' texturing). The per-frame maps (`saliency/frame_NNN.png`) paint each visible feature's saliency "
        "over its screen box, the nearest winning a pixel; cyan: the ROI; green circles: top buildings visible, "
        "red crosses: visible only thanks to the landmark rule.",
        "* **Visible as itself**: its own row, or a block whose only member it is (a lone building is not "
        "aggregated), and visible as above.",
        "* **Without the landmark rule**: a landmark (lm.building.is_landmark, protected from aggregation) "
        "treated as an ordinary building. Where a block-band tile (gen_level ≤ 1) draws it as itself, it would "
        "be merged with every building whose simplified footprint lies within the band's aggregation distance "
        "(gen.tolerance; what ST_ClusterDBSCAN with minpoints 1 joins), or, alone, become a one-member block, "
        "omitted when sqrt(radius² + height²) ≤ the tolerance; in band 2 it is LOD1 instead of LOD2. Computed "
        "once per (landmark, block tile) from gen.footprint; the tile walk is kept as with the rule (without "
        "protection the block tiles' geometric errors could differ slightly). Non-landmarks are the same with and "
        "without, so *with < without* cannot happen.",
        "",
        f"## Top {len(report['top'])} by saliency score",
        "",
    ]
    rows = []
    for t in report["top"]:
        rows.append(
            [
                t["rank"],
                t["osm"],
                t["name"] or "–",
                "yes" if t["is_landmark"] else "no",
                t["level"],
                f"{t['frames_visible_with']} ({t['fraction_with']:.2f})",
                f"{t['frames_visible_without']} ({t['fraction_without']:.2f})",
                _f(t["mean_saliency_with"]),
                _f(t["mean_saliency_without"]),
                _f(t["mean_lod_with"], 1),
                _f(t["mean_lod_without"], 1),
            ]
        )
    lines += markdown_table(
        [
            "rank",
            "OSM",
            "name",
            "landmark",
            "level",
            "frames visible with rule (fraction)",
            "without",
            "mean saliency with",
            "without",
            "mean LOD with",
            "without",
        ],
        rows,
        "rlllrrrrrrr",
    )
    lines += [
        "",
        "Mean saliency and LOD drawn over the frames in which it is visible with the rule; *without*: the same "
        "frames, saliency 0 where it would not be seen as itself, LOD 0 in the block bands (inside a block or a "
        "block of its own), LOD1 instead of LOD2 in band 2.",
        "",
        "## Frames",
        "",
        f"* {s['frames_with_blocks']} of {p['frames']} frames draw a block band (gen_level ≤ 1) somewhere; "
        f"{s['frames_top_lost']} frames lose at least one top building without the rule.",
        f"* Visible features per frame: median {s['visible_median']:.0f}, max {s['visible_max']}; "
        f"{s['rows']:,} feature rows in `saliency/features.csv`.",
        f"* Mean over visible features and frames: view distance {s['mean_distance_n']:.3f}, vertical view angle "
        f"{s['mean_angle_deg']:.1f}°, ROI distance {s['mean_roi_n']:.3f}, interest {s['mean_interest']:.3f}.",
        f"* Mean saliency of a landmark of the top {len(report['top'])} over the frames it is visible in with the "
        f"rule: {_f(s['mean_saliency_landmarks_with'], 3)}; the same frames without the rule (0 where not seen as "
        f"itself): {_f(s['mean_saliency_landmarks_without'], 3)}; mean saliency of the other visible features "
        f"{_f(s['mean_saliency_others'], 3)} (frames weighted by their visible features).",
        f"* api.lod_for_view + features per frame: median {s['query_ms_median']:.1f} ms; the whole report "
        f"{report['seconds']:.1f} s ({s['png_s']:.1f} s of it writing the frame PNGs).",
        "",
    ]
    lines += machine_section(report["machine"])
    lines += ["", "![path, saliency per frame and visibility with and without the landmark rule](saliency.png)", ""]
    return "\n".join(lines)


# --- main --------------------------------------------------------------------------------------------------------


def local_xy(lon: np.ndarray, lat: np.ndarray, city: City) -> np.ndarray:
    """(n, 2) east/north metres from the city centre (tangent plane), for the map of the path."""
    enu = enu_rotation(math.radians(city.lon), math.radians(city.lat))
    d = vs.ecef(np.asarray(lon, float), np.asarray(lat, float), city.ground_h) - vs.ecef(
        city.lon, city.lat, city.ground_h
    )
    return (d @ enu)[:, :2]


def run(
    url: str,
    out: Path,
    frames: int = DEFAULT_FRAMES,
    top: int = TOP,
    roi_m: float = ROI_M,
    min_px: float = MIN_PX,
    grid_w: int = GRID_W,
    max_sse: float = MAX_SSE,
    near_m: float = NEAR_M,
    write_frames: bool = True,
    command: str = "",
) -> dict[str, Any]:
    t_start = time.perf_counter()
    out.mkdir(parents=True, exist_ok=True)
    fdir = out / "saliency"
    fdir.mkdir(exist_ok=True)
    for old in fdir.glob("frame_*.png"):
        old.unlink()
    import matplotlib

    matplotlib.use("Agg")
    with psycopg.connect(url, autocommit=True) as conn:
        conn.execute("SET default_transaction_read_only = on")
        city = read_city(conn)
        tops = read_top(conn, top)
        without = read_without(conn, top)
        far_m = far_distance(city, max_sse=max_sse)
        path = vs.camera_path(
            city.lon, city.lat, city.radius_m, near_m, far_m, frames, city.ground_h, FOV, VIEWPORT_H, ASPECT
        )
        log(
            f"{city.buildings:,} buildings, {len(tops)} top ({sum(t.is_landmark for t in tops)} landmarks), "
            f"{frames} frames from {near_m:.0f} to {far_m:.0f} m"
        )
        rank_of = {t.building_id: t.rank for t in tops}
        stats: list[dict[str, Any]] = []
        png_s = 0.0
        n_rows = 0
        with conn.cursor() as cur, open(fdir / "features.csv", "w", newline="") as fh:
            w = csv.writer(fh)
            w.writerow(_CSV_HEADER)
            for k, pf in enumerate(path):
                frame, query_s = measure_frame(cur, pf, city, roi_m, grid_w, min_px, max_sse)
                record_top(frame, tops, without)
                stats.append(frame_stats(k, pf, frame, tops, query_s))
                rows = feature_rows(k, frame, rank_of)
                w.writerows(rows)
                n_rows += len(rows)
                if write_frames:
                    t0 = time.perf_counter()
                    plot_frame(fdir / f"frame_{k:03d}.png", k, pf, frame, tops)
                    png_s += time.perf_counter() - t0
                if (k + 1) % 20 == 0:
                    log(f"frame {k + 1}/{frames}")
        # the scored buildings, for the map of the path
        pts = np.array(
            conn.execute(
                "SELECT ST_X(c), ST_Y(c), building_id FROM (SELECT building_id, "
                "ST_Transform(centroid, 4326) AS c FROM lm.building) s"
            ).fetchall(),
            float,
        )
        mach = machine(url, osm2pgsql=False)

    def col(key: str) -> np.ndarray:
        return _column(stats, key)

    def nanmean(a: np.ndarray) -> float | None:
        return float(np.nanmean(a)) if np.isfinite(a).any() else None

    def pooled(attr: str) -> float | None:
        lms = [np.asarray(getattr(t, attr), float) for t in tops if t.is_landmark]
        return nanmean(np.concatenate(lms)) if lms else None

    weights_visible = col("visible")
    summary = {
        "height_m": [float(col("height_m").min()), float(col("height_m").max())],
        "pitch": [float(col("pitch").min()), float(col("pitch").max())],
        "frames_with_blocks": int(sum(bool(f["bands"]) and min(f["bands"]) <= 1 for f in stats)),
        "frames_top_lost": int(sum(f["top_visible_without"] < f["top_visible_with"] for f in stats)),
        "visible_median": float(np.median(weights_visible)),
        "visible_max": int(weights_visible.max()),
        "rows": n_rows,
        # means over all visible features of all frames (frames weighted by their visible features)
        "mean_distance_n": _weighted(col("mean_distance_n"), weights_visible),
        "mean_angle_deg": _weighted(col("mean_angle_deg"), weights_visible),
        "mean_roi_n": _weighted(col("mean_roi_n"), weights_visible),
        "mean_interest": _weighted(col("mean_interest"), weights_visible),
        "mean_saliency_landmarks_with": pooled("saliency_with"),
        "mean_saliency_landmarks_without": pooled("saliency_without"),
        "mean_saliency_others": _weighted(col("mean_saliency_others"), col("visible_others")),
        "query_ms_median": float(np.median(col("query_ms"))),
        "png_s": round(png_s, 1),
    }
    report = {
        "command": command or f"python -m benchmarks.report_saliency --frames {frames}",
        "database": db_name(url),
        "machine": mach,
        "parameters": {
            "frames": frames,
            "fov": FOV,
            "viewport": [int(round(ASPECT * VIEWPORT_H)), VIEWPORT_H],
            "max_sse": max_sse,
            "near_m": near_m,
            "far_m": round(far_m, 1),
            "roi_m": roi_m,
            "min_px": min_px,
            "grid": [grid_w, int(round(grid_w / ASPECT))],
            "weights": list(WEIGHTS),
            "top": top,
        },
        "city": {
            "lon": city.lon,
            "lat": city.lat,
            "radius_m": round(city.radius_m, 1),
            "root_geometric_error": city.root_error,
            "ground_h": city.ground_h,
            "buildings": city.buildings,
        },
        "top": [t.as_dict(frames) for t in tops],
        "summary": summary,
        "frames": stats,
    }
    cams = np.array([[p.camera.lon, p.camera.lat] for p in path])
    tgts = np.array([[p.target_lon, p.target_lat] for p in path])
    xy = local_xy(pts[:, 0], pts[:, 1], city) if len(pts) else np.zeros((0, 2))
    where = {int(b): i for i, b in enumerate(pts[:, 2])} if len(pts) else {}
    tops_xy = np.array([xy[where[t.building_id]] for t in tops]).reshape(-1, 2)
    plot_summary(
        report,
        local_xy(cams[:, 0], cams[:, 1], city),
        local_xy(tgts[:, 0], tgts[:, 1], city),
        xy,
        tops_xy,
        out / "saliency.png",
    )
    report["seconds"] = round(time.perf_counter() - t_start, 1)
    (out / "saliency.json").write_text(json.dumps(report, indent=1, ensure_ascii=False) + "\n")
    (out / "saliency.md").write_text(render_markdown(report))
    log(
        f"wrote {out}/saliency.md, .json, .png, saliency/features.csv"
        + (f" and {frames} frame maps" if write_frames else "")
        + f" in {report['seconds']:.1f} s"
    )
    return report


def _column(frames: list[dict[str, Any]], key: str) -> np.ndarray:
    """One figure of every frame (frame_stats) as floats, None as NaN."""
    return np.array([np.nan if f[key] is None else f[key] for f in frames], float)


def _weighted(values: np.ndarray, weights: np.ndarray) -> float:
    ok = np.isfinite(values) & (weights > 0)
    return float(np.average(values[ok], weights=weights[ok])) if ok.any() else math.nan


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="python -m benchmarks.report_saliency", description=__doc__.split("\n\n")[0])
    p.add_argument("--db", help="database URL (default: DATABASE_URL, else the local cluster's city database)")
    p.add_argument("--out", type=Path, default=DEFAULT_OUT, help=f"output directory (default: {DEFAULT_OUT})")
    p.add_argument("--frames", type=int, default=DEFAULT_FRAMES, help=f"frames of the path (default {DEFAULT_FRAMES})")
    p.add_argument("--top", type=int, default=TOP, help=f"top buildings by saliency rank (default {TOP})")
    p.add_argument("--roi-m", type=float, default=ROI_M, help=f"radius of the region of interest (default {ROI_M})")
    p.add_argument("--min-px", type=float, default=MIN_PX, help=f"smallest visible screen box (default {MIN_PX})")
    p.add_argument("--no-frames", action="store_true", help="skip the per-frame PNGs")
    args = p.parse_args(argv)
    if args.frames < 1 or args.top < 1:
        p.error("--frames and --top must be at least 1")
    url = args.db or cluster.ensure()
    out: Path = REPO / args.out  # an absolute --out stays as it is
    command = f"python -m benchmarks.report_saliency --out {args.out} --frames {args.frames}"
    if args.db:
        command += f" --db {db_name(url)}"
    run(url, out, args.frames, args.top, args.roi_m, args.min_px, write_frames=not args.no_frames, command=command)
    return 0


if __name__ == "__main__":
    sys.exit(main())
