"""The pure parts of benchmarks/fidelity_bench.py (make bench's Far view fidelity section): IoU and drawn-area ratio
of building masks, the binary check, the side-by-side picture, the cameras derived from the data's extent, the
per-level figures, the targets and the section's rendering with a missed target and a failed camera. No database,
no browser."""

import math
from pathlib import Path

import numpy as np
import pytest

from benchmarks import fidelity_bench as fb
from core.camera import Camera


def rgb(mask: np.ndarray) -> np.ndarray:
    return np.repeat(mask[..., None], 3, axis=2).astype(np.uint8) * 255


def test_iou_and_area_ratio_of_synthetic_masks() -> None:
    full = np.zeros((10, 20), bool)
    full[2:8, 2:12] = True  # 60 px
    streamed = np.zeros_like(full)
    streamed[2:8, 2:7] = True  # half of it: 30 px
    assert fb.iou(full, full) == 1.0
    assert fb.iou(streamed, full) == pytest.approx(0.5)
    assert fb.area_ratio(streamed, full) == pytest.approx(0.5)
    # drawn where the city is not: the area ratio alone would not see it, the IoU does
    shifted = np.zeros_like(full)
    shifted[2:8, 10:20] = True  # 60 px, 12 of them (2 columns × 6 rows) on the city
    assert fb.area_ratio(shifted, full) == pytest.approx(1.0)
    assert fb.iou(shifted, full) == pytest.approx(12 / 108)
    empty = np.zeros_like(full)
    assert fb.iou(empty, full) == 0.0 and fb.iou(full, empty) == 0.0
    assert fb.area_ratio(empty, full) == 0.0
    assert fb.area_ratio(full, empty) is None
    assert fb.iou(empty, empty) == 1.0  # nothing to draw, nothing missed
    with pytest.raises(ValueError, match="sizes"):
        fb.iou(full, full[:5])


def test_masks_from_pictures_and_the_binary_check() -> None:
    m = np.zeros((6, 8), bool)
    m[1:4, 2:6] = True
    pic = rgb(m)
    assert (fb.mask_of(pic) == m).all()
    rgba = np.concatenate([pic, np.full((6, 8, 1), 255, np.uint8)], axis=2)  # opaque alpha is not a building
    assert (fb.mask_of(rgba) == m).all()
    assert fb.grey_share(pic) == 0.0
    lit = pic.copy()
    lit[1, 2] = (200, 200, 200)  # a lit or anti-aliased pixel
    lit[5, 7] = (0, 0, 3)
    assert fb.grey_share(lit) == pytest.approx(2 / 48)
    c = fb.compare_masks(pic, lit)
    assert c["iou"] == 1.0 and c["grey"] == {"streamed": 0.0, "full": pytest.approx(2 / 48)}
    with pytest.raises(ValueError, match="RGB"):
        fb.mask_of(m)


def test_compare_masks_counts_missed_and_extra_pixels() -> None:
    full = np.zeros((4, 4), bool)
    full[:2] = True  # 8 px
    streamed = np.zeros_like(full)
    streamed[1:3] = True  # 4 on the city, 4 beside it
    c = fb.compare_masks(rgb(streamed), rgb(full))
    assert c == {
        "iou": pytest.approx(4 / 12, abs=1e-4),
        "area_ratio": 1.0,
        "pixels": 16,
        "streamed_px": 8,
        "full_px": 8,
        "missed_px": 4,
        "extra_px": 4,
        "grey": {"streamed": 0.0, "full": 0.0},
    }


def test_side_by_side_colours_the_difference() -> None:
    full = np.zeros((3, 4), bool)
    full[0] = True
    full[1, 0] = True
    streamed = np.zeros_like(full)
    streamed[0] = True
    streamed[2, 3] = True
    pic = fb.side_by_side(rgb(streamed), rgb(full), gap=2)
    assert pic.shape == (3, 3 * 4 + 2 * 2, 3) and pic.dtype == np.uint8
    diff = pic[:, 4 + 2 + 4 + 2 :]
    assert (diff[0] == 255).all()
    assert tuple(diff[1, 0]) == fb.MISSED
    assert tuple(diff[2, 3]) == fb.EXTRA
    assert (diff[1, 1:] == 0).all()
    assert (pic[:, :4] == rgb(streamed)).all() and (pic[:, 6:10] == rgb(full)).all()


