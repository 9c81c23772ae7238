"""Compact geometry (exporter/gltf.py compact=True, exporter/meshopt.py): KHR_mesh_quantization positions within
the stated bound of the float64 input once the node matrix is applied, every attribute, triangle and property-table
value read back through the meshopt decoders, the Khronos glTF-Validator without errors, and plain bytes unchanged."""

import hashlib
import json
import struct

import meshoptimizer
import numpy as np
import pytest

from exporter.checks import check_glb, compressed_metadata_views
from exporter.export import LEAF_POSITION_ERROR_M, is_compact, position_error_m
from exporter.gltf import (
    Image,
    Primitive,
    accessor_array,
    feature_vertices,
    image_size,
    mesh_positions,
    node_positions,
    plan_quantization,
    property_table,
    quantization,
    read_glb,
    view_bytes,
    write_glb,
)
from exporter.meshopt import CompressionError
from exporter.tileset import TileRecord
from tests.conftest import validate_glb
from tests.unit.test_export_gltf import cube_primitive, textured_glb


def city_block(rng: np.random.Generator, half: float, height: float = 600.0) -> Primitive:
    """Random boxes (float64 corners, 12 triangles each) spread over +-half m around a point ``height`` m up:
    the shape of a tile's content in its frame (y up), 300 features."""
    n = 300
    base = np.c_[rng.uniform(-half, half, n), rng.uniform(height, height + 5, n), rng.uniform(-half, half, n)]
    size = rng.uniform(3, 30, (n, 3))
    corners = np.array([[x, y, z] for x in (0, 1) for y in (0, 1) for z in (0, 1)], np.float64)
    pos = (base[:, None, :] + corners[None] * size[:, None, :]).reshape(-1, 3)
    quads = np.array([[0, 1, 3, 2], [4, 6, 7, 5], [0, 4, 5, 1], [2, 3, 7, 6], [0, 2, 6, 4], [1, 5, 7, 3]])
    tri = np.concatenate([quads[:, [0, 1, 2]], quads[:, [0, 2, 3]]])
    idx = (tri[None] + 8 * np.arange(n)[:, None, None]).reshape(-1).astype(np.uint32)
    nrm = rng.normal(size=(len(pos), 3))
    nrm /= np.linalg.norm(nrm, axis=1)[:, None]
    colours = rng.integers(0, 65535, (len(pos), 4)).astype(np.uint16)
    fids = np.repeat(np.arange(n), 8)
    c = cube_primitive()
    props = [
        type(c.properties[0])("osm_id", list(range(10**9, 10**9 + n)), "INT64", required=True),
        type(c.properties[0])("name", [f"house {i}" if i % 3 else None for i in range(n)], None),
        type(c.properties[0])("lod", [i % 4 for i in range(n)], "UINT8", required=True),
        type(c.properties[0])("height", list(size[:, 1]), "FLOAT32", required=True),
    ]
    return Primitive(pos, nrm, colours, fids, idx, props, feature_count=n)


def rigid(angle: float, shift: tuple[float, float, float]) -> list[float]:
    """A column-major node matrix: a rotation about y and a translation (a tile frame -> root frame move)."""
    c, s = np.cos(angle), np.sin(angle)
    m = np.array([[c, 0, s, shift[0]], [0, 1, 0, shift[1]], [-s, 0, c, shift[2]], [0, 0, 0, 1]])
    return m.T.ravel().tolist()


def apply(matrix: list[float], pts: np.ndarray) -> np.ndarray:
    m = np.asarray(matrix).reshape(4, 4).T
    return pts @ m[:3, :3].T + m[:3, 3]


def triangles(gltf: dict, binary: bytes, prim: dict) -> set[tuple[tuple[float, ...], ...]]:
    """The primitive's triangles as sets of corner positions (rounded to mm) in the node's frame, rotation-free."""
    pos = node_positions(gltf, binary, prim["attributes"]["POSITION"]).round(3)
    idx = accessor_array(gltf, binary, prim["indices"]).reshape(-1, 3)
    return {tuple(sorted(map(tuple, pos[t]))) for t in idx}


