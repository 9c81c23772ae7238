"""benchmarks.view_saliency: projection of known points, the frustum against the one api.lod_for_view culls with
(core.camera.Camera.planes), the vertical view angle of known geometry, the ROI distance against the
exact Euclidean distance, the saliency splat, and the camera path (>= 100 frames, deterministic, on target)."""

import math

import numpy as np
import pytest
from scipy import ndimage

from benchmarks import view_saliency as vs
from core.camera import Camera
from core.geodesy import ecef_to_geodetic, enu_rotation

LON, LAT = 24.94, 60.17  # Helsinki
ENU = enu_rotation(math.radians(LON), math.radians(LAT))
GROUND = vs.ecef(LON, LAT, 0.0)


def enu(e: float, n: float, u: float) -> np.ndarray:
    """ECEF of a point east/north/up metres of the ground point at (LON, LAT) in its tangent plane."""
    return GROUND + ENU @ np.array([e, n, u], float)


def test_project_looking_straight_down() -> None:
    cam = Camera(LON, LAT, 500.0, 0.0, -90.0)
    w, h = vs.viewport(cam)
    f = vs.focal_px(cam)
    assert (w, h) == (1920, 1080)
    assert f == pytest.approx(1080 / (2 * math.tan(math.radians(30))))
    # heading 0 looking down: screen right is east, screen up is north
    x, y, depth = vs.project(cam, np.array([enu(0, 0, 0), enu(100, 0, 0), enu(0, 50, 0), enu(0, 0, 600)]))
    assert depth[:3] == pytest.approx([500.0] * 3, abs=1e-6)
    assert x[:3] == pytest.approx([w / 2, w / 2 + f * 100 / 500, w / 2], abs=1e-6)
    assert y[:3] == pytest.approx([h / 2, h / 2, h / 2 - f * 50 / 500], abs=1e-6)
    # above the camera is behind it
    assert depth[3] == pytest.approx(-100.0, abs=1e-6) and np.isnan(x[3]) and np.isnan(y[3])


def test_project_looking_east_level() -> None:
    cam = Camera(LON, LAT, 10.0, 90.0, 0.0)
    w, h = vs.viewport(cam)
    f = vs.focal_px(cam)
    x, y, depth = vs.project(cam, np.array([enu(200, 0, 60), enu(200, -30, 10)]))
    assert depth == pytest.approx([200.0, 200.0], abs=1e-3)
    # 50 m above the camera's eye height; 30 m to the south is to the right when looking east
    assert x == pytest.approx([w / 2, w / 2 + f * 30 / 200], abs=1e-3)
    assert y == pytest.approx([h / 2 - f * 50 / 200, h / 2], abs=1e-3)


def test_frustum_agrees_with_the_culling_planes() -> None:
    rng = np.random.default_rng(3)
    for heading, pitch in [(0.0, -90.0), (37.0, -30.0), (250.0, -5.0)]:
        cam = Camera(LON, LAT, 300.0, heading, pitch)
        pts = np.array([enu(*p) for p in rng.uniform([-3000, -3000, -200], [3000, 3000, 800], (4000, 3))])
        planes = cam.planes()
        inside = np.all((pts - cam.position()) @ planes.T > 0, axis=1)
        got = vs.in_frustum(cam, pts)
        # the planes' normals are exact, the pixel test closes at the viewport edges: only points within a
        # hair of a side plane may differ
        x, y, _ = vs.project(cam, pts)
        w, h = vs.viewport(cam)
        edge = (np.abs(x) < 1e-6) | (np.abs(x - w) < 1e-6) | (np.abs(y) < 1e-6) | (np.abs(y - h) < 1e-6)
        assert np.array_equal(got[~edge], inside[~edge])
        assert 10 < inside.sum() < len(pts)


def test_vertical_view_angle_known_geometry() -> None:
    cam = Camera(LON, LAT, 100.0, 0.0, -45.0)
    pts = np.array([enu(0, 100, 0), enu(0, 0, 0), enu(0, 300, 100), enu(0, 100 * math.sqrt(3), 0)])
    up = np.repeat(vs.geodetic_up(LON, LAT)[None], len(pts), axis=0)
    angle = vs.vertical_view_angle(cam, pts, up)
    # 100 m up over 100 m: 45°; straight below: 90°; at the camera's height: 0°; over 100 √3: 30°
    assert angle == pytest.approx([45.0, 90.0, 0.0, 30.0], abs=1e-3)


