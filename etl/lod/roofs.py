"""LOD2: a closed building solid with a Simple 3D Buildings roof, for one footprint polygon. Pure numpy/shapely.

Three roof engines, each returning roof *surface* triangles over the footprint; ``solid`` then closes them:

* **skeleton** (hipped, gabled, half-hipped, side_hipped, side_half-hipped, hipped-and-gabled, gambrel,
  mansard, round; pyramidal/cone/dome/onion on footprints that are not star-shaped or have holes): the faces
  of the footprint's straight skeleton (computed by SFCGAL ``ST_StraightSkeleton`` in the database; rebuilt
  here as a planar graph). A vertex's height is its distance ``d`` to the face's footprint edge, so every
  face is a plane and all faces have the same slope: correct on L, T, U footprints and courtyards.
  Gables come from the skeleton: a triangular hip face is removed and its apex moved along the ridge onto
  the footprint edge, which becomes a vertical gable wall; half-hipped and hipped-and-gabled move it part
  way. Gambrel, mansard and round bend the slope: faces are cut along lines of equal ``d`` and the height
  becomes a profile f(d).
* **apex** (pyramidal, cone, dome, onion on star-shaped footprints without holes): rings of the footprint
  scaled towards its centroid, lifted along a profile; the onion bulges out beyond the walls.
* **height field** (skillion, saltbox, gabled_height_moved, butterfly, crosspitched, sawtooth, and gabled
  shapes whose tagged roof:orientation/roof:direction puts the ridge across the footprint's long axis):
  z = g(u, v) in a frame from roof:direction (or the footprint's long axis); the footprint is cut along
  the lines where g bends so every piece is planar.

``solid`` adds walls under the roof's rim (its boundary edges, which all lie above the footprint rings),
so gable and skillion walls follow the roof, and a bottom cap triangulated from the rim. The result is
closed when the roof surface is a manifold with the rim as boundary; ``etl.geom.check`` measures that.

All coordinates are relative to an origin given by the caller and snapped to a 1e-7 m grid so that the
same point computed twice (a cut crossing seen from two faces) is one vertex.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import NamedTuple

import numpy as np
import shapely

from core.semantics import SEM_GROUND, SEM_ROOF, SEM_WALL

GRID = 1e-7

SKELETON_SHAPES = {
    "hipped",
    "gabled",
    "half-hipped",
    "side_hipped",
    "side_half-hipped",
    "hipped-and-gabled",
    "gambrel",
    "mansard",
    "round",
}
APEX_SHAPES = {"pyramidal", "cone", "dome", "onion"}
FIELD_SHAPES = {"skillion", "saltbox", "gabled_height_moved", "butterfly", "crosspitched", "sawtooth"}
#: every roof:shape value of the OSM catalogue; anything else (and "many") is drawn flat with a diagnostic
SHAPES = {"flat"} | SKELETON_SHAPES | APEX_SHAPES | FIELD_SHAPES
ALIASES = {
    "pyramid": "pyramidal",
    "hip": "hipped",
    "gable": "gabled",
    "half_hipped": "half-hipped",
    "side-hipped": "side_hipped",
    "side_half_hipped": "side_half-hipped",
    "hipped_and_gabled": "hipped-and-gabled",
    "cross_pitched": "crosspitched",
    "cross-pitched": "crosspitched",
    "gabled-height-moved": "gabled_height_moved",
}
#: shapes that need the straight skeleton (asked of the database only for these)
NEEDS_SKELETON = SKELETON_SHAPES | APEX_SHAPES
#: default pitch in degrees when neither roof:height, roof:angle nor roof:levels is tagged
DEFAULT_PITCH = {
    "hipped": 30.0,
    "gabled": 35.0,
    "half-hipped": 35.0,
    "side_hipped": 35.0,
    "side_half-hipped": 35.0,
    "hipped-and-gabled": 35.0,
    "gambrel": 45.0,
    "mansard": 45.0,
    "round": 45.0,
    "pyramidal": 40.0,
    "cone": 55.0,
    "dome": 45.0,
    "onion": 56.0,
    "skillion": 12.0,
    "saltbox": 30.0,
    "gabled_height_moved": 35.0,
    "butterfly": 12.0,
    "crosspitched": 35.0,
    "sawtooth": 25.0,
}


def canonical_shape(value: str | None) -> tuple[str, bool]:
    """(shape used, known?) for a roof:shape value; untagged is flat and known."""
    if value is None:
        return "flat", True
    v = ALIASES.get(value, value)
    if v in SHAPES:
        return v, True
    return "flat", False


@dataclass(frozen=True)
class RoofSurface:
    vertices: np.ndarray  # (k, 3) local coordinates
    triangles: np.ndarray  # (m, 3) int indices, counter-clockwise seen from above/outside
    semantics: np.ndarray  # (m,) uint8 (SEM_ROOF, or SEM_WALL for vertical faces inside the roof)
    engine: str
    fallback: str | None = None  # why another engine than the shape's own was used


class RoofError(ValueError):
    """The roof could not be built for this footprint; ``code`` is stable for diagnostics."""

    def __init__(self, code: str, detail: str):
        super().__init__(detail)
        self.code = code


def _snap(a: np.ndarray) -> np.ndarray:
    return np.round(np.asarray(a, dtype=np.float64) / GRID) * GRID


# ---------------------------------------------------------------------------------------------------------
# profiles: f(t) for t = d / d_max in [0, 1], f(0) = 0, f(1) = 1; breaks where the slope changes
# ---------------------------------------------------------------------------------------------------------
_ROUND_T = np.array([0.0, 0.1, 0.25, 0.45, 0.7, 1.0])
PROFILES: dict[str, tuple[np.ndarray, np.ndarray]] = {
    "linear": (np.array([0.0, 1.0]), np.array([0.0, 1.0])),
    "gambrel": (np.array([0.0, 0.4, 1.0]), np.array([0.0, 0.72, 1.0])),
    "mansard": (np.array([0.0, 0.3, 1.0]), np.array([0.0, 0.8, 1.0])),
    "round": (_ROUND_T, np.sqrt(1.0 - (1.0 - _ROUND_T) ** 2)),
}


def _profile_for(shape: str) -> str:
    return {"gambrel": "gambrel", "mansard": "mansard", "round": "round", "dome": "round", "onion": "round"}.get(
        shape, "linear"
    )


# ---------------------------------------------------------------------------------------------------------
# small mesh helpers
# ---------------------------------------------------------------------------------------------------------
class _Mesh:
    """Vertices keyed by snapped xy (roof surfaces are height fields apart from vertical faces, whose
    vertices are still distinct in xy), faces as vertex-index cycles."""

    def __init__(self) -> None:
        self.xy: list[tuple[float, float]] = []
        self.d: list[float] = []
        self.index: dict[tuple[float, float], int] = {}
        self.note: str | None = None  # why the roof is not what its shape asks for (the skeleton engine says)

    def vid(self, x: float, y: float, d: float = 0.0) -> int:
        key = (float(x), float(y))
        i = self.index.get(key)
        if i is None:
            i = len(self.xy)
            self.index[key] = i
            self.xy.append(key)
            self.d.append(d)
        return i


def _triangulate_faces(mesh: _Mesh, faces: list[list[int]]) -> np.ndarray:
    """Constrained Delaunay triangulation of planar face polygons (vertex cycles, CCW from above) in one
    vectorised GEOS call; triangle corners map back to vertices by their exact coordinates."""
    if not faces:
        return np.zeros((0, 3), dtype=np.int64)
    xy = np.asarray(mesh.xy)
    flat = np.concatenate([np.asarray(f + f[:1]) for f in faces])
    ring_of = np.repeat(np.arange(len(faces)), [len(f) + 1 for f in faces])
    return _triangulate(mesh, shapely.polygons(shapely.linearrings(xy[flat], indices=ring_of)))


def _triangulate(mesh: _Mesh, polygons: object) -> np.ndarray:
    """(m, 3) vertex ids of the GEOS constrained Delaunay triangles of ``polygons`` (a shapely array or
    collection), counter-clockwise from above, degenerate ones dropped. No Steiner points: every corner is
    one of mesh's vertices, found by its exact coordinates."""
    tri = shapely.get_parts(shapely.constrained_delaunay_triangles(polygons))
    coords = shapely.get_coordinates(shapely.get_exterior_ring(tri)).reshape(-1, 4, 2)[:, :3]
    ids = np.array([mesh.index[(float(x), float(y))] for x, y in coords.reshape(-1, 2)], dtype=np.int64).reshape(-1, 3)
    xy = np.asarray(mesh.xy)
    cross = _cross2(xy[ids])
    ids[cross < 0] = ids[cross < 0][:, [0, 2, 1]]
    return ids[np.abs(cross) > 0]


