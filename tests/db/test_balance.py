"""Every stage prints and records its balance, in = out + rejected, and both sides are what the database holds.

The whole pipeline (ingest ... textures, export) runs on the spine fixtures, whose broken buildings give ingest
real rejects, in a database of its own; each stage's closing line and its meta.pipeline_run counts are read
back and compared with counts taken from the tables and files the stage wrote."""

from __future__ import annotations

import json
import os
import re

import pytest

from exporter.gltf import read_glb
from tests.conftest import BUILD, SPINE_FILES, merge_osm, run_etl

STAGES = ("ingest", "lod", "landmarks", "tiles", "generalize", "textures", "export")
LINE = re.compile(
    r"^(\w+): in ([\d,]+) ([\w ]+?) = (.+) \+ rejected ([\d,]+) \| .+ \| [\d.]+ s \| [\d,]+ buildings/s$", re.M
)


def number(s: str) -> int:
    return int(s.replace(",", ""))


@pytest.fixture(scope="module")
def pipeline(new_db, tmp_path_factory):
    url = new_db("balance")
    osm = merge_osm(SPINE_FILES, BUILD / f"balance-{os.getpid()}.osm")
    out = tmp_path_factory.mktemp("balance") / "tiles"
    lines = {}
    for stage in STAGES:
        extra = {"ingest": ["--osm", str(osm)], "export": ["--out", str(out)]}.get(stage, [])
        stdout = run_etl(url, stage, *extra).stdout
        found = LINE.findall(stdout)
        assert len(found) == 1 and found[0][0] == stage, stdout
        lines[stage] = found[0]
    return url, out, lines


def test_every_stage_prints_and_records_its_balance(pipeline, conn_of) -> None:
    url, _, lines = pipeline
    conn = conn_of(url)
    for stage in STAGES:
        counts = conn.execute(
            """SELECT counts FROM meta.pipeline_run WHERE stage = %s AND status = 'ok'
                                 ORDER BY run_id DESC LIMIT 1""",
            (stage,),
        ).fetchone()[0]
        _, n_in, unit, outs, rejected = lines[stage]
        assert counts["in"] == number(n_in) and counts["rejected"] == number(rejected), (stage, counts)
        assert counts["unit"] == unit and counts["in"] == counts["out"] + counts["rejected"] > 0, (stage, counts)
        # the printed parts of the output are the recorded ones
        printed = {name: number(n) for n, name in re.findall(r"([\d,]+) ([\w ]+?)(?: \+ |$)", outs)}
        assert printed == counts["out_by_kind"] and sum(printed.values()) == counts["out"], (stage, outs)


def test_each_side_of_the_balances_is_what_the_tables_hold(pipeline, conn_of) -> None:
    url, out, _ = pipeline
    conn = conn_of(url)

    def one(q: str) -> int:
        return int(conn.execute(q).fetchone()[0])

    def counts(stage: str) -> dict:
        return conn.execute(
            "SELECT counts FROM meta.pipeline_run WHERE stage = %s AND status = 'ok'", (stage,)
        ).fetchone()[0]

    ingest = counts("ingest")
    assert ingest["out"] == one("SELECT count(*) FROM osm.building")
    assert ingest["rejected"] == one("SELECT count(*) FROM osm.reject WHERE stage = 'ingest'") > 0
    lod = counts("lod")
    assert lod["in"] == one("SELECT count(*) FROM osm.building")
    assert lod["out_by_kind"]["drawn"] == one("SELECT count(*) FROM lod.building_mesh WHERE lod = 1")
    assert lod["rejected"] == one("SELECT count(*) FROM osm.reject WHERE stage = 'lod'")
    assert counts("landmarks")["out"] == one("SELECT count(*) FROM lm.building")
    tiles = counts("tiles")
    assert tiles["in"] == one("SELECT count(*) FROM lod.building_mesh WHERE lod = 3")
    assert tiles["out"] == one("SELECT count(*) FROM tiles.building_tile")
    gen = counts("generalize")
    assert gen["in"] == one("SELECT count(DISTINCT group_id) FROM tiles.building_tile")
    assert gen["out"] == one("SELECT count(*) FROM gen.footprint")
    tex = counts("textures")
    assert tex["out"] == one("SELECT count(*) FROM tex.feature_uv")
    assert tex["rejected"] == one("SELECT count(*) FROM tex.failure")
    assert tex["in"] == one("SELECT sum(content_features) FROM tiles.tile")
    # export: the features its glbs hold, read back from the files
    written = 0
    for glb in out.rglob("*.glb"):
        doc, _ = read_glb(glb.read_bytes())
        written += sum(t["count"] for t in doc["extensions"]["EXT_structural_metadata"]["propertyTables"])
    export = counts("export")
    assert export["out"] == written == export["in"] == one("SELECT sum(content_features) FROM tiles.tile")
    assert json.loads((out / "tileset.json").read_text())["asset"]["version"] == "1.1"
