"""Make is a DAG over the database: `make export` on a fresh database runs every stage, a second `make export`
runs none, and a changed input (a setting, the OSM file, a re-ingest, sql/, the output directory or its files,
FORCE=1) reruns exactly the stages it feeds and everything below them (etl/staleness.py, the Makefile's stage targets).

The spine fixtures are built once with `make export`; each test that changes something works on a copy of that
database (CREATE DATABASE ... TEMPLATE) with its own output directory, and counts the meta.pipeline_run rows
each command adds."""

from __future__ import annotations

import contextlib
import os
import re
import shutil
import signal
import subprocess
import sys
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path

import psycopg
import pytest
from psycopg import sql
from psycopg.conninfo import conninfo_to_dict

from core.pipeline import GRAPH
from etl.migrate import SQL_DIR, reload_sql
from tests.conftest import ETL_TIMEOUT, KEEP, PREFIX, REPO, SPINE_FILES, _with_db, merge_osm, run_etl

ALL = list(GRAPH)  # ingest, lod, landmarks, tiles, generalize, textures, export
#: Every command of the module runs with these settings (one texturing process: the fixtures are one tile).
ENV = {"CITYLOD_TEX_WORKERS": "1"}


def run_make(url: str, *args: str, env: dict[str, str] | None = None) -> str:
    """``make <args>`` in the repo against ``url``, as a user runs it; its output. The venv's install stamp is
    taken as done (-o): the test is about the stage targets, not the installation."""
    cmd = ["make", "-C", str(REPO), "-o", ".venv/.installed", f"PY={sys.executable}", *args]
    full_env = {**os.environ, "DATABASE_URL": url, **ENV, **(env or {})}
    full_env.pop("MAKEFLAGS", None)
    full_env.pop("MAKELEVEL", None)
    with subprocess.Popen(
        cmd, env=full_env, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, start_new_session=True
    ) as proc:
        try:
            out, _ = proc.communicate(timeout=ETL_TIMEOUT)
        except subprocess.TimeoutExpired:
            with contextlib.suppress(ProcessLookupError):
                os.killpg(proc.pid, signal.SIGKILL)
            out, _ = proc.communicate()
            raise AssertionError(f"{' '.join(cmd)} did not finish in {ETL_TIMEOUT:g} s:\n{out}") from None
    assert proc.returncode == 0, f"{' '.join(cmd)} failed ({proc.returncode}):\n{out}"
    return out


def etl(url: str, *args: str, env: dict[str, str] | None = None) -> str:
    return run_etl(url, *args, env={**ENV, **(env or {})}).stdout


def last_run_id(url: str) -> int:
    with psycopg.connect(url) as conn:
        return conn.execute("SELECT coalesce(max(run_id), 0) FROM meta.pipeline_run").fetchone()[0]


def runs_after(url: str, run_id: int) -> list[str]:
    """The stages that ran after ``run_id``, in order (a failed run would show as stage!status)."""
    with psycopg.connect(url) as conn:
        return [
            s if st == "ok" else f"{s}!{st}"
            for s, st in conn.execute(
                "SELECT stage, status FROM meta.pipeline_run WHERE run_id > %s ORDER BY run_id", (run_id,)
            )
        ]


def reran(url: str, action: Callable[[], object]) -> list[str]:
    """The stages ``action`` ran."""
    before = last_run_id(url)
    action()
    return runs_after(url, before)


@dataclass(frozen=True)
class Built:
    url: str
    dbname: str
    osm: Path
    out: Path
    first_output: str


@pytest.fixture(scope="module")
def built(new_db, tmp_path_factory) -> Built:
    """The spine fixtures through `make export` on a fresh database."""
    tmp = tmp_path_factory.mktemp("dag")
    osm = merge_osm(SPINE_FILES, tmp / "spine.osm")
    url = new_db("dag")
    out = tmp / "tiles"
    text = run_make(url, "export", f"OSM={osm}", f"OUT={out}")
    return Built(url, conninfo_to_dict(url)["dbname"], osm, out, text)


@pytest.fixture()
def copy_of(built: Built, server_url: str) -> Iterator[Callable[[str], str]]:
    """Factory: a copy of the built database (its data and its meta.pipeline_run record)."""
    made: list[str] = []

    def make(label: str) -> str:
        name = f"{PREFIX}_dag_{label}"[:63]
        with psycopg.connect(server_url, autocommit=True) as admin:
            admin.execute(sql.SQL("DROP DATABASE IF EXISTS {} WITH (FORCE)").format(sql.Identifier(name)))
            admin.execute(
                sql.SQL("CREATE DATABASE {} TEMPLATE {}").format(sql.Identifier(name), sql.Identifier(built.dbname))
            )
        made.append(name)
        return _with_db(server_url, name)

    yield make
    if not KEEP:
        with psycopg.connect(server_url, autocommit=True) as admin:
            for name in made:
                admin.execute(sql.SQL("DROP DATABASE IF EXISTS {} WITH (FORCE)").format(sql.Identifier(name)))


