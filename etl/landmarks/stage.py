"""Stage landmarks: which buildings are "distinguished" (thesis section 3.4), from their saliency.

Runs after lod (it measures the LOD2 meshes) and before tiles/generalize (landmarks are never aggregated):

1. one set-based query gives, per drawn building (an outline with its parts, or a lone part), its point on
   surface, footprint shape, height and volume of its meshes and its semantic tags;
2. in numpy (etl/landmarks/saliency.py): the measures (height, volume, footprint area, height relative to the
   neighbours within lm_neighbour_radius_m, shape distinctiveness, semantic tags), each normalized, weighted
   by the lm_w_* settings into a score in [0, 1]; the Winter et al. voting hierarchy over the Delaunay
   triangulation of the points gives each building's landmark level;
3. lm.building gets every measure, the score, rank and level (COPY); the highest levels holding at most
   lm_max_fraction of the buildings are the landmarks, flagged osm.building.protected;
4. each landmark gets its predefined exaggeration intervals (lm_min_screen_px, lm_scale_step, lm_max_scale;
   etl.landmarks.saliency.exaggeration_intervals), which api.landmark_scale and api.landmark_exaggeration read;
5. lm.exaggeration gets each building's part in the exaggeration (lm.fill_exaggeration: lm.exaggeration_role
   of the landmarks and the buildings within their reach), which the exporter writes into every feature.

The hierarchy needs every point at once, so the stage holds a few float arrays per building (~100 bytes each,
100 MB at 1M buildings), never the geometries, and never the neighbour pairs of the whole city: those are summed
a block of buildings at a time (etl.landmarks.saliency.neighbour_sums).
"""

from __future__ import annotations

import time
from dataclasses import dataclass
from typing import Any, LiteralString

import numpy as np
import psycopg
import shapely

from core.changes import Changes, differing
from core.db import working_srid
from core.progress import Balance, summary
from core.settings import Settings
from core.stage import Context, Result
from etl.landmarks import saliency as lm

#: what a tile's content reads of a building's landmark rows: the buildings whose rows differ here after the
#: stage are what it changed for the stages after it (core/changes.py)
_READ = "SELECT * FROM lm.tile_inputs()"
_CHANGED = f"SELECT DISTINCT building_id FROM ({differing(_READ, '_lm_was')}) d"

#: Semantic measure: weight of each tag flag (sum 1). A flag holds when the outline or any of its parts has it.
SEMANTIC = {
    "worship": 0.2,
    "religious_building": 0.2,
    "tower": 0.15,
    "historic": 0.15,
    "wikidata": 0.15,
    "tourism": 0.1,
    "name": 0.05,
}
EVERY_BAND = -32768  # lm.building.lod2_band of the top landmark: LOD2 in every band
RELIGIOUS = ["cathedral", "church", "chapel", "mosque", "temple", "synagogue", "shrine", "monastery", "basilica"]
TOWERS = ["tower", "lighthouse", "water_tower", "communications_tower"]

# lm.building, COPYed in rank order; centroid as EWKB (geometry_recv takes it as it is)
_COLUMNS = (
    "building_id",
    "centroid",
    "height_m",
    "volume_m3",
    "area_m2",
    "relative_height",
    "shape_distinctiveness",
    "semantic",
    "score",
    "rank",
    "level",
    "is_landmark",
    "lod2_band",
    "radius_m",
    "scale_distances_m",
    "scale_factors",
)
_TYPES = (
    "int8",
    "bytea",
    "float4",
    "float8",
    "float8",
    "float4",
    "float4",
    "float4",
    "float4",
    "int4",
    "int2",
    "bool",
    "int2",
    "float4",
    "float4[]",
    "float4[]",
)


_BOOL = ("worship", "religious", "tower", "historic", "wikidata", "tourism", "named")
_DTYPE: dict[str, type] = {"building_id": np.int64, **dict.fromkeys(_BOOL, np.bool_)}


def weights(settings: Settings) -> dict[str, float]:
    return {
        "height": settings.lm_w_height,
        "volume": settings.lm_w_volume,
        "area": settings.lm_w_area,
        "relative_height": settings.lm_w_relative_height,
        "shape": settings.lm_w_shape,
        "semantic": settings.lm_w_semantic,
    }


def landmark_min_level(level: np.ndarray, max_fraction: float) -> int:
    """The lowest hierarchy level L >= 1 whose buildings (level >= L) are at most max(1, max_fraction × n); the
    top level always qualifies (it holds one building)."""
    if len(level) < 2:
        return 1
    at_least = np.cumsum(np.bincount(level)[::-1])[::-1]  # at_least[L] = count(level >= L)
    budget = max(1, int(max_fraction * len(level)))
    ok = np.nonzero(at_least[1:] <= budget)[0]
    return int(ok[0]) + 1


