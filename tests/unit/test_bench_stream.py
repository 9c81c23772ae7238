"""The pure parts of benchmarks/stream_bench.py (make bench's Stream section): the glb byte split, the root tile
of an explicit or implicit tileset, the pixel comparison, the camera handed to CesiumJS, the targets and the
section's rendering when the two streams differ or a part failed. No database, no browser."""

import json
import math
import struct
from pathlib import Path

import numpy as np
import pytest

from benchmarks import stream_bench as sb
from core.camera import Camera
from exporter.gltf import read_glb
from tests.unit.test_export_gltf import cube_primitive, textured_glb


def glb(doc: dict, bin_: bytes) -> bytes:
    js = json.dumps(doc).encode()
    js += b" " * (-len(js) % 4)
    bin_ += b"\0" * (-len(bin_) % 4)
    body = struct.pack("<II", len(js), sb.CHUNK_JSON) + js + struct.pack("<II", len(bin_), sb.CHUNK_BIN) + bin_
    return b"glTF" + struct.pack("<II", 2, 12 + len(body)) + body


def test_glb_split_of_a_written_glb() -> None:
    data = textured_glb()
    doc, _ = read_glb(data)
    s = sb.glb_split(data)
    image = doc["bufferViews"][doc["images"][0]["bufferView"]]["byteLength"]
    json_len = struct.unpack_from("<I", data, 12)[0]
    assert s["texture"] == image > 0
    assert s["json"] == json_len
    assert s["geometry"] == len(data) - json_len - image
    assert s["bytes"] == len(data) == s["json"] + s["texture"] + s["geometry"]
    table = doc["extensions"]["EXT_structural_metadata"]["propertyTables"][0]["properties"]
    views = {v for p in table.values() for k, v in p.items() if k in ("values", "arrayOffsets", "stringOffsets")}
    assert s["metadata"] == sum(doc["bufferViews"][v]["byteLength"] for v in views) > 0
    # without a texture every binary byte is geometry
    from exporter.gltf import write_glb

    plain = write_glb(cube_primitive())
    p = sb.glb_split(plain)
    assert p["texture"] == 0 and p["geometry"] == len(plain) - p["json"]


def test_glb_split_counts_stored_bytes_of_meshopt_and_external_views() -> None:
    doc = {
        "asset": {"version": "2.0"},
        # buffer 0: the glb's BIN; 1: the meshopt fallback (no data); 2: an external file
        "buffers": [
            {"byteLength": 48},
            {"byteLength": 400, "extensions": {"EXT_meshopt_compression": {"fallback": True}}},
            {"byteLength": 10, "uri": "x.bin"},
        ],
        "bufferViews": [
            {
                "buffer": 1,
                "byteLength": 400,
                "extensions": {
                    "EXT_meshopt_compression": {
                        "buffer": 0,
                        "byteOffset": 0,
                        "byteLength": 24,
                        "byteStride": 4,
                        "mode": "ATTRIBUTES",
                        "count": 100,
                    }
                },
            },
            {"buffer": 0, "byteOffset": 24, "byteLength": 16},  # a KTX2 page
            {"buffer": 2, "byteLength": 10},  # an external image: not in the glb
            {"buffer": 0, "byteOffset": 40, "byteLength": 8},  # a property table column
        ],
        "images": [{"bufferView": 1, "mimeType": "image/ktx2"}, {"bufferView": 2, "mimeType": "image/png"}],
        "extensions": {
            "EXT_structural_metadata": {
                "propertyTables": [
                    {
                        "class": "b",
                        "count": 2,
                        "properties": {"h": {"values": 3}, "n": {"values": 0, "stringOffsets": 3}},
                    }
                ]
            }
        },
    }
    data = glb(doc, bytes(48))
    s = sb.glb_split(data)
    assert s["texture"] == 16
    assert s["metadata"] == 8 + 24  # views 3 and 0 once each, view 0 at its compressed size
    assert s["json"] + s["texture"] + s["geometry"] == len(data)


