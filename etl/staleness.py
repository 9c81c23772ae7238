"""Whether a stage is current (``python -m etl <stage> --if-stale``, what make runs).

A stage is current when its last successful run in ``meta.pipeline_run`` recorded the same ``inputs`` it would
record now:

* ``upstream``: the run id of the last successful run of every stage it reads, directly or through another
  (a re-ingest makes everything below it stale; a rerun of lod makes generalize stale before tiles reruns);
* ``settings``: the values of the Settings fields its code names (another stage's CITYLOD_* override leaves it
  current);
* ``code``: sha256 of every project module its stage module imports (read from the source, lazy imports
  included), of every sql/ object that code or that SQL names, as loaded in the database (meta.sql_object,
  not the file on disk: the database runs what migrate loaded), and of the migrations applied (third-party
  packages are left out: the venv pins them in constraints.txt);
* ``file`` (ingest: path and sha256 of the OSM file) and ``options`` (export: output directory, --lod and the
  stream's --geometry, --textures, --tiling);
  export is also stale when its files are gone or changed (``output``: the sha256 of the tileset.json written).

The record is the database's own: the database may be the local cluster or DATABASE_URL, so stamp files in the
checkout could lie about it. Make orders the stages (each target depends on the stages it reads) and runs each
with --if-stale, so ``make export`` brings the whole chain up to date and does no work when it already is.
"""

from __future__ import annotations

import dataclasses
import functools
import hashlib
import json
import re
from collections.abc import Iterable, Iterator
from dataclasses import dataclass
from pathlib import Path

import psycopg

from core.pipeline import GRAPH, STAGES, ancestors
from core.settings import REPO, Settings
from core.tiles3d import tileset_files
from etl.migrate import discover_sql, exists

#: The module that defines each stage; its import closure is the stage's Python code.
MODULES = {s.name: s.module for s in STAGES}
_PACKAGES = ("core", "etl", "exporter")
#: Settings that say where the database is, or how the work is spread (the output is the same whatever their
#: values), not how a stage's output is made.
_NOT_INPUTS = frozenset({"pg_port", "pg_database", "lod_workers", "lod_batch_size", "gen_workers", "export_workers"})
#: Defines every setting: the values a stage uses are compared instead, so editing a comment there reruns nothing.
_SETTINGS_MODULE = "core.settings"
_QUALIFIED = re.compile(r"\b([a-z_][a-z0-9_]*)\.([a-z_][a-z0-9_]*)\b")
_SQL_COMMENT = re.compile(r"--[^\n]*")


def sha256_bytes(data: bytes) -> str:
    return hashlib.sha256(data).hexdigest()


# --- the code a stage runs: read from the sources -----------------------------------------------------------
def project_modules(root: Path = REPO, packages: tuple[str, ...] = _PACKAGES) -> dict[str, Path]:
    """Module name -> source file of every module of ``packages`` under ``root``."""
    out = {}
    for pkg in packages:
        for path in sorted((root / pkg).rglob("*.py")):
            parts = list(path.relative_to(root).with_suffix("").parts)
            if parts[-1] == "__init__":
                parts.pop()
            out[".".join(parts)] = path
    return out


_IMPORT = re.compile(
    r"^[ \t]*(?:from[ \t]+(\.*)([\w.]*)[ \t]+import[ \t]+(\([^)]*\)|[^\n#;]*)|import[ \t]+([^\n#;]*))", re.M
)


def module_imports(name: str, path: Path, known: set[str]) -> set[str]:
    """The project modules ``name`` imports, anywhere in the file (lazy imports in functions too). A regular
    expression over the lines, not ast: parsing and walking every module cost ~0.3 s a stage; a docstring line
    that reads like an import only adds a module, it never drops one."""
    is_pkg = path.name == "__init__.py"
    out: set[str] = set()
    for dots, module, names, plain in _IMPORT.findall(path.read_text()):
        if plain:
            mod, targets = "", [n.split()[0] for n in plain.split(",") if n.strip()]
        else:
            mod = module
            if dots:
                base = name.split(".") if is_pkg else name.split(".")[:-1]
                base = base[: len(base) - (len(dots) - 1)]
                mod = ".".join(base + ([module] if module else []))
            names = [n.split()[0] for n in names.strip("()").replace("\n", " ").split(",") if n.strip()]
            targets = [f"{mod}.{n}" if f"{mod}.{n}" in known else mod for n in names]
        for t in targets:
            while t and t not in known:
                t = t.rpartition(".")[0]
            if t:
                out.add(t)
    return out


