"""LOD2 roofs: every roof:shape closes into an outward solid on rectangle, L, U and courtyard footprints, and each
shape keeps its promise (planes, equal slopes, ridges along both arms, gable walls, apex, slope breaks, tags)."""

import math

import numpy as np
import pytest
import shapely
import trimesh

from core.semantics import SEM_GROUND, SEM_ROOF, SEM_WALL
from etl.lod import roofs
from etl.lod.roofs import RoofError

Z_EAVE, H = 6.0, 4.0
# footprint and its straight skeleton as SFCGAL ST_StraightSkeleton returns it (interior arcs only, each once);
# the U's is derived by hand: arm ridges x=4 and x=20 (y 4..16), base ridge y=4, reflex corners bisect to them
FOOTPRINTS: dict[str, tuple[shapely.Polygon, list]] = {
    "rect": (shapely.Polygon([(0, 0), (20, 0), (20, 10), (0, 10)]),
             [[(0, 0), (5, 5)], [(20, 0), (15, 5)], [(20, 10), (15, 5)], [(0, 10), (5, 5)], [(5, 5), (15, 5)]]),
    "L": (shapely.Polygon([(0, 0), (20, 0), (20, 8), (8, 8), (8, 20), (0, 20)]),
          [[(0, 0), (4, 4)], [(20, 0), (16, 4)], [(20, 8), (16, 4)], [(8, 8), (4, 4)], [(8, 20), (4, 16)],
           [(0, 20), (4, 16)], [(16, 4), (4, 4)], [(4, 16), (4, 4)]]),
    "U": (shapely.Polygon([(0, 0), (24, 0), (24, 20), (16, 20), (16, 8), (8, 8), (8, 20), (0, 20)]),
          [[(0, 0), (4, 4)], [(24, 0), (20, 4)], [(24, 20), (20, 16)], [(16, 20), (20, 16)], [(16, 8), (20, 4)],
           [(8, 8), (4, 4)], [(8, 20), (4, 16)], [(0, 20), (4, 16)], [(4, 4), (20, 4)], [(4, 16), (4, 4)],
           [(20, 16), (20, 4)]]),
    "court": (shapely.Polygon([(0, 0), (30, 0), (30, 30), (0, 30)], [[(10, 10), (10, 20), (20, 20), (20, 10)]]),
              [[(0, 0), (5, 5)], [(30, 0), (25, 5)], [(30, 30), (25, 25)], [(0, 30), (5, 25)], [(10, 10), (5, 5)],
               [(10, 20), (5, 25)], [(20, 20), (25, 25)], [(20, 10), (25, 5)], [(5, 5), (5, 25)], [(5, 5), (25, 5)],
               [(25, 5), (25, 25)], [(5, 25), (25, 25)]]),
}  # fmt: skip
PITCHED = sorted(roofs.SHAPES - {"flat"})


def build(fp: str, shape: str, height: float | None = H, angle: float | None = None, direction: float | None = None,
          orientation: str | None = None, max_height: float = 100.0
          ) -> tuple[roofs.RoofSurface, float, np.ndarray, np.ndarray]:  # fmt: skip
    poly, arcs = FOOTPRINTS[fp]
    surf, h = roofs.roof_surface(poly, shape, np.array(arcs, float), height, angle, direction, orientation, max_height)
    tris, sem = roofs.solid(surf, z_eave=Z_EAVE, z_bottom=0.0)
    return surf, h, tris, sem


def normals(tris: np.ndarray) -> np.ndarray:
    n = np.cross(tris[:, 1] - tris[:, 0], tris[:, 2] - tris[:, 0])
    return n / np.linalg.norm(n, axis=1)[:, None]


def slopes(tris: np.ndarray) -> np.ndarray:
    """Angle of each triangle to the horizontal, degrees."""
    return np.degrees(np.arccos(np.clip(normals(tris)[:, 2], -1.0, 1.0)))


def n_planes(tris: np.ndarray) -> int:
    n = normals(tris)
    key = np.round(np.column_stack([n, np.einsum("ij,ij->i", n, tris[:, 0])]), 6) + 0.0  # +0.0: -0.0 is 0.0
    return len(np.unique(key, axis=0))


def top_xy(tris: np.ndarray) -> np.ndarray:
    v = tris.reshape(-1, 3)
    return np.unique(v[np.abs(v[:, 2] - v[:, 2].max()) < 1e-6, :2], axis=0)


