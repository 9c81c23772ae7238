"""Implicit tiling (exporter/subtree.py, tileset.build_implicit, core/tiles3d.expand): the implicit tileset stands
for exactly the explicit tree (same tiles, regions, errors, content), subtree files follow the binary format,
single-LOD tilesets have content at the leaves only, and the checks catch broken subtrees."""

import json
import math
import struct

import numpy as np
import pytest

from core.camera import Camera
from core.geodesy import E2, A, metres_per_radian
from core.tiles3d import content_uris, expand, read_subtree, tileset_files, uniform_region
from exporter.checks import check_tileset
from exporter.gltf import write_glb
from exporter.serve.paths import BadPath, tile_address
from exporter.subtree import choose_subtree_levels, morton, write_subtree
from exporter.tileset import TileRecord, build, build_implicit, build_tileset, implicit_root_error
from exporter.volumes import error_shortfalls, overhangs
from tests.support.traverse import select
from tests.unit.test_export_gltf import cube_primitive

D = math.radians


def tree(depth: int = 5, seed: int = 1) -> list[TileRecord]:
    """A sparse quadtree like tiles.build_quadtree's: leaves at varying levels, regions the extents of their
    content (not the uniform subdivision of the root), parents the union of their children, every ancestor
    present, errors shrinking with depth."""
    rng = np.random.default_rng(seed)
    leaves: list[tuple[int, int, int]] = []

    def split(lv: int, x: int, y: int) -> None:
        if lv == depth or (lv >= 2 and rng.random() < 0.35):
            leaves.append((lv, x, y))
            return
        for i in (0, 1):
            for j in (0, 1):
                if lv < 1 or rng.random() < 0.8:
                    split(lv + 1, 2 * x + i, 2 * y + j)

    split(0, 0, 0)
    region: dict[tuple[int, int, int], list[float]] = {}
    for lv, x, y in leaves:
        n = 1 << lv
        w, s = D(24.9) + D(0.2) * x / n, D(60.1) + D(0.1) * y / n
        pad = D(0.01) / n * rng.random()  # meshes spill out of their cell
        region[(lv, x, y)] = [w - pad, s - pad, w + D(0.2) / n + pad, s + D(0.1) / n, 0.0, 10 + 50 * rng.random()]
    for lv, x, y in list(region):
        for up in range(1, lv + 1):
            k = (lv - up, x >> up, y >> up)
            r, c = region.get(k), region[(lv, x, y)]
            region[k] = (
                c.copy()
                if r is None
                else [
                    min(r[0], c[0]),
                    min(r[1], c[1]),
                    max(r[2], c[2]),
                    max(r[3], c[3]),
                    min(r[4], c[4]),
                    max(r[5], c[5]),
                ]
            )
    leaf = set(leaves)
    return [
        TileRecord(
            lv,
            x,
            y,
            (lv, x, y) in leaf,
            tuple(r),
            0.0 if (lv, x, y) in leaf else 400.0 / 2**lv,
            f"content/{lv}/{x}/{y}.glb",
        )
        for (lv, x, y), r in sorted(region.items())
    ]


def walk(t: dict):
    yield t
    for c in t.get("children", []):
        yield from walk(c)


def shape(tileset: dict) -> dict:
    """Every tile by its bounding region: (error, content uri, children's regions), refine of the root."""
    out = {}
    for t in walk(tileset["root"]):
        out[tuple(t["boundingVolume"]["region"])] = (
            t["geometricError"],
            t.get("content", {}).get("uri"),
            sorted(tuple(c["boundingVolume"]["region"]) for c in t.get("children", [])),
        )
    return out


