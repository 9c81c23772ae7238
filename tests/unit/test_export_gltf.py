"""GLB writer: the container, accessors and the EXT_structural_metadata table read back exactly, and the
Khronos glTF-Validator finds no error."""

import numpy as np
import pytest

from core.geodesy import enu_rotation, geodetic_to_ecef
from exporter.content import srgb_to_linear16, tile_arrays
from exporter.gltf import Primitive, Property, accessor_array, property_table, read_glb, write_glb
from tests.conftest import validate_glb


def cube_primitive() -> Primitive:
    # two features: a unit cube's top (feature 0) and bottom (feature 1) as 2 triangles each
    pos = np.array(
        [[0, 1, 0], [1, 1, 0], [1, 1, -1], [0, 1, -1], [0, 0, 0], [1, 0, 0], [1, 0, -1], [0, 0, -1]], dtype=np.float32
    )
    nrm = np.array([[0, 1, 0]] * 4 + [[0, -1, 0]] * 4, dtype=np.float32)
    col = np.full((8, 4), 200, dtype=np.uint8)
    fid = np.array([0, 0, 0, 0, 1, 1, 1, 1])
    idx = np.array([0, 1, 2, 0, 2, 3, 4, 6, 5, 4, 7, 6], dtype=np.uint32)
    props = [
        Property("osm_id", [123456789012, 42], "INT64", required=True),
        Property("name", ["Tuomiokirkko", None], None),
        Property("empty", [None, None], None),
        Property("height", [12.5, 3.0], "FLOAT32", required=True),
        Property("levels", [None, 2.0], "FLOAT32", no_data=-1.0),
    ]
    return Primitive(pos, nrm, col, fid, idx, props, feature_count=2)


def test_roundtrip() -> None:
    glb = write_glb(cube_primitive())
    assert glb[:4] == b"glTF" and len(glb) % 4 == 0
    gltf, binary = read_glb(glb)
    prim = gltf["meshes"][0]["primitives"][0]
    assert np.array_equal(accessor_array(gltf, binary, prim["attributes"]["POSITION"]), cube_primitive().positions)
    assert accessor_array(gltf, binary, prim["indices"]).tolist() == cube_primitive().indices.tolist()
    assert gltf["accessors"][prim["indices"]]["componentType"] == 5123  # 16-bit indices when they fit
    fids = accessor_array(gltf, binary, prim["attributes"]["_FEATURE_ID_0"])
    assert fids.tolist() == [0, 0, 0, 0, 1, 1, 1, 1]
    ext = prim["extensions"]["EXT_mesh_features"]["featureIds"][0]
    assert ext == {"featureCount": 2, "attribute": 0, "propertyTable": 0}
    table = property_table(gltf, binary)
    assert table["osm_id"] == [123456789012, 42]
    assert table["name"] == ["Tuomiokirkko", ""]
    assert table["height"] == [12.5, 3.0]
    assert table["levels"] == [-1.0, 2.0]
    assert "empty" not in table  # all noData: column omitted, class property kept
    cls = gltf["extensions"]["EXT_structural_metadata"]["schema"]["classes"]["building"]["properties"]
    assert cls["empty"]["noData"] == "" and cls["levels"]["noData"] == -1.0
    assert all(v["byteOffset"] % 8 == 0 and v["byteLength"] > 0 for v in gltf["bufferViews"])
    assert gltf["asset"]["copyright"].startswith("©")


def test_large_primitive_uses_32_bit_indices() -> None:
    n = 70_000
    pos = np.zeros((n, 3), dtype=np.float32)
    pos[:, 0] = np.arange(n)
    p = Primitive(
        pos,
        np.tile(np.float32([0, 1, 0]), (n, 1)),
        np.full((n, 4), 255, np.uint8),
        np.zeros(n),
        np.arange(n - n % 3, dtype=np.uint32),
        [Property("osm_id", [1], "INT64")],
        feature_count=1,
    )
    gltf, binary = read_glb(write_glb(p))
    idx = gltf["meshes"][0]["primitives"][0]["indices"]
    assert gltf["accessors"][idx]["componentType"] == 5125
    assert accessor_array(gltf, binary, idx)[-1] == n - n % 3 - 1


