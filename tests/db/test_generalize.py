"""Stage generalize and the multi-LOD hierarchy on real data (Helsinki with a small tile budget, so the tree has
every band, a coarser block band above them included): each tile stands for every building below it exactly once,
blocks merge what is close and nothing else, footprints stay valid and close, errors are measured and grow towards
the root, and api.lod_for_view chooses exactly what a 3D Tiles client traversing the exported tileset.json
chooses."""

import json
import time

import numpy as np
import psycopg
import pytest

from core.camera import Camera
from core.geodesy import region_box
from core.tiles3d import expand
from exporter.checks import check_tileset
from tests.conftest import run_etl
from tests.support.traverse import select

BUDGET = {"CITYLOD_TILE_MAX_FEATURES": "40", "CITYLOD_TILE_MAX_TRIANGLES": "4000"}


@pytest.fixture(scope="module")
def deep(city, new_db, tmp_path_factory):
    """Helsinki with 40 features per leaf: a tree deep enough for blocks, LOD1, LOD2 and LOD3 bands."""
    src = city("helsinki")
    url = new_db("gen_deep")
    out = tmp_path_factory.mktemp("gen") / "tiles"
    run_etl(url, "ingest", "--osm", str(src.osm))
    run_etl(url, "lod")
    run_etl(url, "tiles", env=BUDGET)
    run_etl(url, "generalize")
    run_etl(url, "export", "--out", str(out))
    return url, out


def test_every_band_is_present(deep, conn_of) -> None:
    conn = conn_of(deep[0])
    bands = dict(conn.execute("SELECT gen_level, count(*) FROM tiles.tile GROUP BY 1").fetchall())
    # 0..4 always; a tree taller than 4 levels gets coarser block bands -1, -2, ... at its top
    assert {0, 1, 2, 3, 4} <= set(bands) and set(bands) == set(range(min(bands), 5)), bands
    wrong = conn.execute(
        """SELECT count(*) FROM tiles.tile WHERE is_leaf <> (height = 0)
           OR gen_level <> gen.level_for_height(height, (SELECT height FROM tiles.tile WHERE level = 0),
                                                 (SELECT size FROM tiles.grid) / 2 ^ level)"""
    ).fetchone()[0]
    assert wrong == 0
    lods = dict(
        conn.execute(
            """SELECT t.gen_level, array_agg(DISTINCT f.lod) FROM tiles.tile t
           CROSS JOIN LATERAL api.buildings_for_tile(t.level, t.x, t.y) f GROUP BY 1"""
        ).fetchall()
    )
    fine = {2: [1], 3: [2], 4: [3]}
    assert {g: v for g, v in lods.items() if g >= 2} == fine
    assert all(v in ([0, 1], [0]) for g, v in lods.items() if g <= 1), lods


def test_each_tile_draws_each_building_below_it_once(deep, conn_of) -> None:
    conn = conn_of(deep[0])
    # the osm outline ids a tile stands for (blocks, drawn or omitted, through their members) = the buildings
    # below it
    bad = conn.execute(
        """WITH drawn AS (
               SELECT t.level, t.x, t.y, coalesce(m.member, b.id) AS group_id
               FROM tiles.tile t
               CROSS JOIN LATERAL api.buildings_for_tile(t.level, t.x, t.y) f
               LEFT JOIN gen.block k ON f.feature_kind = 'block' AND k.block_id = f.building_id
               LEFT JOIN LATERAL unnest(k.members) m(member) ON true
               LEFT JOIN osm.building b ON f.feature_kind <> 'block' AND b.id = f.building_id
               UNION ALL
               SELECT k.level, k.x, k.y, m.member FROM gen.block k CROSS JOIN LATERAL unnest(k.members) m(member)
               WHERE k.omitted
           ), want AS (
               SELECT DISTINCT t.level, t.x, t.y, bt.group_id
               FROM tiles.tile t JOIN tiles.building_tile bt
                 ON bt.level >= t.level AND bt.x >> (bt.level - t.level) = t.x AND bt.y >> (bt.level - t.level) = t.y
           ), got AS (
               SELECT d.level, d.x, d.y, coalesce(o.parent_id, o.id) AS group_id, count(*) AS n
               FROM drawn d JOIN osm.building o ON o.id = d.group_id
               JOIN tiles.tile t USING (level, x, y)
               WHERE t.gen_level <= 2
               GROUP BY 1, 2, 3, 4
           )
           SELECT * FROM want w FULL JOIN got g USING (level, x, y, group_id)
           JOIN tiles.tile t USING (level, x, y)
           WHERE t.gen_level <= 2 AND (w.group_id IS NULL OR g.group_id IS NULL OR g.n <> 1)
           LIMIT 5"""
    ).fetchall()
    assert bad == []
    # LOD2 and LOD3 bands: every feature (building or part) below the tile once
    bad = conn.execute(
        """SELECT t.level, t.x, t.y FROM tiles.tile t
           WHERE t.gen_level >= 3 AND t.content_features <> t.n_features"""
    ).fetchall()
    assert bad == []