def _cross2(tri2d: np.ndarray) -> np.ndarray:
    """Twice the signed area of (m, 3, 2) triangles: > 0 counter-clockwise."""
    a, b, c = tri2d[:, 0], tri2d[:, 1], tri2d[:, 2]
    return (b[:, 0] - a[:, 0]) * (c[:, 1] - a[:, 1]) - (b[:, 1] - a[:, 1]) * (c[:, 0] - a[:, 0])


def _slice(
    xyz_d: list[list[float]], tris: np.ndarray, sem: np.ndarray, levels: np.ndarray
) -> tuple[list[list[float]], np.ndarray, np.ndarray]:
    """Cut triangles along the iso-lines d = level (d linear over each triangle). A cut point on an edge is
    created once per edge, so neighbouring triangles share it."""
    verts = [list(v) for v in xyz_d]
    cache: dict[tuple[int, int, float], int] = {}

    def cut(i: int, j: int, t: float) -> int:
        key = (min(i, j), max(i, j), t)
        k = cache.get(key)
        if k is None:
            p, q = (verts[i], verts[j]) if i < j else (verts[j], verts[i])
            s = (t - p[3]) / (q[3] - p[3])
            k = len(verts)
            verts.append([p[0] + s * (q[0] - p[0]), p[1] + s * (q[1] - p[1]), p[2] + s * (q[2] - p[2]), t])
            cache[key] = k
        return k

    out_t, out_s = [list(t) for t in tris], list(sem)
    for t in levels:
        nt, ns = [], []
        for tri, s in zip(out_t, out_s, strict=True):
            dv = [verts[i][3] for i in tri]
            lo = [dd < t - 1e-12 for dd in dv]
            hi = [dd > t + 1e-12 for dd in dv]
            if not (any(lo) and any(hi)):
                nt.append(tri)
                ns.append(s)
                continue
            # rotate so that tri[0] is the lone vertex on its side (the others may lie on the level)
            for r in range(3):
                a, b, c = tri[r], tri[(r + 1) % 3], tri[(r + 2) % 3]
                la, lb, lc = lo[r], lo[(r + 1) % 3], lo[(r + 2) % 3]
                ha, hb, hc = hi[r], hi[(r + 1) % 3], hi[(r + 2) % 3]
                if (la and not lb and not lc) or (ha and not hb and not hc):
                    break
            on_b = not (lb or hb)
            on_c = not (lc or hc)
            if on_b:  # level passes through b: split into two triangles
                m = cut(c, a, t)
                nt += [[a, b, m], [b, c, m]]
                ns += [s, s]
            elif on_c:
                m = cut(a, b, t)
                nt += [[a, m, c], [m, b, c]]
                ns += [s, s]
            else:
                m1, m2 = cut(a, b, t), cut(c, a, t)
                nt += [[a, m1, m2], [m1, b, c], [m1, c, m2]]
                ns += [s, s, s]
        out_t, out_s = nt, ns
    return verts, np.asarray(out_t, dtype=np.int64).reshape(-1, 3), np.asarray(out_s, dtype=np.uint8)