def _distance_to_target(cam: Camera, target: tuple[float, float], ground: float) -> tuple[float, float]:
    """Horizontal offset (m, north positive) of the target from the camera and where the view's centre line meets
    the ground (m north of the camera), on a flat earth (enough at these distances for the test's purpose)."""
    north = math.radians(target[1] - cam.lat) * fb.EARTH_R
    along = (cam.height - ground) / math.tan(math.radians(-cam.pitch)) if cam.pitch > -89.999 else 0.0
    return north, along


def test_camera_set_scales_with_the_extent_far_to_near() -> None:
    over = Camera(9.55, 47.15, 21_000.0, 0.0, -90.0, 60.0, 1080, 16 / 9)
    target, ground = (9.52, 47.10), 450.0
    cams = fb.camera_set(over, target, ground)
    names = [n for n, _ in cams]
    assert names == [n for n, _, _ in fb.CAMERAS] and len(set(names)) == len(names)
    assert cams[0][1] is over
    heights = [c.height - ground for _, c in cams]
    assert heights == sorted(heights, reverse=True)  # far to near
    assert heights[0] == over.height - ground
    for (_name, share, pitch), (_, c) in zip(fb.CAMERAS, cams, strict=True):
        assert c.height - ground == pytest.approx(share * (over.height - ground))
        assert c.pitch == pitch and c.heading == 0.0
        assert (c.fov, c.viewport_height, c.aspect) == (over.fov, over.viewport_height, over.aspect)
        if c is over:
            continue
        north, along = _distance_to_target(c, target, ground)
        assert c.lon == target[0]
        # straight down over the target, or oblique with the target in the middle of the view
        assert north == pytest.approx(along, rel=1e-6, abs=1e-6)
    pitches = {p for _, _, p in fb.CAMERAS}
    assert -90.0 in pitches and any(-45.0 <= p <= -30.0 for p in pitches)
    # the cameras: 7.7 km overview, 1.8 km the nearest
    assert fb.CAMERAS[-1][1] == pytest.approx(1.8 / 7.7)
    # twice the extent, twice every height
    big = fb.camera_set(Camera(9.55, 47.15, ground + 2 * (over.height - ground), 0.0, -90.0), target, ground)
    assert [c.height - ground for _, c in big] == pytest.approx([2 * h for h in heights])


def test_level_rows_cut_the_tree_at_each_level() -> None:
    # root (level 0) -> two children at level 1: one leaf, one inner -> two leaves at level 2
    tile_level = np.array([0, 1, 1, 2, 2])
    tile_leaf = np.array([False, True, False, True, True])
    # one row per feature: (tile level, leaf, members, vertices, triangles)
    feats = np.array(
        [
            (0, 0, 30, 40, 20),  # a block at the root
            (1, 1, 1, 100, 150),
            (1, 1, 1, 100, 150),  # the leaf at level 1
            (1, 0, 20, 30, 12),  # a block in the inner child
            (2, 1, 1, 200, 300),
            (2, 1, 1, 200, 300),
            (2, 1, 1, 200, 300),
        ]
    )
    rows = fb.level_rows(feats[:, 0], feats[:, 1], feats[:, 2], feats[:, 3], feats[:, 4], tile_level, tile_leaf)
    assert [r["level"] for r in rows] == [0, 1, 2]
    assert [r["tiles"] for r in rows] == [1, 2, 3]
    assert [r["features"] for r in rows] == [1, 3, 5]
    assert [r["members"] for r in rows] == [30, 22, 5]
    assert [r["vertices"] for r in rows] == [40, 230, 800]
    assert [r["triangles"] for r in rows] == [20, 312, 1200]
    assert rows[-1]["vertex_reduction_pct"] == 0.0 and rows[-1]["triangle_reduction_pct"] == 0.0
    assert rows[0]["vertex_reduction_pct"] == pytest.approx(95.0)
    assert rows[1]["triangle_reduction_pct"] == pytest.approx(74.0)
    assert fb.level_rows(*[np.zeros(0)] * 7) == []


