"""`python -m etl update` with real changes, updated it must equal a full rebuild: every table, every glb and subtree.

* Helsinki (the demo extract) as it was on 2018-11-01, as far as the extract's own history tells
  (tests/support/history.py: every object at version 1 stamped after that day left out), brought to the extract by
  the change file of the buildings, parts and other objects mappers created since: creations only.
* A small area of Oakland (a street relation, its members and their nodes) as it stood on three days, from a
  file of its full history (tests.support.history.fetch_history): two real change files between them, with the
  nodes mappers moved and deleted, the buildings they retagged and redrew, a way that became a building and
  buildings drawn new."""

from __future__ import annotations

import datetime as dt
import itertools
from collections.abc import Callable
from pathlib import Path

import osmium
import psycopg
import pytest

from core.settings import REPO
from etl.update.osc import apply_changes
from tests.conftest import helsinki, run_etl
from tests.db.test_update import PIPELINE
from tests.support.equivalence import differences, tileset_differences
from tests.support.history import changes, fetch_history, read_history, split, states

BEFORE = dt.datetime(2018, 11, 1, tzinfo=dt.UTC)
#: tiles of at most 64 features and generalize batches of 100, so that the new buildings leave some unchanged
SETTINGS = {"CITYLOD_TILE_MAX_FEATURES": "64", "CITYLOD_GEN_BATCH_FEATURES": "100"}


def objects(osm: Path) -> set[tuple]:
    """Every object of ``osm``: its type, id, version, location or members, and tags."""
    out: set[tuple] = set()
    for o in osmium.FileProcessor(str(osm)):
        tags = tuple(sorted((t.k, t.v) for t in o.tags))
        if o.is_node():
            out.add(("n", o.id, o.version, o.location.x, o.location.y, tags))
        elif o.is_way():
            out.add(("w", o.id, o.version, tuple(n.ref for n in o.nodes), tags))
        else:
            out.add(("r", o.id, o.version, tuple((m.type, m.ref, m.role) for m in o.members), tags))
    return out


def build(url: str, osm: Path, out: Path) -> None:
    run_etl(url, "ingest", "--osm", str(osm), env=SETTINGS)
    for stage in PIPELINE:
        run_etl(url, stage, env=SETTINGS)
    run_etl(url, "export", "--out", str(out), env=SETTINGS)


@pytest.mark.db
def test_real_creations_update_equals_a_full_rebuild(new_db: Callable[[str], str], tmp_path: Path) -> None:
    real = helsinki()
    base, change = tmp_path / "helsinki-2018-11-01.osm.pbf", tmp_path / "helsinki-since-2018-11-01.osc"
    made = split(real, BEFORE, base, change)
    assert made["ways"] > 0 and made["nodes"] > 0 and made["relations"] > 0, made
    merged = tmp_path / "merged.osm.pbf"
    apply_changes(base, [change], merged)
    truth = objects(real)
    assert objects(merged) == truth, "the change brings the earlier state to the extract, object for object"
    assert len(truth) - len(objects(base)) == sum(made.values())

    inc = new_db("history_inc")
    build(inc, base, tmp_path / "inc")
    with psycopg.connect(inc) as conn:
        (before,) = conn.execute("SELECT count(*) FROM osm.building").fetchone()
        blocks = {b: rest for b, *rest in conn.execute(_BLOCKS)}
    run_etl(inc, "update", "--osc", str(change), "--out", str(tmp_path / "inc"), env=SETTINGS)
    with psycopg.connect(inc) as conn:
        after_blocks = {b: rest for b, *rest in conn.execute(_BLOCKS)}
    # a block whose row did not change keeps its row version, those omitted on their tile's error too (the
    # omissions are decided again, and only the blocks whose omission changes are written)
    unchanged = [b for b, (row, _, _) in blocks.items() if after_blocks.get(b, [None])[0] == row]
    assert unchanged and all(after_blocks[b][1] == blocks[b][1] for b in unchanged)
    assert sum(blocks[b][2] for b in unchanged) > 0, "blocks omitted on tile error, unchanged"

    full = new_db("history_full")
    build(full, real, tmp_path / "full")

    with psycopg.connect(inc) as conn:
        changed = dict(conn.execute("SELECT id, change FROM osm.building_change").fetchall())
        (after,) = conn.execute("SELECT count(*) FROM osm.building").fetchone()
        runs = dict(
            conn.execute(
                "SELECT DISTINCT ON (stage) stage, counts FROM meta.pipeline_run "
                "WHERE status = 'ok' ORDER BY stage, run_id DESC"
            ).fetchall()
        )
    # new buildings (17), and the old ones that gained new parts (2): nothing deleted, most buildings untouched
    assert "added" in changed.values() and "deleted" not in changed.values(), changed
    assert after - before == sum(c == "added" for c in changed.values()) and len(changed) < after / 10
    assert runs["lod"]["changed_only"], "lod drew the changed buildings alone"
    # ingest read again only the candidates the change touched (its parts linked into outlines it did not touch)
    assert runs["ingest"]["partial"] and runs["ingest"]["staged"] < after / 2, runs["ingest"]
    # the block tiles above the new buildings are made again, but their clusters the change missed are kept
    assert runs["generalize"]["batches"]["blocks_kept"] > 0, runs["generalize"]["batches"]
    assert 0 < runs["textures"]["tiles_kept"] < runs["textures"]["tiles"], runs["textures"]
    # leaves the change missed whose LOD2 tile it changed: drawn again for the chart cache, their pages kept
    assert runs["textures"]["tiles_redrawn"] > 0, runs["textures"]
    assert 0 < runs["export"]["glb_copied"] < runs["export"]["glb"], runs["export"]

    assert differences(inc, full) == {}, "every table, row for row"
    # every glb and subtree byte for byte, tileset.json but for its tilesetVersion (the sha256 of the file read)
    assert tileset_differences(tmp_path / "inc", tmp_path / "full") == []