# ---------------------------------------------------------------------------------------------------------
# skeleton engine
# ---------------------------------------------------------------------------------------------------------
def _rings(poly: shapely.Polygon) -> list[np.ndarray]:
    """Ring coordinates without the closing point; exterior counter-clockwise, holes clockwise."""
    out = [np.asarray(poly.exterior.coords)[:-1]]
    out += [np.asarray(r.coords)[:-1] for r in poly.interiors]
    return out


def skeleton_faces(poly: shapely.Polygon, arcs: np.ndarray) -> tuple[_Mesh, list[list[int]], list[tuple[int, int]]]:
    """Faces of the straight skeleton: one vertex cycle per footprint edge, starting with that edge (a, b).

    ``arcs`` is (k, 2, 2), the skeleton's segments (snapped like ``poly``). Raises RoofError when the arcs
    do not cut the footprint into exactly one face per edge."""
    mesh = _Mesh()
    contour: list[tuple[int, int]] = []
    for ring in _rings(poly):
        ids = [mesh.vid(x, y) for x, y in ring]
        contour += [(ids[i], ids[(i + 1) % len(ids)]) for i in range(len(ids))]
    arc_ids = [(mesh.vid(*p), mesh.vid(*q)) for p, q in arcs]
    half = list(contour) + [(b, a) for a, b in contour]
    half += [(a, b) for a, b in arc_ids if a != b] + [(b, a) for a, b in arc_ids if a != b]
    if len(set(half)) != len(half):
        raise RoofError("skeleton_invalid", "the skeleton repeats an edge")
    xy = np.asarray(mesh.xy)
    h = np.asarray(half, dtype=np.int64)
    vec = xy[h[:, 1]] - xy[h[:, 0]]
    ang = np.arctan2(vec[:, 1], vec[:, 0])
    order = np.lexsort((ang, h[:, 0]))  # outgoing half-edges of each vertex, counter-clockwise
    pos = np.empty(len(h), dtype=np.int64)
    pos[order] = np.arange(len(h))
    start = np.searchsorted(h[order, 0], np.arange(len(xy)))
    deg = np.bincount(h[:, 0], minlength=len(xy))
    twin_of = {e: i for i, e in enumerate(half)}
    twin = np.array([twin_of[(b, a)] for a, b in half], dtype=np.int64)
    # next half-edge around the face on the left: the one just clockwise of the twin at the destination
    v = h[:, 1]
    k = pos[twin] - start[v]
    nxt = order[start[v] + (k - 1) % deg[v]]
    seen = np.zeros(len(h), dtype=bool)
    faces: list[list[int]] = []
    n_contour = len(contour)
    for e in range(n_contour):  # walk the face of each footprint edge
        cyc, cur = [], e
        while not seen[cur]:
            seen[cur] = True
            cyc.append(cur)
            cur = int(nxt[cur])
            if len(cyc) > len(h):
                break
        if cur != e or any(c < 2 * n_contour and c != e for c in cyc):
            raise RoofError("skeleton_invalid", "a skeleton face does not belong to exactly one footprint edge")
        faces.append([int(h[c, 0]) for c in cyc])
    area = sum(shapely.Polygon(xy[f]).area for f in faces)
    if abs(area - poly.area) > 1e-6 * max(poly.area, 1.0):
        raise RoofError("skeleton_invalid", f"skeleton faces cover {area:.3f} m² of {poly.area:.3f} m²")
    return mesh, faces, contour


def _edge_frame(xy: np.ndarray, a: int, b: int) -> tuple[np.ndarray, np.ndarray]:
    p, q = xy[a], xy[b]
    t = (q - p) / np.linalg.norm(q - p)
    return p, np.array([-t[1], t[0]])  # inward normal (interior on the left)


#: the end treatment of each shape whose skeleton roof is not hipped all round
_END_TREATMENT = {
    "gabled": "gable",
    "gambrel": "gable",
    "round": "gable",
    "half-hipped": "half",
    "hipped-and-gabled": "gablet",
    "side_hipped": "side",
    "side_half-hipped": "side_half",
}


