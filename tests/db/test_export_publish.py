"""Published tilesets (pub.*, exporter/publish.py) and `python -m etl serve --db`, which streams the live
generation of one: the export's files byte for byte, a re-export stores only what changed (an unchanged tile
keeps its ETag and its cached bytes), old generations and their blobs go, and under a steady 200 requests per
second the server answers every request while the whole pipeline rebuilds the database behind it (the soak)."""

from __future__ import annotations

import hashlib
import json
import os
import threading
import time
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

import psycopg
import pytest

from core.tiles3d import tileset_files
from exporter.publish import check_name, tileset_name
from exporter.serve.app import make_app
from exporter.serve.published import PublishedSource
from exporter.serve.reader import READER_ROLE, reader_url
from tests.conftest import City, run_etl
from tests.db.test_serve_db import Client, city_copy, disk_uris
from tests.support.servers import spawned, threaded
from tests.support.soak import soak


def test_tileset_names() -> None:
    assert tileset_name(Path("/x/build/tiles/demo")) == "demo"
    assert tileset_name(Path("/x/my tiles (2)")) == "my-tiles--2-"
    assert check_name("li_6x.v2") == "li_6x.v2"
    for bad in ("", "a/b", "x" * 101, "naïve"):
        with pytest.raises(ValueError, match="tileset name"):
            check_name(bad)


@pytest.fixture(scope="module")
def fixtures_city(city) -> City:
    return city("fixtures")


@pytest.fixture(scope="module")
def copy_url(fixtures_city: City, server_url: str) -> Iterator[str]:
    """A copy of the fixtures city (made before any server of this module connects to the city)."""
    with city_copy(fixtures_city, server_url, "publish") as url:
        yield url


@pytest.fixture(scope="module")
def soak_url(fixtures_city: City, server_url: str, copy_url: str) -> Iterator[str]:
    with city_copy(fixtures_city, server_url, "soak") as url:
        yield url


def listing(url: str, name: str) -> tuple[int, dict[str, str]]:
    with psycopg.connect(url) as conn:
        (gen,) = conn.execute("SELECT max(generation) FROM pub.generation WHERE tileset = %s", (name,)).fetchone()
        files = {
            p: bytes(s).hex()
            for p, s in conn.execute("SELECT path, sha256 FROM pub.file WHERE generation = %s", (gen,))
        }
    return gen, files


def on_disk(d: Path) -> dict[str, str]:
    return {
        p.relative_to(d).as_posix(): hashlib.sha256(p.read_bytes()).hexdigest() for p in d.rglob("*") if p.is_file()
    }


@contextmanager
def published(url: str, name: str, **options) -> Iterator[tuple[PublishedSource, str]]:
    source = PublishedSource(reader_url(url, environ={}), name, **options)
    try:
        with threaded(make_app(source=source)) as base:
            yield source, base
    finally:
        source.close()


@pytest.mark.db
def test_the_export_is_published_and_streamed_byte_for_byte(fixtures_city: City) -> None:
    name = fixtures_city.tiles.name
    gen, files = listing(fixtures_city.url, name)
    assert files == on_disk(fixtures_city.tiles), "the generation holds exactly the exported files"
    with psycopg.connect(fixtures_city.url) as conn:
        stage, options = conn.execute(
            "SELECT r.stage, g.options FROM pub.generation g JOIN meta.pipeline_run r USING (run_id) "
            "WHERE g.generation = %s",
            (gen,),
        ).fetchone()
    assert stage == "export" and options["lod"] is None and options["geometry"] == "compact"
    with published(fixtures_city.url, name) as (source, base):
        c = Client(base)
        try:
            uris = [
                "tileset.json",
                *tileset_files(
                    json.loads((fixtures_city.tiles / "tileset.json").read_bytes()),
                    lambda u: (fixtures_city.tiles / u).read_bytes(),
                ),
            ]
            assert sorted(uris) == sorted(files)
            for uri in uris:
                status, headers, body = c.get(f"/tiles/{uri}")
                assert status == 200, (uri, body[:200])
                assert body == (fixtures_city.tiles / uri).read_bytes(), uri
                assert headers["etag"] == f'"{files[uri][:32]}"'
                assert headers["content-type"] == (
                    "application/json"
                    if uri.endswith(".json")
                    else "model/gltf-binary"
                    if uri.endswith(".glb")
                    else "application/octet-stream"
                )
                assert c.get(f"/tiles/{uri}", If_None_Match=headers["etag"])[0] == 304
            assert source.stats()["reads"] == len(uris), "each file read from the database once"
            assert c.get("/tiles/content/9/0/0.glb")[0] == 404  # a tile this tileset does not have
            assert c.get("/tiles/content/x/0/0.glb")[0] == 400
        finally:
            c.close()
    with published(fixtures_city.url, "never-exported") as (_, base):
        c = Client(base)
        try:
            status, headers, body = c.get("/tiles/tileset.json")
            assert status == 503 and b"no tileset named 'never-exported' is published" in body
            assert headers["retry-after"]
        finally:
            c.close()


