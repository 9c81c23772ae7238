"""`python -m etl update`: OSM change files applied to a built database. The changes here are written by the test
on top of the spine fixtures (a moved node, a tag edit, a deleted part, a new building, a building gaining a
part, a multipolygon losing its inner ring); the database they give must equal, table by table and tile by tile,
a full rebuild from the changed file, and only the buildings that changed are replaced in osm.building."""

from __future__ import annotations

import gzip
import hashlib
import json
import shutil
from collections.abc import Callable
from pathlib import Path

import psycopg
import pytest

from core import changes
from core.db import analyze
from core.settings import Settings
from core.stage import Context
from etl.ingest import stage as ingest
from etl.update import osc as update
from etl.update.osc import ChangeFileError, apply_changes, count_change, state_path
from tests.conftest import City, run_etl
from tests.support.equivalence import TABLES, Reader, table_rows


def square(way: int, node: int, south: float, west: float, north: float, east: float, tags: str) -> str:
    """A closed way of four new nodes (``node`` to ``node + 3``, anticlockwise from the south-west corner)."""
    corners = [(south, west), (south, east), (north, east), (north, west)]
    nodes = "".join(
        f'\n    <node id="{node + i}" version="1" lat="{lat:.7f}" lon="{lon:.7f}"/>'
        for i, (lat, lon) in enumerate(corners)
    )
    refs = "".join(f'<nd ref="{node + i}"/>' for i in (0, 1, 2, 3, 0))
    return f'{nodes}\n    <way id="{way}" version="1">\n      {refs}\n      {tags}\n    </way>'


#: node ids 170001-, way ids 17001- (the numbering of tests/fixtures: fixture 170 is this test's own)
#: the square's north-east corner moves 3 m east (building 10001 moves with it), and a tag edit: 4 -> 6 levels
MOVE_AND_RETAG = """
    <node id="100003" version="2" lat="60.2001795" lon="24.9004157"/>
    <way id="11001" version="2">
      <nd ref="110001"/><nd ref="110002"/><nd ref="110003"/><nd ref="110004"/><nd ref="110005"/>
      <nd ref="110006"/><nd ref="110001"/>
      <tag k="building" v="residential"/><tag k="building:levels" v="6"/><tag k="roof:shape" v="flat"/>
      <tag k="name" v="L 110"/>
    </way>"""
#: the L gains a building:part in its corner
NEW_PART = square(
    17002, 170011, 60.20002, 24.90275, 60.20007, 24.90285, '<tag k="building:part" v="yes"/><tag k="height" v="30"/>'
)
#: a new building east of the others
NEW_HOUSE = square(
    17001,
    170001,
    60.2,
    24.906,
    60.2001,
    24.9062,
    '<tag k="building" v="house"/><tag k="height" v="7"/><tag k="roof:shape" v="gabled"/>',
)


def osm_change(modify: str = "", delete: str = "", create: str = "") -> str:
    return (
        '<?xml version="1.0" encoding="UTF-8"?>\n<osmChange version="0.6" generator="citylod tests">\n'
        + "".join(
            f"  <{a}>{body}\n  </{a}>\n"
            for a, body in (("modify", modify), ("delete", delete), ("create", create))
            if body
        )
        + "</osmChange>\n"
    )


CHANGE_1 = osm_change(MOVE_AND_RETAG, '\n    <way id="13003" version="2"/>', NEW_HOUSE + NEW_PART)

#: the courtyard multipolygon loses its inner ring (and the ring's way goes)
CHANGE_2 = """<?xml version="1.0" encoding="UTF-8"?>
<osmChange version="0.6" generator="citylod tests">
  <modify>
    <relation id="1201" version="2">
      <member type="way" ref="12001" role="outer"/>
      <tag k="type" v="multipolygon"/><tag k="building" v="apartments"/><tag k="height" v="40 ft"/>
      <tag k="name" v="Courtyard 120"/>
    </relation>
  </modify>
  <delete>
    <way id="12002" version="2"/>
  </delete>
</osmChange>
"""

#: inside the data's extent (the working CRS stays, so an update reads only what the change touched): a moved node,
#: a tag edit, the L gaining a part, and the outline of the parts fixture going (its two parts, unchanged, lose it)
#: a part in the repaired bow tie (fixture 900: a repaired outline read again for the linking)
PART_IN_BOWTIE = square(
    17003, 170021, 60.200035, 25.117195, 60.200045, 25.117205, '<tag k="building:part" v="yes"/><tag k="height" v="3"/>'
)
CHANGE_INSIDE = osm_change(MOVE_AND_RETAG, '\n    <way id="13001" version="2"/>', NEW_PART + PART_IN_BOWTIE)

