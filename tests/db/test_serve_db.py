"""`python -m etl serve --db --live`: tileset.json and every glb built on request from the database, byte for byte the
file export, cached with strong ETags and gzip, CORS, bad addresses 400/404, a lost database 503 (never a 500),
and the server's connection belongs to the read-only role of migration 0011.

The pure parts (address parsing, content negotiation, the LRU) are tested without a database at the top.
"""

from __future__ import annotations

import gzip
import hashlib
import http.client
import json
import os
import subprocess
import sys
import threading
import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any
from urllib.parse import urlsplit

import psycopg
import pytest
from psycopg import sql

from core.settings import Settings
from core.tiles3d import content_uris, tileset_files
from etl.migrate import migrate_and_reload
from exporter.serve.app import make_app
from exporter.serve.cache import ByteLru
from exporter.serve.paths import BadPath, tile_address
from exporter.serve.payload import Payload, accepts_gzip, etag_matches, make_payload
from exporter.serve.reader import READER_ROLE, reader_url
from exporter.serve.source import DbTileSource
from tests.conftest import PREFIX, REPO, City, _with_db, run_etl
from tests.support.servers import spawned, threaded

BASE_HEIGHT = Settings.from_env().base_height_m

# --- pure ---------------------------------------------------------------------------------------------------

BAD_ADDRESSES = [  # (what follows /tiles/ once percent-decoded, expected status)
    ("content/x/1/2.glb", 400),
    ("content/-1/0/0.glb", 400),
    ("content/0/-1/0.glb", 400),
    ("content/0/0/-1.glb", 400),
    ("content/1.5/0/0.glb", 400),
    ("content/01/0/0.glb", 400),  # not canonical: one URL per tile
    ("content/99999999999999999999999/0/0.glb", 400),  # more digits than any tile address has
    ("content/0/0/0.glb/extra", 400),
    ("content/0/0/0.glb.bak", 400),
    ("content/0/0/0", 400),
    ("content/0/0", 400),
    ("content/", 400),
    ("content/../tileset.json", 400),
    ("../../etc/passwd", 400),
    ("content/0/0/0.glb\x00", 400),
    ("content\\0\\0\\0.glb", 400),
    ("content/31/0/0.glb", 404),  # deeper than any quadtree
    ("content/2/4/0.glb", 404),  # x beyond level 2's 4 columns
    ("content/2/0/4.glb", 404),
    ("content/1/2/0.glb", 404),
    ("subtrees/01/0/0.subtree", 400),  # subtree files (implicit tiling): the same rules
    ("subtrees/0/0/0.glb", 400),
    ("subtrees/2/4/0.subtree", 404),
    ("", 404),
    ("nope.json", 404),
    ("tileset.json.gz", 404),
]


def disk_uris(files) -> list[str]:
    """The content of the exported tileset in ``files`` (implicit: listed in its subtree files)."""
    return content_uris(json.loads((files / "tileset.json").read_bytes()), lambda u: (files / u).read_bytes())


@pytest.mark.parametrize(("rel", "status"), BAD_ADDRESSES)
def test_tile_address_rejects(rel: str, status: int) -> None:
    if status == 400:
        with pytest.raises(BadPath):
            tile_address(rel)
    else:
        assert tile_address(rel) is None


def test_tile_address_accepts() -> None:
    assert tile_address("tileset.json") == "tileset.json"
    assert tile_address("content/0/0/0.glb") == "content/0/0/0.glb"
    assert tile_address("content/16/65535/12.glb") == "content/16/65535/12.glb"


def test_accept_encoding_and_if_none_match() -> None:
    assert accepts_gzip("gzip, deflate, br")
    assert accepts_gzip("br;q=1.0, gzip;q=0.8")
    assert accepts_gzip("*")
    assert accepts_gzip("GZIP")
    assert not accepts_gzip(None) and not accepts_gzip("") and not accepts_gzip("identity")
    assert not accepts_gzip("gzip;q=0") and not accepts_gzip("*;q=0") and not accepts_gzip("br, *;q=0")
    assert not accepts_gzip("gzip;q=0, *")  # an explicit refusal wins over the wildcard
    assert etag_matches('"a"', '"a"') and etag_matches('W/"a"', '"a"') and etag_matches('"b", "a"', '"a"')
    assert etag_matches("*", '"a"')
    assert not etag_matches('"b"', '"a"') and not etag_matches(None, '"a"') and not etag_matches('"a-gzip"', '"a"')


