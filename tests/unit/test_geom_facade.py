"""LOD3 facades: window/door counts from the rules, one door per ground building, closed outward boxes
standing out of the walls, no window through the door, batches sorted by building."""

import numpy as np
import pytest
import shapely
import trimesh

from core.semantics import SEM_DOOR, SEM_WINDOW
from etl.geom.facade import FacadeParams, Facades, facades

P = FacadeParams()
OFF = np.array([385_000.0, 6_672_000.0])  # UTM-sized coordinates
RECT = shapely.Polygon([(0, 0), (10, 0), (10, 6), (0, 6)])  # the south wall comes first: ties go to it
ELL = shapely.Polygon([(0, 0), (30, 0), (30, 10), (10, 10), (10, 25), (0, 25)])  # reflex corner at (10, 10)
COURT = shapely.Polygon(shapely.box(0, 0, 40, 40).exterior, [shapely.box(10, 10, 30, 30).exterior.coords])


def walls(poly: shapely.Polygon, owner: int = 0, zb: float = 0.0, zt: float = 9.0, levels: float = 3.0,
          ground: bool = True) -> dict[str, np.ndarray]:  # fmt: skip
    poly = shapely.orient_polygons(poly)  # exterior CCW, holes CW: interior on the left
    a, b, ext = [], [], []
    for k, ring in enumerate([poly.exterior, *poly.interiors]):
        c = np.asarray(ring.coords)[:, :2] + OFF
        a.append(c[:-1])
        b.append(c[1:])
        ext += [k == 0] * (len(c) - 1)
    cols = dict(owner=owner, z_bottom=zb, z_top=zt, levels=levels, ground=ground)
    out = {k: np.full(len(ext), v) for k, v in cols.items()}
    return dict(a=np.concatenate(a), b=np.concatenate(b), exterior=np.array(ext), **out)


def run(*parts: dict[str, np.ndarray], n: int = 1) -> Facades:
    cat = {k: np.concatenate([p[k] for p in parts]) for k in parts[0]}
    return facades(**cat, n_buildings=n)


def boxes(f: Facades) -> tuple[np.ndarray, np.ndarray]:
    """(k, 12, 3, 3) boxes relative to OFF, and their semantics."""
    t = f.triangles.reshape(-1, 12, 3, 3) - np.r_[OFF, 0]
    return t, f.semantics[::12]


def local(box: np.ndarray, wall: tuple[tuple[float, float], tuple[float, float]]) -> np.ndarray:
    """Unique corners of a box as (along the wall, outward, z)."""
    v = np.unique(box.reshape(-1, 3), axis=0)
    (ax, ay), (bx, by) = wall
    d = np.array([bx - ax, by - ay]) / np.hypot(bx - ax, by - ay)
    rel = v[:, :2] - (ax, ay)
    return np.column_stack([rel @ d, rel @ (d[1], -d[0]), v[:, 2]])