class _Hip(NamedTuple):
    """A hip triangle (a, b, apex) of skeleton face ``face`` over footprint edge a->b, whose apex is an interior
    skeleton node; ``side_a`` and ``side_b`` are the faces next to it at a and at b."""

    length: float  # of the footprint edge
    face: int
    a: int
    b: int
    apex: int
    side_a: int
    side_b: int


@dataclass
class _Ends:
    """How the end treatment reshapes the skeleton faces."""

    after_a: dict[tuple[int, int], list[int]] = field(default_factory=dict)  # (a, N) -> vertices replacing N after a
    before_b: dict[tuple[int, int], list[int]] = field(default_factory=dict)  # (N, b) -> vertices replacing N before b
    removed: set[int] = field(default_factory=set)
    new_faces: dict[int, list[int]] = field(default_factory=dict)
    vertical: list[list[int]] = field(default_factory=list)


def _skeleton_roof(
    poly: shapely.Polygon, arcs: np.ndarray, shape: str, direction: float | None
) -> tuple[_Mesh, list[list[int]], list[list[int]]]:
    """Faces (roof) and vertical faces after the end treatment of ``shape``; mesh.d holds distances."""
    mesh, faces, contour = skeleton_faces(poly, arcs)
    xy = np.asarray(mesh.xy)
    frames = [_edge_frame(xy, a, b) for a, b in contour]
    d = _distances(mesh, faces, frames)
    treat = _END_TREATMENT.get(shape)
    if treat is None:
        return mesh, faces, []
    chosen = _gable_ends(_hips(faces, xy, frames, direction))
    if not chosen:
        mesh.note = "no end of the skeleton is a triangle that can take a gable: drawn hipped"
    ends = _Ends()
    for hip, kind in _plan(chosen, treat):
        _treat_end(mesh, ends, hip, kind, xy, d, frames)
    return mesh, _reshaped(faces, ends), ends.vertical


def _distances(mesh: _Mesh, faces: list[list[int]], frames: list[tuple[np.ndarray, np.ndarray]]) -> np.ndarray:
    """Each vertex's distance to the footprint edges of its faces (their mean, at least 0), also into mesh.d."""
    xy = np.asarray(mesh.xy)
    dsum = np.zeros(len(xy))
    dn = np.zeros(len(xy))
    for f, (p, n) in zip(faces, frames, strict=True):
        for vtx in f:
            dsum[vtx] += float((xy[vtx] - p) @ n)
            dn[vtx] += 1
    d = np.where(dn > 0, dsum / np.maximum(dn, 1), 0.0)
    d[d < 0] = 0.0
    mesh.d = d.tolist()
    return d


def _hips(
    faces: list[list[int]], xy: np.ndarray, frames: list[tuple[np.ndarray, np.ndarray]], direction: float | None
) -> list[_Hip]:
    """The hip triangles, shortest footprint edge first; among equal ones the end the roof looks towards last
    (it stays hipped on side_* shapes), else the first face first."""
    face_of_half: dict[tuple[int, int], int] = {}
    for fi, f in enumerate(faces):
        for i in range(len(f)):
            face_of_half[(f[i], f[(i + 1) % len(f)])] = fi
    cands = []
    for fi, f in enumerate(faces):
        if len(f) != 3:
            continue
        a, b, nn = f
        fa, fb = face_of_half.get((a, nn)), face_of_half.get((nn, b))
        if fa is None or fb is None or fa == fb:
            continue
        length = float(np.linalg.norm(xy[b] - xy[a]))
        cands.append(_Hip(length, fi, a, b, nn, fa, fb))
    if direction is not None:  # the end the roof looks towards is the hipped one (side_* shapes)
        g = np.array([math.sin(math.radians(direction)), math.cos(math.radians(direction))])
        cands.sort(key=lambda c: (round(c[0], 6), -float(-frames[c[1]][1] @ g)))
    else:
        cands.sort(key=lambda c: (round(c[0], 6), c[1]))
    return cands


def _gable_ends(cands: list[_Hip]) -> list[_Hip]:
    """The hips that take a gable, in order: a gable removes or reshapes its hip face, so that face must not
    also be reshaped as a neighbour of another."""
    chosen: list[_Hip] = []
    gables: set[int] = set()
    neighbours: set[int] = set()
    for c in cands:
        if c[1] in neighbours or c[5] in gables or c[6] in gables:
            continue
        chosen.append(c)
        gables.add(c[1])
        neighbours.update((c[5], c[6]))
    return chosen


def _plan(chosen: list[_Hip], treat: str) -> list[tuple[_Hip, str]]:
    """What each chosen end becomes: a gable, half-hip or gablet; on side_* shapes one end keeps its (half-)hip."""
    if treat in ("side", "side_half") and chosen:
        # one end keeps (half-)hip, the others get gables
        first, rest = chosen[0], chosen[1:]
        return ([(first, "half")] if treat == "side_half" else []) + [(c, "gable") for c in rest]
    return [(c, treat) for c in chosen]


def _ridge_hit(
    p0: np.ndarray, p1: np.ndarray, pa: np.ndarray, na: np.ndarray, pb: np.ndarray, nb: np.ndarray
) -> float | None:
    """Where on p0 -> p1 (0..1) the planes of the two faces with frames (pa, na) and (pb, nb) meet; None when
    parallel to it."""
    den = float((p1 - p0) @ (na - nb))
    if abs(den) < 1e-9:
        return None
    return float(((pa - p0) @ na - (pb - p0) @ nb) / den)


