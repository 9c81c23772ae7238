"""three.js in the test suite: NASA-AMMOS 3DTilesRendererJS on three.js (tests/e2e/three/client.js, driven by
tests/e2e/three_e2e.mjs in headless Chromium, offline), a client that computes every implicit tile's volume and
error from the root alone (it ignores the subtrees' TILE_BOUNDING_REGION / TILE_GEOMETRIC_ERROR).

* The demo city (textured, the default stream) and the roof gallery: every tile named by tileset.json and the
  subtrees loads, without an error or a warning but the one 3DTilesRendererJS gives every 3D Tiles 1.1 tileset;
  refined to the leaves it draws the triangles the leaves' glbs hold, textures as KTX2 with their mips; no
  building lies further outside the volume the client computes for its tile than its own half-extent (measured
  by the client, against the volume it culls with); no tile's error as the client computes it (root / 2^level) is
  below the one the subtrees give; a raycast straight down on a known building returns its OSM properties.
* The deep tileset of test_lod_views at the same cameras as CesiumJS (which reads the subtree metadata): the
  buildings it covers (members of the drawn tiles' features, blocks expanded) are those CesiumJS covers, but for
  buildings on the frustum's edge or drawn at a level the two clients choose differently.
* The same tileset with its root region moved back to the root tile's own region (the export before the quadtree
  was cut on the root's implicit subdivision) fails both checks: this test sees the bug it guards against.
"""

from __future__ import annotations

import json
from collections.abc import Callable
from pathlib import Path
from typing import Any

import psycopg
import pytest

from core.settings import Settings
from core.tiles3d import content_uris
from exporter.gltf import read_glb
from tests.conftest import REPO, City
from tests.e2e.conftest import CHROMIUM, MAX_SSE
from tests.e2e.test_serve_viewer import PICK_TARGET, run_driver, served
from tests.support.coverage import cesium_cameras, coverage_report, covered, moved_root, tree

pytestmark = pytest.mark.e2e

DRIVER = REPO / "tests" / "e2e" / "three_e2e.mjs"
#: What 3DTilesRendererJS 0.5.3 logs for any tileset of version 1.1; anything else it or three.js warns is a problem.
VERSION_NOTICE = (
    "TilesRenderer: tiles versions at 1.1 or higher have limited support. "
    "Some new extensions and features may not be supported."
)


def three(tiles: Path, *args: str) -> tuple[dict[str, Any], str]:
    assert CHROMIUM.exists(), f"Chromium not found at {CHROMIUM}: run scripts/install-system.sh test"
    for pkg in ("playwright-core", "three", "3d-tiles-renderer"):
        assert (REPO / "node_modules" / pkg).is_dir(), f"node_modules/{pkg} missing: run make setup"
    with served(tiles) as (base, _proc):
        res, context = run_driver(DRIVER, ["--url", base, *args])
    res["base"] = base
    return res, context


def glb_triangles(path: Path) -> int:
    doc, _ = read_glb(path.read_bytes())
    n = 0
    for mesh in doc["meshes"]:
        for prim in mesh["primitives"]:
            assert prim.get("mode", 4) == 4, path
            n += doc["accessors"][prim["indices"]]["count"] // 3
    return n


def page_problems(res: dict[str, Any]) -> list[str]:
    out = [f"load error {e}" for e in res["loadErrors"]]
    out += [f"console error {e}" for e in res["consoleErrors"]]
    out += [f"failed request {e}" for e in res["failedRequests"]]
    out += [f"warning {w}" for w in res["warnings"] if w != VERSION_NOTICE and "GL Driver Message" not in w]
    host = res["base"].split("//")[1].rstrip("/")
    out += [f"request to {h}" for h in res["hosts"] if h != host]
    return out


def containment_problems(res: dict[str, Any]) -> list[str]:
    """Buildings further outside the client's volume for their tile than their own half-extent (+ 5 cm)."""
    return [
        f"{uri}: {b['building']} {b['overhang']:.1f} m outside (half-extent {b['half']:.1f} m)"
        for uri, rec in res["containment"].items()
        for b in rec["beyond"]
    ]


def check_load_all(tiles: Path, res: dict[str, Any]) -> None:
    tileset = json.loads((tiles / "tileset.json").read_text())
    everything = set(content_uris(tileset, lambda u: (tiles / u).read_bytes()))
    nodes = tree(tiles)
    leaves = {u for u, t in nodes.items() if not t.get("children")}
    assert page_problems(res) == []
    assert set(res["loaded"]) == everything, sorted(everything ^ set(res["loaded"]))
    drawn = {t["uri"]: t for t in res["loadAll"]["leaves"]}
    assert set(drawn) == leaves
    want = {u: glb_triangles(tiles / u) for u in leaves}
    assert {u: t["triangles"] for u, t in drawn.items()} == want
    assert res["loadAll"]["renderedTriangles"] == sum(want.values())  # three.js drew them (nothing culled)
    assert set(res["containment"]) == everything  # every tile measured, when it was drawn
    assert containment_problems(res) == []
    # the error the client gives each tile (root / 2^level) is never below the one the subtrees give it
    errors = {u: e for d in res["loadAll"]["depths"] for u, e in d["errors"].items()}
    assert set(errors) == everything
    low = {u: (e, nodes[u]["geometricError"]) for u, e in errors.items() if e < nodes[u]["geometricError"] - 1e-6}
    assert low == {}


