"""The screen-space-error rule is written once in Python (core/camera.py) and once in SQL
(sql/tiles/screen_space_error.sql); these tests hold the two against each other and against the definition."""

from __future__ import annotations

import json
import math

import numpy as np

from core.camera import screen_space_error


def test_sql_and_python_screen_space_error_agree(new_db, conn_of) -> None:
    rng = np.random.default_rng(16)
    n = 2000
    err = rng.uniform(0, 500, n)
    dist = np.concatenate([rng.uniform(0, 5e4, n - 3), [0.0, 1e-9, 1e-7]])  # the clamp included
    fov = rng.uniform(math.radians(10), math.radians(120), n)
    height = rng.integers(100, 4000, n).astype(float)
    conn = conn_of(new_db("camera_sql"))
    got = np.array(
        conn.execute(
            """SELECT tiles.screen_space_error(e, d, f, h)
           FROM unnest(%s::float8[], %s::float8[], %s::float8[], %s::float8[]) WITH ORDINALITY u(e, d, f, h, i)
           ORDER BY i""",
            (err.tolist(), dist.tolist(), fov.tolist(), height.tolist()),
        ).fetchall()
    )[:, 0]
    want = np.array([screen_space_error(e, d, f, h) for e, d, f, h in zip(err, dist, fov, height, strict=True)])
    # the same expression; PostgreSQL's tan() and numpy's may differ in the last bit
    np.testing.assert_allclose(got, want, rtol=1e-14)
    # and both are the definition: e × H / (d × 2 tan(fov / 2)), distances clamped at 1e-7 m
    ref = err * height / (np.maximum(dist, 1e-7) * 2 * np.tan(fov / 2))
    np.testing.assert_allclose(got, ref, rtol=1e-12)
    # the SQL function is inlined where api.lod_for_view calls it (a function call per tile visited otherwise)
    plan = json.dumps(
        conn.execute(
            """EXPLAIN (VERBOSE, FORMAT JSON)
           SELECT tiles.screen_space_error(geometric_error, x, y, level) FROM tiles.tile"""
        ).fetchone()[0]
    )
    assert "screen_space_error" not in plan and "tan(" in plan