def test_payload_keeps_gzip_only_when_it_pays() -> None:
    raw = b'{"a": 1}' * 1000
    text = make_payload(raw, "application/json")
    assert text.gzip is not None and gzip.decompress(text.gzip) == raw and text.body == raw
    assert text.size < len(raw) // 10  # only the compressed variant is kept in the cache
    assert text.etag == f'"{hashlib.sha256(text.body).hexdigest()[:32]}"' and text.gzip_etag != text.etag
    noise = make_payload(os.urandom(4096), "model/gltf-binary")
    assert noise.gzip is None and len(noise.body) == 4096 and noise.size >= 4096


def test_lru_byte_budget_and_single_flight() -> None:
    def payload(n: int) -> Payload:
        return Payload(b"x" * n, False, '"e"', "application/octet-stream")

    lru = ByteLru(budget=3 * payload(1000).size)
    for k in "abc":
        lru.get_or_build(k, lambda: payload(1000))
    lru.get_or_build("a", lambda: pytest.fail("a is cached"))  # a becomes the most recent
    lru.get_or_build("d", lambda: payload(1000))  # evicts b, the least recently used
    assert lru.stats()["entries"] == 3 and lru.stats()["evictions"] == 1
    built: list[str] = []
    lru.get_or_build("b", lambda: built.append("b") or payload(1000))
    assert built == ["b"]
    assert lru.stats()["bytes"] <= lru.budget
    lru.get_or_build("huge", lambda: payload(10_000))  # over the whole budget: served, not kept
    assert lru.stats()["bytes"] <= lru.budget

    # 16 threads miss the same key at once: one build, one shared result
    gate = threading.Event()
    calls: list[int] = []

    def slow() -> Payload:
        calls.append(1)
        gate.wait(5)
        return payload(10)

    results: list[Payload] = []
    threads = [threading.Thread(target=lambda: results.append(lru.get_or_build("same", slow))) for _ in range(16)]
    for t in threads:
        t.start()
    time.sleep(0.2)
    gate.set()
    for t in threads:
        t.join(5)
    assert len(calls) == 1 and len(results) == 16 and len({id(r) for r in results}) == 1

    def boom() -> Payload:
        raise RuntimeError("db down")

    with pytest.raises(RuntimeError):
        lru.get_or_build("err", boom)
    assert lru.get_or_build("err", lambda: payload(1)).body == b"x"  # a failure is not cached


def test_reader_url() -> None:
    url = "postgresql://citylod:secret@db.example:5433/city?sslmode=require"
    derived = psycopg.conninfo.conninfo_to_dict(reader_url(url, environ={}))
    assert derived["user"] == READER_ROLE and "password" not in derived
    assert (derived["host"], derived["port"], derived["dbname"], derived["sslmode"]) == (
        "db.example",
        "5433",
        "city",
        "require",
    )
    sock = "postgresql://citylod@/citylod?host=/work/var/pg/sock&port=55432"  # the local cluster's form
    assert psycopg.conninfo.conninfo_to_dict(reader_url(sock, environ={}))["host"] == "/work/var/pg/sock"
    assert reader_url(url, environ={"CITYLOD_READER_URL": "postgresql://r@h/d"}) == "postgresql://r@h/d"


# --- against the database ------------------------------------------------------------------------------------


@contextmanager
def running(url: str, **options: Any) -> Iterator[tuple[DbTileSource, str]]:
    """An in-process DB-mode server on a free port, serving on a thread; yields (its tile source, base URL)."""
    options.setdefault("base_height", BASE_HEIGHT)
    source = DbTileSource(url, **options)
    try:
        with threaded(make_app(source=source)) as base:
            yield source, base
    finally:
        source.close()