def written(tmp_path, ts: dict, files: dict[str, bytes], uris: list[str]):
    glb = write_glb(cube_primitive())
    for uri in uris:
        (tmp_path / uri).parent.mkdir(parents=True, exist_ok=True)
        (tmp_path / uri).write_bytes(glb)
    for uri, data in files.items():
        (tmp_path / uri).parent.mkdir(parents=True, exist_ok=True)
        (tmp_path / uri).write_bytes(data)
    (tmp_path / "tileset.json").write_text(json.dumps(ts))
    return tmp_path / "tileset.json"


def test_morton_order() -> None:
    assert morton(np.array([0, 1, 0, 1, 3, 2]), np.array([0, 0, 1, 1, 3, 1])).tolist() == [0, 1, 2, 3, 15, 6]


@pytest.mark.parametrize("levels", [None, 1, 2, 3, 7])
@pytest.mark.parametrize("single_lod", [False, True])
def test_implicit_stands_for_the_explicit_tree(levels, single_lod) -> None:
    recs = tree()
    ts, files = build_implicit(recs, single_lod=single_lod, subtree_levels=levels)
    explicit = build_tileset(recs, single_lod=single_lod)
    got = expand(json.loads(json.dumps(ts)), files.__getitem__)
    assert shape(got) == shape(explicit)
    assert got["root"]["refine"] == explicit["root"]["refine"] == ("ADD" if single_lod else "REPLACE")
    assert got["root"]["transform"] == explicit["root"]["transform"]
    assert ts["geometricError"] == explicit["geometricError"]
    assert content_uris(ts, files.__getitem__) == content_uris(explicit)
    if levels == 1:  # one subtree per tile
        assert len(files) == len(recs)
    imp = ts["root"]["implicitTiling"]
    assert imp["availableLevels"] == max(r.level for r in recs) + 1
    assert set(tileset_files(ts, files.__getitem__)) == set(files) | set(content_uris(explicit))


def test_single_lod_content_only_at_leaves() -> None:
    recs = tree()
    ts, files = build_implicit(recs, single_lod=True, subtree_levels=3)
    root = read_subtree(files["subtrees/0/0/0.subtree"])
    tiles, content = root.json["tileAvailability"], root.json["contentAvailability"][0]
    assert content["availableCount"] < tiles["availableCount"]
    assert "content" not in expand(ts, files.__getitem__)["root"]
    assert content_uris(ts, files.__getitem__) == sorted(r.content_uri for r in recs if r.is_leaf)
    # REPLACE: content wherever a tile is, the same bitstream
    _, files = build_implicit(recs, subtree_levels=3)
    root = read_subtree(files["subtrees/0/0/0.subtree"])
    assert root.json["contentAvailability"][0] == root.json["tileAvailability"]


def test_subtree_binary_layout() -> None:
    """Root and its child (1, 1, 0): bits 0 and 1 + morton(1, 0) = 2 set; child subtree (2, 3, 1) at morton 7."""
    data = write_subtree(
        (0, 0, 0),
        2,
        np.array([[0, 0, 0], [1, 1, 0]]),
        np.array([True, False]),
        np.array([[2, 3, 1]]),
        [("geometric_error", np.array([9.0, 1.5]))],
    )
    magic, version, jlen, blen = struct.unpack_from("<4sIQQ", data)
    assert (magic, version) == (b"subt", 1) and jlen % 8 == 0 and blen % 8 == 0 and len(data) == 24 + jlen + blen
    sub = read_subtree(data)
    js = sub.json
    assert sub.view(js["tileAvailability"]["bitstream"]) == bytes([0b101])
    assert js["tileAvailability"]["availableCount"] == 2
    assert js["contentAvailability"][0] == {"bitstream": js["contentAvailability"][0]["bitstream"], "availableCount": 1}
    assert sub.view(js["contentAvailability"][0]["bitstream"]) == bytes([0b1])
    assert sub.view(js["childSubtreeAvailability"]["bitstream"]) == bytes([0b10000000, 0])
    assert all(v["byteOffset"] % 8 == 0 for v in js["bufferViews"])
    table = js["propertyTables"][js["tileMetadata"]]
    assert table["count"] == 2
    assert np.frombuffer(sub.view(table["properties"]["geometric_error"]["values"]), "<f8").tolist() == [9.0, 1.5]
    # all set: constant, no bitstream
    full = read_subtree(write_subtree((0, 0, 0), 1, np.array([[0, 0, 0]]), np.array([True]), np.zeros((0, 3), int), []))
    assert full.json["tileAvailability"] == {"constant": 1, "availableCount": 1}
    assert full.json["childSubtreeAvailability"] == {"constant": 0, "availableCount": 0}
    with pytest.raises(ValueError, match="outside"):
        write_subtree((1, 0, 0), 2, np.array([[2, 2, 0]]), np.array([True]), np.zeros((0, 3), int), [])