@dataclass(frozen=True)
class _Scored:
    """Every drawn building's measures, score, rank, hierarchy level and landmark role, in the input's order."""

    ids: np.ndarray
    xy: np.ndarray
    radius: np.ndarray
    height: np.ndarray
    volume: np.ndarray
    area: np.ndarray
    relative: np.ndarray
    shape: np.ndarray
    semantic: np.ndarray
    score: np.ndarray
    rank: np.ndarray
    level: np.ndarray
    min_level: int
    is_landmark: np.ndarray
    lod2_band: np.ndarray
    intervals: list[tuple[list[float] | None, list[float] | None]]
    weights: dict[str, float]


def run(ctx: Context) -> Result:
    conn, settings = ctx.conn, ctx.settings
    t0 = time.perf_counter()
    srid = working_srid(conn)
    sc = _score(_read_units(conn), settings)
    ids, level, is_landmark, min_level = sc.ids, sc.level, sc.is_landmark, sc.min_level
    n = len(ids)
    with conn.transaction(), conn.cursor() as cur:
        cur.execute(f"CREATE TEMP TABLE _lm_was ON COMMIT DROP AS {_READ}")
        cur.execute("DELETE FROM lm.building")  # not TRUNCATE: readers keep the rows of before until the commit
        _copy_ranked(cur, sc, srid)
        cur.execute("CALL lm.flag_landmarks()")
        # every drawn building is scored (the lod stage recorded the ones it could not draw); checked before commit
        drawn = _scalar(cur, "SELECT lod.drawn_buildings()")
        scored = _scalar(cur, "SELECT count(*) FROM lm.building")
        balance = Balance("drawn buildings", int(drawn), {"scored": int(scored)})
        cur.execute("ANALYZE lm.building")
        # each building's part in the exaggeration, stored once here: the exporter read it per feature per tile
        cur.execute("CALL lm.fill_exaggeration()")
        roles = _scalar(cur, "SELECT count(*) FROM lm.exaggeration")
        cur.execute("ANALYZE lm.exaggeration")
        changed = [int(i) for (i,) in cur.execute(_CHANGED)]
    top = ids[np.argsort(sc.rank)[:10]].tolist()
    seconds = time.perf_counter() - t0
    n_lm = int(is_landmark.sum())
    summary(
        "landmarks",
        balance,
        f"{int(level.max(initial=0))} hierarchy levels, {n_lm:,} landmarks (level >= {min_level})",
        seconds,
        n,
    )
    return Result(
        {
            **balance.counts(),
            "buildings": n,
            "levels": int(level.max(initial=0)),
            "landmark_min_level": min_level,
            "landmarks": n_lm,
            "exaggeration_roles": int(roles),
            "top10": top,
            "weights": sc.weights,
            "seconds": round(seconds, 3),
            "buildings_per_s": round(n / seconds, 1) if seconds > 0 else None,
        },
        Changes(buildings=changed),
    )


def _scalar(cur: psycopg.Cursor[Any], query: LiteralString) -> Any:
    """The first column of the one row ``query`` returns."""
    row = cur.execute(query).fetchone()
    assert row is not None
    return row[0]


def _read_units(conn: psycopg.Connection[Any]) -> dict[str, np.ndarray]:
    """lm.building_measures as numpy columns by name."""
    # lm.building_measures (sql/lm/building_measures.sql), an inlined SQL function streamed into columns by name
    # Each batch becomes numpy columns at once: a list of Python objects per column and building cost ~15x
    # the memory of the arrays (a third of the stage's peak at 107k buildings).
    with conn.cursor(name="lm_units") as src:
        src.itersize = 20_000
        src.execute("SELECT * FROM lm.building_measures(%s, %s)", (RELIGIOUS, TOWERS))
        assert src.description is not None
        chunks: dict[str, list[np.ndarray]] = {d.name: [] for d in src.description}
        while rows := src.fetchmany(20_000):
            for (name, c), vals in zip(chunks.items(), zip(*rows, strict=True), strict=True):
                c.append(np.array(vals, dtype=_DTYPE.get(name, np.float64)))
    return {k: np.concatenate(v) if v else np.zeros(0, dtype=_DTYPE.get(k, np.float64)) for k, v in chunks.items()}


