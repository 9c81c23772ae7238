"""Quadric edge-collapse decimation of a whole batch of closed meshes in one call, with every result checked.

  * weld: each owner's triangle soup becomes an indexed mesh; vertices are shared only within one owner, by
    coordinates rounded to ``_WELD`` relative to the owner's first vertex (projected coordinates ~1e6 m would
    cost the quadrics their precision, so the whole mesh stays owner-relative until the end). Triangles that
    welding collapses to a line or a point are dropped: they are slivers thinner than ``_WELD``.
  * simplify: every owner with at least ``min_triangles`` triangles goes into ONE mesh and one call of
    ``fast_simplification.simplify`` (Forstmann's fast quadric simplification). An edge collapse merges the two
    ends of an edge, so owners never merge, and their overlapping owner-relative coordinates never meet (the
    algorithm has no spatial search). The collapse thresholds rise globally, so the reduction is spent where
    it costs least - coplanar fans of any owner first - rather than the same share of every owner.
  * owners: following the returned collapses (kept, removed) gives each input vertex its representative; the
    output vertices are the representatives the surviving faces use, in input order, hence the owner of every
    output triangle. (The replay mapping is ambiguous when a whole mesh collapses away.)
  * tidy: the simplifier collapses edges without a link-condition check and leaves folded fins (a triangle and
    its mirror image) and vertices moved onto each other; those are undone (``_tidy``), which turns most such
    results back into closed manifolds (an over-tessellated box, for one).
  * check, per owner: the result must be closed and consistently wound (etl.geom.check.closure), outward
    (positive volume: the collapses keep each triangle's winding, so a negative one means it turned inside
    out, or was already),
    smaller, and within ``max_error`` of the original by Hausdorff distance (etl.generalize.hausdorff). Otherwise the
    original is kept and the status says why: 'kept: no reduction', 'kept: not closed after decimation',
    'kept: inside out after decimation', 'kept: no triangles after decimation', 'kept: error 2.3 m > 1.2 m'.

Limitations: the reduction is global, so some owners may lose much and others nothing; at the last threshold
step owners earlier in the batch are collapsed first; owners that fail a check keep their original, and the
batch then falls short of ``target_reduction`` (nothing is retried); vertices closer than ``_WELD`` that fall
either side of a grid line are not welded (the owner then comes back 'not closed'). ``fast_simplification``
keeps its mesh in global state: one call at a time per process. Nearly all the time goes into the Hausdorff
check; the simplification itself runs at a few hundred thousand triangles a second.
"""

from __future__ import annotations

from dataclasses import dataclass

import fast_simplification
import numpy as np

from etl.generalize.hausdorff import hausdorff
from etl.geom.check import closure, weld

_WELD = 1e-3  # metres: vertices of one owner closer than this (on a grid) are one vertex


@dataclass(frozen=True)
class Decimated:
    triangles: np.ndarray  # (m', 3, 3) float64, grouped by owner in owner order
    owner: np.ndarray  # (m',) int64
    decimated: np.ndarray  # (n,) bool: True where this owner's mesh was replaced by a decimated one
    error: np.ndarray  # (n,) float64 Hausdorff distance (metres) decimated vs original, 0 where not decimated
    status: np.ndarray  # (n,) object: 'decimated', 'too small', 'kept: ...' (why the original was kept)


