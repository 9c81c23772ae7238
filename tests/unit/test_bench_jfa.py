"""benchmarks.jfa.jump_flood: the jump-flooding distance map against scipy's exact Euclidean distance transform on
random seed grids, and the edge cases (no seed, one seed, all seeds, thin and tiny grids)."""

import numpy as np
import pytest
from scipy import ndimage

from benchmarks.jfa import jump_flood


def random_seeds(rng: np.random.Generator, shape: tuple[int, int], density: float) -> np.ndarray:
    s = rng.random(shape) < density
    s[rng.integers(shape[0]), rng.integers(shape[1])] = True  # at least one seed
    return s


def check_nearest(distance: np.ndarray, nearest: np.ndarray, seeds: np.ndarray) -> None:
    """``nearest`` names a seed, and ``distance`` is the distance to it."""
    y, x = np.unravel_index(nearest, seeds.shape)
    assert seeds[y, x].all()
    yy, xx = np.indices(seeds.shape)
    np.testing.assert_allclose(np.hypot(y - yy, x - xx), distance, rtol=0, atol=1e-12)


@pytest.mark.parametrize("extra_pass", [True, False])
def test_matches_exact_distance_transform(extra_pass: bool) -> None:
    rng = np.random.default_rng(7)
    total = wrong = 0
    worst = 0.0
    for _ in range(12):
        shape = (int(rng.integers(16, 160)), int(rng.integers(16, 160)))
        seeds = random_seeds(rng, shape, 10 ** rng.uniform(-3.5, -1.5))
        distance, nearest = jump_flood(seeds, extra_pass=extra_pass)
        exact = ndimage.distance_transform_edt(~seeds)
        err = distance - exact
        assert err.min() >= -1e-9  # JFA finds a real seed, so it can never be nearer than the nearest one
        worst = max(worst, float(err.max()))
        wrong += int((err > 1e-9).sum())
        total += err.size
        check_nearest(distance, nearest, seeds)
    assert worst <= 1.0
    assert wrong / total <= (1e-4 if extra_pass else 1e-2)


def test_no_seed_is_infinitely_far() -> None:
    distance, nearest = jump_flood(np.zeros((7, 9), dtype=bool))
    assert np.isinf(distance).all() and (distance > 0).all()
    assert (nearest == -1).all()


def test_one_seed_gives_the_exact_euclidean_distance() -> None:
    seeds = np.zeros((33, 50), dtype=bool)
    seeds[4, 41] = True
    distance, nearest = jump_flood(seeds)
    yy, xx = np.indices(seeds.shape)
    np.testing.assert_allclose(distance, np.hypot(yy - 4, xx - 41), rtol=0, atol=1e-12)
    assert (nearest == 4 * 50 + 41).all()


def test_all_seeds_are_zero() -> None:
    distance, nearest = jump_flood(np.ones((5, 4), dtype=bool))
    assert (distance == 0).all()
    assert (nearest == np.arange(20).reshape(5, 4)).all()


@pytest.mark.parametrize("shape", [(1, 1), (1, 37), (29, 1), (2, 3)])
def test_thin_and_tiny_grids(shape: tuple[int, int]) -> None:
    seeds = np.zeros(shape, dtype=bool)
    seeds[-1, 0] = True
    distance, nearest = jump_flood(seeds)
    np.testing.assert_allclose(distance, ndimage.distance_transform_edt(~seeds), atol=1e-12)
    check_nearest(distance, nearest, seeds)


def test_rejects_non_2d_input() -> None:
    with pytest.raises(ValueError, match="2-D"):
        jump_flood(np.zeros(5, dtype=bool))