class Client:
    """One keep-alive HTTP/1.1 connection; paths are sent verbatim (no client-side normalisation)."""

    def __init__(self, base: str) -> None:
        u = urlsplit(base)
        self.host, self.port = u.hostname, u.port
        self.conn = http.client.HTTPConnection(self.host, self.port, timeout=60)

    def get(self, path: str, method: str = "GET", **headers: str) -> tuple[int, dict[str, str], bytes]:
        hdrs = {k.replace("_", "-"): v for k, v in headers.items()}
        for attempt in (1, 2):
            try:
                self.conn.request(method, path, headers=hdrs)
                r = self.conn.getresponse()
                body = r.read()
                if r.getheader("Connection", "").lower() == "close":
                    self.conn.close()
                return r.status, {k.lower(): v for k, v in r.getheaders()}, body
            except (http.client.RemoteDisconnected, ConnectionResetError, BrokenPipeError):
                self.conn.close()  # the server closed the keep-alive connection (after an error page): reconnect
                if attempt == 2:
                    raise
        raise AssertionError("unreachable")

    def close(self) -> None:
        self.conn.close()


@pytest.fixture(scope="module")
def fixtures_city(city: Callable[[str], City]) -> City:
    return city("fixtures")


@contextmanager
def city_copy(city: City, server_url: str, suffix: str) -> Iterator[str]:
    """A copy of ``city``'s database (dropped after), for a test that drops or changes it. Made before any server
    of this module connects to the city's database (CREATE DATABASE ... TEMPLATE needs the source to be idle)."""
    name = f"{PREFIX}_serve_{suffix}"
    src = psycopg.conninfo.conninfo_to_dict(city.url)["dbname"]
    with psycopg.connect(server_url, autocommit=True) as admin:
        admin.execute(sql.SQL("DROP DATABASE IF EXISTS {} WITH (FORCE)").format(sql.Identifier(name)))
        deadline = time.monotonic() + 30
        while True:
            try:
                admin.execute(
                    sql.SQL("CREATE DATABASE {} TEMPLATE {}").format(sql.Identifier(name), sql.Identifier(src))
                )
                break
            except psycopg.errors.ObjectInUse:  # some session is still on the source: wait for it to leave
                if time.monotonic() > deadline:
                    raise
                time.sleep(0.5)
    try:
        yield _with_db(server_url, name)
    finally:
        with psycopg.connect(server_url, autocommit=True) as admin:
            admin.execute(sql.SQL("DROP DATABASE IF EXISTS {} WITH (FORCE)").format(sql.Identifier(name)))


@pytest.fixture(scope="module")
def outage_url(fixtures_city: City, server_url: str) -> Iterator[str]:
    """A copy of the fixtures city for the outage test to drop."""
    with city_copy(fixtures_city, server_url, "outage") as url:
        yield url


@pytest.fixture(scope="module")
def rerun_url(fixtures_city: City, server_url: str) -> Iterator[str]:
    """A copy of the fixtures city for the re-run test to change."""
    with city_copy(fixtures_city, server_url, "rerun") as url:
        yield url


@pytest.fixture(scope="module")
def db_server(fixtures_city: City, outage_url: str, rerun_url: str) -> Iterator[tuple[DbTileSource, str]]:
    """The DB-mode server on the fixtures city, as the reader role (the copies first: see city_copy)."""
    with running(reader_url(fixtures_city.url, environ={})) as s:
        yield s


