"""etl.landmarks.saliency: measure normalization, relative height, shape distinctiveness, weighted saliency, the
Winter et al. voting hierarchy (known answers, invariants, degenerate inputs, a brute-force reference round),
view-dependent exaggeration and the displacement of the buildings an enlarged landmark would cover."""

import math

import numpy as np
import pytest
from scipy.spatial import Delaunay

from etl.landmarks.saliency import (
    displacement,
    exaggeration_intervals,
    exaggeration_scale,
    fill_descriptors,
    interval_arrays,
    neighbour_sums,
    normalize,
    promote,
    radius_neighbours,
    relative_height,
    saliency,
    shape_descriptors,
    shape_distinctiveness,
    voting_hierarchy,
)

OFF = np.array([385_000.0, 6_672_000.0])  # UTM-sized coordinates, where precision matters


def grid(n: int, spacing: float = 20.0) -> np.ndarray:
    """n x n centroids on a slightly irregular grid (regular grids make Delaunay ties)."""
    rng = np.random.default_rng(n)
    yy, xx = np.mgrid[0:n, 0:n]
    return OFF + np.column_stack([xx.ravel(), yy.ravel()]) * spacing + rng.uniform(-2, 2, (n * n, 2))


def csr(lists: list[list[int]]) -> tuple[np.ndarray, np.ndarray]:
    indptr = np.cumsum([0] + [len(x) for x in lists])
    indices = np.array([j for x in lists for j in x], dtype=np.int64)
    return indptr, indices


# --- normalize --------------------------------------------------------------------------------------------------


def test_normalize_range_nan_inf_and_constant() -> None:
    out = normalize(np.array([3.0, np.nan, 5.0, 4.0, np.inf, -np.inf]))
    assert out.min() >= 0 and out.max() <= 1
    assert out[1] == 0 and out[5] == 0 and out[4] == 1
    assert out[0] < out[3] < out[2]
    assert (normalize(np.full(10, 7.0)) == 0).all()
    assert normalize(np.array([])).shape == (0,)
    assert (normalize(np.array([np.nan, np.nan])) == 0).all()


def test_normalize_keeps_the_top_apart_and_ignores_low_slivers() -> None:
    v = np.append(np.arange(1.0, 201.0), np.zeros(1))  # one zero-area sliver below everything
    out = normalize(v)
    assert out[199] == 1 and np.all(np.diff(out[-12:-1]) > 0)  # the most salient stay ranked among themselves
    assert out[-1] == 0 and out[0] <= 0.01  # the sliver does not stretch the range


def test_normalize_keeps_a_lone_tower() -> None:
    v = np.append(np.full(150, 10.0), 120.0)  # 1st and 99th percentiles are both 10
    out = normalize(v)
    assert out[-1] == 1 and (out[:-1] == 0).all()


# --- neighbours, relative height, shape ------------------------------------------------------------------------


def test_radius_neighbours_matches_brute_force() -> None:
    rng = np.random.default_rng(3)
    xy = OFF + rng.uniform(0, 200, (150, 2))
    indptr, indices = radius_neighbours(xy, 25.0)
    d = np.linalg.norm(xy[:, None] - xy[None], axis=2)
    for i in range(len(xy)):
        expected = np.flatnonzero((d[i] <= 25.0) & (np.arange(len(xy)) != i))
        assert np.array_equal(np.sort(indices[indptr[i] : indptr[i + 1]]), expected)
    indptr, indices = radius_neighbours(np.zeros((0, 2)), 5.0)
    assert indptr.tolist() == [0] and len(indices) == 0


