"""tileset.json building and the 3D Tiles checks: a correct tree passes, and each broken rule is caught."""

import copy
import json
import math

import numpy as np
import pytest

from core.geodesy import Y_UP_TO_Z_UP, column_major, ecef_to_geodetic, enu_to_ecef, geodetic_to_ecef
from core.tiles3d import content_uris
from exporter.checks import check_tileset
from exporter.gltf import write_glb
from exporter.tileset import TileRecord, build_tileset, leaf_frame, node_matrix, region_diagonal
from tests.unit.test_export_gltf import cube_primitive

D = math.radians


def records() -> list[TileRecord]:
    root = (D(24.90), D(60.10), D(25.00), D(60.20), 0.0, 60.0)
    a = (D(24.90), D(60.10), D(24.95), D(60.20), 0.0, 60.0)
    b = (D(24.95), D(60.12), D(25.00), D(60.20), 0.0, 30.0)
    return [
        TileRecord(0, 0, 0, False, root, 500.0, "content/0/0/0.glb"),
        TileRecord(1, 0, 0, True, a, 0.0, "content/1/0/0.glb"),
        TileRecord(1, 1, 0, True, b, 0.0, "content/1/1/0.glb"),
    ]


def write(tmp_path, ts) -> object:
    glb = write_glb(cube_primitive())
    for uri in ("content/0/0/0.glb", "content/1/0/0.glb", "content/1/1/0.glb"):
        (tmp_path / uri).parent.mkdir(parents=True, exist_ok=True)
        (tmp_path / uri).write_bytes(glb)
    p = tmp_path / "tileset.json"
    p.write_text(json.dumps(ts))
    return p


def test_geodesy_roundtrip_and_enu() -> None:
    p = geodetic_to_ecef(D(24.95), D(60.17), 120.0)
    lon, lat, h = ecef_to_geodetic(p)
    assert (math.degrees(lon), math.degrees(lat), h) == pytest.approx((24.95, 60.17, 120.0), abs=1e-9)
    m = enu_to_ecef(D(24.95), D(60.17), 0.0)
    up = m[:3, :3] @ [0, 0, 1]
    assert np.allclose(m @ [0, 0, 10, 1], np.r_[geodetic_to_ecef(D(24.95), D(60.17), 10.0), 1], atol=1e-6)
    assert np.isclose(np.linalg.norm(up), 1.0)
    assert column_major(m)[12:15] == pytest.approx(list(m[:3, 3]))


def world(m: list[float]) -> np.ndarray:
    return np.array(m, float).reshape(4, 4).T


def test_build_and_check(tmp_path) -> None:
    ts = build_tileset(records())
    assert ts["asset"]["version"] == "1.1"
    assert ts["root"]["refine"] == "REPLACE"
    assert len(ts["root"]["children"]) == 2
    assert all("content" in t for t in [ts["root"], *ts["root"]["children"]])
    # one transform, the root's ENU frame; the glbs' node matrices place each tile in it (test_node_matrix...)
    assert not any("transform" in t for t in ts["root"]["children"])
    w, s, e, n = records()[0].region[:4]
    lon, lat = (w + e) / 2, (s + n) / 2
    assert np.allclose(world(ts["root"]["transform"]), enu_to_ecef(lon, lat, 0.0), atol=1e-6)
    assert ts["geometricError"] >= region_diagonal(records()[0].region)
    assert check_tileset(write(tmp_path, ts)) == []


def y_up_to_z_up() -> np.ndarray:
    m = np.eye(4)
    m[:3, :3] = Y_UP_TO_Z_UP
    return m


def test_node_matrix_places_a_tile_frame_point_where_the_per_tile_transform_did() -> None:
    """root transform @ (y-up -> z-up, what CesiumJS applies to glTF) @ node matrix = the tile's own ENU frame
    @ (y-up -> z-up): the chain the per-tile transforms used to give."""
    root = records()[0].region
    pts = np.array([[0, 0, 0, 1], [120.0, 35.0, -80.0, 1], [-3000.0, 2.0, 4000.0, 1]]).T  # glTF frame, y up
    for rec in records():
        new = world(column_major(leaf_frame(root))) @ y_up_to_z_up() @ world(node_matrix(rec.region, root)) @ pts
        old = leaf_frame(rec.region) @ y_up_to_z_up() @ pts
        assert np.allclose(new, old, atol=1e-6)
        # and the point's height above the ellipsoid is its y in the tile frame (the tile's frame is its own)
        h = ecef_to_geodetic(new[:3, 0])[2]
        assert h == pytest.approx(0.0, abs=1e-6)
    assert np.allclose(world(node_matrix(root, root)), np.eye(4), atol=1e-9)
    b = records()[2].region
    shift = world(node_matrix(b, root))[:3, 3]  # B's centre is east of the root's: +x, and north: -z (y up)
    assert shift[0] > 1000 and shift[2] < -1000


