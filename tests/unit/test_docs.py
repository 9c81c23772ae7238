"""The documents name only what exists: every path, link, make target, command, stage and database object in
README.md, ARCHITECTURE.md and the READMEs of benchmarks/, migrations/ and sql/ is checked against the tree,
the Makefile and the CLI; every test file is linked from ARCHITECTURE.md; every stage has its section."""

from __future__ import annotations

import re
import subprocess
import sys
from pathlib import Path

import pytest

from core.pipeline import GRAPH

REPO = Path(__file__).resolve().parents[2]
DOCS = [
    "README.md",
    "ARCHITECTURE.md",
    "CONTRIBUTING.md",
    "benchmarks/README.md",
    "migrations/README.md",
    "sql/README.md",
    *sorted(str(p.relative_to(REPO)) for p in (REPO / "docs" / "decisions").glob("*.md")),
]
#: Paths in backticks are checked when they start with one of these (build/, var/, data/ are made at run time).
TRACKED_ROOTS = ("core/", "etl/", "exporter/", "sql/", "migrations/", "tests/", "benchmarks/", "scripts/", ".ci/")
SCHEMAS = ("osm", "lod", "gen", "lm", "tex", "tiles", "meta", "api")
#: A name like lod.py is a file, not a database object.
FILE_SUFFIXES = {"py", "sql", "md", "js", "mjs", "html", "json", "glb", "osm", "pbf", "lua", "toml", "txt", "png"}
#: The pipeline's stages, in order; each has a make target, a `python -m etl` command and an ARCHITECTURE section.
STAGES = (*GRAPH, "serve", "update")


def make_targets(makefile: str) -> set[str]:
    """The Makefile's targets and those it includes from the stage graph (core/pipeline.py)."""
    from core.pipeline import make_rules

    return set(re.findall(r"^([A-Za-z][\w-]*)\s*:(?!=)", makefile + make_rules(), re.M))


def etl_commands() -> set[str]:
    out = subprocess.run(
        [sys.executable, "-m", "etl", "--help"], cwd=REPO, capture_output=True, text=True, check=True
    ).stdout
    m = re.search(r"\{([\w,-]+)\}", out)
    assert m, out
    return set(m.group(1).split(","))


def db_objects() -> set[str]:
    """schema.object names that exist: sql/<schema>/<object>.sql and every schema-qualified name the
    migrations and the migration runner create or mention."""
    names = {f"{p.parent.name}.{p.stem}" for p in (REPO / "sql").glob("*/*.sql")}
    text = "\n".join(p.read_text() for p in sorted((REPO / "migrations").glob("*.sql")))
    text += (REPO / "etl" / "migrate.py").read_text()
    pattern = rf"\b((?:{'|'.join(SCHEMAS)})\.[a-z_][a-z0-9_]*)"
    names |= set(re.findall(pattern, text))
    return names


#: where a backticked name of code must be found: the sources, SQL, migrations, Makefile and scripts
CODE_GLOBS = (
    "core/**/*.py",
    "etl/**/*.py",
    "exporter/**/*.py",
    "benchmarks/**/*.py",
    "tests/**/*.py",
    "sql/**/*.sql",
    "migrations/*.sql",
    "Makefile",
    "scripts/*",
    "exporter/viewer/*",
    "tests/**/*.mjs",
    "benchmarks/**/*.mjs",
    "pyproject.toml",
    "package.json",
)
#: a backticked word that names code: snake_case (a function, setting, column), CamelCase (a class), or a call
IDENTIFIER = re.compile(r"^(?:[a-z][a-z0-9]*(?:_[a-z0-9]+)+|[A-Z][a-z0-9]+(?:[A-Z][a-z0-9]+)+|[A-Za-z_]\w*\(\))$")
#: a dotted name of our Python: package.module[.name]
DOTTED = re.compile(r"^(core|etl|exporter|benchmarks|tests)(\.\w+)+$")
#: something that reads as a commit hash: 7 to 40 hex digits, letters and digits both
COMMIT = re.compile(r"(?<![\w/.-])(?=[0-9a-f]*[a-f])(?=[0-9a-f]*[0-9])[0-9a-f]{7,40}(?![\w/-])")


def code_words() -> set[str]:
    words: set[str] = set()
    for g in CODE_GLOBS:
        for f in REPO.glob(g):
            if f.is_file() and f != Path(__file__).resolve():  # this file names missing things on purpose
                words |= set(re.findall(r"\w+", f.read_text(errors="replace")))
    return words