def test_neighbour_sums_in_blocks_equal_the_csr_lists() -> None:
    rng = np.random.default_rng(5)
    xy = OFF + rng.uniform(0, 300, (400, 2))
    xy[7] = xy[3]  # a duplicate point counts as a neighbour, not as itself
    vals = np.column_stack([rng.uniform(3, 40, 400), rng.normal(size=400)])
    indptr, indices = radius_neighbours(xy, 30.0)
    adj = np.zeros((400, 400))
    np.add.at(adj, (np.repeat(np.arange(400), np.diff(indptr)), indices), 1.0)
    for block in (1, 37, 4096):
        count, sums = neighbour_sums(xy, 30.0, vals, block=block)
        assert np.array_equal(count, np.diff(indptr))
        assert np.allclose(sums, adj @ vals)
    assert count[3] >= 1 and 7 in indices[indptr[3] : indptr[4]]
    h = vals[:, 0]
    assert np.allclose(relative_height(h, sums=(count, sums[:, 0])), relative_height(h, indptr, indices))
    desc = fill_descriptors(np.column_stack([vals, vals**2]))
    c2, s2 = neighbour_sums(xy, 30.0, np.column_stack([desc, desc**2]), block=50)
    assert np.allclose(shape_distinctiveness(desc, sums=(c2, s2)), shape_distinctiveness(desc, indptr, indices))
    c0, s0 = neighbour_sums(np.zeros((0, 2)), 5.0, np.zeros((0, 3)))
    assert c0.shape == (0,) and s0.shape == (0, 3)


def test_relative_height_flags_the_tower() -> None:
    xy = grid(7)
    h = np.full(len(xy), 12.0) + np.random.default_rng(0).uniform(-2, 2, len(xy))
    tower = 24  # the middle of the 7 x 7 grid
    h[tower] = 90.0
    rel = relative_height(h, *radius_neighbours(xy, 45.0))
    assert rel.argmax() == tower and rel[tower] > 6
    others = np.delete(rel, tower)
    assert others.max() < 1.5  # the others blend in (the tower only lowers its neighbours' ratios)


def test_relative_height_without_neighbours_ignores_self_loops_and_floors_the_mean() -> None:
    indptr, indices = csr([[0], [2], [1], []])  # 0: only itself; 3: nobody
    rel = relative_height(np.array([30.0, 10.0, 20.0, 50.0]), indptr, indices)
    np.testing.assert_allclose(rel, [1.0, 0.5, 2.0, 1.0])
    rel = relative_height(np.array([8.0, 0.0]), *csr([[1], [0]]), min_height=2.0)
    np.testing.assert_allclose(rel, [4.0, 0.0])


def test_shape_descriptors_of_known_shapes() -> None:
    d = shape_descriptors(
        area=np.array([np.pi, 2.0]),
        perimeter=np.array([2 * np.pi, 6.0]),
        mrr_area=np.array([4.0, 2.0]),
        n_vertices=np.array([64, 4]),
    )
    np.testing.assert_allclose(d[:, 0], [1.0, 4 * np.pi * 2 / 36])  # disc compactness 1
    np.testing.assert_allclose(d[:, 1], [np.pi / 4, 1.0])  # rectangle fills its rectangle
    np.testing.assert_allclose(d[:, 2], np.log([64, 4]))


def test_shape_distinctiveness_picks_the_round_building_among_boxes() -> None:
    xy = grid(6)
    n = len(xy)
    rng = np.random.default_rng(5)
    area = rng.uniform(90, 110, n)
    side = np.sqrt(area)
    perim = 4 * side * rng.uniform(1.0, 1.05, n)
    mrr = area * rng.uniform(1.0, 1.05, n)
    nv = np.full(n, 4)
    odd = 14
    perim[odd], mrr[odd], nv[odd] = 2 * np.sqrt(np.pi * area[odd]), area[odd] * 4 / np.pi, 48  # a rotunda
    desc = shape_descriptors(area, perim, mrr, nv)
    local = shape_distinctiveness(desc, *radius_neighbours(xy, 45.0))
    assert local.argmax() == odd and local[odd] > 3 * np.delete(local, odd).max()
    glob = shape_distinctiveness(desc)  # no neighbour lists: against the whole set
    assert glob.argmax() == odd
    assert (shape_distinctiveness(np.tile(desc[0], (10, 1))) == 0).all()  # identical shapes: nothing stands out