def test_screen_boxes_of_a_cylinder_from_above_and_from_the_side() -> None:
    down = Camera(LON, LAT, 400.0, 0.0, -90.0)
    f = vs.focal_px(down)
    up = vs.geodetic_up(LON, LAT)[None]
    boxes, depth = vs.screen_boxes(down, enu(0, 0, 0)[None], enu(0, 0, 100)[None], np.array([20.0]), up)
    assert depth[0] == pytest.approx(350.0, abs=1e-6)
    r = f * 20 / 350
    assert boxes[0] == pytest.approx([960 - r, 540 - r, 960 + r, 540 + r], abs=1e-6)
    side = Camera(LON, LAT, 50.0, 90.0, 0.0)
    boxes, _ = vs.screen_boxes(side, enu(200, 0, 0)[None], enu(200, 0, 100)[None], np.array([10.0]), up)
    f = vs.focal_px(side)
    # from the side the disc is flat: the box is the axis, 2 × 50 m high, widened by the radius
    assert boxes[0] == pytest.approx(
        [960 - f * 10 / 200, 540 - f * 50 / 200, 960 + f * 10 / 200, 540 + f * 50 / 200], abs=0.05
    )
    assert vs.box_visible(side, boxes, 4.0).tolist() == [True]
    assert vs.box_visible(side, boxes + [3000, 0, 3000, 0], 4.0).tolist() == [False]
    assert vs.box_visible(side, boxes, 1e4).tolist() == [False]


def test_roi_disc_seen_from_above_is_a_circle() -> None:
    cam = Camera(LON, LAT, 500.0, 0.0, -90.0)
    width = 192
    mask = vs.roi_disc_mask(cam, width, GROUND, vs.geodetic_up(LON, LAT), 100.0)
    assert mask.shape == (108, 192)
    r = vs.focal_px(cam) * width / 1920 * 100 / 500  # radius in grid pixels
    assert mask.sum() == pytest.approx(math.pi * r * r, rel=0.05)
    yy, xx = np.nonzero(mask)
    assert (xx.mean(), yy.mean()) == pytest.approx((width / 2 - 0.5, 54 - 0.5), abs=0.5)
    # the disc behind the camera is not seen
    assert not vs.roi_disc_mask(
        Camera(LON, LAT, 500.0, 0.0, 30.0), width, GROUND, vs.geodetic_up(LON, LAT), 100.0
    ).any()


def test_roi_distance_is_the_euclidean_distance_to_the_roi() -> None:
    mask = np.zeros((40, 64), bool)
    yy, xx = np.indices(mask.shape)
    mask |= (xx - 20) ** 2 + (yy - 15) ** 2 <= 36  # a disc
    mask[30:33, 50:60] = True  # and a bar
    got = vs.roi_distance_map(mask)
    exact = ndimage.distance_transform_edt(~mask)
    assert got[mask].max() == 0
    # JFA+1 on a grid this small is exact but for a rare pixel, and then by less than a pixel
    assert np.mean(np.abs(got - exact) < 1e-9) > 0.99
    assert np.abs(got - exact).max() < 1.0
    assert np.isinf(vs.roi_distance_map(np.zeros((5, 7), bool))).all()


def test_frame_metrics_on_a_synthetic_scene() -> None:
    cam = Camera(LON, LAT, 600.0, 0.0, -90.0)
    # four features: on the ROI centre, 300 m east (outside the 100 m ROI), 300 m north and tall, far away
    pts = np.array([enu(0, 0, 0), enu(300, 0, 0), enu(0, 300, 0), enu(9000, 0, 0)])
    geo = ecef_to_geodetic(pts)
    lon, lat = np.degrees(geo[:, 0]), np.degrees(geo[:, 1])
    m = vs.frame_metrics(
        cam,
        lon,
        lat,
        geo[:, 2],
        np.array([10.0, 10.0, 200.0, 10.0]),
        np.array([10.0, 10.0, 10.0, 10.0]),
        GROUND,
        100.0,
        grid_width=384,
        min_px=4.0,
    )
    assert m.visible.tolist() == [True, True, True, False]
    assert np.isnan(m.interest[3]) and np.isnan(m.distance_n[3])
    assert m.roi_n[0] == 0.0 and m.roi_px[0] == 0.0
    # outside the disc: the distance to it on screen, 300 - 100 m at 600 m depth, within a grid pixel
    f = vs.focal_px(cam)
    assert m.roi_px[1] == pytest.approx(f * 200 / 600, abs=1.5 / m.scale)
    assert m.roi_px[2] == pytest.approx(m.roi_px[1], abs=1.5 / m.scale)
    # the tall one is nearest to the camera, the normalized distances peak at 1
    assert np.nanmax(m.distance_n) == 1.0 and m.distance_n[2] < m.distance_n[1]
    assert m.angle_deg[0] == pytest.approx(90.0, abs=1e-6) and m.angle_deg[1] < 90.0
    assert np.all((m.interest[:3] >= 0) & (m.interest[:3] <= 1))
    assert m.interest[0] > m.interest[1]


