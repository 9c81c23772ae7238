"""LOD1 extrusion: closed, outward-oriented, right volume, for squares, L-shapes, courtyards, multipolygons."""

import numpy as np
import pytest
import shapely
import trimesh

from core.wkb import decode_triangles, encode_triangles, encode_triangles_batch
from etl.geom.extrude import extrude

OFF = np.array([385_000.0, 6_672_000.0])  # UTM-sized coordinates, where precision matters


def shapes() -> dict[str, shapely.MultiPolygon]:
    sq = shapely.box(0, 0, 20, 20)
    ell = shapely.Polygon([(0, 0), (30, 0), (30, 10), (10, 10), (10, 25), (0, 25)])
    court = shapely.Polygon(shapely.box(0, 0, 40, 40).exterior, [shapely.box(10, 10, 30, 30).exterior.coords])
    cw = shapely.Polygon(list(sq.exterior.coords)[::-1])  # clockwise input must still face outwards
    two = shapely.MultiPolygon([shapely.box(0, 0, 5, 5), shapely.box(10, 0, 15, 5)])
    dup = shapely.Polygon([(0, 0), (10, 0), (10, 0), (10, 10), (0, 10)])  # repeated vertex
    out = {}
    for k, g in {"square": sq, "L": ell, "courtyard": court, "clockwise": cw, "two": two, "dup": dup}.items():
        g = shapely.affinity.translate(g, *OFF)
        out[k] = g if isinstance(g, shapely.MultiPolygon) else shapely.MultiPolygon([g])
    return out


def as_trimesh(tris: np.ndarray) -> trimesh.Trimesh:
    m = trimesh.Trimesh(tris.reshape(-1, 3) - np.r_[OFF, 0], np.arange(len(tris) * 3).reshape(-1, 3), process=False)
    m.merge_vertices()
    return m


@pytest.mark.parametrize("name", ["square", "L", "courtyard", "clockwise", "two", "dup"])
def test_closed_outward_and_volume(name: str) -> None:
    g = shapes()[name]
    ex = extrude(np.array([g]), np.array([2.0]), np.array([14.0]))
    assert ex.ok[0]
    m = as_trimesh(ex.of(0))
    assert m.is_watertight and m.is_winding_consistent
    assert m.volume > 0  # positive only when the faces point outwards
    expected = g.area * 12.0
    assert m.volume == pytest.approx(expected, rel=1e-9)
    assert ex.volume[0] == pytest.approx(expected, rel=1e-9)
    z = ex.of(0)[:, :, 2]
    assert z.min() == 2.0 and z.max() == 14.0


def test_triangle_counts() -> None:
    # square: 2 + 2 cap triangles, 4 walls x 2; courtyard: 8 + 8 caps, 8 walls x 2
    s = shapes()
    ex = extrude(np.array([s["square"], s["courtyard"], s["L"]]), np.zeros(3), np.full(3, 10.0))
    assert list(ex.counts) == [12, 32, 20]


def test_caps_face_up_and_down() -> None:
    tris = extrude(np.array([shapes()["L"]]), np.array([0.0]), np.array([9.0])).of(0)
    n = np.cross(tris[:, 1] - tris[:, 0], tris[:, 2] - tris[:, 0])
    top = np.all(tris[:, :, 2] == 9.0, axis=1)
    bottom = np.all(tris[:, :, 2] == 0.0, axis=1)
    assert np.all(n[top, 2] > 0) and np.all(n[bottom, 2] < 0)
    walls = ~(top | bottom)
    assert np.allclose(n[walls, 2], 0.0)


def test_rejects_bad_heights() -> None:
    with pytest.raises(ValueError):
        extrude(np.array([shapes()["square"]]), np.array([5.0]), np.array([5.0]))


def test_wkb_roundtrip_and_batch() -> None:
    s = shapes()
    ex = extrude(np.array([s["square"], s["L"]]), np.zeros(2), np.full(2, 3.0))
    blobs = encode_triangles_batch(ex.triangles, ex.offsets, srid=32635)
    assert len(blobs) == 2
    for k, blob in enumerate(blobs):
        assert np.array_equal(decode_triangles(blob), ex.of(k))
        assert blob == encode_triangles(ex.of(k), srid=32635)
    assert decode_triangles(encode_triangles(ex.of(0))).shape == (12, 3, 3)
