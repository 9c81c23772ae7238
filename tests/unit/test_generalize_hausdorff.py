"""etl.generalize.hausdorff.hausdorff: the symmetric Hausdorff distance per owner, within ``spacing`` below the truth
(never above), checked on cases with a known answer and against a brute-force reference built on trimesh."""

import numpy as np
import pytest
import trimesh

from etl.generalize.hausdorff import _GEOS_PAIR_MAX, _dist_to, _Fans, _Targets, hausdorff, outline_hausdorff

UTM = np.array([385_000.0, 6_672_000.0, 30.0])  # coordinates where float precision matters


def box(lo: tuple[float, float, float], hi: tuple[float, float, float]) -> np.ndarray:
    return trimesh.creation.box(bounds=[lo, hi]).triangles


def h1(a: np.ndarray, b: np.ndarray, spacing: float = 0.05) -> float:
    """Hausdorff distance of one pair of meshes."""
    return float(hausdorff(a, np.zeros(len(a), np.int64), b, np.zeros(len(b), np.int64), 1, spacing)[0])


def roof(apex: float) -> np.ndarray:
    """A 50 x 50 roof at z = 0 as four triangles meeting at the centre, raised to z = apex there."""
    c = np.array([25.0, 25.0, apex])
    corners = np.array([[0, 0, 0], [50, 0, 0], [50, 50, 0], [0, 50, 0]], float)
    return np.stack([np.stack([corners[i], corners[(i + 1) % 4], c]) for i in range(4)])


def flat_roof() -> np.ndarray:
    p = np.array([[0, 0, 0], [50, 0, 0], [50, 50, 0], [0, 50, 0]], float)
    return np.stack([p[[0, 1, 2]], p[[0, 2, 3]]])


def test_identical_meshes_are_zero_apart() -> None:
    sphere = trimesh.creation.icosphere(subdivisions=3, radius=10.0).triangles
    assert h1(sphere, sphere) <= 1e-12
    assert h1(box((0, 0, 0), (20, 10, 6)), box((0, 0, 0), (20, 10, 6))) <= 1e-12


def test_translated_box() -> None:
    a = box((0, 0, 0), (10, 8, 6))
    assert h1(a, a + [0.0, 0.0, 0.7]) == pytest.approx(0.7, abs=1e-9)


def test_taller_cube() -> None:
    assert h1(box((0, 0, 0), (1, 1, 1)), box((0, 0, 0), (1, 1, 1.5))) == pytest.approx(0.5, abs=1e-9)


def test_thin_panel_on_a_wall() -> None:
    house = box((0, 0, 0), (12, 9, 7))
    panel = box((2, -0.12, 1), (5, 0, 3))  # 0.12 m thick, flat against the wall y = 0
    assert h1(house, np.concatenate([house, panel]), spacing=0.01) == pytest.approx(0.12, abs=0.01)


def test_peaked_roof() -> None:
    assert h1(flat_roof(), roof(3.0), spacing=0.1) == pytest.approx(3.0, abs=0.1)


def test_distance_inside_big_triangles_where_vertices_see_none() -> None:
    # every vertex of either side lies on the other surface, yet the middle of the big faces of the block is
    # 24 m from the two end slabs: only sampling the interior of the triangles finds it
    block = box((0, 0, 0), (50, 50, 10))
    ends = np.concatenate([box((0, 0, 0), (1, 50, 10)), box((49, 0, 0), (50, 50, 10))])
    verts = np.unique(np.concatenate([block, ends]).reshape(-1, 3), axis=0)
    assert vertex_only(verts, block, ends) == pytest.approx(0.0, abs=1e-9)
    for spacing in (1.0, 0.25, 0.05):
        got = h1(block, ends, spacing)
        assert 24.0 - spacing - 1e-9 <= got <= 24.0 + 1e-9


