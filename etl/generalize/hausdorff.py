"""Symmetric Hausdorff distance between the surfaces of two triangle soups, owner by owner, for a whole batch.

For each owner k, h(A -> B) = max over points p of A of d(p, B), and the answer is max(h(A -> B), h(B -> A)).
d(p, B) is exact: the closest point on each candidate triangle (Ericson's region method, vectorised) and the
minimum over them. Rather than a fixed grid of samples, the maximum over p is bracketed and refined:

  * lower bound: L(k) = the largest d(v, B) over the points v evaluated so far - a distance actually reached;
  * upper bound ub(t) >= max over p in t of d(p, B) for every triangle t of A, the smallest of
      - Lipschitz: every point of t is within (longest edge) / sqrt(3) of a corner of t (the circumradius if t
        is acute, at most half the longest edge if not) and d(., B) changes no faster than p moves;
      - convexity: p -> d(p, u) is convex for one triangle u of B, so over t it peaks at a corner of t:
        ub(t) = min over u of (max over the corners v of t of d(v, u));
      - sectors: the half-planes from a vertex w of B along its edges, around w's normal, partition space;
        they cut t into convex pieces, each bounded by convexity against the triangle of B spanning its
        sector (a piece reaching past that triangle's far edge is cut once more, by the plane through that edge
        halfway between it and the triangle beyond, and its outer part bounded against the triangle beyond).
        This settles triangles lying across edges and corners of B, where no single u is close to all of t;
  * a triangle with ub(t) <= L(k) + spacing cannot hide anything worth finding; the others are split in four at
    their edge midpoints and go round again. The Lipschitz bound stops this at the latest once the edges are
    shorter than sqrt(3) * spacing - the points of a uniform barycentric grid of that spacing - but where the
    surfaces run close together (a decimated mesh and its original) most triangles settle at once, without
    evaluating any point inside them.

Accuracy: the answer is a distance actually reached, so never above the true Hausdorff distance h, and every
piece of A ends bounded by L + spacing, so the answer is >= h - spacing (up to float rounding, ~1e-9 m).

Candidates: B is covered by small spheres (its triangles, the big ones split in four until no wider than the
owner's median), held in one k-d tree with the owner as a fourth coordinate, owners so far apart on it that
they never meet. The nearest triangle to a point v at most ub(v) away has a sphere within ub(v) + reach of v,
and querying with max(ub(v), L + spacing) + reach also yields every triangle the convexity bound can use.
Vertices shared by several triangles are measured once. Work is depth first in batches of at most ``_BATCH``
triangles, so memory stays bounded whatever the owner sizes.

Coordinates are taken relative to a per-owner origin first: projected coordinates (~1e6 m) would cost the
closest-point arithmetic its precision.
"""

from __future__ import annotations

import itertools
import math

import numpy as np
from scipy.spatial import cKDTree

from etl.geom.check import weld

_BATCH = 1 << 15  # triangles refined together: a few hundred thousand (point, triangle) pairs
_FAN_CHUNK = 1 << 12  # triangles cut by sectors at once (~5 pieces each): small enough to stay in cache
_CHUNK = 1 << 13  # closest-point evaluations at once: small enough to stay in cache (2-3x faster)
_EPS = 1e-7  # metres of slack in the candidate radii, far above the rounding of owner-relative coordinates
_SQRT3 = np.sqrt(3.0)


