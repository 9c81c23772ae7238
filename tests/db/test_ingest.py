"""Stage ingest on the real PostGIS: hand-written fixtures (one idea per file) and the real extracts."""

import hashlib
import json

import pytest

from tests.conftest import SPINE_FILES, helsinki, merge_osm, run_etl


@pytest.fixture(scope="module")
def fx(city):
    return city("fixtures")


def one(conn, q, *args):
    row = conn.execute(q, args).fetchone()
    assert row is not None, q
    return row


def test_counts_in_equals_loaded_plus_rejected(fx, conn_of) -> None:
    conn = conn_of(fx.url)
    counts = one(conn, "SELECT counts FROM meta.pipeline_run WHERE stage = 'ingest' AND status = 'ok'")[0]
    loaded = one(conn, "SELECT count(*) FROM osm.building")[0]
    rejected = one(conn, "SELECT count(*) FROM osm.reject WHERE stage = 'ingest'")[0]
    # 100: 1, 110: 1, 120: 1, 130: 3, 140: 4, 150: 9, 160: 2, 900: 10 ways + 2 relations = 33 candidates
    assert counts["in"] == 33
    assert (counts["loaded"], counts["rejected"]) == (loaded, rejected) == (26, 7)
    assert counts["in"] == loaded + rejected


def test_run_is_recorded(fx, conn_of) -> None:
    conn = conn_of(fx.url)
    run = one(
        conn,
        """SELECT status, input_file, input_sha256, params, duration_s, git_commit
                       FROM meta.pipeline_run WHERE stage = 'ingest'""",
    )
    assert run[0] == "ok"
    assert run[1] == str(fx.osm)
    assert run[2] == hashlib.sha256(fx.osm.read_bytes()).hexdigest()
    assert run[3]["level_height_m"] == 3.0 and run[3]["osm"] == str(fx.osm)
    assert run[4] > 0
    stages = [r[0] for r in conn.execute("SELECT stage FROM meta.pipeline_run WHERE status = 'ok' ORDER BY run_id")]
    # the city's build, in order (tests that export this city again may add export runs after it)
    assert stages[:6] == ["ingest", "lod", "landmarks", "tiles", "generalize", "export"]
    assert set(stages[6:]) <= {"export"}


def test_square_and_lshape(fx, conn_of) -> None:
    conn = conn_of(fx.url)
    sq = one(
        conn,
        """SELECT kind, height, name, area_m2, ST_SRID(geom_local), ST_NPoints(geom)
                       FROM osm.building WHERE id = 10001""",
    )
    assert sq[0:3] == ("building", 12.0, "Square 100")
    # 20 x 20 m drawn in degrees with a spherical approximation, measured in UTM 35N
    assert sq[3] == pytest.approx(400.0, rel=1e-2)
    assert sq[4] == 32635 and sq[5] == 5
    ell = one(conn, "SELECT levels, roof_shape, area_m2, height FROM osm.building WHERE id = 11001")
    assert ell[0] == 4.0 and ell[1] == "flat" and ell[3] is None
    assert ell[2] == pytest.approx(30 * 10 + 10 * 15, rel=1e-2)


def test_courtyard_multipolygon_keeps_its_hole(fx, conn_of) -> None:
    conn = conn_of(fx.url)
    r = one(
        conn,
        """SELECT osm_type, osm_id, kind, building, height, ST_NumInteriorRings(ST_GeometryN(geom, 1)),
                            area_m2 FROM osm.building WHERE id = -1201""",
    )
    assert r[0:4] == ("R", 1201, "building", "apartments")
    assert r[4] == pytest.approx(12.192)  # "40 ft"
    assert r[5] == 1
    assert r[6] == pytest.approx(40 * 40 - 20 * 20, rel=1e-2)


def test_parts_linked_by_containment(fx, conn_of) -> None:
    conn = conn_of(fx.url)
    rows = conn.execute("""SELECT id, kind, parent_id, parent_source, n_parts, part_coverage, min_height, height
                           FROM osm.building WHERE id BETWEEN 13001 AND 13003 ORDER BY id""").fetchall()
    assert rows[0][1] == "building" and rows[0][4] == 2 and rows[0][5] == pytest.approx(1.0, abs=1e-3)
    assert [(r[1], r[2], r[3]) for r in rows[1:]] == [("part", 13001, "contains")] * 2
    assert rows[2][6:] == (5.0, 20.0)


