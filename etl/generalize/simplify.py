"""Building footprint simplification: the Sester–Brenner short-edge rules, then vertex importance (thesis
Algorithm 1), for a whole batch of footprints in a metric CRS at once (numpy over flat vertex arrays, no
per-building Python loop).

Every ring (exteriors and holes alike, each polygon of a MultiPolygon on its own) becomes consecutive rows of
flat arrays, in coordinates relative to its polygon's first vertex (projected coordinates are ~1e6 m and their
differences would lose the precision); vertices that survive are written back with their exact input values.

1. Sester–Brenner, over all rings at once, at most ``MAX_PASSES`` passes. Maximal runs of consecutive edges
   shorter than the tolerance are replaced as one unit (a single short edge is a run of one), using the long
   edges A before and B after the run:
     * A, B not parallel (a cut corner, a notch at a corner): both are extended to their intersection;
     * A, B parallel and on one line (a notch or bump in a wall): the run goes, A and B become one edge;
     * A, B parallel with an offset (a step, a staircase): the shorter of A and B goes and the longer one's
       line is extended to meet the next edge (C after B, or Z before A), so right angles stay right angles;
     * A, B antiparallel (a narrow spike or slot): left alone, removing it would move the outline by its length.
   A replacement is taken only if it removes no pinned vertex and moves the outline by at most the
   tolerance, measured against the *original* vertices it replaces (each assigned to one of the new edges,
   the assignment that minimises the largest distance; the original edge that straddles a new corner is
   measured to its bisector crossings). Overlapping replacements in a ring go smallest change first, the
   others wait for the next pass.
2. Vertex importance = turning angle (pi minus the interior angle, 0 when collinear) x incoming x outgoing
   edge length. Every iteration drops the least important vertex of every ring still going, all rings in one
   numpy step (np.minimum.reduceat), so the Python iterations are bounded by the largest ring, not by the
   number of buildings. A ring stops when its least important vertex's removal would move the outline by more
   than the tolerance: its distance to the chord of its neighbours, or that of an original vertex removed
   earlier between them (so errors never pile up past the tolerance), or of the chord's middle to the
   original outline, exceeds it. Rings keep >= 3 vertices. Pinned vertices and corners turning by
   >= ``CORNER_DEG`` next to an edge >= the tolerance are never taken: those are walls the Sester–Brenner pass
   kept on purpose, and cutting them diagonally would break the right angles.
3. Per footprint: a result that changes the area by more than ``max_area_change``, is invalid or is empty
   falls back to the original. The measured error is the densified boundary Hausdorff distance. The checks
   above hold it to the tolerance at every original and made vertex and along every edge replaced in one
   step; an original edge next to a corner made in an earlier pass is only checked at its ends, which on
   jagged outlines lets it exceed the tolerance by a few percent (measured: <= 1.00 x tolerance on OSM
   buildings and orthogonal footprints, <= 1.02 x on noisy random outlines). A dropped hole (below
   tolerance²) counts with its full distance to the rest of the outline.

Pinning (Sester–Brenner rule 3): a vertex within ``PIN_DISTANCE`` of its footprint's ``fixed`` geometry (e.g.
the boundary of a touching neighbour) is never removed nor moved, so a shared wall stays shared.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import shapely

#: A vertex this close (metres) to its footprint's ``fixed`` geometry is pinned.
PIN_DISTANCE = 0.05
#: Long edges around a short-edge run within this angle (degrees) of each other count as parallel.
PARALLEL_DEG = 20.0
#: Parallel long edges whose merged edge would slant by at most this (degrees) count as one line.
COLLINEAR_DEG = 0.25
#: Vertex importance never takes a corner turning by at least this (degrees) next to an edge >= the tolerance.
CORNER_DEG = 40.0
#: Upper bound on the Sester–Brenner passes (each removes every non-overlapping short-edge run at once).
MAX_PASSES = 8

_DUP = 1e-7  # metres: consecutive vertices closer than this are one vertex
_EPS = 1e-9


@dataclass(frozen=True)
class Simplified:
    geoms: np.ndarray  # (n,) object array of shapely MultiPolygon (always MultiPolygon, valid)
    n_vertices_in: np.ndarray  # (n,) int, distinct vertices (closing point not counted)
    n_vertices_out: np.ndarray
    area_in: np.ndarray  # (n,) float
    area_out: np.ndarray
    hausdorff: np.ndarray  # (n,) float, metres
    # (n,) object: 'simplified', 'unchanged' or 'kept_original: <reason>', reason 'area changed by 23% (limit
    # 10%)', 'invalid result: <shapely reason>', 'empty result' or 'invalid input: <shapely reason>' (an
    # invalid input is returned as it came, so only then is the output not valid); 'simplified' gets
    # '; dropped k holes below tolerance²' appended when holes were dropped.
    status: np.ndarray


@dataclass
class _Rings:
    """Current vertices of all rings being simplified, grouped by ring (rows of one ring are consecutive and
    in ring order, no closing vertex), plus each ring's original vertices to measure the error against."""

    xy: np.ndarray  # (v, 2) relative to the ring's polygon origin
    ring: np.ndarray  # (v,) ring id, non-decreasing
    orig: np.ndarray  # (v,) index into orig_xy, -1 for a vertex made by a Sester–Brenner replacement
    opos: np.ndarray  # (v,) float position along the original ring (made vertices sit between two originals)
    pin: np.ndarray  # (v,) bool
    tol: np.ndarray  # (r,) metres
    orig_xy: np.ndarray  # (N, 2) original vertices, grouped by ring
    orig_off: np.ndarray  # (r,) first original vertex of each ring
    orig_n: np.ndarray  # (r,) original vertex count of each ring


