"""core/camera.py: the screen-space-error rule and its inverse (the SQL copy is tested in
tests/db/test_camera_sql.py)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from core.camera import Camera, distance_for_pixels, pixels_per_metre, screen_space_error


def test_distance_for_pixels_inverts_the_rule() -> None:
    d = distance_for_pixels(np.array([1.0, 12.5, 300.0]), 16.0, math.radians(60), 1080)
    np.testing.assert_allclose(screen_space_error(np.array([1.0, 12.5, 300.0]), d, math.radians(60), 1080), 16.0)
    # a metre at the focal length spans one pixel
    cam = Camera(24.9, 60.2, 100, 0, -30, fov=45, viewport_height=900)
    assert pixels_per_metre(cam.focal_px(), math.radians(45), 900) == pytest.approx(1.0)
    assert cam.sse(10, 1000) == pytest.approx(10 * 900 / (1000 * 2 * math.tan(math.radians(22.5))))