@pytest.mark.db
def test_every_tile_byte_for_byte_the_file_export(db_server: tuple[DbTileSource, str], fixtures_city: City) -> None:
    server, base = db_server
    files = fixtures_city.tiles
    c = Client(base)
    try:
        status, headers, body = c.get("/tiles/tileset.json")
        assert status == 200, body
        assert headers["content-type"] == "application/json"
        assert headers["access-control-allow-origin"] == "*"
        assert "content-encoding" not in headers  # the client did not ask for gzip
        assert body == (files / "tileset.json").read_bytes()
        # implicit: the content is listed in the subtree files
        uris = tileset_files(json.loads(body), lambda u: (files / u).read_bytes())
        on_disk = sorted(
            p.relative_to(files).as_posix() for p in files.rglob("*") if p.is_file() and p.name != "tileset.json"
        )
        assert uris == on_disk and uris, "the tileset lists exactly the exported glb and subtree files"
        assert any(u.endswith(".subtree") for u in uris) and any(u.endswith(".glb") for u in uris)
        for uri in uris:
            status, headers, body = c.get(f"/tiles/{uri}")
            assert status == 200, (uri, body[:200])
            assert headers["content-type"] == (
                "model/gltf-binary" if uri.endswith(".glb") else "application/octet-stream"
            ), uri
            assert headers["access-control-allow-origin"] == "*", uri
            assert int(headers["content-length"]) == len(body)
            assert body == (files / uri).read_bytes(), f"{uri} differs from the file export"
        # the viewer and CesiumJS are served in DB mode too, exactly as in file mode
        for path, media in (
            ("/", "text/html"),
            ("/viewer/viewer.js", "text/javascript"),
            ("/cesium/Cesium.js", "text/javascript"),
        ):
            status, headers, _ = c.get(path)
            assert (status, headers["content-type"].split(";")[0]) == (200, media), path
        assert c.get("/tiles/tileset.json", "OPTIONS")[0] == 204
    finally:
        c.close()


@pytest.mark.db
def test_etag_304_and_cache(db_server: tuple[DbTileSource, str], fixtures_city: City) -> None:
    server, base = db_server
    uri = disk_uris(fixtures_city.tiles)[-1]
    c = Client(base)
    try:
        for path in ("/tiles/tileset.json", f"/tiles/{uri}"):
            status, headers, body = c.get(path)
            assert status == 200
            etag = headers["etag"]
            assert etag == f'"{hashlib.sha256(body).hexdigest()[:32]}"', "strong, from the bytes"
            assert headers["cache-control"] == "no-cache" and "Accept-Encoding" in headers["vary"]

            before = server.stats()
            status, headers, body = c.get(path, If_None_Match=etag)
            assert (status, body) == (304, b"")
            assert headers["etag"] == etag and headers["access-control-allow-origin"] == "*"
            after = server.stats()
            assert after["builds"] == before["builds"], "a revalidation does not rebuild the tile"

            assert c.get(path, If_None_Match='"0000", ' + etag)[0] == 304
            assert c.get(path, If_None_Match=f"W/{etag}")[0] == 304  # If-None-Match compares weakly
            assert c.get(path, If_None_Match='"stale"')[0] == 200
            status, headers, body = c.get(path, "HEAD")
            assert status == 200 and body == b"" and headers["etag"] == etag and int(headers["content-length"]) > 0

        builds = server.stats()["builds"]
        hits = server.stats()["hits"]
        assert c.get(f"/tiles/{uri}")[0] == 200
        assert server.stats()["builds"] == builds and server.stats()["hits"] == hits + 1
    finally:
        c.close()


@pytest.mark.db
def test_gzip_negotiated(db_server: tuple[DbTileSource, str], fixtures_city: City) -> None:
    _, base = db_server
    files = fixtures_city.tiles
    c = Client(base)
    try:
        status, plain_headers, _ = c.get("/tiles/tileset.json")
        status, headers, body = c.get("/tiles/tileset.json", Accept_Encoding="gzip, deflate, br")
        assert status == 200 and headers["content-encoding"] == "gzip" and "Accept-Encoding" in headers["vary"]
        assert headers["content-type"] == "application/json" and headers["access-control-allow-origin"] == "*"
        assert int(headers["content-length"]) == len(body)
        assert gzip.decompress(body) == (files / "tileset.json").read_bytes()
        assert len(body) <= 0.9 * len(gzip.decompress(body))  # the policy: kept only when it saves 10 %
        assert headers["etag"] != plain_headers["etag"], "each representation has its own strong ETag"
        assert c.get("/tiles/tileset.json", Accept_Encoding="gzip", If_None_Match=headers["etag"])[0] == 304
        # the identity ETag does not validate the gzip representation (nor the other way round)
        assert c.get("/tiles/tileset.json", Accept_Encoding="gzip", If_None_Match=plain_headers["etag"])[0] == 200
        assert c.get("/tiles/tileset.json", If_None_Match=headers["etag"])[0] == 200
        for refuse in ("identity", "gzip;q=0", "br"):
            assert "content-encoding" not in c.get("/tiles/tileset.json", Accept_Encoding=refuse)[1], refuse

        # glb: gzip only when it saves at least 10 %; whatever is sent decodes to the exported bytes
        for uri in disk_uris(files):
            status, headers, body = c.get(f"/tiles/{uri}", Accept_Encoding="gzip")
            raw = (files / uri).read_bytes()
            if headers.get("content-encoding") == "gzip":
                assert gzip.decompress(body) == raw and len(body) <= 0.9 * len(raw)
            else:
                assert body == raw and len(gzip.compress(raw, 6)) > 0.9 * len(raw)
    finally:
        c.close()