def _treat_end(
    mesh: _Mesh,
    ends: _Ends,
    hip: _Hip,
    kind: str,
    xy: np.ndarray,
    d: np.ndarray,
    frames: list[tuple[np.ndarray, np.ndarray]],
) -> None:
    """One end into ``ends``: its hip face removed (gable), cut to a small hip (half) or a gablet, the apex moved
    along the ridge; an end whose ridge meets the edge too near a corner is left hipped."""
    if kind == "gablet":
        _gablet(mesh, ends, hip, xy, d, frames)
        return
    _, fi, a, b, nn, fa, fb = hip
    pa, na = frames[fa]
    pb, nb = frames[fb]
    A, B, N = xy[a], xy[b], xy[nn]
    t = _ridge_hit(A, B, pa, na, pb, nb)
    if t is None or not 0.05 < t < 0.95:
        return
    pp = _snap(A + t * (B - A))
    dp = float((pp - pa) @ na)
    if kind == "gable":
        ip = mesh.vid(pp[0], pp[1], dp)
        ends.after_a[(a, nn)] = [ip]
        ends.before_b[(nn, b)] = [ip]
        ends.removed.add(fi)
    else:  # half: gable up to half the roof, a small hip above
        s = 0.5
        q1, q2 = _snap(A + s * (pp - A)), _snap(B + s * (pp - B))
        r = _snap(pp + (1 - s) * (N - pp))
        iq1, iq2 = mesh.vid(q1[0], q1[1], s * dp), mesh.vid(q2[0], q2[1], s * dp)
        ir = mesh.vid(r[0], r[1], float((r - pa) @ na))
        ends.after_a[(a, nn)] = [iq1, ir]
        ends.before_b[(nn, b)] = [ir, iq2]
        ends.new_faces[fi] = [iq1, iq2, ir]


def _gablet(
    mesh: _Mesh, ends: _Ends, hip: _Hip, xy: np.ndarray, d: np.ndarray, frames: list[tuple[np.ndarray, np.ndarray]]
) -> None:
    """A hipped-and-gabled end: the hip face cut at half its height, a small vertical gable above the cut."""
    _, fi, a, b, nn, fa, fb = hip
    pa, na = frames[fa]
    pb, nb = frames[fb]
    A, B, N = xy[a], xy[b], xy[nn]
    s = 0.5
    q1 = _snap(A + s * (N - A))
    q2 = _snap(B + s * (N - B))
    t = _ridge_hit(q1, q2, pa, na, pb, nb)
    if t is None or not 0.05 < t < 0.95:
        return
    pp = _snap(q1 + t * (q2 - q1))
    iq1, iq2 = mesh.vid(q1[0], q1[1], s * d[nn]), mesh.vid(q2[0], q2[1], s * d[nn])
    ip = mesh.vid(pp[0], pp[1], float((pp - pa) @ na))
    ends.after_a[(a, nn)] = [iq1, ip]
    ends.before_b[(nn, b)] = [ip, iq2]
    ends.new_faces[fi] = [a, b, iq2, iq1]
    ends.vertical.append([iq1, iq2, ip])


def _reshaped(faces: list[list[int]], ends: _Ends) -> list[list[int]]:
    """The faces after the end treatment: removed, replaced, or with the vertices that replace a moved apex."""
    out = []
    for fi, f in enumerate(faces):
        if fi in ends.removed:
            continue
        if fi in ends.new_faces:
            out.append(ends.new_faces[fi])
            continue
        cyc = []
        for i, vtx in enumerate(f):
            prev, nxt = f[i - 1], f[(i + 1) % len(f)]
            # the apex stays (collinear on the ridge) so faces that are not reshaped still meet it
            cyc += ends.after_a.get((prev, vtx), []) + [vtx] + ends.before_b.get((vtx, nxt), [])
        out.append(cyc)
    return out


# ---------------------------------------------------------------------------------------------------------
# apex engine
# ---------------------------------------------------------------------------------------------------------
_ONION = np.array(
    [[1.0, 0.0], [1.18, 0.12], [1.25, 0.3], [1.1, 0.48], [0.75, 0.63], [0.4, 0.76], [0.18, 0.87], [0.06, 0.95]]
)
_DOME = np.array([[math.cos(a), math.sin(a)] for a in np.radians([0, 22.5, 45, 67.5, 80])])


def _star_centre(poly: shapely.Polygon) -> np.ndarray | None:
    """The centroid when every exterior edge sees it (the footprint is star-shaped around it), else None."""
    if len(poly.interiors):
        return None
    c = np.asarray(poly.centroid.coords[0])
    ring = np.asarray(poly.exterior.coords)
    a, b = ring[:-1] - c, ring[1:] - c
    cross = a[:, 0] * b[:, 1] - a[:, 1] * b[:, 0]
    # and not too close to any wall, or faces next to a reflex corner stand almost vertical
    if not np.all(cross > 1e-9) or poly.exterior.distance(shapely.Point(c)) < 0.25 * math.sqrt(poly.area / math.pi):
        return None
    return c