def dotted_problem(name: str) -> str | None:
    """Why the dotted name ``name`` (core.db.connect, etl.lod.stage) names nothing (None: it names something)."""
    parts = name.split(".")
    for i in range(len(parts), 0, -1):
        base = REPO.joinpath(*parts[:i])
        src = base.with_suffix(".py") if base.with_suffix(".py").is_file() else base / "__init__.py"
        if src.is_file():
            rest = parts[i:]
            if rest and not re.search(rf"^\s*(?:def|class|async def)?\s*{re.escape(rest[0])}\b", src.read_text(), re.M):
                return f"{name}: {'.'.join(parts[:i])} defines no {rest[0]}"
            return None
    return f"{name}: no such module"


def problems(
    doc: str, text: str, *, targets: set[str], commands: set[str], objects: set[str], words: set[str] | None = None
) -> list[str]:
    """What ``text`` (the document at repo path ``doc``) names that does not exist."""
    out = path_problems(doc, text)
    code = "\n".join(re.findall(r"```.*?\n(.*?)```", text, re.S) + re.findall(r"`([^`\n]+)`", text))
    for target in re.findall(r"(?<![\w-])make ([a-z][\w-]*)", code):  # commands, not the verb in prose
        if target not in targets:
            out.append(f"{doc}: no make target: make {target}")
    for cmd in re.findall(r"python -m etl ([a-z][\w-]*)", text):
        if cmd not in commands:
            out.append(f"{doc}: no such command: python -m etl {cmd}")
    for mod in re.findall(r"python -m (benchmarks\.\w+|tests\.[\w.]+)", text):
        if not (REPO / (mod.replace(".", "/") + ".py")).exists():
            out.append(f"{doc}: no such module: python -m {mod}")
    if words is not None:
        out += identifier_problems(doc, text, words)
    pattern = rf"(?<![\w./-])((?:{'|'.join(SCHEMAS)})\.[a-z_][a-z0-9_]*)(?![\w/-]|\.py|\.sql|\.md)"
    for name in re.findall(pattern, text):
        if name.rpartition(".")[2] not in FILE_SUFFIXES and name not in objects:
            out.append(f"{doc}: no such database object: {name}")
    return out


def path_problems(doc: str, text: str) -> list[str]:
    """The links and backticked paths of ``text`` (the document at repo path ``doc``) to files that are not there."""
    out: list[str] = []
    base = (REPO / doc).parent
    for target in re.findall(r"\]\(([^)\s]+)\)", text):  # markdown links
        if re.match(r"[a-z]+:", target) or target.startswith("#"):
            continue
        path = target.split("#")[0]
        if path and not (base / path).exists():
            out.append(f"{doc}: link to a missing file: {target}")
    for token in re.findall(r"`([^`\n]+)`", text):
        for word in token.split():
            word = word.rstrip(".,;:)")
            placeholder = re.search(r"[<>*…{}$|\[]", word)
            if word.startswith(TRACKED_ROOTS) and not placeholder and not (REPO / word.split("#")[0]).exists():
                out.append(f"{doc}: missing path: {word}")
    return out


def identifier_problems(doc: str, text: str, words: set[str]) -> list[str]:
    """The backticked names of code in ``text`` that the code does not hold: a function, setting, column or class
    by its word, our dotted Python names by their module, CITYLOD_* variables by the settings or the code."""
    out = []
    for token in re.findall(r"`([^`\n]+)`", text):
        word = token.strip().rstrip(".,;:")
        if DOTTED.match(word) and not re.search(r"\.(py|sql|md|json|mjs|js|html)$", word):
            if why := dotted_problem(word):
                out.append(f"{doc}: no such Python name: {why}")
        elif IDENTIFIER.match(word) and word.removesuffix("()") not in words:
            out.append(f"{doc}: no such name in the code: {word}")
        elif (
            word.startswith("CITYLOD_")
            and re.fullmatch(r"CITYLOD_[A-Z0-9_]+", word)
            and word not in words
            and word.removeprefix("CITYLOD_").lower() not in words
        ):
            out.append(f"{doc}: no such setting or variable: {word}")
    return out


@pytest.fixture(scope="module")
def known() -> dict[str, set[str]]:
    return {
        "targets": make_targets((REPO / "Makefile").read_text()),
        "commands": etl_commands(),
        "objects": db_objects(),
        "words": code_words(),
    }


@pytest.mark.parametrize("doc", DOCS)
def test_every_name_in_the_docs_exists(doc: str, known: dict[str, set[str]]) -> None:
    found = problems(doc, (REPO / doc).read_text(), **known)
    assert not found, "\n".join(found)


@pytest.mark.parametrize("doc", ["README.md", "ARCHITECTURE.md", "CONTRIBUTING.md"])
def test_no_commit_hashes_in_the_docs_for_users_and_newcomers(doc: str) -> None:
    # a hash names a moment of the history: the design is the tree's; decisions name theirs (docs/decisions)
    found = COMMIT.findall((REPO / doc).read_text())
    assert not found, f"{doc} names commits: {found}"