def has_xy(pts: np.ndarray, xy: tuple[float, float]) -> bool:
    return bool((np.linalg.norm(pts - np.asarray(xy), axis=1) < 1e-6).any())


@pytest.mark.parametrize("height", [H, None])
@pytest.mark.parametrize("fp", list(FOOTPRINTS))
@pytest.mark.parametrize("shape", PITCHED)
def test_closed_solid_with_semantics(shape: str, fp: str, height: float | None) -> None:
    poly = FOOTPRINTS[fp][0]
    _, h, tris, sem = build(fp, shape, height)
    if height is not None:
        assert h == pytest.approx(height)
    m = trimesh.Trimesh(tris.reshape(-1, 3), np.arange(3 * len(tris)).reshape(-1, 3), process=True)
    assert m.is_watertight and m.is_winding_consistent
    # the walls alone hold area × 6; a roof never exceeds its ridge (the onion bulge stays well inside this)
    assert poly.area * Z_EAVE < m.volume < poly.area * (Z_EAVE + h)
    assert tris[..., 2].max() == pytest.approx(Z_EAVE + h, abs=1e-6)
    n = normals(tris)
    ground = tris[sem == SEM_GROUND]
    assert np.all(ground[..., 2] == 0.0) and np.allclose(n[sem == SEM_GROUND], [0, 0, -1])
    assert sum(shapely.Polygon(t[:, :2]).area for t in ground) == pytest.approx(poly.area)
    assert np.allclose(n[sem == SEM_WALL, 2], 0.0, atol=1e-9)  # walls and gable/gablet walls are vertical
    assert tris[sem == SEM_ROOF][..., 2].min() >= Z_EAVE - 1e-9
    if shape != "onion":  # the onion's bulge faces outwards and down; every other roof faces the sky
        assert np.all(n[sem == SEM_ROOF, 2] > 1e-6)


# (footprint, shape, roof planes): the skeleton gives one plane per footprint edge (U: both arm ends share y=20)
# minus the hip triangles a gable removes; half-hips and gablets keep a smaller plane there
@pytest.mark.parametrize("fp,shape,planes", [
    ("rect", "hipped", 4), ("L", "hipped", 6), ("U", "hipped", 7), ("court", "hipped", 8),
    ("rect", "gabled", 2), ("L", "gabled", 4), ("U", "gabled", 6), ("court", "gabled", 8),
    ("rect", "half-hipped", 4), ("L", "half-hipped", 6), ("rect", "hipped-and-gabled", 4),
    ("rect", "side_hipped", 3), ("rect", "side_half-hipped", 3), ("U", "pyramidal", 7), ("court", "cone", 8),
])  # fmt: skip
def test_skeleton_roofs_have_one_slope(fp: str, shape: str, planes: int) -> None:
    surf, _, tris, sem = build(fp, shape)
    roof = tris[sem == SEM_ROOF]
    assert surf.engine == "skeleton"
    assert n_planes(roof) == planes
    d_max = 5.0 if fp in ("rect", "court") else 4.0  # half the narrowest width: where the ridge sits
    assert np.allclose(slopes(roof), math.degrees(math.atan2(H, d_max)), atol=1e-6)


@pytest.mark.parametrize("fp", list(FOOTPRINTS))
def test_default_pitch(fp: str) -> None:
    _, _, tris, sem = build(fp, "hipped", height=None)
    assert np.allclose(slopes(tris[sem == SEM_ROOF]), roofs.DEFAULT_PITCH["hipped"], atol=1e-6)


@pytest.mark.parametrize("shape,roof_volume", [
    ("hipped", 10 * H / 6 * (3 * 20 - 10)), ("gabled", 10 * H / 2 * 20), ("pyramidal", 200 * H / 3),
])  # fmt: skip
def test_rectangle_roof_volumes(shape: str, roof_volume: float) -> None:
    _, _, tris, _ = build("rect", shape)
    m = trimesh.Trimesh(tris.reshape(-1, 3), np.arange(3 * len(tris)).reshape(-1, 3), process=True)
    assert m.volume == pytest.approx(200 * Z_EAVE + roof_volume, rel=1e-9)