@pytest.mark.parametrize(
    ("half", "geometric_error", "leaf"), [(150.0, 0.0, True), (300.0, 0.0, True), (900.0, 40.0, False)]
)
def test_positions_within_the_bound_after_the_node_matrix(half, geometric_error, leaf) -> None:
    rng = np.random.default_rng(7)
    prim = city_block(rng, half)
    rec = TileRecord(
        level=3,
        x=0,
        y=0,
        is_leaf=leaf,
        region=(0, 0, 0, 0, 0, 0),
        geometric_error=geometric_error,
        content_uri="t.glb",
        n_features=300,
        content_features=300,
    )
    bound = position_error_m(rec)
    assert bound == (LEAF_POSITION_ERROR_M if leaf else max(0.01, 0.01 * geometric_error))
    q = quantization([prim.positions], bound)
    assert q is not None  # these extents fit int16 at this bound
    node = rigid(0.3, (1234.5, -20.0, 77.0))
    glb = write_glb(prim, compact=True, quantization=q, node_matrix=node)
    gltf, binary = read_glb(glb)
    assert is_compact(glb) and set(gltf["extensionsRequired"]) == {"KHR_mesh_quantization", "KHR_meshopt_compression"}
    assert gltf["buffers"][1] == {
        "byteLength": gltf["buffers"][1]["byteLength"],
        "extensions": {"KHR_meshopt_compression": {"fallback": True}},
    }
    p = gltf["meshes"][0]["primitives"][0]
    assert gltf["accessors"][p["attributes"]["POSITION"]]["componentType"] == 5122  # SHORT
    # each stored vertex is one of the input's (reordered): match them by feature and nearest corner
    got = node_positions(gltf, binary, p["attributes"]["POSITION"])
    fid = accessor_array(gltf, binary, p["attributes"]["_FEATURE_ID_0"])
    want = apply(node, prim.positions)
    err = []
    for f in range(prim.feature_count):
        g, w = got[fid == f], want[prim.feature_ids == f]
        assert len(g) == len(w) == 8
        err.append(np.linalg.norm(g[:, None] - w[None], axis=2).min(axis=1).max())
    assert max(err) <= bound, (max(err), bound)
    assert max(err) > bound / 10  # the bound is used, not a much finer step
    # the mesh frame (the landmark metadata's) is the stored value times the node's scale
    np.testing.assert_allclose(
        mesh_positions(gltf, binary, p["attributes"]["POSITION"]),
        accessor_array(gltf, binary, p["attributes"]["POSITION"]) * q.step,
    )
    # the property table and the colours read back exactly, normals within BYTE precision
    table = property_table(gltf, binary)
    for prop in prim.properties:
        want_v = [("" if v is None else v) for v in prop.values]
        assert (
            table[prop.name] == pytest.approx(want_v)
            if prop.component_type == "FLOAT32"
            else table[prop.name] == want_v
        )
    assert check_glb(glb) == []


def test_every_triangle_survives_reordering_and_compression() -> None:
    prim = city_block(np.random.default_rng(3), 200.0)
    q = quantization([prim.positions], 0.01)
    gltf, binary = read_glb(write_glb(prim, compact=True, quantization=q))
    cgltf, cbin = read_glb(write_glb(prim))
    p, cp = gltf["meshes"][0]["primitives"][0], cgltf["meshes"][0]["primitives"][0]
    assert len(triangles(gltf, binary, p)) == len(triangles(cgltf, cbin, cp)) == 3600
    # colours and feature ids travel with their vertices (compare as sorted multisets)
    for name in ("COLOR_0", "_FEATURE_ID_0"):
        a = accessor_array(gltf, binary, p["attributes"][name]).reshape(len(prim.positions), -1)
        b = accessor_array(cgltf, cbin, cp["attributes"][name]).reshape(len(prim.positions), -1)
        assert np.array_equal(np.unique(a, axis=0, return_counts=True)[1], np.unique(b, axis=0, return_counts=True)[1])
    nrm = accessor_array(gltf, binary, p["attributes"]["NORMAL"]) / 127.0
    assert np.abs(np.linalg.norm(nrm, axis=1) - 1).max() < 0.02


