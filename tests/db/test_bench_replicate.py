"""benchmarks/replicate.py, the scale runs' input: a city copied N times ingests as N copies of it."""

from benchmarks.replicate import replicate
from tests.conftest import SPINE_FILES, merge_osm, run_etl


def test_replica_ingests_as_copies_of_the_city(new_db, conn_of, tmp_path) -> None:
    """benchmarks/replicate.py's scale input: every copy loads, rejects and links its parts as the original."""
    src = merge_osm(SPINE_FILES, tmp_path / "fixtures.osm")
    step = replicate(src, 3, tmp_path / "x3.osm.pbf")["id_step"]
    url = new_db("ingest_replica")
    proc = run_etl(url, "ingest", "--osm", str(tmp_path / "x3.osm.pbf"))
    assert "ingest: in 99 buildings and parts = 78 loaded + rejected 21 |" in proc.stdout
    conn = conn_of(url)
    links = conn.execute(
        """SELECT osm_type, osm_id %% %s, parent_id %% %s, parent_source, count(*),
                                   max(area_m2) / min(area_m2)
                            FROM osm.building GROUP BY 1, 2, 3, 4""",
        (step, step),
    ).fetchall()
    assert len(links) == 26 and {r[4] for r in links} == {3}
    assert max(r[5] for r in links) < 1.01  # the same footprints, a few km apart in the working CRS
    assert sum(r[2] is not None for r in links) == 6  # the fixtures' 6 linked parts, linked in every copy
    rejects = conn.execute(
        """SELECT osm_type, osm_id %% %s, reason, count(*) FROM osm.reject
                              GROUP BY 1, 2, 3""",
        (step,),
    ).fetchall()
    assert len(rejects) == 7 and {r[3] for r in rejects} == {3}