def test_blocks_merge_what_is_close_and_only_that(deep, conn_of) -> None:
    conn = conn_of(deep[0])
    n_blocks, multi = conn.execute("SELECT count(*), count(*) FILTER (WHERE n_members > 1) FROM gen.block").fetchone()
    assert multi > 20 and n_blocks > multi
    assert conn.execute("SELECT count(*) FROM gen.block WHERE n_members <> cardinality(members)").fetchone()[0] == 0
    # no two buildings of different blocks in one tile are within the band's distance (else one cluster); the
    # coarser bands cluster their children's simplified blocks, whose outlines moved, so only bands 0 and 1
    close = conn.execute(
        """SELECT a.block_id, b.block_id FROM gen.block a
           JOIN gen.block b ON (a.level, a.x, a.y) = (b.level, b.x, b.y) AND a.block_id < b.block_id
           JOIN gen.footprint fa ON fa.building_id = ANY(a.members)
           JOIN gen.footprint fb ON fb.building_id = ANY(b.members)
           WHERE a.gen_level >= 0 AND ST_DWithin(fa.geom, fb.geom, gen.tolerance(a.gen_level) * 0.999)
           LIMIT 3"""
    ).fetchall()
    assert close == []
    # members of one block are chained by gaps of at most the distance: the block covers its members (in the
    # coarser bands within the sum of the tolerances of the chain of blocks, < 2 x the band's)
    uncovered = conn.execute(
        """SELECT k.block_id FROM gen.block k JOIN gen.footprint f ON f.building_id = ANY(k.members)
           WHERE k.n_members > 1
             AND ST_Area(ST_Difference(f.geom, ST_Buffer(k.footprint, gen.tolerance(k.gen_level)
                                                                      * CASE WHEN k.gen_level < 0 THEN 2 ELSE 1 END)
                 )) > 1
           LIMIT 3"""
    ).fetchall()
    assert uncovered == []
    # a coarser band merges further: each of its tiles has fewer blocks than its children hold in their place
    # (drawn or omitted)
    grew = conn.execute(
        """SELECT t.level, t.x, t.y FROM tiles.tile t
           WHERE t.gen_level < 0 AND (SELECT count(*) FROM gen.block k WHERE (k.level, k.x, k.y) = (t.level, t.x, t.y))
             > (SELECT count(*) FROM tiles.tile_content c
                WHERE c.level = t.level + 1 AND c.x >> 1 = t.x AND c.y >> 1 = t.y)
             + (SELECT count(*) FROM gen.block k
                WHERE k.omitted AND k.level = t.level + 1 AND k.x >> 1 = t.x AND k.y >> 1 = t.y)"""
    ).fetchall()
    assert grew == []
    assert conn.execute("SELECT count(*) FROM gen.block WHERE gen_level < 0 AND n_members > 1").fetchone()[0] > 0
    # height is the members' area-weighted height
    off = conn.execute(
        """SELECT k.block_id, k.height, sum(g.height * ST_Area(f.geom)) / sum(ST_Area(f.geom)) FROM gen.block k
           JOIN gen.footprint f ON f.building_id = ANY(k.members)
           JOIN gen.building_mesh g ON g.building_id = f.building_id AND g.gen_level = 2
           GROUP BY k.block_id, k.height
           HAVING abs(k.height - sum(g.height * ST_Area(f.geom)) / sum(ST_Area(f.geom))) > 0.01"""
    ).fetchall()
    assert off == []


