"""The analyst queries in README.md run on a real city and answer what they say."""

import re

import psycopg
import pytest

from tests.conftest import REPO

QUERIES = re.findall(r"```sql\n(.*?)```", (REPO / "README.md").read_text(), flags=re.S)


def test_readme_has_the_eleven_queries() -> None:
    assert len(QUERIES) == 11


@pytest.fixture(scope="module")
def munich(city):
    with psycopg.connect(city("munich").url, autocommit=True) as conn:
        yield conn


def test_tallest(munich) -> None:
    rows = munich.execute(QUERIES[0]).fetchall()
    assert len(rows) == 10
    # the Frauenkirche's towers are building:parts of about 100 m; its outline alone is far lower
    assert rows[0][3] >= 95 and rows[0][4] > 1
    assert [r[3] for r in rows] == sorted((r[3] for r in rows), reverse=True)


def test_buildings_per_tile(munich) -> None:
    rows = munich.execute(QUERIES[1]).fetchall()
    leaves = munich.execute("SELECT count(*) FROM tiles.tile WHERE is_leaf").fetchone()[0]
    assert len(rows) == leaves
    buildings = munich.execute(
        "SELECT count(DISTINCT coalesce(b.parent_id, b.id)) FROM tiles.building_tile t"
        " JOIN osm.building b ON b.id = t.building_id").fetchone()[0]
    assert sum(r[3] for r in rows) == buildings  # a building is in exactly one tile


def test_volume_per_building(munich) -> None:
    rows = munich.execute(QUERIES[2]).fetchall()
    assert len(rows) == 10
    assert all(vol > 0 for _, _, vol, _ in rows)
    # the largest is the sum of its meshes, each of which SFCGAL measures alike when it is one shell
    osm_id, _, vol, _ = rows[0]
    parts = munich.execute(
        """SELECT m.volume_m3, ST_NumGeometries(b.geom_local), m.geom FROM lod.building_mesh m
           JOIN osm.building b ON b.id = m.building_id WHERE m.lod = 1 AND coalesce(b.parent_id, b.id) =
           (SELECT id FROM osm.building WHERE osm_id = %s AND kind = 'building')""", (osm_id,)).fetchall()
    assert sum(p[0] for p in parts) == pytest.approx(float(vol), abs=0.5)
    for v, shells, geom in parts:
        if shells == 1:
            sfcgal = munich.execute("SELECT ST_Volume(ST_MakeSolid(%s::geometry))", (geom,)).fetchone()[0]
            assert sfcgal == pytest.approx(v, rel=1e-6)


def test_reject_summaries_run(munich) -> None:
    for q in QUERIES[3].split(";"):
        if q.strip():
            munich.execute(q).fetchall()


def test_buildings_per_roof_shape(munich) -> None:
    rows = munich.execute(QUERIES[4]).fetchall()
    assert {"flat", "gabled", "hipped", "pyramidal", "dome", "skillion"} <= {r[0] for r in rows}
    lod2 = munich.execute("SELECT count(*) FROM lod.building_mesh WHERE lod = 2").fetchone()[0]
    assert sum(r[2] for r in rows) == lod2


def test_roof_area_by_material(munich) -> None:
    got = {r[0]: float(r[2]) for r in munich.execute(QUERIES[5]).fetchall()}
    assert "(untagged)" in got and all(v >= 0 for v in got.values())
    total = munich.execute("SELECT sum(roof_area_m2) FROM lod.building_mesh WHERE lod = 2").fetchone()[0]
    assert sum(got.values()) == pytest.approx(total, abs=len(got))


def test_volume_by_lod(munich) -> None:
    got = {r[0]: r for r in munich.execute(QUERIES[6]).fetchall()}
    assert set(got) == {1, 2, 3}
    assert got[1][1] == got[2][1] == got[3][1]  # one mesh per building and LOD
    assert got[2][2] < got[1][2]  # pitched roofs take volume out of the blocks
    assert got[3][4] > 0 and got[3][5] > 0 and got[2][4] == 0  # windows and doors only at LOD3
    assert got[2][6] >= 99.5


def test_building_diagnostic_view(munich) -> None:
    got = {(r[0], r[1]): r[2] for r in munich.execute(QUERIES[7]).fetchall()}
    assert got[("unknown_roof_shape", False)] >= 1  # roof:shape=many


def test_bands(munich) -> None:
    rows = munich.execute(QUERIES[8]).fetchall()
    assert [r[0] for r in rows] == sorted(r[0] for r in rows) and rows[-1][0] == 4  # leaves hold LOD3
    assert rows[-1][5] == 0 and all(r[5] > 0 for r in rows[:-1])  # errors measured above the leaves
    assert rows[0][1] > rows[-1][1] == 0


def test_lod_for_view_query(munich) -> None:
    # the README camera is over Helsinki: move it over Munich's old town, same view
    q = QUERIES[9].replace("24.945, 60.165", "11.575, 48.125")
    rows = munich.execute(q).fetchall()
    assert rows and all(r[3] <= 16 or r[0] == 3 for r in rows)  # drawn tiles are fine enough, or leaves
    assert sum(r[1] for r in rows) > 100


def test_largest_blocks(munich) -> None:
    rows = munich.execute(QUERIES[10]).fetchall()
    assert len(rows) == 10 and rows[0][2] > 1 and rows[0][2] >= rows[-1][2]
    assert all(len(r[5]) == min(5, r[2]) for r in rows)