def test_property_length_mismatch_is_an_error() -> None:
    p = cube_primitive()
    p.properties.append(Property("bad", [1], "INT32"))
    with pytest.raises(ValueError):
        write_glb(p)


def test_tile_arrays_place_and_dedupe() -> None:
    lon, lat = np.radians(24.95), np.radians(60.17)
    origin = geodetic_to_ecef(lon, lat, 0.0)
    rot = enu_rotation(lon, lat)
    # one horizontal square roof 10 m up and 5 m east, 3 m north of the origin, as two triangles
    enu = np.array([[[5, 3, 10], [6, 3, 10], [6, 4, 10]], [[5, 3, 10], [6, 4, 10], [5, 4, 10]]], dtype=float)
    ecef = origin + enu @ rot.T
    wall = np.array([[10, 20, 30, 255]], dtype=np.uint8)
    roof = np.array([[200, 100, 50, 255]], dtype=np.uint8)
    arr = tile_arrays(ecef, np.array([0, 0]), wall, roof, lon, lat)
    assert len(arr.positions) == 4 and len(arr.indices) == 6  # shared corners merged
    # glTF frame is (E, U, -N)
    corners = sorted([(5, 10, -3), (6, 10, -3), (6, 10, -4), (5, 10, -4)])
    assert np.allclose(sorted(map(tuple, arr.positions.round(3))), corners, atol=1e-3)
    assert np.allclose(arr.normals, [0, 1, 0], atol=1e-6)
    assert (arr.colors == srgb_to_linear16(roof)[0]).all()  # up-facing: roof colour, linearised
    # sRGB mid-grey 128 is linear 0.2159; black, white and alpha are unchanged
    lin = srgb_to_linear16(np.array([[255, 128, 0, 128]], np.uint8))[0] / 65535
    assert lin == pytest.approx([1.0, 0.2159, 0.0, 128 / 255], abs=2e-4)


def test_khronos_validator_accepts(tmp_path) -> None:
    f = tmp_path / "cube.glb"
    f.write_bytes(write_glb(cube_primitive()))
    report = validate_glb(f)
    assert report["files"] == 1
    assert report["errors"] == 0 and report["warnings"] == 0, report


def _mutated(mutate) -> bytes:
    from exporter.gltf import _pack

    gltf, binary = read_glb(write_glb(cube_primitive()))
    binary = bytearray(binary)
    mutate(gltf, binary)
    return _pack(gltf, bytes(binary))


def _ext(g):
    return g["meshes"][0]["primitives"][0]["extensions"]["EXT_mesh_features"]["featureIds"][0]


def _table(g):
    return g["extensions"]["EXT_structural_metadata"]["propertyTables"][0]


def _string_offsets_view(g):
    return g["bufferViews"][_table(g)["properties"]["name"]["stringOffsets"]]


@pytest.mark.parametrize(
    ("mutate", "needle"),
    [
        (lambda g, b: _ext(g).update(featureCount=1), "!= 2 distinct feature ids"),
        (lambda g, b: _table(g).update(count=3) or _ext(g).update(featureCount=3), "have no vertex"),
        (lambda g, b: _table(g)["properties"].pop("osm_id"), "required property osm_id missing"),
        (lambda g, b: _table(g).update({"class": "nope"}), "not in the schema"),
        (lambda g, b: _table(g)["properties"].update(bogus={"values": 0}), "not a property of class"),
        (lambda g, b: _ext(g).update(propertyTable=4), "does not exist"),
        (lambda g, b: g["extensionsUsed"].remove("EXT_mesh_features"), "not in extensionsUsed"),
        (lambda g, b: g["bufferViews"][0].update(byteLength=10**7), "outside its buffer"),
        (
            lambda g, b: b.__setitem__(
                slice(_string_offsets_view(g)["byteOffset"] + 4, _string_offsets_view(g)["byteOffset"] + 8),
                (999).to_bytes(4, "little"),
            ),
            "string offsets",
        ),
    ],
)
def test_metadata_checks_catch_each_rule(mutate, needle) -> None:
    from exporter.checks import check_glb

    assert check_glb(write_glb(cube_primitive())) == []
    problems = check_glb(_mutated(mutate))
    assert any(needle in p for p in problems), problems


