"""Footprint simplification (etl/generalize/simplify.py): vertex importance, the Sester–Brenner rules, curves, area and
validity fallbacks, holes, multipolygons, pinned shared walls, and a 10,000-footprint batch. All shapes sit at
UTM-sized coordinates.

Hausdorff bounds: a Sester–Brenner replacement or a vertex removal is only taken if it moves the outline by at
most the tolerance, measured against the original vertices, so the rule shapes below are held to the exact
distance their feature moves (the step height, the notch depth, half the chamfer). The random batch is held
to 1.05 x tolerance: the check is exact at every vertex, and along an original edge next to a corner made in
an earlier pass only at its ends (see the module docstring; measured <= 1.00 x on these footprints)."""

import math

import numpy as np
import pytest
import shapely

import etl.generalize.simplify as simplify
from etl.generalize.simplify import Simplified, _importance, _verdict, simplify_footprints

OFF = np.array([385_000.0, 6_672_000.0])  # UTM-sized coordinates, where precision matters
TOL = 1.0


def utm(g: shapely.Geometry) -> shapely.Geometry:
    return shapely.affinity.translate(g, *OFF)


def local(g: shapely.Geometry) -> shapely.Geometry:
    return shapely.affinity.translate(g, *-OFF)


def run(*shapes: shapely.Geometry, tolerance: float | np.ndarray = TOL, **kw) -> Simplified:
    return simplify_footprints(np.array([utm(s) for s in shapes], dtype=object), tolerance, **kw)


def same_shape(a: shapely.Geometry, b: shapely.Geometry, tol: float = 1e-6) -> bool:
    """Same (multi)polygon with the same vertices up to tol, whatever the start vertex and orientation."""
    a, b = (shapely.MultiPolygon([g]) if isinstance(g, shapely.Polygon) else g for g in (a, b))
    return bool(shapely.equals_exact(shapely.normalize(a), shapely.normalize(b), tolerance=tol))