def test_make_export_on_a_fresh_database_runs_every_stage(built: Built) -> None:
    assert runs_after(built.url, 0) == ALL
    for stage in ALL:
        assert re.search(rf"^{stage}: no successful run.* yet; running$", built.first_output, re.M), stage
    assert (built.out / "tileset.json").is_file() and list((built.out / "content").rglob("*.glb"))
    with psycopg.connect(built.url) as conn:
        inputs = dict(conn.execute("SELECT stage, inputs FROM meta.pipeline_run").fetchall())
    # what each run recorded: the runs it read, its own settings only, its code, the file, the output options
    assert inputs["generalize"]["upstream"] == {"ingest": 1, "lod": 2, "landmarks": 3, "tiles": 4}
    assert inputs["ingest"]["file"]["path"] == str(built.osm)
    assert "level_height_m" in inputs["lod"]["settings"] and "tex_quality" not in inputs["lod"]["settings"]
    assert "etl/lod/stage.py" in inputs["lod"]["code"] and "exporter/export.py" not in inputs["lod"]["code"]
    assert inputs["export"]["options"] == {
        "out": str(built.out),
        "lod": None,
        "geometry": "compact",
        "textures": "ktx2",
        "tiling": "implicit",
        "tables": "plain",
        "publish": built.out.name,
    }


def test_second_make_export_does_no_stage_work(built: Built) -> None:
    before = last_run_id(built.url)
    tileset = (built.out / "tileset.json").stat().st_mtime_ns
    text = run_make(built.url, "export", f"OSM={built.osm}", f"OUT={built.out}")
    assert runs_after(built.url, before) == []
    assert re.search(r"^migrate: current .*; skipped$", text, re.M)
    for stage in ALL:
        assert re.search(rf"^{stage}: current since run \d+ .*; skipped$", text, re.M), text
    assert (built.out / "tileset.json").stat().st_mtime_ns == tileset


def test_force_reruns_the_named_stage_and_then_what_is_below_it(built: Built, copy_of, tmp_path) -> None:
    url = copy_of("force")
    out = f"OUT={tmp_path / 'tiles'}"
    assert reran(url, lambda: run_make(url, "lod", f"OSM={built.osm}", out, "FORCE=1")) == ["lod"]
    # the tile tree, landmarks and everything below were built from the old meshes
    assert reran(url, lambda: run_make(url, "export", f"OSM={built.osm}", out)) == ALL[2:]
    assert reran(url, lambda: run_make(url, "export", f"OSM={built.osm}", out)) == []


def test_a_setting_reruns_its_stage_and_below_only(built: Built, copy_of, tmp_path) -> None:
    url = copy_of("setting")
    out = f"OUT={tmp_path / 'tiles'}"
    assert reran(url, lambda: run_make(url, "export", f"OSM={built.osm}", out)) == ["export"]  # a new directory
    # landmarks' weight: tiles does not read lm.*, so it stays current
    changed = reran(url, lambda: run_make(url, "export", f"OSM={built.osm}", out, env={"CITYLOD_LM_W_HEIGHT": "2"}))
    assert changed == ["landmarks", "generalize", "textures", "export"]
    with psycopg.connect(url) as conn:
        assert (
            conn.execute("""SELECT inputs -> 'settings' -> 'lm_w_height' FROM meta.pipeline_run
                               WHERE stage = 'landmarks' ORDER BY run_id DESC LIMIT 1""").fetchone()[0]
            == 2.0
        )
    # a texture setting: textures and export
    assert reran(
        url,
        lambda: run_make(
            url, "export", f"OSM={built.osm}", out, env={"CITYLOD_LM_W_HEIGHT": "2", "CITYLOD_TEX_QUALITY": "80"}
        ),
    ) == ["textures", "export"]
    # back to the defaults: what ran with the other values reruns
    assert reran(url, lambda: run_make(url, "export", f"OSM={built.osm}", out)) == [
        "landmarks",
        "generalize",
        "textures",
        "export",
    ]