def test_every_test_file_is_linked_from_architecture() -> None:
    text = (REPO / "ARCHITECTURE.md").read_text()
    missing = [
        p.relative_to(REPO).as_posix()
        for p in sorted((REPO / "tests").rglob("test_*.py"))
        if p.relative_to(REPO).as_posix() not in text
    ]
    assert not missing, "test files ARCHITECTURE.md does not name:\n" + "\n".join(missing)


def test_every_stage_is_documented(known: dict[str, set[str]]) -> None:
    arch = (REPO / "ARCHITECTURE.md").read_text()
    readme = (REPO / "README.md").read_text()
    headings = re.findall(r"^## Stage [\w.]+: (\w+)", arch, re.M)
    for stage in STAGES:
        assert stage in known["targets"] and stage in known["commands"], stage
        assert stage in headings, f"ARCHITECTURE.md has no '## Stage …: {stage}' section"
        assert f"`make {stage}" in readme, f"README.md's stage table has no make {stage}"


def test_the_checker_finds_what_is_missing(known: dict[str, set[str]]) -> None:
    # every rule on a made-up document, so a broken pattern cannot pass the real ones vacuously
    doc = (
        "See [the stage](etl/stages/nowhere.py), `sql/api/no_such.sql` and `etl/lod/stage.py`; run "
        "`make frobnicate` or `make lod`, `python -m etl nosuchstage`, `python -m benchmarks.nothing`, and "
        "query `api.no_such_function` or `api.lod_for_view`. `unmake_omissions()` is gone, `build_batch` and "
        "`core.db.connect` are not, `core.db.no_such` and `etl.nowhere` never were; `CITYLOD_LEVEL_HEIGHT_M` "
        "and `CITYLOD_DEBUG` are read, `CITYLOD_NO_SUCH` is not."
    )
    found = problems("README.md", doc, **known)
    assert found == [
        "README.md: link to a missing file: etl/stages/nowhere.py",
        "README.md: missing path: sql/api/no_such.sql",
        "README.md: no make target: make frobnicate",
        "README.md: no such command: python -m etl nosuchstage",
        "README.md: no such module: python -m benchmarks.nothing",
        "README.md: no such name in the code: unmake_omissions()",
        "README.md: no such Python name: core.db.no_such: core.db defines no no_such",
        "README.md: no such Python name: etl.nowhere: etl defines no nowhere",
        "README.md: no such setting or variable: CITYLOD_NO_SUCH",
        "README.md: no such database object: api.no_such_function",
    ]
    assert COMMIT.findall("at 6c942bd and e0f9fe7, not at a1b2c3 or deadbeef or sql/0045_x or v1.2.3") == [
        "6c942bd",
        "e0f9fe7",
    ]


def test_readme_client_snippets_use_what_the_tests_run() -> None:
    """README's client snippets import only pinned packages (but deck.gl's drawing, named as untested), and the three.js
    and loaders.gl snippets import every name from the module the tested driver (tests/e2e/three/client.js,
    tests/e2e/loadersgl_tileset.mjs) imports it from."""
    import json

    readme = (REPO / "README.md").read_text()
    section = readme[readme.index("### Clients") :]
    section = section[: section.index("\n## ")]
    pinned = set(json.loads((REPO / "package.json").read_text())["dependencies"])
    imports = re.findall(r'^import (.+?) from "([^"]+)";', section, re.M)
    assert imports, "no import in README's client snippets"
    for _names, module in imports:
        package = "/".join(module.split("/")[:2]) if module.startswith("@") else module.split("/")[0]
        assert package in pinned or package == "@deck.gl/geo-layers", module
    assert "deck.gl's drawing itself is not tested" in section and "(not run by the tests)" in section
    tested = {}
    for driver in ("three/client.js", "loadersgl_tileset.mjs"):
        text = (REPO / "tests" / "e2e" / driver).read_text()
        tested.update({m: n for n, m in re.findall(r"^import (.+?) from '([^']+)';", text, re.M)})
        # the Node driver imports loaders.gl after its offline setup: const {names} = await import('module');
        tested.update({m: n for n, m in re.findall(r"^const \{(.+?)\} = await import\('([^']+)'\);", text, re.M)})
    run = section[: section.index("(not run by the tests)")]  # the deck.gl snippet after it is not
    for names, module in re.findall(r'^import (.+?) from "([^"]+)";', run, re.M):
        if module.startswith(("three", "3d-tiles-renderer", "@loaders.gl/", "@deck.gl/")):
            assert module in tested, module
            used = set(re.findall(r"\w+", names)) - {"as"}
            assert used <= set(re.findall(r"\w+", tested[module])), (module, names, tested[module])
    for client_name in ("CesiumJS", "three.js", "3DTilesRendererJS", "loaders.gl", "deck.gl"):
        assert client_name in section, client_name
