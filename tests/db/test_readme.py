"""The analyst queries in README.md run on a real city, the Helsinki demo extract the README describes (its
camera query is over Helsinki), and answer what they say."""

import re

import numpy as np
import psycopg
import pytest
import trimesh

from core.wkb import decode_triangles
from tests.conftest import REPO

QUERIES = re.findall(r"```sql\n(.*?)```", (REPO / "README.md").read_text(), flags=re.S)


def test_readme_has_the_eleven_queries() -> None:
    assert len(QUERIES) == 11


#: Helsinki Central Station: its 48.5 m clock tower is one of its five building:parts, its outline is 15 m.
STATION = 122595198


@pytest.fixture(scope="module")
def helsinki(city):
    with psycopg.connect(city("helsinki").url, autocommit=True) as conn:
        yield conn


def test_tallest(helsinki) -> None:
    rows = helsinki.execute(QUERIES[0]).fetchall()
    assert len(rows) == 10
    assert [r[3] for r in rows] == sorted((r[3] for r in rows), reverse=True)
    # a building:part counts for its building: the station is as tall as its clock tower, not its outline
    station = {r[1]: r for r in rows}[STATION]
    outline = helsinki.execute(
        """SELECT m.height FROM lod.building_mesh m JOIN osm.building b ON b.id = m.building_id
           WHERE b.osm_id = %s AND b.kind = 'building' AND m.lod = 1""",
        (STATION,),
    ).fetchone()[0]
    assert station[3] == pytest.approx(48.5) and station[4] == 6 and outline < 20


def test_buildings_per_tile(helsinki) -> None:
    rows = helsinki.execute(QUERIES[1]).fetchall()
    leaves = helsinki.execute("SELECT count(*) FROM tiles.tile WHERE is_leaf").fetchone()[0]
    assert len(rows) == leaves
    buildings = helsinki.execute(
        "SELECT count(DISTINCT coalesce(b.parent_id, b.id)) FROM tiles.building_tile t"
        " JOIN osm.building b ON b.id = t.building_id"
    ).fetchone()[0]
    assert sum(r[3] for r in rows) == buildings  # a building is in exactly one tile