def decimate(
    triangles: np.ndarray,
    owner: np.ndarray,
    n: int,
    target_reduction: float,
    *,
    min_triangles: int = 64,
    max_error: float = np.inf,
    spacing: float = 0.25,
) -> Decimated:
    """Decimate every owner with at least min_triangles triangles, aiming at target_reduction (0 .. 1, the share
    of those triangles to remove, over the whole batch). Hausdorff errors are measured within ``spacing``
    below the truth. Owners without triangles come back empty, as 'too small'."""
    tri = np.asarray(triangles, dtype=np.float64).reshape(-1, 3, 3)
    own = np.asarray(owner, dtype=np.int64).reshape(-1)
    if len(tri) != len(own):
        raise ValueError("one owner per triangle")
    if len(own) and (own.min() < 0 or own.max() >= n):
        raise ValueError("owners must lie in [0, n)")
    if not 0.0 <= target_reduction < 1.0:
        raise ValueError("target_reduction must be in [0, 1)")
    order = np.argsort(own, kind="stable")
    tri, own = tri[order], own[order]
    counts = np.bincount(own, minlength=n)
    eligible = counts >= max(min_triangles, 1)
    status = np.where(eligible, "kept: no reduction", "too small").astype(object)
    error = np.zeros(n)
    done = np.zeros(n, dtype=bool)
    sel = eligible[own]
    if target_reduction == 0.0 or not sel.any():
        return Decimated(tri, own, done, error, status)

    src, src_owner = tri[sel], own[sel]
    origin = np.zeros((n, 3))
    starts = np.concatenate([[0], np.cumsum(counts)[:-1]])
    origin[eligible] = tri[starts[eligible], 0]
    points, v_owner, faces = _weld_owner_relative(src - origin[src_owner][:, None, :], src_owner)
    if not len(faces):
        return Decimated(tri, own, done, error, status)
    simplified = _simplify_batch(points, v_owner, faces, target_reduction)
    if simplified is None:
        # not seen on real data; should it happen, the batch keeps its originals rather than stopping the run
        status[eligible] = "kept: decimation mixed meshes"
        return Decimated(tri, own, done, error, status)
    dec = simplified[0] + origin[simplified[1]][:, None, :]
    f_owner = simplified[1]
    done = _check(src, src_owner, dec, f_owner, counts, eligible, n, status, error, max_error, spacing)

    # originals where not decimated, results where decimated, in owner order
    keep, take = ~done[own], done[f_owner]
    out_tri = np.concatenate([tri[keep], dec[take]])
    out_own = np.concatenate([own[keep], f_owner[take]])
    o = np.argsort(out_own, kind="stable")
    return Decimated(out_tri[o], out_own[o], done, error, status)


