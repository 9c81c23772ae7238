"""Functions a person can read: none of the product's is over 100 lines (ruff's C901/PLR0912/PLR0915 bound
their complexity, mypy their types; this bounds what those rules do not: length), and no `# type: ignore`
comes back (the code had 70 before mypy ran in make lint; narrowing took them all out)."""

from __future__ import annotations

import ast
import re
from pathlib import Path

REPO = Path(__file__).resolve().parents[2]
PRODUCT = ("core", "etl", "exporter")
MAX_LINES = 100
MAX_IGNORES = 0


def long_functions(root: Path) -> list[str]:
    """'path:line name (n lines)' for every function of the product's Python over MAX_LINES lines."""
    found = []
    for pkg in PRODUCT:
        for path in sorted((root / pkg).rglob("*.py")):
            for node in ast.walk(ast.parse(path.read_text(), str(path))):
                if isinstance(node, ast.FunctionDef | ast.AsyncFunctionDef):
                    n = (node.end_lineno or node.lineno) - node.lineno + 1
                    if n > MAX_LINES:
                        found.append(f"{path.relative_to(root)}:{node.lineno} {node.name} ({n} lines)")
    return found


def type_ignores(root: Path) -> int:
    pattern = re.compile(r"#\s*type:\s*ignore")
    return sum(len(pattern.findall(p.read_text())) for pkg in PRODUCT for p in (root / pkg).rglob("*.py"))


def test_no_function_of_the_product_is_over_100_lines() -> None:
    assert long_functions(REPO) == []


def test_no_type_ignore_comes_back() -> None:
    assert type_ignores(REPO) <= MAX_IGNORES


def test_the_measures_see_a_long_function_and_an_ignore(tmp_path: Path) -> None:
    (tmp_path / "etl").mkdir()
    body = "".join(f"    x{i} = {i}  # type: ignore\n" for i in range(MAX_LINES))
    (tmp_path / "etl" / "long.py").write_text(f"def short():\n    pass\n\n\ndef long():\n{body}")
    assert long_functions(tmp_path) == [f"{Path('etl', 'long.py')}:5 long ({MAX_LINES + 1} lines)"]
    assert type_ignores(tmp_path) == MAX_LINES
