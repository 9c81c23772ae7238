"""The analyst queries in README.md run on a real city and answer what they say."""

import re

import psycopg
import pytest

from tests.conftest import REPO

QUERIES = re.findall(r"```sql\n(.*?)```", (REPO / "README.md").read_text(), flags=re.S)


def test_readme_has_the_three_queries() -> None:
    assert len(QUERIES) >= 4


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
           JOIN osm.building b ON b.id = m.building_id WHERE coalesce(b.parent_id, b.id) =
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