def test_normalize_interest_and_lod_weight() -> None:
    v = np.array([1.0, 2.0, 4.0, np.inf, np.nan])
    out = vs.normalize_by_max(v)
    assert out[:4].tolist() == [0.25, 0.5, 1.0, 1.0] and np.isnan(out[4])
    assert vs.normalize_by_max(v, np.array([True, True, False, False, False]))[:3].tolist() == [0.5, 1.0, 1.0]
    assert vs.normalize_by_max(np.zeros(3)).tolist() == [0.0, 0.0, 0.0]
    assert vs.interest(np.array([0.0, 1.0]), np.array([0.0, 1.0]), np.array([0.0, 1.0])).tolist() == [1.0, 0.0]
    assert vs.interest(0.5, 1.0, 0.0, weights=(2.0, 0.0, 2.0)) == pytest.approx(0.75)
    with pytest.raises(ValueError):
        vs.interest(0, 0, 0, weights=(0.0, 0.0, 0.0))
    assert vs.lod_weight(np.array([0, 1, 2, 3])).tolist() == [0.25, 0.5, 0.75, 1.0]


def test_splat_nearest_wins() -> None:
    boxes = np.array([[0, 0, 10, 10], [5, 5, 20, 8], [30.2, 4.1, 30.4, 4.3], [np.nan] * 4, [-50, -50, -40, -40]])
    depth = np.array([100.0, 50.0, 10.0, 1.0, 1.0])
    values = np.array([0.1, 0.9, 0.5, 0.7, 0.3])
    sal, owner = vs.splat(boxes, depth, values, 40, 12)
    assert sal.shape == owner.shape == (12, 40)
    assert owner[2, 2] == 0 and sal[2, 2] == pytest.approx(0.1)
    assert owner[6, 7] == 1 and owner[6, 15] == 1  # box 1 is nearer where they overlap
    assert owner[9, 7] == 0
    assert owner[4, 30] == 2  # a box between pixel centres gets the pixel of its centre
    assert np.isnan(sal[11, 39]) and owner[11, 39] == -1
    assert set(np.unique(owner)) == {-1, 0, 1, 2}
    # scaled to a grid of half the resolution
    _, half = vs.splat(boxes, depth, values, 20, 6, scale=0.5)
    assert half[1, 1] == 0 and half[3, 5] == 1


def test_camera_path_is_deterministic_on_target_and_long_enough() -> None:
    a = vs.camera_path(LON, LAT, 800.0, 150.0, 4000.0)
    b = vs.camera_path(LON, LAT, 800.0, 150.0, 4000.0)
    assert len(a) >= 100 and a == b
    d = np.array([p.distance_m for p in a])
    assert d.min() == pytest.approx(150.0, rel=1e-6) and d.max() == pytest.approx(4000.0, rel=1e-3)
    pitch = np.array([p.camera.pitch for p in a])
    assert -75.5 < pitch.min() < -70 and -12.5 < pitch.max() <= -11.5
    assert min(p.camera.height for p in a) >= 25.0 - 1e-6
    headings = np.unwrap(np.radians([p.camera.heading for p in a]))
    assert abs(headings[-1] - headings[0]) > math.radians(330)  # one turn around the city
    for p in a[::7]:
        x, y, depth = vs.project(p.camera, vs.ecef(p.target_lon, p.target_lat, p.target_h)[None])
        assert (x[0], y[0]) == pytest.approx((960.0, 540.0), abs=1e-3)
        assert depth[0] == pytest.approx(p.distance_m, rel=1e-6)
    # the focus stays over the city
    t = np.array([[p.target_lon, p.target_lat] for p in a])
    assert np.abs(t - [LON, LAT]).max() < 0.01
    with pytest.raises(ValueError):
        vs.camera_path(LON, LAT, 800.0, 500.0, 100.0)