def view(iou: float | None, streamed_tri: int, full_tri: int, error: str | None = None) -> dict:
    v: dict = {
        "passes": {
            "streamed": {"trianglesSelected": streamed_tri, "tilesDrawn": 4, "leavesDrawn": 0},
            "full": {"trianglesSelected": full_tri, "tilesDrawn": 40, "leavesDrawn": 40},
        }
    }
    if iou is not None:
        v["masks"] = {"iou": iou, "area_ratio": iou}
    if error:
        v = {"name": "x", "error": error}
    return v


def result(views: dict) -> dict:
    cams = [{"name": n, "height": 1000.0 * (i + 1), "pitch": -90.0} for i, n in enumerate(views)]
    return {
        "views": views,
        "cameras": cams,
        "levels": [
            {
                "level": 0,
                "tiles": 1,
                "features": 10,
                "members": 300,
                "vertices": 100,
                "triangles": 50,
                "vertex_reduction_pct": 99.0,
                "triangle_reduction_pct": 99.5,
            },
            {
                "level": 1,
                "tiles": 4,
                "features": 300,
                "members": 300,
                "vertices": 10_000,
                "triangles": 10_000,
                "vertex_reduction_pct": 0.0,
                "triangle_reduction_pct": 0.0,
            },
        ],
    }


def test_judge_the_targets() -> None:
    ok = fb.judge(
        result(
            {
                "overview": view(0.95, 100, 10_000),
                "down-mid": view(0.85, 900, 1000),
                "oblique-low": view(None, 1, 1),
                "broken": view(None, 0, 0, error="boom"),
            }
        )
    )
    assert ok["overview"] == {"iou": True, "triangles": True}
    assert ok["down-mid"] == {"iou": False}
    assert ok["oblique-low"] == {"iou": None} and ok["broken"] == {"iou": None}
    # the overview drawing more than 1/20 of the full-detail triangles misses its target
    assert fb.judge(result({"overview": view(0.95, 600, 10_000)}))["overview"]["triangles"] is False
    assert fb.judge(result({"overview": view(0.90, 500, 10_000)}))["overview"] == {"iou": True, "triangles": True}


def test_section_shows_targets_failures_and_levels() -> None:
    res = result(
        {
            "overview": view(0.58, 1000, 10_000),
            "down-mid": view(0.95, 900, 1000),
            "oblique-low": view(None, 0, 0, error="tiles still loading after 600000 ms"),
        }
    )
    res["bound"] = {**fb.budget_bound(np.arange(1.0, 11.0), 1000), "iou_boxes": 0.61}
    broken = {**fb.failed("the driver | exited 1"), "bound_error": "no tiles"}
    text = "\n".join(fb.section_lines([("city", res), ("other", broken), ("none", {})]))
    assert "## Far view fidelity" in text and "### Vertices and polygons per level" in text
    lines = text.splitlines()
    over = next(line for line in lines if line.startswith("| city | overview |"))
    assert "0.580" in over and "**FAIL**" in over  # IoU below 0.90
    assert "1,000 / 10,000" in over and "1/10.0" in over  # and more than 1/20 of the triangles
    assert over.count("**FAIL**") == 2
    mid = next(line for line in lines if line.startswith("| city | down-mid |"))
    assert "0.950" in mid and "**pass**" in mid and "**FAIL**" not in mid
    low = next(line for line in lines if line.startswith("| city | oblique-low |"))
    assert "failed: tiles still loading after 600000 ms" in low
    assert next(line for line in lines if line.startswith("| other |")).count("failed: the driver / exited 1") == 1
    assert not any(line.startswith("| none |") for line in lines)
    assert "Targets missed: city overview." in text
    assert "| city | 0 | 1 | 10 (300) | 100 | 99.0 % | 50 | 99.5 % |" in text
    assert "### What 1/20 of the triangles can draw" in text
    assert "| city | 10 | 100 | 50 (5 outlines) | 0.727 | 0.610 |" in text
    assert "| other | failed: no tiles |" in text
    assert fb.section_lines([]) == [] and fb.section_lines([("x", {})]) == []
    # every row has as many cells as the header
    for block in (t for t in text.split("\n\n") if t.startswith("|")):
        widths = {line.count("|") for line in block.splitlines()}
        assert len(widths) == 1, block