def test_too_large_a_tile_keeps_float_positions_compressed() -> None:
    # 2 km across: int16 at 1 cm reaches 378 m from the origin, so the tile keeps FLOAT positions (meshopt still)
    prim = city_block(np.random.default_rng(5), 1000.0)
    assert quantization([prim.positions], 0.01) is None
    glb = write_glb(prim, compact=True, quantization=None)
    gltf, binary = read_glb(glb)
    p = gltf["meshes"][0]["primitives"][0]
    assert gltf["accessors"][p["attributes"]["POSITION"]]["componentType"] == 5126 and "matrix" not in gltf["nodes"][0]
    np.testing.assert_allclose(
        node_positions(gltf, binary, p["attributes"]["POSITION"]).min(axis=0), prim.positions.min(axis=0), atol=1e-3
    )
    assert len(glb) < len(write_glb(prim)) * 0.8


def test_a_wide_tile_keeps_one_mesh_of_exponential_float_positions_within_the_bound(tmp_path) -> None:
    # 2 km across at 1 cm: int16 does not reach, so FLOAT positions rounded to a power-of-two step through the
    # EXPONENTIAL filter, one mesh and node (no chunks: no extra primitives), within the same bound
    prim = city_block(np.random.default_rng(5), 1000.0)
    assert quantization([prim.positions], 0.01) is None
    q = plan_quantization([prim], 0.01)
    assert q.exponent == -7 and q.step == 2.0**-7 and q.scale == 1.0  # 7.8 mm steps: 6.8 mm at worst
    node = rigid(-0.7, (10.0, 20.0, 30.0))
    glb = write_glb(prim, compact=True, quantization=q, node_matrix=node)
    gltf, binary = read_glb(glb)
    assert len(gltf["nodes"]) == len(gltf["meshes"]) == 1 and len(gltf["meshes"][0]["primitives"]) == 1
    p = gltf["meshes"][0]["primitives"][0]
    acc = gltf["accessors"][p["attributes"]["POSITION"]]
    view = gltf["bufferViews"][acc["bufferView"]]
    assert acc["componentType"] == 5126 and view["byteStride"] == 12
    assert view["extensions"]["KHR_meshopt_compression"]["filter"] == "EXPONENTIAL"
    got, fid = feature_vertices(gltf, binary)
    want = apply(node, prim.positions)
    worst = max(
        np.linalg.norm(got[fid == f][:, None] - want[prim.feature_ids == f][None], axis=2).min(axis=1).max()
        for f in range(prim.feature_count)
    )
    assert 0.001 < worst <= 0.01
    # min/max are exact for the decoded values (what a loader without the filter would read from the fallback)
    stored = accessor_array(gltf, binary, p["attributes"]["POSITION"])
    assert acc["min"] == stored.min(axis=0).tolist() and acc["max"] == stored.max(axis=0).tolist()
    # the mesh frame (the landmark metadata's) is the tile's less the origin: positions in metres
    mesh, mfid = feature_vertices(gltf, binary, frame="mesh")
    for f in (0, 150, 299):
        tile = mesh[mfid == f] + np.asarray(q.origin)
        assert (
            np.linalg.norm(tile[:, None] - prim.positions[prim.feature_ids == f][None], axis=2).min(axis=1).max()
            <= 0.01
        )
    assert check_glb(glb) == []
    (tmp_path / "wide.glb").write_bytes(glb)
    report = validate_glb(tmp_path)
    assert report["errors"] == 0 and report["warnings"] == 0, report


def test_exponential_filter_round_trips_exactly() -> None:
    from exporter.meshopt import decode_exp, encode_exp

    v = np.array([[0.0, -1.5, 65000.123], [-8388607 * 2.0**-7, 3.0, 1e-3]])
    got = np.frombuffer(decode_exp(encode_exp(v, -7).tobytes(), 2, 12), "<f4").reshape(2, 3)
    np.testing.assert_array_equal(got, np.round(v / 2.0**-7) * 2.0**-7)
    with pytest.raises(ValueError, match="24 bits"):
        encode_exp(np.array([2.0**17]), -7)