def vertex_only(verts: np.ndarray, a: np.ndarray, b: np.ndarray) -> float:
    def dist(p: np.ndarray, tris: np.ndarray) -> np.ndarray:
        pp = np.repeat(p, len(tris), axis=0)
        tt = np.tile(tris, (len(p), 1, 1))
        return np.linalg.norm(trimesh.triangles.closest_point(tt, pp) - pp, axis=1).reshape(len(p), -1).min(axis=1)

    on_a = verts[dist(verts, a) < 1e-9]
    on_b = verts[dist(verts, b) < 1e-9]
    return float(max(dist(on_a, b).max(), dist(on_b, a).max()))


def test_owners_are_independent() -> None:
    a0, a1 = box((0, 0, 0), (10, 10, 5)), box((0, 0, 0), (10, 10, 5))
    b0, b1 = a0, box((0, 0, 0), (10, 10, 9))  # owner 1 grows 4 m, in the very same place as owner 0
    a = np.concatenate([a0, a1])
    b = np.concatenate([b0, b1])
    own = np.repeat([0, 1], 12)
    got = hausdorff(a, own, b, own, 2, 0.05)
    assert got[0] <= 1e-12
    assert got[1] == pytest.approx(4.0, abs=1e-9)
    # owners in any order
    perm = np.random.default_rng(1).permutation(24)
    assert np.array_equal(hausdorff(a[perm], own[perm], b, own, 2, 0.05), got)


def test_utm_offsets() -> None:
    a = box((0, 0, 0), (10, 8, 6))
    near = hausdorff(a, np.zeros(12, int), a + [0, 0.3, 0], np.zeros(12, int), 1, 0.05)
    far = hausdorff(a + UTM, np.zeros(12, int), a + UTM + [0, 0.3, 0], np.zeros(12, int), 1, 0.05)
    assert far[0] == pytest.approx(0.3, abs=1e-8)
    assert far[0] == pytest.approx(near[0], abs=1e-8)
    sphere = trimesh.creation.icosphere(subdivisions=2, radius=10.0).triangles + UTM
    assert h1(sphere, sphere) <= 1e-12


def test_missing_owner_is_nan() -> None:
    a = np.concatenate([box((0, 0, 0), (1, 1, 1)), box((0, 0, 0), (2, 2, 2))])
    got = hausdorff(a, np.repeat([0, 2], 12), a[:12], np.zeros(12, int), 4, 0.1)
    assert got[0] <= 1e-12
    assert np.isnan(got[1:]).all()  # 1: on neither side, 2: only on a, 3: nowhere
    assert np.isnan(hausdorff(np.zeros((0, 3, 3)), np.zeros(0, int), a, np.zeros(24, int), 1, 0.1)).all()


def test_rejects_bad_input() -> None:
    a = box((0, 0, 0), (1, 1, 1))
    with pytest.raises(ValueError):
        hausdorff(a, np.full(12, 3), a, np.zeros(12, int), 2, 0.1)
    with pytest.raises(ValueError):
        hausdorff(a, np.zeros(12, int), a, np.zeros(12, int), 1, 0.0)


def test_point_triangle_matches_trimesh_including_slivers() -> None:
    rng = np.random.default_rng(0)
    tri = rng.normal(size=(3000, 3, 3))
    tri[:500, 2] = tri[:500, 0] + 0.3 * (tri[:500, 1] - tri[:500, 0])  # collinear
    tri[500:600, 1] = tri[500:600, 0]  # two vertices equal
    tri[600:700, 1:] = tri[600:700, :1]  # a point
    p = rng.normal(size=(3000, 3)) * 2
    got = _dist_to(p, np.arange(len(tri)), _Targets(tri))
    ref = np.linalg.norm(trimesh.triangles.closest_point(tri[700:], p[700:]) - p[700:], axis=1)
    assert np.allclose(got[700:], ref, atol=1e-12)
    seg = np.min([segment(p[:700], tri[:700, i], tri[:700, (i + 1) % 3]) for i in range(3)], axis=0)
    assert np.allclose(got[:700], seg, atol=1e-12)


def segment(p: np.ndarray, a: np.ndarray, b: np.ndarray) -> np.ndarray:
    ab = b - a
    den = (ab * ab).sum(axis=1)
    s = np.clip(np.divide(((p - a) * ab).sum(axis=1), den, out=np.zeros(len(p)), where=den > 0), 0, 1)
    return np.linalg.norm(p - a - s[:, None] * ab, axis=1)


