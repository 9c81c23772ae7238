"""LOD1: footprints extruded from a bottom to a top height as closed, outward-oriented triangle meshes.

Works on a whole batch of footprints at once (numpy and vectorised shapely/GEOS calls, no per-building
Python loop):
  * caps: GEOS constrained Delaunay triangulation of each (multi)polygon, holes respected, no Steiner points;
  * walls: two triangles per ring edge;
  * bottom caps face down, top caps face up, walls face out (exterior rings counter-clockwise, holes
    clockwise), so every triangle winds counter-clockwise seen from outside.
Cap and wall triangles reuse the exact footprint coordinates, so each edge is shared by exactly two triangles
and the solid is closed. A cap whose triangles do not add up to the footprint area is reported, not written.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import shapely

from core.semantics import SEM_GROUND, SEM_ROOF, SEM_WALL
from etl.geom.check import signed_volume


@dataclass(frozen=True)
class Walls:
    """Footprint ring edges a -> b with the interior on the left (exterior rings counter-clockwise, holes
    clockwise), repeated points removed."""

    a: np.ndarray  # (w, 2)
    b: np.ndarray  # (w, 2)
    owner: np.ndarray  # (w,) footprint index
    exterior: np.ndarray  # (w,) bool: on an exterior ring (False: a courtyard wall)


@dataclass(frozen=True)
class Extrusion:
    """Triangles of a batch, grouped by footprint: those of footprint k are triangles[offsets[k]:offsets[k+1]]."""

    triangles: np.ndarray  # (m, 3, 3) float64, counter-clockwise seen from outside
    offsets: np.ndarray  # (n + 1,) int64
    ok: np.ndarray  # (n,) bool: False = cap triangulation did not cover the footprint (no triangles then)
    volume: np.ndarray  # (n,) float64 enclosed volume
    semantics: np.ndarray  # (m,) uint8 per triangle: ground (bottom cap), wall, roof (top cap); core/semantics.py
    walls: Walls  # the footprint ring edges the walls stand on (LOD3 puts its openings on them)

    def of(self, k: int) -> np.ndarray:
        return self.triangles[self.offsets[k] : self.offsets[k + 1]]

    @property
    def counts(self) -> np.ndarray:
        return np.diff(self.offsets)


def _orient_ccw(tri2d: np.ndarray) -> np.ndarray:
    """(m, 3, 2) triangles flipped where needed so each is counter-clockwise seen from above."""
    a, b, c = tri2d[:, 0], tri2d[:, 1], tri2d[:, 2]
    cross = (b[:, 0] - a[:, 0]) * (c[:, 1] - a[:, 1]) - (b[:, 1] - a[:, 1]) * (c[:, 0] - a[:, 0])
    out = tri2d.copy()
    flip = cross < 0
    out[flip] = tri2d[flip][:, [0, 2, 1]]
    return out


def extrude(geoms: np.ndarray, bottom: np.ndarray, top: np.ndarray) -> Extrusion:
    """Extrude polygonal geometries (shapely array) from bottom[k] to top[k]; top must exceed bottom."""
    geoms = np.asarray(geoms, dtype=object)
    n = len(geoms)
    bottom = np.asarray(bottom, dtype=np.float64)
    top = np.asarray(top, dtype=np.float64)
    if np.any(top <= bottom):
        raise ValueError("every top must exceed its bottom")
    # Work relative to each footprint's first coordinate: projected coordinates are ~1e6 m and the
    # triangulation and the area check need the precision. Shifted back exactly at the end.
    clean = shapely.orient_polygons(shapely.remove_repeated_points(geoms), exterior_cw=False)
    first = shapely.get_coordinates(shapely.get_point(shapely.get_exterior_ring(shapely.get_geometry(clean, 0)), 0))
    if len(first) != n:
        raise ValueError("every footprint needs an exterior ring")

    # --- caps ---------------------------------------------------------------------------------------------
    cdt = shapely.constrained_delaunay_triangles(clean)
    tri_polys, tri_owner = shapely.get_parts(cdt, return_index=True)
    tri2d = shapely.get_coordinates(shapely.get_exterior_ring(tri_polys)).reshape(-1, 4, 2)[:, :3]
    tri2d = _orient_ccw(tri2d)
    cap_area = np.bincount(tri_owner, weights=_area(tri2d - first[tri_owner][:, None, :]), minlength=n)
    area = shapely.area(clean)
    ok = np.abs(cap_area - area) <= 1e-6 * np.maximum(area, 1.0)
    ok &= area > 0

    # --- walls --------------------------------------------------------------------------------------------
    polys, poly_owner = shapely.get_parts(clean, return_index=True)
    rings, ring_poly = shapely.get_rings(polys, return_index=True)
    ring_owner = poly_owner[ring_poly]
    coords, coord_ring = shapely.get_coordinates(rings, return_index=True)
    same = coord_ring[:-1] == coord_ring[1:]  # consecutive points of one closed ring = an edge
    a2, b2 = coords[:-1][same], coords[1:][same]
    wall_ring = coord_ring[:-1][same]
    wall_owner = ring_owner[wall_ring]
    ring_exterior = np.zeros(len(rings), dtype=bool)
    ring_exterior[np.unique(ring_poly, return_index=True)[1]] = True  # a polygon's first ring is its exterior

    def lift(xy: np.ndarray, z: np.ndarray) -> np.ndarray:
        return np.concatenate([xy, z[:, None]], axis=1)

    zb_w, zt_w = bottom[wall_owner], top[wall_owner]
    a0, b0, a1, b1 = lift(a2, zb_w), lift(b2, zb_w), lift(a2, zt_w), lift(b2, zt_w)
    walls = np.concatenate([np.stack([a0, b0, b1], axis=1), np.stack([a0, b1, a1], axis=1)])
    walls_owner = np.concatenate([wall_owner, wall_owner])

    zb_c = np.repeat(bottom[tri_owner][:, None], 3, axis=1)[..., None]
    zt_c = np.repeat(top[tri_owner][:, None], 3, axis=1)[..., None]
    bottom_caps = np.concatenate([tri2d[:, [0, 2, 1]], zb_c], axis=2)  # reversed: facing down
    top_caps = np.concatenate([tri2d, zt_c], axis=2)

    triangles = np.concatenate([bottom_caps, top_caps, walls])
    owner = np.concatenate([tri_owner, tri_owner, walls_owner])
    sem = np.concatenate(
        [
            np.full(len(tri_owner), SEM_GROUND, np.uint8),
            np.full(len(tri_owner), SEM_ROOF, np.uint8),
            np.full(len(walls_owner), SEM_WALL, np.uint8),
        ]
    )
    keep = ok[owner]
    triangles, owner, sem = triangles[keep], owner[keep], sem[keep]
    order = np.argsort(owner, kind="stable")
    triangles, owner, sem = triangles[order], owner[order], sem[order]
    counts = np.bincount(owner, minlength=n)
    offsets = np.concatenate([[0], np.cumsum(counts)]).astype(np.int64)

    return Extrusion(
        triangles=triangles,
        offsets=offsets,
        ok=ok,
        volume=signed_volume(triangles, offsets),
        semantics=sem,
        walls=Walls(a2, b2, wall_owner, ring_exterior[wall_ring]),
    )


def _area(tri2d: np.ndarray) -> np.ndarray:
    a, b, c = tri2d[:, 0], tri2d[:, 1], tri2d[:, 2]
    return 0.5 * np.abs((b[:, 0] - a[:, 0]) * (c[:, 1] - a[:, 1]) - (b[:, 1] - a[:, 1]) * (c[:, 0] - a[:, 0]))
