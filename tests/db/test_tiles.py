"""Stage tiles: every feature in exactly one leaf, a building never split, budgets respected, regions nested."""

import math

import pytest

from tests.conftest import run_etl


def test_fixture_tree(city, conn_of) -> None:
    conn = conn_of(city("fixtures").url)
    n_mesh = conn.execute("SELECT count(*) FROM lod.building_mesh WHERE lod = 1").fetchone()[0]
    rows = conn.execute("SELECT building_id, count(*) FROM tiles.building_tile GROUP BY 1").fetchall()
    assert len(rows) == n_mesh and all(n == 1 for _, n in rows)
    assert split_buildings(conn) == []


def split_buildings(conn) -> list:
    """Buildings (outline + parts) whose meshes landed in more than one tile."""
    return conn.execute(
        """SELECT coalesce(b.parent_id, b.id) FROM tiles.building_tile bt JOIN osm.building b ON b.id = bt.building_id
           GROUP BY 1 HAVING count(DISTINCT (bt.level, bt.x, bt.y)) > 1"""
    ).fetchall()


TRIANGLES = 3_000  # below what 60 features hold at LOD3 (~200 triangles each), above it at LOD1 (~30)


@pytest.fixture(scope="module")
def small_budget(city, new_db):
    """Helsinki (572 buildings and parts) tiled with a budget of 60 features and 3,000 triangles per tile, to get
    a deep tree."""
    src = city("helsinki")
    url = new_db("tiles_budget")
    run_etl(url, "ingest", "--osm", str(src.osm))
    run_etl(url, "lod")
    run_etl(url, "tiles", env={"CITYLOD_TILE_MAX_FEATURES": "60", "CITYLOD_TILE_MAX_TRIANGLES": str(TRIANGLES)})
    return url


def test_budget_and_single_assignment(small_budget, conn_of) -> None:
    conn = conn_of(small_budget)
    assert conn.execute("SELECT max(level) FROM tiles.tile").fetchone()[0] >= 3
    over = conn.execute(
        """SELECT t.level, t.x, t.y, t.n_features,
                  (SELECT count(DISTINCT coalesce(b.parent_id, b.id)) FROM tiles.building_tile bt
                   JOIN osm.building b ON b.id = bt.building_id
                   WHERE (bt.level, bt.x, bt.y) = (t.level, t.x, t.y)) AS groups
           FROM tiles.tile t WHERE t.is_leaf AND t.n_features > 60"""
    ).fetchall()
    assert all(groups == 1 for *_, groups in over), over  # only a single big building may exceed the budget
    # the triangle budget counts LOD3, the largest mesh, so a tile exported at any LOD keeps to it
    heavy = conn.execute(
        """SELECT bt.level, bt.x, bt.y, sum(m.n_triangles), count(DISTINCT coalesce(b.parent_id, b.id))
           FROM tiles.building_tile bt JOIN osm.building b ON b.id = bt.building_id
           JOIN lod.building_mesh m ON m.building_id = bt.building_id AND m.lod = 3
           WHERE bt.level < 16  -- the deepest level is a leaf whatever its load
           GROUP BY 1, 2, 3 HAVING sum(m.n_triangles) > %s""",
        (TRIANGLES,),
    ).fetchall()
    assert all(groups == 1 for *_, groups in heavy), heavy
    total = conn.execute("SELECT count(*) FROM lod.building_mesh WHERE lod = 1").fetchone()[0]
    assigned = conn.execute("SELECT count(*), count(DISTINCT building_id) FROM tiles.building_tile").fetchone()
    assert assigned == (total, total)
    assert split_buildings(conn) == []
    assert conn.execute("SELECT count(*) FROM osm.building WHERE parent_id IS NOT NULL").fetchone()[0] > 100
    assert conn.execute("SELECT sum(n_features) FROM tiles.tile WHERE is_leaf").fetchone()[0] == total
    assert conn.execute("SELECT n_features FROM tiles.tile WHERE level = 0").fetchone()[0] == total


def test_every_leaf_has_its_parents(small_budget, conn_of) -> None:
    conn = conn_of(small_budget)
    orphans = conn.execute(
        """SELECT c.level, c.x, c.y FROM tiles.tile c WHERE c.level > 0 AND NOT EXISTS (
               SELECT 1 FROM tiles.tile p WHERE p.level = c.level - 1 AND p.x = c.x / 2 AND p.y = c.y / 2
               AND NOT p.is_leaf)"""
    ).fetchall()
    assert orphans == []