# --- brute force ---------------------------------------------------------------------------------------------


def dense(tris: np.ndarray, radius: float) -> np.ndarray:
    """Points of a barycentric grid on every triangle, every point of the triangle within radius of one."""
    pts = []
    for t in tris:
        longest = max(np.linalg.norm(t[i] - t[(i + 1) % 3]) for i in range(3))
        k = max(1, int(np.ceil(longest / (np.sqrt(3) * radius))))
        i, j = np.meshgrid(np.arange(k + 1), np.arange(k + 1), indexing="ij")
        ok = i + j <= k
        u, v = i[ok] / k, j[ok] / k
        pts.append(t[0] + u[:, None] * (t[1] - t[0]) + v[:, None] * (t[2] - t[0]))
    return np.concatenate(pts)


def directed_brute(a: np.ndarray, b: np.ndarray, radius: float) -> float:
    p = dense(a, radius)
    # every point against every triangle: slow, simple, independent of the code under test
    pp, tt = np.repeat(p, len(b), axis=0), np.tile(b, (len(p), 1, 1))
    return float(np.linalg.norm(trimesh.triangles.closest_point(tt, pp) - pp, axis=1).reshape(len(p), -1).min(1).max())


def random_solid(rng: np.random.Generator) -> np.ndarray:
    kind = rng.integers(3)
    if kind == 0:
        lo = rng.uniform(-2, 2, 3)
        return box(tuple(lo), tuple(lo + rng.uniform(0.5, 5, 3)))
    if kind == 1:
        return trimesh.convex.convex_hull(rng.normal(size=(int(rng.integers(8, 30)), 3)) * rng.uniform(1, 2)).triangles
    return trimesh.creation.icosphere(subdivisions=1, radius=rng.uniform(1, 2)).triangles + rng.uniform(-1, 1, 3)


