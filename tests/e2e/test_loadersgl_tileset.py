"""loaders.gl's Tileset3D (@loaders.gl/tiles, what deck.gl's Tile3DLayer walks) traverses our tilesets: driven by
tests/e2e/loadersgl_tileset.mjs in Node, offline, with deck.gl WebMercatorViewports as cameras. Like
3DTilesRendererJS it computes every implicit tile's volume and error from the root alone.

* The demo city (textured, the default stream), the roof gallery and the deep tileset: every tile named by
  tileset.json and the subtrees loads without an error; the leaves hold the triangles their glbs hold; no tile's
  error as the client computes it (root / 2^level) is below the one the subtrees give it.
* The deep tileset at the cameras of test_lod_views: the buildings it covers (members of the selected tiles'
  features, blocks expanded) are those CesiumJS covers, but for buildings on the frustum's edge or drawn at a level
  the two clients choose differently (tests/support/coverage.py, as for three.js).
* The same tileset with its root region moved back to the root tile's own region: a camera straight down on the
  middle of the leaf the move displaces most no longer covers the building there.
"""

from __future__ import annotations

import json
import math
import subprocess
from collections.abc import Callable
from pathlib import Path
from typing import Any

import pytest

from core.tiles3d import content_uris, expand
from exporter.reuse import glb_triangles
from tests.conftest import REPO, City
from tests.e2e.conftest import MAX_SSE
from tests.support.coverage import cesium_cameras, coverage_report, covered, moved_root, tree

pytestmark = pytest.mark.e2e

DRIVER = REPO / "tests" / "e2e" / "loadersgl_tileset.mjs"


def tileset3d(tiles: Path, *args: str) -> dict[str, Any]:
    for pkg in ("@loaders.gl/tiles", "@loaders.gl/3d-tiles", "@deck.gl/core"):
        assert (REPO / "node_modules" / pkg).is_dir(), f"node_modules/{pkg} missing: run make setup"
    proc = subprocess.run(
        ["node", str(DRIVER), "--tileset", str(tiles / "tileset.json"), *args],
        cwd=REPO,
        capture_output=True,
        text=True,
        timeout=900,
    )
    assert proc.stdout.strip(), f"no report (exit {proc.returncode}): {proc.stderr[-3000:]}"
    res: dict[str, Any] = json.loads(proc.stdout)
    assert res["network"] == [], res["network"]
    assert res["errors"] == [] and proc.returncode == 0, (res["errors"][:5], proc.stderr[-2000:])
    return res


def check_load_all(tiles: Path, res: dict[str, Any]) -> None:
    tileset = json.loads((tiles / "tileset.json").read_text())
    everything = set(content_uris(tileset, lambda u: (tiles / u).read_bytes()))
    loaded = {t["uri"]: t for t in res["loadAll"]}
    assert set(loaded) == everything, sorted(everything ^ set(loaded))
    assert all(t["loaded"] for t in loaded.values()), [u for u, t in loaded.items() if not t["loaded"]]
    nodes = tree(tiles)
    leaves = {u for u, t in nodes.items() if not t.get("children")}
    assert {u for u, t in loaded.items() if t["leaf"]} == leaves
    # loaders.gl decoded every leaf's geometry (meshopt, quantized): the triangles its glb holds
    assert {u: loaded[u]["triangles"] for u in leaves} == {u: glb_triangles((tiles / u).read_bytes()) for u in leaves}
    low = {
        u: (t["error"], nodes[u]["geometricError"])
        for u, t in loaded.items()
        if t["error"] < nodes[u]["geometricError"] - 1e-3
    }
    assert low == {}


def test_demo_city_loads_every_tile(demo: City) -> None:
    res = tileset3d(demo.tiles, "--load-all")
    check_load_all(demo.tiles, res)
    assert any(t["images"] for t in res["loadAll"]), "no texture in the demo city: the KTX2 path was not exercised"


def test_roof_gallery_loads_every_tile(city: Callable) -> None:
    tiles = city("roofs").tiles
    check_load_all(tiles, tileset3d(tiles, "--load-all"))


