"""make report-textures on a textured city (test_textures' Helsinki fixture, built for this module): the files are
written, utilization is tex.page's texel-weighted value, the draw calls per tile are the exported glbs'
primitives, atlases never need more draw calls than one texture per building, both packers place every real
chart, and bench.py's Textures section renders from the same figures."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from benchmarks import bench
from benchmarks import report_textures as rt
from exporter.gltf import read_glb
from tests.db.test_textures import textured  # noqa: F401 -- the module fixture: Helsinki through textures, exported


@pytest.mark.db
def test_report_textures_on_helsinki(textured, conn_of, tmp_path) -> None:  # noqa: F811
    url, out, counts = textured
    assert rt.main(["--db", url, "--out", str(tmp_path), "--packer-tiles", "3", "--max-encode", "300"]) == 0
    for name in ("textures.md", "textures.json", "textures.png"):
        assert (tmp_path / name).stat().st_size > 0, name
    report = json.loads((tmp_path / "textures.json").read_text())
    conn = conn_of(url)

    # utilization: texel-weighted over tex.page, as the stage recorded it
    n_pages, n_bytes, weighted = conn.execute(
        "SELECT count(*), sum(n_bytes), sum(utilization * width * height) / sum(width * height) FROM tex.page"
    ).fetchone()
    t = report["totals"]
    assert 0 < t["utilization"] <= 1
    assert t["utilization"] == pytest.approx(weighted, abs=1e-4) == pytest.approx(counts["utilization"], abs=1e-4)
    assert (
        t["pages"] == n_pages == sum(b["pages"] for b in report["bands"]) == sum(lv["pages"] for lv in report["levels"])
    )
    assert t["bytes"] == n_bytes == sum(b["bytes"] for b in report["bands"])
    for b in report["bands"]:
        if b["pages"]:
            assert 0 < b["min_page_utilization"] <= b["mean_page_utilization"] <= 1
            assert 0 < b["utilization"] <= 1

    # draw calls per tile: the primitives of the exported glb (one per atlas page used + the vertex-coloured one)
    tiles = {(x["level"], x["x"], x["y"]): x for x in report["tiles"]}
    glbs = sorted(out.rglob("*.glb"))
    assert len(glbs) == len(tiles)
    for glb in glbs:
        key = tuple(int(p) for p in glb.relative_to(out / "content").with_suffix("").parts)
        gltf, _ = read_glb(glb.read_bytes())
        # one material per atlas page plus the vertex-coloured one (a wide compact tile repeats them per chunk)
        assert len(gltf["materials"]) == tiles[key]["draw_calls"], key
        assert tiles[key]["draw_calls"] <= tiles[key]["per_building_draw_calls"] + 1

    # atlases against one texture per building, at both cameras
    for name in ("near", "overview"):
        v = report["views"][name]
        a, pb = v["atlas"], v["per_building"]
        assert v["tiles"] > 0 and v["textured_features"] > 0 and v["unassigned_triangles"] == 0, name
        assert 0 < a["draw_calls"] <= pb["draw_calls"], name
        assert pb["draw_calls"] >= v["textured_features"]
        assert a["bytes"] > 0 and pb["bytes"] > 0
        # at least --max-encode encoded (more when the near view's tiles encoded some of the overview's already)
        assert pb["encoded"] + pb["estimated"] == v["textured_features"]
        assert min(300, v["textured_features"]) <= pb["encoded"]
        assert v["draw_call_ratio"] == pytest.approx(pb["draw_calls"] / a["draw_calls"], rel=1e-2)
    assert report["views"]["overview"]["draw_call_ratio"] > 1

    # shelf and xatlas on the real chart sizes: every chart placed once, unshrunk, apart
    pk = report["packers"]
    assert pk["tiles"] == 3 and pk["totals"]["shelf"]["ok"] and pk["totals"]["xatlas"]["ok"]
    for row in pk["rows"]:
        n = conn.execute(
            "SELECT sum(n_charts) FROM tex.page WHERE (level, x, y) = (%s, %s, %s)", (row["level"], row["x"], row["y"])
        ).fetchone()[0]
        assert row["charts"] == n
        for p in ("shelf", "xatlas"):
            assert row[p]["placed_ok"] and 0 < row[p]["utilization"] <= 1 and row[p]["pages"] >= 1
    # the stage packs with shelf: its chart sizes packed again give its own pages back
    assert pk["stage_packer"] == "shelf" and pk["stage_reproduced"]
    assert all(r["shelf"]["pages"] == r["stored"]["pages"] for r in pk["rows"])
    assert np.isfinite(pk["totals"]["xatlas"]["seconds"])

    md = (tmp_path / "textures.md").read_text()
    assert "one texture per building" in md.lower() and "Shelf packer against xatlas" in md

    # bench.py's Textures section from the same figures
    res = bench.ExtractResult(path=Path(f"{bench.HEADLINE}.osm.pbf"), textures=report)
    lines = bench._textures_section([res], res)
    assert "## Textures" in lines and "### Atlases per band" in lines
    assert any(line.startswith(f"| {bench.HEADLINE} |") for line in lines)
