"""Landmarks (thesis section 3.4, after Winter et al. 2008): per-building saliency from simple measures, the
voting hierarchy that ranks landmarks over a Delaunay triangulation of their centroids, and the view-dependent
exaggeration of a landmark with the displacement of the buildings its enlarged footprint would cover.

Pure numpy/scipy on arrays of all buildings at once; the only Python loops run over hierarchy levels and over
landmarks, never over buildings. Neighbourhoods are CSR lists ``(indptr, indices)``: the neighbours of building i
are ``indices[indptr[i]:indptr[i + 1]]`` (``radius_neighbours`` builds them; self-loops are ignored), or, for a
whole city, only the sums over them (``neighbour_sums``: count, sum of values), computed in blocks of query points
so that memory follows the block and the local density, never the number of pairs in the city (at a 150 m radius
a dense city has hundreds of neighbours per building: the CSR lists of 107k buildings took ~300 MB).

Coordinates may be projected (~1e6 m): they are taken relative to their mean before any triangulation.
"""

from __future__ import annotations

from typing import Literal

import numpy as np
from scipy import sparse
from scipy.spatial import Delaunay, QhullError, cKDTree

from core.camera import distance_for_pixels

# ---------------------------------------------------------------------------------------------------------------
# measures


def normalize(values: np.ndarray) -> np.ndarray:
    """Map one measure to [0, 1] by min-max between its 1st percentile and its maximum, clipped below.

    The top is not clipped: landmarks are the top of the distribution, and clipping at a high percentile would
    give the 1 % most salient buildings the same 1 and leave the ranking among them to chance. The 1st
    percentile keeps a few zero-area slivers from stretching the range; heavy-tailed measures (volume, area)
    are better passed through a log by the caller, so one freak value does not squash everybody else. When
    the 1st percentile is the maximum (one tower among 100 equal houses) plain min-max applies. Only finite
    values set the range; NaN and -inf -> 0, +inf -> 1; constant (or empty) input -> zeros.
    """
    v = np.asarray(values, dtype=np.float64)
    out = np.zeros(v.shape)
    finite = np.isfinite(v)
    if finite.any():
        f = v[finite]
        lo, hi = np.percentile(f, 1.0), f.max()
        if not hi > lo:
            lo = f.min()
        if hi > lo:
            out[finite] = np.clip((f - lo) / (hi - lo), 0.0, 1.0)
    out[v == np.inf] = 1.0
    return out


def radius_neighbours(xy: np.ndarray, radius: float) -> tuple[np.ndarray, np.ndarray]:
    """CSR ``(indptr, indices)`` of the other points within ``radius`` of each point (symmetric, sorted by
    point, no self-loops; duplicates of a point count as its neighbours)."""
    xy = _as_xy(xy)
    n = len(xy)
    pairs = cKDTree(xy - xy.mean(axis=0) if n else xy).query_pairs(radius, output_type="ndarray")
    rows = np.concatenate([pairs[:, 0], pairs[:, 1]]).astype(np.int64)
    cols = np.concatenate([pairs[:, 1], pairs[:, 0]]).astype(np.int64)
    order = np.lexsort((cols, rows))
    indptr = np.zeros(n + 1, dtype=np.int64)
    np.cumsum(np.bincount(rows, minlength=n), out=indptr[1:])
    return indptr, cols[order]


def neighbour_sums(
    xy: np.ndarray, radius: float, values: np.ndarray, block: int = 4096
) -> tuple[np.ndarray, np.ndarray]:
    """``(count (n,), sums (n, m))``: per point, how many other points lie within ``radius`` and the sum of their
    ``values`` rows, what the CSR lists of ``radius_neighbours`` give, without them: the pairs of ``block`` query
    points at a time are found, summed and dropped. Duplicates of a point count as its neighbours."""
    xy = _as_xy(xy)
    n = len(xy)
    v = np.asarray(values, dtype=np.float64)
    v = v[:, None] if v.ndim == 1 else v
    count = np.zeros(n, dtype=np.int64)
    sums = np.zeros(v.shape, dtype=np.float64)
    if n == 0:
        return count, sums
    local = xy - xy.mean(axis=0)
    tree = cKDTree(local)
    for start in range(0, n, block):
        stop = min(start + block, n)
        pairs = cKDTree(local[start:stop]).sparse_distance_matrix(tree, radius, output_type="ndarray")
        i, j = pairs["i"].astype(np.int64), pairs["j"].astype(np.int64)
        other = i + start != j  # the self-pair goes; a duplicate (distance 0 too) stays
        i, j = i[other], j[other]
        count[start:stop] = np.bincount(i, minlength=stop - start)
        for c in range(v.shape[1]):
            sums[start:stop, c] = np.bincount(i, weights=v[j, c], minlength=stop - start)
    return count, sums