def test_blocks_too_small_for_their_band_are_omitted_with_their_error(deep, conn_of) -> None:
    conn = conn_of(deep[0])
    # the rule: omitted exactly when the members fit within the band's tolerance of one ground point
    by_rule = conn.execute(
        """WITH k AS (
               SELECT k.block_id, k.omitted, k.gen_level, k.error_m,
                      sqrt((ST_MinimumBoundingRadius(ST_Collect(f.geom))).radius ^ 2 + max(g.height) ^ 2) AS collapse,
                      -- the selection on tile error (tiles.omit_within_error)
                      bool_or(k.omitted AND k.total_error_m <= t.geometric_error) AS within_tile_error
               FROM gen.block k JOIN gen.footprint f ON f.building_id = ANY(k.members)
               JOIN gen.building_mesh g ON g.building_id = f.building_id AND g.gen_level = 2
               JOIN tiles.tile t ON (t.level, t.x, t.y) = (k.level, k.x, k.y)
               WHERE k.gen_level >= 0  -- the coarser bands measure their inputs' simplified outlines
               GROUP BY k.block_id)
           SELECT count(*) FILTER (WHERE omitted), count(*) FILTER (WHERE NOT omitted),
                  count(*) FILTER (WHERE omitted <> (collapse <= gen.tolerance(gen_level) + 1e-3 OR within_tile_error)
                                   AND abs(collapse - gen.tolerance(gen_level)) > 1e-3),
                  count(*) FILTER (WHERE omitted AND abs(error_m - collapse) > 1e-3),
                  count(*) FILTER (WHERE within_tile_error AND collapse > gen.tolerance(gen_level) + 1e-3)
           FROM k"""
    ).fetchone()
    assert by_rule[0] > 0 and by_rule[1] > 0, by_rule
    assert by_rule[2:4] == (0, 0), by_rule
    assert by_rule[4] > 0, "no block omitted on its tile's error alone"
    # the selection on tile error: no drawn block fits within its tile's error
    drawn_within = conn.execute(
        """SELECT count(*) FROM gen.block k JOIN tiles.tile t USING (level, x, y)
           WHERE NOT k.omitted AND k.collapse_m + (k.total_error_m - k.error_m) <= t.geometric_error"""
    ).fetchone()[0]
    assert drawn_within == 0
    # never drawn, and the tile's geometric error covers the omission
    drawn = conn.execute(
        """SELECT count(*) FROM gen.block k JOIN tiles.tile_content c
             ON c.feature_kind = 'block' AND c.feature_id = k.block_id WHERE k.omitted"""
    ).fetchone()[0]
    assert drawn == 0
    under = conn.execute(
        """SELECT count(*) FROM gen.block k JOIN tiles.tile t USING (level, x, y)
           WHERE k.omitted AND t.geometric_error < k.total_error_m - 1e-3"""
    ).fetchone()[0]
    assert under == 0
    # the coarser bands still merge omitted blocks: some block of a band < 0 has an omitted child block's members
    merged = conn.execute(
        """SELECT count(*) FROM gen.block p JOIN gen.block c
             ON c.level = p.level + 1 AND c.x >> 1 = p.x AND c.y >> 1 = p.y AND c.omitted AND c.members <@ p.members
           WHERE p.gen_level < 0 AND p.n_members > c.n_members"""
    ).fetchone()[0]
    assert merged > 0


def test_tile_content_lists_what_each_tile_draws(deep, conn_of) -> None:
    # tiles.finish_hierarchy lists the blocks from gen.block as made, decides the omissions on tile error, and
    # the rest from api.buildings_for_tile: what it stores must be what the exporter writes, tile by tile
    conn = conn_of(deep[0])
    only_drawn, only_listed, listed, blocks = conn.execute(
        """WITH f AS (SELECT t.level, t.x, t.y, f.feature_kind, f.building_id, f.osm_type, f.osm_id, f.lod,
                             f.gen_level, f.n_members, f.n_triangles, f.error_m
                      FROM tiles.tile t CROSS JOIN LATERAL api.buildings_for_tile(t.level, t.x, t.y) f),
                c AS (SELECT level, x, y, feature_kind, feature_id, osm_type, osm_id, lod, gen_level, n_members,
                             n_triangles, error_m FROM tiles.tile_content)
           SELECT (SELECT count(*) FROM (SELECT * FROM f EXCEPT SELECT * FROM c) a),
                  (SELECT count(*) FROM (SELECT * FROM c EXCEPT SELECT * FROM f) b),
                  (SELECT count(*) FROM c), (SELECT count(*) FROM c WHERE feature_kind = 'block')"""
    ).fetchone()
    assert (only_drawn, only_listed) == (0, 0) and listed > blocks > 0
    omitted = conn.execute("SELECT count(*) FROM gen.block WHERE built_error_m IS NOT NULL").fetchone()[0]
    assert omitted > 0, "no block omitted on its tile's error: the case is not covered"