def test_single_lod_is_add_with_leaf_content(tmp_path) -> None:
    ts = build_tileset(records(), single_lod=True)
    assert ts["root"]["refine"] == "ADD" and "content" not in ts["root"]
    assert all("content" in c for c in ts["root"]["children"])
    assert check_tileset(write(tmp_path, ts)) == []


def test_unmeasured_error_refused() -> None:
    recs = records()
    recs[0] = TileRecord(0, 0, 0, False, recs[0].region, None, "content/0/0/0.glb")
    with pytest.raises(ValueError, match="generalize"):
        build_tileset(recs)


@pytest.mark.parametrize(
    ("mutate", "needle"),
    [
        (lambda t: t["asset"].update(version="2.0"), "asset.version"),
        (lambda t: t.update(geometricError=10.0), "too small"),
        (lambda t: t["root"].pop("refine"), "refine is required"),
        (lambda t: t["root"]["children"][0].update(refine="MERGE"), "refine must be"),
        (lambda t: t["root"]["children"][0].update(geometricError=900.0), "exceeds its parent"),
        (lambda t: t["root"]["children"][0].update(geometricError=-1), ">= 0"),
        (lambda t: t["root"]["children"][1]["boundingVolume"]["region"].__setitem__(5, 99.0), "not inside"),
        (lambda t: t["root"]["children"][1]["boundingVolume"]["region"].__setitem__(2, D(25.5)), "not inside"),
        (lambda t: t["root"]["children"][0].update(content={"uri": "content/nope.glb"}), "does not resolve"),
        (lambda t: t["root"]["children"][0].update(transform=[1, 0, 0]), "16 numbers"),
        (lambda t: t["root"].update(children=[]), "non-empty"),
        (lambda t: t["root"]["children"][0].update(boundingVolume={"region": [0, 1, 0, 0, 0, 1]}), "south <= north"),
        (lambda t: t["root"]["children"][0].update(boundingVolume={"box": [0] * 11}), "12 numbers"),
        (lambda t: t["root"]["children"][0].update(boundingVolume={}), "exactly one"),
        (lambda t: t.update(extensionsRequired=["X"]), "extensionsRequired"),
    ],
)
def test_checks_catch_each_rule(tmp_path, mutate, needle) -> None:
    ts = copy.deepcopy(build_tileset(records()))
    mutate(ts)
    problems = check_tileset(write(tmp_path, ts))
    assert any(needle in p for p in problems), problems


def test_checks_non_glb_content(tmp_path) -> None:
    p = write(tmp_path, build_tileset(records()))
    (tmp_path / "content/1/0/0.glb").write_bytes(b"not a glb at all")
    assert any("too short to be a GLB" in x for x in check_tileset(p))
    (tmp_path / "content/1/0/0.glb").write_bytes(b"not a glb at all, but long enough")
    assert any("not a GLB 2.0 file" in x for x in check_tileset(p))
    broken = bytearray(write_glb(cube_primitive()))
    broken[8:12] = (len(broken) + 4).to_bytes(4, "little")  # header length disagrees with the file
    (tmp_path / "content/1/0/0.glb").write_bytes(bytes(broken))
    assert any("header length" in x for x in check_tileset(p))


def test_content_uris_reads_every_content_of_the_tree() -> None:
    ts = build_tileset(records())
    assert content_uris(ts) == sorted(r.content_uri for r in records() if r.content_uri)
    # 3D Tiles 1.1's multiple contents and a tile without content, deeper down
    ts["root"]["children"][0]["children"] = [{"contents": [{"uri": "a.glb"}, {"uri": "b.glb"}]}, {"children": []}]
    assert {"a.glb", "b.glb"} <= set(content_uris(ts))
    assert content_uris({"root": {}}) == []