def test_subtree_levels_one_file_or_a_small_root_subtree() -> None:
    small = np.array([[r.level, r.x, r.y] for r in tree(depth=4)])
    assert choose_subtree_levels(small, 56) == 5  # a city that fits: one subtree file of all its levels
    # a deep tree (13 levels, 1024 leaves): one file would hold 2.8 MB of tile availability; the first subtree a client
    # fetches stays within the budget, and the files are far fewer than the tiles
    leaves = np.array([[12, x, y] for x in range(0, 4096, 128) for y in range(0, 4096, 128)])
    deep = np.unique(
        np.concatenate([np.c_[np.full(len(leaves), lv), leaves[:, 1:] >> (12 - lv)] for lv in range(13)]), axis=0
    )
    assert choose_subtree_levels(deep, 56, single_budget=4 << 20) == 13  # one file: 2.8 MB of bitstream alone
    s = choose_subtree_levels(deep, 56)  # over the 2 MB for one file
    assert s < 13
    ts, files = build_implicit(
        [
            TileRecord(
                int(lv),
                int(x),
                int(y),
                lv == 12,
                (0.1, 0.1, 0.2, 0.2, 0.0, 1.0),
                0.0 if lv == 12 else 1.0,
                f"content/{lv}/{x}/{y}.glb",
            )
            for lv, x, y in deep.tolist()
        ],
        subtree_levels=s,
    )
    assert len(files["subtrees/0/0/0.subtree"]) <= 65_536 and 1 < len(files) < len(deep) / 4


def test_implicit_tileset_passes_the_checks(tmp_path) -> None:
    recs = tree()
    ts, files = build_implicit(recs, subtree_levels=2)
    p = written(tmp_path, ts, files, [r.content_uri for r in recs])
    assert check_tileset(p) == []
    ts1, files1 = build_implicit(recs, single_lod=True, subtree_levels=3)
    assert check_tileset(written(tmp_path, ts1, files1, [r.content_uri for r in recs])) == []


def sparse(files: dict[str, bytes]) -> str:
    """A subtree whose tiles are not all available."""
    return next(u for u, d in sorted(files.items()) if "bitstream" in read_subtree(d).json["tileAvailability"])


def corrupt(data: bytes, fn) -> bytes:
    sub = read_subtree(data)
    js = json.loads(json.dumps(sub.json))
    fn(js)
    text = json.dumps(js).encode()
    text += b" " * ((-len(text)) % 8)
    return struct.pack("<4sIQQ", b"subt", 1, len(text), len(sub.binary)) + text + sub.binary