def test_gabled_rectangle_has_gable_walls_up_to_the_ridge() -> None:
    _, _, tris, sem = build("rect", "gabled")
    walls = tris[sem == SEM_WALL].reshape(-1, 3)
    for end in ((0.0, 5.0, Z_EAVE + H), (20.0, 5.0, Z_EAVE + H)):
        assert (np.linalg.norm(walls - end, axis=1) < 1e-9).any()
    assert np.allclose(top_xy(tris[sem == SEM_ROOF])[:, 1], 5.0)  # ridge along the long axis


def test_gabled_L_ridges_follow_both_arms() -> None:
    _, _, tris, sem = build("L", "gabled")
    top = top_xy(tris[sem == SEM_ROOF])
    # both arm ends become gables at the footprint edge; a bounding-box gable would have one straight ridge
    assert has_xy(top, (4, 20)) and has_xy(top, (20, 4)) and has_xy(top, (4, 4))


def test_half_hipped_gable_wall_reaches_half_the_roof() -> None:
    _, _, tris, sem = build("rect", "half-hipped")
    end_wall = [t for t in tris[sem == SEM_WALL] if np.allclose(t[:, 0], 0.0)]
    assert max(t[:, 2].max() for t in end_wall) == pytest.approx(Z_EAVE + H / 2)
    top = top_xy(tris[sem == SEM_ROOF])
    assert has_xy(top, (2.5, 5)) and has_xy(top, (17.5, 5)) and not has_xy(top, (0, 5))


def test_hipped_and_gabled_has_vertical_gablets_above_the_eaves() -> None:
    surf, _, tris, sem = build("rect", "hipped-and-gabled")
    gablets = surf.vertices[surf.triangles[surf.semantics == SEM_WALL]]
    assert len(gablets) == 2
    for g in gablets:  # at the hip's half height, rising to the ridge, in a vertical plane x = 2.5 or 17.5
        assert np.ptp(g[:, 0]) < 1e-9 and g[0, 0] in (2.5, 17.5)
        assert g[:, 2].min() == pytest.approx(H / 2) and g[:, 2].max() == pytest.approx(H)
    assert tris[sem == SEM_WALL][..., 2].max() == pytest.approx(Z_EAVE + H)


@pytest.mark.parametrize("direction,gable_x,hip_x", [(90.0, 0.0, 20.0), (270.0, 20.0, 0.0)])
def test_side_hipped_hips_the_end_the_roof_faces(direction: float, gable_x: float, hip_x: float) -> None:
    _, _, tris, sem = build("rect", "side_hipped", direction=direction)
    walls = tris[sem == SEM_WALL].reshape(-1, 3)
    assert (np.linalg.norm(walls - (gable_x, 5.0, Z_EAVE + H), axis=1) < 1e-9).any()
    v = tris.reshape(-1, 3)
    assert v[np.abs(v[:, 0] - hip_x) < 1e-9, 2].max() == pytest.approx(Z_EAVE)  # hip end: nothing above the eaves


@pytest.mark.parametrize("shape", ["pyramidal", "cone", "dome", "onion"])
def test_apex_roofs_peak_at_the_centroid(shape: str) -> None:
    surf, _, tris, sem = build("rect", shape)
    assert surf.engine == "apex"
    top = top_xy(tris)
    assert len(top) == 1 and np.allclose(top[0], (10, 5))
    roof = tris[sem == SEM_ROOF]
    if shape == "dome":
        assert n_planes(roof) > 8
    if shape == "onion":  # bulges beyond the walls: further from the centre than any footprint corner
        up = roof.reshape(-1, 3)
        up = up[up[:, 2] > Z_EAVE + 1e-6]
        assert np.linalg.norm(up[:, :2] - (10, 5), axis=1).max() > 1.1 * math.hypot(10, 5)


@pytest.mark.parametrize("fp", ["U", "court"])
def test_apex_shapes_fall_back_to_the_skeleton(fp: str) -> None:
    surf, _, _, _ = build(fp, "pyramidal")
    assert surf.engine == "skeleton" and surf.fallback  # not star-shaped / has a hole


@pytest.mark.parametrize("fp", ["rect", "L"])
@pytest.mark.parametrize("shape,n_slopes", [("gambrel", 2), ("mansard", 2), ("round", 5)])
def test_slope_breaks(fp: str, shape: str, n_slopes: int) -> None:
    _, _, tris, sem = build(fp, shape)
    roof = tris[sem == SEM_ROOF]
    s = slopes(roof)
    assert len(np.unique(np.round(s, 6))) == n_slopes
    # the slope flattens towards the ridge: faces touching the eaves are the steepest
    at_eave = roof[..., 2].min(axis=1) < Z_EAVE + 1e-9
    at_ridge = roof[..., 2].max(axis=1) > Z_EAVE + H - 1e-9
    assert s[at_eave].min() > s[at_ridge].max()


