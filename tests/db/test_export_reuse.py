"""An export that publishes copies the glbs whose input did not change (exporter/reuse.py, api.export_digest):
the tiles a change touches are built again and nothing else, and the directory is byte for byte what an export
building every tile writes."""

from __future__ import annotations

import re
import shutil
from collections.abc import Iterator
from pathlib import Path

import psycopg
import pytest

from exporter.reuse import glb_triangles
from tests.conftest import City, run_etl
from tests.db.test_export_publish import on_disk
from tests.db.test_serve_db import city_copy

SMALL = {"CITYLOD_TILE_MAX_FEATURES": "4"}  # many tiles from the few fixtures


@pytest.fixture(scope="module")
def reuse_url(city, server_url: str) -> Iterator[str]:
    fixtures: City = city("fixtures")
    with city_copy(fixtures, server_url, "reuse") as url:
        for stage in ("tiles", "generalize", "textures"):
            run_etl(url, stage, env=SMALL)
        yield url


def last_export(url: str) -> dict:
    with psycopg.connect(url) as conn:
        (counts,) = conn.execute(
            "SELECT counts FROM meta.pipeline_run WHERE stage = 'export' ORDER BY run_id DESC LIMIT 1"
        ).fetchone()
    return counts


def export(url: str, out: Path, *args: str) -> dict:
    run_etl(url, "export", "--out", str(out), *args, env=SMALL)
    return last_export(url)


@pytest.mark.db
def test_the_digest_hashes_every_column_of_export_features(reuse_url: str) -> None:
    with psycopg.connect(reuse_url) as conn:
        columns = [
            n
            for (n,) in conn.execute(
                "SELECT a.n FROM pg_proc p, unnest(p.proargnames, p.proargmodes) AS a(n, m) "
                "WHERE p.oid = 'api.export_features'::regproc AND a.m = 't'"
            )
        ]
        (body,) = conn.execute("SELECT prosrc FROM pg_proc WHERE oid = 'api.export_digest'::regproc").fetchone()
    assert len(columns) > 30 and "lm_level" in columns and "lm_rank" not in columns
    missing = [
        c for c in columns if not re.search(rf"\br\.{c}\b", body) or not re.search(rf"\bAS {c}\b|\bf\.{c}\b", body)
    ]
    assert not missing, f"api.export_digest does not hash {missing}: a change there would keep a stale glb"


@pytest.mark.db
def test_an_export_builds_only_the_tiles_whose_input_changed(reuse_url: str, tmp_path: Path) -> None:
    out, full = tmp_path / "r", tmp_path / "full" / "r"
    first = export(reuse_url, out)
    n = first["glb"]
    assert n > 4 and (first["glb_copied"], first["glb_built"]) == (0, n)

    again = export(reuse_url, out)  # nothing changed: every glb copied, the same bytes
    assert (again["glb_copied"], again["glb_built"]) == (n, 0)
    assert (again["features"], again["triangles"], again["bytes"]) == (
        first["features"],
        first["triangles"],
        first["bytes"],
    )
    before = on_disk(out)

    with psycopg.connect(reuse_url) as conn:  # one building renamed: the tiles it is drawn in
        (bid,) = conn.execute(
            "SELECT id FROM osm.building WHERE kind = 'building' AND n_parts = 0 ORDER BY id LIMIT 1"
        ).fetchone()
        conn.execute("UPDATE osm.building SET name = 'renamed for reuse' WHERE id = %s", (bid,))
        drawn_in = {
            f"content/{lv}/{x}/{y}.glb"
            for lv, x, y in conn.execute(
                "SELECT t.level, t.x, t.y FROM tiles.tile t WHERE EXISTS (SELECT 1 FROM "
                "api.buildings_for_tile(t.level, t.x, t.y) f WHERE f.kind <> 'block' AND f.building_id = %s)",
                (bid,),
            )
        }
    renamed = export(reuse_url, out)
    after = on_disk(out)
    changed = {u for u in after if u.endswith(".glb") and after[u] != before[u]}
    assert changed == drawn_in and renamed["glb_built"] == len(drawn_in) and 0 < len(drawn_in) < n
    assert renamed["glb_copied"] == n - len(drawn_in)
    built = export(reuse_url, full, "--no-publish")  # every tile built: the same files
    assert built["glb_copied"] == 0 and on_disk(full) == after
    assert (renamed["features"], renamed["triangles"], renamed["bytes"]) == (
        built["features"],
        built["triangles"],
        built["bytes"],
    )
    assert sum(glb_triangles((out / u).read_bytes()) for u in after if u.endswith(".glb")) == built["triangles"]

    with psycopg.connect(reuse_url) as conn:  # a building's landmark level (in the glbs it is drawn in)
        (lid,) = conn.execute(
            "SELECT building_id FROM lm.building WHERE NOT is_landmark ORDER BY building_id LIMIT 1"
        ).fetchone()
        conn.execute("UPDATE lm.building SET level = level + 1 WHERE building_id = %s", (lid,))
    leveled = export(reuse_url, out)
    assert 0 < leveled["glb_built"] < n
    export(reuse_url, full, "--no-publish")
    assert on_disk(full) == on_disk(out)

    shutil.rmtree(out)  # the directory lost: the unchanged glbs come from pub.blob
    lost = export(reuse_url, out)
    assert (lost["glb_copied"], lost["glb_built"]) == (n, 0) and on_disk(out) == on_disk(full)
    with psycopg.connect(reuse_url) as conn:
        recorded = conn.execute(
            "SELECT count(*) FILTER (WHERE input_digest IS NOT NULL), count(*) FILTER (WHERE path LIKE '%%.glb') "
            "FROM pub.file WHERE generation = (SELECT max(generation) FROM pub.generation WHERE tileset = 'r')"
        ).fetchone()
    assert recorded == (n, n), "every glb and only the glbs record their input"