def _apex_roof(poly: shapely.Polygon, centre: np.ndarray, shape: str, height: float) -> tuple[np.ndarray, np.ndarray]:
    ring = np.asarray(poly.exterior.coords)[:-1]
    n = len(ring)
    prof = {"dome": _DOME, "onion": _ONION}.get(shape, np.array([[1.0, 0.0]]))
    verts = [np.column_stack([_snap(centre + s * (ring - centre)), np.full(n, z * height)]) for s, z in prof]
    verts.append(np.array([[*_snap(centre), height]]))
    v = np.concatenate(verts)
    tris = []
    idx = np.arange(n)
    for k in range(len(prof) - 1):
        lo, hi = k * n + idx, (k + 1) * n + idx
        lo2, hi2 = k * n + (idx + 1) % n, (k + 1) * n + (idx + 1) % n
        tris += [np.column_stack([lo, lo2, hi2]), np.column_stack([lo, hi2, hi])]
    top = (len(prof) - 1) * n
    tris.append(np.column_stack([top + idx, top + (idx + 1) % n, np.full(n, len(v) - 1)]))
    return v, np.concatenate(tris)


# ---------------------------------------------------------------------------------------------------------
# height-field engine
# ---------------------------------------------------------------------------------------------------------
def long_axis(poly: shapely.Polygon) -> np.ndarray:
    """Unit vector along the longer side of the minimum rotated rectangle."""
    rect = np.asarray(shapely.minimum_rotated_rectangle(poly).exterior.coords)
    e1, e2 = rect[1] - rect[0], rect[2] - rect[1]
    e = e1 if np.linalg.norm(e1) >= np.linalg.norm(e2) else e2
    n = np.linalg.norm(e)
    return e / n if n > 0 else np.array([1.0, 0.0])


def _field(
    shape: str, u: np.ndarray, v: np.ndarray, U: tuple[float, float], V: tuple[float, float]
) -> tuple[np.ndarray, list[tuple[str, float]]]:
    """g in [0, 1] at (u, v) and the break lines ('u' or 'v', value); v runs across the ridge / down-slope."""
    (u0, u1), (v0, v1) = U, V
    du, dv = max(u1 - u0, 1e-9), max(v1 - v0, 1e-9)
    s = (v - v0) / dv  # 0 .. 1 across
    if shape == "skillion":  # v runs from the front (the way the roof faces) to the high back
        return s, []
    if shape in ("gabled", "saltbox", "gabled_height_moved"):
        r = {"gabled": 0.5, "saltbox": 0.3, "gabled_height_moved": 0.35}[shape]
        g = np.where(s <= r, s / r, (1.0 - s) / (1.0 - r))
        return g, [("v", v0 + r * dv)]
    if shape == "butterfly":
        return np.abs(2.0 * s - 1.0), [("v", v0 + 0.5 * dv)]
    if shape == "crosspitched":
        t = (u - u0) / du
        g = np.maximum(1.0 - np.abs(2.0 * s - 1.0), 1.0 - np.abs(2.0 * t - 1.0))
        # the max() switches gable on the lines |2s-1| = |2t-1| through the centre: cut there too
        return g, [("v", v0 + 0.5 * dv), ("u", u0 + 0.5 * du), ("d+", 0.0), ("d-", 0.0)]
    if shape == "sawtooth":
        n = max(1, int(round(dv / 6.0)))
        period = dv / n
        x = (v - v0) / period
        k = np.minimum(np.floor(x), n - 1)
        f = x - k
        g = np.where(f <= 0.85, f / 0.85, (1.0 - f) / 0.15)
        lines = [("v", v0 + (i + 0.85) * period) for i in range(n)] + [("v", v0 + i * period) for i in range(1, n)]
        return g, lines
    raise ValueError(shape)


def _field_roof(poly: shapely.Polygon, shape: str, axis: np.ndarray, height: float) -> tuple[np.ndarray, np.ndarray]:
    eu = axis / np.linalg.norm(axis)
    ev = np.array([-eu[1], eu[0]])
    ring_all = np.concatenate(_rings(poly))
    u_all, v_all = ring_all @ eu, ring_all @ ev
    U, V = (float(u_all.min()), float(u_all.max())), (float(v_all.min()), float(v_all.max()))
    _, lines = _field(shape, u_all, v_all, U, V)
    pieces = [poly]
    big = 10.0 * (U[1] - U[0] + V[1] - V[0] + 1.0)
    centre = 0.5 * (U[0] + U[1]) * eu + 0.5 * (V[0] + V[1]) * ev
    du, dv = max(U[1] - U[0], 1e-9), max(V[1] - V[0], 1e-9)
    for kind, val in lines:
        if kind in ("u", "v"):
            d = ev if kind == "v" else eu
            c = val * d
        else:  # a diagonal of the (u, v) box through its centre, normal (1/du, ±1/dv) in box units
            d = eu / du + (1.0 if kind == "d-" else -1.0) * ev / dv
            d = d / np.linalg.norm(d)
            c = centre
        e = np.array([-d[1], d[0]])
        lo = shapely.Polygon([c - big * e, c + big * e, c + big * e - big * d, c - big * e - big * d])
        hi = shapely.Polygon([c - big * e, c + big * e, c + big * e + big * d, c - big * e + big * d])
        nxt = []
        for p in pieces:
            for q in (p.intersection(lo), p.intersection(hi)):
                nxt += [g for g in shapely.get_parts(q) if isinstance(g, shapely.Polygon) and g.area > 1e-9]
        pieces = nxt
    # snap piece vertices so that a crossing computed in two pieces is one vertex
    pieces = [shapely.orient_polygons(shapely.set_precision(p, GRID)) for p in pieces]
    pieces = [g for p in pieces for g in shapely.get_parts(p) if isinstance(g, shapely.Polygon) and g.area > 1e-9]
    mesh = _Mesh()
    for p in pieces:
        for x, y in shapely.get_coordinates(p):
            mesh.vid(x, y)
    ids = _triangulate(mesh, shapely.GeometryCollection(pieces))
    xy = np.asarray(mesh.xy)
    g, _ = _field(shape, xy @ eu, xy @ ev, U, V)
    return np.column_stack([xy, height * g]), ids