@pytest.fixture(scope="module")
def demo_in_three(demo: City) -> tuple[dict[str, Any], str, tuple]:
    with psycopg.connect(demo.url) as conn:
        row = conn.execute(PICK_TARGET).fetchone()
    assert row, "no building in Helsinki fits the pick-target query"
    osm_type, osm_id, lon, lat, height = row
    top = Settings.from_env().base_height_m + float(height)
    res, context = three(demo.tiles, "--load-all", "--pick", json.dumps({"lon": lon, "lat": lat, "top": top}))
    return res, context, row


def test_demo_city_loads_and_draws_every_leaf(demo: City, demo_in_three: tuple) -> None:
    res, context, _ = demo_in_three
    check_load_all(demo.tiles, res)
    textured = [t for t in res["loadAll"]["leaves"] if t["textures"]]
    assert textured, "the demo city's leaves carry no texture: the KTX2 path was not exercised"
    assert all(t["fewestMips"] and t["fewestMips"] > 1 for t in textured), textured  # KTX2 with its mips


def test_raycast_returns_the_osm_properties(demo_in_three: tuple) -> None:
    res, context, (osm_type, osm_id, *_rest) = demo_in_three
    picked = res["pick"]
    assert picked and "properties" in picked, context
    props = picked["properties"]
    assert (props["osm_type"], int(props["osm_id"])) == ({"W": "way", "R": "relation"}[osm_type], osm_id), props
    assert props["lod"] == 3 and props["kind"] == "building", props


def test_roof_gallery_loads_and_draws_every_leaf(city: Callable) -> None:
    tiles = city("roofs").tiles
    res, context = three(tiles, "--load-all")
    check_load_all(tiles, res)


# --- the deep tileset at the cameras of test_lod_views, against CesiumJS ----------------------------------------


def test_three_covers_what_cesium_covers(
    deep: tuple[str, Path], drawn: dict[str, Any], conn_of: Callable, tmp_path: Path
) -> None:
    url, tiles = deep
    conn = conn_of(url)
    cams = json.dumps(cesium_cameras(drawn))
    args = ["--load-all", "--cameras", cams, "--max-sse", str(MAX_SSE)]
    res, context = three(tiles, *args)
    check_load_all(tiles, res)
    lines = []
    for v in res["views"]:
        rep = coverage_report(conn, drawn["by_name"][v["name"]], [t["uri"] for t in v["tiles"]], "three")
        lines.append(f"{v['name']}: {rep}")
        assert rep["three"] > 0 and rep["unexplained"] == [], lines[-1]
        assert rep["both"] >= 0.8 * max(rep["three"], rep["cesium"]), lines[-1]
    print("\n" + "\n".join(lines))

    # the same with the root region moved: the client's volumes no longer hold the tiles' content ...
    moved = moved_root(tiles, tmp_path / "moved")
    bad, _ = three(moved, "--load-all")
    problems = containment_problems(bad)
    assert problems, bad["containment"]
    # ... and a camera straight down on the building furthest out of its tile's volume sees it in the true tileset,
    # not in the moved one (its tile is culled while the building is in the middle of the view)
    worst = max(
        (b for rec in bad["containment"].values() for b in rec["beyond"] if b["building"].split()[0] != "block"),
        key=lambda b: b["overhang"],
    )
    osm_type, osm_id = worst["building"].split()
    lon, lat, b = conn.execute(
        """SELECT ST_X(p), ST_Y(p), o.id FROM osm.building o CROSS JOIN LATERAL ST_PointOnSurface(o.geom) AS p
           WHERE o.osm_type = %s AND o.osm_id = %s""",
        ({"way": "W", "relation": "R"}[osm_type], int(osm_id)),
    ).fetchone()
    over = dict(cesium_cameras(drawn)[0], name="over", lon=lon, lat=lat, height=150.0, heading=0.0, pitch=-90.0)
    seen = {}
    for name, ts in (("true", tiles), ("moved", moved)):
        res_over, _ = three(ts, "--cameras", json.dumps([over]), "--max-sse", str(MAX_SSE))
        seen[name] = b in covered(conn, [t["uri"] for t in res_over["views"][0]["tiles"]])
    assert seen == {"true": True, "moved": False}, (worst, seen, problems[:5])
