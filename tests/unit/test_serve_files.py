"""The server's file mode in-process (no database): media types, HEAD, CORS on every answer and the preflight,
no directory listings, and every way out of the tileset directory refused: '..' plain or percent-encoded, NUL,
backslashes, bytes that are not UTF-8, and symlinks that lead outside (file or directory)."""

from __future__ import annotations

import http.client
from collections.abc import Iterator
from pathlib import Path
from urllib.parse import urlsplit

import pytest

from exporter.serve.app import make_app
from exporter.serve.paths import BadPath, decode, safe_join
from tests.support.servers import threaded

SECRET = b"root:x:0:0 outside the tileset"


@pytest.fixture(scope="module")
def tree(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """base/tiles (served) next to base/outside (not): tileset.json, one glb, and links pointing out."""
    base = tmp_path_factory.mktemp("files")
    tiles, outside = base / "tiles", base / "outside"
    (tiles / "content" / "0" / "0").mkdir(parents=True)
    outside.mkdir()
    (tiles / "tileset.json").write_text('{"asset": {"version": "1.1"}}')
    (tiles / "content" / "0" / "0" / "0.glb").write_bytes(b"glTF" + bytes(60))
    (outside / "secret.txt").write_bytes(SECRET)
    (tiles / "leak.txt").symlink_to(outside / "secret.txt")
    (tiles / "leakdir").symlink_to(outside, target_is_directory=True)
    (tiles / "inside.json").symlink_to(tiles / "tileset.json")  # a link that stays inside is fine
    return tiles


@pytest.fixture(scope="module")
def base(tree: Path) -> Iterator[str]:
    with threaded(make_app(tiles_dir=tree)) as url:
        yield url


def get(base: str, path: str, method: str = "GET", **headers: str) -> tuple[int, dict[str, str], bytes]:
    """One request with ``path`` sent verbatim (no client-side normalisation of '..' or %2e)."""
    u = urlsplit(base)
    conn = http.client.HTTPConnection(u.hostname, u.port, timeout=30)
    try:
        conn.request(method, path, headers=headers)
        r = conn.getresponse()
        return r.status, {k.lower(): v for k, v in r.getheaders()}, r.read()
    finally:
        conn.close()


def test_safe_join_and_decode(tree: Path) -> None:
    assert safe_join(tree, "tileset.json") == tree / "tileset.json"
    assert safe_join(tree, "./content//0/0/0.glb") == tree / "content" / "0" / "0" / "0.glb"
    assert safe_join(tree, "inside.json") == tree / "tileset.json"
    for rel in ("leak.txt", "leakdir/secret.txt", "content", "", "missing.json"):
        assert safe_join(tree, rel) is None, rel
    for rel in ("../outside/secret.txt", "content/../../outside/secret.txt", "a\x00b", "content\\0"):
        with pytest.raises(BadPath):
            safe_join(tree, rel)
    assert decode(b"/tiles/%2e%2e/x%20y") == "/tiles/../x y"
    with pytest.raises(BadPath):
        decode(b"/tiles/%ff.json")


def test_files_media_types_head_and_cors(base: str) -> None:
    status, headers, body = get(base, "/tiles/tileset.json")
    assert (status, headers["content-type"], body) == (200, "application/json", b'{"asset": {"version": "1.1"}}')
    assert headers["access-control-allow-origin"] == "*" and headers["cache-control"] == "no-cache"
    status, headers, body = get(base, "/tiles/content/0/0/0.glb", "HEAD")
    assert (status, headers["content-type"], body) == (200, "model/gltf-binary", b"")
    assert int(headers["content-length"]) == 64
    for path, media in (("/", "text/html"), ("/index.html", "text/html"), ("/viewer/viewer.js", "text/javascript")):
        status, headers, _ = get(base, path)
        assert (status, headers["content-type"].split(";")[0]) == (200, media), path
    status, headers, body = get(
        base,
        "/tiles/tileset.json",
        "OPTIONS",
        Origin="https://elsewhere.example",
        **{"Access-Control-Request-Method": "GET"},
    )
    assert (status, body) == (204, b"")
    assert headers["access-control-allow-origin"] == "*" and "GET" in headers["access-control-allow-methods"]


@pytest.mark.parametrize(
    ("path", "status"),
    [
        ("/tiles/content/", 404),  # no directory listing
        ("/tiles/content/0/0/1.glb", 404),
        ("/tiles/leak.txt", 404),  # symlink to a file outside the root
        ("/tiles/leakdir/secret.txt", 404),  # through a symlinked directory
        ("/tiles/../outside/secret.txt", 400),
        ("/tiles/%2e%2e/outside/secret.txt", 400),
        ("/tiles/..%2foutside%2fsecret.txt", 400),
        ("/tiles/content%5c..%5c..%5coutside%5csecret.txt", 400),
        ("/tiles/tileset.json%00", 400),
        ("/tiles/%ff.json", 400),  # not UTF-8
        ("/viewer/%2e%2e/%2e%2e/pyproject.toml", 400),
        ("/viewer", 404),
        ("/../pyproject.toml", 404),
        ("/nowhere", 404),
    ],
)
def test_refused(base: str, path: str, status: int) -> None:
    got, headers, body = get(base, path)
    assert got == status, (path, got, body[:200])
    assert headers["access-control-allow-origin"] == "*", path  # errors too, so other origins can read them
    assert SECRET not in body and b"[project]" not in body and b"Traceback" not in body, path
    assert get(base, path, "HEAD")[0] == status