def test_regions_nest_and_errors_wait_for_generalize(small_budget, conn_of) -> None:
    conn = conn_of(small_budget)
    tiles = {
        (lv, x, y): (leaf, reg, ge)
        for lv, x, y, leaf, reg, ge in conn.execute(
            "SELECT level, x, y, is_leaf, region, geometric_error FROM tiles.tile"
        )
    }
    for (lv, x, y), (leaf, reg, ge) in tiles.items():
        assert reg[0] <= reg[2] and reg[1] <= reg[3] and reg[4] < reg[5]
        # no rule of thumb: inner tiles get the error generalize measures, leaves are exact
        assert ge == (0.0 if leaf else None)
        if lv:
            p = tiles[(lv - 1, x // 2, y // 2)][1]
            assert p[0] <= reg[0] and p[1] <= reg[1] and reg[2] <= p[2] and reg[3] <= p[3]
            assert p[4] <= reg[4] and reg[5] <= p[5]


def test_leaf_region_bounds_its_buildings(small_budget, conn_of) -> None:
    conn = conn_of(small_budget)
    outside = conn.execute(
        """SELECT count(*) FROM tiles.building_tile bt JOIN tiles.tile t USING (level, x, y)
           JOIN osm.building b ON b.id = bt.building_id JOIN lod.building_mesh m ON m.building_id = b.id
           WHERE radians(ST_XMin(b.geom)) < t.region[1] - 1e-12 OR radians(ST_YMin(b.geom)) < t.region[2] - 1e-12
              OR radians(ST_XMax(b.geom)) > t.region[3] + 1e-12 OR radians(ST_YMax(b.geom)) > t.region[4] + 1e-12
              OR m.min_height < t.region[5] OR m.height > t.region[6]"""  # 1e-12 rad: 6 µm of reprojection
    ).fetchone()[0]
    assert outside == 0
    # ... and every mesh, at every LOD: LOD3 openings stand out of the walls
    outside_mesh = conn.execute(
        """SELECT count(*) FROM tiles.building_tile bt JOIN tiles.tile t USING (level, x, y)
           JOIN lod.building_mesh m ON m.building_id = bt.building_id
           CROSS JOIN LATERAL (SELECT ST_Transform(m.geom, 4326) AS g) w
           WHERE radians(ST_XMin(w.g)) < t.region[1] - 1e-12 OR radians(ST_YMin(w.g)) < t.region[2] - 1e-12
              OR radians(ST_XMax(w.g)) > t.region[3] + 1e-12 OR radians(ST_YMax(w.g)) > t.region[4] + 1e-12"""
    ).fetchone()[0]
    assert outside_mesh == 0
    # the region is tight: the root spans the data (each mesh's UTM bounding box, so a few metres at most
    # more than the footprints: LOD3 openings stand out of the walls, grid north is not true north), not the
    # padded quadtree cell
    w, s, e, n = conn.execute("SELECT region[1:4] FROM tiles.tile WHERE level = 0").fetchone()[0]
    ext = conn.execute(
        """SELECT ST_XMin(e), ST_YMin(e), ST_XMax(e), ST_YMax(e) FROM (
               SELECT ST_Extent(b.geom) e FROM osm.building b JOIN lod.building_mesh m ON m.building_id = b.id) q"""
    ).fetchone()
    fw, fs, fe, fn = (math.radians(v) for v in ext)
    metre = 10 / 6.37e6  # ten metres in radians
    assert fw - metre < w <= fw and fs - metre < s <= fs and fe <= e < fe + metre and fn <= n < fn + metre


def test_cells_are_the_implicit_subdivision_of_the_root_region(small_budget, conn_of) -> None:
    """A client ignoring the subtrees' metadata halves the root region per level: every building sits in the cell
    so computed that its anchor falls in, the root covers every mesh and is square on the ground, and the
    working-CRS cell (the GiST filter) holds the anchors of its tile's buildings."""
    from core.geodesy import metres_per_radian
    from exporter.volumes import measure

    conn = conn_of(small_budget)
    w, s, e, n, size = conn.execute("SELECT * FROM api.quadtree_root()").fetchone()
    me, mn = metres_per_radian((s + n) / 2)
    assert (e - w) * me == pytest.approx(size, rel=1e-6) and (n - s) * mn == pytest.approx(size, rel=1e-6)
    ext = conn.execute("SELECT ST_Extent(envelope_4326) FROM lod.building_mesh").fetchone()[0]
    fw, fs, fe, fn = (
        math.radians(float(v)) for v in ext.replace("BOX(", "").replace(")", "").replace(",", " ").split()
    )
    assert w < fw and s < fs and fe < e and fn < n
    wrong = conn.execute(
        """SELECT count(*) FROM tiles.building_tile bt
           CROSS JOIN LATERAL (SELECT ST_Transform(bt.anchor, 4326) AS a) g
           CROSS JOIN LATERAL tiles.cell_region(bt.level, bt.x, bt.y) r
           WHERE NOT (radians(ST_X(g.a)) BETWEEN r[1] AND r[3] AND radians(ST_Y(g.a)) BETWEEN r[2] AND r[4])
              OR NOT bt.anchor && (SELECT t.cell FROM tiles.tile t
                                   WHERE (t.level, t.x, t.y) = (bt.level, bt.x, bt.y))"""
    ).fetchone()[0]
    assert wrong == 0
    assert conn.execute("SELECT tiles.cell_region(2, 1, 3)").fetchone()[0] == pytest.approx(
        [w + (e - w) / 4, s + (n - s) * 3 / 4, w + (e - w) / 2, n], abs=1e-15
    )
    # so no building lies further outside its tile's computed volume than its own half-extent, in a deep tree
    m = measure(conn)
    assert conn.execute("SELECT max(level) FROM tiles.tile").fetchone()[0] >= 3
    assert m["buildings"]["beyond_half_extent"] == 0 and m["buildings"]["outside"] > 0
    assert 0 < m["buildings"]["worst_m"] < 200
    # the measure sees a displaced tree: the same cells under a root a tenth of a cell off
    shifted = {"root": {"boundingVolume": {"region": [w + (e - w) / 40, s, e + (e - w) / 40, n]}, "geometricError": 1}}
    assert measure(conn, shifted)["buildings"]["beyond_half_extent"] > 10


def test_tiles_without_lod_is_a_clear_error(new_db) -> None:
    proc = run_etl(new_db("tiles_empty"), "tiles", check=False)
    assert proc.returncode != 0 and "ingest" in proc.stderr