# ---------------------------------------------------------------------------------------------------------
# entry point
# ---------------------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class _Pitch:
    """The roof height of a slope: the tagged ``height``, else from ``angle`` or the shape's default pitch over
    the slope's horizontal extent; never above ``max_height``."""

    shape: str
    height: float | None
    angle: float | None
    max_height: float

    def of(self, extent: float) -> float:
        """The height over a horizontal ``extent`` of the slope."""
        a = self.angle if self.angle is not None else DEFAULT_PITCH.get(self.shape, 30.0)
        h = self.height if self.height is not None else math.tan(math.radians(min(a, 89.0))) * extent
        return float(min(h, self.max_height))


def roof_surface(
    poly: shapely.Polygon,
    shape: str,
    arcs: np.ndarray | None,
    height: float | None,
    angle: float | None,
    direction: float | None,
    orientation: str | None,
    max_height: float,
) -> tuple[RoofSurface, float]:
    """Roof surface of one polygon (local coordinates, exterior CCW, holes CW) with z = 0 at the eaves.

    ``height`` is the tagged roof height (None: from ``angle``, else the shape's default pitch); the
    result's height never exceeds ``max_height``. Returns (surface, roof height used)."""
    # the same rounding as the skeleton's arcs, so footprint corners and arc ends are the same vertices
    poly = shapely.orient_polygons(shapely.make_valid(shapely.transform(poly, _snap)))
    if not isinstance(poly, shapely.Polygon) or poly.is_empty or poly.area <= 0:
        raise RoofError("footprint_degenerate", "footprint vanished on the 1e-7 m grid")
    fallback = None
    axis = long_axis(poly)
    across = orientation == "across"
    dir_vec = None
    if direction is not None:
        dir_vec = np.array([math.sin(math.radians(direction)), math.cos(math.radians(direction))])
    pitch = _Pitch(shape, height, angle, max_height)

    field_shape = _field_shape(poly, shape, axis, across, dir_vec)
    if field_shape is not None:
        return _field_surface(poly, field_shape, axis, across, dir_vec, pitch)

    if shape in APEX_SHAPES:
        centre = _star_centre(poly)
        if centre is not None:
            h = pitch.of(math.sqrt(poly.area / math.pi))  # the radius of a circle of the same area
            v, t = _apex_roof(poly, centre, shape, h)
            return RoofSurface(v, t, np.full(len(t), SEM_ROOF, np.uint8), "apex"), h
        fallback = "not star-shaped or has holes: built from the straight skeleton"

    if arcs is None or len(arcs) == 0:
        raise RoofError("skeleton_missing", "the database returned no straight skeleton")
    return _skeleton_surface(poly, _snap(arcs), shape, direction, pitch, fallback)


def _field_shape(
    poly: shapely.Polygon, shape: str, axis: np.ndarray, across: bool, dir_vec: np.ndarray | None
) -> str | None:
    """The height-field shape the roof is built as, None for another engine: the field shapes, and gabled
    where the mapper put the ridge across the long axis of a boxy footprint."""
    field_shape = shape if shape in FIELD_SHAPES else None
    # a ridge across the long axis only exists as one ridge over the whole footprint: done so on footprints
    # that are (nearly) their minimum rectangle; L, T, U and courtyards keep the skeleton roof
    boxy = not len(poly.interiors) and poly.area >= 0.9 * shapely.minimum_rotated_rectangle(poly).area
    if shape == "gabled" and boxy:
        ridge = np.array([-dir_vec[1], dir_vec[0]]) if dir_vec is not None else None
        if across or (ridge is not None and abs(float(ridge @ axis)) < math.cos(math.radians(45))):
            field_shape = "gabled"  # the mapper put the ridge across the long axis: not a skeleton roof
    return field_shape


def _field_surface(
    poly: shapely.Polygon, field_shape: str, axis: np.ndarray, across: bool, dir_vec: np.ndarray | None, pitch: _Pitch
) -> tuple[RoofSurface, float]:
    """The height-field roof in its frame: v down the slope from roof:direction where the shape has one,
    else across the ridge, which runs along the long axis (across it with roof:orientation=across)."""
    sloped = ("skillion", "saltbox", "gabled_height_moved", "butterfly", "sawtooth")
    if field_shape in sloped and dir_vec is not None:
        ev = -dir_vec  # v runs against the direction the roof faces: high at the back
        eu = np.array([ev[1], -ev[0]])
    else:
        eu = axis if not across else np.array([-axis[1], axis[0]])
        if field_shape == "gabled" and dir_vec is not None:
            eu = np.array([-dir_vec[1], dir_vec[0]])
    ring_all = np.concatenate(_rings(poly))
    ev = np.array([-eu[1], eu[0]])
    extent = float(np.ptp(ring_all @ ev))
    if field_shape in ("gabled", "saltbox", "gabled_height_moved", "butterfly", "crosspitched"):
        extent *= 0.5
    h = pitch.of(extent)
    v, t = _field_roof(poly, field_shape, eu, h)
    return RoofSurface(v, t, np.full(len(t), SEM_ROOF, np.uint8), "field"), h