def _with_packages(module: str) -> Iterator[str]:
    """``module`` and its parent packages, whose __init__ runs when it is imported."""
    parts = module.split(".")
    for i in range(1, len(parts) + 1):
        yield ".".join(parts[:i])


def python_closure(module: str, root: Path = REPO) -> list[Path]:
    """The source files of ``module`` and of every project module it imports, transitively."""
    mods = project_modules(root)
    known = set(mods)
    seen: set[str] = set()
    todo = [m for m in _with_packages(module) if m in known]
    while todo:
        m = todo.pop()
        if m in seen:
            continue
        seen.add(m)
        for dep in module_imports(m, mods[m], known):
            todo.extend(p for p in _with_packages(dep) if p in known and p not in seen)
    return sorted(mods[m] for m in seen)


def sql_closure(texts: Iterable[str], root: Path = REPO) -> list[Path]:
    """The sql/ files of the objects ``texts`` name (``schema.object``), and of the objects their SQL names."""
    objs = {f"{o.schema}.{o.name}": o.path for o in discover_sql(root / "sql")}

    def named(text: str) -> set[str]:
        return {f"{a}.{b}" for a, b in _QUALIFIED.findall(text.lower())} & objs.keys()

    todo = set().union(*(named(t) for t in texts))
    seen: set[str] = set()
    while todo:
        o = todo.pop()
        if o not in seen:
            seen.add(o)
            todo |= named(_SQL_COMMENT.sub("", objs[o].read_text())) - seen
    return sorted(objs[o] for o in seen)


@dataclass(frozen=True)
class StageCode:
    python: dict[str, str]  # repo-relative path -> sha256
    sql: tuple[str, ...]  # sql/<schema>/<object>.sql the stage calls (hashes come from the database)
    settings: tuple[str, ...]  # the Settings fields its code names


@functools.cache
def stage_code(stage: str, root: Path = REPO) -> StageCode:
    """What defines ``stage`` in the sources under ``root`` (a few dozen small files: milliseconds)."""
    files = python_closure(MODULES[stage], root)
    settings_file = project_modules(root)[_SETTINGS_MODULE]
    files = [f for f in files if f != settings_file]
    texts = [f.read_text() for f in files]
    words = set().union(*(re.findall(r"\w+", t) for t in texts))
    fields = sorted(f.name for f in dataclasses.fields(Settings) if f.name in words and f.name not in _NOT_INPUTS)
    return StageCode(
        python={str(f.relative_to(root)): sha256_bytes(f.read_bytes()) for f in files},
        sql=tuple(str(p.relative_to(root)) for p in sql_closure(texts, root)),
        settings=tuple(fields),
    )


# --- the inputs a run records, and the comparison -------------------------------------------------------------
def _json(value: object) -> object:
    """As it comes back from jsonb (tuples become lists, paths strings)."""
    return json.loads(json.dumps(value, default=str))


def last_ok_runs(conn: psycopg.Connection, stages: list[str]) -> dict[str, int]:
    rows = conn.execute(
        """SELECT stage, max(run_id) FROM meta.pipeline_run
                           WHERE status = 'ok' AND stage = ANY(%s) GROUP BY stage""",
        (stages,),
    ).fetchall()
    return {s: int(r) for s, r in rows}


def inputs(
    conn: psycopg.Connection,
    stage: str,
    settings: Settings,
    reads: tuple[str, ...] | None = None,
    file: dict[str, object] | None = None,
    options: dict[str, object] | None = None,
) -> dict[str, object]:
    """What a run of ``stage`` would record in meta.pipeline_run.inputs now."""
    if not exists(conn, "meta.sql_object"):
        raise RuntimeError("the database is older than this code: run `python -m etl migrate` (make migrate)")
    ups = ancestors(GRAPH[stage] if reads is None else reads)
    last = last_ok_runs(conn, ups)
    code = stage_code(stage)
    loaded: dict[str, str] = dict(
        conn.execute("SELECT path, sha256 FROM meta.sql_object WHERE path = ANY(%s)", (list(code.sql),)).fetchall()
    )
    migrations = "".join(
        f"{v}:{c}\n" for v, c in conn.execute("SELECT version, checksum FROM meta.schema_migrations ORDER BY version")
    )
    out: dict[str, object] = {
        "upstream": {s: last.get(s) for s in ups},
        "settings": {f: getattr(settings, f) for f in code.settings},
        # an object sql/ defines but migrate has not loaded yet is None: the stage would not find it
        "code": {
            **code.python,
            **{p: loaded.get(p) for p in code.sql},
            "migrations": sha256_bytes(migrations.encode()),
        },
    }
    if file is not None:
        out["file"] = file
    if options is not None:
        out["options"] = options
    return {k: _json(v) for k, v in out.items()}