def test_type_building_relation(fx, conn_of) -> None:
    conn = conn_of(fx.url)
    rel = one(conn, "SELECT name, tags->>'type' FROM osm.building_relation WHERE relation_id = 1401")
    assert rel == ("Relation 140", "building")
    roles = conn.execute("""SELECT member_id, role FROM osm.building_relation_member WHERE relation_id = 1401
                            ORDER BY seq""").fetchall()
    assert roles == [(14001, "outline"), (14002, "part"), (14003, "part"), (14004, "part")]
    parts = conn.execute("""SELECT id, parent_id, parent_source FROM osm.building WHERE kind = 'part'
                            AND id BETWEEN 14001 AND 14004 ORDER BY id""").fetchall()
    # 14004 lies outside the outline: only the relation can link it
    assert parts == [(14002, 14001, "relation"), (14003, 14001, "relation"), (14004, 14001, "relation")]


def test_units_and_typed_tags(fx, conn_of) -> None:
    conn = conn_of(fx.url)
    heights = [
        r[0] for r in conn.execute("SELECT height FROM osm.building WHERE id BETWEEN 15001 AND 15006 ORDER BY id")
    ]
    assert heights == pytest.approx([12.0, 12.0, 12.5, 12.192, 12.192, 3.81], abs=1e-4)
    r = one(
        conn,
        """SELECT roof_shape, roof_direction, roof_orientation, building_colour, roof_colour, roof_angle,
                            levels, roof_levels, tags->>'building:colour' FROM osm.building WHERE id = 15011""",
    )
    assert r == ("gabled", 22.5, "across", "#ff0000", "#aabbcc", 30.0, 2.0, 1.0, "red")
    r = one(conn, "SELECT min_level, roof_shape, building_material, roof_height FROM osm.building WHERE id = 15012")
    assert r == (1.0, "hipped", "brick", 2.5)


def test_broken_input_is_rejected_with_reasons(fx, conn_of) -> None:
    conn = conn_of(fx.url)
    rejects = dict(
        ((t, i), reason)
        for t, i, reason in conn.execute("SELECT osm_type, osm_id, reason FROM osm.reject WHERE stage = 'ingest'")
    )
    assert rejects == {
        ("W", 90001): "unclosed_way",
        ("W", 90003): "missing_nodes",
        ("W", 90007): "degenerate_ring",
        ("W", 90013): "degenerate_ring",
        ("W", 90008): "too_small",
        ("R", 9001): "multipolygon_assembly_failed",
        ("R", 9002): "unsupported_relation",
    }
    detail, tags = one(conn, "SELECT detail, tags FROM osm.reject WHERE osm_id = 90003")
    assert "900999" in detail and tags["name"] == "missing node"  # nothing lost: tags kept with the reject


def test_invalid_geometry_is_repaired_and_flagged(fx, conn_of) -> None:
    conn = conn_of(fx.url)
    r = one(
        conn,
        """SELECT repaired, repair_reason, ST_IsValid(geom_local), ST_NumGeometries(geom_local), area_m2
                     FROM osm.building WHERE id = 90002""",
    )
    assert r[0] is True and r[1].startswith("Self-intersection")
    assert r[2] is True and r[3] == 2  # the bow-tie becomes its two triangles
    assert r[4] == pytest.approx(50.0, rel=1e-2)
    assert one(conn, "SELECT count(*) FROM meta.diagnostic WHERE osm_id = 90002 AND code = 'geometry_repaired'")[0] == 1
    invalid = "SELECT count(*) FROM osm.building WHERE NOT ST_IsValid(geom_local) OR NOT ST_IsValid(geom)"
    assert one(conn, invalid)[0] == 0