@pytest.mark.db
def test_a_new_generation_stores_and_serves_only_what_changed(copy_url: str, tmp_path: Path) -> None:
    out = tmp_path / "t"
    small = {"CITYLOD_TILE_MAX_FEATURES": "4"}  # many tiles from the few fixtures
    for stage in ("tiles", "generalize"):
        run_etl(copy_url, stage, env=small)
    run_etl(copy_url, "export", "--out", str(out), env=small)
    g1, files1 = listing(copy_url, "t")
    with published(copy_url, "t", revalidate_s=0.0) as (source, base):
        c = Client(base)
        try:
            etags = {u: c.get(f"/tiles/{u}")[1]["etag"] for u in files1}
            run_etl(copy_url, "export", "--out", str(out), env=small)  # nothing changed: nothing new stored
            g2, files2 = listing(copy_url, "t")
            with psycopg.connect(copy_url) as conn:
                assert conn.execute(
                    "SELECT n_files, n_new_files FROM pub.generation WHERE generation = %s", (g2,)
                ).fetchone() == (len(files1), 0)
            assert g2 > g1 and files2 == files1
            reads = source.stats()["reads"]
            assert {u: c.get(f"/tiles/{u}")[1]["etag"] for u in files1} == etags
            assert source.stats()["reads"] == reads, "the same bytes: served from the cache"

            with psycopg.connect(copy_url) as conn:  # one building renamed: only the tiles it is drawn in change
                (bid,) = conn.execute(
                    "SELECT id FROM osm.building WHERE kind = 'building' AND n_parts = 0 ORDER BY id LIMIT 1"
                ).fetchone()
                conn.execute("UPDATE osm.building SET name = 'renamed once' WHERE id = %s", (bid,))
            run_etl(copy_url, "export", "--out", str(out), env=small)
            g3, files3 = listing(copy_url, "t")
            assert files3 == on_disk(out)
            changed = {u for u in files3 if files3[u] != files1.get(u)}
            assert changed and len(changed) < len([u for u in files3 if u.endswith(".glb")])
            with psycopg.connect(copy_url) as conn:
                assert conn.execute(
                    "SELECT n_new_files FROM pub.generation WHERE generation = %s", (g3,)
                ).fetchone() == (len(set(files3[u] for u in changed)),)
                # publish_keep = 2: the first generation is gone; its blobs were all named by the second
                assert [
                    g for (g,) in conn.execute("SELECT generation FROM pub.generation WHERE tileset = 't' ORDER BY 1")
                ] == [g2, g3]
                assert conn.execute(
                    "SELECT count(*) FROM pub.blob b WHERE NOT EXISTS "
                    "(SELECT 1 FROM pub.file f WHERE f.sha256 = b.sha256)"
                ).fetchone() == (0,)
            for u in files3:
                status, headers, body = c.get(f"/tiles/{u}")
                assert status == 200 and body == (out / u).read_bytes(), u
                assert (headers["etag"] == etags[u]) == (u not in changed), u
            assert any(b"renamed once" in (out / u).read_bytes() for u in changed)

            # g4 replaces g2: g2's blobs of the changed tiles go
            run_etl(copy_url, "export", "--out", str(out), env=small)
            with psycopg.connect(copy_url) as conn:
                gone = [files2[u] for u in changed]
                assert conn.execute(
                    "SELECT count(*) FROM pub.blob WHERE encode(sha256, 'hex') = ANY(%s)", (gone,)
                ).fetchone() == (0,)
        finally:
            c.close()