def _weld_owner_relative(rel: np.ndarray, src_owner: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(points, their owners, int32 faces) of owner-relative triangles welded within each owner on the
    ``_WELD`` grid; faces welding collapses to a line or a point are dropped."""
    pts = rel.reshape(-1, 3)
    p_owner = np.repeat(src_owner, 3)
    vid, first = weld(np.rint(pts / _WELD).astype(np.int64), p_owner)
    points = pts[first]  # first of each group: exact input coordinates where nothing needed welding
    v_owner = p_owner[first]
    faces = vid.reshape(-1, 3)
    solid = (faces[:, 0] != faces[:, 1]) & (faces[:, 1] != faces[:, 2]) & (faces[:, 2] != faces[:, 0])
    return points, v_owner, faces[solid].astype(np.int32)


def _simplify_batch(
    points: np.ndarray, v_owner: np.ndarray, faces: np.ndarray, target_reduction: float
) -> tuple[np.ndarray, np.ndarray] | None:
    """One simplification for the whole batch: (owner-relative triangles grouped by owner, their owners), or
    None when an output face would join two owners' vertices."""
    out_pts, out_faces, collapses = fast_simplification.simplify(
        points, faces, target_reduction=target_reduction, return_collapses=True
    )
    # Each collapse (kept, removed) merges its second vertex into its first. Following the merges gives every
    # input vertex its final representative; the faces whose three representatives differ are the output
    # faces, and the output keeps exactly the representatives those faces use, in input order. So output
    # vertex k is the k-th of them and has its owner. (fast_simplification's replay mapping is ambiguous
    # here: a mesh that collapses entirely maps its vertices onto an index another mesh keeps.)
    pairs = np.asarray(collapses, dtype=np.int64).reshape(-1, 2)
    rep = np.arange(len(points))
    rep[pairs[:, 1]] = pairs[:, 0]
    while not np.array_equal(nxt := rep[rep], rep):
        rep = nxt
    merged = rep[faces]
    live = (merged[:, 0] != merged[:, 1]) & (merged[:, 1] != merged[:, 2]) & (merged[:, 2] != merged[:, 0])
    kept_v = np.unique(merged[live])
    if len(kept_v) == len(out_pts) and live.sum() == len(out_faces):
        out_owner_v = v_owner[kept_v]
    else:
        out_owner_v = np.full(len(out_pts), -1, dtype=np.int64)
    f_owner = out_owner_v[out_faces]
    if np.any(f_owner[:, 0] < 0) | np.any(f_owner != f_owner[:, :1]):
        return None
    f_vid, f_owner = _tidy(out_pts, out_owner_v, out_faces, f_owner[:, 0])
    f_order = np.argsort(f_owner, kind="stable")
    return out_pts[f_vid[f_order]], f_owner[f_order]


def _check(
    src: np.ndarray,
    src_owner: np.ndarray,
    dec: np.ndarray,
    f_owner: np.ndarray,
    counts: np.ndarray,
    eligible: np.ndarray,
    n: int,
    status: np.ndarray,
    error: np.ndarray,
    max_error: float,
    spacing: float,
) -> np.ndarray:
    """Which owners' decimated meshes are kept (closed, outward, smaller, within max_error); fills status and
    error in place."""
    done = np.zeros(n, dtype=bool)
    dec_counts = np.bincount(f_owner, minlength=n)
    shut = closure(dec, np.concatenate([[0], np.cumsum(dec_counts)]).astype(np.int64))
    smaller = eligible & (dec_counts < counts)
    closed = shut.watertight & shut.winding_consistent
    status[smaller & ~closed] = "kept: not closed after decimation"
    status[smaller & closed & (shut.volume <= 0)] = "kept: inside out after decimation"
    status[smaller & (dec_counts == 0)] = "kept: no triangles after decimation"
    measure = smaller & shut.ok
    if measure.any():
        m_src, m_dec = measure[src_owner], measure[f_owner]
        h = hausdorff(src[m_src], src_owner[m_src], dec[m_dec], f_owner[m_dec], n, spacing)
        error[measure] = h[measure]
        over = measure & (error > max_error)
        status[over] = [f"kept: error {e:.3g} m > {max_error:.3g} m" for e in error[over]]
        error[over] = 0.0
        done = measure & ~over
        status[done] = "decimated"
    return done


def _tidy(
    pts: np.ndarray, v_owner: np.ndarray, faces: np.ndarray, f_owner: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Undo the folds fast_simplification leaves behind (it collapses edges without a link-condition check):

      * vertices of one owner moved to the very same point become one (as check.closure would see them), and
        the triangles that leaves with a repeated vertex go: they have no area, and each runs its remaining
        edge once each way, so dropping it keeps every edge balanced;
      * triangles on the same three vertices cancel in opposite pairs (a folded fin): only the net |+ - -| of
        them, in the net orientation, stay.

    Whatever is still not a closed manifold after this is caught by the closure check."""
    group, first = weld(pts, v_owner)
    f = first[group][faces]  # each vertex to the first of its group, indices into pts
    ok = (f[:, 0] != f[:, 1]) & (f[:, 1] != f[:, 2]) & (f[:, 2] != f[:, 0])
    f, f_owner = f[ok], f_owner[ok]
    if not len(f):
        return f, f_owner
    srt = np.sort(f, axis=1)
    lo = np.argmin(f, axis=1)
    sign = np.where(f[np.arange(len(f)), (lo + 1) % 3] == srt[:, 1], 1, -1)  # +1: (lo, mid, hi) cyclically
    g = np.lexsort((sign, srt[:, 2], srt[:, 1], srt[:, 0]))  # by vertex set, then orientation
    sg = srt[g]
    first = np.ones(len(g), dtype=bool)
    first[1:] = np.any(sg[1:] != sg[:-1], axis=1)
    group = np.empty(len(g), dtype=np.int64)
    group[g] = np.cumsum(first) - 1
    net = np.bincount(group, weights=sign).astype(np.int64)
    sub = np.ones(len(g), dtype=bool)  # start of each (vertex set, orientation) run
    sub[1:] = first[1:] | (sign[g][1:] != sign[g][:-1])
    run_start = np.maximum.accumulate(np.where(sub, np.arange(len(g)), 0))
    rank = np.empty(len(g), dtype=np.int64)
    rank[g] = np.arange(len(g)) - run_start
    keep = (sign == np.sign(net[group])) & (rank < np.abs(net[group]))
    return f[keep], f_owner[keep]