@pytest.mark.db
@pytest.mark.parametrize(
    ("rel", "status"),
    BAD_ADDRESSES
    + [
        ("content/30/1073741823/1073741823.glb", 404),  # in range, no such tile
        ("content/16/0/0.glb", 404),
        ("subtrees/5/0/0.subtree", 404),  # no subtree starts at level 5 here
        ("content/0/0/0.glb%00", 400),
        ("%2e%2e/%2e%2e/etc/passwd", 400),
        ("content/%2e%2e/tileset.json", 400),
        ("content/%ff/0/0.glb", 400),  # not UTF-8
        ("content/0/0/0.glb%2fextra", 400),
    ],
)
def test_bad_addresses_are_400_or_404(db_server: tuple[DbTileSource, str], rel: str, status: int) -> None:
    _, base = db_server
    path = "/tiles/" + rel.replace("\x00", "%00").replace("\\", "%5C")
    c = Client(base)
    try:
        got, headers, body = c.get(path)
        assert got == status, (path, got, body[:300])
        assert headers["access-control-allow-origin"] == "*"
        assert b"Traceback" not in body and b"root:" not in body
        assert c.get(path, "HEAD")[0] == status
    finally:
        c.close()


@pytest.mark.db
def test_concurrent_clients_cold_cache(fixtures_city: City, db_server: tuple[DbTileSource, str]) -> None:
    """32 threads fetch every tile at once from a fresh server: every answer is right, each tile is built once,
    and the server never holds more connections than its pool."""
    files = fixtures_city.tiles
    uris = ["tileset.json"] + tileset_files(
        json.loads((files / "tileset.json").read_bytes()), lambda u: (files / u).read_bytes()
    )
    expected = {u: (files / u).read_bytes() for u in uris}
    dbname = psycopg.conninfo.conninfo_to_dict(fixtures_city.url)["dbname"]
    with running(reader_url(fixtures_city.url, environ={}), pool_size=3) as (server, base):
        errors: list[str] = []
        peak = [0]

        def worker(i: int) -> None:
            c = Client(base)
            try:
                for u in uris[i % len(uris) :] + uris[: i % len(uris)]:
                    status, _, body = c.get(f"/tiles/{u}")
                    if status != 200 or body != expected[u]:
                        errors.append(f"{u}: {status}")
            except Exception as e:  # noqa: BLE001 - reported below
                errors.append(repr(e))
            finally:
                c.close()

        stop = threading.Event()

        def watch() -> None:
            with psycopg.connect(fixtures_city.url, autocommit=True) as admin:
                while not stop.is_set():
                    n = admin.execute(
                        "SELECT count(*) FROM pg_stat_activity WHERE usename = %s AND datname = %s",
                        (READER_ROLE, dbname),
                    ).fetchone()[0]
                    peak[0] = max(peak[0], n)
                    time.sleep(0.005)

        watcher = threading.Thread(target=watch)
        watcher.start()
        threads = [threading.Thread(target=worker, args=(i,)) for i in range(32)]
        for t in threads:
            t.start()
        for t in threads:
            t.join(120)
        stop.set()
        watcher.join(10)
        assert errors == []
        glbs = [u for u in uris if u.endswith(".glb")]
        assert server.stats()["builds"] == len(glbs), "single flight: each glb built exactly once"
        # the module's other server holds its own pool on the same database
        assert peak[0] <= 3 + db_server[0].reader.pool.max_size