def test_bad_tag_values_are_refused_and_reported(fx, conn_of) -> None:
    conn = conn_of(fx.url)
    heights = conn.execute(
        "SELECT id, height, tags->>'height' FROM osm.building WHERE id IN (90004, 90005, 90006) ORDER BY id"
    )
    assert [(i, h) for i, h, _ in heights] == [(90004, None), (90005, None), (90006, None)]
    diags = dict(
        conn.execute("""SELECT osm_id, detail FROM meta.diagnostic WHERE code = 'invalid_tag'
                                 AND osm_id IN (90004, 90005, 90006)""").fetchall()
    )
    assert "negative" in diags[90004] and "not a length" in diags[90005] and "exceeds" in diags[90006]


def test_not_candidates_are_not_counted(fx, conn_of) -> None:
    conn = conn_of(fx.url)
    assert one(conn, "SELECT count(*) FROM osm.building WHERE osm_id IN (90010, 90011, 90012)")[0] == 0
    assert one(conn, "SELECT count(*) FROM osm.reject WHERE osm_id IN (90010, 90011, 90012)")[0] == 0


def _snapshot(conn) -> str:
    h = hashlib.sha256()
    for q in (
        "SELECT id, kind, tags::text, ST_AsEWKB(geom), ST_AsEWKB(geom_local), height, parent_id, part_coverage"
        " FROM osm.building ORDER BY id",
        "SELECT reject_id, osm_type, osm_id, stage, reason, detail FROM osm.reject ORDER BY reject_id",
        "SELECT diagnostic_id, stage, osm_type, osm_id, code, detail FROM meta.diagnostic ORDER BY 1",
        "SELECT srid, source_sha256 FROM meta.dataset",
    ):
        for row in conn.execute(q):
            h.update(repr(row).encode())
    return h.hexdigest()


def test_rerun_gives_the_same_database(new_db, conn_of, tmp_path) -> None:
    src = merge_osm(SPINE_FILES, tmp_path / "fixtures.osm")
    url = new_db("ingest_rerun")
    run_etl(url, "ingest", "--osm", str(src))
    first = _snapshot(conn_of(url))
    proc = run_etl(url, "ingest", "--osm", str(src))
    assert "ingest: in 33 buildings and parts = 26 loaded + rejected 7 |" in proc.stdout  # the one-line summary
    assert _snapshot(conn_of(url)) == first


def test_a_way_whose_nodes_are_all_missing_is_missing_nodes(new_db, conn_of, tmp_path) -> None:
    src = tmp_path / "gone.osm"
    src.write_text(
        '<?xml version="1.0"?><osm version="0.6" generator="hand">'
        '<node id="1" lat="47.0" lon="9.0"/><node id="2" lat="47.0" lon="9.0002"/>'
        '<node id="3" lat="47.0002" lon="9.0"/>'
        '<way id="7"><nd ref="1"/><nd ref="2"/><nd ref="3"/><nd ref="1"/><tag k="building" v="yes"/></way>'
        '<way id="8"><nd ref="91"/><nd ref="92"/><nd ref="93"/><nd ref="91"/><tag k="building" v="yes"/>'
        "</way></osm>"
    )
    url = new_db("ingest_all_missing")
    run_etl(url, "ingest", "--osm", str(src))
    rows = conn_of(url).execute("SELECT osm_id, reason, detail FROM osm.reject").fetchall()
    assert [(r[0], r[1]) for r in rows] == [(8, "missing_nodes")] and "4 of 4 nodes" in rows[0][2]


def test_missing_file_is_a_clear_error(new_db, tmp_path) -> None:
    proc = run_etl(new_db("ingest_missing"), "ingest", "--osm", str(tmp_path / "nope.osm.pbf"), check=False)
    assert proc.returncode != 0 and "not found" in proc.stderr