#: two small buildings south-west and north-east of the fixtures (which all stand on one parallel, the edge of
#: their extent), so that CHANGE_INSIDE moves no footprint on the edge of the data
FRAME = osm_change(
    create=square(17101, 171001, 60.199, 24.899, 60.19905, 24.8991, '<tag k="building" v="shed"/>')
    + square(17102, 171011, 60.202, 25.12, 60.20205, 25.1201, '<tag k="building" v="shed"/>')
)

EXPECTED_CHANGES = {
    1: {10001: "modified", 11001: "modified", 13003: "deleted", 13001: "modified", 17001: "added", 17002: "added"},
    2: {-1201: "modified"},
}
PIPELINE = ("lod", "landmarks", "tiles", "generalize", "textures")
#: many small tiles from the few fixtures, so that a change leaves some tiles as they were
#: many tiles and many generalize batches from the few fixtures
SMALL = {"CITYLOD_TILE_MAX_FEATURES": "4", "CITYLOD_GEN_BATCH_FEATURES": "8"}


def build(url: str, osm: Path, out: Path) -> None:
    run_etl(url, "ingest", "--osm", str(osm), env=SMALL)
    for stage in PIPELINE:
        run_etl(url, stage, env=SMALL)
    run_etl(url, "export", "--out", str(out), env=SMALL)


def files(d: Path) -> dict[str, str]:
    return {
        p.relative_to(d).as_posix(): hashlib.sha256(p.read_bytes()).hexdigest()
        for p in sorted(d.rglob("*"))
        if p.is_file()
    }


@pytest.fixture(scope="module")
def fixtures_city(city: Callable[[str], City]) -> City:
    return city("fixtures")


def test_count_change_and_refusals(tmp_path: Path) -> None:
    c1 = tmp_path / "c1.osc"
    c1.write_text(CHANGE_1)
    assert count_change(c1) == {
        "create": {"node": 8, "way": 2, "relation": 0},
        "modify": {"node": 1, "way": 1, "relation": 0},
        "delete": {"node": 0, "way": 1, "relation": 0},
    }
    gz = tmp_path / "c2.osc.gz"
    gz.write_bytes(gzip.compress(CHANGE_2.encode()))
    assert count_change(gz)["modify"]["relation"] == 1
    not_change = tmp_path / "x.osc"
    not_change.write_text('<?xml version="1.0"?><osm version="0.6"></osm>')
    with pytest.raises(ChangeFileError, match="not an OSM change file"):
        count_change(not_change)
    broken = tmp_path / "y.osc"
    broken.write_text('<osmChange version="0.6"><modify><node id="1"')
    with pytest.raises(ChangeFileError, match="cannot be read"):
        count_change(broken)


