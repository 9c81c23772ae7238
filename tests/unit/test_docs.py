"""The documents name only what exists: every path, link, make target, command, stage and database object in
README.md, ARCHITECTURE.md and the READMEs of benchmarks/, migrations/ and sql/ is checked against the tree,
the Makefile and the CLI; every test file is linked from ARCHITECTURE.md; every stage has its section."""

from __future__ import annotations

import re
import subprocess
import sys
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[2]
DOCS = ["README.md", "ARCHITECTURE.md", "benchmarks/README.md", "migrations/README.md", "sql/README.md"]
#: Paths in backticks are checked when they start with one of these (build/, var/, data/ are made at run time).
TRACKED_ROOTS = ("core/", "etl/", "exporter/", "sql/", "migrations/", "tests/", "benchmarks/", "scripts/", ".ci/")
SCHEMAS = ("osm", "lod", "gen", "lm", "tex", "tiles", "meta", "api")
#: A name like lod.py is a file, not a database object.
FILE_SUFFIXES = {"py", "sql", "md", "js", "mjs", "html", "json", "glb", "osm", "pbf", "lua", "toml", "txt", "png"}
#: The pipeline's stages, in order; each has a make target, a `python -m etl` command and an ARCHITECTURE section.
STAGES = ("ingest", "lod", "landmarks", "tiles", "generalize", "textures", "export", "serve")


def make_targets(makefile: str) -> set[str]:
    """The Makefile's targets and those it includes from the stage graph (core/pipeline.py)."""
    from core.pipeline import make_rules

    return set(re.findall(r"^([A-Za-z][\w-]*)\s*:(?!=)", makefile + make_rules(), re.M))


def etl_commands() -> set[str]:
    out = subprocess.run([sys.executable, "-m", "etl", "--help"], cwd=REPO, capture_output=True, text=True,
                         check=True).stdout
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


def problems(doc: str, text: str, *, targets: set[str], commands: set[str], objects: set[str]) -> list[str]:
    """What ``text`` (the document at repo path ``doc``) names that does not exist."""
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
    pattern = rf"(?<![\w./-])((?:{'|'.join(SCHEMAS)})\.[a-z_][a-z0-9_]*)(?![\w/-]|\.py|\.sql|\.md)"
    for name in re.findall(pattern, text):
        if name.rpartition(".")[2] not in FILE_SUFFIXES and name not in objects:
            out.append(f"{doc}: no such database object: {name}")
    return out


@pytest.fixture(scope="module")
def known() -> dict[str, set[str]]:
    return {"targets": make_targets((REPO / "Makefile").read_text()), "commands": etl_commands(),
            "objects": db_objects()}


@pytest.mark.parametrize("doc", DOCS)
def test_every_name_in_the_docs_exists(doc: str, known: dict[str, set[str]]) -> None:
    found = problems(doc, (REPO / doc).read_text(), **known)
    assert not found, "\n".join(found)


def test_every_test_file_is_linked_from_architecture() -> None:
    text = (REPO / "ARCHITECTURE.md").read_text()
    missing = [p.relative_to(REPO).as_posix() for p in sorted((REPO / "tests").rglob("test_*.py"))
               if p.relative_to(REPO).as_posix() not in text]
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
    doc = ("See [the stage](etl/stages/nowhere.py), `sql/api/no_such.sql` and `etl/lod/stage.py`; run "
           "`make frobnicate` or `make lod`, `python -m etl nosuchstage`, `python -m benchmarks.nothing`, and "
           "query `api.no_such_function` or `api.lod_for_view`.")
    found = problems("README.md", doc, **known)
    assert found == [
        "README.md: link to a missing file: etl/stages/nowhere.py",
        "README.md: missing path: sql/api/no_such.sql",
        "README.md: no make target: make frobnicate",
        "README.md: no such command: python -m etl nosuchstage",
        "README.md: no such module: python -m benchmarks.nothing",
        "README.md: no such database object: api.no_such_function",
    ]
