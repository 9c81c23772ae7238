"""etl.geom.check.closure gives trimesh's verdicts (is_watertight, is_winding_consistent, volume) for each mesh,
alone or in a batch, and meshes in a batch never share edges with each other."""

import numpy as np
import pytest
import shapely
import trimesh

from etl.geom.check import Closure, closure
from etl.lod import roofs

UTM = np.array([385_000.0, 6_672_000.0, 30.0])  # coordinates where float precision matters


def box(shift: tuple[float, float, float] = (0.0, 0.0, 0.0)) -> np.ndarray:
    """A closed outward 2 × 3 × 4 box (volume 24), x from -1 to 1, as (12, 3, 3) triangles."""
    return trimesh.creation.box(extents=(2.0, 3.0, 4.0)).triangles + np.asarray(shift)


def roof_solid(shape: str) -> np.ndarray:
    poly = shapely.Polygon([(0, 0), (20, 0), (20, 8), (8, 8), (8, 20), (0, 20)])
    arcs = np.array(
        [
            [(0, 0), (4, 4)],
            [(20, 0), (16, 4)],
            [(20, 8), (16, 4)],
            [(8, 8), (4, 4)],
            [(8, 20), (4, 16)],
            [(0, 20), (4, 16)],
            [(16, 4), (4, 4)],
            [(4, 16), (4, 4)],
        ],
        float,
    )
    surf, _ = roofs.roof_surface(poly, shape, arcs, 4.0, None, None, None, 100.0)
    return roofs.solid(surf, z_eave=6.0, z_bottom=0.0)[0]


def flipped() -> np.ndarray:
    t = box()
    t[0] = t[0, ::-1]
    return t


MESHES: dict[str, np.ndarray] = {
    "box": box(),
    "open": box()[1:],
    "flipped": flipped(),
    "inverted": box()[:, ::-1],  # every triangle reversed: closed, consistent, facing inwards
    "glued": np.concatenate([box(), box((2.0, 0.0, 0.0))]),  # two boxes sharing the face x = 1 in one mesh
    "far": box(tuple(UTM)),
    "hipped_L": roof_solid("hipped"),
    "gablets_L": roof_solid("hipped-and-gabled"),  # vertical gablet triangles inside the roof
}
# (watertight, winding consistent, volume sign or None where it depends on the reference point) as trimesh
# says; spelled out so that a change in both is caught too
EXPECTED: dict[str, tuple[bool, bool, int | None]] = {
    "box": (True, True, 1), "open": (False, True, None), "flipped": (True, False, None), "inverted": (True, True, -1),
    "glued": (False, True, 1), "far": (True, True, 1), "hipped_L": (True, True, 1), "gablets_L": (True, True, 1),
}  # fmt: skip


def as_trimesh(tris: np.ndarray) -> trimesh.Trimesh:
    return trimesh.Trimesh(tris.reshape(-1, 3), np.arange(3 * len(tris)).reshape(-1, 3), process=True)


def one(tris: np.ndarray) -> Closure:
    return closure(tris, np.array([0, len(tris)]))


def batch(meshes: list[np.ndarray]) -> Closure:
    return closure(np.concatenate(meshes), np.concatenate([[0], np.cumsum([len(m) for m in meshes])]))


@pytest.mark.parametrize("name", list(MESHES))
def test_one_mesh_matches_trimesh(name: str) -> None:
    tris = MESHES[name]
    c, m = one(tris), as_trimesh(tris)
    assert (bool(c.watertight[0]), bool(c.winding_consistent[0])) == (m.is_watertight, m.is_winding_consistent)
    assert (m.is_watertight, m.is_winding_consistent) == EXPECTED[name][:2]
    # the volume is only defined where the triangles form closed consistent shells (glued: two of them, 48)
    if EXPECTED[name][2] is not None:
        assert np.sign(m.volume) == np.sign(c.volume[0]) == EXPECTED[name][2]
        assert c.volume[0] == pytest.approx(m.volume, rel=1e-9)
    assert bool(c.ok[0]) == (m.is_watertight and m.is_winding_consistent and m.volume > 0)


def test_batch_matches_one_by_one() -> None:
    names = list(MESHES)
    c = batch([MESHES[k] for k in names])
    for i, k in enumerate(names):
        s = one(MESHES[k])
        assert c.watertight[i] == s.watertight[0] and c.winding_consistent[i] == s.winding_consistent[0], k
        assert c.open_edges[i] == s.open_edges[0] and c.nonmanifold_edges[i] == s.nonmanifold_edges[0], k
        assert c.volume[i] == pytest.approx(s.volume[0], rel=1e-9), k
    assert c.ok.tolist() == [EXPECTED[k] == (True, True, 1) for k in names]


def test_volume_is_exact_far_from_the_origin() -> None:
    # measured from each mesh's own first vertex, so UTM coordinates lose nothing
    assert one(MESHES["far"]).volume[0] == pytest.approx(24.0, abs=1e-9)
    assert one(MESHES["box"]).volume[0] == pytest.approx(24.0, abs=1e-12)
    assert one(MESHES["inverted"]).volume[0] == pytest.approx(-24.0, abs=1e-12)


def test_edge_counts() -> None:
    c = batch([box(), box()[1:], box()[2:], MESHES["glued"]])
    # one missing triangle leaves its 3 edges open; the two triangles of one side leave that side's 4
    assert c.open_edges.tolist()[:3] == [0, 3, 4]
    assert c.nonmanifold_edges.tolist()[:3] == [0, 0, 0]
    assert c.open_edges[3] == 0 and c.nonmanifold_edges[3] > 0 and not c.watertight[3]


def test_nonmanifold_edges_are_counted_once() -> None:
    tris = MESHES["glued"]
    e = np.sort(as_trimesh(tris).edges, axis=1)
    _, uses = np.unique(e, axis=0, return_counts=True)
    assert one(tris).nonmanifold_edges[0] == (uses > 2).sum()  # the 4 sides of the shared face


def test_meshes_in_a_batch_are_independent() -> None:
    # the same two boxes as one mesh are non-manifold; as two meshes they touch but share nothing
    c = batch([box(), box((2.0, 0.0, 0.0))])
    assert c.watertight.tolist() == [True, True] and c.nonmanifold_edges.tolist() == [0, 0]
    assert not one(MESHES["glued"]).watertight[0]
    # a box missing a triangle is not closed by that triangle coming in the next mesh
    t = box()
    c = batch([t[1:], t[:1]])
    assert c.watertight.tolist() == [False, False] and c.open_edges.tolist() == [3, 3]
    # and the same coordinates in a mesh after it do not change its verdicts
    c = batch([t[1:], box(), t[:1]])
    assert c.open_edges.tolist() == [3, 0, 3] and c.watertight.tolist() == [False, True, False]


def test_empty_mesh_in_a_batch() -> None:
    c = closure(np.concatenate([box(), box()]), np.array([0, 12, 12, 24]))
    assert c.watertight.tolist() == [True, False, True] and c.winding_consistent.tolist() == [True, False, True]
    assert c.volume.tolist() == pytest.approx([24.0, 0.0, 24.0])
    m = trimesh.Trimesh()
    assert not m.is_watertight and not m.is_winding_consistent  # trimesh's verdict on an empty mesh
    c = closure(np.zeros((0, 3, 3)), np.array([0, 0]))
    assert c.watertight.tolist() == [False] and c.winding_consistent.tolist() == [False]