def relative_height(
    heights: np.ndarray,
    indptr: np.ndarray | None = None,
    indices: np.ndarray | None = None,
    min_height: float = 1.0,
    *,
    sums: tuple[np.ndarray, np.ndarray] | None = None,
) -> np.ndarray:
    """(n,) height / mean height of the building's neighbours: > 1 stands out, ~1 blends in.

    A building without neighbours gets 1.0 (nothing to stand out from). The mean is floored at ``min_height``
    metres so that neighbours of unknown/zero height do not make the ratio explode; NaN heights propagate
    (``normalize`` then maps them to 0).
    """
    h = np.asarray(heights, dtype=np.float64)
    if sums is None:  # from the CSR lists; ``sums`` = neighbour_sums(xy, radius, h) gives the same
        if indptr is None or indices is None:
            raise ValueError("relative_height needs the CSR lists or their sums")
        adj = _adjacency(indptr, indices, len(h))
        count, total = adj.sum(axis=1), adj @ h
    else:
        count, total = sums[0], np.asarray(sums[1], dtype=np.float64).reshape(len(h))
    with np.errstate(invalid="ignore", divide="ignore"):
        mean = total / count
    rel = h / np.maximum(mean, min_height)
    return np.where(count > 0, rel, 1.0)


def shape_descriptors(
    area: np.ndarray, perimeter: np.ndarray, mrr_area: np.ndarray, n_vertices: np.ndarray
) -> np.ndarray:
    """(n, 4) footprint descriptors for ``shape_distinctiveness``: compactness 4*pi*A/P^2 (1 for a disc),
    rectangularity A / area of the minimum rotated rectangle (1 for a rectangle), log(vertex count) and
    log(area); logs because counts and areas are heavy-tailed and a 2x difference should weigh the same at any
    size. Degenerate inputs (P or MRR area 0) give compactness/rectangularity 0."""
    a = np.asarray(area, dtype=np.float64)
    p = np.asarray(perimeter, dtype=np.float64)
    m = np.asarray(mrr_area, dtype=np.float64)
    with np.errstate(invalid="ignore", divide="ignore"):
        compact = np.where(p > 0, 4.0 * np.pi * a / p**2, 0.0)
        rect = np.where(m > 0, a / m, 0.0)
    nv = np.maximum(np.asarray(n_vertices, dtype=np.float64), 1.0)
    return np.column_stack([compact, rect, np.log(nv), np.log(np.maximum(a, 1e-6))])


def fill_descriptors(descriptors: np.ndarray) -> np.ndarray:
    """(n, k) descriptors with each NaN replaced by its column's mean, as shape_distinctiveness compares them."""
    x = np.asarray(descriptors, dtype=np.float64)
    x = x[:, None] if x.ndim == 1 else x
    if len(x) == 0:
        return x
    return np.where(np.isnan(x), np.nanmean(x, axis=0), x)


