"""make report-saliency on the Helsinki demo city (the session's city('helsinki'), read only) with a short
camera path: the files are written, the metrics are normalized, and the landmark rule only ever adds
visibility, and does add it for the landmarks in the far frames that draw blocks."""

from __future__ import annotations

import csv
import json

import numpy as np
import pytest

from benchmarks import report_saliency as rs

FRAMES = 24  # the path zooms out twice: frames 6 and 18 are at the far end, where only the root is drawn


@pytest.mark.db
def test_report_saliency_on_helsinki(city, tmp_path) -> None:
    c = city("helsinki")
    assert rs.main(["--db", c.url, "--out", str(tmp_path), "--frames", str(FRAMES)]) == 0

    for name in ("saliency.md", "saliency.json", "saliency.png", "saliency/features.csv"):
        assert (tmp_path / name).stat().st_size > 0, name
    assert sorted(p.name for p in (tmp_path / "saliency").glob("frame_*.png")) == [
        f"frame_{k:03d}.png" for k in range(FRAMES)
    ]

    report = json.loads((tmp_path / "saliency.json").read_text())
    frames, top = report["frames"], report["top"]
    assert len(frames) == FRAMES and len(top) == 10
    assert [t["rank"] for t in top] == list(range(1, 11))
    assert all(f["visible"] > 0 and f["unplaced"] == 0 for f in frames)
    # the path reaches the root band (blocks) and the leaves
    assert any(f["bands"] == [0] for f in frames) and any(4 in f["bands"] for f in frames)

    for t in top:
        assert 0.0 <= t["fraction_without"] <= t["fraction_with"] <= 1.0, t
        assert t["frames_visible_with"] == round(t["fraction_with"] * FRAMES)
        if not t["is_landmark"]:
            assert t["frames_visible_with"] == t["frames_visible_without"], t
    for f in frames:
        assert f["top_visible_without"] <= f["top_visible_with"]
    # the rule matters: a landmark drawn by itself in the root's block band would be merged there without it
    landmarks = [t for t in top if t["is_landmark"]]
    assert landmarks and any(t["frames_visible_with"] > t["frames_visible_without"] for t in landmarks)
    by_osm = {t["osm"]: t for t in top}
    assert by_osm["W123525580"]["name"] == "Hotelli Torni" and by_osm["W123525580"]["is_landmark"]

    with open(tmp_path / "saliency" / "features.csv", newline="") as fh:
        rows = list(csv.DictReader(fh))
    assert len(rows) == sum(f["visible"] for f in frames) == report["summary"]["rows"]
    for key in ("distance_n", "angle_n", "roi_n", "interest", "saliency"):
        v = np.array([float(r[key]) for r in rows])
        assert np.all((v >= 0) & (v <= 1)), key
    assert np.all(np.array([float(r["angle_deg"]) for r in rows]) <= 90.0)
    # within each frame the normalized view distance peaks at 1
    for k in range(FRAMES):
        assert max(float(r["distance_n"]) for r in rows if int(r["frame"]) == k) == pytest.approx(1.0)

    md = (tmp_path / "saliency.md").read_text()
    assert "Hotelli Torni" in md and "jump flooding" in md and "Without the landmark rule" in md