def _skeleton_surface(
    poly: shapely.Polygon, arcs: np.ndarray, shape: str, direction: float | None, pitch: _Pitch, fallback: str | None
) -> tuple[RoofSurface, float]:
    """The skeleton roof: its faces triangulated, cut where the shape's profile bends, lifted along it."""
    mesh, faces, vertical = _skeleton_roof(poly, arcs, shape, direction)
    fallback = mesh.note or fallback
    d = np.asarray(mesh.d)
    dmax = float(d.max()) if len(d) else 0.0
    if dmax <= 0:
        raise RoofError("skeleton_invalid", "the skeleton has no interior node")
    h = pitch.of(dmax)
    tris = _triangulate_faces(mesh, faces)
    sem = np.full(len(tris), SEM_ROOF, np.uint8)
    if vertical:
        tris = np.concatenate([tris, np.asarray(vertical, dtype=np.int64)])
        sem = np.concatenate([sem, np.full(len(vertical), SEM_WALL, np.uint8)])
    xy = np.asarray(mesh.xy)
    prof = _profile_for(shape)
    pt, pf = PROFILES[prof]
    verts = np.column_stack([xy, np.zeros(len(xy)), d]).tolist()
    if len(pt) > 2:
        verts, tris, sem = _slice(verts, tris, sem, pt[1:-1] * dmax)
    va = np.asarray(verts)
    z = h * np.interp(va[:, 3] / dmax, pt, pf)
    return RoofSurface(np.column_stack([va[:, :2], z]), tris, sem, "skeleton", fallback), h


def solid(
    roof: RoofSurface, z_eave: float, z_bottom: float, rim_semantic: int = SEM_WALL
) -> tuple[np.ndarray, np.ndarray]:
    """Close a roof surface (z relative to the eaves) into a solid from z_bottom: walls under every rim edge,
    a bottom cap triangulated from the rim. Returns ((m, 3, 3) triangles, (m,) semantics)."""
    v = roof.vertices.copy()
    v[:, 2] += z_eave
    t = roof.triangles
    e = np.concatenate([t[:, [0, 1]], t[:, [1, 2]], t[:, [2, 0]]])
    key = e[:, 0] * (len(v) + 1) + e[:, 1]
    rkey = e[:, 1] * (len(v) + 1) + e[:, 0]
    rim = e[~np.isin(key, rkey)]
    # walls: under each rim edge p->q the quad (p_bot, q_bot, q, p); zero-height corners dropped
    p, q = v[rim[:, 0]], v[rim[:, 1]]
    pb, qb = p.copy(), q.copy()
    pb[:, 2] = z_bottom
    qb[:, 2] = z_bottom
    w1 = np.stack([pb, qb, q], axis=1)
    w2 = np.stack([pb, q, p], axis=1)
    keep1 = q[:, 2] > z_bottom
    keep2 = p[:, 2] > z_bottom
    walls = np.concatenate([w1[keep1], w2[keep2]])
    # bottom: the rim loops as rings
    nxt = {int(a): int(b) for a, b in rim}
    if len(nxt) != len(rim):
        raise RoofError("roof_not_manifold", "the roof rim passes a vertex twice")
    rings, todo = [], set(nxt)
    while todo:
        s = todo.pop()
        loop, cur = [s], nxt[s]
        while cur != s:
            if cur not in todo:
                raise RoofError("roof_not_manifold", "the roof rim does not close")
            todo.discard(cur)
            loop.append(cur)
            cur = nxt[cur]
        rings.append(v[loop, :2])
    signed = [shapely.area(shapely.Polygon(r)) * (1 if shapely.is_ccw(shapely.LinearRing(r)) else -1) for r in rings]
    outer = [r for r, a in zip(rings, signed, strict=True) if a > 0]
    holes = [r for r, a in zip(rings, signed, strict=True) if a < 0]
    if len(outer) != 1:
        raise RoofError("roof_not_manifold", f"the roof rim has {len(outer)} outer rings")
    base = shapely.Polygon(outer[0], holes)
    cdt = shapely.get_parts(shapely.constrained_delaunay_triangles(base))
    bt = shapely.get_coordinates(shapely.get_exterior_ring(cdt)).reshape(-1, 4, 2)[:, :3]
    bt = np.where((_cross2(bt) > 0)[:, None, None], bt[:, [0, 2, 1]], bt)  # facing down
    bottom = np.concatenate([bt, np.full((len(bt), 3, 1), z_bottom)], axis=2)
    top = v[t]
    tris = np.concatenate([bottom, walls, top])
    sem = np.concatenate(
        [np.full(len(bottom), SEM_GROUND, np.uint8), np.full(len(walls), rim_semantic, np.uint8), roof.semantics]
    )
    return tris, sem