def shape_distinctiveness(
    descriptors: np.ndarray,
    indptr: np.ndarray | None = None,
    indices: np.ndarray | None = None,
    min_neighbours: int = 3,
    min_std_fraction: float = 0.1,
    *,
    sums: tuple[np.ndarray, np.ndarray] | None = None,
) -> np.ndarray:
    """(n,) how unusual each footprint is among its neighbours: the root mean square of the per-descriptor
    z-scores of its descriptor row against the mean and standard deviation of its neighbours' rows.

    A z-score distance (diagonal Mahalanobis) because a neighbourhood has few members: a full covariance of
    4 descriptors from ~10 neighbours is nearly singular. Buildings with fewer than ``min_neighbours``
    neighbours (or when no CSR lists are given) are compared with the whole set instead. Each standard
    deviation is floored at ``min_std_fraction`` x that descriptor's global one, so a row of identical houses
    does not turn a small difference into a huge score; a descriptor constant over the whole set counts 0.
    NaN descriptors count as 0 (typical). 0 = typical, ~1 = one standard deviation off on average.
    Instead of the CSR lists, ``sums`` = neighbour_sums(xy, radius, [x, x²]) of ``fill_descriptors(descriptors)``
    (k columns of x, then k of x²) gives the same (``descriptors`` stay the raw ones, NaN included).
    """
    x = np.asarray(descriptors, dtype=np.float64)
    if x.ndim == 1:
        x = x[:, None]
    n, k = x.shape
    if n == 0:
        return np.zeros(0)
    g_mean = np.nanmean(x, axis=0) if k else np.zeros(0)
    g_std = np.nanstd(x, axis=0) if k else np.zeros(0)
    x = np.where(np.isnan(x), g_mean, x)
    mean = np.broadcast_to(g_mean, (n, k)).copy()
    std = np.broadcast_to(g_std, (n, k)).copy()
    count = None
    if sums is not None:
        count, s12 = sums
        s12 = np.asarray(s12, dtype=np.float64).reshape(n, 2 * k)
        all_s1, all_s2 = s12[:, :k], s12[:, k:]
    elif indptr is not None and indices is not None:
        adj = _adjacency(indptr, indices, n)
        count, all_s1, all_s2 = adj.sum(axis=1), adj @ x, adj @ x**2
    if count is not None:
        local = count >= max(min_neighbours, 1)
        if local.any():
            c = count[local, None]
            s1 = all_s1[local]
            s2 = all_s2[local]
            mean[local] = s1 / c
            std[local] = np.sqrt(np.maximum(s2 / c - (s1 / c) ** 2, 0.0))
    std = np.maximum(std, min_std_fraction * g_std)
    varies = g_std > 1e-9 * np.maximum(np.abs(g_mean), 1.0)  # not just rounding noise of a constant column
    with np.errstate(invalid="ignore", divide="ignore"):
        z = np.where(varies, (x - mean) / std, 0.0)
    return np.sqrt(np.mean(z**2, axis=1)) if k else np.zeros(n)


def saliency(measures: dict[str, np.ndarray], weights: dict[str, float]) -> np.ndarray:
    """(n,) in [0, 1]: sum of weight x ``normalize(measure)`` over the weighted measures / sum of the weights.

    A measure with no weight, or weight 0, is ignored (not even normalized). Raises ValueError for a weight
    naming no measure, a negative or non-finite weight, no positive weight, or measures of different lengths.
    Measures are "more is more salient": negate one that is not.
    """
    unknown = sorted(set(weights) - set(measures))
    if unknown:
        raise ValueError(f"saliency weights for unknown measures {unknown}; measures are {sorted(measures)}")
    bad = {k: w for k, w in weights.items() if not (np.isfinite(w) and w >= 0)}
    if bad:
        raise ValueError(f"saliency weights must be finite and >= 0, got {bad}")
    used = {k: float(w) for k, w in weights.items() if w > 0}
    if not used:
        raise ValueError("saliency needs at least one measure with a positive weight")
    shapes = {k: np.shape(measures[k]) for k in used}
    if len(set(shapes.values())) != 1 or any(len(shape) != 1 for shape in shapes.values()):
        raise ValueError(f"saliency measures must be 1-D arrays of one length, got shapes {shapes}")
    total = sum(used.values())
    out = sum(w * normalize(measures[k]) for k, w in used.items()) / total
    return np.clip(out, 0.0, 1.0)


# ---------------------------------------------------------------------------------------------------------------
# the Winter et al. voting hierarchy


def promote(xy: np.ndarray, score: np.ndarray) -> np.ndarray:
    """(n,) bool: one voting round. Every point votes for the most salient of itself and its Delaunay
    neighbours; the points with at least one vote are promoted. Ties: higher score first, then lower index."""
    xy = _as_xy(xy)
    rank = _rank(np.asarray(score, dtype=np.float64))
    if len(xy) != len(rank):
        raise ValueError(f"xy has {len(xy)} points but score has {len(rank)}")
    won = np.zeros(len(xy), dtype=bool)
    if len(xy):
        won[_votes(xy, rank)] = True
    return won