# --- saliency -------------------------------------------------------------------------------------------------


def test_saliency_single_measure_is_its_normalized_value() -> None:
    h = np.array([5.0, 10.0, 40.0, 20.0])
    np.testing.assert_allclose(saliency({"height": h}, {"height": 3.0}), normalize(h))


def test_saliency_weights() -> None:
    rng = np.random.default_rng(2)
    a, b = rng.uniform(0, 50, 30), rng.uniform(0, 5, 30)
    np.testing.assert_allclose(saliency({"a": a, "b": b}, {"a": 1.0, "b": 0.0}), normalize(a))
    np.testing.assert_allclose(saliency({"a": a, "b": b}, {"a": 1.0}), normalize(a))  # unweighted: ignored
    np.testing.assert_allclose(saliency({"a": a, "b": b}, {"a": 1.0, "b": 3.0}), (normalize(a) + 3 * normalize(b)) / 4)
    out = saliency({"a": a, "b": b}, {"a": 2.0, "b": 5.0})
    assert out.min() >= 0 and out.max() <= 1
    # a zero-weight measure is not even looked at: its shape and NaNs do not matter
    np.testing.assert_allclose(saliency({"a": a, "junk": np.full(3, np.nan)}, {"a": 1.0, "junk": 0.0}), normalize(a))


@pytest.mark.parametrize(
    ("weights", "message"),
    [
        ({"height": 1.0, "heigth": 1.0}, "unknown measures \\['heigth'\\]"),
        ({"height": -1.0}, ">= 0"),
        ({"height": np.nan}, ">= 0"),
        ({"height": 0.0}, "positive weight"),
        ({}, "positive weight"),
        ({"height": 1.0, "short": 1.0}, "one length"),
    ],
)
def test_saliency_rejects_bad_weights(weights: dict[str, float], message: str) -> None:
    with pytest.raises(ValueError, match=message):
        saliency({"height": np.arange(5.0), "short": np.arange(3.0)}, weights)


# --- voting hierarchy ---------------------------------------------------------------------------------------


def reference_round(xy: np.ndarray, score: np.ndarray) -> np.ndarray:
    """One voting round written out plainly from the Delaunay triangles (points in general position)."""
    n = len(xy)
    nbrs: list[set[int]] = [{i} for i in range(n)]
    for tri in Delaunay(xy - xy.mean(axis=0)).simplices:
        for a in tri:
            nbrs[a].update(int(b) for b in tri)
    won = np.zeros(n, dtype=bool)
    for i in range(n):
        won[min(nbrs[i], key=lambda j: (-score[j], j))] = True
    return won


def check_invariants(xy: np.ndarray, score: np.ndarray, level: np.ndarray) -> None:
    n = len(score)
    assert level.shape == (n,) and level.dtype.kind == "i" and (level >= 0).all()
    if n < 2:
        assert (level == 0).all()
        return
    top = level.max()
    assert (level == top).sum() == 1  # exactly one landmark at the top
    assert top <= n - 1
    # level k = the points promote() keeps from level k - 1, re-triangulated (so nested by construction)
    members = np.arange(n)
    for k in range(1, top + 1):
        won = members[promote(xy[members], score[members])]
        assert np.array_equal(won, np.flatnonzero(level >= k)), f"level {k}"
        assert len(won) < len(members)
        members = won


def test_tall_building_among_small_ones_reaches_the_top() -> None:
    xy = grid(8)
    rng = np.random.default_rng(11)
    score = rng.uniform(5, 15, len(xy))
    score[27] = 100.0
    level = voting_hierarchy(xy, score)
    assert level.argmax() == 27
    check_invariants(xy, score, level)
    assert level.max() >= 2 and (level == 0).sum() > len(xy) // 2  # a real hierarchy, most never promoted