@pytest.mark.parametrize(
    ("breaks", "needle"),
    [
        (lambda f, t: f.pop("subtrees/2/1/1.subtree"), "No such file"),
        (lambda f, t: f.update({"subtrees/0/0/0.subtree": b"subX" + f["subtrees/0/0/0.subtree"][4:]}), "magic"),
        (lambda f, t: f.update({"subtrees/0/0/0.subtree": f["subtrees/0/0/0.subtree"][:-8]}), "header says"),
        (
            lambda f, t: f.update(
                {
                    "subtrees/0/0/0.subtree": corrupt(
                        f["subtrees/0/0/0.subtree"], lambda js: js["tileAvailability"].update(availableCount=99)
                    )
                }
            ),
            "availableCount",
        ),
        (
            lambda f, t: f.update(
                {
                    "subtrees/0/0/0.subtree": corrupt(
                        f["subtrees/0/0/0.subtree"], lambda js: js["propertyTables"][0].update(count=1)
                    )
                }
            ),
            "count",
        ),
        (
            lambda f, t: f.update(
                {
                    "subtrees/0/0/0.subtree": corrupt(
                        f["subtrees/0/0/0.subtree"], lambda js: js["propertyTables"][0].update({"class": "nope"})
                    )
                }
            ),
            "schema",
        ),
        (
            lambda f, t: f.update(
                {sparse(f): corrupt(f[sparse(f)], lambda js: js["contentAvailability"].__setitem__(0, {"constant": 1}))}
            ),
            "content available on a tile that is not",
        ),
        (lambda f, t: t["root"]["implicitTiling"].update(subdivisionScheme="HEXTREE"), "subdivisionScheme"),
        (lambda f, t: t["root"]["implicitTiling"].update(subtreeLevels=0), "subtreeLevels"),
        (lambda f, t: t["root"]["content"].update(uri="content/tile.glb"), "template"),
        (lambda f, t: t["root"]["implicitTiling"].update(availableLevels=2), "availableLevels"),
    ],
)
def test_checks_catch_broken_implicit_tilesets(tmp_path, breaks, needle) -> None:
    recs = tree()
    ts, files = build_implicit(recs, subtree_levels=2)
    assert "subtrees/2/1/1.subtree" in files
    breaks(files, ts)
    problems = check_tileset(written(tmp_path, ts, files, [r.content_uri for r in recs]))
    assert any(needle in p for p in problems), problems


def test_checks_read_the_metadata_volumes_and_errors(tmp_path) -> None:
    recs = tree()
    i = next(i for i, r in enumerate(recs) if r.level == 3)
    r = recs[i]
    recs[i] = TileRecord(r.level, r.x, r.y, r.is_leaf, (*r.region[:5], 9999.0), 9999.0, r.content_uri)
    ts, files = build_implicit(recs, subtree_levels=2)
    problems = check_tileset(written(tmp_path, ts, files, [r.content_uri for r in recs]))
    assert any("not inside its parent" in p for p in problems) and any("exceeds its parent" in p for p in problems)


def test_traversal_of_implicit_equals_explicit() -> None:
    recs = tree()
    ts, files = build(recs, tiling="implicit")
    explicit, none = build(recs, tiling="explicit")
    assert none == {} and "implicitTiling" not in explicit["root"]
    for cam in (
        Camera(25.0, 60.15, 40_000, 0, -90),
        Camera(24.95, 60.13, 2_000, 30, -45),
        Camera(25.05, 60.18, 300, 200, -20),
    ):
        want = [(d.uri, round(d.sse, 6)) for d in select(explicit, cam)]
        assert want
        assert [(d.uri, round(d.sse, 6)) for d in select(ts, cam, read=files.__getitem__)] == want
    with pytest.raises(ValueError, match="read"):
        select(ts, cam)
    with pytest.raises(ValueError, match="read"):
        content_uris(ts)


def test_content_must_follow_the_template() -> None:
    recs = tree()
    recs[3] = TileRecord(
        recs[3].level,
        recs[3].x,
        recs[3].y,
        recs[3].is_leaf,
        recs[3].region,
        recs[3].geometric_error,
        "content/elsewhere.glb",
    )
    with pytest.raises(ValueError, match="does not follow"):
        build_implicit(recs)


def test_db_server_addresses_subtrees() -> None:
    assert tile_address("subtrees/3/5/2.subtree") == "subtrees/3/5/2.subtree"
    assert tile_address("subtrees/3/8/2.subtree") is None  # x beyond the level
    with pytest.raises(BadPath):
        tile_address("subtrees/03/5/2.subtree")