def test_compact_glbs_pass_the_khronos_validator(tmp_path) -> None:
    prim = city_block(np.random.default_rng(11), 100.0)
    c = cube_primitive()
    files = {
        "block.glb": write_glb(
            prim,
            compact=True,
            quantization=quantization([prim.positions], 0.01),
            node_matrix=rigid(1.0, (5.0, 6.0, 7.0)),
        ),
        "cube.glb": write_glb(c, compact=True, quantization=quantization([c.positions], 0.01)),
        "float.glb": write_glb(prim, compact=True),
    }
    for name, glb in files.items():
        (tmp_path / name).write_bytes(glb)
        assert check_glb(glb) == [], name
    report = validate_glb(tmp_path)
    # KHR_meshopt_compression is not one the validator knows: it reports it as an info (unsupported extension)
    # and validates the decoded layout (buffer 1, the fallback, has no bytes it can check)
    assert report["files"] == 3 and report["errors"] == 0 and report["warnings"] == 0, report


def test_encoder_refusal_is_a_compression_error() -> None:
    prim = city_block(np.random.default_rng(1), 50.0)
    old = meshoptimizer.MeshoptLimits.MAX_VERTEX_COUNT
    meshoptimizer.MeshoptLimits.MAX_VERTEX_COUNT = 100  # the binding's own configurable limit
    try:
        with pytest.raises(CompressionError, match="refused"):
            write_glb(prim, compact=True, quantization=quantization([prim.positions], 0.01))
    finally:
        meshoptimizer.MeshoptLimits.MAX_VERTEX_COUNT = old


def test_plain_bytes_are_todays() -> None:
    # sha256 of what citylod wrote before compact geometry existed (commit db08689) for the same primitives
    assert hashlib.sha256(write_glb(cube_primitive())).hexdigest() == PLAIN_CUBE
    assert hashlib.sha256(textured_glb()).hexdigest() == PLAIN_TEXTURED


PLAIN_CUBE = "da4bc8aef027f1d0c9479b3a4d852fc766f8d364ebd37d515851b7d7ce51125b"
PLAIN_TEXTURED = "df11d66832f1d7d1815f6013cf3a84466b880387ce31a742ff42318af13c88e2"


def test_property_views_keep_their_exact_length() -> None:
    # CesiumJS counts a column's values by its bufferView's length: a padded UINT8 column (9 rows -> 12 bytes)
    # would make it drop the table, and with it every custom shader's metadata
    c = cube_primitive()
    n = 9
    props = [
        type(c.properties[0])("lod", [3] * n, "UINT8", required=True),
        type(c.properties[0])("osm_id", list(range(n)), "INT64", required=True),
        type(c.properties[0])("name", [f"n{i}" for i in range(n)], None),
    ]
    prim = Primitive(
        np.repeat(c.positions, 2, axis=0)[:16],
        np.repeat(c.normals, 2, axis=0)[:16],
        np.repeat(c.colors, 2, axis=0)[:16],
        np.arange(16) % n,
        np.arange(15, dtype=np.uint32),
        props,
        n,
    )
    gltf, binary = read_glb(write_glb(prim, compact=True, quantization=quantization([prim.positions], 0.01)))
    table = gltf["extensions"]["EXT_structural_metadata"]["propertyTables"][0]["properties"]
    assert gltf["bufferViews"][table["lod"]["values"]]["byteLength"] == n
    assert gltf["bufferViews"][table["osm_id"]["values"]]["byteLength"] == 8 * n
    assert property_table(gltf, binary)["lod"] == [3] * n


def _geometry_views(gltf: dict) -> set[int]:
    return {
        gltf["accessors"][a]["bufferView"]
        for m in gltf["meshes"]
        for p in m["primitives"]
        for a in [*p["attributes"].values(), p["indices"]]
    }