def test_export_reruns_for_another_directory_lod_or_missing_files(built: Built, copy_of, tmp_path) -> None:
    url = copy_of("files")
    out = tmp_path / "tiles"
    make_export = ["export", f"OSM={built.osm}", f"OUT={out}"]
    assert reran(url, lambda: run_make(url, *make_export)) == ["export"]
    assert reran(url, lambda: run_make(url, *make_export)) == []
    glb = next((out / "content").rglob("*.glb"))
    glb.unlink()
    text = run_make(url, *make_export)
    assert re.search(r"^export: stale since run \d+: 1 content files missing .*; running$", text, re.M), text
    assert glb.is_file()
    # an implicit tileset's content is listed in its subtrees: one missing makes the export stale too
    subtree = next((out / "subtrees").rglob("*.subtree"))
    subtree.unlink()
    text = run_make(url, *make_export)
    assert re.search(r"^export: stale since run \d+: the tileset in .* cannot be read.*; running$", text, re.M), text
    assert subtree.is_file()
    (out / "tileset.json").write_text((out / "tileset.json").read_text().replace('"1.1"', '"1.1" '))
    assert reran(url, lambda: run_make(url, *make_export)) == ["export"]
    # a one-LOD export into the same directory replaces it: the hierarchy's export is stale again afterwards
    assert reran(url, lambda: run_make(url, *make_export, "LOD=2")) == ["export"]
    assert reran(url, lambda: run_make(url, *make_export, "LOD=2")) == []
    assert reran(url, lambda: run_make(url, *make_export)) == ["export"]
    # the first directory, still as its export wrote it, is still current
    assert reran(url, lambda: run_make(url, "export", f"OSM={built.osm}", f"OUT={built.out}")) == []


def test_reingest_and_another_osm_file_rerun_everything_below(built: Built, copy_of, tmp_path) -> None:
    url = copy_of("ingest")
    out = str(tmp_path / "tiles")
    stages = [
        [s, "--if-stale"]
        + (["--osm", str(built.osm)] if s == "ingest" else [])
        + (["--out", out] if s == "export" else [])
        for s in ALL
    ]

    def chain() -> None:  # what make runs, without make
        for args in stages:
            etl(url, *args)

    chain()  # the copy's export goes to its own directory
    # by hand, without the flag, a stage always runs, and makes everything below it stale
    assert reran(url, lambda: etl(url, "ingest", "--osm", str(built.osm))) == ["ingest"]
    assert reran(url, chain) == ALL[1:]
    assert reran(url, chain) == []
    # the same content under another name is another input; so is another content under the same name
    other = tmp_path / "spine.osm"
    shutil.copy(built.osm, other)
    assert "file path" in etl(url, "ingest", "--if-stale", "--osm", str(other))
    text = other.read_text()
    other.write_text(text.replace("</osm>", "<!-- edited -->\n</osm>"))
    line = etl(url, "ingest", "--if-stale", "--osm", str(other)).splitlines()[0]
    assert re.fullmatch(r"ingest: stale since run \d+: file sha256 \w+ -> \w+; running", line), line


def test_sql_edit_reruns_the_stages_that_call_it_and_migrate_reloads_once(built: Built, copy_of, tmp_path) -> None:
    url = copy_of("sql")
    out = str(tmp_path / "tiles")
    chain = [
        [s, "--if-stale"]
        + (["--osm", str(built.osm)] if s == "ingest" else [])
        + (["--out", out] if s == "export" else [])
        for s in ALL
    ]
    assert reran(url, lambda: [etl(url, *a) for a in chain]) == ["export"]
    # load an edited tiles.finish_hierarchy (generalize calls it; lod, landmarks and tiles do not)
    edited = tmp_path / "sql"
    shutil.copytree(SQL_DIR, edited)
    f = edited / "tiles" / "finish_hierarchy.sql"
    f.write_text(f.read_text() + "\n-- an edit\n")
    with psycopg.connect(url) as conn:
        reload_sql(conn, directory=edited, quiet=True)
    text: list[str] = []
    assert reran(url, lambda: text.extend(etl(url, *a) for a in chain)) == ["generalize", "textures", "export"]
    assert "generalize: stale since run" in text[4] and "code changed: sql/tiles/finish_hierarchy.sql" in text[4]
    # migrate --if-stale sees that sql/ on disk is not what is loaded, reloads it, then has nothing to do
    assert "sql objects loaded" in etl(url, "migrate", "--if-stale")
    assert re.match(r"migrate: current .*; skipped$", etl(url, "migrate", "--if-stale"))
    assert reran(url, lambda: [etl(url, *a) for a in chain]) == ["generalize", "textures", "export"]