def ring_angles(geoms: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Interior-side angle (degrees, 0..180 between the two edges) at every vertex, and its footprint index."""
    parts, owner = shapely.get_parts(geoms, return_index=True)
    rings, ring_part = shapely.get_rings(parts, return_index=True)
    xy, ci = shapely.get_coordinates(rings, return_index=True)
    cnt = np.bincount(ci, minlength=len(rings))
    keep = np.ones(len(xy), dtype=bool)
    keep[np.cumsum(cnt) - 1] = False  # closing vertex
    xy, ci, cnt = xy[keep], ci[keep], cnt - 1
    start = np.cumsum(cnt) - cnt
    row = np.arange(len(xy))
    loc = row - start[ci]
    nxt = np.where(loc == cnt[ci] - 1, start[ci], row + 1)
    prv = np.where(loc == 0, start[ci] + cnt[ci] - 1, row - 1)
    a, b = xy[prv] - xy, xy[nxt] - xy
    ang = np.degrees(np.abs(np.arctan2(a[:, 0] * b[:, 1] - a[:, 1] * b[:, 0], (a * b).sum(1))))
    return ang, owner[ring_part[ci]]


def off_right_angle(geoms: np.ndarray) -> np.ndarray:
    """Per footprint: how many vertices are not within 1 degree of a right angle."""
    ang, owner = ring_angles(geoms)
    return np.bincount(owner[np.abs(ang - 90) > 1], minlength=len(geoms))


def vertices(g: shapely.Geometry) -> set[tuple[float, float]]:
    return set(map(tuple, shapely.get_coordinates(g)))


# --- vertex importance (Algorithm 1) ------------------------------------------------------------------------


def test_importance_is_turning_angle_times_edge_lengths() -> None:
    prev = np.array([[0.0, 0.0], [0.0, 0.0], [0.0, 0.0], [0.0, 0.0]])
    cur = np.array([[2.0, 0.0], [2.0, 0.0], [2.0, 0.0], [2.0, 0.0]])
    nxt = np.array([[5.0, 0.0], [2.0, 3.0], [2.0, -3.0], [2.0 + 3 / math.sqrt(2), 3 / math.sqrt(2)]])
    imp, turn, lin, lout = _importance(prev, cur, nxt)
    np.testing.assert_allclose(turn, [0.0, math.pi / 2, math.pi / 2, math.pi / 4], atol=1e-12)
    np.testing.assert_allclose(imp, [0.0, math.pi / 2 * 6, math.pi / 2 * 6, math.pi / 4 * 6], atol=1e-12)
    np.testing.assert_allclose(lin, 2.0)
    np.testing.assert_allclose(lout, 3.0)


def test_least_important_vertex_goes_first_until_the_next_would_move_the_outline_too_far() -> None:
    # Two shallow bumps: 0.4 m on the bottom wall, 2 m on the top wall. With a 1 m tolerance the 0.4 m bump is
    # the least important vertex and goes; then the 2 m bump is the least important (the corners are kept
    # walls) and would move the outline by 2 m > 1 m, so the ring stops there.
    bumps = shapely.Polygon([(0, 0), (10, -0.4), (20, 0), (20, 10), (10, 12), (0, 10)])
    r = run(bumps, tolerance=1.0)
    assert r.status[0] == "simplified"
    assert (r.n_vertices_in[0], r.n_vertices_out[0]) == (6, 5)
    out = vertices(local(r.geoms[0]))
    assert (10.0, 12.0) in out and not any(abs(y + 0.4) < 1e-9 for _, y in out)
    assert r.hausdorff[0] == pytest.approx(0.4, abs=1e-6)
    # The tolerance is in metres: 0.3 m keeps both bumps, 2.5 m removes both (-24 m², 10.7 %).
    assert run(bumps, tolerance=0.3).status[0] == "unchanged"
    r = run(bumps, tolerance=2.5, max_area_change=0.2)
    assert r.n_vertices_out[0] == 4 and same_shape(local(r.geoms[0]), shapely.box(0, 0, 20, 10))


def test_removal_errors_do_not_pile_up() -> None:
    # A wobbly top wall. Each removal measured only by the removed vertex's distance to its neighbours' chord
    # would straighten the whole wall to y ~ 10 and leave (4.6, 11.2) 1.23 m off; measured against every
    # original vertex removed between the neighbours, the simplification stops while all stay within 1 m.
    wobbly = shapely.Polygon(
        [
            (0, 0),
            (30, 0),
            (30, 10),
            (29.8, 9.8),
            (27.7, 9.6),
            (20.9, 9.5),
            (17.7, 10.1),
            (11.8, 10.4),
            (4.6, 11.2),
            (4.1, 10.8),
            (0, 10),
        ]
    )
    r = run(wobbly)
    assert r.status[0] == "simplified" and r.n_vertices_out[0] < r.n_vertices_in[0]
    dist = shapely.distance(shapely.points(shapely.get_coordinates(utm(wobbly))), r.geoms[0].boundary)
    assert dist.max() <= TOL and r.hausdorff[0] <= TOL


def test_collinear_vertices_have_no_importance() -> None:
    sq = shapely.Polygon([(0, 0), (5, 0), (10, 0), (10, 5), (10, 10), (3, 10), (0, 10), (0, 4)])
    r = run(sq, tolerance=0.01)
    assert r.n_vertices_out[0] == 4 and r.hausdorff[0] == pytest.approx(0.0, abs=1e-9)
    assert same_shape(local(r.geoms[0]), shapely.box(0, 0, 10, 10))


def test_rings_never_go_below_three_vertices() -> None:
    # A 2 m square with a 5 m tolerance: every vertex is within tolerance of its chord.
    r = run(shapely.box(0, 0, 2, 2), tolerance=5.0, max_area_change=1.0)
    assert r.n_vertices_out[0] == 3
    assert shapely.is_valid(r.geoms[0]) and r.status[0] == "simplified"


# --- Sester–Brenner ----------------------------------------------------------------------------------------

L_STEP = shapely.Polygon([(0, 0), (14, 0), (14, -0.8), (30, -0.8), (30, 10), (10, 10), (10, 25), (0, 25)])
NOTCH = shapely.Polygon([(0, 0), (20, 0), (20, 10), (10.5, 10), (10.5, 9.5), (9.5, 9.5), (9.5, 10), (0, 10)])
BAY = shapely.Polygon([(0, 0), (9.5, 0), (9.5, -0.5), (10.5, -0.5), (10.5, 0), (20, 0), (20, 10), (0, 10)])
STAIRS = shapely.Polygon(
    [(0, 0), (10, 0), (10, 0.3), (10.3, 0.3), (10.3, 0.6), (10.6, 0.6), (10.6, 0.9), (20, 0.9), (20, 10), (0, 10)]
)
CHAMFER = shapely.Polygon([(0, 0), (20, 0), (20, 9.4), (19.4, 10), (0, 10)])
RECT = shapely.box(0, 0, 20, 10)

#: name: (shape, tolerance, expected result, expected Hausdorff = how far the feature moves)
RULES = {
    # offset: the 14 m wall is shorter than the 16 m one, so it goes and the 16 m wall is extended to x = 0
    "L with 0.8 m step": (
        L_STEP,
        1.0,
        shapely.Polygon([(0, -0.8), (30, -0.8), (30, 10), (10, 10), (10, 25), (0, 25)]),
        0.8,
    ),
    # 1 m x 0.5 m notch; at 1.0 m its 1 m edge is not short (two one-edge runs), at 1.2 m it is one run of three
    "notch 1 x 0.5, tol 1.0": (NOTCH, 1.0, RECT, 0.5),
    "notch 1 x 0.5, tol 1.2": (NOTCH, 1.2, RECT, 0.5),
    "bay 1 x 0.5": (BAY, 1.2, RECT, 0.5),
    # three 0.3 m steps, 0.9 m in all: one run of five short edges between two parallel walls
    "staircase facade": (STAIRS, 1.0, RECT, 0.9),
    # 0.85 m cut corner between orthogonal walls: extended to their intersection, 0.6 / sqrt 2 away
    "chamfered corner": (CHAMFER, 1.0, RECT, 0.6 / math.sqrt(2)),
}


@pytest.mark.parametrize("name", list(RULES))
def test_sester_brenner_rules_keep_right_angles(name: str) -> None:
    shape, tol, expected, moved = RULES[name]
    r = run(shape, tolerance=tol)
    assert r.status[0] == "simplified"
    out = r.geoms[0]
    assert isinstance(out, shapely.MultiPolygon) and shapely.is_valid(out)
    assert same_shape(local(out), expected), local(out).wkt
    assert off_right_angle(r.geoms)[0] == 0  # every corner within 1 degree of 90 / 270
    assert r.n_vertices_out[0] == len(expected.exterior.coords) - 1 < r.n_vertices_in[0]
    assert r.hausdorff[0] == pytest.approx(moved, abs=1e-6) and r.hausdorff[0] <= tol
    assert abs(r.area_out[0] - r.area_in[0]) <= 0.1 * r.area_in[0]
    assert r.area_in[0] == pytest.approx(shape.area) and r.area_out[0] == pytest.approx(expected.area)


def test_narrow_spike_and_long_features_are_kept() -> None:
    # A 0.5 m wide, 3 m deep spike: its short end lies between antiparallel walls, removing it would move the
    # outline by 3 m; a 2 m x 2 m bay is no detail at 1 m. Both stay, right angles and all.
    spike = shapely.Polygon([(0, 0), (20, 0), (20, 10), (10.5, 10), (10.5, 13), (10, 13), (10, 10), (0, 10)])
    bay = shapely.Polygon([(0, 0), (9, 0), (9, -2), (11, -2), (11, 0), (20, 0), (20, 10), (0, 10)])
    r = run(spike, bay)
    assert list(r.status) == ["unchanged", "unchanged"]
    assert same_shape(local(r.geoms[0]), spike) and same_shape(local(r.geoms[1]), bay)


# --- curves ------------------------------------------------------------------------------------------------


def test_round_tower_becomes_a_few_segments() -> None:
    tower = shapely.Point(0, 0).buffer(10, quad_segs=8)  # 32 vertices
    r = run(tower)
    assert r.n_vertices_in[0] == 32
    assert r.status[0] == "simplified" and 6 <= r.n_vertices_out[0] <= 8
    assert r.hausdorff[0] <= TOL
    assert abs(r.area_out[0] - r.area_in[0]) <= 0.1 * r.area_in[0]


def test_rounded_side_becomes_a_few_segments() -> None:
    # A 20 x 10 rectangle whose right side is a half circle of 17 vertices (16 edges of 0.98 m: all short,
    # between antiparallel walls, so this is vertex importance's job).
    arc = [(20 + 5 * math.sin(a), 5 - 5 * math.cos(a)) for a in np.linspace(0, math.pi, 17)]
    rounded = shapely.Polygon([(0, 0), *arc, (0, 10)])
    r = run(rounded)
    assert r.n_vertices_in[0] == 19 and r.status[0] == "simplified"
    out = shapely.get_coordinates(local(r.geoms[0]))[:-1]
    assert (out[:, 0] > 20 + 1e-9).sum() <= 4  # the arc: at most 5 segments
    assert {(0.0, 0.0), (0.0, 10.0)} <= set(map(tuple, out))
    assert r.hausdorff[0] <= TOL
    assert abs(r.area_out[0] - r.area_in[0]) <= 0.1 * r.area_in[0]


# --- area, validity, empty, holes, multipolygons ------------------------------------------------------------


def test_area_change_beyond_the_limit_keeps_the_original() -> None:
    tower = shapely.Point(0, 0).buffer(10, quad_segs=8)  # the 8-gon loses 9.4 % of the area
    r = run(tower, max_area_change=0.05)
    assert r.status[0] == "kept_original: area changed by 9% (limit 5%)"
    assert same_shape(local(r.geoms[0]), shapely.MultiPolygon([tower]), tol=1e-9)
    assert r.n_vertices_out[0] == r.n_vertices_in[0] == 32
    assert r.area_out[0] == r.area_in[0] and r.hausdorff[0] == 0.0
    assert run(tower, max_area_change=0.1).status[0] == "simplified"


def test_invalid_result_keeps_the_original() -> None:
    # Removing the 0.9 m bump on the top wall pulls the wall through the courtyard below it.
    court = [(8, 9.5), (12, 9.5), (12, 10.5), (8, 10.5)]
    g = shapely.Polygon([(0, 0), (20, 0), (20, 10), (10, 10.9), (0, 10)], [court])
    r = run(g)
    assert r.status[0].startswith("kept_original: invalid result: Self-intersection")
    assert same_shape(local(r.geoms[0]), shapely.MultiPolygon([g]), tol=1e-9)
    assert shapely.is_valid(r.geoms[0])


def test_verdict_reasons() -> None:
    result = np.array(
        [
            shapely.MultiPolygon(),
            shapely.box(0, 0, 1, 1),
            utm(shapely.box(0, 0, 1, 1)),
            shapely.Polygon([(0, 0), (2, 2), (2, 0), (0, 2)]),
        ],
        dtype=object,
    )
    changed = np.array([True, True, False, True])
    area_in = np.array([5.0, 1.3, 1.0, 4.0])
    failed, why = _verdict(changed, result, area_in, shapely.area(result), 0.1)
    assert list(failed) == [True, True, False, True]
    assert why[0] == "empty result"
    assert why[1] == "area changed by 23% (limit 10%)"
    assert why[3].startswith("invalid result: Self-intersection")


def test_holes_are_simplified_and_tiny_holes_dropped() -> None:
    courtyard = [(10, 10), (10, 30), (19.5, 30), (19.5, 30.5), (20.5, 30.5), (20.5, 30), (30, 30), (30, 10)]
    tiny = [(35, 35), (35, 35.5), (35.5, 35.5), (35.5, 35)]  # 0.25 m² < 1 m²
    g = shapely.Polygon([(0, 0), (40, 0), (40, 40), (0, 40)], [courtyard, tiny])
    r = run(g)
    assert r.status[0] == "simplified; dropped 1 holes below tolerance²"
    assert (r.n_vertices_in[0], r.n_vertices_out[0]) == (16, 8)
    expected = shapely.Polygon(shapely.box(0, 0, 40, 40).exterior, [shapely.box(10, 10, 30, 30).exterior.coords])
    assert same_shape(local(r.geoms[0]), shapely.MultiPolygon([expected]))
    assert r.geoms[0].geoms[0].interiors[0].is_ccw is False and r.geoms[0].geoms[0].exterior.is_ccw
    # The dropped hole counts in the measured error: its corner (35, 35) is 5 m from the exterior wall x = 40.
    assert r.hausdorff[0] == pytest.approx(5.0, abs=1e-6)


def test_multipolygon_parts_are_simplified_separately() -> None:
    chamfered = shapely.Polygon([(0, 0), (10, 0), (10, 5), (9.5, 5.5), (0, 5.5)])
    mp = shapely.MultiPolygon([chamfered, shapely.Point(30, 0).buffer(10, quad_segs=8)])
    r = run(mp)
    assert r.status[0] == "simplified"
    out = r.geoms[0]
    assert isinstance(out, shapely.MultiPolygon) and len(out.geoms) == 2 and shapely.is_valid(out)
    assert same_shape(local(out.geoms[0]), shapely.box(0, 0, 10, 5.5))
    assert len(out.geoms[1].exterior.coords) - 1 <= 8
    assert r.n_vertices_in[0] == 5 + 32 and r.n_vertices_out[0] == 4 + len(out.geoms[1].exterior.coords) - 1
    assert r.hausdorff[0] <= TOL


# --- neighbours (Sester–Brenner rule 3) ----------------------------------------------------------------------

# Two houses sharing a wall x = 10 .. 10.5 with a 0.5 m step at y = 4; the left one has a chamfered corner.
LEFT = shapely.Polygon([(0, 0), (10, 0), (10, 4), (10.5, 4), (10.5, 10), (0.6, 10), (0, 9.4)])
RIGHT = shapely.Polygon([(10, 0), (20, 0), (20, 10), (10.5, 10), (10.5, 4), (10, 4)])
WALL = [(10, 0), (10, 4), (10.5, 4), (10.5, 10)]


def test_shared_wall_is_pinned_by_the_neighbour() -> None:
    g = np.array([utm(LEFT), utm(RIGHT)], dtype=object)
    fixed = np.array([g[1].boundary, g[0].boundary], dtype=object)
    r = simplify_footprints(g, TOL, fixed=fixed)
    assert list(r.status) == ["simplified", "unchanged"]
    wall = {tuple(np.array(p) + OFF) for p in WALL}
    assert wall <= vertices(r.geoms[0]) and wall <= vertices(r.geoms[1])  # exactly, bit for bit
    assert same_shape(local(r.geoms[0]), shapely.Polygon([(0, 0), *WALL, (0, 10)]))  # chamfer gone, step kept
    shared = shapely.intersection(r.geoms[0].boundary, r.geoms[1].boundary)
    assert shared.length == pytest.approx(10.5, abs=1e-9)
    assert shapely.intersection(r.geoms[0], r.geoms[1]).area < 1e-9
    # Without the neighbour the 0.5 m step is a detail like any other and goes.
    alone = simplify_footprints(g, TOL)
    assert not wall <= vertices(alone.geoms[0])


def test_pinned_vertices_are_never_removed_or_moved() -> None:
    # A fixed geometry touching one end of the chamfer: the chamfer cannot be replaced by the corner.
    g = np.array([utm(CHAMFER), utm(CHAMFER)], dtype=object)
    fixed = np.array([utm(shapely.Point(20, 9.4)), None], dtype=object)
    r = simplify_footprints(g, TOL, fixed=fixed)
    assert r.status[0] == "unchanged" and r.n_vertices_out[0] == 5
    assert tuple(np.array([20, 9.4]) + OFF) in vertices(r.geoms[0])
    assert r.status[1] == "simplified" and r.n_vertices_out[1] == 4


# --- inputs ------------------------------------------------------------------------------------------------


def test_zero_tolerance_per_footprint_tolerance_and_empty_inputs() -> None:
    g = np.array([utm(NOTCH), utm(NOTCH), None, shapely.Polygon()], dtype=object)
    r = simplify_footprints(g, np.array([0.0, 1.0, 1.0, 1.0]))
    assert list(r.status) == ["unchanged", "simplified", "unchanged", "unchanged"]
    assert same_shape(local(r.geoms[0]), shapely.MultiPolygon([NOTCH]), tol=1e-9)
    assert all(isinstance(x, shapely.MultiPolygon) for x in r.geoms)
    assert r.geoms[2].is_empty and r.geoms[3].is_empty
    assert list(r.n_vertices_in) == [8, 8, 0, 0] and list(r.n_vertices_out) == [8, 4, 0, 0]
    with pytest.raises(ValueError):
        simplify_footprints(g, -1.0)
    with pytest.raises(TypeError):
        simplify_footprints(np.array([shapely.LineString([(0, 0), (1, 1)])]), 1.0)


def test_results_do_not_depend_on_the_coordinate_offset() -> None:
    shapes = [L_STEP, NOTCH, STAIRS, CHAMFER, shapely.Point(0, 0).buffer(10, quad_segs=8)]
    near = simplify_footprints(np.array(shapes, dtype=object), TOL)
    far = run(*shapes)
    assert list(near.status) == list(far.status)
    assert list(near.n_vertices_out) == list(far.n_vertices_out)
    for a, b in zip(near.geoms, far.geoms, strict=True):
        assert same_shape(a, local(b), tol=1e-6)


# --- batch ------------------------------------------------------------------------------------------------


def orthogonal_footprints(n: int, seed: int) -> np.ndarray:
    """Random-ish orthogonal buildings: rectangles, L/T wings (often with a small step where the wing nearly
    continues a wall), notches, chamfered corners, small bays; rotated, at UTM coordinates."""
    rng = np.random.default_rng(seed)
    w, h = rng.uniform(6, 30, n), rng.uniform(6, 20, n)
    geoms = shapely.box(0, 0, w, h)
    ww, wh = rng.uniform(3, 12, n), rng.uniform(3, 10, n)
    wx = np.where(rng.random(n) < 0.5, rng.uniform(-1.0, 1.0, n), rng.uniform(0, w - 3))
    geoms = np.where(rng.random(n) < 0.6, shapely.union(geoms, shapely.box(wx, h - 0.5, wx + ww, h + wh)), geoms)
    nx, nw, nd = rng.uniform(1, w - 2), rng.uniform(0.3, 1.5, n), rng.uniform(0.2, 1.0, n)
    geoms = np.where(rng.random(n) < 0.4, shapely.difference(geoms, shapely.box(nx, -1, nx + nw, nd)), geoms)
    c, z = rng.uniform(0.3, 0.9, n), np.zeros(n)
    corner = shapely.polygons(np.stack([np.stack(p, 1) for p in [(w - c, z), (w + 1, z), (w + 1, c + 1), (w, c)]], 1))
    geoms = np.where(rng.random(n) < 0.3, shapely.difference(geoms, corner), geoms)
    bay = shapely.box(w - 0.01, 2, w + rng.uniform(0.3, 1.2, n), 2 + rng.uniform(0.5, 3, n))
    geoms = np.where(rng.random(n) < 0.3, shapely.union(geoms, bay), geoms)
    geoms = shapely.normalize(shapely.simplify(geoms, 0))  # no collinear vertices left from the unions
    xy, idx = shapely.get_coordinates(geoms, return_index=True)
    a = rng.uniform(0, np.pi, n)[idx]
    rot = np.stack([xy[:, 0] * np.cos(a) - xy[:, 1] * np.sin(a), xy[:, 0] * np.sin(a) + xy[:, 1] * np.cos(a)], 1)
    return shapely.set_coordinates(geoms.copy(), rot + (OFF + rng.uniform(0, 5000, (n, 2)))[idx])


def test_noisy_outlines_stay_within_the_tolerance() -> None:
    # Jagged random outlines (40 noisy radii, some rounded by a buffer) are where a corner made by one pass and
    # an original edge running past it meet: the error is measured at that edge's bisector crossings, which
    # holds it to the tolerance (without: 1.04 x here). 1.02: the measured worst case over other seeds.
    rng = np.random.default_rng(2)
    n = 2000
    ang = np.sort(rng.uniform(0, 2 * np.pi, (n, 40)), axis=1)
    rad = rng.uniform(5, 20, (n, 1)) * (1 + 0.15 * rng.standard_normal((n, 40)))
    xy = np.stack([rad * np.cos(ang), rad * np.sin(ang)], -1) + rng.uniform(0, 3000, (n, 1, 2)) + OFF
    g = shapely.make_valid(shapely.polygons(xy))
    g = np.where(rng.random(n) < 0.3, shapely.buffer(g, 1.0, quad_segs=8), g)
    g = g[np.isin(shapely.get_type_id(g), (3, 6)) & ~shapely.is_empty(g)]
    r = simplify_footprints(g, 3.0, max_area_change=1.0)
    assert shapely.is_valid(r.geoms).all() and (r.n_vertices_out < r.n_vertices_in).mean() > 0.9
    assert r.hausdorff.max() <= 1.02 * 3.0


def test_batch_of_10000_footprints(monkeypatch: pytest.MonkeyPatch) -> None:
    g = orthogonal_footprints(10_000, seed=1)
    assert shapely.is_valid(g).all()
    # Count the Python-level iterations: one vertex-importance evaluation per iteration, one call per pass.
    calls = {"importance": 0, "passes": 0}
    importance, sb_pass = simplify._importance, simplify._sester_brenner_pass

    def count_importance(*a):
        calls["importance"] += 1
        return importance(*a)

    def count_pass(*a):
        calls["passes"] += 1
        return sb_pass(*a)

    monkeypatch.setattr(simplify, "_importance", count_importance)
    monkeypatch.setattr(simplify, "_sester_brenner_pass", count_pass)
    r = simplify_footprints(g, TOL)
    assert calls["importance"] <= r.n_vertices_in.max() and calls["passes"] <= simplify.MAX_PASSES

    assert all(isinstance(x, shapely.MultiPolygon) for x in r.geoms) and shapely.is_valid(r.geoms).all()
    status = np.array([s.split(":")[0] for s in r.status])
    assert set(status) <= {"simplified", "unchanged", "kept_original"}
    assert (status == "simplified").sum() > 5_000  # most have a step, notch, chamfer or bay below 1 m
    assert (r.n_vertices_out <= r.n_vertices_in).all()
    assert (r.hausdorff <= 1.05 * TOL).all()
    ok = status == "simplified"
    assert (np.abs(r.area_out - r.area_in)[ok] <= 0.1 * r.area_in[ok]).all()
    np.testing.assert_allclose(r.area_out, shapely.area(r.geoms))
    # Footprints that were all right angles still are.
    orthogonal = off_right_angle(g) == 0
    assert orthogonal.sum() > 5_000 and (off_right_angle(r.geoms)[orthogonal] == 0).all()