@pytest.mark.db
def test_server_connection_cannot_write(db_server: tuple[DbTileSource, str], fixtures_city: City) -> None:
    server, _ = db_server
    with server.reader.connection() as conn:
        assert conn.execute("SELECT current_user").fetchone()[0] == READER_ROLE
        assert conn.execute("SHOW default_transaction_read_only").fetchone()[0] == "on"
        with pytest.raises(psycopg.errors.ReadOnlySqlTransaction), conn.transaction():
            conn.execute("INSERT INTO meta.diagnostic (stage, osm_type, osm_id, code) VALUES ('x', 'W', 1, 'x')")
        # even a transaction that asks to be read-write: the role has no write privilege anywhere
        conn.read_only = False
        try:
            for statement in (
                "INSERT INTO meta.diagnostic (stage, osm_type, osm_id, code) VALUES ('x', 'W', 1, 'x')",
                "UPDATE osm.building SET id = id",
                "DELETE FROM tiles.tile",
                "TRUNCATE lod.building_mesh",
                "CREATE TABLE api.x (a int)",
                "SELECT lo_from_bytea(0, '\\x00'::bytea)",  # large objects too (0026)
                "SELECT lo_create(0)",
                "DELETE FROM pub.generation",  # the published tilesets (0027)
                "INSERT INTO pub.blob VALUES (sha256('x'), 'x')",
            ):
                with pytest.raises(psycopg.errors.InsufficientPrivilege), conn.transaction():
                    conn.execute("SET TRANSACTION READ WRITE")
                    conn.execute(statement)  # type: ignore[call-overload]
        finally:
            conn.read_only = True
    with psycopg.connect(fixtures_city.url) as admin:
        row = admin.execute(
            "SELECT rolcanlogin, rolinherit, rolsuper, rolcreaterole, rolcreatedb FROM pg_roles WHERE rolname = %s",
            (READER_ROLE,),
        ).fetchone()
        assert row == (True, False, False, False, False)
        unreadable = admin.execute(
            "SELECT schemaname || '.' || tablename FROM pg_tables WHERE schemaname = ANY(%s)"
            " AND NOT has_table_privilege(%s, quote_ident(schemaname) || '.' || quote_ident(tablename), 'SELECT')",
            (["meta", "osm", "lod", "gen", "tiles", "api", "pub"], READER_ROLE),
        ).fetchall()
        assert unreadable == []


@pytest.mark.db
def test_reader_migration_in_a_second_database(server_url: str) -> None:
    """0011 in another database of a cluster where the role already exists (the session template made it):
    no error; and tables created after it are readable through the default privileges."""
    name = f"{PREFIX}_serve_reader2"
    with psycopg.connect(server_url, autocommit=True) as admin:
        admin.execute(sql.SQL("DROP DATABASE IF EXISTS {} WITH (FORCE)").format(sql.Identifier(name)))
        admin.execute(sql.SQL("CREATE DATABASE {}").format(sql.Identifier(name)))
        assert admin.execute("SELECT 1 FROM pg_roles WHERE rolname = %s", (READER_ROLE,)).fetchone()
    url = _with_db(server_url, name)
    try:
        with psycopg.connect(url) as conn:
            assert "0011_reader_role.sql" in migrate_and_reload(conn, quiet=True)[0]
            conn.execute("CREATE TABLE gen.later_table (a int)")
            conn.execute("INSERT INTO gen.later_table VALUES (42)")
            conn.commit()
        with psycopg.connect(reader_url(url, environ={})) as reader:
            assert reader.execute("SELECT a FROM gen.later_table").fetchone() == (42,)
            assert reader.execute("SELECT count(*) FROM meta.schema_migrations").fetchone()[0] >= 11
    finally:
        with psycopg.connect(server_url, autocommit=True) as admin:
            admin.execute(sql.SQL("DROP DATABASE IF EXISTS {} WITH (FORCE)").format(sql.Identifier(name)))