@pytest.mark.parametrize(
    "data, needle",
    [
        (b"glTF" + struct.pack("<II", 2, 99) + bytes(8), "header length"),
        (b"GLTF" + bytes(30), "magic"),
        (b"glTF" + struct.pack("<II", 2, 28) + struct.pack("<II", 100, sb.CHUNK_JSON) + bytes(8), "past the end"),
    ],
)
def test_glb_split_refuses_broken_files(data: bytes, needle: str) -> None:
    with pytest.raises(ValueError, match=needle):
        sb.glb_split(data)


def test_root_content_uri_explicit_implicit_and_none() -> None:
    assert (
        sb.root_content_uri({"root": {"content": {"uri": "content/0/0/0.glb"}, "children": []}}) == "content/0/0/0.glb"
    )
    assert sb.root_content_uri({"root": {"contents": [{"uri": "a.glb"}, {"uri": "b.glb"}]}}) == "a.glb"
    implicit = {
        "root": {
            "content": {"uri": "content/{level}/{x}/{y}.glb"},
            "implicitTiling": {
                "subdivisionScheme": "QUADTREE",
                "subtreeLevels": 4,
                "availableLevels": 6,
                "subtrees": {"uri": "subtrees/{level}/{x}/{y}.subtree"},
            },
        }
    }
    assert sb.root_content_uri(implicit) == "content/0/0/0.glb"
    assert sb.root_content_uri({"root": {"children": []}}) is None


def test_measure_dir_splits_files_and_finds_the_root(tmp_path: Path) -> None:
    data = textured_glb()
    (tmp_path / "content" / "0" / "0").mkdir(parents=True)
    (tmp_path / "content" / "0" / "0" / "0.glb").write_bytes(data)
    (tmp_path / "subtrees").mkdir()
    (tmp_path / "subtrees" / "0.0.0.subtree").write_bytes(bytes(100))
    ts = {
        "asset": {"version": "1.1"},
        "root": {"content": {"uri": "content/{level}/{x}/{y}.glb"}, "implicitTiling": {}},
    }
    (tmp_path / "tileset.json").write_text(json.dumps(ts))
    m = sb.measure_dir(tmp_path)
    s = m["split"]
    js = len((tmp_path / "tileset.json").read_bytes())
    assert m["bytes"] == s["bytes"] == len(data) + 100 + js
    assert (s["subtree"], s["tileset_json"], s["glb_files"]) == (100, js, 1)
    assert s["texture"] == sb.glb_split(data)["texture"] > 0
    assert (m["root_uri"], m["root_bytes"]) == ("content/0/0/0.glb", len(data))
    # served gzipped: every file is counted, the zero-filled subtree shrinks to a few bytes
    assert 0 < s["gzip"] < s["bytes"] - 60


def test_mean_abs_diff() -> None:
    a = np.zeros((4, 5, 4), np.uint8)
    b = a.copy()
    assert sb.mean_abs_diff(a, b) == {"mad": 0.0, "differing": 0.0, "pixels": 20}
    b[0, 0, :3] = (30, 0, 0)  # one pixel, one channel: 30 / (20 × 3)
    b[1, 1, 3] = 255  # alpha is not compared
    b[2, 2, :3] = 5  # under the threshold: counted in the mean, not as differing
    r = sb.mean_abs_diff(a, b)
    assert r["mad"] == pytest.approx((30 + 15) / 60, abs=1e-3)
    assert r["differing"] == pytest.approx(1 / 20)
    assert sb.mean_abs_diff(b, a) == r  # symmetric, no uint8 wrap-around
    with pytest.raises(ValueError, match="different sizes"):
        sb.mean_abs_diff(a, np.zeros((4, 6, 4), np.uint8))


def test_cesium_camera_horizontal_fov() -> None:
    c = sb.cesium_camera(Camera(9.5, 47.1, 500.0, 10.0, -15.0), "street")
    assert (c["width"], c["height_px"]) == (1920, 1080)
    # CesiumJS takes fov as the horizontal angle of a wide view: the same vertical 60° on a 16:9 viewport
    assert math.degrees(2 * math.atan(math.tan(math.radians(c["fovDeg"]) / 2) * 9 / 16)) == pytest.approx(60.0)
    assert (c["lon"], c["lat"], c["height"], c["heading"], c["pitch"]) == (9.5, 47.1, 500.0, 10.0, -15.0)
    tall = sb.cesium_camera(Camera(0, 0, 1, 0, -90, fov=50, viewport_height=800, aspect=0.5), "t")
    assert (tall["fovDeg"], tall["width"]) == (50, 400)