def most_displaced_leaf(tiles: Path, moved: Path) -> tuple[str, float, float]:
    """The leaf whose true centre lies furthest outside the volume a metadata-blind client computes for it in the
    moved tileset: its uri and its true centre (lon, lat degrees)."""
    true = tree(tiles)
    tileset = json.loads((moved / "tileset.json").read_text())
    stack = [expand(tileset, lambda u: (moved / u).read_bytes(), metadata=False)["root"]]
    worst: tuple[float, str, float, float] = (0.0, "", 0.0, 0.0)
    while stack:
        t = stack.pop()
        stack.extend(t.get("children", []))
        uri = t.get("content", {}).get("uri")
        if not uri or t.get("children"):
            continue
        w, s, e, n = true[uri]["boundingVolume"]["region"][:4]
        cx, cy = (w + e) / 2, (s + n) / 2
        bw, bs, be, bn = t["boundingVolume"]["region"][:4]
        out = max(bw - cx, cx - be, 0.0) * math.cos(cy) + max(bs - cy, cy - bn, 0.0)  # radians, roughly
        if out > worst[0]:
            worst = (out, uri, math.degrees(cx), math.degrees(cy))
    assert worst[1], "the moved root displaces no leaf"
    return worst[1], worst[2], worst[3]


def test_loadersgl_covers_what_cesium_covers(
    deep: tuple[str, Path], drawn: dict[str, Any], conn_of: Callable, tmp_path: Path
) -> None:
    url, tiles = deep
    conn = conn_of(url)
    cams = cesium_cameras(drawn)
    res = tileset3d(tiles, "--load-all", "--cameras", json.dumps(cams), "--max-sse", str(MAX_SSE))
    check_load_all(tiles, res)
    lines = []
    for v in res["views"]:
        assert v["settled"], v
        rep = coverage_report(conn, drawn["by_name"][v["name"]], [t["uri"] for t in v["tiles"]], "loadersgl")
        lines.append(f"{v['name']}: {rep}")
        assert rep["loadersgl"] > 0 and rep["unexplained"] == [], lines[-1]
        assert rep["both"] >= 0.8 * max(rep["loadersgl"], rep["cesium"]), lines[-1]
    print("\n" + "\n".join(lines))

    # the root region moved: straight above the middle of the leaf the move displaces most, the true tileset draws
    # the building there from that leaf; the moved one culls the leaf and shows its parent's coarser features
    # instead (loaders.gl keeps a parent whose children are all culled), at a screen-space error past MAX_SSE
    moved = moved_root(tiles, tmp_path / "moved")
    leaf, lon, lat = most_displaced_leaf(tiles, moved)
    (b,) = conn.execute(
        """SELECT o.id FROM osm.building o
           WHERE o.id = ANY(%s) ORDER BY o.geom <-> ST_SetSRID(ST_MakePoint(%s, %s), 4326) LIMIT 1""",
        (list(covered(conn, [leaf])), lon, lat),
    ).fetchone()
    lon, lat = conn.execute(
        "SELECT ST_X(p), ST_Y(p) FROM osm.building o CROSS JOIN LATERAL ST_PointOnSurface(o.geom) p WHERE o.id = %s",
        (b,),
    ).fetchone()
    over = dict(cams[0], name="over", lon=lon, lat=lat, height=150.0, heading=0.0, pitch=-90.0)
    seen = {}
    for name, ts in (("true", tiles), ("moved", moved)):
        view = tileset3d(ts, "--cameras", json.dumps([over]), "--max-sse", str(MAX_SSE))["views"][0]
        by = covered(conn, [t["uri"] for t in view["tiles"]])
        seen[name] = leaf in by.get(b, set())
        if name == "moved":
            coarse = [t for t in view["tiles"] if tree(ts)[t["uri"]].get("children") and t["sse"] > view["maxSse"]]
            assert coarse, view["tiles"]  # a tile that should have refined, drawn because its children were culled
    assert seen == {"true": True, "moved": False}, (leaf, b, seen)
