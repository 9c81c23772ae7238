"""The roof gallery end to end: fixture 200 of tests/fixtures/osm_fixtures.py (every OSM roof:shape and tagging
variants) through the real pipeline into a fresh database, exported at LOD 2, served by
``python -m exporter serve``, and
exporter/viewer/gallery.html driven in headless Chromium (tests/e2e/gallery_e2e.mjs).

The gallery must find all the buildings in the loaded tiles, list every roof shape with the number of buildings the
OSM file gives it, frame the tileset so that every building really shows on screen (decoded from rendered pixels,
not from the camera maths), highlight a shape from the legend and from a click on a building, and render a
non-blank picture, saved as build/screenshots/roof_gallery.png.
A missing Chromium or Node.js fails this test; it never skips.
"""

from __future__ import annotations

import os
from collections import Counter
from collections.abc import Callable
from pathlib import Path
from urllib.parse import urlsplit

import numpy as np
import pytest

from tests.conftest import REPO
from tests.e2e.test_serve_viewer import run_driver, served
from tests.fixtures.osm_fixtures import ROOF_SHAPES, roofs

DRIVER = REPO / "tests" / "e2e" / "gallery_e2e.mjs"
SCREENSHOTS = REPO / "build" / "screenshots"
SCREENSHOT = SCREENSHOTS / "roof_gallery.png"
HIGHLIGHT = "gabled"  # the legend entry the driver clicks
PICK = "hipped"  # the roof shape of the building the driver clicks
HIGHLIGHT_SCREENSHOT = SCREENSHOTS / f"roof_gallery_{HIGHLIGHT}.png"
CHROMIUM = Path(os.environ.get("CHROMIUM", "/usr/bin/chromium"))

CATALOGUE = set(ROOF_SHAPES)  # the roof:shape values of the OSM catalogue (wiki Key:roof:shape)


def expected_shapes() -> tuple[Counter[str], dict[int, str]]:
    """(buildings per roof shape, shape of each way id) as fixture 200 tags them: roof:shape, else
    building:roof:shape, else flat; "many" and anything outside the catalogue are drawn flat."""
    counts: Counter[str] = Counter()
    by_id: dict[int, str] = {}
    for wid, _refs, tags in roofs().ways:
        shape = (tags.get("roof:shape") or tags.get("building:roof:shape") or "flat").strip().lower()
        if shape not in CATALOGUE:  # "many" included
            shape = "flat"
        counts[shape] += 1
        by_id[wid] = shape
    return counts, by_id


@pytest.fixture(scope="module")
def roofs_tiles(city: Callable) -> Path:
    """Fixture 200 alone in its own database, exported at LOD 2 (the default)."""
    return city("roofs").tiles


def read_rgb(path: Path) -> np.ndarray:
    from etl.textures.atlas import openimageio

    oiio = openimageio()

    buf = oiio.ImageBuf(str(path))
    assert not buf.has_error, buf.geterror()
    px = buf.get_pixels(oiio.UINT8)
    assert px is not None and px.ndim == 3 and px.shape[2] >= 3, path
    return px[..., :3]


@pytest.mark.e2e
def test_roof_gallery_in_chromium(roofs_tiles: Path) -> None:
    assert CHROMIUM.exists(), f"Chromium not found at {CHROMIUM}: run scripts/install-system.sh test"
    for pkg in ("playwright-core", "cesium"):
        assert (REPO / "node_modules" / pkg).is_dir(), f"node_modules/{pkg} missing: run make setup"

    expected, shape_of = expected_shapes()
    total = sum(expected.values())

    SCREENSHOTS.mkdir(parents=True, exist_ok=True)
    for p in (SCREENSHOT, HIGHLIGHT_SCREENSHOT):
        p.unlink(missing_ok=True)
    with served(roofs_tiles) as (base, _proc):
        res, context = run_driver(
            DRIVER,
            [
                "--url",
                base,
                "--screenshot",
                str(SCREENSHOT),
                "--highlight",
                HIGHLIGHT,
                "--highlight-screenshot",
                str(HIGHLIGHT_SCREENSHOT),
                "--pick-shape",
                PICK,
            ],
        )

    # Counts read from the loaded tile content, and the legend the page shows.
    assert res["featureCount"] == total, context
    assert res["shapes"] == dict(expected), context
    assert res["legend"] == dict(expected), context
    assert res["legendAll"] == total, context
    assert res["tilesLoaded"] is True, context

    # The framing: every building shows as a patch of pixels outside the panel and the credits.
    vis = res["visible"]
    assert vis["features"] == total, context
    assert vis["hidden"] == [] and vis["shown"] == total, f"buildings not on screen: {vis['hidden']}"

    # The legend entry highlights exactly that shape's buildings, and a second click clears it.
    hl = res["highlight"]
    assert hl["highlighted"] == {HIGHLIGHT: expected[HIGHLIGHT]}, context
    assert hl["selectedItems"] == [HIGHLIGHT], context
    assert res["selectedAfterToggle"] == [], context

    # Clicking a building names it with its shape and highlights that shape.
    pick = res["pick"]
    osm_type, osm_id = pick["feature"].split("/")
    assert shape_of[int(osm_id)] == PICK, pick
    assert pick["text"] == f"{osm_type} {osm_id}: {PICK}", pick
    assert pick["selected"] == PICK and pick["selectedItems"] == [PICK], pick

    # Offline: nothing but the local server, no errors, no failed requests.
    assert res["hosts"] == [urlsplit(base).netloc], f"requests left the local server: {res['hosts']}"
    assert res["consoleErrors"] == [], context
    assert res["failedRequests"] == [], context

    # The screenshot is a picture, not a blank canvas: many colours, and right of the panel a good share of the
    # pixels are not the ground colour.
    assert SCREENSHOT.exists(), SCREENSHOT
    rgb = read_rgb(SCREENSHOT)
    assert rgb.shape[:2] == (800, 1280), rgb.shape
    packed = (rgb[..., 0].astype(np.uint32) << 16) | (rgb[..., 1].astype(np.uint32) << 8) | rgb[..., 2]
    distinct = len(np.unique(packed))
    assert distinct > 500, f"{SCREENSHOT}: only {distinct} distinct colours"
    scene = packed[:, 300:]
    _, n = np.unique(scene, return_counts=True)
    dominant = n.max() / scene.size
    assert dominant < 0.95, f"{SCREENSHOT}: {dominant:.1%} of the scene is one colour"
    assert HIGHLIGHT_SCREENSHOT.exists(), HIGHLIGHT_SCREENSHOT