def test_metadata_checks_catch_out_of_range_feature_ids() -> None:
    from exporter.checks import check_glb

    p = cube_primitive()
    p.feature_ids = np.array([0, 0, 0, 0, 1, 1, 1, 7])
    assert any("integers in [0, 2)" in x for x in check_glb(write_glb(p)))


def textured_glb() -> bytes:
    """The cube with its top (feature 0) textured from a WebP page and its bottom (feature 1) vertex-coloured."""
    from etl.textures.atlas import encode_image
    from exporter.gltf import Image

    c = cube_primitive()
    page = np.zeros((8, 12, 3), np.uint8)
    page[:, :6] = (200, 40, 30)
    data, mime = encode_image(page, "webp")
    top = Primitive(
        c.positions[:4],
        c.normals[:4],
        np.zeros((0, 4), np.uint8),
        c.feature_ids[:4],
        np.array([0, 1, 2, 0, 2, 3], np.uint32),
        uvs=np.array([[0, 0], [0.5, 0], [0.5, 1], [0, 1]], np.float32),
        image=0,
    )
    plain = Primitive(
        c.positions[4:],
        c.normals[4:],
        c.colors[4:],
        c.feature_ids[4:],
        np.array([0, 2, 1, 0, 3, 2], np.uint32),
        c.properties,
        feature_count=2,
    )
    return write_glb(plain, textured=[top], images=[Image(data, mime)])


def test_textured_glb_validates_with_one_material_per_page(tmp_path) -> None:
    from exporter.checks import check_glb

    glb = textured_glb()
    gltf, binary = read_glb(glb)
    assert gltf["extensionsRequired"] == ["EXT_texture_webp"] and "EXT_texture_webp" in gltf["extensionsUsed"]
    plain, top = gltf["meshes"][0]["primitives"]
    assert "COLOR_0" in plain["attributes"] and "TEXCOORD_0" not in plain["attributes"]
    assert "TEXCOORD_0" in top["attributes"] and "COLOR_0" not in top["attributes"]
    # each primitive counts the features of its own vertices; together they draw the whole table
    assert [p["extensions"]["EXT_mesh_features"]["featureIds"][0]["featureCount"] for p in (plain, top)] == [1, 1]
    texture = gltf["textures"][gltf["materials"][top["material"]]["pbrMetallicRoughness"]["baseColorTexture"]["index"]]
    assert (
        "source" not in texture
        and gltf["images"][texture["extensions"]["EXT_texture_webp"]["source"]]["mimeType"] == "image/webp"
    )
    assert gltf["samplers"] == [{"magFilter": 9729, "minFilter": 9987, "wrapS": 33071, "wrapT": 33071}]
    np.testing.assert_allclose(accessor_array(gltf, binary, top["attributes"]["TEXCOORD_0"])[2], [0.5, 1])
    assert check_glb(glb) == []
    f = tmp_path / "textured.glb"
    f.write_bytes(glb)
    report = validate_glb(f)
    assert report["errors"] == 0 and report["warnings"] == 0, report


def test_feature_checks_span_primitives() -> None:
    from exporter.checks import check_glb

    gltf, binary = read_glb(textured_glb())
    gltf["meshes"][0]["primitives"].pop(0)  # feature 1 is drawn nowhere now
    from exporter.gltf import _pack

    assert any("1 of 2 features have no vertex" in p for p in check_glb(_pack(gltf, binary)))