def hausdorff(
    a: np.ndarray, a_owner: np.ndarray, b: np.ndarray, b_owner: np.ndarray, n: int, spacing: float
) -> np.ndarray:
    """(n,) symmetric Hausdorff distance in metres between the surfaces of a[a_owner == k] and b[b_owner == k]
    for every k; NaN where either side has no triangles. Within ``spacing`` below the true distance, never
    above it (see the module docstring)."""
    a = np.asarray(a, dtype=np.float64).reshape(-1, 3, 3)
    b = np.asarray(b, dtype=np.float64).reshape(-1, 3, 3)
    a_owner = np.asarray(a_owner, dtype=np.int64).reshape(-1)
    b_owner = np.asarray(b_owner, dtype=np.int64).reshape(-1)
    if len(a) != len(a_owner) or len(b) != len(b_owner):
        raise ValueError("one owner per triangle")
    for o in (a_owner, b_owner):
        if len(o) and (o.min() < 0 or o.max() >= n):
            raise ValueError("owners must lie in [0, n)")
    if not spacing > 0:
        raise ValueError("spacing must be positive")
    out = np.full(n, np.nan)
    both = (np.bincount(a_owner, minlength=n) > 0) & (np.bincount(b_owner, minlength=n) > 0)
    if not both.any():
        return out
    ka, kb = both[a_owner], both[b_owner]
    a, a_owner, b, b_owner = a[ka], a_owner[ka], b[kb], b_owner[kb]

    origin = np.zeros((n, 3))
    firsts = np.unique(a_owner, return_index=True)
    origin[firsts[0]] = a[firsts[1], 0]
    a = a - origin[a_owner][:, None, :]
    b = b - origin[b_owner][:, None, :]
    # owners sit this far apart on the k-d tree's fourth axis: more than any radius asked of it
    extent = max(np.abs(a).max(), np.abs(b).max())
    lane = 16.0 * extent + 4.0 * spacing + 1.0

    # the second direction only has to find out whether it beats the first: it starts from its answer
    h = _directed(a, a_owner, b, b_owner, n, spacing, lane, _directed(b, b_owner, a, a_owner, n, spacing, lane))
    out[both] = h[both]
    return out


class _Targets:
    """The triangles distances are measured to, packed for the region method: a, ab, ac, ab.ab, ab.ac, ac.ac."""

    def __init__(self, tri: np.ndarray) -> None:
        ab, ac = tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]
        self.pack = np.column_stack(
            [
                tri[:, 0],
                ab,
                ac,
                np.einsum("ij,ij->i", ab, ab),
                np.einsum("ij,ij->i", ab, ac),
                np.einsum("ij,ij->i", ac, ac),
            ]
        )