def test_footprints_are_valid_close_and_smaller(deep, conn_of) -> None:
    conn = conn_of(deep[0])
    row = conn.execute(
        """SELECT count(*), count(*) FILTER (WHERE NOT ST_IsValid(geom)),
                  count(*) FILTER (WHERE status LIKE 'kept_original%%'
                                   AND abs(area_out_m2 - area_in_m2) > 0.1 * area_in_m2
                                   OR status NOT LIKE 'kept_original%%'
                                   AND abs(area_out_m2 - area_in_m2) > 0.1 * area_in_m2 + 1e-6),
                  sum(n_vertices_in), sum(n_vertices_out), max(error_m), max(tolerance_m)
           FROM gen.footprint"""
    ).fetchone()
    n, invalid, area_off, v_in, v_out, worst, tol = row
    groups = conn.execute("SELECT count(DISTINCT group_id) FROM tiles.building_tile").fetchone()[0]
    assert n == groups > 400 and invalid == 0 and area_off == 0  # one per building (outline and its parts)
    assert v_out < 0.85 * v_in  # Helsinki's centre outlines lose more than 15 % of their vertices at 2.5 m
    assert 0 < worst <= 2 * tol  # measured, and of the order of the tolerance
    # the stored error is the Hausdorff distance PostGIS measures between the outlines
    diff = conn.execute(
        """SELECT max(abs(f.error_m - ST_HausdorffDistance(ST_Boundary(b.geom_local), ST_Boundary(f.geom), 0.05)))
           FROM gen.footprint f JOIN osm.building b ON b.id = f.building_id"""
    ).fetchone()[0]
    assert diff < 0.05


def test_decimation_within_tolerance(deep, conn_of) -> None:
    conn = conn_of(deep[0])
    n, worst, saved = conn.execute(
        """SELECT count(*), max(error_m), sum(n_triangles_in - n_triangles) FROM gen.building_mesh
           WHERE gen_level = 3 AND geom IS NOT NULL"""
    ).fetchone()
    assert n > 0 and worst <= conn.execute("SELECT gen.tolerance(3)").fetchone()[0] and saved > 0
    assert (
        conn.execute(
            """SELECT count(*) FROM gen.building_mesh
           WHERE gen_level = 3 AND geom IS NOT NULL AND n_triangles >= n_triangles_in"""
        ).fetchone()[0]
        == 0
    )
    # every feature has its LOD2-band row, decimated or not
    assert (
        conn.execute(
            """SELECT count(*) FROM tiles.building_tile bt LEFT JOIN gen.building_mesh g
           ON g.building_id = bt.building_id AND g.gen_level = 3 WHERE g.building_id IS NULL"""
        ).fetchone()[0]
        == 0
    )


def test_geometric_error_is_measured_and_monotone(deep, conn_of) -> None:
    conn = conn_of(deep[0])
    rows = {
        (lv, x, y): (leaf, ge, ce)
        for lv, x, y, leaf, ge, ce in conn.execute(
            "SELECT level, x, y, is_leaf, geometric_error, content_error_m FROM tiles.tile"
        )
    }
    for (lv, x, y), (leaf, ge, ce) in rows.items():
        if leaf:
            assert ge == 0 and ce == 0
        else:
            assert ge >= ce > 0
            kids = [rows[k][1] for k in ((lv + 1, 2 * x + i, 2 * y + j) for i in (0, 1) for j in (0, 1)) if k in rows]
            assert kids and ge == pytest.approx(max(ce, *kids))
    # the coarsest band carries the 10 m aggregation and more; LOD2 tiles are near-exact
    by_band = dict(conn.execute("SELECT gen_level, max(content_error_m) FROM tiles.tile GROUP BY 1").fetchall())
    assert by_band[0] > by_band[2] > by_band[3] > 0 and by_band[4] == 0