def test_primitives_share_one_view_per_attribute_and_read_back(tmp_path) -> None:
    # several primitives (atlas pages): every one's POSITION, NORMAL, COLOR_0, feature ids and indices go into
    # one view each (accessors by byteOffset), so the views do not grow with the primitives
    prim = city_block(np.random.default_rng(5), 100.0)
    half = np.arange(prim.feature_count) < 150
    parts = [_features(prim, half), _features(prim, ~half)]
    q = quantization([prim.positions], 0.01)
    empty = Primitive(
        np.zeros((0, 3)),
        np.zeros((0, 3)),
        np.zeros((0, 4), np.uint16),
        np.zeros(0, np.int64),
        np.zeros(0, np.uint32),
        prim.properties,
        prim.feature_count,
    )
    glb = write_glb(empty, compact=True, quantization=q, textured=parts, images=[_ktx2_like(64, 32)] * 2)
    gltf, binary = read_glb(glb)
    prims = gltf["meshes"][0]["primitives"]
    assert len(prims) == 2 and len(_geometry_views(gltf)) == 5
    assert sum(len(triangles(gltf, binary, p)) for p in prims) == len(prim.indices) // 3
    offsets = [gltf["accessors"][p["attributes"]["POSITION"]].get("byteOffset", 0) for p in prims]
    assert len(set(offsets)) == len(prims)  # each primitive its own range of the pooled view
    nrm = np.concatenate([accessor_array(gltf, binary, p["attributes"]["NORMAL"]) for p in prims]) / 127.0
    assert np.abs(np.linalg.norm(nrm, axis=1) - 1).max() < 0.02


def _features(prim: Primitive, keep: np.ndarray) -> Primitive:
    """The vertices and triangles of the features ``keep`` selects, with made-up uvs in [0, 1] (page 0)."""
    keep_v = keep[prim.feature_ids]
    new = np.cumsum(keep_v) - 1
    tris = prim.indices.reshape(-1, 3)
    tris = tris[keep_v[tris[:, 0]]]
    uv = np.random.default_rng(1).uniform(0, 1, (int(keep_v.sum()), 2))
    return Primitive(
        prim.positions[keep_v],
        prim.normals[keep_v],
        np.zeros((0, 4), np.uint8),
        prim.feature_ids[keep_v],
        new[tris].reshape(-1).astype(np.uint32),
        uvs=uv,
        image=0,
    )


def _ktx2_like(width: int, height: int) -> Image:
    """An image whose KTX2 header gives its size (the glb writer reads only that)."""
    return Image(b"\xabKTX 20\xbb\r\n\x1a\n" + struct.pack("<IIII", 0, 1, width, height) + bytes(64), "image/ktx2")


def test_texcoords_are_quarter_texels_scaled_back_by_the_texture_transform(tmp_path) -> None:
    from etl.textures.atlas import encode_image

    prim = city_block(np.random.default_rng(2), 100.0)
    page = np.zeros((32, 64, 3), np.uint8)
    webp, mime = encode_image(page, "webp")
    empty = Primitive(
        np.zeros((0, 3)),
        np.zeros((0, 3)),
        np.zeros((0, 4), np.uint16),
        np.zeros(0, np.int64),
        np.zeros(0, np.uint32),
        prim.properties,
        prim.feature_count,
    )
    tp = _features(prim, np.ones(prim.feature_count, bool))
    for image in (Image(webp, mime), _ktx2_like(64, 32)):
        assert image_size(image) == (64, 32)
        glb = write_glb(
            empty, compact=True, quantization=quantization([prim.positions], 0.01), textured=[tp], images=[image]
        )
        gltf, binary = read_glb(glb)
        p = gltf["meshes"][0]["primitives"][0]
        acc = gltf["accessors"][p["attributes"]["TEXCOORD_0"]]
        assert acc["componentType"] == 5123 and not acc.get("normalized")
        info = gltf["materials"][p["material"]]["pbrMetallicRoughness"]["baseColorTexture"]
        scale = info["extensions"]["KHR_texture_transform"]["scale"]
        assert scale == [1 / 256, 1 / 128]
        assert "KHR_texture_transform" in gltf["extensionsRequired"]
        # every vertex's texcoord, scaled back, within 1/8 texel of the input (matched through the positions)
        got = accessor_array(gltf, binary, p["attributes"]["TEXCOORD_0"]) * np.asarray(scale)
        pos = node_positions(gltf, binary, p["attributes"]["POSITION"])
        near = np.linalg.norm(pos[:, None] - tp.positions[None], axis=2).argmin(axis=1)
        texel_err = np.abs(got - tp.uvs[near]) * [64, 32]
        assert texel_err.max() <= 1 / 8 + 1e-9 and texel_err.max() > 1 / 32
        (tmp_path / f"uv_{image.mime.split('/')[1]}.glb").write_bytes(glb)
    report = validate_glb(tmp_path)
    assert report["errors"] == 0, report
    # an image whose size is unknown keeps normalized texcoords and no transform
    gltf, _ = read_glb(
        write_glb(
            empty,
            compact=True,
            quantization=quantization([prim.positions], 0.01),
            textured=[tp],
            images=[Image(b"not an image", "image/png")],
        )
    )
    assert gltf["accessors"][gltf["meshes"][0]["primitives"][0]["attributes"]["TEXCOORD_0"]]["normalized"]
    assert "KHR_texture_transform" not in gltf["extensionsUsed"]