def test_skillion_with_direction_is_one_plane_tilted_along_it() -> None:
    _, _, tris, sem = build("rect", "skillion", direction=90.0)
    n = normals(tris[sem == SEM_ROOF])
    assert np.allclose(n, n[0]) and abs(n[0, 1]) < 1e-9 and abs(n[0, 0]) > 0.1  # gradient along x only


@pytest.mark.parametrize("direction,high", [(90.0, (0.0, None)), (0.0, (None, 0.0))])
def test_skillion_faces_its_direction(direction: float, high: tuple[float | None, float | None]) -> None:
    _, _, tris, sem = build("rect", "skillion", direction=direction)
    top = top_xy(tris[sem == SEM_ROOF])  # roof:direction is where the slope looks: high at the back
    for axis, value in enumerate(high):
        if value is not None:
            assert np.allclose(top[:, axis], value)


def test_crosspitched_is_made_of_the_two_gables() -> None:
    _, _, tris, sem = build("rect", "crosspitched")
    # max of a gable across (ridge y=5, half-width 5) and one along (ridge x=10, half-length 10): two slopes only
    expected = np.degrees(np.arctan([H / 5, H / 10]))
    s = slopes(tris[sem == SEM_ROOF])
    assert np.all(np.min(np.abs(s[:, None] - expected[None]), axis=1) < 1e-6)


def test_roof_angle_sets_the_height() -> None:
    _, h, tris, sem = build("rect", "hipped", height=None, angle=45.0)
    assert h == pytest.approx(5.0, abs=1e-9)  # tan 45° × half the width
    assert np.allclose(slopes(tris[sem == SEM_ROOF]), 45.0, atol=1e-6)


@pytest.mark.parametrize("height", [None, 9.0])
def test_max_height_clamps(height: float | None) -> None:
    _, h, tris, _ = build("rect", "hipped", height=height, max_height=1.0)
    assert h == 1.0 and tris[..., 2].max() == pytest.approx(Z_EAVE + 1.0)


@pytest.mark.parametrize("kw", [{"orientation": "across"}, {"direction": 90.0}])
def test_gabled_ridge_across_the_long_axis(kw: dict) -> None:
    surf, _, tris, sem = build("rect", "gabled", **kw)
    assert surf.engine == "field"
    assert np.allclose(top_xy(tris[sem == SEM_ROOF])[:, 0], 10.0) and n_planes(tris[sem == SEM_ROOF]) == 2


def test_gabled_facing_along_the_short_axis_keeps_the_skeleton() -> None:
    surf, _, tris, sem = build("rect", "gabled", direction=0.0)  # faces north: ridge east-west, the long axis
    assert surf.engine == "skeleton" and np.allclose(top_xy(tris[sem == SEM_ROOF])[:, 1], 5.0)


def test_skeleton_errors_have_stable_codes() -> None:
    poly, arcs = FOOTPRINTS["rect"]
    with pytest.raises(RoofError) as e:
        roofs.roof_surface(poly, "hipped", None, H, None, None, None, 100.0)
    assert e.value.code == "skeleton_missing"
    with pytest.raises(RoofError) as e:  # without the ridge the faces of the two long edges merge
        roofs.roof_surface(poly, "hipped", np.array(arcs[:-1], float), H, None, None, None, 100.0)
    assert e.value.code == "skeleton_invalid"


@pytest.mark.parametrize("value,expected", [
    (None, ("flat", True)), ("flat", ("flat", True)), ("pyramid", ("pyramidal", True)), ("hip", ("hipped", True)),
    ("gable", ("gabled", True)), ("half_hipped", ("half-hipped", True)), ("cross-pitched", ("crosspitched", True)),
    ("gambrel", ("gambrel", True)), ("many", ("flat", False)), ("dome-ish", ("flat", False)), ("", ("flat", False)),
])  # fmt: skip
def test_canonical_shape(value: str | None, expected: tuple[str, bool]) -> None:
    assert roofs.canonical_shape(value) == expected