_BLOCKS = "SELECT block_id, md5(k::text), xmin::text, built_error_m IS NOT NULL FROM gen.block k"

#: the Oakland history's three days: every change of its buildings falls between them
DAYS = [
    dt.datetime(2014, 10, 1, tzinfo=dt.UTC),
    dt.datetime(2015, 6, 1, tzinfo=dt.UTC),
    dt.datetime(2016, 12, 31, tzinfo=dt.UTC),
]


def buildings(osm: Path) -> dict[int, tuple]:
    """The building ways of ``osm``: id -> (version, node ids, tags)."""
    return {
        o.id: (o.version, tuple(n.ref for n in o.nodes), dict(o.tags))
        for o in osmium.FileProcessor(str(osm))
        if o.is_way() and "building" in o.tags
    }


@pytest.mark.db
def test_real_edits_and_deletions_update_equals_a_full_rebuild(new_db: Callable[[str], str], tmp_path: Path) -> None:
    history = read_history(fetch_history(REPO / "data" / "oakland-relation-4017808-history.osm"))
    days = [tmp_path / f"oakland-{d.date()}.osm" for d in DAYS]
    for d, out in zip(DAYS, days, strict=True):
        states(history, d, out)
    osc = [tmp_path / f"oakland-{a.date()}-to-{b.date()}.osc" for a, b in itertools.pairwise(DAYS)]
    made = [changes(history, a, b, out) for (a, b), out in zip(itertools.pairwise(DAYS), osc, strict=True)]
    # real edits of every kind: nodes moved and deleted, ways redrawn and drawn new, the relation's members changed
    for m in made:
        assert m["modify"]["node"] and m["delete"]["node"] and m["modify"]["way"] and m["create"]["way"], m
        assert m["modify"]["relation"] == 1, m
    merged = tmp_path / "merged.osm.pbf"
    apply_changes(days[0], osc, merged)
    assert objects(merged) == objects(days[2]), "the changes bring the first day's state to the last day's"
    first, middle, last = (buildings(d) for d in days)
    assert set(first) < set(middle) == set(last), "buildings drawn new in the first step"
    grew = [i for i in first if i in last and (first[i][1] != last[i][1] or first[i][2] != last[i][2])]
    assert grew, "a building of the first day retagged or redrawn"
    became = [i for i in last if i not in first and history[("w", i)][0][1] < DAYS[0]]
    assert became, "a way of the first day that became a building"

    inc = new_db("oakland_inc")
    build(inc, days[0], tmp_path / "inc")
    seen = []
    for change in osc:
        run_etl(inc, "update", "--osc", str(change), "--out", str(tmp_path / "inc"), env=SETTINGS)
        with psycopg.connect(inc) as conn:
            seen.append(dict(conn.execute("SELECT id, change FROM osm.building_change").fetchall()))
    full = new_db("oakland_full")
    build(full, days[2], tmp_path / "full")
    # what each update saw: buildings added (new, and the way retagged a building) then, and buildings modified
    assert "added" in seen[0].values() and all("modified" in s.values() for s in seen), seen
    with psycopg.connect(inc) as conn:
        assert [r[0] for r in conn.execute("SELECT seq FROM meta.osm_change ORDER BY seq")] == [1, 2]
    assert differences(inc, full) == {}, "every table, row for row"
    assert tileset_differences(tmp_path / "inc", tmp_path / "full") == []