def _variant(bpb: float, lod1: float, root: int, seconds: float, tex: float | None) -> dict:
    views = {
        "street": {
            "name": "street",
            "loaded": True,
            "texturesByteLength": tex,
            "geometryByteLength": 5e6,
            "batchTableByteLength": 1e5,
            "tilesWithContent": 9,
            "trianglesSelected": 1000,
        },
        "overview": {"name": "overview", "error": "tiles still loading after 9 ms"},
    }
    split = {
        "bytes": 100,
        "json": 5,
        "texture": 20,
        "geometry": 75,
        "metadata": 3,
        "tileset_json": 9,
        "subtree": 0,
        "glb_files": 2,
    }
    return {
        "all": {
            "bytes_per_building": bpb,
            "root_bytes": root,
            "seconds": seconds,
            "buildings": 100,
            "runs": 1,
            "split": split,
        },
        "lod1": {"bytes_per_building": lod1},
        "client": {"views": views, "gpu": {"astc": True, "s3tc": True, "etc": False, "renderer": "x"}},
    }


def test_judge_and_section_when_the_streams_differ() -> None:
    res = {
        "compact": _variant(2600, 300, 400_000, 12.0, 40e6),
        "plain": _variant(13_399, 1_764, 3_600_000, 10.0, 422e6),
        "pixels": {
            "street": {
                "mad": 1.25,
                "differing": 0.01,
                "compact": "/b/x/screenshots/compact/street.png",
                "plain": "/b/x/screenshots/plain/street.png",
            },
            "overview": {"error": "a view failed: tiles still loading"},
        },
    }
    assert sb.judge(res, headline=True) == {
        "all": True,
        "lod1": True,
        "root": True,
        "export": True,
        "texture_memory": True,
    }
    res["plain"]["all"]["bytes_per_building"] = 14_000.0
    res["compact"]["all"]["bytes_per_building"] = 2_950.0  # ≤ 0.22× plain but over 2,900 B
    assert sb.judge(res, headline=True)["all"] is False
    assert sb.judge(res, headline=False)["all"] is True
    res["compact"]["all"]["seconds"] = 13.5  # 1.35× plain
    res["compact"]["lod1"]["bytes_per_building"] = 1_700
    ok = sb.judge(res, headline=True)
    assert (ok["export"], ok["lod1"]) == (False, False)

    text = "\n".join(sb.section_lines([("liechtenstein_2022-07-24", res)]))
    assert text.startswith("\n## Stream")
    row = next(line for line in text.splitlines() if line.startswith("| liechtenstein_2022-07-24 | compact | 2,"))
    assert "0.21×" in row and "2,950" in row and "**FAIL**" in row and "1.35×" in row
    assert "failed: tiles still loading" in text and "failed: a view failed" in text
    assert "| 1.25 | 1.00 % |" in text and "ASTC yes" in text and "ETC no" in text
    assert "| compact-ext |" not in text  # not measured: no row

    # compact-ext (the EXT_meshopt_compression variant) gets its own bytes rows, judged on nothing, not run in the
    # client (it decodes to the same views as compact)
    ext = _variant(2_900, 340, 420_000, 12.5, None)
    del ext["client"]
    res["compact-ext"] = ext
    text = "\n".join(sb.section_lines([("liechtenstein_2022-07-24", res)]))
    row = next(line for line in text.splitlines() if line.startswith("| liechtenstein_2022-07-24 | compact-ext |"))
    assert "2,900" in row and "0.21×" in row and "**" not in row
    assert not any(line.startswith("| liechtenstein_2022-07-24 | compact-ext | street") for line in text.splitlines())


def test_section_records_failures_without_crashing() -> None:
    res = {
        "compact": {
            "all": {"error": "export exited 1"},
            "lod1": {"error": "export exited 1"},
            "client": {"error": "not exported"},
        },
        "plain": _variant(13_399, 1_764, 3_600_000, 10.0, 422e6),
        "pixels": {"street": {"error": "a view failed"}, "overview": {"error": "a view failed"}},
    }
    assert set(sb.judge(res, headline=True).values()) == {None}
    text = "\n".join(sb.section_lines([("x", res)]))
    assert "failed: export exited 1" in text and "failed: not exported" in text
    assert sb.section_lines([]) == []


