"""The import graph points one way: core <- stages (etl) <- exporter/server <- CLI <- benchmarks.

Every import of the project's own modules is read from the source (function-level imports included, since a
lazy import is still a dependency) and checked against the layers, and the module graph must have no cycle.
"""

from __future__ import annotations

import ast
from pathlib import Path

REPO = Path(__file__).resolve().parents[2]
PACKAGES = ("core", "etl", "exporter", "benchmarks")
CLI = {"etl.__main__", "exporter.__main__"}


def layer(module: str) -> int:
    """0 core (settings, db, cluster, geodesy, camera, semantics, wkb, progress), 1 stages and their pure code,
    2 exporter and server, 3 the command lines, 4 benchmarks and reports."""
    if module in CLI:
        return 3
    return {"core": 0, "etl": 1, "exporter": 2, "benchmarks": 4}[module.split(".")[0]]


def modules() -> dict[str, Path]:
    out = {}
    for pkg in PACKAGES:
        for path in sorted((REPO / pkg).rglob("*.py")):
            parts = list(path.relative_to(REPO).with_suffix("").parts)
            if parts[-1] == "__init__":
                parts.pop()
            out[".".join(parts)] = path
    return out


def imports(name: str, path: Path, known: set[str]) -> set[str]:
    """The project modules ``name`` imports (``from pkg import mod`` counts as pkg.mod when that is a module)."""
    is_pkg = path.name == "__init__.py"
    out: set[str] = set()
    for node in ast.walk(ast.parse(path.read_text(), str(path))):
        if isinstance(node, ast.Import):
            targets = [a.name for a in node.names]
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                base = name.split(".") if is_pkg else name.split(".")[:-1]
                base = base[: len(base) - (node.level - 1)]
                mod = ".".join(base + ([node.module] if node.module else []))
            else:
                mod = node.module or ""
            targets = [f"{mod}.{a.name}" if f"{mod}.{a.name}" in known else mod for a in node.names]
        else:
            continue
        for t in targets:
            while t and t not in known:
                t = t.rpartition(".")[0]
            if t and t != name:
                out.add(t)
    return out


def graph() -> dict[str, set[str]]:
    mods = modules()
    known = set(mods)
    return {m: imports(m, p, known) for m, p in mods.items()}


def test_imports_point_down_the_layers() -> None:
    g = graph()
    assert {"core.settings", "core.db", "core.geodesy", "core.camera", "core.semantics"} <= set(g)
    upward = sorted(f"{a} -> {b}" for a, deps in g.items() for b in deps if layer(b) > layer(a))
    assert not upward, "imports against the layers:\n" + "\n".join(upward)


def test_no_import_cycles() -> None:
    g = graph()
    state: dict[str, int] = {}
    cycles: list[list[str]] = []

    def visit(m: str, stack: list[str]) -> None:
        state[m] = 1
        for d in sorted(g[m]):
            if state.get(d) == 1:
                cycles.append(stack[stack.index(d):] + [d])
            elif d not in state:
                visit(d, stack + [d])
        state[m] = 2

    for m in sorted(g):
        if m not in state:
            visit(m, [m])
    assert not cycles, "import cycles:\n" + "\n".join(" -> ".join(c) for c in cycles)


def test_the_checker_sees_a_cycle_and_an_upward_import(tmp_path) -> None:
    # the two rules above on a made-up module pair, so a broken parser cannot pass them vacuously
    a = tmp_path / "a.py"
    a.write_text("from exporter import serve\nimport core.db\n")
    assert imports("etl.a", a, {"etl.a", "exporter", "exporter.serve", "core.db"}) == {"exporter.serve", "core.db"}
    assert layer("exporter.serve") > layer("etl.a")
    rel = tmp_path / "b.py"
    rel.write_text("def f():\n    from ..geom import atlas\n    from .. import workers\n")
    assert imports("etl.stages.b", rel, {"etl.geom.atlas", "etl.workers", "etl.geom", "etl"}) == {
        "etl.geom.atlas", "etl.workers"}
