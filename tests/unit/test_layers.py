"""The import graph points one way: core <- stages (etl) <- exporter/server <- CLI <- benchmarks.

Every import of the project's own modules is read from the source (function-level imports included, since a
lazy import is still a dependency; the reader is etl/dag.py's, which decides what code a stage runs) and checked
against the layers, and the module graph must have no cycle.
"""

from __future__ import annotations

from pathlib import Path

from etl.dag import module_imports, project_modules

REPO = Path(__file__).resolve().parents[2]
PACKAGES = ("core", "etl", "exporter", "benchmarks")
CLI = {"etl.__main__", "exporter.__main__"}


def layer(module: str) -> int:
    """0 core (settings, db, cluster, geodesy, camera, semantics, wkb, progress), 1 stages and their pure code,
    2 exporter and server, 3 the command lines, 4 benchmarks and reports."""
    if module in CLI:
        return 3
    return {"core": 0, "etl": 1, "exporter": 2, "benchmarks": 4}[module.split(".")[0]]


def graph() -> dict[str, set[str]]:
    """Module -> the project modules it imports (etl/dag.py's reader, which also decides what code a stage
    runs)."""
    mods = project_modules(REPO, PACKAGES)
    known = set(mods)
    return {m: module_imports(m, p, known) - {m} for m, p in mods.items()}


def test_imports_point_down_the_layers() -> None:
    g = graph()
    assert {"core.settings", "core.db", "core.geodesy", "core.camera", "core.semantics"} <= set(g)
    upward = sorted(f"{a} -> {b}" for a, deps in g.items() for b in deps if layer(b) > layer(a))
    assert not upward, "imports against the layers:\n" + "\n".join(upward)


def cycles(g: dict[str, set[str]]) -> list[list[str]]:
    """Every cycle a depth-first walk of ``g`` closes, as the path round it."""
    state: dict[str, int] = {}
    found: list[list[str]] = []

    def visit(m: str, stack: list[str]) -> None:
        state[m] = 1
        for d in sorted(g[m]):
            if state.get(d) == 1:
                found.append(stack[stack.index(d):] + [d])
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
    a.write_text("from exporter import serve\nimport core.db\n")
    known = {"etl.a", "exporter", "exporter.serve", "core.db"}
    assert module_imports("etl.a", a, known) == {"exporter.serve", "core.db"}
    assert layer("exporter.serve") > layer("etl.a")
    rel = tmp_path / "b.py"
    rel.write_text("def f():\n    from ..geom import check\n    from .. import fetch\n")
    assert module_imports("etl.textures.b", rel, {"etl.geom.check", "etl.fetch", "etl.geom", "etl"}) == {
        "etl.geom.check", "etl.fetch"}
    # the loop benchmarks/ had: bench -> report_textures -> view_bench -> bench
    loop = {"b.bench": {"b.report"}, "b.report": {"b.view", "b.bench"}, "b.view": {"b.bench"}, "core": set()}
    assert cycles(loop) == [["b.bench", "b.report", "b.bench"], ["b.bench", "b.report", "b.view", "b.bench"]]