def test_tileset_is_replace_with_content_everywhere(deep, conn_of) -> None:
    ts_path = deep[1] / "tileset.json"
    assert check_tileset(ts_path) == []
    # the export is implicit: the tree its subtrees stand for
    ts = expand(json.loads(ts_path.read_text()), lambda u: (deep[1] / u).read_bytes())
    assert ts["root"]["refine"] == "REPLACE"

    def walk(t):
        yield t
        for k in t.get("children", []):
            yield from walk(k)

    tiles = list(walk(ts["root"]))
    assert all("content" in t for t in tiles)
    assert len(tiles) == conn_of(deep[0]).execute("SELECT count(*) FROM tiles.tile").fetchone()[0]


def test_protected_buildings_are_never_merged(deep, conn_of, new_db) -> None:
    conn = conn_of(deep[0])
    # a building merged into a 5 m block below a 10 m band tile, so both block bands stand above it
    bid = conn.execute(
        """SELECT k.members[1] FROM gen.block k WHERE k.n_members > 3 AND k.gen_level = 1
             AND EXISTS (SELECT 1 FROM tiles.tile t WHERE t.gen_level = 0 AND t.level < k.level
                         AND k.x >> (k.level - t.level) = t.x AND k.y >> (k.level - t.level) = t.y)
           ORDER BY k.block_id LIMIT 1"""
    ).fetchone()[0]
    above = {
        g
        for (g,) in conn.execute(
            """SELECT DISTINCT t.gen_level FROM tiles.tile t JOIN tiles.building_tile bt ON bt.group_id = %s
           AND bt.level >= t.level AND bt.x >> (bt.level - t.level) = t.x AND bt.y >> (bt.level - t.level) = t.y
           WHERE t.gen_level <= 2""",
            (bid,),
        )
    }
    assert {0, 1} <= above
    conn.execute("UPDATE osm.building SET protected = true WHERE id = %s", (bid,))
    try:
        run_etl(deep[0], "generalize")
        assert conn.execute("SELECT count(*) FROM gen.block WHERE %s = ANY(members)", (bid,)).fetchone()[0] == 0
        bands = conn.execute(
            """SELECT DISTINCT t.gen_level, f.lod FROM tiles.tile t
               CROSS JOIN LATERAL api.buildings_for_tile(t.level, t.x, t.y) f
               WHERE f.feature_kind <> 'block' AND f.building_id = %s AND t.gen_level <= 2""",
            (bid,),
        ).fetchall()
        assert {b for b, _ in bands} == above and {lod for _, lod in bands} == {1}
    finally:
        conn.execute("UPDATE osm.building SET protected = false WHERE id = %s", (bid,))
        run_etl(deep[0], "generalize")


CAMERAS = [  # Helsinki's centre spans lon 24.935-24.953, lat 60.164-60.179
    Camera(24.944, 60.171, 30_000, 0, -90),  # the whole centre from far above
    Camera(24.944, 60.171, 3_000, 0, -90),
    Camera(24.944, 60.171, 800, 30, -45),
    Camera(24.941, 60.170, 150, 120, -20),  # street level, oblique
    Camera(24.95, 60.175, 400, 250, -60),
    Camera(24.944, 60.156, 1_500, 0, -30, fov=40, viewport_height=720, aspect=1.0),  # 1.7 km south, looking north
]


