"""Landmark exaggeration in the viewer, end to end: the Helsinki export (whose features carry the exaggeration
metadata, exporter/export.py) served by ``python -m exporter serve`` and drawn by CesiumJS in headless Chromium
(tests/e2e/landmarks_e2e.mjs) with the viewer's "Exaggerate landmarks" toggle off, on and off again.

The camera looks at the most salient landmark with several intervals from inside its last interval, so the
viewer must apply the top scale (the min(step^(i+1), max) clamp included); the reference is the database's
api.landmark_scale and api.landmark_exaggeration for the same camera.

* With the toggle on, the landmark alone on the background (globe and other features hidden) is taller and wider
  by the expected scale, and its pixel area by its square; picking the point halfway between the unscaled and
  the scaled roof hits the landmark only with the toggle on.
* The building the landmark pushes furthest moves on screen where its centre, moved by api.landmark_exaggeration's
  offset, projects.
* Turning it off restores the picture pixel for pixel; no shader error, no disabled custom shader, offline.

The view uses the tileset's leaves (maximumScreenSpaceError 1): in coarser tiles the neighbours are merged into
blocks, which carry no exaggeration role. A narrow field of view makes the landmark big enough to measure.
Canvas captures: build/test/landmarks/*.png. A missing Chromium or Node.js fails this test.
"""

from __future__ import annotations

import json
import math
import os
from collections.abc import Callable
from pathlib import Path
from urllib.parse import urlsplit

import numpy as np
import psycopg
import pytest

from core.geodesy import ecef_to_geodetic, enu_rotation, geodetic_to_ecef
from core.settings import Settings
from tests.conftest import BUILD, REPO
from tests.e2e.test_serve_viewer import run_driver, served

pytestmark = pytest.mark.e2e

DRIVER = REPO / "tests" / "e2e" / "landmarks_e2e.mjs"
OUT = BUILD / "landmarks"
CHROMIUM = Path(os.environ.get("CHROMIUM", "/usr/bin/chromium"))
PITCH = -30.0
FOV = 20.0  # degrees across the 800-pixel width: the landmark is ~50 pixels tall unscaled
#: Relative tolerance of the silhouette's height and width ratios (measured within 3 %: ±1 pixel on the ~23
#: pixels of its width is 4 %, perspective adds ~1 %), below the 12.5 % a missing clamp to lm_max_scale would add
#: on this landmark.
SIZE_TOL = 0.08
AREA_TOL = 0.12

# The most salient landmark with at least two intervals; centroid in degrees.
LANDMARK = """
SELECT b.osm_id, l.building_id, ST_X(p.g), ST_Y(p.g), l.height_m, l.scale_distances_m, l.scale_factors
FROM lm.building l
JOIN osm.building b ON b.id = l.building_id
CROSS JOIN LATERAL ST_Transform(l.centroid, 4326) AS p(g)
WHERE l.is_landmark AND cardinality(l.scale_factors) >= 2
ORDER BY l.rank
LIMIT 1
"""

# The buildings a landmark pushes for a camera, furthest first, whose exported role-2 metadata names the same
# landmark (one pushed by two landmarks follows the one that would push it furthest at its top scale); its
# centre (degrees, metres above ground at half its height) before and after the push.
PUSHED = """
SELECT b.osm_id, x.scale, x.dx, x.dy, ST_X(p.g), ST_Y(p.g), ST_X(q.g), ST_Y(q.g), o.height_m
FROM api.landmark_exaggeration(ST_SetSRID(ST_MakePoint(%(lon)s, %(lat)s, %(h)s), 4326)) x
JOIN osm.building b ON b.id = x.building_id
JOIN lm.building o ON o.building_id = x.building_id
CROSS JOIN LATERAL lm.exaggeration_role(x.building_id) r
CROSS JOIN LATERAL ST_Transform(o.centroid, 4326) AS p(g)
CROSS JOIN LATERAL ST_Transform(ST_Translate(o.centroid, x.dx, x.dy), 4326) AS q(g)
WHERE x.role = 'displaced' AND x.landmark_id = %(landmark)s AND r.landmark_id = %(landmark)s
ORDER BY x.dx ^ 2 + x.dy ^ 2 DESC
"""


def camera_at(lon: float, lat: float, ground: float, heading: float, pitch: float, rng: float) -> tuple[float, ...]:
    """(lon, lat, height) in degrees/metres of a camera ``rng`` metres from the target, looking at it with
    heading and pitch in degrees (Cesium's HeadingPitchRange)."""
    h, p = math.radians(heading), math.radians(pitch)
    enu = rng * np.array([-math.sin(h) * math.cos(p), -math.cos(h) * math.cos(p), -math.sin(p)])
    lo, la = math.radians(lon), math.radians(lat)
    g = ecef_to_geodetic(geodetic_to_ecef(lo, la, ground) + enu_rotation(lo, la) @ enu)
    return math.degrees(g[0]), math.degrees(g[1]), float(g[2])


