"""The reference traversal (tests/support/traverse.py) and the boxes it measures against: a far camera stops at the
root, a near one reaches a leaf, culling drops what is behind the camera, ADD keeps parents, REPLACE drops them."""

import math

import numpy as np
import pytest

from core.camera import Camera
from core.geodesy import box_distance, box_visible, geodetic_to_ecef, region_box
from exporter.tileset import TileRecord, build_tileset
from tests.support.traverse import select

D = math.radians
ROOT = (D(24.90), D(60.10), D(25.00), D(60.20), 0.0, 60.0)
A = (D(24.90), D(60.10), D(24.95), D(60.20), 0.0, 60.0)
B = (D(24.95), D(60.12), D(25.00), D(60.20), 0.0, 30.0)


def tileset(single_lod: bool = False) -> dict:
    return build_tileset(
        [
            TileRecord(0, 0, 0, False, ROOT, 20.0, "content/0/0/0.glb"),
            TileRecord(1, 0, 0, True, A, 0.0, "content/1/0/0.glb"),
            TileRecord(1, 1, 0, True, B, 0.0, "content/1/1/0.glb"),
        ],
        single_lod=single_lod,
    )


def test_region_box_bounds_the_region() -> None:
    box = region_box(np.array([ROOT]))[0]
    lon, lat = np.meshgrid(np.linspace(ROOT[0], ROOT[2], 11), np.linspace(ROOT[1], ROOT[3], 11))
    for h in (ROOT[4], ROOT[5]):
        for p in geodetic_to_ecef(lon.ravel(), lat.ravel(), np.full(lon.size, h)):
            assert box_distance(box, p) == 0.0
    # tight: 1 km above the top is about 1 km away
    top = geodetic_to_ecef(D(24.95), D(60.15), ROOT[5] + 1000)
    assert box_distance(box, top) == pytest.approx(1000, abs=5)
    axes = box[3:].reshape(3, 3)
    assert abs(axes[0] @ axes[1]) < 1e-6 and abs(axes[1] @ axes[2]) < 1e-6


def test_box_visible_by_planes() -> None:
    box = region_box(np.array([A]))[0]
    eye = geodetic_to_ecef(D(24.925), D(60.15), 5000.0)
    down = -eye / np.linalg.norm(eye)
    assert box_visible(box, eye, np.array([down]))
    assert not box_visible(box, eye, np.array([-down]))  # the box is wholly behind a camera looking up


def test_far_camera_draws_root_near_camera_reaches_leaf() -> None:
    far = Camera(24.95, 60.15, 200_000, 0, -90)
    assert [d.uri for d in select(tileset(), far)] == ["content/0/0/0.glb"]
    near = Camera(24.97, 60.16, 300, 0, -90)
    got = [d.uri for d in select(tileset(), near)]
    assert "content/1/1/0.glb" in got and "content/0/0/0.glb" not in got  # REPLACE: the root is gone
    assert "content/1/0/0.glb" not in got  # tile A is outside a downward view over B


def test_add_keeps_the_parent_and_sse_formula() -> None:
    near = Camera(24.97, 60.16, 300, 0, -90)
    got = select(tileset(single_lod=True), near)
    assert [d.uri for d in got] == ["content/1/1/0.glb"]  # ADD with an empty root: only the leaf has content
    cam = Camera(24.97, 60.16, 300, 0, -90, fov=60, viewport_height=1000)
    assert cam.sse(20.0, 100.0) == pytest.approx(20 * 1000 / (100 * 2 * math.tan(D(30))))


def test_camera_axes_are_orthonormal() -> None:
    d, r, u = Camera(24.9, 60.1, 100, 37, -20).axes()
    for v in (d, r, u):
        assert np.linalg.norm(v) == pytest.approx(1)
    assert abs(d @ r) < 1e-12 and abs(d @ u) < 1e-12 and u @ geodetic_to_ecef(D(24.9), D(60.1), 0) > 0