@pytest.mark.db
def test_a_pipeline_rerun_drops_the_cache(rerun_url: str, tmp_path: Path) -> None:
    """Cached tiles are served until a pipeline run lands (the generation changes); then they are built again
    from the database as it is now."""
    with running(reader_url(rerun_url, environ={}), revalidate_s=0.0) as (server, base):
        c = Client(base)
        try:
            status, _, js = c.get("/tiles/tileset.json")
            assert status == 200
            uri = max(
                content_uris(json.loads(js), lambda u: c.get(f"/tiles/{u}")[2]), key=lambda u: int(u.split("/")[1])
            )  # a leaf: named buildings
            status, _, before = c.get(f"/tiles/{uri}")
            assert status == 200 and b"renamed by a re-run" not in before
            builds = server.stats()["builds"]
            with psycopg.connect(rerun_url) as admin:
                admin.execute("UPDATE osm.building SET name = 'renamed by a re-run'")
            # no run recorded yet: the cached bytes, not the database's
            assert c.get(f"/tiles/{uri}")[2] == before and server.stats()["builds"] == builds

            run_etl(rerun_url, "export", "--out", str(tmp_path / "tiles"))  # a real run: a new generation
            status, _, after = c.get(f"/tiles/{uri}")
            assert status == 200 and b"renamed by a re-run" in after
            assert after == (tmp_path / "tiles" / uri).read_bytes(), "the rebuilt tile is the new export's"
            assert server.stats()["builds"] == builds + 1
        finally:
            c.close()


@pytest.mark.db
def test_connections_killed_under_the_server_are_replaced(fixtures_city: City, server_url: str) -> None:
    """A restart or a terminated backend kills the pooled connections: the next request is still answered, on a
    fresh connection, not a 503."""
    dbname = psycopg.conninfo.conninfo_to_dict(fixtures_city.url)["dbname"]
    with running(reader_url(fixtures_city.url, environ={}), revalidate_s=0.0) as (server, base):
        c = Client(base)
        try:
            for _ in range(3):
                assert c.get("/tiles/tileset.json")[0] == 200
                with psycopg.connect(server_url, autocommit=True) as admin:
                    killed = admin.execute(
                        "SELECT count(pg_terminate_backend(pid)) FROM pg_stat_activity"
                        " WHERE usename = %s AND datname = %s",
                        (READER_ROLE, dbname),
                    ).fetchone()[0]
                assert killed >= 1
                status, _, body = c.get("/tiles/tileset.json")
                assert status == 200, body[:300]
        finally:
            c.close()