@pytest.mark.parametrize("cam", CAMERAS, ids=lambda c: f"{c.height:g}m{c.heading:g}h{c.pitch:g}p")
def test_lod_for_view_agrees_with_the_tileset_traversal(deep, conn_of, cam) -> None:
    conn = conn_of(deep[0])
    ts = json.loads((deep[1] / "tileset.json").read_text())
    want = {d.uri: d.sse for d in select(ts, cam, read=lambda u: (deep[1] / u).read_bytes())}
    # every feature of the drawn tiles, as a client loads them (the default culls by feature, tested below)
    rows = conn.execute(
        """SELECT DISTINCT format('content/%%s/%%s/%%s.glb', level, x, y), screen_space_error
           FROM api.lod_for_view(ST_SetSRID(ST_MakePoint(%s, %s, %s), 4326), %s, %s, %s, %s, 16, %s,
                                 cull_features => false)""",
        (cam.lon, cam.lat, cam.height, cam.heading, cam.pitch, cam.fov, cam.viewport_height, cam.aspect),
    ).fetchall()
    got = dict(rows)
    assert want, "the camera sees nothing: a useless test camera"
    assert set(got) == set(want)
    for uri, sse in want.items():
        assert got[uri] == pytest.approx(sse, rel=1e-6, abs=1e-9)


def _view(conn: psycopg.Connection, cam: Camera, cull: bool) -> list[tuple]:
    return conn.execute(
        """SELECT v.level, v.x, v.y, v.feature_kind, v.feature_id, c.cx, c.cy, c.cz, c.radius
           FROM api.lod_for_view(ST_SetSRID(ST_MakePoint(%s, %s, %s), 4326), %s, %s, %s, %s, 16, %s, %s) v
           JOIN tiles.tile_content c ON (c.level, c.x, c.y, c.feature_kind, c.feature_id)
                                      = (v.level, v.x, v.y, v.feature_kind, v.feature_id)""",
        (cam.lon, cam.lat, cam.height, cam.heading, cam.pitch, cam.fov, cam.viewport_height, cam.aspect, cull),
    ).fetchall()


@pytest.mark.parametrize("cam", CAMERAS, ids=lambda c: f"{c.height:g}m{c.heading:g}h{c.pitch:g}p")
def test_lod_for_view_returns_the_drawn_features_in_the_frustum(deep, conn_of, cam) -> None:
    # of the drawn tiles' features exactly those whose bounding sphere meets the frustum, by the same plane
    # test written in numpy
    conn = conn_of(deep[0])
    every = _view(conn, cam, cull=False)
    centre = np.array([r[5:8] for r in every], float)
    radius = np.array([r[8] for r in every], float)
    dist = (centre - cam.position()) @ cam.planes().T
    inside = (dist >= -radius[:, None]).all(axis=1)
    # knife-edge spheres (within a millimetre of a plane) may go either way in float4/float8
    edge = (np.abs(dist + radius[:, None]) < 1e-3).any(axis=1)
    got = {r[:5] for r in _view(conn, cam, cull=True)}
    want = {r[:5] for r, keep in zip(every, inside, strict=True) if keep}
    sure = {r[:5] for r, e in zip(every, edge, strict=True) if not e}
    assert got & sure == want & sure and got <= {r[:5] for r in every}
    assert got, "the camera sees nothing: a useless test camera"


def test_feature_spheres_bound_their_meshes(deep, conn_of) -> None:
    # every vertex of every feature's mesh (its tile's content, as exported) inside the stored sphere: a sphere
    # too small would drop a visible feature from api.lod_for_view
    conn = conn_of(deep[0])
    rows = conn.execute(
        """SELECT c.level, c.feature_kind, max(sqrt((ST_X(p) - c.cx) ^ 2 + (ST_Y(p) - c.cy) ^ 2
                                                   + (ST_Z(p) - c.cz) ^ 2) / c.radius) AS worst, count(*)
           FROM tiles.tile_content c
           CROSS JOIN LATERAL (SELECT f.geom FROM api.buildings_for_tile(c.level, c.x, c.y) f
                               WHERE f.feature_kind = c.feature_kind AND f.building_id = c.feature_id) g
           CROSS JOIN LATERAL ST_DumpPoints(g.geom) d
           CROSS JOIN LATERAL (SELECT ST_Transform(d.geom, 4978) AS p) q  -- base height 0
           WHERE c.x % 3 = 0
           GROUP BY 1, 2"""
    ).fetchall()
    assert {k for _, k, _, _ in rows} >= {"block", "building"}
    for level, kind, worst, n in rows:
        # never outside; the farthest vertex of a group near the sphere (at most radius / 1.002 at a box corner,
        # less when no vertex is at one: a roof apex)
        assert 0.5 < worst <= 1.0, (level, kind, worst, n)


