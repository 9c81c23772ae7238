"""The import graph points one way: core <- exporter <- etl (the stages, the update, the command line on top)
<- benchmarks, and every stage's package stands alone.

Every import of the project's own modules is read from the source (function-level imports included, since a
lazy import is still a dependency; the reader is etl/staleness.py's, which decides what code a stage runs) and
checked against the layers, and the module graph must have no cycle.
"""

from __future__ import annotations

from pathlib import Path

from core.pipeline import STAGES
from etl.staleness import module_imports, project_modules

REPO = Path(__file__).resolve().parents[2]
PACKAGES = ("core", "etl", "exporter", "benchmarks", "tests/support")
CLI = {"etl.__main__"}
#: the packages of the stages under etl/ (etl.ingest, ...), each its stage's Python
STAGE_PACKAGES = {".".join(s.module.split(".")[:2]) for s in STAGES if s.module.startswith("etl.")}


def layer(module: str) -> int:
    """0 core (what every layer shares: settings, db, the stage graph and contract, the worker pool, change
    tracking), 1 exporter (export, writers, publish, server), 2 etl (the stages and the update), 3 the command
    line and the helpers tests share, 4 benchmarks and reports."""
    if module in CLI or module.startswith("tests."):
        return 3
    return {"core": 0, "exporter": 1, "etl": 2, "benchmarks": 4}[module.split(".")[0]]


def graph() -> dict[str, set[str]]:
    """Module -> the project modules it imports (etl/staleness.py's reader, which also decides what code a stage
    runs)."""
    mods = project_modules(REPO, PACKAGES)
    known = set(mods)
    return {m: module_imports(m, p, known) - {m} for m, p in mods.items()}


def test_imports_point_down_the_layers() -> None:
    g = graph()
    assert {
        "core.settings",
        "core.db",
        "core.pipeline",
        "core.workers",
        "core.changes",
        "exporter.export",
        "etl.update.run",
        "tests.support.servers",
    } <= set(g)
    upward = sorted(f"{a} -> {b}" for a, deps in g.items() for b in deps if layer(b) > layer(a))
    assert not upward, "imports against the layers:\n" + "\n".join(upward)
    # core imports no other package of ours, the exporter nothing of etl
    assert not [(a, b) for a, deps in g.items() for b in deps if a.startswith("core") and not b.startswith("core")]
    assert not [(a, b) for a, deps in g.items() for b in deps if a.startswith("exporter") and b.startswith("etl")]


def stage_package(module: str) -> str | None:
    return next((p for p in STAGE_PACKAGES if module == p or module.startswith(p + ".")), None)


def test_a_stage_imports_no_other_stage() -> None:
    # what two stages share lives in etl/geom or core; only the update (and the command line) drive the stages
    g = graph()
    assert len(STAGE_PACKAGES) == 6
    across = sorted(
        f"{a} -> {b}"
        for a, deps in g.items()
        for b in deps
        if stage_package(a) and stage_package(b) and stage_package(a) != stage_package(b)
    )
    assert not across, "stages importing each other:\n" + "\n".join(across)


def cycles(g: dict[str, set[str]]) -> list[list[str]]:
    """Every cycle a depth-first walk of ``g`` closes, as the path round it."""
    state: dict[str, int] = {}
    found: list[list[str]] = []

    def visit(m: str, stack: list[str]) -> None:
        state[m] = 1
        for d in sorted(g[m]):
            if state.get(d) == 1:
                found.append(stack[stack.index(d) :] + [d])
            elif d not in state:
                visit(d, stack + [d])
        state[m] = 2

    for m in sorted(g):
        if m not in state:
            visit(m, [m])
    return found


def test_no_import_cycles() -> None:
    found = cycles(graph())
    assert not found, "import cycles:\n" + "\n".join(" -> ".join(c) for c in found)


def test_the_checker_sees_a_cycle_and_an_upward_import(tmp_path) -> None:
    # the two rules above on a made-up module pair, so a broken parser cannot pass them vacuously
    a = tmp_path / "a.py"
    a.write_text("from etl import runner\nimport core.db\n")
    known = {"exporter.a", "etl", "etl.runner", "core.db"}
    assert module_imports("exporter.a", a, known) == {"etl.runner", "core.db"}
    assert layer("etl.runner") > layer("exporter.a") > layer("core.db")
    assert stage_package("etl.lod.roofs") == "etl.lod" and stage_package("etl.geom.check") is None
    rel = tmp_path / "b.py"
    rel.write_text("def f():\n    from ..geom import check\n    from .. import fetch\n")
    assert module_imports("etl.textures.b", rel, {"etl.geom.check", "etl.fetch", "etl.geom", "etl"}) == {
        "etl.geom.check",
        "etl.fetch",
    }
    # the loop benchmarks/ had: bench -> report_textures -> view_bench -> bench
    loop = {"b.bench": {"b.report"}, "b.report": {"b.view", "b.bench"}, "b.view": {"b.bench"}, "core": set()}
    assert cycles(loop) == [["b.bench", "b.report", "b.bench"], ["b.bench", "b.report", "b.view", "b.bench"]]


def test_no_product_test_imports_benchmarks() -> None:
    # tests of the benchmark code itself are test_bench_*.py; the product's tests share tests/support instead
    tests = {
        ".".join(p.relative_to(REPO).with_suffix("").parts): p
        for p in sorted((REPO / "tests").rglob("*.py"))
        if not p.name.startswith("test_bench_")
    }
    bench = set(project_modules(REPO, ("benchmarks",)))
    assert len(tests) > 50 and "benchmarks.update_bench" in bench
    importing = sorted(f"{m} -> {b}" for m, p in tests.items() for b in module_imports(m, p, bench))
    assert not importing, "product tests importing benchmarks/:\n" + "\n".join(importing)