def voting_hierarchy(xy: np.ndarray, score: np.ndarray) -> np.ndarray:
    """(n,) int landmark level: the number of voting rounds the point was promoted in (``promote`` repeated on
    the promoted points, re-triangulated, until one is left). 0 = never promoted; the level-k points are a
    subset of the level-(k-1) points; exactly one point (the most salient) has the top level, the number of
    rounds. n <= 1 -> zeros. NaN scores rank lowest.

    Terminates in at most n - 1 rounds: with ties broken by index the order is strict and the Delaunay graph
    connected, so nobody votes for the least salient point of a round and it is always eliminated.
    """
    xy = _as_xy(xy)
    rank = _rank(np.asarray(score, dtype=np.float64))
    if len(xy) != len(rank):
        raise ValueError(f"xy has {len(xy)} points but score has {len(rank)}")
    level = np.zeros(len(xy), dtype=np.int64)
    active = np.arange(len(xy))
    while len(active) > 1:
        won = active[_votes(xy[active], rank[active])]
        if len(won) >= len(active):  # cannot happen (see above); guards against an endless loop all the same
            raise RuntimeError("a voting round eliminated no point")
        level[won] += 1
        active = won
    return level


def _as_xy(xy: np.ndarray) -> np.ndarray:
    a = np.asarray(xy, dtype=np.float64).reshape(-1, 2)
    if not np.isfinite(a).all():
        raise ValueError("coordinates must be finite")
    return a


def _rank(score: np.ndarray) -> np.ndarray:
    """0 = most salient; higher score first, then lower index (a strict order, which guarantees progress)."""
    key = np.where(np.isnan(score), -np.inf, score)
    order = np.lexsort((np.arange(len(key)), -key))
    rank = np.empty(len(key), dtype=np.int64)
    rank[order] = np.arange(len(key))
    return rank


def _votes(xy: np.ndarray, rank: np.ndarray) -> np.ndarray:
    """Sorted positions (into xy) that receive at least one vote, for points with distinct ``rank``s.

    Duplicate points share one triangulation vertex: only the best of them stands there, the others vote like
    it (so they vote for it or for something better). Votes go to location representatives only. Coordinates
    are taken relative to their mean here, so a round depends only on the points taking part in it."""
    uniq, loc = np.unique(xy - xy.mean(axis=0), axis=0, return_inverse=True)
    loc = loc.ravel()
    best = np.full(len(uniq), np.iinfo(np.int64).max)
    np.minimum.at(best, loc, rank)  # the best rank at each location
    rows, cols = _delaunay_edges(uniq)
    vote = best.copy()
    np.minimum.at(vote, rows, best[cols])  # the best rank among each location and its neighbours
    point_of_rank = np.full(rank.max() + 1, -1, dtype=np.int64)
    point_of_rank[rank] = np.arange(len(rank))
    return np.sort(point_of_rank[np.unique(vote)])