def test_the_ext_variant_decodes_to_the_same_views_with_codec_version_0() -> None:
    # --geometry compact-ext: EXT_meshopt_compression (vertex codec 0) for loaders without the KHR extension;
    # the same decoded data, larger streams (random normals and colours here: 4 %; 11-29 % on real tiles)
    prim = city_block(np.random.default_rng(9), 100.0)
    q = quantization([prim.positions], 0.01)
    khr, ext = (
        read_glb(write_glb(prim, compact=True, quantization=q, meshopt_extension=e))
        for e in ("KHR_meshopt_compression", "EXT_meshopt_compression")
    )
    assert "EXT_meshopt_compression" in ext[0]["extensionsRequired"]
    assert "KHR_meshopt_compression" not in json.dumps(ext[0])
    assert len(khr[0]["bufferViews"]) == len(ext[0]["bufferViews"])
    sizes = {"KHR_meshopt_compression": 0, "EXT_meshopt_compression": 0}
    for (g, binary), name in ((khr, "KHR_meshopt_compression"), (ext, "EXT_meshopt_compression")):
        for v in g["bufferViews"]:
            e = v.get("extensions", {}).get(name)
            if e and e["mode"] == "ATTRIBUTES":
                assert binary[e["byteOffset"]] == (0xA1 if name.startswith("KHR") else 0xA0)  # codec version
                sizes[name] += e["byteLength"]
    for i in range(len(khr[0]["bufferViews"])):
        assert view_bytes(*khr, i) == view_bytes(*ext, i)
    assert sizes["KHR_meshopt_compression"] < sizes["EXT_meshopt_compression"]


def test_octahedral_normals_within_1_2_degrees() -> None:
    from exporter.meshopt import decode_oct, encode_oct

    rng = np.random.default_rng(7)
    n = rng.normal(size=(20000, 3))
    n = np.concatenate([n / np.linalg.norm(n, axis=1)[:, None], np.eye(3), -np.eye(3)])
    got = np.frombuffer(decode_oct(encode_oct(n).tobytes(), len(n), 4), np.int8).reshape(-1, 4)
    v = got[:, :3] / np.linalg.norm(got[:, :3], axis=1)[:, None]
    angle = np.degrees(np.arccos(np.clip((v * n).sum(axis=1), -1.0, 1.0)))
    assert angle.max() < 1.2
    assert np.array_equal(got[-6:, :3], np.r_[np.eye(3), -np.eye(3)] * 127)  # the axes exactly
    # a glb's stream carries the filter; the reader applies it
    prim = city_block(np.random.default_rng(3), 100.0)
    gltf, binary = read_glb(write_glb(prim, compact=True, quantization=quantization([prim.positions], 0.01)))
    p = gltf["meshes"][0]["primitives"][0]
    view = gltf["bufferViews"][gltf["accessors"][p["attributes"]["NORMAL"]]["bufferView"]]
    assert view["extensions"]["KHR_meshopt_compression"]["filter"] == "OCTAHEDRAL"