@pytest.mark.db
def test_soak_during_a_full_rebuild_and_an_update(soak_url: str, fixtures_city: City, tmp_path: Path) -> None:
    """`serve --db` (its own process, as a user runs it) under 200 requests per second while every stage runs
    again and the export publishes a new generation, then while an update applies a change file and publishes
    again: no 5xx, no transport error, no body that is not its ETag, no server connection ever waiting on a
    lock; then the last generation is served."""
    dbname = psycopg.conninfo.conninfo_to_dict(soak_url)["dbname"]
    name = fixtures_city.tiles.name
    env = {**os.environ, "DATABASE_URL": soak_url}
    env.pop("CITYLOD_READER_URL", None)
    waits: list[tuple[str, str]] = []
    stop = threading.Event()
    with spawned(["etl", "serve", "--db", "--tileset", name, "--port", "0"], env, timeout=60) as (base, _, err):

        def watch() -> None:
            with psycopg.connect(soak_url, autocommit=True) as admin:
                while not stop.is_set():
                    waits.extend(
                        admin.execute(
                            "SELECT wait_event, query FROM pg_stat_activity WHERE usename = %s AND datname = %s "
                            "AND wait_event_type = 'Lock'",
                            (READER_ROLE, dbname),
                        ).fetchall()
                    )
                    time.sleep(0.01)

        result: dict = {}

        def client() -> None:
            result["soak"] = soak(base, stop)

        threads = [threading.Thread(target=watch), threading.Thread(target=client)]
        for t in threads:
            t.start()
        try:
            time.sleep(1.0)
            # a full rebuild from an edited file: one building named, so that the tiles drawing it change
            osm = tmp_path / "edited.osm"
            text = fixtures_city.osm.read_text()
            assert '"Square 100"' in text
            osm.write_text(text.replace('"Square 100"', '"rebuilt under load"'))
            out = tmp_path / name
            run_etl(soak_url, "ingest", "--osm", str(osm))
            for stage in ("lod", "landmarks", "tiles", "generalize", "textures"):
                run_etl(soak_url, stage)
            run_etl(soak_url, "export", "--out", str(out))
            time.sleep(2.0)
            # then an update: the square's corner moves (tests/db/test_update.py writes the same node)
            osc = tmp_path / "move.osc"
            osc.write_text(
                '<?xml version="1.0"?><osmChange version="0.6"><modify><node id="100003" version="2" '
                'lat="60.2001795" lon="24.9004157"/></modify></osmChange>'
            )
            run_etl(soak_url, "update", "--osc", str(osc), "--out", str(out))
            time.sleep(2.0)
        finally:
            stop.set()
            for t in threads:
                t.join(120)
        r = result["soak"]
        figures = r.as_dict()
        print("soak during a full rebuild and an update:", figures)
        err.seek(0)
        assert r.failures == 0, (figures, err.read()[-2000:])
        assert r.bad_etags == 0 and waits == []
        assert r.requests > 1000 and set(r.statuses) <= {200, 304}
    # the server now streams the last generation: the rebuilt tiles, the edited building among them
    with published(soak_url, name) as (_, base):
        c = Client(base)
        try:
            new = [u for u in disk_uris(out) if b"rebuilt under load" in (out / u).read_bytes()]
            assert new
            for u in ["tileset.json", *new]:
                assert c.get(f"/tiles/{u}")[2] == (out / u).read_bytes(), u
        finally:
            c.close()