def _delaunay_edges(pts: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Directed edges (both ways) of the Delaunay graph of distinct points; a chain along the line when they are
    collinear (or fewer than 3), where Qhull gives up. A point Qhull leaves out of every triangle (nearly
    coincident with another) is joined to the vertex Qhull reports as nearest and to that vertex's neighbours,
    as if it stood there, so the graph stays connected and it votes like its twin."""
    m = len(pts)
    if m < 2:
        return np.zeros(0, np.int64), np.zeros(0, np.int64)
    try:
        if m < 3:
            raise QhullError("fewer than 3 points")
        tri = Delaunay(pts)
    except QhullError:
        centred = pts - pts.mean(axis=0)
        axis = np.linalg.svd(centred, full_matrices=False)[2][0]
        chain = np.lexsort((pts[:, 1], pts[:, 0], centred @ axis))
        a, b = chain[:-1], chain[1:]
        return np.concatenate([a, b]), np.concatenate([b, a])
    indptr, indices = tri.vertex_neighbor_vertices
    rows = np.repeat(np.arange(m), np.diff(indptr))
    cols = indices.astype(np.int64)
    if len(tri.coplanar):
        # a left-out point sits (nearly) on its nearest vertex: it gets that vertex and all its neighbours
        lost, near = tri.coplanar[:, 0].astype(np.int64), tri.coplanar[:, 2].astype(np.int64)
        deg = np.diff(indptr)[near]
        first = np.repeat(indptr[near] - np.cumsum(deg) + deg, deg) + np.arange(deg.sum())
        a = np.concatenate([lost, np.repeat(lost, deg)])
        b = np.concatenate([near, cols[first]])
        rows = np.concatenate([rows, a, b])
        cols = np.concatenate([cols, b, a])
    return rows, cols


def _adjacency(indptr: np.ndarray, indices: np.ndarray, n: int) -> sparse.csr_array:
    """0/1 (n, n) CSR matrix of the neighbour lists without self-loops (a repeated neighbour counts twice)."""
    indptr = np.asarray(indptr, dtype=np.int64)
    indices = np.asarray(indices, dtype=np.int64)
    if len(indptr) != n + 1:
        raise ValueError(f"indptr must have n + 1 = {n + 1} entries, got {len(indptr)}")
    rows = np.repeat(np.arange(n), np.diff(indptr))
    keep = indices != rows
    return sparse.csr_array((np.ones(int(keep.sum())), (rows[keep], indices[keep])), shape=(n, n))


# ---------------------------------------------------------------------------------------------------------------
# exaggeration and displacement


def exaggeration_intervals(
    height: np.ndarray,
    level: np.ndarray,
    min_level: int,
    *,
    min_screen_px: float,
    step: float,
    max_scale: float,
    fov_deg: float = 60.0,
    viewport_px: float = 1080.0,
) -> tuple[np.ndarray, np.ndarray]:
    """Per landmark, where its exaggeration starts and how far it goes: ``(from_m, top_scale)``.

    ``from_m`` is the distance at which the landmark's ``height`` (m) would fill fewer than ``min_screen_px``
    pixels of a ``viewport_px`` high view with vertical field of view ``fov_deg``; ``top_scale`` grows linearly
    with the hierarchy level, from ``1 + (max_scale - 1) / k`` at ``min_level`` to ``max_scale`` at the top
    (``k`` levels of landmarks), so the more distinguished a building, the more it may grow.
    ``interval_arrays`` turns them into the predefined intervals ``exaggeration_scale`` reads."""
    if step <= 1 or max_scale < 1 or min_screen_px <= 0:
        raise ValueError("step must be > 1, max_scale >= 1, min_screen_px > 0")
    h = np.maximum(np.asarray(height, dtype=np.float64), 1.0)
    lv = np.asarray(level, dtype=np.float64)
    top = lv.max(initial=min_level)
    k = top - min_level + 1
    from_m = np.asarray(distance_for_pixels(h, min_screen_px, np.radians(fov_deg), viewport_px))  # float only for 0-d h
    top_scale = 1 + (max_scale - 1) * np.clip(lv - min_level + 1, 0, k) / k
    return from_m, top_scale


def interval_arrays(from_m: float, step: float, top_scale: float) -> tuple[np.ndarray, np.ndarray]:
    """The predefined intervals of one landmark: boundaries ``from_m * step**i`` and scales
    ``min(step**(i + 1), top_scale)``, as many as reach ``top_scale`` (none when it is 1)."""
    if top_scale <= 1 + 1e-9:
        return np.zeros(0), np.zeros(0)
    n = int(np.ceil(np.log(top_scale) / np.log(step) - 1e-9))
    i = np.arange(n)
    return from_m * step**i, np.minimum(step ** (i + 1), top_scale)


def exaggeration_scale(
    distance: np.ndarray | float, boundaries: np.ndarray, scales: np.ndarray, ramp: float = 0.0
) -> np.ndarray:
    """Scale factor of a landmark seen from ``distance`` (metres), piecewise constant over predefined intervals:
    1.0 below ``boundaries[0]``, ``scales[i]`` from ``boundaries[i]`` up to ``boundaries[i + 1]``, ``scales[-1]``
    beyond the last boundary (boundaries strictly increasing, one scale per boundary).

    Piecewise constant as in the thesis; a ``ramp`` > 0 (metres, at most the narrowest interval and the first
    boundary) replaces each jump by a linear blend over the ``ramp`` metres before its boundary, so a moving
    camera sees the landmark grow rather than pop. NaN distance -> NaN.
    """
    d = np.asarray(distance, dtype=np.float64)
    b = np.asarray(boundaries, dtype=np.float64).ravel()
    s = np.asarray(scales, dtype=np.float64).ravel()
    if len(b) != len(s):
        raise ValueError(f"one scale per boundary: {len(b)} boundaries, {len(s)} scales")
    if not (np.isfinite(b).all() and np.isfinite(s).all() and (s > 0).all()):
        raise ValueError("boundaries and scales must be finite, scales > 0")
    if len(b) == 0:
        return np.where(np.isnan(d), np.nan, np.ones_like(d))
    if (np.diff(b) <= 0).any():
        raise ValueError("boundaries must be strictly increasing")
    values = np.concatenate([[1.0], s])
    if ramp > 0:
        if ramp > b[0] or (len(b) > 1 and ramp > np.diff(b).min()):
            raise ValueError("ramp must not exceed the first boundary nor the narrowest interval")
        knots = np.stack([b - ramp, b], axis=1).ravel()
        out = np.interp(d, knots, np.repeat(values, 2)[1:-1])
    elif ramp == 0:
        out = values[np.searchsorted(b, d, side="right")]
    else:
        raise ValueError("ramp must be >= 0")
    return np.where(np.isnan(d), np.nan, out)


def displacement(
    landmark_xy: np.ndarray,
    landmark_radius: np.ndarray | float,
    scale: np.ndarray | float,
    others_xy: np.ndarray,
    others_radius: np.ndarray | float,
    *,
    combine: Literal["max", "sum"] = "max",
    only_growth: bool = False,
) -> np.ndarray:
    """(m, 2) offset moving each surrounding building out of the way of the scaled landmark(s); footprints are
    approximated by circles (centre, radius).

    A building whose centre is closer than ``scale * r_L + r_o`` to a landmark centre is pushed radially away
    from it by exactly the missing distance (a building on the landmark centre goes along +x); the rest get 0.
    Landmarks: one ``(2,)`` or several ``(L, 2)`` with radius and scale scalars or ``(L,)``. With several, a
    building takes the largest push (``combine="max"``: it clears the landmark that covers it most, maybe not
    another one) or the vector sum (``"sum"``). ``only_growth=True`` pushes only by the overlap the scaling
    adds, keeping any overlap that already existed at scale 1 (adjacent buildings, whose circles overlap, then
    move continuously from 0 as the landmark grows instead of jumping clear at once).
    """
    lxy = np.asarray(landmark_xy, dtype=np.float64).reshape(-1, 2)
    n_l = len(lxy)
    lr = np.broadcast_to(np.asarray(landmark_radius, dtype=np.float64), (n_l,))
    ls = np.broadcast_to(np.asarray(scale, dtype=np.float64), (n_l,))
    oxy = np.asarray(others_xy, dtype=np.float64).reshape(-1, 2)
    orad = np.broadcast_to(np.asarray(others_radius, dtype=np.float64), (len(oxy),))
    if combine not in ("max", "sum"):
        raise ValueError(f"combine must be 'max' or 'sum', got {combine!r}")
    out = np.zeros((len(oxy), 2))
    if n_l == 0 or len(oxy) == 0:
        return out
    origin = lxy.mean(axis=0)  # projected coordinates lose precision in the differences otherwise
    lxy, oxy = lxy - origin, oxy - origin
    reach = ls * lr + orad.max()
    hits = cKDTree(oxy).query_ball_point(lxy, r=reach, return_sorted=False)
    j = np.concatenate([np.asarray(h, dtype=np.int64) for h in hits])  # a loop over landmarks only
    i = np.repeat(np.arange(n_l), [len(h) for h in hits])
    delta = oxy[j] - lxy[i]
    dist = np.hypot(delta[:, 0], delta[:, 1])
    push = ls[i] * lr[i] + orad[j] - dist
    if only_growth:
        push -= np.maximum(lr[i] + orad[j] - dist, 0.0)
    keep = push > 0
    i, j, delta, dist, push = i[keep], j[keep], delta[keep], dist[keep], push[keep]
    unit = np.where(dist[:, None] > 0, delta / np.where(dist > 0, dist, 1.0)[:, None], [1.0, 0.0])
    vec = unit * push[:, None]
    if combine == "sum":
        np.add.at(out, j, vec)
    else:
        order = np.lexsort((-push, j))  # per building, the largest push first
        j, vec = j[order], vec[order]
        first = np.ones(len(j), dtype=bool)
        first[1:] = j[1:] != j[:-1]
        out[j[first]] = vec[first]
    return out
