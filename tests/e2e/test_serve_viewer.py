"""The viewer end to end: `python -m exporter serve` on the real Helsinki tileset, CesiumJS in headless Chromium
(tests/e2e/viewer_e2e.mjs) loads it offline, clicks a known building and must read back its OSM id.

Also the server alone (no browser): media types, CORS, 404s and refused path traversal.
A missing Chromium or Node.js fails these tests; it never skips them.
"""

from __future__ import annotations

import http.client
import json
import os
import shutil
import subprocess
import sys
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from pathlib import Path
from urllib.parse import urlsplit

import pytest

from tests.support.servers import spawned

REPO = Path(__file__).resolve().parents[2]
DRIVER = REPO / "tests" / "e2e" / "viewer_e2e.mjs"
SCREENSHOT = REPO / "build" / "screenshots" / "viewer_helsinki.png"
CHROMIUM = Path(os.environ.get("CHROMIUM", "/usr/bin/chromium"))

# The largest tall-ish, roughly convex, standalone building, with no other building within 3 m of the point
# we click: looking straight down at that point must hit this roof and nothing else.
PICK_TARGET = """
SELECT b.osm_type, b.osm_id, ST_X(p.geom), ST_Y(p.geom), m.height
FROM osm.building b
JOIN lod.building_mesh m ON m.building_id = b.id AND m.lod = 1
CROSS JOIN LATERAL ST_PointOnSurface(b.geom) AS p(geom)
WHERE b.kind = 'building' AND b.n_parts = 0 AND m.height >= 10
  AND ST_Area(b.geom_local) >= 0.8 * ST_Area(ST_ConvexHull(b.geom_local))
  AND NOT EXISTS (
      SELECT 1 FROM osm.building o
      WHERE o.id <> b.id AND ST_DWithin(o.geom::geography, p.geom::geography, 3))
ORDER BY b.area_m2 DESC
LIMIT 1
"""


def run_driver(driver: Path, args: list[str]) -> tuple[dict, str]:
    """Run a Node e2e driver; returns (its last JSON line, a context string for assertion messages)."""
    node = shutil.which("node")
    assert node, f"Node.js is not installed: it is needed to drive Chromium ({driver.name})"
    r = subprocess.run([node, str(driver), *args], cwd=REPO, capture_output=True, text=True, timeout=600)
    out = r.stdout.strip().splitlines()
    context = f"driver exit {r.returncode}\nstdout:\n{r.stdout}\nstderr:\n{r.stderr}"
    assert out, context
    res = json.loads(out[-1])
    assert r.returncode == 0, context
    return res, context


@contextmanager
def served(tiles: Path, timeout: float = 30.0) -> Iterator[tuple[str, subprocess.Popen]]:
    """Run ``python -m exporter serve --port 0`` and yield (base URL, process); always terminated after."""
    with spawned(["exporter", "serve", "--dir", str(tiles), "--port", "0"], timeout=timeout) as (base, proc, _):
        yield base, proc


def raw_get(base: str, path: str, method: str = "GET") -> tuple[int, dict[str, str], bytes]:
    """One request with ``path`` sent verbatim (no client-side normalisation of '..' or %2e)."""
    u = urlsplit(base)
    conn = http.client.HTTPConnection(u.hostname, u.port, timeout=30)
    try:
        conn.request(method, path)
        r = conn.getresponse()
        return r.status, {k.lower(): v for k, v in r.getheaders()}, r.read()
    finally:
        conn.close()