@pytest.mark.parametrize(
    ("name", "buildings"),
    # building areas per ../shared/data/PROVENANCE.md (pyosmium's assembler), minus the ways tagged
    # building=no, which are not buildings (London has 3); Helsinki's counted alike (pyosmium 4.3.2 area handler,
    # building not no)
    [
        ("helsinki", 446),
        pytest.param("munich", 2425, marks=pytest.mark.extracts),
        pytest.param("london", 2158 - 3, marks=pytest.mark.extracts),
    ],
)
def test_real_extracts(city, conn_of, name, buildings) -> None:
    c = city(name)
    conn = conn_of(c.url)
    counts = one(conn, "SELECT counts FROM meta.pipeline_run WHERE stage = 'ingest'")[0]
    assert counts["in"] == counts["loaded"] + counts["rejected"]
    # every area pyosmium's assembler builds is loaded; what is rejected are objects without a geometry of their
    # own (type=site relations and the like, and in Helsinki's cut extract ways with nodes outside it)
    n_buildings = one(conn, "SELECT count(*) FROM osm.building WHERE kind = 'building'")[0]
    assert n_buildings == buildings
    reasons = {r[0] for r in conn.execute("SELECT DISTINCT reason FROM osm.reject WHERE stage = 'ingest'")}
    assert reasons <= {"unsupported_relation", "multipolygon_assembly_failed", "missing_nodes"}
    assert one(conn, "SELECT count(*) FROM osm.building WHERE NOT ST_IsValid(geom_local)")[0] == 0
    assert json.dumps(counts)  # recorded as JSON


def test_unreadable_files_fail_with_one_clear_line(new_db, conn_of, tmp_path) -> None:
    url = new_db("ingest_unreadable")
    truncated = tmp_path / "truncated.osm.pbf"
    truncated.write_bytes(helsinki().read_bytes()[:100_000])
    garbage = tmp_path / "garbage.osm"
    garbage.write_text("not osm at all")
    for f in (truncated, garbage):
        proc = run_etl(url, "ingest", "--osm", str(f), check=False)
        assert proc.returncode == 1
        assert proc.stderr.startswith(f"ingest: error: cannot read {f}")
        assert "Traceback" not in proc.stderr
    runs = (
        conn_of(url)
        .execute("SELECT status, error FROM meta.pipeline_run WHERE stage = 'ingest' ORDER BY run_id")
        .fetchall()
    )
    assert [r[0] for r in runs] == ["failed", "failed"] and "PBF error" in runs[0][1]


def _osm(path, body: str, generator: str = "hand"):
    path.write_text(f'<?xml version="1.0"?><osm version="0.6" generator="{generator}">{body}</osm>')
    return path


def test_a_file_whose_only_building_has_no_area_is_a_reject_and_lod_and_tiles_say_so(new_db, conn_of, tmp_path) -> None:
    src = _osm(
        tmp_path / "line.osm",
        '<node id="1" lat="47.0" lon="9.0"/><node id="2" lat="47.0" lon="9.0002"/>'
        '<node id="3" lat="47.0" lon="9.0004"/>'
        '<way id="7"><nd ref="1"/><nd ref="2"/><nd ref="3"/><nd ref="1"/><tag k="building" v="yes"/></way>',
    )
    url = new_db("ingest_collinear")
    run_etl(url, "ingest", "--osm", str(src))
    conn = conn_of(url)
    assert conn.execute("SELECT osm_id, reason FROM osm.reject").fetchall() == [(7, "invalid_geometry")]
    assert conn.execute("SELECT GeometryType(bbox) FROM meta.dataset").fetchone()[0] == "POLYGON"
    run_etl(url, "lod")  # nothing to draw is not an error
    proc = run_etl(url, "tiles", check=False)
    assert proc.returncode != 0 and "run the lod stage first" not in proc.stderr
    assert "the lod stage drew no building (0 buildings in osm.building, 1 rejected in osm.reject" in proc.stderr


def test_ways_of_nodes_with_negative_ids_are_built(new_db, conn_of, tmp_path) -> None:
    # as JOSM saves unsaved data: negative ids, which libosmium's location index does not keep
    src = _osm(
        tmp_path / "josm.osm",
        '<node id="-1" lat="47.0" lon="9.0"/><node id="-2" lat="47.0" lon="9.0002"/>'
        '<node id="-3" lat="47.0002" lon="9.0002"/><node id="4" lat="47.0002" lon="9.0"/>'
        '<way id="-5"><nd ref="-1"/><nd ref="-2"/><nd ref="-3"/><nd ref="4"/><nd ref="-1"/>'
        '<tag k="building" v="yes"/></way>'
        '<way id="-6"><nd ref="-1"/><nd ref="-2"/><nd ref="-99"/><nd ref="-1"/>'
        '<tag k="building" v="yes"/></way>',
        generator="JOSM",
    )
    url = new_db("ingest_negative")
    run_etl(url, "ingest", "--osm", str(src))
    conn = conn_of(url)
    area, n = conn.execute("SELECT area_m2, ST_NPoints(geom) FROM osm.building WHERE osm_id = -5").fetchone()
    assert 330 < area < 345 and n == 5  # 15.2 m x 22.2 m at 47° N, its four corners closed
    rejects = conn.execute("SELECT osm_id, reason, detail FROM osm.reject").fetchall()
    assert [(r[0], r[1]) for r in rejects] == [(-6, "missing_nodes")] and "-99" in rejects[0][2]