def test_landmark_exaggeration_in_chromium(city: Callable, conn_of: Callable) -> None:
    assert CHROMIUM.exists(), f"Chromium not found at {CHROMIUM}: run scripts/install-system.sh test"
    for pkg in ("playwright-core", "cesium"):
        assert (REPO / "node_modules" / pkg).is_dir(), f"node_modules/{pkg} missing: run make setup"
    helsinki = city("helsinki")
    conn: psycopg.Connection = conn_of(helsinki.url)
    row = conn.execute(LANDMARK).fetchone()
    assert row, "no Helsinki landmark with two or more exaggeration intervals"
    osm_id, building_id, lon, lat, height, bounds, factors = row
    ground = Settings.from_env().base_height_m

    # Halfway into the interval past the last boundary: the top scale, far from any boundary, so the viewer's
    # distance (to the ground centre) and api.landmark_exaggeration's (to mid-height) agree on the interval.
    step = bounds[1] / bounds[0]
    rng = bounds[-1] * math.sqrt(step)
    scale = conn.execute("SELECT api.landmark_scale(%s, %s)", (building_id, rng)).fetchone()[0]
    assert scale == pytest.approx(factors[-1]) and scale > 1

    def pushed(heading: float) -> tuple:
        cam = camera_at(lon, lat, ground, heading, PITCH, rng)
        rows = conn.execute(PUSHED, {"lon": cam[0], "lat": cam[1], "h": cam[2], "landmark": building_id}).fetchall()
        assert rows, f"landmark {osm_id} pushes nothing from {cam}"
        return cam, rows[0]

    # Look across the push of the building pushed furthest, so its move is in the picture plane.
    _, (_, _, dx, dy, *_) = pushed(0.0)
    heading = (math.degrees(math.atan2(dx, dy)) + 90.0) % 360.0
    cam, (n_osm, n_scale, dx, dy, n_lon, n_lat, m_lon, m_lat, n_height) = pushed(heading)
    assert n_scale == pytest.approx(scale)
    push = math.hypot(dx, dy)

    OUT.mkdir(parents=True, exist_ok=True)
    for old in OUT.glob("*.png"):
        old.unlink()
    mid = ground + n_height / 2
    with served(helsinki.tiles) as (base, _proc):
        res, context = run_driver(
            DRIVER,
            [
                "--url",
                base,
                "--out-dir",
                str(OUT),
                "--max-sse",
                "1",
                "--landmark",
                json.dumps({"osmId": str(osm_id), "lon": lon, "lat": lat, "ground": ground}),
                "--camera",
                json.dumps({"heading": heading, "pitch": PITCH, "range": rng, "fov": FOV}),
                "--pick-height",
                repr(height * (1 + scale) / 2),
                "--neighbour",
                json.dumps(
                    {
                        "osmId": str(n_osm),
                        "from": {"lon": n_lon, "lat": n_lat, "height": mid},
                        "to": {"lon": m_lon, "lat": m_lat, "height": mid},
                    }
                ),
            ],
        )

    # The page: offline, clean, the toggle off at first and the checkbox following it.
    assert res["hosts"] == [urlsplit(base).netloc], context
    assert res["consoleErrors"] == [] and res["failedRequests"] == [] and res["error"] is None, context
    assert not [w for w in res["warnings"] if "custom shader" in w.lower()], context
    assert res["toggleInitially"] == {"exaggeration": False, "checked": False}, context
    assert res["toggleOn"] is True and res["toggleOff"] is False, context  # the checkbox drives citylod
    assert res["camera"]["distance"] == pytest.approx(rng, abs=0.01), context
    assert (res["camera"]["lon"], res["camera"]["lat"], res["camera"]["height"]) == pytest.approx(cam, abs=1e-6)

    # The whole view: on changes it, off restores it.
    sc = res["scene"]
    assert sc["offVsOn"] > 0.002 * sc["pixels"], context
    assert sc["offVsOffAgain"] <= 0.0005 * sc["pixels"], context

    # The landmark alone grows by the scale; its area by the square.
    lm = res["landmark"]
    off, on = lm["off"], lm["on"]
    assert lm["shown"] >= 1 and off["pixels"] > 300, context
    assert on["height"] / off["height"] == pytest.approx(scale, rel=SIZE_TOL), context
    assert on["width"] / off["width"] == pytest.approx(scale, rel=SIZE_TOL), context
    assert on["pixels"] / off["pixels"] == pytest.approx(scale**2, rel=AREA_TOL), context

    # Above the unscaled roof: the landmark only when exaggerated.
    assert res["pick"]["off"]["osmId"] != str(osm_id), context
    assert res["pick"]["on"]["osmId"] == str(osm_id), context

    # The pushed building keeps its size and moves where api.landmark_exaggeration says.
    nb = res["neighbour"]
    assert nb["shown"] >= 1 and nb["off"]["pixels"] > 50, context
    assert nb["on"]["pixels"] == pytest.approx(nb["off"]["pixels"], rel=0.15), context
    moved = np.array([nb["on"]["cx"] - nb["off"]["cx"], nb["on"]["cy"] - nb["off"]["cy"]])
    want = np.array([nb["to"]["x"] - nb["from"]["x"], nb["to"]["y"] - nb["from"]["y"]])
    assert np.linalg.norm(want) > 5, f"a {push:.1f} m push is too small to measure from here\n{context}"
    assert np.linalg.norm(moved - want) <= 0.15 * np.linalg.norm(want) + 1.0, (moved, want, context)
    print(
        f"landmark {osm_id} at {rng:.0f} m, scale {scale:.3f}: silhouette height x{on['height'] / off['height']:.3f},"
        f" width x{on['width'] / off['width']:.3f}, area x{on['pixels'] / off['pixels']:.3f} (want {scale**2:.3f});"
        f" {n_osm} pushed {push:.1f} m: moved {moved.round(2).tolist()} px, want {want.round(2).tolist()};"
        f" pixels changed on {sc['offVsOn']}, off again {sc['offVsOffAgain']} of {sc['pixels']};"
        f" driver {res['seconds']} s"
    )
    for name in ("off", "on", "off_again", "landmark_off", "landmark_on", "neighbour_off", "neighbour_on"):
        assert (OUT / f"{name}.png").stat().st_size > 1000, name