def test_volume_per_building(helsinki) -> None:
    rows = helsinki.execute(QUERIES[2]).fetchall()
    assert len(rows) == 10
    assert [r[2] for r in rows] == sorted((r[2] for r in rows), reverse=True) and rows[-1][2] > 0
    assert STATION in {r[0] for r in rows}  # one with parts among them (an outline counted where they are not)
    # each is the sum of its meshes; the station's are its five parts, which SFCGAL measures alike, and its
    # outline drawn only where they are not: several shells, which SFCGAL refuses (as the README says)
    for osm_id, _, vol, meshes in rows:
        parts = helsinki.execute(
            """SELECT m.volume_m3, ST_AsBinary(m.geom), m.geom FROM lod.building_mesh m
               JOIN osm.building b ON b.id = m.building_id WHERE m.lod = 1 AND coalesce(b.parent_id, b.id) =
               (SELECT id FROM osm.building WHERE osm_id = %s AND kind = 'building')""",
            (osm_id,),
        ).fetchall()
        assert len(parts) == meshes and sum(p[0] for p in parts) == pytest.approx(float(vol), abs=0.5), osm_id
        if osm_id != STATION:
            continue  # SFCGAL's exact arithmetic takes seconds per mesh: one building is enough
        shells = []
        for v, blob, geom in parts:
            tris = decode_triangles(blob)
            shells.append(
                trimesh.Trimesh((tris - tris[0, 0]).reshape(-1, 3), np.arange(tris.size // 3).reshape(-1, 3)).body_count
            )
            if shells[-1] == 1:
                sfcgal = helsinki.execute("SELECT ST_Volume(ST_MakeSolid(%s::geometry))", (geom,)).fetchone()[0]
                assert sfcgal == pytest.approx(v, rel=1e-6)
        assert sorted(shells)[:5] == [1] * 5 and max(shells) > 1, shells


def test_reject_summaries(helsinki) -> None:
    rejects, diagnostics = (helsinki.execute(q).fetchall() for q in QUERIES[3].split(";") if q.strip())
    # what ingest dropped (the extract is cut: ways with nodes outside it), as the stage counted it
    ingest = helsinki.execute("SELECT counts FROM meta.pipeline_run WHERE stage = 'ingest'").fetchone()[0]
    assert {r[1]: r[2] for r in rejects if r[0] == "ingest"} == ingest["rejected_by_reason"]
    assert sum(r[2] for r in rejects) == ingest["rejected"] > 0
    # what lod repaired or refused, as the stage counted it
    lod = helsinki.execute("SELECT counts FROM meta.pipeline_run WHERE stage = 'lod'").fetchone()[0]
    got = {(r[0], r[1]): r[2] for r in diagnostics}
    assert got[("lod", "outline_hidden_by_parts")] == lod["hidden_by_parts"] > 0
    assert got[("lod", "not_watertight")] == lod["lod2_not_closed"]
    assert got[("lod", "unknown_roof_shape")] >= 1


def test_buildings_per_roof_shape(helsinki) -> None:
    rows = helsinki.execute(QUERIES[4]).fetchall()
    assert {"flat", "gabled", "hipped", "pyramidal", "dome", "round", "gambrel"} <= {r[0] for r in rows}
    assert {r[1] for r in rows if r[0] == "gabled"} == {"skeleton", "field"}  # both gable engines
    lod2 = helsinki.execute("SELECT count(*) FROM lod.building_mesh WHERE lod = 2").fetchone()[0]
    assert sum(r[2] for r in rows) == lod2


def test_roof_area_by_material(helsinki) -> None:
    got = {r[0]: float(r[2]) for r in helsinki.execute(QUERIES[5]).fetchall()}
    assert {"(untagged)", "copper"} <= set(got) and all(v > 0 for v in got.values())
    total = helsinki.execute("SELECT sum(roof_area_m2) FROM lod.building_mesh WHERE lod = 2").fetchone()[0]
    assert sum(got.values()) == pytest.approx(total, abs=len(got))


def test_volume_by_lod(helsinki) -> None:
    got = {r[0]: r for r in helsinki.execute(QUERIES[6]).fetchall()}
    assert set(got) == {1, 2, 3}
    assert got[1][1] == got[2][1] == got[3][1]  # one mesh per building and LOD
    assert got[2][2] < got[1][2]  # pitched roofs take volume out of the blocks
    assert got[3][4] > 0 and got[3][5] > 0 and got[2][4] == 0  # windows and doors only at LOD3
    assert got[2][6] >= 99.5


def test_building_diagnostic_view(helsinki) -> None:
    got = {(r[0], r[1]): r[2] for r in helsinki.execute(QUERIES[7]).fetchall()}
    assert got[("unknown_roof_shape", False)] >= 1
    # kept and dropped buildings alike: every reject is there with its reason
    rejects = dict(helsinki.execute("SELECT reason, count(*) FROM osm.reject GROUP BY 1").fetchall())
    assert rejects and {code: n for (code, dropped), n in got.items() if dropped} == rejects


def test_bands(helsinki) -> None:
    rows = helsinki.execute(QUERIES[8]).fetchall()
    assert [r[0] for r in rows] == sorted(r[0] for r in rows) and rows[-1][0] == 4  # leaves hold LOD3
    assert rows[-1][5] == 0 and all(r[5] > 0 for r in rows[:-1])  # errors measured above the leaves
    assert rows[0][1] > rows[-1][1] == 0


def test_lod_for_view_query(helsinki) -> None:
    rows = helsinki.execute(QUERIES[9]).fetchall()
    assert rows and all(r[3] <= 16 or r[0] == 3 for r in rows)  # drawn tiles are fine enough, or leaves
    assert sum(r[1] for r in rows) > 100


def test_largest_blocks(helsinki) -> None:
    rows = helsinki.execute(QUERIES[10]).fetchall()
    assert len(rows) == 10 and rows[0][2] > 1 and rows[0][2] >= rows[-1][2]
    assert all(len(r[5]) == min(5, r[2]) for r in rows)
