"""What makes a stage stale, without a database: the stage graph, the code and settings each stage is defined by
(read from the sources under a root, so an edit in a copy of the tree shows which stages it touches), and the
comparison of recorded inputs (etl/staleness.py)."""

from __future__ import annotations

import shutil
from pathlib import Path

import pytest

from core.pipeline import GRAPH, ancestors
from etl.staleness import StageCode, differences, python_closure, stage_code
from tests.conftest import REPO


def test_the_graph_is_in_pipeline_order_and_ancestors_are_transitive() -> None:
    order = list(GRAPH)
    assert order == ["ingest", "lod", "landmarks", "tiles", "generalize", "textures", "export"]
    for stage, reads in GRAPH.items():
        assert all(order.index(r) < order.index(stage) for r in reads), stage
    assert ancestors(GRAPH["tiles"]) == ["ingest", "lod"]
    assert ancestors(GRAPH["generalize"]) == ["ingest", "lod", "landmarks", "tiles"]
    assert ancestors(GRAPH["export"]) == order[:-1]


def test_each_stage_is_its_module_closure_its_sql_and_its_settings() -> None:
    lod, export, tiles = stage_code("lod"), stage_code("export"), stage_code("tiles")
    assert {"etl/lod/stage.py", "etl/lod/roofs.py", "core/wkb.py", "etl/__init__.py"} <= lod.python.keys()
    assert {"exporter/export.py", "exporter/gltf.py"} <= export.python.keys()
    for code in map(stage_code, GRAPH):
        # the command line and the bookkeeping are not a stage's code; the settings' values are compared instead
        assert (
            not {"etl/__main__.py", "etl/runs.py", "etl/staleness.py", "core/settings.py", "exporter/serve/app.py"}
            & code.python.keys()
        )
        assert "pg_port" not in code.settings
    assert "sql/lod/outline_remainder.sql" in lod.sql
    # named in Python (api.buildings_for_tile) and through its SQL (tiles.lod2_features; the landmarks stage reaches
    # lm.exaggeration_role through lm.fill_exaggeration)
    assert {"sql/api/buildings_for_tile.sql", "sql/tiles/lod2_features.sql"} <= set(export.sql)
    assert {"sql/lm/fill_exaggeration.sql", "sql/lm/exaggeration_role.sql"} <= set(stage_code("landmarks").sql)
    assert "sql/tiles/build_quadtree.sql" in tiles.sql and "sql/tiles/finish_hierarchy.sql" not in tiles.sql
    assert {"level_height_m", "outline_part_coverage"} <= set(lod.settings) and "tex_quality" not in lod.settings
    assert "tex_quality" in stage_code("textures").settings and "lm_w_height" in stage_code("landmarks").settings
    assert set(tiles.settings) >= {"tile_max_features", "base_height_m"} and "lm_w_height" not in tiles.settings


def test_lazy_imports_are_followed(tmp_path: Path) -> None:
    for pkg in ("core", "etl", "exporter"):
        (tmp_path / pkg).mkdir()
        (tmp_path / pkg / "__init__.py").write_text("")
    (tmp_path / "etl" / "a.py").write_text("def f():\n    from .b import g\n    return g\n")
    (tmp_path / "etl" / "b.py").write_text("from core import c\n")
    (tmp_path / "core" / "c.py").write_text("")
    (tmp_path / "exporter" / "d.py").write_text("")
    got = {str(p.relative_to(tmp_path)) for p in python_closure("etl.a", tmp_path)}
    assert got == {"etl/__init__.py", "etl/a.py", "etl/b.py", "core/__init__.py", "core/c.py"}


def _tree(tmp_path: Path, name: str) -> Path:
    root = tmp_path / name
    for d in ("core", "etl", "exporter", "sql"):
        shutil.copytree(REPO / d, root / d, ignore=shutil.ignore_patterns("__pycache__"))
    return root


def _touched(before: dict[str, StageCode], root: Path) -> list[str]:
    return [s for s in GRAPH if stage_code(s, root) != before[s]]


@pytest.mark.parametrize(
    ("edit", "stages"),
    [
        ("etl/textures/stage.py", ["textures"]),
        ("core/wkb.py", ["lod", "generalize", "textures", "export"]),
        ("etl/geom/facade.py", ["lod", "generalize", "textures"]),
        ("exporter/gltf.py", ["export"]),
        ("exporter/serve/app.py", []),
        ("etl/__main__.py", []),
    ],
)
def test_a_python_edit_touches_exactly_the_stages_that_import_it(tmp_path: Path, edit: str, stages: list[str]) -> None:
    root = _tree(tmp_path, "tree")
    before = {s: stage_code(s, root) for s in GRAPH}
    (root / edit).write_text((root / edit).read_text() + "\n# an edit\n")
    stage_code.cache_clear()
    assert _touched(before, root) == stages


def test_a_new_sql_reference_and_a_new_setting_are_seen(tmp_path: Path) -> None:
    root = _tree(tmp_path, "tree")
    tiles = stage_code("tiles", root)
    f = root / "etl" / "tiles" / "stage.py"
    f.write_text(f.read_text() + "\n# uses tiles.finish_hierarchy and settings.gen_max_area_change now\n")
    stage_code.cache_clear()
    now = stage_code("tiles", root)
    assert "sql/tiles/finish_hierarchy.sql" in set(now.sql) - set(tiles.sql)
    assert set(now.settings) - set(tiles.settings) == {"gen_max_area_change"}


def test_differences_name_what_changed() -> None:
    rec = {
        "upstream": {"ingest": 1, "lod": 2},
        "settings": {"level_height_m": 3.0},
        "code": {"a.py": "x"},
        "file": {"path": "/a.osm", "sha256": "s1"},
    }
    assert differences(rec, {**rec, "settings": {"level_height_m": 3}}) == []  # jsonb gives 3 for 3.0
    assert differences(rec, {**rec, "upstream": {"ingest": 5, "lod": None}}) == [
        "upstream runs ingest 1 -> 5",
        "lod has no successful run",
    ]
    assert differences(rec, {**rec, "settings": {"level_height_m": 3.5}}) == ["settings level_height_m 3.0 -> 3.5"]
    assert differences(rec, {**rec, "code": {"a.py": "y", "b.sql": "z"}}) == ["code changed: a.py, b.sql"]
    assert differences(rec, {**rec, "file": {"path": "/a.osm", "sha256": "s2"}}) == ["file sha256 s1 -> s2"]