def test_a_string_over_libosmiums_limit_is_refused_with_its_place(new_db, conn_of, tmp_path) -> None:
    url = new_db("ingest_long_tag")
    nodes = (
        '<node id="1" lat="47.0" lon="9.0"/><node id="2" lat="47.0" lon="9.0002"/>'
        '<node id="3" lat="47.0002" lon="9.0002"/>'
    )
    ok = _osm(
        tmp_path / "ok.osm",
        nodes + '<way id="7"><nd ref="1"/><nd ref="2"/><nd ref="3"/><nd ref="1"/>'
        f'<tag k="building" v="yes"/><tag k="note" v="{"x" * 1024}"/></way>',
    )
    run_etl(url, "ingest", "--osm", str(ok))  # 1,024 bytes: libosmium's limit, still read
    long = _osm(
        tmp_path / "long.osm",
        nodes + '\n<way id="7"><nd ref="1"/><nd ref="2"/><nd ref="3"/><nd ref="1"/>'
        f'\n<tag k="building" v="yes"/><tag k="note" v="{"&amp;" * 1025}"/></way>',
    )
    proc = run_etl(url, "ingest", "--osm", str(long), check=False)
    assert proc.returncode == 1 and "Traceback" not in proc.stderr
    assert (
        f"cannot read {long}: OSM tag value is too long (line 3, way 7: the value of tag 'note' has 1,025 "
        "bytes; libosmium reads at most 1,024 bytes)"
    ) in proc.stderr
    ctrl = _osm(tmp_path / "ctrl.osm", '\n<node id="1" lat="47.0" lon="9.0"><tag k="name" v="a\x01b"/></node>')
    proc = run_etl(url, "ingest", "--osm", str(ctrl), check=False)
    assert proc.returncode == 1 and "XML parsing error at line 2, column" in proc.stderr
    # refused whole: the database keeps the last good load
    assert conn_of(url).execute("SELECT count(*) FROM osm.building").fetchone()[0] == 1


def test_a_building_across_the_antimeridian_is_rejected_not_a_world_wide_tile(new_db, conn_of, tmp_path) -> None:
    src = _osm(
        tmp_path / "fiji.osm",
        '<node id="1" lat="-16.8" lon="179.9999"/><node id="2" lat="-16.8" lon="-179.9999"/>'
        '<node id="3" lat="-16.7999" lon="-179.9999"/><node id="4" lat="-16.7999" lon="179.9999"/>'
        '<node id="11" lat="-16.8" lon="179.99"/><node id="12" lat="-16.8" lon="179.9902"/>'
        '<node id="13" lat="-16.7998" lon="179.9902"/><node id="14" lat="-16.7998" lon="179.99"/>'
        '<way id="7"><nd ref="1"/><nd ref="2"/><nd ref="3"/><nd ref="4"/><nd ref="1"/>'
        '<tag k="building" v="yes"/></way>'
        '<way id="8"><nd ref="11"/><nd ref="12"/><nd ref="13"/><nd ref="14"/><nd ref="11"/>'
        '<tag k="building" v="yes"/></way>',
    )
    url = new_db("ingest_antimeridian")
    run_etl(url, "ingest", "--osm", str(src))
    run_etl(url, "lod")
    run_etl(url, "tiles")
    conn = conn_of(url)
    assert conn.execute("SELECT osm_id, reason FROM osm.reject").fetchall() == [(7, "crosses_antimeridian")]
    west, east = conn.execute("SELECT min(region[1]), max(region[3]) FROM tiles.tile").fetchone()
    assert 0 < east - west < 1e-4  # radians: the one building's few metres, not the world