def _sphere(tri: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Centroid and the radius around it that holds the whole triangle."""
    c = tri.mean(axis=1)
    return c, np.sqrt(((tri - c[:, None, :]) ** 2).sum(axis=2).max(axis=1))


def _directed(
    src: np.ndarray,
    src_owner: np.ndarray,
    dst: np.ndarray,
    dst_owner: np.ndarray,
    n: int,
    spacing: float,
    lane: float,
    floor: np.ndarray | None = None,
) -> np.ndarray:
    """(n,) max(floor, max over the surface of src[k] of the distance to dst[k]), within spacing below the
    truth (floor: a distance already reached, default 0). Owners without src triangles keep the floor."""
    tg = _Targets(dst)
    centre, parent, reach = _proxies(dst, dst_owner, n)
    tree = cKDTree(np.column_stack([centre, dst_owner[parent] * lane]))
    fans: _Fans | None = None  # built on first need: identical surfaces never need it
    lower = np.zeros(n) if floor is None else floor.copy()
    stack = [(src, src_owner, np.full(len(src), np.inf))]
    while stack:
        tri, own, ub_parent = stack.pop()
        live = ub_parent > lower[own] + spacing  # the bound may have risen since this batch was queued
        tri, own = tri[live], own[live]
        if len(tri) > _BATCH:
            half = len(tri) // 2
            stack.append((tri[half:], own[half:], np.full(len(tri) - half, np.inf)))
            stack.append((tri[:half], own[:half], np.full(half, np.inf)))
            continue
        if not len(tri):
            continue

        pid, pts, p_own = _weld(tri, own)
        q = np.column_stack([pts, p_own * lane])
        _, near = tree.query(q, workers=-1)
        ub_v = _distances(pts, np.arange(len(pts)), parent[near], tg)  # a first upper bound per point
        enough = lower[p_own] + spacing  # a triangle u farther than this from a vertex cannot settle its triangle
        radius = np.maximum(ub_v, enough) + reach[p_own] + _EPS
        lists = tree.query_ball_point(q, radius, return_sorted=False, workers=-1)
        counts = np.fromiter(map(len, lists), dtype=np.int64, count=len(lists))
        pp = np.repeat(np.arange(len(pts)), counts)
        pu = parent[np.fromiter(itertools.chain.from_iterable(lists), dtype=np.int64, count=int(counts.sum()))]
        key = np.sort(pp * len(dst) + pu)  # one row per (point, triangle), sorted by point
        key = key[np.r_[True, key[1:] != key[:-1]]]
        pp, pu = key // len(dst), key % len(dst)
        d = _distances(pts, pp, pu, tg)

        # exact distance of every point: its nearest triangle is always among the candidates
        dv = ub_v.copy()
        head = np.flatnonzero(np.r_[True, pp[1:] != pp[:-1]])
        if len(head):
            dv[pp[head]] = np.minimum(dv[pp[head]], np.minimum.reduceat(d, head))
        np.maximum.at(lower, p_own, dv)

        longest = np.sqrt(
            np.max([((tri[:, i] - tri[:, j]) ** 2).sum(axis=1) for i, j in ((0, 1), (1, 2), (2, 0))], axis=0)
        )
        ub = np.minimum(_convex(pid, pp, pu, d, enough, len(dst)), dv[pid].max(axis=1) + longest / _SQRT3)
        split = ub > lower[own] + spacing
        # a triangle across edges of B: cut it by the sectors around the nearest vertex of B
        if split.any():
            fans = fans or _Fans(dst, dst_owner, lane)
            i = np.flatnonzero(split)
            for c in range(0, len(i), _FAN_CHUNK):
                j = i[c : c + _FAN_CHUNK]
                ub[j] = np.minimum(ub[j], fans.bound(tri[j], own[j], tg))
            split[i] = ub[i] > lower[own[i]] + spacing
        if split.any():
            stack.append((_subdivide(tri[split]), np.repeat(own[split], 4), np.repeat(ub[split], 4)))
    return lower


def _proxies(tri: np.ndarray, owner: np.ndarray, n: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Spheres covering the triangles for the k-d tree: centres, the triangle each belongs to, and per owner
    the largest radius. Triangles wider than their owner's median are split in four until they are not (one big
    roof triangle would otherwise widen every query), within a budget of 16 spheres per triangle."""
    _, r = _sphere(tri)
    cnt = np.bincount(owner, minlength=n)
    order = np.lexsort((r, owner))
    median = np.ones(n)
    has = cnt > 0
    median[has] = r[order[(np.cumsum(cnt) - cnt + cnt // 2)[has]]]
    cap = np.maximum(median, 1e-3)[owner]
    steps = np.ceil(np.log2(np.maximum(r / cap, 1.0))).astype(np.int64)  # each split halves the radius
    while (4.0**steps).sum() > 16 * len(tri):
        steps = np.minimum(steps, steps.max() - 1)
    centres, parents, radii = [], [], []
    for k in np.unique(steps):
        idx = np.flatnonzero(steps == k)
        pieces = tri[idx]
        for _ in range(k):
            pieces = _subdivide(pieces)
        c, pr = _sphere(pieces)
        centres.append(c)
        parents.append(np.repeat(idx, 4**k))
        radii.append(pr)
    parent = np.concatenate(parents)
    reach = np.zeros(n)
    np.maximum.at(reach, owner[parent], np.concatenate(radii))
    return np.concatenate(centres), parent, reach


def _rays(
    pid: np.ndarray, vert: np.ndarray, axis: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """The distinct edges leaving every vertex w of B (triangles ``pid`` of vertices ``vert``), sorted by angle
    around w's axis: (w, the other end x, angle, unit direction in the plane normal to the axis, up to two
    triangles on the edge (-1 padded), and the plane's two axes e1, e2 per vertex)."""
    # every edge leaving w, once per triangle using it: (w, x, triangle), sorted by angle around w
    w = np.concatenate([pid[:, 0], pid[:, 1], pid[:, 2], pid[:, 0], pid[:, 1], pid[:, 2]])
    x = np.concatenate([pid[:, 1], pid[:, 2], pid[:, 0], pid[:, 2], pid[:, 0], pid[:, 1]])
    u = np.tile(np.arange(len(pid)), 6)
    e1 = np.cross(axis, np.where(np.abs(axis[:, :1]) < 0.9, [[1.0, 0, 0]], [[0, 1.0, 0]]))
    e1 /= np.linalg.norm(e1, axis=1)[:, None]
    e2 = np.cross(axis, e1)
    q = vert[x] - vert[w]
    ang = np.arctan2(np.einsum("ij,ij->i", q, e2[w]), np.einsum("ij,ij->i", q, e1[w]))
    order = np.lexsort((x, ang, w))
    w, x, u, ang = w[order], x[order], u[order], ang[order]
    ray = np.r_[True, (w[1:] != w[:-1]) | (x[1:] != x[:-1])]
    # rays (distinct edges leaving w) with up to two triangles each (a manifold edge has exactly two)
    r_w, r_x, r_ang = w[ray], x[ray], ang[ray]
    r_dir = np.cos(r_ang)[:, None] * e1[r_w] + np.sin(r_ang)[:, None] * e2[r_w]
    r_tri = np.full((len(r_w), 2), -1, dtype=np.int64)
    r_tri[:, 0] = u[ray]
    again = np.flatnonzero(~ray)
    again = again[ray[again - 1]]  # a ray's second row
    r_tri[np.cumsum(ray)[again] - 1, 1] = u[again]
    return r_w, r_x, r_ang, r_dir, r_tri, e1, e2


class _Fans:
    """Around every vertex w of B (vertices welded by exact coordinates, per owner): an axis (the area-weighted
    normal) and the sectors between the edges leaving w, in angular order around the axis, each at most a half
    turn. Per sector: the triangle of B spanning it, the triangle beyond that one's far edge, and the plane
    through that far edge halfway between the two; where there is no spanning triangle, the triangles on the
    sector's two edges (up to 4, -1 padded)."""

    def __init__(self, dst: np.ndarray, dst_owner: np.ndarray, lane: float) -> None:
        pid, vert, v_owner = _weld(dst, dst_owner)
        nvert = len(vert)
        self.vert, self.lane = vert, lane
        self.tree = cKDTree(np.column_stack([vert, v_owner * lane]))
        normal = np.cross(dst[:, 1] - dst[:, 0], dst[:, 2] - dst[:, 0])
        corner = pid.reshape(-1)
        axis = np.column_stack(
            [np.bincount(corner, weights=np.repeat(normal[:, j], 3), minlength=nvert) for j in range(3)]
        )
        with np.errstate(divide="ignore", invalid="ignore"):
            axis = axis / np.linalg.norm(axis, axis=1)[:, None]
            unit = normal / np.linalg.norm(normal, axis=1)[:, None]
        self.axis = axis  # NaN where the normals cancel: no sectors there
        r_w, r_x, r_ang, r_dir, r_tri, e1, e2 = _rays(pid, vert, axis)
        # sectors: from each ray to the next one around the same vertex (cyclically)
        first = np.r_[True, r_w[1:] != r_w[:-1]]
        last = np.r_[r_w[1:] != r_w[:-1], True]
        nxt = np.arange(len(r_w)) + 1
        nxt[last] = np.flatnonzero(first)
        gap = (r_ang[nxt] - r_ang) % (2 * np.pi)
        gap[first & last] = 2 * np.pi  # a lone ray: the whole turn
        ok = np.isfinite(gap) & (gap > 0)
        wide = ok & (gap >= np.pi)  # half a turn or more: split in the middle to keep sectors convex
        mid_ang = r_ang + gap / 2
        mid = np.cos(mid_ang)[:, None] * e1[r_w] + np.sin(mid_ang)[:, None] * e2[r_w]
        on_next = (r_tri[:, :, None] == r_tri[nxt][:, None, :]).any(axis=2) & (r_tri >= 0)
        span = np.where(on_next[:, 0], r_tri[:, 0], np.where(on_next[:, 1], r_tri[:, 1], -1))
        cand = np.where(
            (span >= 0)[:, None],
            np.column_stack([span, np.full((len(span), 3), -1)]),
            np.column_stack([r_tri, r_tri[nxt]]),
        )
        # beyond the far edge (x, x_next) of the spanning triangle
        rkey = r_w * nvert + r_x
        by_key = np.argsort(rkey)
        far = by_key[np.minimum(np.searchsorted(rkey[by_key], r_x * nvert + r_x[nxt]), len(rkey) - 1)]
        found = (rkey[far] == r_x * nvert + r_x[nxt]) & (span >= 0)
        beyond = np.where(r_tri[far, 0] != span, r_tri[far, 0], r_tri[far, 1])
        beyond = np.where(found, beyond, -1)
        with np.errstate(invalid="ignore"):
            cut = np.cross(vert[r_x[nxt]] - vert[r_x], unit[span] + unit[beyond])
            side = np.sign(np.einsum("ij,ij->i", cut, dst[span].mean(axis=1) - vert[r_x]))
        cut *= side[:, None]
        beyond = np.where((beyond >= 0) & (side != 0) & np.isfinite(cut).all(axis=1), beyond, -1)

        def both(a: np.ndarray, b: np.ndarray | None = None) -> np.ndarray:
            return np.concatenate([a[ok], (a if b is None else b)[wide]])

        sv = both(r_w)
        o = np.argsort(sv, kind="stable")
        self.start = np.searchsorted(sv[o], np.arange(nvert + 1))
        self.ra = both(r_dir, mid)[o]
        self.rb = both(np.where(wide[:, None], mid, r_dir[nxt]), r_dir[nxt])[o]
        self.cand, self.span, self.beyond = both(cand)[o], both(span)[o], both(beyond)[o]
        self.cut, self.cut_at = both(cut)[o], both(vert[r_x])[o]

    def bound(self, tri: np.ndarray, own: np.ndarray, tg: _Targets) -> np.ndarray:
        """(k,) upper bound of d(., B) over each triangle, from the sectors around the vertex of B nearest its
        centroid: the sectors partition space, so they cut the triangle into convex pieces, and over each piece
        the distance to any one triangle of B peaks at a corner of the piece. A piece reaching past the far
        edge of its sector's triangle is cut once more there, and its outer part measured to the triangle
        beyond."""
        k = len(tri)
        _, w = self.tree.query(np.column_stack([tri.mean(axis=1), own * self.lane]), workers=-1)
        cnt = self.start[w + 1] - self.start[w]
        pt = np.repeat(np.arange(k), cnt)
        ps = np.repeat(self.start[w] - np.cumsum(cnt) + cnt, cnt) + np.arange(int(cnt.sum()))
        at = self.vert[w[pt]]
        axis = self.axis[w[pt]]
        rel = tri[pt] - at[:, None, :]
        h1, h2 = np.cross(axis, self.ra[ps]), np.cross(self.rb[ps], axis)
        # sectors the triangle surely misses (all corners behind one of the two planes) are not clipped
        hit = np.flatnonzero(
            (np.einsum("pvj,pj->pv", rel, h1) >= 0).any(axis=1) & (np.einsum("pvj,pj->pv", rel, h2) >= 0).any(axis=1)
        )
        pt, ps, at, rel, h2 = pt[hit], ps[hit], at[hit], rel[hit], h2[hit]
        rel, nv = _clip(rel, np.full(len(pt), 3), h1[hit])
        rel, nv = _clip(rel, nv, h2)
        poly = rel + at[:, None, :]
        best = np.full(len(pt), np.inf)
        cut_twice = (self.beyond[ps] >= 0) & (nv > 0)
        for c in range(self.cand.shape[1]):
            u = self.cand[ps, c]
            use = np.flatnonzero((u >= 0) & (nv > 0) & ~cut_twice)
            best[use] = np.minimum(best[use], _farthest(poly[use], nv[use], u[use], tg))
        two = np.flatnonzero(cut_twice)
        if len(two):
            h, s2 = self.cut[ps[two]], ps[two]
            off = np.einsum("ij,ij->i", h, self.cut_at[s2] - at[two])
            near, n_near = _clip(rel[two], nv[two], h, off)
            out_, n_out = _clip(rel[two], nv[two], -h, -off)
            split = np.maximum(
                _farthest(near + at[two][:, None, :], n_near, self.span[s2], tg),
                _farthest(out_ + at[two][:, None, :], n_out, self.beyond[s2], tg),
            )
            best[two] = np.minimum(best[two], split)
        best[nv == 0] = 0.0  # the sector misses the triangle
        out = np.zeros(k)
        np.maximum.at(out, pt, best)
        out[cnt == 0] = np.inf
        return out


def _farthest(poly: np.ndarray, nv: np.ndarray, u: np.ndarray, tg: _Targets) -> np.ndarray:
    """(p,) max over the nv corners of each polygon of the distance to triangle u; 0 for empty polygons."""
    out = np.zeros(len(poly))
    row, corner = np.nonzero(np.arange(poly.shape[1])[None, :] < nv[:, None])
    if len(row):
        d = _dist_to(poly[row, corner], u[row], tg)
        heads = np.flatnonzero(np.r_[True, row[1:] != row[:-1]])
        out[row[heads]] = np.maximum.reduceat(d, heads)
    return out


def _clip(
    poly: np.ndarray, nv: np.ndarray, h: np.ndarray, off: np.ndarray | float = 0.0
) -> tuple[np.ndarray, np.ndarray]:
    """Convex polygons (p, V, 3), nv corners each then copies of the first, cut to the side h . x >= off
    (Sutherland-Hodgman, all polygons at once): (p, V + 1, 3) in the same form and the new counts (0: empty).
    The copies make every slot's successor the next slot, wrapping round, at the cost of repeated corners."""
    p, v = poly.shape[:2]
    s = np.einsum("pvj,pj->pv", poly, h) - np.reshape(off, (-1, 1))
    inside = (s >= 0).all(axis=1)
    out = np.concatenate([poly, poly[:, :1]], axis=1)  # wholly inside: unchanged
    cnt = np.where(inside, nv, 0)  # wholly outside: empty
    cut = np.flatnonzero(~inside & (s >= 0).any(axis=1) & (nv > 0))
    if not len(cut):
        return out, cnt
    poly, s = poly[cut], s[cut]
    s_next = np.roll(s, -1, axis=1)
    keep = s >= 0
    cross = s * s_next < 0
    f = np.where(cross, s / np.where(cross, s - s_next, 1.0), 0.0)
    inter = poly + f[:, :, None] * (np.roll(poly, -1, axis=1) - poly)
    emit = np.stack([keep, cross], axis=2).reshape(len(cut), 2 * v)  # each corner, then its edge's crossing
    corners = np.stack([poly, inter], axis=2).reshape(len(cut), 2 * v, 3)
    c = np.minimum(emit.sum(axis=1), v + 1)  # more only by rounding, on a numerically non-convex polygon
    pos = np.cumsum(emit, axis=1) - 1
    emit &= pos <= v
    piece = np.zeros((len(cut), v + 1, 3))
    r, k = np.nonzero(emit)
    piece[r, pos[r, k]] = corners[r, k]
    out[cut] = np.where(np.arange(v + 1)[None, :, None] < c[:, None, None], piece, piece[:, :1])
    cnt[cut] = c
    return out, cnt


def _weld(tri: np.ndarray, own: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The distinct vertices (exact coordinates, per owner): (w, 3) index of each triangle corner, the points,
    their owners."""
    p = tri.reshape(-1, 3)
    po = np.repeat(own, 3)
    pid, first = weld(p, po)
    return pid.reshape(-1, 3), p[first], po[first]


def _convex(pid: np.ndarray, pp: np.ndarray, pu: np.ndarray, d: np.ndarray, enough: np.ndarray, m: int) -> np.ndarray:
    """(w,) min over triangles u of max over the vertices of d(v, u), counting only the u within ``enough`` of
    all three vertices (any other cannot settle the triangle); inf where there is none."""
    w = len(pid)
    out = np.full(w, np.inf)
    close = d <= enough[pp]
    pp, pu, d = pp[close], pu[close], d[close]
    start = np.searchsorted(pp, np.arange(len(enough)))
    cnt = np.searchsorted(pp, np.arange(len(enough)), side="right") - start
    corner = pid.reshape(-1)
    rows = cnt[corner]
    if not rows.sum():
        return out
    tri_of = np.repeat(np.arange(w), 3)
    rt = np.repeat(tri_of, rows)
    src = np.repeat(start[corner] - np.concatenate([[0], np.cumsum(rows)[:-1]]), rows) + np.arange(rows.sum())
    key = rt * m + pu[src]
    order = np.argsort(key, kind="stable")
    key, dd = key[order], d[src][order]
    first = np.flatnonzero(np.r_[True, key[1:] != key[:-1]])
    size = np.diff(np.r_[first, len(key)])
    worst = np.maximum.reduceat(dd, first)
    full = size == 3  # a triangle u within reach of all three corners (one row per corner and u)
    np.minimum.at(out, key[first[full]] // m, worst[full])
    return out


def _subdivide(tri: np.ndarray) -> np.ndarray:
    """(4m, 3, 3): each triangle split at its edge midpoints, the four children of triangle i at 4i .. 4i + 3."""
    v0, v1, v2 = tri[:, 0], tri[:, 1], tri[:, 2]
    m01, m12, m20 = (v0 + v1) / 2, (v1 + v2) / 2, (v2 + v0) / 2
    kids = np.stack(
        [
            np.stack([v0, m01, m20], 1),
            np.stack([m01, v1, m12], 1),
            np.stack([m20, m12, v2], 1),
            np.stack([m01, m12, m20], 1),
        ],
        axis=1,
    )
    return kids.reshape(-1, 3, 3)


def _distances(p: np.ndarray, pp: np.ndarray, pu: np.ndarray, tg: _Targets) -> np.ndarray:
    """Exact distance from each point p[pp] to the target triangle pu."""
    return _dist_to(p[pp], pu, tg)


def _dist_to(p: np.ndarray, u: np.ndarray, tg: _Targets) -> np.ndarray:
    """Exact distance from each point p[i] to the target triangle u[i], in cache-sized chunks."""
    out = np.empty(len(p))
    for s in range(0, len(p), _CHUNK):
        out[s : s + _CHUNK] = _point_triangle(p[s : s + _CHUNK], tg.pack[u[s : s + _CHUNK]].T)
    return out


def _point_triangle(p: np.ndarray, g: np.ndarray) -> np.ndarray:
    """Distance from p[i] to triangle i, given packed as g[:, i] (see _Targets), all rows at once (Ericson,
    Real-Time Collision Detection 5.1.5).

    The region tests pick the closest feature (vertex, edge or face); the point is written a + s*ab + t*ac and
    the distance taken from the residual vector, not from expanded dot products, so it stays exact near 0.
    Component arrays rather than (k, 3) ones: about twice as fast."""
    ax, ay, az, bx, by, bz, cx, cy, cz, abab, abac, acac = g
    apx, apy, apz = p[:, 0] - ax, p[:, 1] - ay, p[:, 2] - az
    d1 = bx * apx + by * apy + bz * apz  # ab.ap
    d2 = cx * apx + cy * apy + cz * apz  # ac.ap
    d3, d4 = d1 - abab, d2 - abac  # ab.bp, ac.bp
    d5, d6 = d1 - abac, d2 - acac  # ab.cp, ac.cp
    va = d3 * d6 - d5 * d4
    vb = d5 * d2 - d1 * d6
    vc = d1 * d4 - d3 * d2
    e1, e2 = d4 - d3, d5 - d6
    den = va + vb + vc  # |ab x ac|^2
    face = np.ones(len(p), dtype=bool)
    with np.errstate(divide="ignore", invalid="ignore"):
        s, t = vb / den, vc / den
        # the other regions in rising precedence, each overriding the ones before
        m = (va <= 0) & (e1 >= 0) & (e2 >= 0)  # edge bc
        w = e1[m] / (e1[m] + e2[m])
        s[m], t[m], face[m] = 1 - w, w, False
        m = (vb <= 0) & (d2 >= 0) & (d6 <= 0)  # edge ac
        s[m], t[m], face[m] = 0.0, d2[m] / acac[m], False
        m = (d6 >= 0) & (d5 <= d6)  # vertex c
        s[m], t[m], face[m] = 0.0, 1.0, False
        m = (vc <= 0) & (d1 >= 0) & (d3 <= 0)  # edge ab
        s[m], t[m], face[m] = d1[m] / abab[m], 0.0, False
        m = (d3 >= 0) & (d4 <= d3)  # vertex b
        s[m], t[m], face[m] = 1.0, 0.0, False
        m = (d1 <= 0) & (d2 <= 0)  # vertex a
        s[m], t[m], face[m] = 0.0, 0.0, False
    rx, ry, rz = apx - s * bx - t * cx, apy - s * by - t * cy, apz - s * bz - t * cz
    dist = np.sqrt(rx * rx + ry * ry + rz * rz)
    # on a (near) zero-area sliver the face region is meaningless, and 0 / 0 or a point off the triangle are
    # possible: measure to its three edges instead (off by at most its width, < 1e-6 of its longest edge)
    bad = ~np.isfinite(dist) | (s < -1e-9) | (t < -1e-9) | (s + t > 1 + 1e-9) | (face & (den <= 1e-12 * abab * acac))
    if bad.any():
        a = g[0:3, bad].T
        corners = [a, a + g[3:6, bad].T, a + g[6:9, bad].T]
        dist[bad] = np.min([_point_segment(p[bad], corners[i], corners[(i + 1) % 3]) for i in range(3)], axis=0)
    return dist


def _point_segment(p: np.ndarray, a: np.ndarray, b: np.ndarray) -> np.ndarray:
    ab, ap = b - a, p - a
    den = np.einsum("ij,ij->i", ab, ab)
    with np.errstate(divide="ignore", invalid="ignore"):
        s = np.clip(np.where(den > 0, np.einsum("ij,ij->i", ap, ab) / den, 0.0), 0.0, 1.0)
    r = ap - s[:, None] * ab
    return np.sqrt((r * r).sum(axis=1))


GRID_BITS = 16  # outline_hausdorff's tree measures on a grid of 2^-16 m (15 µm): exact under its shifts
_GEOS_PAIR_MAX = 250_000  # vertex pairs up to which GEOS' quadratic discrete Hausdorff is the faster


def outline_hausdorff(a: np.ndarray, b: np.ndarray, spacing: np.ndarray | float) -> np.ndarray:
    """Hausdorff distance between the boundaries of a[i] and b[i] (shapely polygons or lines), for a batch.

    Every vertex of each boundary, and points every ``spacing[i]`` along it, are measured exactly to the other
    boundary's nearest segment: one STRtree over the segments of every pair, the pairs moved apart along x so
    that a point's nearest segment is always its own pair's. Near-linear in the vertices, where GEOS' discrete
    Hausdorff is quadratic (a city block's outline has thousands). Never above the true distance, and within
    spacing/2 of it: the farthest point of one boundary is within spacing/2 of a sample."""
    import shapely

    a = np.asarray(a, dtype=object)
    b = np.asarray(b, dtype=object)
    n = len(a)
    out = np.zeros(n)
    if n == 0:
        return out
    sp = np.broadcast_to(np.asarray(spacing, float), (n,))
    lines = [shapely.segmentize(shapely.boundary(g), sp) for g in (a, b)]
    # small pairs: GEOS (the same measure: every vertex to the other's segments), cheaper than a tree
    small = shapely.get_num_coordinates(lines[0]) * shapely.get_num_coordinates(lines[1]) <= _GEOS_PAIR_MAX
    out[small] = shapely.hausdorff_distance(lines[0][small], lines[1][small])
    big = np.flatnonzero(~small)
    if len(big) == 0:
        return np.nan_to_num(out)
    out[big] = _outline_tree(lines[0][big], lines[1][big])
    return np.nan_to_num(out)


def _outline_tree(la: np.ndarray, lb: np.ndarray) -> np.ndarray:
    import shapely

    n = len(la)
    out = np.zeros(n)
    lines = [la, lb]
    ba, bb = (shapely.bounds(g) for g in lines)
    if not (np.isfinite(ba).any() or np.isfinite(bb).any()):
        return out
    # each pair in its own frame (its corner, floored to the metre) on a grid of 2^-GRID_BITS m, then moved
    # apart by a power of two: the moved coordinates are exact, and so are their differences, which is all a
    # point-to-segment distance reads, so a pair measures the same whatever else is in the batch (an update
    # copies blocks measured in another batch than a full rebuild's)
    corner = np.floor(np.fmin(ba[:, :2], bb[:, :2]))
    corner = np.where(np.isfinite(corner), corner, 0.0)
    extent = np.nan_to_num(np.fmax(ba[:, 2:], bb[:, 2:]) - corner).max(initial=0.0)
    step = 2.0 ** math.ceil(math.log2(3.0 * 2.0 * extent + 1.0))  # > twice any distance in a pair plus its width
    if n * step >= 2.0 ** (52 - GRID_BITS):
        raise ValueError(f"{n} pairs {extent:.0f} m wide do not fit the exact grid: measure fewer at a time")
    shift = np.arange(n) * step
    pts, segs = [], []
    for g in lines:
        parts, owner = shapely.get_parts(g, return_index=True)
        xy, part = shapely.get_coordinates(parts, return_index=True)
        own = owner[part]
        xy = np.round((xy - corner[own]) * 2.0**GRID_BITS) / 2.0**GRID_BITS
        xy[:, 0] += shift[own]
        pts.append((xy, own))
        same = part[1:] == part[:-1]
        segs.append((np.stack([xy[:-1][same], xy[1:][same]], axis=1), own[:-1][same]))
    for (p, p_own), (s, s_own) in ((pts[0], segs[1]), (pts[1], segs[0])):
        if len(p) == 0 or len(s) == 0:
            continue
        tree = shapely.STRtree(shapely.linestrings(s))
        (_, _), dist = tree.query_nearest(shapely.points(p), return_distance=True, all_matches=False)
        # query_nearest answers one row per point here (all_matches=False)
        has = np.zeros(n, bool)
        has[s_own] = True
        keep = has[p_own]
        np.maximum.at(out, p_own[keep], dist[keep])
    return out