def test_rectangle_counts_and_door() -> None:
    f = run(walls(RECT))
    t, sem = boxes(f)
    # 10 m walls: floor(9.2 / 3) = 3 per storey; 6 m walls: floor(5.2 / 3) = 1; 3 storeys; the door takes one.
    assert f.n_windows.tolist() == [(3 + 1 + 3 + 1) * 3 - 1] and f.n_doors.tolist() == [1]
    assert (sem == SEM_DOOR).sum() == 1 and (sem == SEM_WINDOW).sum() == 23
    door = local(t[sem == SEM_DOOR][0], ((0, 0), (10, 0)))
    assert door[:, 1].min() == pytest.approx(-0.01) and door[:, 1].max() == pytest.approx(P.depth)  # on y = 0
    assert door[:, 0].min() == pytest.approx(5 - P.door_width / 2) and door[:, 0].max() == pytest.approx(5.55)
    assert door[:, 2].min() == 0.0 and door[:, 2].max() == pytest.approx(P.door_height)
    south = [local(b, ((0, 0), (10, 0))) for b in t[sem == SEM_WINDOW] if b[..., 1].mean() < 0]
    per_storey = np.bincount([int(w[:, 2].min() // 3) for w in south], minlength=3)
    assert per_storey.tolist() == [2, 3, 3]
    for w in south:  # no window box intersects the door box
        along = w[:, 0].min() < door[:, 0].max() and door[:, 0].min() < w[:, 0].max()
        up = w[:, 2].min() < door[:, 2].max() and door[:, 2].min() < w[:, 2].max()
        assert not (along and up)
    z0 = sorted({round(w[:, 2].min(), 9) for w in south})
    assert z0 == pytest.approx([0.9, 3.9, 6.9])


@pytest.mark.parametrize("poly", [RECT, ELL, COURT], ids=["rect", "L", "courtyard"])
def test_boxes_closed_outward_and_outside(poly: shapely.Polygon) -> None:
    f = run(walls(poly))
    t, sem = boxes(f)
    assert len(t) > 0
    boundary = poly.boundary
    for box, s in zip(t, sem, strict=True):
        m = trimesh.Trimesh(box.reshape(-1, 3), np.arange(36).reshape(-1, 3), process=True)
        assert m.is_watertight and m.is_winding_consistent
        w, h = (P.window_width, P.window_height) if s == SEM_WINDOW else (P.door_width, P.door_height)
        assert m.volume == pytest.approx(w * h * (P.depth + 0.01), rel=1e-6)  # positive: faces point out
        v = np.unique(box.reshape(-1, 3), axis=0)
        centre = shapely.Point(v[:, :2].mean(axis=0))
        assert not poly.contains(centre)
        assert poly.distance(centre) == pytest.approx((P.depth - 0.01) / 2, abs=1e-6)
        # back face embedded 1 cm, front face `depth` out of the wall line
        d = np.sort(shapely.distance(boundary, shapely.points(v[:, :2])))
        assert d[:4] == pytest.approx([0.01] * 4, abs=1e-6) and d[4:] == pytest.approx([P.depth] * 4, abs=1e-6)


def test_courtyard_windows_but_door_outside() -> None:
    f = run(walls(COURT))
    t, sem = boxes(f)
    hole = shapely.box(10, 10, 30, 30)
    inside = np.array([hole.contains(shapely.Point(b[..., :2].reshape(-1, 2).mean(axis=0))) for b in t])
    assert inside.sum() == 4 * 6 * 3  # 20 m hole walls: floor(19.2 / 3) = 6 per storey, 3 storeys
    assert f.n_doors[0] == 1 and not inside[sem == SEM_DOOR].any()
    holes_only = walls(COURT)
    holes_only["exterior"][:] = False
    g = run(holes_only)
    assert g.n_doors[0] == 0 and g.n_windows[0] == f.n_windows[0] + 1  # the door no longer takes a window


def test_no_windows_on_short_walls_or_low_storeys() -> None:
    narrow = run(walls(shapely.box(0, 0, 1.5, 10)))
    t, sem = boxes(narrow)
    # only the 10 m walls: 3 per storey x 3 storeys each; the centred door takes the middle ground window
    assert narrow.n_windows[0] == 2 * 3 * 3 - 1
    assert all(abs(b[..., 0].mean() - 0.75) > 0.5 for b in t)  # nothing on the 1.5 m walls (x centre 0.75)
    low = run(walls(RECT, zt=4.0, levels=2.0))  # 2 m storeys
    assert low.n_windows[0] == 0 and low.n_doors[0] == 1
    assert run(walls(shapely.box(0, 0, 1.5, 1.0))).triangles.shape == (0, 3, 3)


def test_floating_building_has_no_door() -> None:
    f = run(walls(RECT, zb=6.0, zt=15.0, ground=False))
    assert f.n_doors[0] == 0 and f.n_windows[0] == 24
    assert set(f.semantics.tolist()) == {SEM_WINDOW}
    assert f.triangles[..., 2].min() == pytest.approx(6.9)


def test_two_buildings_sorted_with_counts() -> None:
    # building 1 listed first; levels missing -> round(7 / 3) = 2 storeys of 3.5 m
    big = walls(shapely.box(20, 0, 40, 8), owner=1, zt=7.0, levels=np.nan)
    f = run(big, walls(RECT, owner=0), n=2)
    assert np.all(np.diff(f.owner) >= 0) and f.owner[0] == 0 and f.owner[-1] == 1
    # 20 m walls: floor(19.2 / 3) = 6, 8 m walls: floor(7.2 / 3) = 2; the door at 10 m falls between windows
    assert f.n_windows.tolist() == [23, (6 + 2 + 6 + 2) * 2]
    assert f.n_doors.tolist() == [1, 1]
    assert len(f.triangles) == len(f.semantics) == len(f.owner) == 12 * (23 + 32 + 2)
    assert np.bincount(f.owner, minlength=2).tolist() == [12 * 24, 12 * 33]


def test_panels_are_the_boxes_front_faces() -> None:
    # the pipeline default: per opening the 2 triangles of its box's front face, `depth` out of the wall, facing out
    w = walls(RECT)
    box = run(w)
    panel = facades(**{k: w[k] for k in w}, n_buildings=1, params=FacadeParams(style="panel"))
    assert (panel.n_windows, panel.n_doors) == (box.n_windows, box.n_doors)
    assert len(panel.triangles) == 2 * (box.n_windows[0] + box.n_doors[0])
    front = box.triangles.reshape(-1, 12, 3, 3)[:, 10:12].reshape(-1, 3, 3)
    assert np.array_equal(panel.triangles, front) and np.array_equal(panel.semantics, box.semantics[::6])
    t = panel.triangles - np.r_[OFF, 0]
    normal = np.cross(t[:, 1] - t[:, 0], t[:, 2] - t[:, 0])[:, :2]
    centre = t.mean(axis=1)[:, :2]
    inside = shapely.contains_xy(RECT, centre[:, 0], centre[:, 1])
    assert not inside.any()  # in front of the wall ...
    dist = shapely.distance(RECT.exterior, shapely.points(centre))
    assert np.allclose(dist, P.depth)  # ... by `depth`
    outward = shapely.contains_xy(RECT, *(centre - 0.5 * normal / np.linalg.norm(normal, axis=1)[:, None]).T)
    assert outward.all()  # stepping against the normal leads back into the building: it faces out


def test_unknown_style_is_refused() -> None:
    with pytest.raises(ValueError, match="opening style"):
        facades(**walls(RECT), n_buildings=1, params=FacadeParams(style="decal"))