@pytest.mark.db
def test_database_outage_is_503(outage_url: str, fixtures_city: City, server_url: str) -> None:
    files = fixtures_city.tiles
    uris = disk_uris(files)
    # revalidate on every request: with the default (1 s) a cached answer may be served for up to a second
    with running(reader_url(outage_url, environ={}), revalidate_s=0.0) as (server, base):
        c = Client(base)
        try:
            assert c.get("/tiles/tileset.json")[2] == (files / "tileset.json").read_bytes()
            assert c.get(f"/tiles/{uris[0]}")[0] == 200
            with psycopg.connect(server_url, autocommit=True) as admin:
                admin.execute(
                    sql.SQL("DROP DATABASE {} WITH (FORCE)").format(
                        sql.Identifier(psycopg.conninfo.conninfo_to_dict(outage_url)["dbname"])
                    )
                )
            for path in ("/tiles/tileset.json", f"/tiles/{uris[0]}", f"/tiles/{uris[-1]}"):
                for _ in range(2):  # the dead pooled connection, then a failed reconnect
                    status, headers, body = c.get(path)
                    assert status == 503, (path, status, body[:300])
                    assert headers["access-control-allow-origin"] == "*" and headers["retry-after"]
                    assert headers["content-type"].startswith("text/plain")
                    assert body.strip() == b"database unavailable, retry later"
            assert c.get("/tiles/content/x/0/0.glb")[0] == 400  # bad input is still bad input
            assert c.get("/")[0] == 200  # the viewer is still served
        finally:
            c.close()

    # unreachable from the start: the CLI refuses to start, with a hint, and no traceback
    env = {**os.environ, "DATABASE_URL": outage_url}
    env.pop("CITYLOD_READER_URL", None)
    r = subprocess.run(
        [sys.executable, "-m", "etl", "serve", "--db", "--port", "0"],
        cwd=REPO,
        env=env,
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert r.returncode != 0 and r.stdout == ""
    assert "cannot read the database" in r.stderr and "make migrate" in r.stderr
    assert "Traceback" not in r.stderr


@pytest.mark.db
def test_a_stage_lock_is_answered_503_not_waited_for(fixtures_city: City) -> None:
    """--live reads the stage tables; a stage that holds them (a full ingest's or lod's TRUNCATE: until it
    commits) makes a request give up after the reader's lock_timeout and say so, instead of hanging until the
    statement timeout (30 s), which would answer a different 503."""
    with running(reader_url(fixtures_city.url, environ={}), revalidate_s=0.0) as (_, base):
        c = Client(base)
        try:
            assert c.get("/tiles/tileset.json")[0] == 200
            uri = disk_uris(fixtures_city.tiles)[0]  # not built yet by this server: read from the tables
            with psycopg.connect(fixtures_city.url) as holder:  # rolled back: nothing changes
                holder.execute("LOCK TABLE tiles.tile, lod.building_mesh IN ACCESS EXCLUSIVE MODE")
                status, headers, body = c.get(f"/tiles/{uri}")
                holder.rollback()
            assert status == 503 and headers["retry-after"]
            assert body.startswith(b"a stage is rebuilding the tables"), body
            assert c.get(f"/tiles/{uri}")[0] == 200
        finally:
            c.close()


@pytest.mark.db
def test_stale_tiles_are_503_with_the_reason(new_db: Callable[[str], str]) -> None:
    """A migrated database without tiles (a stage still to run): 503 that says so, not a 500."""
    url = new_db("serve_empty")
    with running(reader_url(url, environ={})) as (_, base):
        c = Client(base)
        try:
            status, headers, body = c.get("/tiles/tileset.json")
            assert status == 503 and b"no tiles" in body and b"Traceback" not in body
            assert c.get("/tiles/content/0/0/0.glb")[0] == 503
        finally:
            c.close()


@pytest.mark.db
def test_cli_serves_from_the_database(fixtures_city: City) -> None:
    """`python -m etl serve --db --live` with DATABASE_URL (the stages' URL) connects as citylod_reader and serves
    the same bytes; SIGTERM stops it cleanly. (`serve --db` without --live: tests/db/test_export_publish.py.)"""
    env = {**os.environ, "DATABASE_URL": fixtures_city.url}
    env.pop("CITYLOD_READER_URL", None)
    with spawned(["etl", "serve", "--db", "--live", "--port", "0"], env, timeout=60) as (base, proc, stderr):
        c = Client(base)
        try:
            status, _, body = c.get("/tiles/tileset.json")
            assert status == 200 and body == (fixtures_city.tiles / "tileset.json").read_bytes()
        finally:
            c.close()
        proc.terminate()
        assert proc.wait(timeout=10) == 0
        stderr.seek(0)
        assert "straight from the database" in stderr.read()

    for args in (["--lod", "2"], ["--live"]):
        r = subprocess.run(
            [sys.executable, "-m", "etl", "serve", *args, "--port", "0"],
            cwd=REPO,
            capture_output=True,
            text=True,
            timeout=60,
        )
        assert r.returncode == 2 and "need --db" in r.stderr
    r = subprocess.run(
        [sys.executable, "-m", "etl", "serve", "--db", "--lod", "2", "--port", "0"],
        cwd=REPO,
        capture_output=True,
        text=True,
        timeout=60,
        env=env,
    )
    assert r.returncode == 2 and "--lod needs --live" in r.stderr
