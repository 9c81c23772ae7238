"""A textured street in CesiumJS: Helsinki exported with and without the textures stage, the same street-level
camera in headless Chromium (tests/e2e/lod_views_e2e.mjs), screenshots in build/test/textures/. The textured
picture must show texture detail where the plain one has flat faces (luminance varying inside the faces and
window panels of the plain picture); CesiumJS must load every textured tile without an error (EXT_texture_webp,
WebP pages). The street is the longest wall of a many-windowed building that faces open space.
"""

from __future__ import annotations

import json
import math
from collections.abc import Callable
from pathlib import Path

import numpy as np
import psycopg
import pytest
from scipy import ndimage

from etl.textures.atlas import openimageio
from tests.conftest import BUILD, helsinki, run_etl
from tests.e2e.test_serve_viewer import CHROMIUM, REPO, run_driver, served

DRIVER = REPO / "tests" / "e2e" / "lod_views_e2e.mjs"
SHOTS = BUILD / "textures"
DISTANCE = 30.0  # m from the wall
EYE = 6.0  # m above ground

# The longest wall of a building with many LOD3 windows that looks onto open space: nothing within DISTANCE m
# in front of it (footprints counter-clockwise, so the outward normal of edge a -> b is (dy, -dx) / length).
STREET_CAMERA = """
WITH b AS (
    SELECT o.id, ST_ExteriorRing(ST_ForcePolygonCCW(ST_GeometryN(o.geom_local, 1))) AS ring
    FROM osm.building o JOIN lod.building_mesh m ON m.building_id = o.id AND m.lod = 3
    WHERE o.kind = 'building' AND o.n_parts = 0 AND m.n_windows >= 12 AND m.height BETWEEN 10 AND 30
), w AS (
    SELECT b.id, ST_X(a) AS ax, ST_Y(a) AS ay, ST_X(c) AS cx, ST_Y(c) AS cy, ST_Distance(a, c) AS len
    FROM b CROSS JOIN LATERAL generate_series(1, ST_NPoints(b.ring) - 1) i
    CROSS JOIN LATERAL (SELECT ST_PointN(b.ring, i) AS a, ST_PointN(b.ring, i + 1) AS c) p
), v AS (
    SELECT id, len, (ax + cx) / 2 AS mx, (ay + cy) / 2 AS my, (cy - ay) / len AS nx, -(cx - ax) / len AS ny
    FROM w WHERE len >= 15
)
SELECT v.id, v.len, v.nx, v.ny,
       ST_X(ST_Transform(ST_SetSRID(ST_MakePoint(mx + %(d)s * nx, my + %(d)s * ny), meta.working_srid()), 4326)),
       ST_Y(ST_Transform(ST_SetSRID(ST_MakePoint(mx + %(d)s * nx, my + %(d)s * ny), meta.working_srid()), 4326))
FROM v
WHERE NOT EXISTS (
    SELECT 1 FROM osm.building o
    WHERE ST_Intersects(o.geom_local, ST_Buffer(ST_SetSRID(ST_MakeLine(
        ST_MakePoint(mx + 4 * nx, my + 4 * ny), ST_MakePoint(mx + (%(d)s + 5) * nx, my + (%(d)s + 5) * ny)),
        meta.working_srid()), 3)))
ORDER BY v.len DESC, v.id
LIMIT 1
"""


def read_rgb(path: Path) -> np.ndarray:
    oiio = openimageio()
    buf = oiio.ImageBuf(str(path))
    return np.asarray(buf.get_pixels(oiio.UINT8)).reshape(buf.spec().height, buf.spec().width, -1)[..., :3]


def detail_within_faces(plain: np.ndarray, other: np.ndarray) -> tuple[float, float]:
    """(plain, other): the mean luminance spread (standard deviation, weighted by area) of each picture inside
    the flat regions of the plain picture (building faces and window panels, 2 px away from any edge). An
    untextured face is one flat colour (flat shading, one sun); a texture puts windows, storeys and its
    material's noise inside it."""
    lum = np.array([0.2126, 0.7152, 0.0722])
    la, lb = plain.astype(float) @ lum, other.astype(float) @ lum
    bg = np.median(plain[0], axis=0)  # the sky: the most common colour of the top row
    building = np.abs(plain.astype(int) - bg).sum(axis=2) > 30
    grad = np.maximum(np.abs(np.diff(la, axis=0, append=la[-1:])), np.abs(np.diff(la, axis=1, append=la[:, -1:])))
    flat = building & (ndimage.maximum_filter(grad, 5) < 3)
    lab, n = ndimage.label(flat)
    idx = np.arange(1, n + 1)
    size = ndimage.sum(np.ones_like(la), lab, idx)
    big = size >= 200
    assert big.any() and size[big].sum() > 0.1 * la.size, "the buildings should fill a good part of the view"

    def spread(lum_img: np.ndarray) -> float:
        return float((ndimage.standard_deviation(lum_img, lab, idx) * size)[big].sum() / size[big].sum())

    return spread(la), spread(lb)


@pytest.mark.e2e
def test_textured_street_shows_texture_detail(new_db: Callable[[str], str], tmp_path: Path) -> None:
    assert CHROMIUM.exists(), f"Chromium not found at {CHROMIUM}: run scripts/install-system.sh test"
    url = new_db("textured_street")
    run_etl(url, "ingest", "--osm", str(helsinki()))
    for stage in ("lod", "landmarks", "tiles", "generalize"):
        run_etl(url, stage)
    plain, textured = tmp_path / "plain", tmp_path / "textured"
    run_etl(url, "export", "--out", str(plain))
    run_etl(url, "textures")
    run_etl(url, "export", "--out", str(textured))
    with psycopg.connect(url) as conn:
        row = conn.execute(STREET_CAMERA, {"d": DISTANCE}).fetchone()
    assert row, "no wall in Helsinki faces open space"
    _, _, nx, ny, lon, lat = row
    heading = math.degrees(math.atan2(-nx, -ny)) % 360  # looking back at the wall (compass: east of north)
    shots = {}
    results = {}
    for name, tiles in (("street_plain", plain), ("street", textured)):
        shot = SHOTS / f"{name}.png"
        shot.unlink(missing_ok=True)
        cam = {
            "name": name,
            "lon": lon,
            "lat": lat,
            "height": EYE,
            "heading": heading,
            "pitch": 5.0,
            "screenshot": str(shot),
        }
        with served(tiles) as (base, _):
            res, context = run_driver(DRIVER, ["--url", base, "--cameras", json.dumps([cam])])
        assert res["consoleErrors"] == [] and res["failedRequests"] == [], context
        view = res["views"][0]
        assert view["settled"]["loaded"] and any(t["leaf"] for t in view["tiles"]), context
        shots[name] = read_rgb(shot)
        results[name] = view
    a, b = shots["street_plain"], shots["street"]
    assert a.shape == b.shape
    plain_detail, textured_detail = detail_within_faces(a, b)
    (SHOTS / "street.json").write_text(
        json.dumps(
            {
                "camera": results["street"]["camera"],
                "tiles": [t["uri"] for t in results["street"]["tiles"]],
                "luminance_spread_within_faces": {"plain": plain_detail, "textured": textured_detail},
            },
            indent=1,
        )
    )
    assert textured_detail > 0.5 and textured_detail > 5 * plain_detail, (plain_detail, textured_detail)