def test_round_matches_a_plain_reference() -> None:
    rng = np.random.default_rng(4)
    for n in (4, 10, 60, 300):
        xy = OFF + rng.uniform(0, 500, (n, 2))
        score = rng.integers(0, 6, n).astype(float)  # many ties, broken by index
        assert np.array_equal(promote(xy, score), reference_round(xy, score))


def test_random_sets_are_consistent_and_deterministic() -> None:
    rng = np.random.default_rng(9)
    for n in (5, 40, 400):
        xy = OFF + rng.uniform(0, 1000, (n, 2))
        score = rng.uniform(0, 60, n)
        level = voting_hierarchy(xy, score)
        check_invariants(xy, score, level)
        assert level.argmax() == score.argmax()
        assert np.array_equal(level, voting_hierarchy(xy.copy(), score.copy()))


def test_known_answer_on_a_line() -> None:
    xy = OFF + np.column_stack([np.arange(5.0) * 10, np.arange(5.0) * 3])  # collinear: Qhull gives up
    level = voting_hierarchy(xy, np.array([1.0, 5.0, 2.0, 4.0, 3.0]))
    # chain 0-1-2-3-4: votes 0->1, 1->1, 2->1, 3->3, 4->3; then 1 and 3 both vote for 1
    assert level.tolist() == [0, 2, 0, 1, 0]
    shuffled = np.array([3, 0, 4, 1, 2])  # the order along the line, not the input order, makes neighbours
    assert voting_hierarchy(xy[shuffled], np.array([4.0, 1.0, 3.0, 5.0, 2.0])).tolist() == [1, 0, 0, 2, 0]


@pytest.mark.parametrize("n", [0, 1, 2, 3])
def test_tiny_inputs(n: int) -> None:
    xy = OFF + np.array([[0.0, 0.0], [10.0, 0.0], [0.0, 10.0]])[:n]
    score = np.array([1.0, 3.0, 2.0])[:n]
    level = voting_hierarchy(xy, score)
    expected = {0: [], 1: [0], 2: [0, 1], 3: [0, 1, 0]}[n]
    assert level.tolist() == expected


def test_duplicate_points() -> None:
    xy = OFF + np.array([[0.0, 0.0], [0.0, 0.0], [10.0, 0.0], [0.0, 10.0]])
    assert voting_hierarchy(xy, np.array([1.0, 2.0, 0.0, 0.0])).tolist() == [0, 1, 0, 0]
    assert voting_hierarchy(np.tile(OFF, (6, 1)), np.arange(6.0)).tolist() == [0, 0, 0, 0, 0, 1]
    rng = np.random.default_rng(1)
    xy = OFF + rng.integers(0, 6, (80, 2)) * 10.0  # many exact duplicates and collinear triples
    score = rng.uniform(0, 1, 80)
    level = voting_hierarchy(xy, score)
    check_invariants(xy, score, level)
    assert level.argmax() == score.argmax()


def test_near_duplicates_that_qhull_drops_still_vote() -> None:
    xy = np.array([[0, 0], [30, 0], [0, 30], [30, 30], [15, 15], [15, 15 + 1e-13]])
    score = np.array([1.0, 1.0, 1.0, 1.0, 2.0, 9.0])  # the point Qhull leaves out is the best one
    level = voting_hierarchy(xy, score)
    assert level.argmax() == 5
    check_invariants(xy, score, level)
    # the left-out point is joined to its neighbour: if it were isolated it would vote for itself and climb
    level = voting_hierarchy(xy, np.array([5.0, 6.0, 7.0, 8.0, 0.5, 0.0]))
    assert level[4] == 0 and level[5] == 0 and level.argmax() == 3


def test_equal_scores_still_terminate() -> None:
    xy = grid(6)
    level = voting_hierarchy(xy, np.zeros(len(xy)))
    check_invariants(xy, np.zeros(len(xy)), level)
    assert level.argmax() == 0  # ties go to the lower index
    level = voting_hierarchy(xy, np.full(len(xy), np.nan))  # NaN ranks lowest, and ties as well
    assert level.argmax() == 0