def test_tile_boxes_are_their_regions_boxes(deep, conn_of) -> None:
    # tiles.set_boxes stores each tile's box where it belongs: exactly region_box of its own region
    rows = conn_of(deep[0]).execute("SELECT region, box FROM tiles.tile ORDER BY level DESC, x DESC, y").fetchall()
    assert len(rows) > 4 and all(b is not None for _, b in rows)
    np.testing.assert_array_equal(np.array([b for _, b in rows]), region_box(np.array([r for r, _ in rows])))


def test_the_walk_inlines_its_box_tests(deep, conn_of) -> None:
    # tiles.box_visible / box_distance are SQL functions meant to be inlined into api.lod_for_view's walk: called
    # as functions they cost the walk several times over (a STRICT one stops being inlined)
    plan = (
        conn_of(deep[0])
        .execute(
            """EXPLAIN (VERBOSE, FORMAT JSON)
           SELECT tiles.box_visible(box, 1, 2, 3, ARRAY[1, 0, 0, -1, 0, 0, 0, 1, 0, 0, -1, 0, 0, 0, 1]),
                  tiles.box_distance(box, 1, 2, 3)
           FROM tiles.tile"""
        )
        .fetchone()[0]
    )
    text = json.dumps(plan)
    assert "box_visible" not in text and "box_distance" not in text and "box[12]" in text
    # and the per-feature sphere test, evaluated on every row of a drawn tile
    plan = (
        conn_of(deep[0])
        .execute(
            """EXPLAIN (VERBOSE, FORMAT JSON)
           SELECT tiles.sphere_visible(cx, cy, cz, radius, 1, 2, 3,
                                       ARRAY[1, 0, 0, -1, 0, 0, 0, 1, 0, 0, -1, 0, 0, 0, 1])
           FROM tiles.tile_content"""
        )
        .fetchone()[0]
    )
    assert "sphere_visible" not in json.dumps(plan)


def test_far_view_is_coarse_and_cheap(deep, conn_of) -> None:
    conn = conn_of(deep[0])
    far, near = CAMERAS[0], CAMERAS[3]

    def view(cam):
        return conn.execute(
            """SELECT v.lod, count(*), sum(f.n_triangles) FROM api.lod_for_view(
                   ST_SetSRID(ST_MakePoint(%s, %s, %s), 4326), %s, %s, %s, %s, cull_features => false) v
               CROSS JOIN LATERAL (SELECT n_triangles FROM api.buildings_for_tile(v.level, v.x, v.y) b
                                   WHERE b.feature_kind = v.feature_kind AND b.building_id = v.feature_id) f
               GROUP BY v.lod""",
            (cam.lon, cam.lat, cam.height, cam.heading, cam.pitch, cam.fov, cam.viewport_height),
        ).fetchall()

    far_lods = {lod for lod, *_ in view(far)}
    assert far_lods <= {0, 1}
    assert 3 in {lod for lod, *_ in view(near)}
    far_tris = sum(t for *_, t in view(far))
    all_lod3 = conn.execute("SELECT sum(n_triangles) FROM lod.building_mesh WHERE lod = 3").fetchone()[0]
    assert far_tris * 5 <= all_lod3


def test_a_tile_missing_buildings_is_refused(deep, conn_of) -> None:
    conn = conn_of(deep[0])
    # the transaction is rolled back: the module's database stays as it was
    with (
        pytest.raises(psycopg.errors.RaiseException, match="do not stand for the buildings below them"),
        conn.transaction(),
    ):
        conn.execute("DELETE FROM gen.block WHERE block_id = (SELECT min(block_id) FROM gen.block)")
        conn.execute("CALL tiles.finish_hierarchy(0)")


def _gen_digest(conn: psycopg.Connection) -> tuple[str, str, str]:
    return conn.execute(
        """SELECT (SELECT md5(string_agg(concat_ws(':', building_id, md5(ST_AsEWKB(geom)::text), n_vertices_out,
                                                   error_m, status), ',' ORDER BY building_id)) FROM gen.footprint),
                  (SELECT md5(string_agg(concat_ws(':', building_id, gen_level,
                                                   md5(coalesce(ST_AsEWKB(geom), '')::text),
                                                   md5(coalesce(semantics, '')::text), n_triangles, error_m,
                                                   total_error_m, status), ',' ORDER BY building_id, gen_level))
                   FROM gen.building_mesh),
                  (SELECT md5(string_agg(concat_ws(':', level, x, y, members::text, md5(ST_AsEWKB(geom)::text),
                                                   error_m), ',' ORDER BY level, x, y, members::text))
                   FROM gen.block)"""
    ).fetchone()