def test_only_a_state_file_the_database_left_is_dropped(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(update, "STATE_DIR", tmp_path / "osm")
    # a base file that is itself a state file (another database's, in build/osm/) is still the user's
    base, old, new = update.state_path("c" * 64), update.state_path("a" * 64), update.state_path("b" * 64)
    for p in (base, old, new):
        p.parent.mkdir(exist_ok=True)
        p.write_bytes(b"x")
    at_base = update.Chain(base, "c" * 64)
    assert not update.drop_previous_state(at_base, new) and base.exists(), "the base file is the user's"
    at_new = update.Chain(base, "c" * 64, [update.Change(1, tmp_path / "c1.osc", "d" * 64, "b" * 64)])
    assert not update.drop_previous_state(at_new, new) and new.exists()
    at_old = update.Chain(base, "c" * 64, [update.Change(1, tmp_path / "c1.osc", "d" * 64, "a" * 64)])
    assert update.drop_previous_state(at_old, new) and not old.exists() and new.exists() and base.exists()


@pytest.mark.db
def test_input_digests_change_with_what_is_read_and_only_there(
    fixtures_city: City, new_db: Callable[[str], str], tmp_path: Path
) -> None:
    """An update textures again only the tiles whose tex.input_digests changed: a colour tag of one of a tile's
    features and the LOD3 windows of one of its LOD2 buildings (read for the paint, not drawn there) each change
    that tile's digest, and only the digests of tiles that draw the building. Generalize likewise computes
    again only the batches whose gen.*_unit_digests changed: a LOD2 mesh that moves (its footprint input the
    same) changes its batch's digests, and no other batch's; an outline moved to within the pinning distance of
    a building of another batch changes that batch's footprint digest too."""
    url = new_db("update_digests")
    build(url, fixtures_city.osm, tmp_path / "out")
    with psycopg.connect(url) as conn:
        # the digest stored with each mesh (migrations/0041), which the digests hash, is its mesh's
        n, wrong = conn.execute(
            "SELECT count(*), count(*) FILTER (WHERE f.mesh_md5 IS DISTINCT FROM md5(ST_AsEWKB(f.geom))) "
            "FROM tiles.tile t CROSS JOIN LATERAL api.buildings_for_tile(t.level, t.x, t.y) f"
        ).fetchone()
        assert n > 0 and wrong == 0, (n, wrong)
        _check_input_digests(conn)
        _check_unit_digests(conn)


def _check_unit_digests(conn: psycopg.Connection) -> None:
    queries = {
        "footprints": "SELECT unit_level, unit_x, unit_y, group_ids, digest FROM gen.footprint_unit_digests(0.05, 8)",
        "decimation": "SELECT unit_level, unit_x, unit_y, building_ids, digest FROM gen.decimation_unit_digests(0, 8)",
    }  # every mesh decimated: all read

    def digests() -> dict[tuple[str, int, int, int], tuple[list[int], str]]:
        return {(step, lv, x, y): (ids, d) for step, q in queries.items() for lv, x, y, ids, d in conn.execute(q)}

    before = digests()
    assert digests() == before and len({k[1:] for k in before}) > 2, "more than one batch unit"
    (bid,) = conn.execute(
        "SELECT building_id FROM lod.building_mesh WHERE lod = 2 ORDER BY building_id LIMIT 1"
    ).fetchone()
    try:
        conn.execute(
            "UPDATE lod.building_mesh SET geom = ST_Translate(geom, 0.25, 0, 0) WHERE building_id = %s AND lod = 2",
            (bid,),
        )
        after = digests()
        changed = {k for k in before if after[k][1] != before[k][1]}
        (group,) = conn.execute("SELECT coalesce(parent_id, id) FROM osm.building WHERE id = %s", (bid,)).fetchone()
        # its feature's decimation batch, its building's footprint batch (measured against its LOD2 meshes)
        holding = {k for k, (ids, _) in before.items() if (bid if k[0] == "decimation" else group) in ids}
        assert changed == holding and {k[0] for k in changed} == {"footprints", "decimation"}, (changed, holding)
    finally:
        conn.rollback()
    # an outline moved to within 5 cm of a building of another batch pins it: that batch's footprint digest
    # changes too, though it looks up the neighbours once per batch, not per building as footprint_input does
    pinned, neighbour = conn.execute(
        "WITH u AS (SELECT unit_level, unit_x, unit_y, unnest(group_ids) AS id "
        "FROM gen.footprint_unit_digests(0.05, 8)) "
        "SELECT o.id, n.id FROM osm.building o JOIN u uo ON uo.id = o.id "
        "JOIN osm.building n ON n.parent_id IS NULL JOIN u un ON un.id = n.id "
        "AND (un.unit_level, un.unit_x, un.unit_y) <> (uo.unit_level, uo.unit_x, uo.unit_y) "
        "WHERE o.parent_id IS NULL ORDER BY 1, 2 LIMIT 1"
    ).fetchone()
    try:
        # by the vector between their closest points, and 1 cm past it
        conn.execute(
            "UPDATE osm.building n SET geom_local = ST_Translate(n.geom_local, "
            "(1 + 0.01 / d) * (ST_X(b) - ST_X(a)), (1 + 0.01 / d) * (ST_Y(b) - ST_Y(a))) "
            "FROM (SELECT ST_ClosestPoint(n.geom_local, o.geom_local) AS a, ST_ClosestPoint(o.geom_local, "
            "n.geom_local) AS b, ST_Distance(n.geom_local, o.geom_local) AS d FROM osm.building n, osm.building o "
            "WHERE n.id = %s AND o.id = %s) c WHERE n.id = %s",
            (neighbour, pinned, neighbour),
        )
        assert conn.execute(
            "SELECT ST_DWithin(n.geom_local, o.geom_local, 0.05) FROM osm.building n, osm.building o "
            "WHERE n.id = %s AND o.id = %s",
            (neighbour, pinned),
        ).fetchone() == (True,)
        after = digests()
        assert [k for k, (ids, d) in before.items() if k[0] == "footprints" and pinned in ids and after[k][1] != d]
    finally:
        conn.rollback()


def _check_input_digests(conn: psycopg.Connection) -> None:
    tiles = conn.execute(
        "SELECT array_agg(level), array_agg(x), array_agg(y) FROM tiles.tile WHERE content_features > 0"
    ).fetchone()

    def digests() -> dict[tuple[int, int, int], str]:
        return {
            (lv, x, y): d
            for lv, x, y, d in conn.execute("SELECT level, x, y, digest FROM tex.input_digests(%s, %s, %s)", tiles)
        }

    before = digests()
    assert digests() == before and len(before) == len(tiles[0])
    # a LOD2 tile's building whose LOD3 mesh has openings (so texturing reads them), drawn at LOD2 in it
    lv, x, y, bid = conn.execute(
        "SELECT t.level, t.x, t.y, f.building_id FROM tiles.tile t "
        "CROSS JOIN LATERAL tex.tile_features(t.level, t.x, t.y) f "
        "JOIN lod.building_mesh m ON m.building_id = f.building_id AND m.lod = 3 AND m.n_windows > 0 "
        "WHERE t.gen_level = 3 AND f.gen_level = 3 AND f.feature_kind <> 'block' "
        "ORDER BY 1, 2, 3, 4 LIMIT 1"
    ).fetchone()
    # the tiles that draw it (its LOD3 mesh in its leaf): their digests may change too, no other tile's
    drawing = {
        (a, b, c)
        for a, b, c in conn.execute(
            "SELECT t.level, t.x, t.y FROM tiles.tile t CROSS JOIN LATERAL tex.tile_features(t.level, t.x, t.y) f "
            "WHERE f.building_id = %s",
            (bid,),
        )
    }
    try:
        conn.execute(
            "UPDATE lod.building_mesh SET geom = ST_Translate(geom, 0, 0, 0.5) WHERE building_id = %s AND lod = 3",
            (bid,),
        )
        after = digests()
        changed = {k for k in before if after[k] != before[k]}
        assert (lv, x, y) in changed and changed <= drawing, "the openings are read: covered"
    finally:
        conn.rollback()
    try:
        conn.execute("UPDATE osm.building SET building_colour = '#123456' WHERE id = %s", (bid,))
        after = digests()
        changed = {k for k in before if after[k] != before[k]}
        assert (lv, x, y) in changed and changed <= drawing, changed
    finally:
        conn.rollback()


#: row versions of the generalized rows, of the tiles' content rows, and of the blocks (a block's row, all but its
#: version, its version, and whether it is omitted on its tile's error)
_VERSIONS = (
    "SELECT 'footprint', building_id, xmin::text FROM gen.footprint UNION ALL "
    "SELECT 'mesh', building_id * 4 + gen_level, xmin::text FROM gen.building_mesh"
)
_CONTENT = "SELECT (level, x, y, feature_kind, feature_id)::text, xmin::text FROM tiles.tile_content"
_BLOCKS = "SELECT block_id, md5(k::text), xmin::text, built_error_m IS NOT NULL FROM gen.block k"
_LAST_STATE = "SELECT state_sha256 FROM meta.osm_change ORDER BY seq DESC LIMIT 1"


def _last_counts(conn: psycopg.Connection, stage: str) -> dict:
    (counts,) = conn.execute(
        "SELECT counts FROM meta.pipeline_run WHERE stage = %s ORDER BY run_id DESC LIMIT 1", (stage,)
    ).fetchone()
    return counts


def _wrote_only_what_changed(conn: psycopg.Connection, seq: int, before: tuple, base: Path) -> None:
    """After change ``seq``: the state file left is gone, and only the rows the change reached were written."""
    versions, content, blocks, left = before
    after = {(t, k): v for t, k, v in conn.execute(_VERSIONS)}
    # the state file the update left is removed (one copy of the city per change file would fill the disk of a
    # service following minutely diffs); the base file and the new state stay
    assert state_path(conn.execute(_LAST_STATE).fetchone()[0]).is_file() and base.is_file()
    assert left is None or not state_path(left[0]).exists(), seq
    # the rows of the batches the change missed stay where they are (the same row versions), the others are
    # written anew: an update writes what changed, not the whole table again
    same = sum(after[k] == v for k, v in versions.items() if k in after)
    assert 0 < same < len(after), (seq, same, len(after))
    # so do the tiles' content rows the change did not reach (the hierarchy writes the rows that differ)
    after_content = dict(conn.execute(_CONTENT).fetchall())
    same = sum(after_content.get(k) == v for k, v in content.items())
    assert 0 < same < len(after_content), (seq, same, len(after_content))
    # a block whose row did not change keeps its version, those omitted on their tile's error too (the omissions
    # are decided again, and only the blocks whose omission changes are written)
    after_blocks = {b: rest for b, *rest in conn.execute(_BLOCKS)}
    unchanged = [b for b, (row, _, _) in blocks.items() if after_blocks.get(b, [None])[0] == row]
    assert all(after_blocks[b][1] == blocks[b][1] for b in unchanged), seq
    # (that some of them are omitted on their tile's error is asserted on Helsinki, test_update_history.py: the
    # fixtures' small tree need not have one the change misses)
    changed = dict(conn.execute("SELECT id, change FROM osm.building_change"))
    assert changed == EXPECTED_CHANGES[seq], f"change {seq}: only what it touched is replaced"


def _stages_kept_their_work(conn: psycopg.Connection, seq: int) -> None:
    """After change ``seq``: every stage redid only what the change reached, as its counts say."""
    tex, gen = _last_counts(conn, "textures"), _last_counts(conn, "generalize")
    assert 0 < tex["tiles_kept"] < tex["tiles"], "the textures of the tiles the change missed are kept"
    # the hierarchy measured and the textures fingerprinted again only where the change reached
    # (core/changes.py); the first change adds a building beyond the others, which moves every tile's cell
    (n_tiles,) = conn.execute("SELECT count(*) FROM tiles.tile").fetchone()
    assert gen["hierarchy_tiles"] is not None and tex["tiles_fingerprinted"] > 0, (gen, tex)
    if seq == 2:
        assert gen["hierarchy_tiles"] < n_tiles and tex["tiles_fingerprinted"] < tex["tiles"], (gen, tex)
    assert gen["batches"]["blocks_kept"] > 0, gen  # the blocks the change missed in the tiles it hit
    for step in ("footprints", "decimation", "blocks"):  # the batches the change missed are kept, the rest made
        assert gen["batches"][step]["kept"] > 0 and gen["batches"][step]["computed"] > 0, (step, gen)
    exp = _last_counts(conn, "export")
    assert exp["glb_built"] > 0 and exp["glb_copied"] == exp["glb"] - exp["glb_built"], exp
    # the first change adds a building beyond the others: the root region, every glb's frame, grows
    assert (exp["glb_copied"] > 0) == (seq == 2), exp
    # the second: only the tiles it reached are fingerprinted (core/changes.py), the others keep their keys
    assert (exp["glb_fingerprinted"] < exp["glb"]) == (seq == 2), exp
    lod, ing = _last_counts(conn, "lod"), _last_counts(conn, "ingest")
    (n,) = conn.execute("SELECT count(*) FROM osm.building").fetchone()
    # the first change adds a building beyond the extent (a new working CRS may follow): every candidate is read
    # again; the second reads only what it touched (every relation, of which the courtyard)
    assert ing["partial"] == (seq == 2) and (ing["staged"] < n) == (seq == 2), ing
    assert lod["changed_only"] and 0 < lod["in"] < n, "lod drew the changed buildings (and kin) alone"


@pytest.mark.db
def test_update_equals_a_full_rebuild(fixtures_city: City, new_db: Callable[[str], str], tmp_path: Path) -> None:
    base = tmp_path / "base.osm"
    shutil.copyfile(fixtures_city.osm, base)
    c1, c2 = tmp_path / "c1.osc", tmp_path / "c2.osc.gz"
    c1.write_text(CHANGE_1)
    c2.write_bytes(gzip.compress(CHANGE_2.encode()))

    inc = new_db("update_inc")
    build(inc, base, tmp_path / "inc")
    for seq, change in ((1, c1), (2, c2)):
        with psycopg.connect(inc) as conn:
            before = (
                {(t, k): v for t, k, v in conn.execute(_VERSIONS)},
                dict(conn.execute(_CONTENT).fetchall()),
                {b: rest for b, *rest in conn.execute(_BLOCKS)},
                conn.execute(_LAST_STATE).fetchone(),
            )
        run_etl(inc, "update", "--osc", str(change), "--out", str(tmp_path / "inc"), env=SMALL)
        with psycopg.connect(inc) as conn:
            _wrote_only_what_changed(conn, seq, before, base)
            _stages_kept_their_work(conn, seq)
    state_sha = _equals_the_full_rebuild(inc, new_db("update_full"), base, [c1, c2], tmp_path)
    _the_state_chain(inc, state_sha, base, c1, tmp_path)


def _equals_the_full_rebuild(inc: str, full: str, base: Path, changes: list[Path], tmp_path: Path) -> str:
    """The updated database and tileset are a full rebuild's of the merged file; returns the last state's sha256."""
    c1, c2 = changes
    merged = tmp_path / "merged.osm.pbf"
    apply_changes(base, [c1, c2], merged)
    build(full, merged, tmp_path / "full")
    with psycopg.connect(full) as conn:
        assert conn.execute("SELECT count(*) FROM tiles.tile WHERE is_leaf").fetchone()[0] > 3

    with psycopg.connect(inc) as a, psycopg.connect(full) as b:
        for table in TABLES:
            ra, rb = table_rows(a, table), table_rows(b, table)
            assert ra == rb, (table, len(ra), len(rb), sorted(set(ra) ^ set(rb))[:3])
        # what the changes did, read back
        (moved,) = a.execute("SELECT ST_XMax(geom) FROM osm.building WHERE id = 10001").fetchone()
        assert moved == pytest.approx(24.9004157)
        assert a.execute("SELECT levels, n_parts FROM osm.building WHERE id = 11001").fetchone() == (6.0, 1)
        assert a.execute("SELECT count(*) FROM osm.building WHERE id = 13003").fetchone() == (0,)
        (area,) = a.execute("SELECT area_m2 FROM osm.building WHERE id = -1201").fetchone()
        assert area == pytest.approx(1600, rel=0.01), "the courtyard is filled"
        chain = a.execute("SELECT seq, path, counts -> 'delete' ->> 'way' FROM meta.osm_change ORDER BY seq").fetchall()
        assert chain == [(1, str(c1), "1"), (2, str(c2), "1")]
    fa, fb = files(tmp_path / "inc"), files(tmp_path / "full")
    assert fa.pop("tileset.json") and fb.pop("tileset.json") and fa == fb, "every glb and subtree byte for byte"
    # tileset.json too, but for its tilesetVersion: the sha256 of the OSM file each was built from
    ta, tb = (json.loads((tmp_path / d / "tileset.json").read_text()) for d in ("inc", "full"))
    with psycopg.connect(inc) as conn:
        (state_sha,) = conn.execute("SELECT state_sha256 FROM meta.osm_change ORDER BY seq DESC LIMIT 1").fetchone()
    assert ta["asset"].pop("tilesetVersion") == hashlib.sha256(state_path(state_sha).read_bytes()).hexdigest()[:16]
    assert tb["asset"].pop("tilesetVersion") == hashlib.sha256(merged.read_bytes()).hexdigest()[:16]
    assert ta == tb
    return state_sha


def _the_state_chain(inc: str, state_sha: str, base: Path, c1: Path, tmp_path: Path) -> None:
    """The state is made again when its file is gone, a change file applies once, a lost one stops the rebuild
    of the state, and a full ingest starts a new chain."""
    # the state is made again from the base file and the recorded changes when its file is gone
    state_path(state_sha).unlink()
    c3 = tmp_path / "c3.osc"
    c3.write_text(
        CHANGE_1.replace(
            'version="2" lat="60.2001795" lon="24.9004157"', 'version="3" lat="60.2001795" lon="24.9003615"'
        )
    )
    run_etl(inc, "update", "--osc", str(c3), env=SMALL)
    with psycopg.connect(inc) as conn:
        assert dict(conn.execute("SELECT id, change FROM osm.building_change")) == {10001: "modified"}
    # make ingest with the base file: the database follows it (plus its changes), nothing to do
    r = run_etl(inc, "ingest", "--osm", str(base), "--if-stale")
    assert "current" in r.stdout and "skipped" in r.stdout
    # applying a change file twice is a no-op; a recorded change file that vanished stops the rebuild of the state
    r = run_etl(inc, "update", "--osc", str(c3))
    assert "nothing new to apply" in r.stdout
    with psycopg.connect(inc) as conn:
        (state_sha,) = conn.execute("SELECT state_sha256 FROM meta.osm_change ORDER BY seq DESC LIMIT 1").fetchone()
    state_path(state_sha).unlink()
    c1.unlink()
    c4 = tmp_path / "c4.osc"
    c4.write_text(CHANGE_2.replace('version="2"', 'version="3"'))
    r = run_etl(inc, "update", "--osc", str(c4), check=False)
    assert r.returncode != 0 and f"change file 1 {c1} is missing" in r.stderr and "Traceback" not in r.stderr

    # a full ingest starts a new chain; lod not run since, the next update draws every building, not the changed
    run_etl(inc, "ingest", "--osm", str(base), env=SMALL)
    run_etl(inc, "update", "--osc", str(c4), env=SMALL)
    with psycopg.connect(inc) as conn:
        (lod,) = conn.execute(
            "SELECT counts FROM meta.pipeline_run WHERE stage = 'lod' ORDER BY run_id DESC LIMIT 1"
        ).fetchone()
        assert not lod["changed_only"]
        assert conn.execute("SELECT seq, path FROM meta.osm_change").fetchall() == [(1, str(c4))]

    # a change that touches no building (a bench appears): the stages' work stands, carried over; only the export
    # runs again, and its glbs are the same bytes
    run_etl(inc, "export", "--out", str(tmp_path / "before"), env=SMALL)
    c5 = tmp_path / "c5.osc"
    c5.write_text(
        '<?xml version="1.0"?><osmChange version="0.6"><create><node id="170101" version="1" '
        'lat="60.2005" lon="24.9010"><tag k="amenity" v="bench"/></node></create></osmChange>'
    )
    r = run_etl(inc, "update", "--osc", str(c5), "--out", str(tmp_path / "after"), env=SMALL)
    assert "no building changed" in r.stderr
    with psycopg.connect(inc) as conn:
        assert conn.execute("SELECT count(*) FROM osm.building_change").fetchone() == (0,)
        carried = dict(
            conn.execute(
                "SELECT DISTINCT ON (stage) stage, counts ? 'carried_from' FROM "
                "meta.pipeline_run WHERE status = 'ok' ORDER BY stage, run_id DESC"
            )
        )
    assert all(carried[st] for st in PIPELINE) and not carried["export"] and not carried["ingest"]
    for st in PIPELINE:  # current with the new ingest run: make finds nothing to do
        assert "current" in run_etl(inc, st, "--if-stale", env=SMALL).stdout
    before, after = files(tmp_path / "before"), files(tmp_path / "after")
    assert before.pop("tileset.json") != after.pop("tileset.json") and before == after
    with psycopg.connect(inc, autocommit=True) as conn:
        # the runs carried over changed nothing; a run that recorded no change set (it died after its commit, or
        # ran before migration 0043) may have changed anything: the stages after it read every tile again
        def reached(stage: str) -> set[tuple[int, int, int]] | None:
            since = changes.since(conn, stage, changes.last_ok_run(conn, stage))
            return None if since is None else changes.reach(conn, since)

        assert reached("generalize") == set() and reached("textures") == set()
        conn.execute("INSERT INTO meta.pipeline_run (stage, status, finished_at) VALUES ('tiles', 'failed', now())")
        assert reached("generalize") is None and reached("textures") is None


@pytest.mark.db
def test_an_update_reads_only_what_its_change_touched(
    fixtures_city: City, new_db: Callable[[str], str], tmp_path: Path
) -> None:
    """Ingest in an update stages only the ways the change names or whose nodes it moves (and every relation);
    the part linking still finds what a full ingest of the new state finds."""
    frame, change = tmp_path / "frame.osc", tmp_path / "inside.osc"
    frame.write_text(FRAME)
    change.write_text(CHANGE_INSIDE)
    base, state = tmp_path / "base.osm.pbf", tmp_path / "state.osm.pbf"
    apply_changes(fixtures_city.osm, [frame], base)
    apply_changes(base, [change], state)
    inc = new_db("partial_inc")
    run_etl(inc, "ingest", "--osm", str(base))
    with psycopg.connect(inc) as conn:
        (n_before,) = conn.execute("SELECT count(*) FROM osm.building").fetchone()
        ctx = Context(
            conn,
            inc,
            Settings.from_env(),
            0,
            mode="update",
            options=ingest.Input(state, "x", update.change_ids([change])),
        )
        counts = ingest.run(ctx).counts
        changed = dict(conn.execute("SELECT id, change FROM osm.building_change"))
    assert counts["partial"] and counts["staged"] < n_before / 2, counts
    # the parts of the outline that went are unchanged ways, linked again (to nothing); the L's new part is linked
    assert changed == {
        10001: "modified",
        11001: "modified",
        13001: "deleted",
        13002: "modified",
        13003: "modified",
        17002: "added",
        17003: "added",
        90002: "modified",
    }, changed
    full = new_db("partial_full")
    run_etl(full, "ingest", "--osm", str(state))
    with psycopg.connect(inc) as a, psycopg.connect(full) as b:
        for table in (t for t in TABLES if t.split(".")[0] in ("osm", "meta")):  # what ingest writes
            ra, rb = table_rows(a, table), table_rows(b, table)
            assert ra == rb, (table, len(ra), len(rb), sorted(set(ra) ^ set(rb))[:3])
        assert a.execute("SELECT parent_id FROM osm.building WHERE id = 17002").fetchone() == (11001,)
        assert a.execute("SELECT n_parts FROM osm.building WHERE id = 11001").fetchone() == (1,)
        assert a.execute(
            "SELECT b.parent_id, o.repaired FROM osm.building b JOIN osm.building o ON o.id = b.parent_id "
            "WHERE b.id = 17003"
        ).fetchone() == (90002, True)


def test_a_small_write_leaves_the_statistics_to_autovacuum(new_db: Callable[[str], str]) -> None:
    """core.db.analyze, which every stage of an update calls for the tables it wrote: an update of a few rows
    skips the ANALYZE (0.1 to 0.4 s a table of meshes), a larger write and a full run (written None) do not."""
    with psycopg.connect(new_db("update_analyze"), autocommit=True) as conn, conn.cursor() as cur:
        cur.execute("CREATE TABLE public.t AS SELECT g AS id FROM generate_series(1, 1000) g")

        def counted() -> float:
            return cur.execute("SELECT reltuples FROM pg_class WHERE oid = 'public.t'::regclass").fetchone()[0]

        assert analyze(cur, "public.t", 1) and counted() == 1000, "no statistics yet: it runs whatever was written"
        cur.execute("INSERT INTO public.t SELECT generate_series(1001, 1050)")
        assert not analyze(cur, "public.t", 50) and counted() == 1000, "5 % written: the statistics stand"
        assert analyze(cur, "public.t", 100) and counted() == 1050
        cur.execute("INSERT INTO public.t SELECT generate_series(1051, 1060)")
        assert analyze(cur, "public.t") and counted() == 1060, "a full run always analyzes"


#: CHANGE_1's edits that delete or add no building (a moved node, a tag edit): every table the stages write holds
#: as many rows after the update as before, or changes its count at one commit
MODIFY_ONLY = CHANGE_1[: CHANGE_1.index("  <delete>")] + "</osmChange>\n"


@pytest.mark.db
def test_readers_never_wait_nor_see_a_table_half_written(
    fixtures_city: City, new_db: Callable[[str], str], tmp_path: Path
) -> None:
    """Issue 20's generations for the analysts' tables: while an update runs, a reader counting the rows of
    every table the stages write (and the root tile's content through api.buildings_for_tile) over and over
    never waits on a lock for more than 100 ms and finds each table as it was before or as it is after, never
    emptied or half written (update_bench.Reader)."""
    url = new_db("update_readers")
    build(url, fixtures_city.osm, tmp_path / "out")
    change = tmp_path / "modify.osc"
    change.write_text(MODIFY_ONLY)
    with Reader(url) as reader:
        run_etl(url, "update", "--osc", str(change), env=SMALL)
    r = reader.report()
    with psycopg.connect(url) as conn:
        (changed,) = conn.execute("SELECT count(*) FROM osm.building_change WHERE change = 'modified'").fetchone()
    assert changed > 0 and r["lock_timeouts"] == 0 and not r["errors"], r
    # the reader was there while the stages that rewrite whole tables rewrote them
    assert {"generalize", "textures"} <= set(r["running"]) and r["rounds"] > 10, r
    assert not r["odd_counts"], (r, reader.before, reader.after)