def _show(v: object) -> str:
    if isinstance(v, str) and re.fullmatch(r"[0-9a-f]{64}", v):
        return v[:12]  # a sha256
    return "unset" if v is None else json.dumps(v) if isinstance(v, dict | list) else str(v)


def differences(recorded: dict[str, object], now: dict[str, object]) -> list[str]:
    """Why ``recorded`` inputs are not ``now``'s, one short phrase each (empty: the same)."""
    out: list[str] = []
    order = ["upstream", "file", "options", "settings", "code"]
    for key in sorted(recorded.keys() | now.keys(), key=lambda k: (order.index(k) if k in order else len(order), k)):
        a, b = recorded.get(key), now.get(key)
        if a == b:
            continue
        if not (isinstance(a, dict) and isinstance(b, dict)):
            out.append(f"{key} {_show(a)} -> {_show(b)}")
        elif key == "upstream":
            changed = [s for s in b if a.get(s) != b.get(s)]
            if reran := [f"{s} {a.get(s)} -> {b[s]}" for s in changed if b[s] is not None]:
                out.append("upstream runs " + ", ".join(reran))
            out += [f"{s} has no successful run" for s in changed if b[s] is None]
        elif key == "code":
            changed = sorted(k for k in a.keys() | b.keys() if a.get(k) != b.get(k))
            out.append(
                "code changed: "
                + ", ".join(changed[:3])
                + (f" and {len(changed) - 3} more" if len(changed) > 3 else "")
            )
        else:
            out += [
                f"{key} {k} {_show(a.get(k))} -> {_show(b.get(k))}"
                for k in sorted(a.keys() | b.keys())
                if a.get(k) != b.get(k)
            ]
    return out


@dataclass(frozen=True)
class LastRun:
    run_id: int
    finished_at: str
    inputs: dict[str, object] | None
    output: dict[str, object] | None
    counts: dict[str, object] | None


def last_run(conn: psycopg.Connection, stage: str, out: str | None = None) -> LastRun | None:
    """The last successful run of ``stage`` (of export: into ``out``, since each directory holds its own)."""
    row = conn.execute(
        """SELECT run_id, to_char(finished_at AT TIME ZONE 'UTC', 'YYYY-MM-DD HH24:MI:SS'), inputs, output, counts
           FROM meta.pipeline_run
           WHERE stage = %s AND status = 'ok' AND (%s::text IS NULL OR inputs -> 'options' ->> 'out' = %s)
           ORDER BY run_id DESC LIMIT 1""",
        (stage, out, out),
    ).fetchone()
    return LastRun(*row) if row else None


def output_problems(out: Path, recorded: dict[str, object] | None) -> list[str]:
    """Why the export directory ``out`` is no longer what the run recorded wrote (empty: it is)."""
    ts = out / "tileset.json"
    if not ts.is_file():
        return [f"{ts} is missing"]
    data = ts.read_bytes()
    if not recorded or recorded.get("tileset_sha256") != sha256_bytes(data):
        return [f"{ts} is not the one it wrote"]
    try:  # content, and an implicit tileset's subtrees (read to list its content)
        uris = tileset_files(json.loads(data), lambda u: (out / u).read_bytes())
    except (OSError, ValueError) as e:
        return [f"the tileset in {out} cannot be read: {e}"]
    missing = [u for u in uris if not (out / u).is_file()]
    if missing:
        return [f"{len(missing)} content files missing from {out} ({missing[0]}, ...)"]
    return []


def verdict(conn: psycopg.Connection, stage: str, now: dict[str, object], out: Path | None = None) -> tuple[bool, str]:
    """(current?, one line saying so and why) for ``stage`` whose inputs are ``now`` (export: into ``out``)."""
    last = last_run(conn, stage, str(out) if out else None)
    if last is None:
        return False, f"{stage}: no successful run{f' into {out}' if out else ''} yet"
    if last.inputs is None:
        return False, f"{stage}: stale: run {last.run_id} recorded no inputs (older code)"
    why = differences(last.inputs, now)
    if out is not None and not why:
        why = output_problems(out, last.output)
    if why:
        return False, f"{stage}: stale since run {last.run_id}: {'; '.join(why)}"
    return True, (
        f"{stage}: current since run {last.run_id} ({last.finished_at} UTC): same upstream runs, "
        "settings, code" + (", input file" if "file" in now else "") + (", files" if out else "")
    )