def _score(cols: dict[str, np.ndarray], settings: Settings) -> _Scored:
    """The measures of every building, its saliency score, rank and level in the voting hierarchy, and for the
    landmarks their LOD2 band and exaggeration intervals."""
    ids = cols["building_id"]
    n = len(ids)
    xy = np.column_stack([cols["x"], cols["y"]]) if n else np.zeros((0, 2))
    area, perimeter, mrr, nverts, height, volume = (
        cols[k] for k in ("area", "perimeter", "envelope_area", "n_points", "height", "volume")
    )
    flags = np.column_stack([cols[k] for k in _BOOL]) if n else np.zeros((0, len(SEMANTIC)), bool)
    radius = cols["radius"]

    # one pass over the neighbour pairs, summed block by block (never all pairs at once): sum of heights for the
    # relative height, sums of descriptors and of their squares for the shape
    raw = lm.shape_descriptors(area, perimeter, mrr, nverts)
    desc = lm.fill_descriptors(raw)
    count, sums = lm.neighbour_sums(
        xy, settings.lm_neighbour_radius_m, np.column_stack([height, desc, desc**2]) if n else np.zeros((0, 9))
    )
    relative = lm.relative_height(height, sums=(count, sums[:, 0]))
    shape = lm.shape_distinctiveness(raw, sums=(count, sums[:, 1:]))  # its global spread from the raw values
    semantic = flags.astype(float) @ np.array(list(SEMANTIC.values()))
    # volume, area and relative height are heavy-tailed: logs, so one hangar does not squash the city to ~0
    measures = {
        "height": height,
        "volume": np.log1p(volume),
        "area": np.log1p(area),
        "relative_height": np.log(np.maximum(relative, 1e-3)),
        "shape": shape,
        "semantic": semantic,
    }
    w = weights(settings)
    score = lm.saliency(measures, w) if n else np.zeros(0)
    level = lm.voting_hierarchy(xy, score)
    rank = np.empty(n, dtype=np.int64)
    rank[np.lexsort((ids, -score))] = np.arange(1, n + 1)  # ties: lower id first
    min_level = landmark_min_level(level, settings.lm_max_fraction)
    is_landmark = level >= min_level
    # from the lowest landmark level LOD2 replaces the simplified solid in band 2, one band coarser per level;
    # the top of the hierarchy, the city's landmark, in every band (the smallest band there can be)
    lod2_band = np.where(is_landmark, 2 - (level - min_level), 0)
    lod2_band[level == level.max(initial=0)] = EVERY_BAND
    intervals = _intervals(height, level, min_level, is_landmark, settings)
    return _Scored(
        ids,
        xy,
        radius,
        height,
        volume,
        area,
        relative,
        shape,
        semantic,
        score,
        rank,
        level,
        min_level,
        is_landmark,
        lod2_band,
        intervals,
        w,
    )


def _intervals(
    height: np.ndarray, level: np.ndarray, min_level: int, is_landmark: np.ndarray, settings: Settings
) -> list[tuple[list[float] | None, list[float] | None]]:
    """The predefined exaggeration intervals (boundaries, scales) of each landmark; (None, None) for the others."""
    # a loop over the landmarks, ~1 % of the buildings
    from_m, top_scale = lm.exaggeration_intervals(
        height,
        level,
        min_level,
        min_screen_px=settings.lm_min_screen_px,
        step=settings.lm_scale_step,
        max_scale=settings.lm_max_scale,
    )
    intervals: list[tuple[list[float] | None, list[float] | None]] = [(None, None)] * len(height)
    for i in np.flatnonzero(is_landmark):
        b, s = lm.interval_arrays(float(from_m[i]), settings.lm_scale_step, float(top_scale[i]))
        intervals[i] = (b.tolist(), s.tolist())
    return intervals


def _copy_ranked(cur: psycopg.Cursor[Any], sc: _Scored, srid: int) -> None:
    """lm.building, COPYed in rank order (as analysts read it), the points as EWKB in the working CRS."""
    n = len(sc.ids)
    # the points as EWKB in the working CRS: what ST_SetSRID(ST_MakePoint(x, y), srid) would make of them
    centroids = shapely.to_wkb(shapely.set_srid(shapely.points(sc.xy), srid), include_srid=True) if n else []
    band = [int(b) if lm_ else None for b, lm_ in zip(sc.lod2_band.tolist(), sc.is_landmark.tolist(), strict=True)]
    with cur.copy(f"COPY lm.building ({', '.join(_COLUMNS)}) FROM STDIN (FORMAT BINARY)") as copy:
        copy.set_types(list(_TYPES))
        # in rank order, as analysts read it; each column made a list at once (numpy scalars row by row took
        # 0.36 s against 0.09 s for 106k rows of synthetic columns, measured alone)
        order = np.argsort(sc.rank)
        at = order.tolist()
        ranked = [
            c[order].tolist()
            for c in (
                sc.ids,
                sc.height,
                sc.volume,
                sc.area,
                sc.relative,
                sc.shape,
                sc.semantic,
                sc.score,
                sc.rank,
                sc.level,
                sc.is_landmark,
            )
        ]
        for row in zip(
            ranked[0],
            [centroids[i] for i in at],
            *ranked[1:],
            [band[i] for i in at],
            sc.radius[order].tolist(),
            *zip(*[sc.intervals[i] for i in at], strict=True),
            strict=True,
        ):
            copy.write_row(row)