def test_hierarchy_rejects_bad_input() -> None:
    with pytest.raises(ValueError, match="score"):
        voting_hierarchy(np.zeros((3, 2)), np.zeros(4))
    with pytest.raises(ValueError, match="finite"):
        voting_hierarchy(np.array([[0.0, np.nan], [1.0, 1.0]]), np.zeros(2))


# --- exaggeration and displacement ----------------------------------------------------------------------------


def test_exaggeration_intervals_start_where_the_landmark_gets_small() -> None:
    from_m, top = exaggeration_intervals(
        np.array([60.0, 30.0, 30.0]), np.array([5, 3, 4]), 3, min_screen_px=48, step=1.5, max_scale=3.0
    )
    # 60 m fill 48 px of 1080 px / 60° at 60 * 1080 / (2 tan 30° * 48) = 1169 m
    assert from_m[0] == pytest.approx(60 * 1080 / (2 * math.tan(math.radians(30)) * 48))
    assert from_m[1] == pytest.approx(from_m[0] / 2)
    # the top level gets the full scale, each level below a third less of the growth (3 landmark levels)
    assert top.tolist() == pytest.approx([3.0, 1 + 2 / 3, 1 + 4 / 3])
    b, s = interval_arrays(1000.0, 1.5, 3.0)
    assert b.tolist() == pytest.approx([1000, 1500, 2250]) and s.tolist() == pytest.approx([1.5, 2.25, 3.0])
    assert exaggeration_scale([999, 1000, 2000, 1e9], b, s).tolist() == pytest.approx([1, 1.5, 2.25, 3.0])
    assert [len(a) for a in interval_arrays(1000.0, 1.5, 1.0)] == [0, 0]
    with pytest.raises(ValueError):
        exaggeration_intervals(np.ones(1), np.ones(1), 1, min_screen_px=48, step=1.0, max_scale=3)


def test_exaggeration_scale_steps() -> None:
    d = np.array([-5.0, 0.0, 99.9, 100.0, 250.0, 500.0, 1e6, np.nan])
    out = exaggeration_scale(d, [100.0, 500.0], [1.5, 2.5])
    np.testing.assert_array_equal(out[:-1], [1.0, 1.0, 1.0, 1.5, 1.5, 2.5, 2.5])
    assert np.isnan(out[-1])
    assert exaggeration_scale(300.0, [100.0, 500.0], [1.5, 2.5]) == 1.5
    np.testing.assert_array_equal(exaggeration_scale(d[:-1], [], []), 1.0)


def test_exaggeration_scale_ramp() -> None:
    b, s = [100.0, 500.0], [1.5, 2.5]
    d = np.array([0.0, 80.0, 90.0, 100.0, 300.0, 480.0, 490.0, 500.0, 900.0])
    np.testing.assert_allclose(exaggeration_scale(d, b, s, ramp=20.0), [1, 1, 1.25, 1.5, 1.5, 1.5, 2.0, 2.5, 2.5])
    fine = np.linspace(0, 1000, 2001)  # no jump anywhere: the landmark grows, it does not pop
    assert np.abs(np.diff(exaggeration_scale(fine, b, s, ramp=20.0))).max() <= 1.0 / 20 * 0.5 + 1e-12
    with pytest.raises(ValueError, match="ramp"):
        exaggeration_scale(d, b, s, ramp=150.0)


@pytest.mark.parametrize(("b", "s"), [([100.0, 50.0], [1.5, 2.0]), ([100.0], [1.5, 2.0]), ([100.0], [0.0])])
def test_exaggeration_scale_rejects_bad_intervals(b: list[float], s: list[float]) -> None:
    with pytest.raises(ValueError):
        exaggeration_scale(10.0, b, s)