def test_compare_views_reads_the_masks_and_writes_side_by_side(tmp_path: Path) -> None:
    from etl.textures.atlas import encode_image

    full = np.zeros((6, 8), bool)
    full[1:5, 1:7] = True
    streamed = np.zeros_like(full)
    streamed[1:5, 1:4] = True
    paths = {}
    for name, m in (("streamed", streamed), ("full", full)):
        paths[name] = tmp_path / f"c-{name}.png"
        paths[name].write_bytes(encode_image(rgb(m), "png")[0])
    views = {
        "c": {"passes": {p: {"mask": str(paths[p]), "trianglesSelected": 1} for p in fb.PASSES}},
        "lost": {"passes": {"streamed": {"mask": str(tmp_path / "nothing.png")}, "full": {}}},
        "failed": {"name": "failed", "error": "tiles still loading"},
    }
    fb.compare_views(views, tmp_path)
    assert views["c"]["masks"]["iou"] == pytest.approx(0.5) and views["c"]["masks"]["area_ratio"] == 0.5
    side = tmp_path / "c.png"
    assert views["c"]["side_by_side"] == str(side) and side.stat().st_size > 0
    assert "error" in views["lost"]["masks"]
    assert "masks" not in views["failed"]


def test_bench_report_has_the_fidelity_section() -> None:
    from benchmarks import bench

    res = bench.ExtractResult(path=Path(f"{bench.HEADLINE}.osm.pbf"))
    for st in bench.STAGES:
        res.stages[st].append(bench.Sample(1.0, 10.0, {"in": 5, "buildings": 5, "features": 5}))
    res.o2p.append(bench.Sample(0.5, 10.0))
    res.fidelity = result({"overview": view(0.95, 100, 10_000)})
    text = bench.render([res], {"cores": "2"}, 1, "python -m benchmarks.bench")
    assert "\n## Far view fidelity\n" in text and text.index("## Far view fidelity") < text.index("## How to read")
    assert f"| {bench.HEADLINE} | overview | 1,000 m, -90° | 0.950 | **pass** |" in text
    res.fidelity = fb.failed("chromium not found")
    assert "failed: chromium not found" in bench.render([res], {"cores": "2"}, 1, "x")


def test_budget_bound_keeps_the_largest_outlines_that_fit() -> None:
    # 10 outlines, 1,000 full-detail triangles: 1/20 is 50 triangles, 5 outlines of 10 triangles. The largest five
    # (10 + 9 + 8 + 7 + 6 = 40 of 55 m²) bound the IoU.
    b = fb.budget_bound(np.arange(1.0, 11.0), 1000)
    assert b["budget_triangles"] == 50 and b["outlines_in_budget"] == 5 and b["outlines"] == 10
    assert b["min_triangles_all"] == 100
    assert b["iou_bound"] == pytest.approx(40 / 55, abs=1e-4)
    # a budget for every outline bounds nothing; an empty city has no bound
    assert fb.budget_bound(np.arange(1.0, 11.0), 10_000)["iou_bound"] == 1.0
    assert fb.budget_bound(np.zeros(0), 1000)["iou_bound"] is None