def test_random_batch_against_brute_force() -> None:
    rng = np.random.default_rng(7)
    n, spacing, fine = 8, 0.25, 0.07
    a_parts, b_parts, a_own, b_own = [], [], [], []
    for k in range(n):
        a = random_solid(rng)
        if k % 3 == 0:  # jittered
            b = a + rng.normal(scale=0.2, size=a.shape)
        elif k % 3 == 1:  # a coarser hull of some of its vertices: the farthest points are inside big triangles
            v = np.unique(a.reshape(-1, 3), axis=0)
            b = trimesh.convex.convex_hull(v[rng.permutation(len(v))[: max(6, len(v) // 3)]]).triangles
        else:  # unrelated
            b = random_solid(rng)
        origin = UTM + [k * 3.0, 0, 0]  # owners overlap in space: only the owner decides who is compared
        a_parts.append(a + origin)
        b_parts.append(b + origin)
        a_own.append(np.full(len(a), k))
        b_own.append(np.full(len(b), k))
    got = hausdorff(
        np.concatenate(a_parts), np.concatenate(a_own), np.concatenate(b_parts), np.concatenate(b_own), n, spacing
    )
    for k in range(n):
        a, b = a_parts[k] - UTM, b_parts[k] - UTM
        ref = max(directed_brute(a, b, fine), directed_brute(b, a, fine))  # within `fine` below the truth
        assert ref - spacing - 1e-6 <= got[k] <= ref + fine + 1e-6, k


def test_sector_bound_is_an_upper_bound() -> None:
    """The bound that settles triangles lying across edges and corners of B never undercuts the distance."""
    rng = np.random.default_rng(3)
    for _ in range(6):
        m = trimesh.creation.icosphere(subdivisions=2, radius=5)
        b = (m.vertices + rng.normal(scale=0.3, size=m.vertices.shape))[m.faces]
        c = rng.normal(size=(150, 3))
        c *= (5 + rng.normal(scale=0.2, size=(150, 1))) / np.linalg.norm(c, axis=1)[:, None]
        t = c[:, None, :] + rng.normal(scale=rng.uniform(0.2, 2.0), size=(150, 3, 3))
        tg = _Targets(b)
        bound = _Fans(b, np.zeros(len(b), np.int64), 1e4).bound(t, np.zeros(150, np.int64), tg)
        assert np.isfinite(bound).all()
        k = 12
        i, j = np.meshgrid(np.arange(k + 1), np.arange(k + 1), indexing="ij")
        ok = i + j <= k
        u, v = i[ok] / k, j[ok] / k
        pts = (
            t[:, None, 0]
            + u[None, :, None] * (t[:, None, 1] - t[:, None, 0])
            + v[None, :, None] * (t[:, None, 2] - t[:, None, 0])
        ).reshape(-1, 3)
        d = _dist_to(np.repeat(pts, len(b), axis=0), np.tile(np.arange(len(b)), len(pts)), tg)
        dense = d.reshape(len(pts), len(b)).min(axis=1).reshape(150, -1).max(axis=1)
        assert np.all(dense <= bound + 1e-9)


def test_outline_hausdorff_matches_geos_on_small_and_large_outlines() -> None:
    """Outlines of blocks: exact on a known case, and on random wiggly polygons (small ones through GEOS, large
    ones, with more vertex pairs than _GEOS_PAIR_MAX, through the segment tree) within spacing/2 below a densely
    sampled GEOS reference, never above it; pairs in one batch do not see each other's outlines."""
    import shapely

    square = shapely.box(0, 0, 100, 100)
    notch = shapely.Polygon([(0, 0), (100, 0), (100, 100), (50, 70), (0, 100)])
    assert outline_hausdorff(np.array([square]), np.array([notch]), 1.0)[0] == pytest.approx(30.0)

    rng = np.random.default_rng(5)

    def wiggly(n: int, r: float, x0: float) -> shapely.Polygon:
        t = np.sort(rng.uniform(0, 2 * np.pi, n))
        rad = r * (1 + 0.01 * rng.standard_normal(n))
        return shapely.Polygon(np.stack([UTM[0] + x0 + rad * np.cos(t), UTM[1] + rad * np.sin(t)], axis=1))

    a = np.array([wiggly(n, r, 5000.0 * k) for k, (n, r) in enumerate([(12, 20), (30, 50), (900, 400), (1500, 800)])])
    b = np.array(
        [shapely.simplify(g, 3.0) if k % 2 else wiggly(len(g.exterior.coords), 21, 5000.0 * k) for k, g in enumerate(a)]
    )
    spacing = 2.0
    n_pairs = shapely.get_num_coordinates(
        shapely.segmentize(shapely.boundary(a), spacing)
    ) * shapely.get_num_coordinates(shapely.segmentize(shapely.boundary(b), spacing))
    assert (n_pairs <= _GEOS_PAIR_MAX).any() and (n_pairs > _GEOS_PAIR_MAX).any()  # both paths run
    got = outline_hausdorff(a, b, spacing)

    def directed(x: shapely.Geometry, y: shapely.Geometry) -> float:
        # densely sampled points of x against the exact outline of y: a reference within 0.1 m of the true value
        pts = shapely.points(shapely.get_coordinates(shapely.segmentize(shapely.boundary(x), 0.1)))
        return float(shapely.distance(pts, shapely.boundary(y)).max())

    ref = np.array([max(directed(x, y), directed(y, x)) for x, y in zip(a, b, strict=True)])
    assert np.all(got <= ref + 0.1) and np.all(got >= ref - spacing / 2 - 0.1), (got, ref)
    # a pair measures the same bits alone, in this batch, and in a batch of other far and wide pairs (an update
    # copies blocks measured in other batches than a full rebuild's); the big pairs take the segment tree
    big = np.flatnonzero(n_pairs > _GEOS_PAIR_MAX)
    for k in big:
        alone = outline_hausdorff(a[k : k + 1], b[k : k + 1], spacing)[0]
        wide = shapely.box(UTM[0] - 90_000, UTM[1], UTM[0] - 87_000, UTM[1] + 3_000)
        others = outline_hausdorff(
            np.array([wide, a[k], *a]), np.array([shapely.simplify(wide, 1.0), b[k], *b]), spacing
        )
        assert alone == got[k] == others[1] == others[2 + k], (alone, got[k], others[1], others[2 + k])