def test_bench_report_has_the_stream_section() -> None:
    from benchmarks import bench

    res = bench.ExtractResult(path=Path(f"{bench.HEADLINE}.osm.pbf"))
    for st in bench.STAGES:
        res.stages[st].append(bench.Sample(1.0, 10.0, {"in": 5, "buildings": 5, "features": 5}))
    res.o2p.append(bench.Sample(0.5, 10.0))
    res.stream = {
        "compact": _variant(2600, 300, 400_000, 12.0, 40e6),
        "plain": _variant(13_399, 1_764, 3_600_000, 10.0, 422e6),
        "pixels": {},
    }
    text = bench.render([res], {"cores": "2"}, 1, "python -m benchmarks.bench")
    assert "\n## Stream\n" in text and text.index("## Stream") < text.index("## How to read this")
    assert f"| {bench.HEADLINE} | compact | 2,600 | 0.19× | **pass** |" in text
    res.stream = sb.failed("psql: connection refused")
    assert "failed: psql: connection refused" in bench.render([res], {"cores": "2"}, 1, "x")


def test_compare_shots_reads_pngs_and_records_failed_clients(tmp_path: Path) -> None:
    import OpenImageIO as oiio  # noqa: N813

    paths = []
    for name, value in (("a", 10), ("b", 40)):
        img = np.full((6, 8, 4), value, np.uint8)
        img[..., 3] = 255
        buf = oiio.ImageBuf(oiio.ImageSpec(8, 6, 4, oiio.UINT8))
        buf.set_pixels(oiio.ROI(), img)
        assert buf.write(str(tmp_path / f"{name}.png"))
        paths.append(str(tmp_path / f"{name}.png"))
    views = [{cam: {"name": cam, "loaded": True, "screenshot": p} for cam in sb.CAMERAS} for p in paths]
    res = {"compact": {"client": {"views": views[0]}}, "plain": {"client": {"views": views[1]}}}
    out = sb.compare_shots(res)
    assert out["street"]["mad"] == 30.0 and out["street"]["differing"] == 1.0
    res["compact"]["client"] = {"error": "driver exit 1: Chromium crashed"}
    res["plain"]["client"]["views"]["overview"] = {"name": "overview", "error": "3 tiles failed to load"}
    out = sb.compare_shots(res)
    assert "Chromium crashed" in out["street"]["error"] and "Chromium crashed" in out["overview"]["error"]
    res["compact"] = {}
    assert "not measured" in sb.compare_shots(res)["street"]["error"]


def test_scale_section_states_the_tileset_sizes() -> None:
    from benchmarks import bench

    lat = {
        "buildings": 1_000_000,
        "tiles": 8134,
        "p50_ms": 2.0,
        "p95_ms": 8.0,
        "max_ms": 20.0,
        "mean_features": 10,
        "max_features": 50,
        "pass": True,
        "cameras": 200,
        "seed": 4,
        "profile": {
            "slowest": {
                "camera": {"height": 100, "pitch": -20},
                "features": 10,
                "planning_ms": 1.0,
                "execution_ms": 2.0,
            },
            "p95": {"planning_ms": 1.0, "execution_ms": 2.0},
        },
    }
    size = {
        "tiles": 8134,
        "levels": 10,
        "implicit_tileset_json_bytes": 1340,
        "explicit_tileset_json_bytes": 1_520_918,
        "subtrees": 1,
        "subtree_bytes": 499_744,
    }
    text = "\n".join(bench._scale_section({"1m": {**lat, "tileset": size}}))
    assert "| ~1M | 8,134 | 10 | 1,340 B | 1,520,918 B | 1, 499,744 B | **pass** |" in text
    too_big = {**size, "implicit_tileset_json_bytes": 100_001}
    assert "**FAIL**" in "\n".join(bench._scale_section({"1m": {**lat, "tileset": too_big}}))