def gaps(lxy: np.ndarray, lr: float, scale: float, oxy: np.ndarray, orad: np.ndarray) -> np.ndarray:
    """Centre distance minus the distance the circles need: < 0 is an overlap."""
    return np.linalg.norm(oxy - lxy, axis=1) - (scale * lr + orad)


def test_displacement_removes_every_overlap_and_nothing_else() -> None:
    rng = np.random.default_rng(8)
    lxy, lr, scale = OFF + 250.0, 15.0, 2.5
    oxy = OFF + rng.uniform(0, 500, (2000, 2))
    orad = rng.uniform(3, 10, 2000)
    before = gaps(lxy, lr, scale, oxy, orad)
    move = displacement(lxy, lr, scale, oxy, orad)
    hit = before < 0
    assert hit.sum() > 20
    assert (move[~hit] == 0).all()
    after = gaps(lxy, lr, scale, oxy + move, orad)
    np.testing.assert_allclose(after[hit], 0.0, atol=1e-6)  # just far enough
    # radially outward: parallel to the offset from the landmark, by the missing distance
    off = oxy[hit] - lxy
    cross = off[:, 0] * move[hit, 1] - off[:, 1] * move[hit, 0]
    assert np.allclose(cross / np.linalg.norm(off, axis=1), 0, atol=1e-6)
    assert ((off * move[hit]).sum(axis=1) > 0).all()
    np.testing.assert_allclose(np.linalg.norm(move[hit], axis=1), -before[hit], rtol=1e-9)


def test_displacement_edge_cases() -> None:
    move = displacement(OFF, 10.0, 2.0, np.vstack([OFF, OFF + [100.0, 0]]), np.array([5.0, 5.0]))
    np.testing.assert_allclose(move, [[25.0, 0.0], [0.0, 0.0]])  # on the centre: along +x
    assert displacement(OFF, 10.0, 2.0, np.zeros((0, 2)), np.zeros(0)).shape == (0, 2)
    assert (displacement(np.zeros((0, 2)), [], [], OFF[None], 5.0) == 0).all()
    with pytest.raises(ValueError, match="combine"):
        displacement(OFF, 10.0, 2.0, OFF[None], 5.0, combine="mean")  # type: ignore[arg-type]


def test_displacement_only_growth_keeps_existing_overlaps() -> None:
    lxy, lr = OFF, 10.0
    oxy = OFF + np.array([[12.0, 0.0], [0.0, 20.0], [40.0, 0.0]])  # overlaps already, touches later, far
    orad = np.array([5.0, 5.0, 5.0])
    assert (displacement(lxy, lr, 1.0, oxy, orad, only_growth=True) == 0).all()
    move = displacement(lxy, lr, 2.0, oxy, orad, only_growth=True)
    np.testing.assert_allclose(move, [[10.0, 0.0], [0.0, 5.0], [0.0, 0.0]])  # the growth of r_L: 10 m
    np.testing.assert_allclose(gaps(lxy, lr, 2.0, oxy + move, orad)[:2], [-3.0, 0.0])  # old overlap kept


def test_displacement_several_landmarks() -> None:
    lxy = OFF + np.array([[0.0, 0.0], [100.0, 0.0]])
    oxy = OFF + np.array([[20.0, 0.0], [50.0, 0.0], [50.0, 50.0], [120.0, 0.0]])
    orad = np.full(4, 5.0)
    lr, scale = np.array([10.0, 10.0]), np.array([6.0, 5.0])  # needed centre distances: 65 and 55
    move = displacement(lxy, lr, scale, oxy, orad)
    # 0: covered by landmark 0 only; 1: by both, 15 m by landmark 0, 5 m by landmark 1; 2: by neither
    np.testing.assert_allclose(move, [[45.0, 0.0], [15.0, 0.0], [0.0, 0.0], [35.0, 0.0]])
    summed = displacement(lxy, lr, scale, oxy, orad, combine="sum")
    np.testing.assert_allclose(summed, [[45.0, 0.0], [10.0, 0.0], [0.0, 0.0], [35.0, 0.0]])