def test_the_root_volume_is_the_grid_and_its_error_bounds_every_level() -> None:
    # a deep tile that measured more than root / 2^level: the implicit root error must cover it
    recs = [
        r if (r.level, r.is_leaf) != (2, False) else TileRecord(**{**r.__dict__, "geometric_error": 180.0})
        for r in tree()
    ]
    assert implicit_root_error(recs) == 720.0 and max(r.geometric_error for r in recs if r.level == 0) == 400.0
    grid = (D(24.9), D(60.1), D(25.1), D(60.2))
    ts, files = build_implicit(recs, root_volume=grid)
    assert ts["root"]["boundingVolume"]["region"][:4] == list(grid)
    assert ts["root"]["geometricError"] == 720.0 and ts["geometricError"] >= 720.0
    assert error_shortfalls(np.array([r.level for r in recs]), np.array([r.geometric_error for r in recs]), 720.0) == 0
    assert error_shortfalls(np.array([r.level for r in recs]), np.array([r.geometric_error for r in recs]), 400.0) > 0
    # a client reading the metadata sees every tile's own region and error, as the explicit tree lists them
    exact = {tuple(t["implicit"]): t for t in walk(expand(json.loads(json.dumps(ts)), files.__getitem__)["root"])}
    for r in recs:
        assert exact[(r.level, r.x, r.y)]["boundingVolume"]["region"] == list(r.region)
        assert exact[(r.level, r.x, r.y)]["geometricError"] == r.geometric_error
    # one that ignores it halves the grid and the root error
    blind = {tuple(t["implicit"]): t for t in walk(expand(ts, files.__getitem__, metadata=False)["root"])}
    root6 = [*grid, *ts["root"]["boundingVolume"]["region"][4:]]
    for (lv, x, y), t in blind.items():
        assert t["boundingVolume"]["region"] == uniform_region(root6, (lv, x, y))
        assert t["geometricError"] == 720.0 / 2**lv
    assert uniform_region(root6, (2, 1, 3))[:4] == pytest.approx([D(24.95), D(60.175), D(25.0), D(60.2)], abs=1e-15)


def test_overhangs_allow_half_an_extent_and_no_more() -> None:
    root = (D(24.9), D(60.1), D(25.1), D(60.2))
    me, mn = metres_per_radian(D(60.15))
    assert metres_per_radian(0.0)[0] == pytest.approx(A) and metres_per_radian(0.0)[1] == pytest.approx(A * (1 - E2))
    assert me == pytest.approx(A * math.cos(D(60.15)), rel=3e-3) and mn == pytest.approx(6.3e6, rel=0.02)
    keys = np.array([[1, 0, 0], [1, 0, 0], [1, 0, 0], [1, 1, 1]])
    ext = np.array(
        [
            [24.95, 60.12, 24.96, 60.13],  # inside cell (1, 0, 0): west half, south half
            [24.995, 60.12, 25.003, 60.121],  # straddles its east edge by 0.003° of its 0.008°
            [25.01, 60.12, 25.02, 60.121],  # in the next cell east: displaced by its whole width
            [25.0, 60.15, 25.1, 60.2],  # the north-east cell exactly
        ]
    )
    over, beyond = overhangs(root, keys, ext)
    me = metres_per_radian(np.radians((ext[:, 1] + ext[:, 3]) / 2))[0]
    assert over[0] == 0 and over[3] < 1e-6 and beyond[3] < 1e-6
    assert over[1] == pytest.approx(D(0.003) * me[1], rel=1e-9) and beyond[1] == 0
    assert over[2] == pytest.approx(D(0.02) * me[2], rel=1e-9)
    assert beyond[2] == pytest.approx(D(0.015) * me[2], rel=1e-9)