@dataclass(frozen=True)
class _Layout:
    start: np.ndarray  # (r,) first row of each ring
    cnt: np.ndarray  # (r,) rows per ring
    local: np.ndarray  # (v,) position within its ring
    nxt: np.ndarray  # (v,) row of the next vertex (cyclic)
    prv: np.ndarray  # (v,) row of the previous vertex (cyclic)


def _layout(ring: np.ndarray, n_rings: int) -> _Layout:
    cnt = np.bincount(ring, minlength=n_rings)
    start = np.cumsum(cnt) - cnt
    row = np.arange(len(ring))
    local = row - start[ring]
    first, last = start[ring], start[ring] + cnt[ring] - 1
    return _Layout(start, cnt, local, np.where(row == last, first, row + 1), np.where(row == first, last, row - 1))


def _cross(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    return a[:, 0] * b[:, 1] - a[:, 1] * b[:, 0]


def _seg_dist(p: np.ndarray, a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Distance from points p to segments a-b (all (k, 2)); a degenerate segment is its point."""
    abx, aby = b[:, 0] - a[:, 0], b[:, 1] - a[:, 1]
    apx, apy = p[:, 0] - a[:, 0], p[:, 1] - a[:, 1]
    den = abx * abx + aby * aby
    t = np.clip((apx * abx + apy * aby) / np.where(den > 0, den, 1.0), 0.0, 1.0)
    return np.hypot(apx - t * abx, apy - t * aby)


def _importance(prev: np.ndarray, cur: np.ndarray, nxt: np.ndarray) -> tuple[np.ndarray, ...]:
    """Vertex importance (turning angle x incoming x outgoing edge length), the turning angle (radians, 0 when
    collinear, pi for a spike) and both edge lengths, for vertices cur between prev and nxt (all (k, 2))."""
    din, dout = cur - prev, nxt - cur
    turn = np.abs(np.arctan2(_cross(din, dout), np.einsum("ij,ij->i", din, dout)))
    lin, lout = np.hypot(din[:, 0], din[:, 1]), np.hypot(dout[:, 0], dout[:, 1])
    return turn * lin * lout, turn, lin, lout


def _expand(count: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """For groups of the given sizes: each element's group and its position within the group."""
    group = np.repeat(np.arange(len(count)), count)
    return group, np.arange(len(group)) - np.repeat(np.cumsum(count) - count, count)


def _group_reduce(ufunc: np.ufunc, values: np.ndarray, count: np.ndarray, empty: float) -> np.ndarray:
    """ufunc.reduce over consecutive groups of the given sizes; ``empty`` for groups of size 0."""
    out = np.full(len(count), empty)
    nz = count > 0
    if nz.any():
        out[nz] = ufunc.reduceat(values, (np.cumsum(count) - count)[nz])
    return out


def _orig_span(st: _Rings, ring: np.ndarray, lo: np.ndarray, hi: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """First original position strictly after lo, and how many lie strictly between lo and hi (cyclic)."""
    n = st.orig_n[ring]
    span = hi - lo
    span = np.where(span <= 0, span + n, span)
    first = np.floor(lo).astype(np.int64) + 1
    return first, np.maximum(np.ceil(lo + span).astype(np.int64) - first, 0)


def _orig_to_path(
    st: _Rings, ring: np.ndarray, lo: np.ndarray, hi: np.ndarray, p0: np.ndarray, p1: np.ndarray
) -> np.ndarray:
    """Largest distance from the original vertices strictly between positions lo and hi to the segment p0-p1
    (the distance to one segment is convex, so the edges between those vertices are no farther)."""
    first, count = _orig_span(st, ring, lo, hi)
    g, j = _expand(count)
    rg = ring[g]
    pts = st.orig_xy[st.orig_off[rg] + (first[g] + j) % st.orig_n[rg]]
    return _group_reduce(np.maximum, _seg_dist(pts, p0[g], p1[g]), count, 0.0)


def _path_dist(x: np.ndarray, p0: np.ndarray, p1: np.ndarray, p2: np.ndarray) -> np.ndarray:
    return np.minimum(_seg_dist(x, p0, p1), _seg_dist(x, p1, p2))


def _straddle(u: np.ndarray, v: np.ndarray, p0: np.ndarray, p1: np.ndarray, p2: np.ndarray) -> np.ndarray:
    """Largest distance from the edge u-v to the path p0-p1-p2. The distance to either segment is convex along
    the edge, their minimum is not: it peaks at the ends or where the edge crosses from one segment's side to
    the other's, i.e. (where both feet are inside the segments) on a bisector of the angle at p1."""
    best = np.maximum.reduce([_path_dist(x, p0, p1, p2) for x in (u, v, 0.5 * (u + v))])
    with np.errstate(divide="ignore", invalid="ignore"):
        e1, e2 = p0 - p1, p2 - p1
        e1 = e1 / np.hypot(e1[:, 0], e1[:, 1])[:, None]
        e2 = e2 / np.hypot(e2[:, 0], e2[:, 1])[:, None]
        for b in (e1 + e2, e1 - e2):
            t, _ = _intersect(u, v - u, p1, b)
            ok = (t >= 0) & (t <= 1)
            x = u + np.where(ok, t, 0.0)[:, None] * (v - u)
            best = np.where(ok, np.maximum(best, _path_dist(x, p0, p1, p2)), best)
    return best


def _point_to_orig(st: _Rings, ring: np.ndarray, lo: np.ndarray, hi: np.ndarray, pt: np.ndarray) -> np.ndarray:
    """Distance from pt to the original outline between the original vertices at or around lo and hi."""
    first, count = _orig_span(st, ring, lo, hi)
    nseg = count + 1  # from the original at/before lo to the one at/after hi
    g, j = _expand(nseg)
    rg, n = ring[g], st.orig_n[ring[g]]
    a = st.orig_xy[st.orig_off[rg] + (first[g] - 1 + j) % n]
    b = st.orig_xy[st.orig_off[rg] + (first[g] + j) % n]
    return _group_reduce(np.minimum, _seg_dist(pt[g], a, b), nseg, np.inf)


def _intersect(p: np.ndarray, d: np.ndarray, q: np.ndarray, e: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Parameters t, w with p + t d == q + w e (NaN/inf for parallel lines)."""
    den = _cross(d, e)
    with np.errstate(divide="ignore", invalid="ignore"):
        return _cross(q - p, e) / den, _cross(q - p, d) / den


def _split_error(
    st: _Rings, ring: np.ndarray, lo: np.ndarray, hi: np.ndarray, p0: np.ndarray, p1: np.ndarray, p2: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """The original outline between positions lo and hi is replaced by the path p0-p1-p2 (p1 made). Each original
    vertex strictly between is assigned to one of the two new edges, a prefix to p0-p1 and the rest to p1-p2,
    so that the largest distance is smallest; the one original edge whose ends go to different new edges is
    measured against both (``_straddle``). Returns that distance and the position for p1 on the original ring
    (between the two parts, never an integer), so later removals measure each original against the edge it
    was assigned to."""
    n = st.orig_n[ring]
    hi = np.where(hi <= lo, hi + n, hi)
    first, count = _orig_span(st, ring, lo, hi)
    g, j = _expand(count)
    base = st.orig_off[ring]
    pts = st.orig_xy[base[g] + (first[g] + j) % n[g]]
    d1, d2 = _seg_dist(pts, p0[g], p1[g]), _seg_dist(pts, p1[g], p2[g])
    # Running maxima within each group: offset each group above all earlier ones so max.accumulate restarts.
    big = (max(d1.max(initial=0.0), d2.max(initial=0.0)) + 1.0) * np.arange(len(count))
    pre1 = np.append(np.maximum.accumulate(d1 + big[g]) - big[g], 0.0)  # max d1 over the group's first ..i
    suf2 = np.append((np.maximum.accumulate((d2 - big[g])[::-1]) + big[g][::-1])[::-1], 0.0)  # i.. its last
    # Split k in 0..c: originals first..first+k-1 go to p0-p1, the edge from first+k-1 to first+k straddles
    # (index -1 / len hit the 0.0 sentinels).
    gk, k = _expand(count + 1)
    at = np.cumsum(count)[gk] - count[gk] + k  # row of the first original going to p1-p2
    u = st.orig_xy[base[gk] + (first[gk] + k - 1) % n[gk]]
    v = st.orig_xy[base[gk] + (first[gk] + k) % n[gk]]
    cost = np.maximum.reduce(
        [
            np.where(k > 0, pre1[at - 1], 0.0),
            np.where(k < count[gk], suf2[at], 0.0),
            _straddle(u, v, p0[gk], p1[gk], p2[gk]),
        ]
    )
    order = np.lexsort((cost, gk))
    best = order[np.unique(gk[order], return_index=True)[1]]  # cheapest split per group (every group has one)
    kb = k[best]
    lft = np.where(kb > 0, first + kb - 1, lo)
    rgt = np.where(kb < count, first + kb, hi)
    return cost[best], (0.5 * (lft + rgt)) % n


@dataclass(frozen=True)
class _Ops:
    """Candidate replacements of runs of short edges, one row each, with their run's ring."""

    run: np.ndarray  # the run replaced
    rank: np.ndarray  # preference among one run's candidates, lowest first
    first: np.ndarray  # int64 offset in the ring of the first vertex removed (from the run's first vertex)
    m: np.ndarray  # int64 vertices removed
    new: np.ndarray  # (k, 2) the vertex made, NaN where none is
    ring: np.ndarray
    cnt: np.ndarray  # vertices in the ring
    start: np.ndarray  # its first row

    @property
    def made(self) -> np.ndarray:
        return ~np.isnan(self.new[:, 0])


def _sester_brenner_pass(st: _Rings, todo: np.ndarray) -> np.ndarray:
    """Replace every non-overlapping run of short edges in the rings flagged in ``todo``, all at once. Returns
    the rings worth another pass: those that changed or had a replacement wait for an overlapping one."""
    n_rings = len(st.tol)
    again = np.zeros(n_rings, dtype=bool)
    lay = _layout(st.ring, n_rings)
    runs = _short_runs(st, lay, todo)
    if runs is None:
        return again
    ops = _candidates(st.xy, lay, *runs)
    if ops is None:
        return again
    good, err, split = _feasible(st, ops)
    if not len(good):
        return again
    take = _non_overlapping(ops, good, err, len(st.xy))
    again[ops.ring[good]] = True
    _apply(st, lay, ops, take, split)
    return again


def _short_runs(st: _Rings, lay: _Layout, todo: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray] | None:
    """The maximal runs of short edges of the rings in ``todo``: (ring, local index of the run's first vertex,
    short edges in the run), or None when there are none."""
    n_rings = len(st.tol)
    xy = st.xy
    edge = xy[lay.nxt] - xy  # edge i runs from vertex i to the next
    short = (np.hypot(edge[:, 0], edge[:, 1]) < st.tol[st.ring]) & todo[st.ring]
    n_short = np.bincount(st.ring, weights=short, minlength=n_rings)
    short &= (n_short < lay.cnt)[st.ring]  # a ring of short edges only has no long edges to extend
    if not short.any():
        return None
    # Rotate each ring to start at a long edge so that no run wraps around.
    has_run = np.bincount(st.ring[short], minlength=n_rings) > 0
    sel = np.flatnonzero(has_run[st.ring])
    longs = sel[~short[sel]]
    first_long = np.zeros(n_rings, np.int64)
    rings_l, i0 = np.unique(st.ring[longs], return_index=True)
    first_long[rings_l] = lay.local[longs[i0]]
    rs = st.ring[sel]
    order = np.lexsort(((lay.local[sel] - first_long[rs]) % lay.cnt[rs], rs))
    eo = sel[order]
    so = short[eo]
    begin = so & ~np.roll(so, 1)  # the first row of every ring is long, so the roll never joins two rings
    run_first = eo[begin]
    k = np.bincount((np.cumsum(begin) - 1)[so], minlength=len(run_first))  # short edges per run
    return st.ring[run_first], lay.local[run_first], k


def _candidates(xy: np.ndarray, lay: _Layout, r: np.ndarray, s: np.ndarray, k: np.ndarray) -> _Ops | None:
    """Every geometrically possible replacement of every run (corner, one line, step either way), or None."""
    cnt, start = lay.cnt[r], lay.start[r]

    def at(j: np.ndarray | int) -> np.ndarray:  # row of the vertex j places after the run's first vertex
        return start + (s + j) % cnt

    a0, a1, b0, b1, c1, z0 = (xy[at(j)] for j in (-1, 0, k, k + 1, k + 2, -2))
    da, db, dc, dz = a1 - a0, b1 - b0, c1 - b1, a0 - z0
    la, lb = np.hypot(da[:, 0], da[:, 1]), np.hypot(db[:, 0], db[:, 1])
    sin_ab, cos_ab = _cross(da, db) / (la * lb), np.einsum("ij,ij->i", da, db) / (la * lb)
    parallel = np.abs(sin_ab) < np.sin(np.radians(PARALLEL_DEG))
    same = parallel & (cos_ab > 0)
    nr = np.arange(len(r))

    # Candidate replacements: (run, preference rank, first removed vertex offset, removed count, new vertex).
    # Parallel lines give inf/NaN parameters, which fail the comparisons.
    ops = []
    t, w = _intersect(a0, da, b0, db)  # corner: A and B meet
    ok = ~parallel & (t >= -_EPS) & (w <= 1 + _EPS) & (cnt - k >= 3)
    ops.append((nr[ok], np.zeros(ok.sum()), s[ok], k[ok] + 1, a0[ok] + t[ok, None] * da[ok]))
    chord = b1 - a0  # one line: the run goes, A and B merge
    slant = np.abs(_cross(da / la[:, None], chord)) / np.maximum(np.hypot(chord[:, 0], chord[:, 1]), _EPS)
    ok = same & (slant <= np.sin(np.radians(COLLINEAR_DEG))) & (cnt - k - 1 >= 3)
    ops.append((nr[ok], np.zeros(ok.sum()), s[ok], k[ok] + 1, np.full((ok.sum(), 2), np.nan)))
    t, w = _intersect(a0, da, b1, dc)  # step, B dropped: A extended to meet C
    ok = same & (t >= -_EPS) & (w <= 1 + _EPS) & (cnt - k - 1 >= 3)
    ops.append((nr[ok], np.where(la >= lb, 1, 2)[ok], s[ok], k[ok] + 2, a0[ok] + t[ok, None] * da[ok]))
    t, w = _intersect(z0, dz, b0, db)  # step, A dropped: B extended back to meet Z
    ok = same & (t >= -_EPS) & (w <= 1 + _EPS) & (cnt - k - 1 >= 3)
    ops.append((nr[ok], np.where(la >= lb, 2, 1)[ok], s[ok] - 1, k[ok] + 2, z0[ok] + t[ok, None] * dz[ok]))
    run, rank, first, m, new = (np.concatenate(c) for c in zip(*ops, strict=True))
    if not len(run):
        return None
    return _Ops(run, rank, first.astype(np.int64), m.astype(np.int64), new, r[run], cnt[run], start[run])


def _feasible(st: _Rings, ops: _Ops) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(the preferred feasible candidate per run, every candidate's error, its split on the original outline):
    no pinned vertex goes, and the outline moves by at most the tolerance."""
    xy, first, m, orr, ocnt, ostart, made, new = (
        st.xy,
        ops.first,
        ops.m,
        ops.ring,
        ops.cnt,
        ops.start,
        ops.made,
        ops.new,
    )
    g, j = _expand(m)
    pinned = np.bincount(g, weights=st.pin[ostart[g] + (first[g] + j) % ocnt[g]], minlength=len(ops.run)) > 0
    # The outline may move by at most the tolerance, measured against the original vertices.
    g1, g2 = ostart + (first - 1) % ocnt, ostart + (first + m) % ocnt
    lo, hi = st.opos[g1], st.opos[g2]
    mid = np.where(made[:, None], new, xy[g1])  # no made vertex: p0-p0-p2, everything goes to p0-p2
    err, split = _split_error(st, orr, lo, hi, xy[g1], mid, xy[g2])
    # ... and the made vertex and the middles of its two edges must lie near the original outline.
    mr, mlo, mhi, y = orr[made], lo[made], hi[made], new[made]
    for pt in (y, 0.5 * (xy[g1[made]] + y), 0.5 * (y + xy[g2[made]])):
        err[made] = np.maximum(err[made], _point_to_orig(st, mr, mlo, mhi, pt))
    good = np.flatnonzero(~pinned & (err <= st.tol[orr] + _EPS))
    if len(good):
        good = good[np.lexsort((ops.rank[good], ops.run[good]))]
        good = good[np.unique(ops.run[good], return_index=True)[1]]  # the preferred feasible one per run
    return good, err, split


def _non_overlapping(ops: _Ops, good: np.ndarray, err: np.ndarray, n_rows: int) -> np.ndarray:
    """Of overlapping replacements (sharing a vertex of their windows, anchors included) the smallest change
    wins."""
    m = ops.m[good]
    prio = np.empty(len(good), np.int64)
    prio[np.lexsort((good, err[good]))] = np.arange(len(good))
    g, j = _expand(m + 2)
    win = ops.start[good][g] + (ops.first[good][g] - 1 + j) % ops.cnt[good][g]
    best = np.full(n_rows, len(good))
    np.minimum.at(best, win, prio[g])
    return good[np.logical_and.reduceat(best[win] == prio[g], np.cumsum(m + 2) - (m + 2))]


def _apply(st: _Rings, lay: _Layout, ops: _Ops, take: np.ndarray, split: np.ndarray) -> None:
    """Drop the removed rows, insert each made vertex right after its first anchor."""
    xy = st.xy
    g, j = _expand(ops.m[take])
    keep = np.ones(len(xy), dtype=bool)
    keep[ops.start[take][g] + (ops.first[take][g] + j) % ops.cnt[take][g]] = False
    tk = take[ops.made[take]]
    g1 = ops.start[tk] + (ops.first[tk] - 1) % ops.cnt[tk]
    key = np.concatenate([lay.local[keep].astype(float), lay.local[g1] + 0.5])
    ring = np.concatenate([st.ring[keep], ops.ring[tk]])
    o = np.lexsort((key, ring))
    st.xy = np.concatenate([xy[keep], ops.new[tk]])[o]
    st.ring = ring[o]
    st.orig = np.concatenate([st.orig[keep], np.full(len(tk), -1)])[o]
    st.opos = np.concatenate([st.opos[keep], split[tk]])[o]
    st.pin = np.concatenate([st.pin[keep], np.zeros(len(tk), dtype=bool)])[o]
    _drop_duplicates(st)


def _drop_duplicates(st: _Rings) -> None:
    """A made vertex that landed on its neighbour (e.g. an extended wall meeting the next corner) goes; the
    input's own vertices are never touched here."""
    lay = _layout(st.ring, len(st.tol))
    d = st.xy[lay.nxt] - st.xy
    made = st.orig < 0
    dup = np.flatnonzero((np.hypot(d[:, 0], d[:, 1]) < _DUP) & (made | made[lay.nxt]))
    if not len(dup):
        return
    drop = np.unique(np.where(made[lay.nxt[dup]], lay.nxt[dup], dup))
    lost = np.bincount(st.ring[drop], minlength=len(st.tol))
    drop = drop[(lay.cnt - lost >= 3)[st.ring[drop]]]
    keep = np.ones(len(st.xy), dtype=bool)
    keep[drop] = False
    st.xy, st.ring, st.orig, st.opos, st.pin = st.xy[keep], st.ring[keep], st.orig[keep], st.opos[keep], st.pin[keep]


def _remove_unimportant(st: _Rings) -> None:
    """Algorithm 1 on all rings at once: each iteration drops the least important vertex of every ring that is
    still going; a ring stops for good when that vertex's removal would move the outline by more than its
    tolerance. All importances of the going rings are recomputed per iteration (same result as updating the two
    neighbours, and one vectorised pass costs no more than the per-ring argmin it needs anyway)."""
    alive = np.ones(len(st.xy), dtype=bool)
    idx = np.arange(len(st.xy))  # rows of the rings still going
    corner = np.radians(CORNER_DEG)
    while len(idx):
        r = st.ring[idx]
        st0 = np.concatenate([[0], np.flatnonzero(r[1:] != r[:-1]) + 1])
        cnt = np.diff(np.append(st0, len(idx)))
        seg = np.repeat(np.arange(len(st0)), cnt)
        row = np.arange(len(idx))
        first, last = st0[seg], st0[seg] + cnt[seg] - 1
        nx, pv = np.where(row == last, first, row + 1), np.where(row == first, last, row - 1)
        p = st.xy[idx]
        imp, turn, lin, lout = _importance(p[pv], p, p[nx])
        # Compared at float32 precision: importances equal but for rounding noise (a regular polygon) tie
        # exactly and the first in ring order goes, so symmetric shapes simplify symmetrically whatever the
        # coordinate offset.
        imp = imp.astype(np.float32)
        tol = st.tol[r]
        imp[st.pin[idx] | ((turn >= corner) & ((lin >= tol) | (lout >= tol)))] = np.inf
        low = np.minimum.reduceat(imp, st0)
        cand = np.flatnonzero(imp == low[seg])
        cand = cand[np.unique(seg[cand], return_index=True)[1]]  # first least important vertex per ring
        go = np.isfinite(low) & (cnt > 3)
        c = cand[go]
        err = np.full(len(st0), np.inf)
        rc = r[c]
        a, b, lo, hi = p[pv[c]], p[nx[c]], st.opos[idx[pv[c]]], st.opos[idx[nx[c]]]
        err[go] = np.maximum.reduce(
            [_seg_dist(p[c], a, b), _orig_to_path(st, rc, lo, hi, a, b), _point_to_orig(st, rc, lo, hi, 0.5 * (a + b))]
        )
        go &= err <= st.tol[r[st0]] + _EPS
        alive[idx[cand[go]]] = False
        keep = go[seg]
        keep[cand[go]] = False
        idx = idx[keep]
    st.xy, st.ring, st.orig, st.opos, st.pin = (a[alive] for a in (st.xy, st.ring, st.orig, st.opos, st.pin))


def _percent(x: float, limit: float) -> str:
    """x as a percentage, with as many decimals as it takes not to read like the limit."""
    for digits in range(4):
        txt = f"{x:.{digits}%}"
        if float(txt[:-1]) != round(100 * limit, digits) or x == limit:
            return txt
    return txt


def _verdict(
    changed: np.ndarray, result: np.ndarray, area_in: np.ndarray, area_out: np.ndarray, max_area_change: float
) -> tuple[np.ndarray, np.ndarray]:
    """Per footprint: whether the result fails (the original is kept) and why. Vectorised checks; strings are
    only built for the (few) failures."""
    why = np.full(len(result), None, dtype=object)
    empty = changed & shapely.is_empty(result)
    invalid = changed & ~empty & ~shapely.is_valid(result)
    with np.errstate(divide="ignore", invalid="ignore"):
        rel = np.where(area_in > 0, np.abs(area_out - area_in) / area_in, np.where(area_out == area_in, 0.0, np.inf))
    area = changed & ~empty & ~invalid & (rel > max_area_change)
    why[empty] = "empty result"
    why[invalid] = "invalid result: " + shapely.is_valid_reason(result[invalid]).astype(object)
    why[area] = [f"area changed by {_percent(a, max_area_change)} (limit {max_area_change:.0%})" for a in rel[area]]
    return empty | invalid | area, why


@dataclass(frozen=True)
class _Footprints:
    """The input taken apart: cleaned MultiPolygons, their polygons, rings and vertices (closing ones left out)."""

    original: np.ndarray  # per footprint: repeated points removed, exteriors counter-clockwise (the fallback)
    poly_owner: np.ndarray  # per polygon: its footprint
    ring_poly: np.ndarray  # per ring: its polygon
    ring_owner: np.ndarray  # per ring: its footprint
    ring_cnt: np.ndarray  # per ring: its vertices
    coords: np.ndarray  # (v, 2) every ring's vertices
    coord_ring: np.ndarray  # per vertex: its ring
    n_in: np.ndarray  # per footprint: its vertices
    area_in: np.ndarray
    valid_in: np.ndarray


def simplify_footprints(
    geoms: np.ndarray, tolerance: float | np.ndarray, *, max_area_change: float = 0.1, fixed: np.ndarray | None = None
) -> Simplified:
    """Simplify polygonal footprints (shapely array, metric CRS); ``tolerance`` in metres, scalar or per
    footprint, 0 = leave unchanged; ``fixed``: per footprint a geometry (or None) whose nearby vertices are
    pinned. Results are MultiPolygons, exteriors counter-clockwise and holes clockwise, 2D."""
    geoms = np.asarray(geoms, dtype=object)
    n = len(geoms)
    tol = np.broadcast_to(np.asarray(tolerance, dtype=np.float64), (n,)).copy()
    if not np.all(np.isfinite(tol) & (tol >= 0)):
        raise ValueError("tolerance must be finite and >= 0")
    if not max_area_change >= 0:
        raise ValueError("max_area_change must be >= 0")
    missing = shapely.is_missing(geoms) | shapely.is_empty(geoms)
    geoms = np.where(missing, shapely.Polygon(), geoms)
    if not np.all(np.isin(shapely.get_type_id(geoms), (3, 6))):
        raise TypeError("footprints must be Polygons or MultiPolygons")
    if fixed is not None:
        fixed = np.asarray(fixed, dtype=object)
        if fixed.shape != (n,):
            raise ValueError("fixed needs one entry (geometry or None) per footprint")

    fp = _decompose(geoms)
    work = ~missing & fp.valid_in & (tol > 0)
    st, used, poly_origin, n_dropped = _working_rings(fp, tol, work, fixed)
    todo = np.ones(len(used), dtype=bool)
    for _ in range(MAX_PASSES):
        todo = _sester_brenner_pass(st, todo)
        if not todo.any():
            break
    _remove_unimportant(st)
    result, n_out, changed = _rebuild(fp, st, used, poly_origin, work, n_dropped)

    area_out = shapely.area(result)
    failed, why = _verdict(changed, result, fp.area_in, area_out, max_area_change)
    original = fp.original
    result[failed], area_out[failed], n_out[failed] = original[failed], fp.area_in[failed], fp.n_in[failed]
    status = np.full(n, "unchanged", dtype=object)
    ok = changed & ~failed
    status[ok] = "simplified"
    status[failed] = "kept_original: " + why[failed]
    notes = ok & (n_dropped > 0)
    dropped_txt = n_dropped[notes].astype(str).astype(object)
    status[notes] = status[notes] + "; dropped " + dropped_txt + " holes below tolerance²"
    bad_in = np.flatnonzero(~missing & ~fp.valid_in)
    status[bad_in] = "kept_original: invalid input: " + shapely.is_valid_reason(original[bad_in]).astype(object)

    hausdorff = np.zeros(n)
    if ok.any():
        hausdorff[ok] = shapely.hausdorff_distance(
            shapely.boundary(original[ok]), shapely.boundary(result[ok]), densify=0.25
        )
    return Simplified(
        geoms=result,
        n_vertices_in=fp.n_in,
        n_vertices_out=n_out,
        area_in=fp.area_in,
        area_out=area_out,
        hausdorff=hausdorff,
        status=status,
    )


def _decompose(geoms: np.ndarray) -> _Footprints:
    """Repeated points removed, exteriors counter-clockwise, as MultiPolygons, and taken apart into rings."""
    n = len(geoms)
    clean = shapely.orient_polygons(shapely.remove_repeated_points(geoms), exterior_cw=False)
    polys, poly_owner = shapely.get_parts(clean, return_index=True)
    solid = ~shapely.is_empty(polys)
    polys, poly_owner = polys[solid], poly_owner[solid]
    original = np.empty(n, dtype=object)
    original[:] = shapely.MultiPolygon()
    shapely.multipolygons(polys, indices=poly_owner, out=original)
    rings, ring_poly = shapely.get_rings(polys, return_index=True)
    coords, coord_ring = shapely.get_coordinates(rings, return_index=True)
    ring_cnt = np.bincount(coord_ring, minlength=len(rings)) - 1  # closing vertex not counted
    not_closing = np.ones(len(coords), dtype=bool)
    not_closing[np.cumsum(ring_cnt + 1) - 1] = False
    coords, coord_ring = coords[not_closing], coord_ring[not_closing]
    ring_owner = poly_owner[ring_poly]
    return _Footprints(
        original=original,
        poly_owner=poly_owner,
        ring_poly=ring_poly,
        ring_owner=ring_owner,
        ring_cnt=ring_cnt,
        coords=coords,
        coord_ring=coord_ring,
        n_in=np.bincount(ring_owner, weights=ring_cnt, minlength=n).astype(np.int64),
        area_in=shapely.area(original),
        valid_in=shapely.is_valid(original),
    )


def _working_rings(
    fp: _Footprints, tol: np.ndarray, work: np.ndarray, fixed: np.ndarray | None
) -> tuple[_Rings, np.ndarray, np.ndarray, np.ndarray]:
    """(the rings to simplify, relative to their polygon's first vertex; which input rings they are; each
    polygon's origin; holes dropped per footprint). Holes below tolerance² go."""
    n, n_rings = len(work), len(fp.ring_cnt)
    coords, coord_ring, ring_cnt, ring_poly, ring_owner = (
        fp.coords,
        fp.coord_ring,
        fp.ring_cnt,
        fp.ring_poly,
        fp.ring_owner,
    )
    ring_first = np.cumsum(ring_cnt) - ring_cnt
    is_hole = np.ones(n_rings, dtype=bool)
    is_hole[np.unique(ring_poly, return_index=True)[1]] = False  # a polygon's first ring is its exterior
    poly_origin = np.zeros((len(fp.poly_owner), 2))
    poly_origin[ring_poly[~is_hole]] = coords[ring_first[~is_hole]]
    rel = coords - poly_origin[ring_poly[coord_ring]]
    nxt_rel = rel[
        np.where(
            np.arange(len(rel)) == (ring_first + ring_cnt - 1)[coord_ring],
            ring_first[coord_ring],
            np.arange(len(rel)) + 1,
        )
    ]
    ring_area = 0.5 * np.abs(np.bincount(coord_ring, weights=_cross(rel, nxt_rel), minlength=n_rings))
    dropped = work[ring_owner] & is_hole & (ring_area < tol[ring_owner] ** 2)
    n_dropped = np.bincount(ring_owner[dropped], minlength=n)
    use = work[ring_owner] & ~dropped
    used = np.flatnonzero(use)
    new_id = np.full(n_rings, -1)
    new_id[used] = np.arange(len(used))
    vsel = use[coord_ring]
    pin = np.zeros(len(coords), dtype=bool)
    if fixed is not None:
        has_fix = ~shapely.is_missing(fixed) & ~shapely.is_empty(fixed)
        check = np.flatnonzero(vsel & has_fix[ring_owner[coord_ring]])
        pin[check] = shapely.dwithin(shapely.points(coords[check]), fixed[ring_owner[coord_ring[check]]], PIN_DISTANCE)
    orig_rows = np.flatnonzero(vsel)
    sel_ring = new_id[coord_ring[orig_rows]]
    orig_n = ring_cnt[used]
    orig_off = np.cumsum(orig_n) - orig_n
    st = _Rings(
        xy=rel[orig_rows],
        ring=sel_ring,
        orig=orig_rows,
        opos=(np.arange(len(orig_rows)) - orig_off[sel_ring]).astype(np.float64),
        pin=pin[orig_rows],
        tol=tol[ring_owner[used]],
        orig_xy=rel[orig_rows],
        orig_off=orig_off,
        orig_n=orig_n,
    )
    return st, used, poly_origin, n_dropped


def _rebuild(
    fp: _Footprints, st: _Rings, used: np.ndarray, poly_origin: np.ndarray, work: np.ndarray, n_dropped: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(footprints with the simplified rings, vertices per footprint, which changed). Rings go back to absolute
    coordinates: original vertices exactly as they came, made ones shifted back."""
    n = len(work)
    ring_owner = fp.ring_owner
    orig_n = fp.ring_cnt[used]
    out_cnt = np.bincount(st.ring, minlength=len(used))
    made = np.bincount(st.ring, weights=st.orig < 0, minlength=len(used)) > 0
    ring_changed = (out_cnt != orig_n) | made
    changed = work & ((np.bincount(ring_owner[used], weights=ring_changed, minlength=n) > 0) | (n_dropped > 0))
    absxy = np.where(
        (st.orig >= 0)[:, None], fp.coords[np.maximum(st.orig, 0)], st.xy + poly_origin[fp.ring_poly[used]][st.ring]
    )
    result = fp.original.copy()
    rebuild = changed[ring_owner[used]]  # every kept ring of a changed footprint
    if rebuild.any():
        rr = np.flatnonzero(rebuild)
        rows = rebuild[st.ring]
        new_rings = shapely.linearrings(absxy[rows], indices=np.searchsorted(rr, st.ring[rows]))
        rpoly = fp.ring_poly[used[rr]]
        upoly, pidx = np.unique(rpoly, return_inverse=True)
        new_polys = shapely.polygons(new_rings, indices=pidx)
        shapely.multipolygons(new_polys, indices=fp.poly_owner[upoly], out=result)
    n_out = fp.n_in.copy()
    n_out[changed] = np.bincount(ring_owner[used], weights=out_cnt, minlength=n).astype(np.int64)[changed]
    return result, n_out, changed