def test_compact_tables_share_equal_columns_and_drop_all_nodata_optional_ones() -> None:
    c = cube_primitive()
    P = type(c.properties[0])
    n = 8
    props = [
        P("lm_centre_x", [0.0] * n, "FLOAT32", "desc x", required=True),
        P("lm_centre_y", [0.0] * n, "FLOAT32", "desc y", required=True),
        P("lm_rank", [None] * n, "UINT32", "rank", no_data=0),
        P("levels", [None, 2.0] * 4, "FLOAT32", "levels", no_data=-1.0),
    ]
    prim = Primitive(
        c.positions, c.normals, c.colors, np.arange(len(c.positions)) % n, np.asarray(c.indices, np.uint32), props, n
    )
    gltf, binary = read_glb(write_glb(prim, compact=True, quantization=quantization([prim.positions], 0.01)))
    meta = gltf["extensions"]["EXT_structural_metadata"]
    cols = meta["propertyTables"][0]["properties"]
    assert cols["lm_centre_x"]["values"] == cols["lm_centre_y"]["values"]  # the same bytes, one view
    assert "lm_rank" not in cols and "levels" in cols  # optional, all noData: omitted (the spec's reading)
    assert meta["schema"]["classes"]["building"]["properties"]["lm_rank"] == {
        "type": "SCALAR",
        "componentType": "UINT32",
        "noData": 0,
    }  # no descriptions: tileset.json has them
    table = property_table(gltf, binary)
    assert table["lm_centre_y"] == [0.0] * n and table["levels"] == [-1.0, 2.0] * 4 and "lm_rank" not in table
    assert property_table(gltf, binary, fill_no_data=True)["lm_rank"] == [0] * n
    # plain glbs keep every column in its own view, with the descriptions
    pg, _ = read_glb(write_glb(prim))
    pmeta = pg["extensions"]["EXT_structural_metadata"]
    assert len({c["values"] for c in pmeta["propertyTables"][0]["properties"].values()}) == 4
    assert pmeta["schema"]["classes"]["building"]["properties"]["lm_rank"]["description"] == "rank"


def test_the_tileset_schema_describes_what_compact_glbs_leave_out() -> None:
    from exporter.export import PROPERTIES, building_schema_class

    cls = building_schema_class()
    assert list(cls["properties"]) == [p[0] for p in PROPERTIES]
    assert all(spec["description"] for spec in cls["properties"].values())
    assert cls["properties"]["lm_level"] == {
        "description": dict((p[0], p[2]) for p in PROPERTIES)["lm_level"],
        "type": "SCALAR",
        "componentType": "UINT8",
        "noData": 255,
    }
    assert "mesh frame" in cls["properties"]["lm_centre_x"]["description"]  # compact's words (COMPACT_DOCS)


def test_property_tables_stay_plain_unless_asked_and_read_the_same() -> None:
    # a reader of metadata without a meshopt decoder (the CesiumGS 3d-tiles-validator) reads the views as they
    # are: the default compact glb compresses its geometry and leaves every view a property table reads plain
    prim = city_block(np.random.default_rng(7), 150.0)
    q = quantization([prim.positions], 0.01)
    plain_tables = write_glb(prim, compact=True, quantization=q)
    packed_tables = write_glb(prim, compact=True, quantization=q, compress_tables=True)
    (g0, b0), (g1, b1) = read_glb(plain_tables), read_glb(packed_tables)
    compressed = [i for i, v in enumerate(g0["bufferViews"]) if "KHR_meshopt_compression" in v.get("extensions", {})]
    assert set(compressed) & _geometry_views(g0) and compressed_metadata_views(g0) == []
    assert len(compressed_metadata_views(g1)) >= 3 and len(packed_tables) < len(plain_tables)
    assert property_table(g0, b0) == property_table(g1, b1) == property_table(*read_glb(write_glb(prim)))
    assert check_glb(plain_tables) == [] and check_glb(packed_tables) == []
