"""The pure helpers of benchmarks/report_generalization.py (make report-generalization): counts, the outline
Hausdorff distance, the Markdown and the plot. No database."""

import json

import numpy as np
import pytest
import shapely
import trimesh

from benchmarks import report_generalization as rg

OFF = np.array([385_000.0, 6_672_000.0])  # UTM-sized coordinates


def square(x0: float, y0: float, size: float) -> shapely.MultiPolygon:
    return shapely.MultiPolygon([shapely.box(OFF[0] + x0, OFF[1] + y0, OFF[0] + x0 + size, OFF[1] + y0 + size)])


def test_reduction_pct():
    assert rg.reduction_pct(200, 50) == 75.0
    assert rg.reduction_pct(10, 10) == 0.0
    assert rg.reduction_pct(0, 0) == 0.0


def test_distinct_vertices_welds_per_owner():
    box = trimesh.creation.box(bounds=[[0, 0, 0], [10, 10, 5]]).triangles + np.array([*OFF, 0.0])
    tri = np.concatenate([box, box, box[:2] + 1e-4])  # owner 2: two triangles, 4 corners, nudged below the weld
    own = np.repeat([0, 1, 2], [12, 12, 2])
    assert rg.distinct_vertices(tri, own, 4).tolist() == [8, 8, 4, 0]
    # the same corner in two owners counts in both; corners 1 cm apart are two
    assert rg.distinct_vertices(np.concatenate([box, box + 0.01]), np.repeat([0, 0], [12, 12]), 1).tolist() == [16]
    assert rg.distinct_vertices(np.zeros((0, 3, 3)), np.zeros(0, np.int64), 2).tolist() == [0, 0]


def test_outline_walls_one_wall_per_edge_hole_included():
    g = shapely.MultiPolygon(
        [shapely.Polygon(shapely.box(0, 0, 10, 10).exterior, [shapely.box(4, 4, 6, 6).exterior.coords])]
    )
    tri, own = rg.outline_walls(np.array([g, square(0, 0, 1)], dtype=object))
    assert len(tri) == 2 * (4 + 4 + 4)
    assert np.bincount(own).tolist() == [16, 8]
    assert np.allclose(np.unique(tri[:, :, 2]), [0.0, 1.0])


@pytest.mark.parametrize("seed", [1, 2, 3])
def test_outline_hausdorff_matches_dense_sampling(seed):
    rng = np.random.default_rng(seed)
    a, b = [], []
    for k in range(20):
        pts = rng.uniform(0, 30, (12, 2)) + OFF + 100 * k
        hull = shapely.convex_hull(shapely.multipoints(pts))
        a.append(shapely.MultiPolygon([hull]))
        b.append(shapely.MultiPolygon([shapely.simplify(hull, rng.uniform(0.5, 4.0))]))
    a, b = np.array(a, dtype=object), np.array(b, dtype=object)
    got = rg.outline_hausdorff(a, b, spacing=0.02)
    ref = shapely.hausdorff_distance(shapely.segmentize(shapely.boundary(a), 0.01), shapely.boundary(b))
    ref = np.maximum(
        ref, shapely.hausdorff_distance(shapely.boundary(a), shapely.segmentize(shapely.boundary(b), 0.01))
    )
    # the reference samples one side only each way, so it is itself within 5 mm below the truth
    assert np.all(got >= ref - 0.02 - 1e-9)
    assert np.all(got <= ref + 0.005 + 1e-9)


def test_outline_hausdorff_known_cases():
    # a 10 m square against one with a 2 x 3 m notch cut into a wall: the notch bottom is 3 m from the wall
    cut = shapely.box(OFF[0] + 4, OFF[1] - 1, OFF[0] + 6, OFF[1] + 3)
    notched = shapely.MultiPolygon([shapely.difference(square(0, 0, 10).geoms[0], cut)])
    h = rg.outline_hausdorff(
        np.array([square(0, 0, 10), square(0, 0, 10)], dtype=object),
        np.array([notched, square(0, 0, 10)], dtype=object),
    )
    assert h[0] == pytest.approx(3.0, abs=rg.SPACING_FOOTPRINT_M)
    assert h[1] == 0.0


def test_markdown_table():
    assert rg.markdown_table(["a", "b"], [[1, "x"]], "lr") == ["| a | b |", "|---|---:|", "| 1 | x |"]
    with pytest.raises(ValueError):
        rg.markdown_table(["a", "b"], [[1]], "lr")
    with pytest.raises(ValueError):
        rg.markdown_table(["a", "b"], [], "l")