def test_the_same_rows_on_one_or_two_dask_workers_and_a_hung_batch_is_kept_as_mapped(new_db, conn_of) -> None:
    """The footprint and decimation batches as Dask tasks on 2 workers give the rows one process gives; with a
    time limit every batch exceeds, every building is kept as mapped and every LOD2 mesh undecimated, each
    saying why, and the hierarchy still stands for every building."""
    from tests.conftest import helsinki

    url = new_db("gen_workers")
    run_etl(url, "ingest", "--osm", str(helsinki()))
    run_etl(url, "lod")
    run_etl(url, "tiles", env=BUDGET)
    conn = conn_of(url)
    run_etl(url, "generalize", env={"CITYLOD_GEN_WORKERS": "1"})
    one = _gen_digest(conn)
    assert all(one)
    run_etl(url, "generalize", env={"CITYLOD_GEN_WORKERS": "2"})
    assert _gen_digest(conn) == one
    proc = run_etl(url, "generalize", env={"CITYLOD_GEN_WORKERS": "2", "CITYLOD_GEN_BATCH_TIMEOUT_S": "0.001"})
    assert "Timeout (" in proc.stderr
    c = conn.execute(
        "SELECT counts FROM meta.pipeline_run WHERE stage = 'generalize' ORDER BY run_id DESC LIMIT 1"
    ).fetchone()[0]
    # nothing lost: every building kept as mapped, its LOD2 meshes its level-2 mesh, the status saying why
    assert c["in"] == c["out"] == c["out_by_kind"]["left as mapped"] == c["footprints"]["lost"] > 100
    fp = conn.execute("""SELECT count(*), count(*) FILTER (WHERE f.status LIKE 'kept_original: generalize hung%%'
                                                                AND f.status LIKE '%%time limit%%'
                                                                AND m.error_m = 0 AND m.n_triangles = (
                             SELECT sum(l.n_triangles) FROM tiles.building_tile bt JOIN lod.building_mesh l
                             ON l.building_id = bt.building_id AND l.lod = 2 WHERE bt.group_id = f.building_id))
                         FROM gen.footprint f JOIN gen.building_mesh m ON m.building_id = f.building_id
                                                                      AND m.gen_level = 2""").fetchone()
    assert fp[0] == fp[1] == c["in"]
    kept = conn.execute(
        "SELECT count(*), count(*) FILTER (WHERE geom IS NULL AND status LIKE 'kept: decimation hung%')"
        " FROM gen.building_mesh WHERE gen_level = 3"
    ).fetchone()
    assert kept[0] == c["decimation"]["features"] == c["decimation"]["lost"] == kept[1] > 100
    run_etl(url, "generalize", env={"CITYLOD_GEN_WORKERS": "1"})
    assert _gen_digest(conn) == one


def test_a_query_read_beside_a_failing_step_is_cancelled(server_url) -> None:
    # generalize reads the decimation digests beside the footprint step (core.db.thread_map): a step that fails
    # leaves no query running behind it, which the block would wait for at its end
    from core.db import thread_map

    mark = "beside-a-failing-step"
    cancelled: list[bool] = []

    def sleep(c: psycopg.Connection, _: None) -> None:
        try:
            c.execute(f"SELECT pg_sleep(60) -- {mark}")
        except psycopg.errors.QueryCanceled:
            cancelled.append(True)

    with (
        psycopg.connect(server_url, autocommit=True) as watch,
        pytest.raises(RuntimeError, match="the step failed"),
        thread_map(server_url, sleep, [None], 1),
    ):
        for _ in range(200):  # until the query runs: a cancel before it is sent cancels nothing
            if watch.execute(
                "SELECT count(*) FROM pg_stat_activity WHERE state = 'active' AND query LIKE %s", (f"%-- {mark}",)
            ).fetchone()[0]:
                break
            time.sleep(0.05)
        raise RuntimeError("the step failed")
    assert cancelled == [True]