@pytest.mark.db
def test_server_routes(city: Callable, tmp_path: Path) -> None:
    tiles = city("helsinki").tiles
    glb = next(tiles.rglob("*.glb")).relative_to(tiles).as_posix()
    with served(tiles) as (base, proc):
        status, headers, body = raw_get(base, f"/tiles/{glb}")
        assert status == 200
        assert headers["content-type"] == "model/gltf-binary"
        assert headers["access-control-allow-origin"] == "*"
        assert body[:4] == b"glTF" and len(body) == int(headers["content-length"])

        status, headers, body = raw_get(base, "/tiles/tileset.json")
        assert status == 200 and headers["content-type"] == "application/json"
        assert json.loads(body)["asset"]["version"] == "1.1"

        for path, media in (
            ("/", "text/html"),
            ("/index.html", "text/html"),
            ("/viewer/viewer.js", "text/javascript"),
            ("/viewer/viewer.css", "text/css"),
            ("/cesium/Cesium.js", "text/javascript"),
        ):
            status, headers, _ = raw_get(base, path)
            assert (status, headers["content-type"].split(";")[0]) == (200, media), path
            assert headers["access-control-allow-origin"] == "*", path

        status, headers, _ = raw_get(base, "/tiles/content/99/0/0.glb")
        assert status == 404
        assert headers["access-control-allow-origin"] == "*"  # errors too, so other origins can read them
        assert raw_get(base, "/tiles/content/")[0] == 404  # no directory listing
        for path in (
            "/tiles/../../etc/passwd",
            "/tiles/%2e%2e/%2e%2e/etc/passwd",
            "/cesium/..%2f..%2f..%2fpackage.json",
            "/viewer/%00",
            "/../pyproject.toml",
        ):
            status, _, body = raw_get(base, path)
            assert status in (400, 404), (path, status)
            assert b"root:" not in body and b"[project]" not in body, path
        assert raw_get(base, "/tiles/tileset.json", "OPTIONS")[0] == 204  # CORS preflight

        # SIGTERM stops it cleanly.
        proc.terminate()
        assert proc.wait(timeout=10) == 0

    # Nothing to serve: a clear message that says how to make a tileset.
    r = subprocess.run(
        [sys.executable, "-m", "exporter", "serve", "--dir", str(tmp_path), "--port", "0"],
        cwd=REPO,
        capture_output=True,
        text=True,
        timeout=30,
    )
    assert r.returncode != 0 and "make export" in r.stderr and r.stdout == ""


@pytest.mark.e2e
def test_viewer_picks_building_in_chromium(city: Callable, conn_of: Callable) -> None:
    assert CHROMIUM.exists(), f"Chromium not found at {CHROMIUM}: run scripts/install-system.sh test"
    for pkg in ("playwright-core", "cesium"):
        assert (REPO / "node_modules" / pkg).is_dir(), f"node_modules/{pkg} missing: run make setup"

    from core.settings import Settings

    helsinki = city("helsinki")
    row = conn_of(helsinki.url).execute(PICK_TARGET).fetchone()
    assert row, "no building in Helsinki fits the pick-target query"
    osm_type, osm_id, lon, lat, height = row
    top = Settings.from_env().base_height_m + float(height)  # the roof, metres above the ellipsoid

    SCREENSHOT.parent.mkdir(parents=True, exist_ok=True)
    SCREENSHOT.unlink(missing_ok=True)
    with served(helsinki.tiles) as (base, _proc):
        res, context = run_driver(
            DRIVER,
            [
                "--url",
                base,
                "--lon",
                repr(lon),
                "--lat",
                repr(lat),
                "--height",
                repr(top),
                "--screenshot",
                str(SCREENSHOT),
                "--expect-osm-id",
                str(osm_id),
            ],
        )

    assert res["tilesWithContent"] > 0, context
    assert res["triangles"] > 0, context
    # the status line counts what it names: buildings, parts and blocks of the drawn tiles, adding up to the
    # features CesiumJS selected; the overview of a whole city draws merged blocks, which are not buildings
    for view in (res["overview"], res["far"], res):
        kinds = view["kinds"]
        assert sum(kinds.values()) == view["features"] > 0 and kinds["other"] == 0, (view, context)
    for view in (res["overview"], res["far"]):
        kinds, members = view["kinds"], view["blockMembers"]
        assert members >= kinds["block"], view  # every block merges at least one building
        # the buildings the view stands for first, then how they are drawn: on their own, merged into blocks
        assert (
            f"{kinds['building'] + members:,} buildings shown: {kinds['building']:,} on their own" in view["status"]
        ), view["status"]
        assert f"{members:,} merged into {kinds['block']:,} blocks" in view["status"], view["status"]
    assert res["far"]["kinds"]["block"] > 0 and res["far"]["blockMembers"] > res["far"]["kinds"]["block"], res["far"]
    picked = res["picked"]
    assert picked, f"nothing picked at {osm_type} {osm_id}\n{context}"
    assert int(picked["osm_id"]) == osm_id, context
    assert picked["osm_type"] == {"W": "way", "R": "relation"}[osm_type], context
    assert res["panelRows"] == len(picked) > 1, context  # the panel shows every property
    host = urlsplit(base).netloc
    assert res["hosts"] == [host], f"requests left the local server: {res['hosts']}"
    assert "OpenStreetMap contributors" in (res["attribution"] or "")
    # a tile CesiumJS could not load, or any page error, shows up here (the viewer logs tileFailed as an error)
    assert res["consoleErrors"] == [], context
    assert res["failedRequests"] == [], context
    assert SCREENSHOT.exists() and SCREENSHOT.stat().st_size > 10_000, SCREENSHOT