def _report() -> dict:
    rows = []
    for kind, unit, thresholds in (
        (rg.KIND_SIMPLIFIED, "m", rg.TOLERANCES_M),
        (rg.KIND_AGGREGATED, "m", rg.TOLERANCES_M),
        (rg.KIND_DECIMATED, "target", rg.REDUCTIONS),
    ):
        for i, t in enumerate(thresholds):
            r = rg.Row(kind, t, unit)
            r.add(
                features_in=100,
                features_out=100 - 10 * i if kind == rg.KIND_AGGREGATED else 100,
                vertices_before=1000,
                vertices_after=900 - 100 * i,
                polygons_before=100,
                polygons_after=100 - 10 * i,
                errors=np.array([0.5 * t, t]),
                status=["kept: not closed after decimation"] if kind == rg.KIND_DECIMATED else ["simplified"],
            )
            rows.append(r.as_dict())
    ex = {
        "key": "munich",
        "name": "munich_altstadt",
        "path": "x",
        "outlines": 100,
        "meshes": 100,
        "seconds": {"build": 1.0, "footprints": 2.0, "meshes": 3.0},
        "rows": rows,
    }
    return {
        "command": "python -m benchmarks.report_generalization --extracts munich",
        "machine": {"CPU": "test"},
        "parameters": {
            "tolerances_m": list(rg.TOLERANCES_M),
            "reductions": list(rg.REDUCTIONS),
            "min_triangles": 8,
            "batch": 2000,
            "spacing_footprint_m": 0.05,
            "spacing_mesh_m": 0.1,
            "weld_m": 0.001,
            "pin": True,
            "max_area_change": 0.1,
        },
        "extracts": [ex, {**ex, "key": "london", "name": "london_city"}],
        "seconds": 6.0,
    }


def test_row_statistics():
    r = rg.Row(rg.KIND_SIMPLIFIED, 1.0, "m")
    r.add(
        features_in=3,
        features_out=3,
        vertices_before=30,
        vertices_after=20,
        polygons_before=3,
        polygons_after=3,
        errors=np.array([0.5, 1.0]),
        status=["simplified", "simplified", "unchanged"],
    )
    r.add(
        features_in=1,
        features_out=1,
        vertices_before=10,
        vertices_after=10,
        polygons_before=1,
        polygons_after=1,
        errors=np.array([]),
        status=["unchanged"],
    )
    d = r.as_dict()
    assert d["changed"] == 2 and d["mean_error_m"] == 0.75 and d["max_error_m"] == 1.0
    assert d["vertex_reduction_pct"] == 25.0 and d["polygon_reduction_pct"] == 0.0
    assert d["status"] == {"simplified": 2, "unchanged": 2}
    json.dumps(d)


def test_render_markdown():
    md = rg.render_markdown(_report())
    assert md.count("## munich_altstadt") == 1 and md.count("## london_city") == 1
    assert "| footprints aggregated | 2.5 m | 2 / 90 | 1,000 | 800 | 20.0 % | 100 | 90 | 10.0 % | 2.50 | 1.875 |" in md
    assert "| LOD2 decimated | 75% of triangles |" in md
    assert "1 kept: not closed after decimation" in md
    assert "python -m benchmarks.report_generalization --extracts munich" in md
    assert md.endswith("\n")


def test_plot_writes_a_png(tmp_path):
    path = tmp_path / "g.png"
    rg.plot(_report(), path)
    assert path.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def test_the_report_carries_the_far_view_fidelity_pictures(tmp_path):
    src, out = tmp_path / "fidelity", tmp_path / "reports"
    (src / "city").mkdir(parents=True)
    pic = src / "city" / "overview.png"
    pic.write_bytes(b"\x89PNG\r\n\x1a\n")
    (src / "city" / "fidelity.json").write_text(
        json.dumps(
            {
                "name": "city",
                "cameras": [{"name": "overview", "height": 7700.0, "pitch": -90.0}],
                "views": {
                    "overview": {
                        "masks": {"iou": 0.58, "area_ratio": 0.55},
                        "side_by_side": str(pic),
                        "passes": {"streamed": {"trianglesSelected": 1000}, "full": {"trianglesSelected": 90000}},
                    },
                    "oblique-low": {"error": "tiles still loading after 600000 ms"},
                },
            }
        )
    )
    (src / "broken").mkdir()
    (src / "broken" / "fidelity.json").write_text("{not json")
    fid = rg.collect_fidelity(src, out)
    assert [f["name"] for f in fid] == ["city"]
    assert (out / "fidelity" / "city" / "overview.png").read_bytes() == pic.read_bytes()
    md = rg.render_markdown({**_report(), "fidelity": fid})
    assert "## Far view fidelity" in md and "### city" in md
    assert "| overview | 7,700 m, -90° | 0.580 | 0.550 | 1,000 / 90,000 |" in md
    assert "| oblique-low | – | failed: tiles still loading after 600000 ms | – | – |" in md
    assert "![city overview](fidelity/city/overview.png)" in md
    assert "## Far view fidelity" not in rg.render_markdown(_report())
    assert rg.collect_fidelity(tmp_path / "none", out) == []
