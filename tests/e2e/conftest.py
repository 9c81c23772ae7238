"""What the e2e tests share: the deep multi-LOD Helsinki tileset (40 features per leaf, so every band exists) and
what CesiumJS draws of it from the cameras VIEWS (tests/e2e/lod_views_e2e.mjs, the plain traversal at MAX_SSE),
built once per session for test_lod_views (CesiumJS against api.lod_for_view) and the other clients' tests
(test_three_client, test_loadersgl_tileset), which compare what they draw with what CesiumJS draws.
"""

from __future__ import annotations

import json
import os
from collections.abc import Callable
from pathlib import Path
from typing import Any
from urllib.parse import urlsplit

import pytest

from tests.conftest import REPO, helsinki, run_etl
from tests.e2e.test_serve_viewer import run_driver, served

CESIUM_DRIVER = REPO / "tests" / "e2e" / "lod_views_e2e.mjs"
SCREENSHOTS = REPO / "build" / "screenshots"
CHROMIUM = Path(os.environ.get("CHROMIUM", "/usr/bin/chromium"))
BUDGET = {"CITYLOD_TILE_MAX_FEATURES": "40", "CITYLOD_TILE_MAX_TRIANGLES": "4000"}
MAX_SSE = 16.0

#: Degrees, metres above the ellipsoid (Helsinki's ground is at height 0 in this tileset), no roll.
VIEWS: dict[str, dict[str, float]] = {
    # The whole centre straight down from 6 km: the root refines (SSE ~24), its four children do not (6-10).
    "far": {"lon": 24.944, "lat": 60.1715, "height": 6000.0, "heading": 0.0, "pitch": -90.0},
    # 150 m up, oblique to the south-east over the roofs (a camera of test_generalize's CAMERAS).
    "mid": {"lon": 24.941, "lat": 60.170, "height": 150.0, "heading": 120.0, "pitch": -20.0},
    # 30 m above the streets in the middle of the centre, looking north.
    "near": {"lon": 24.9465, "lat": 60.1700, "height": 30.0, "heading": 0.0, "pitch": -20.0},
    # 30 m up by Senate Square, looking west over the centre: CesiumJS's own rules and a knife edge show here.
    "street": {"lon": 24.9525, "lat": 60.1688, "height": 30.0, "heading": 270.0, "pitch": -20.0},
}
SCREENSHOT = {"far": SCREENSHOTS / "lod_far.png", "near": SCREENSHOTS / "lod_near.png"}


@pytest.fixture(scope="session")
def deep(new_db: Callable[[str], str], tmp_path_factory: pytest.TempPathFactory) -> tuple[str, Path]:
    """Helsinki with 40 features per leaf: blocks near the root, then LOD1, LOD2 and LOD3 at the leaves."""
    osm = helsinki()
    url = new_db("lod_views")
    out = tmp_path_factory.mktemp("lod_views") / "tiles"
    run_etl(url, "ingest", "--osm", str(osm))
    run_etl(url, "lod")
    run_etl(url, "tiles", env=BUDGET)
    run_etl(url, "generalize")
    run_etl(url, "export", "--out", str(out))
    return url, out


@pytest.fixture(scope="session")
def drawn(deep: tuple[str, Path]) -> dict[str, Any]:
    """The driver's report: for each view, the tiles CesiumJS selected for rendering and its camera numbers."""
    assert CHROMIUM.exists(), f"Chromium not found at {CHROMIUM}: run scripts/install-system.sh test"
    for pkg in ("playwright-core", "cesium"):
        assert (REPO / "node_modules" / pkg).is_dir(), f"node_modules/{pkg} missing: run make setup"
    cams = []
    for name, v in VIEWS.items():
        cam: dict[str, Any] = {"name": name, **v}
        if name in SCREENSHOT:
            SCREENSHOT[name].parent.mkdir(parents=True, exist_ok=True)
            SCREENSHOT[name].unlink(missing_ok=True)
            cam["screenshot"] = str(SCREENSHOT[name])
        cams.append(cam)
    with served(deep[1]) as (base, _proc):
        res, context = run_driver(
            CESIUM_DRIVER, ["--url", base, "--cameras", json.dumps(cams), "--max-sse", str(MAX_SSE)]
        )
    res["context"] = context
    res["host"] = urlsplit(base).netloc
    res["by_name"] = {v["name"]: v for v in res["views"]}
    assert set(res["by_name"]) == set(VIEWS), context
    return res
