"""What the benchmarks and the reports share: data paths, child processes, scratch databases, the machine
block and markdown tables. Imports nothing else of benchmarks/, so every report and the bench import it and
nothing imports them back."""

from __future__ import annotations

import datetime as dt
import json
import os
import platform
import re
import subprocess
import sys
import time
from collections.abc import Iterable, Sequence
from pathlib import Path
from typing import Any

import psycopg
from psycopg import sql
from psycopg.conninfo import conninfo_to_dict

from core.settings import REPO
from tests.support.data import SHARED_OSM  # noqa: F401  (the benchmarks' import of it)

HEADLINE = "liechtenstein_2022-07-24"

OUT_ROOT = REPO / "build" / "bench"
LOG_DIR = OUT_ROOT / "logs"


def log(msg: str) -> None:
    print(f"[bench {time.strftime('%H:%M:%S')}] {msg}", file=sys.stderr, flush=True)


def run_child(cmd: Sequence[str], env: dict[str, str], logfile: Path) -> tuple[float, float]:
    """Run ``cmd`` to completion; return (wall seconds, peak RSS MiB). Raises on a non-zero exit."""
    logfile.parent.mkdir(parents=True, exist_ok=True)
    with logfile.open("wb") as fh:
        fh.write(("$ " + " ".join(cmd) + "\n").encode())
        fh.flush()
        t0 = time.perf_counter()
        proc = subprocess.Popen(list(cmd), env=env, cwd=REPO, stdout=fh, stderr=subprocess.STDOUT)
        # wait4 rather than proc.wait(): it hands back this child's own rusage, whereas
        # getrusage(RUSAGE_CHILDREN) would mix in every earlier child of the benchmark.
        _, status, usage = os.wait4(proc.pid, 0)
        seconds = time.perf_counter() - t0
    proc.returncode = os.waitstatus_to_exitcode(status)  # tell Popen the child is already reaped
    if proc.returncode != 0:
        tail = logfile.read_text(errors="replace").splitlines()[-20:]
        raise RuntimeError(f"{' '.join(cmd)} exited {proc.returncode}; log {logfile}:\n" + "\n".join(tail))
    return seconds, usage.ru_maxrss / 1024  # Linux reports ru_maxrss in KiB


O2P_DB = "citylod_bench_o2p"
STYLE = Path(__file__).resolve().parent / "osm2pgsql" / "buildings.lua"


def osm2pgsql_cmd(url: str, path: Path) -> tuple[list[str], dict[str, str]]:
    """The osm2pgsql command line for ``url`` (-H/-P/-U/-d), plus PGPASSWORD when the URL carries one."""
    info = conninfo_to_dict(url)
    cmd = ["osm2pgsql"]
    for flag, key in (("-H", "host"), ("-P", "port"), ("-U", "user")):
        if info.get(key):
            cmd += [flag, str(info[key])]
    cmd += ["-d", str(info["dbname"]), "-O", "flex", "-S", str(STYLE), "--create", str(path)]
    env = dict(os.environ)
    if info.get("password"):
        env["PGPASSWORD"] = str(info["password"])
    return cmd, env


def last_run(url: str, stage: str) -> tuple[dict[str, Any], float | None]:
    with psycopg.connect(url) as conn:
        row = conn.execute(
            "SELECT status, counts, duration_s FROM meta.pipeline_run WHERE stage = %s ORDER BY run_id DESC LIMIT 1",
            (stage,),
        ).fetchone()
    if row is None or row[0] != "ok":
        raise RuntimeError(f"{stage}: no successful meta.pipeline_run row (got {row!r})")
    return dict(row[1] or {}), (float(row[2]) if row[2] is not None else None)


def recreate_db(admin_url: str, name: str) -> None:
    with psycopg.connect(admin_url, autocommit=True) as conn:
        conn.execute(sql.SQL("DROP DATABASE IF EXISTS {} WITH (FORCE)").format(sql.Identifier(name)))
        conn.execute(sql.SQL("CREATE DATABASE {}").format(sql.Identifier(name)))


def drop_db(admin_url: str, name: str) -> None:
    with psycopg.connect(admin_url, autocommit=True) as conn:
        conn.execute(sql.SQL("DROP DATABASE IF EXISTS {} WITH (FORCE)").format(sql.Identifier(name)))


def extract_name(path: Path) -> str:
    name = path.name
    for suffix in (".osm.pbf", ".pbf", ".osm"):
        if name.endswith(suffix):
            return name[: -len(suffix)]
    return name


#: the stages that build what the export reads
PIPELINE = ("ingest", "lod", "landmarks", "tiles", "generalize", "textures")


def build_pipeline_db(osm: Path, admin_url: str, name: str, logs_sub: str) -> str:
    """A fresh database ``name`` (on ``admin_url``'s server) with the pipeline run on ``osm`` up to textures;
    the stages' logs under LOG_DIR/<extract>/<logs_sub>. Returns its URL."""
    from core import cluster

    url = cluster.database_url(name)
    env = {**os.environ, "DATABASE_URL": url}
    logs = LOG_DIR / extract_name(osm) / logs_sub
    recreate_db(admin_url, name)
    run_child([sys.executable, "-m", "etl", "migrate"], env, logs / "migrate.log")
    for stage in PIPELINE:
        log(f"{extract_name(osm)}: {stage}")
        run_child(
            [sys.executable, "-m", "etl", stage, *(["--osm", str(osm)] if stage == "ingest" else [])],
            env,
            logs / f"{stage}.log",
        )
    return url


# --- machine block ------------------------------------------------------------------------------------------


def _first(cmd: Sequence[str]) -> str | None:
    try:
        r = subprocess.run(list(cmd), capture_output=True, text=True, check=True, cwd=REPO)
    except (OSError, subprocess.CalledProcessError):
        return None
    out = (r.stdout or r.stderr).strip().splitlines()
    return out[0].strip() if out else None


def _cpu_model() -> str:
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or "unknown"


def cpu() -> str:
    """The CPU model and core count, for a section measured apart from make bench's machine block."""
    return f"{_cpu_model()}, {os.cpu_count()} cores"


def _ram_gib() -> str:
    try:
        for line in Path("/proc/meminfo").read_text().splitlines():
            if line.startswith("MemTotal:"):
                return f"{int(line.split()[1]) / 1024**2:.1f} GiB"
    except OSError:
        pass
    return "unknown"


def _os_name() -> str:
    try:
        for line in Path("/etc/os-release").read_text().splitlines():
            if line.startswith("PRETTY_NAME="):
                return line.split("=", 1)[1].strip().strip('"')
    except OSError:
        pass
    return platform.platform()


def _osm2pgsql_version() -> str:
    # It logs the version to stderr behind a timestamp ("2026-… osm2pgsql version 1.8.0").
    try:
        r = subprocess.run(["osm2pgsql", "--version"], capture_output=True, text=True)
    except OSError:
        return "not installed"
    m = re.search(r"osm2pgsql version (\S+)", r.stdout + r.stderr)
    return m.group(1) if m else "unknown"


def _git() -> str:
    sha = _first(["git", "rev-parse", "--short", "HEAD"])
    if sha is None:
        return "no commit yet"
    dirty = subprocess.run(
        ["git", "status", "--porcelain", "--untracked-files=no"], capture_output=True, text=True, cwd=REPO
    ).stdout.strip()
    return sha + ("-dirty" if dirty else "")


def _postgis_short(full: str) -> str:
    """``POSTGIS="3.3.2 ..." GEOS="3.11.1-CAPI-1.17.1" SFCGAL="SFCGAL 1.4.1, ..."`` -> short form."""
    parts = []
    for key in ("POSTGIS", "GEOS", "PROJ", "SFCGAL"):
        m = re.search(rf'{key}="(?:SFCGAL )?([0-9][^ ",]*)', full)
        if m:
            parts.append(f"{'PostGIS' if key == 'POSTGIS' else key} {m.group(1).split('-')[0]}")
    return ", ".join(parts) or full


def machine(url: str, osm2pgsql: bool = True) -> dict[str, str]:
    """The machine a report ran on (its Machine table); ``osm2pgsql=False`` for the reports that do not run it."""
    with psycopg.connect(url) as conn:
        server = conn.execute("SHOW server_version").fetchone()
        full = conn.execute("SELECT postgis_full_version()").fetchone()
    out = {
        "CPU": _cpu_model(),
        "cores": str(os.cpu_count()),
        "RAM": _ram_gib(),
        "OS": _os_name(),
        "Python": platform.python_version(),
        "PostgreSQL": str(server[0]) if server else "?",
        "PostGIS": _postgis_short(str(full[0])) if full else "?",
    }
    if osm2pgsql:
        out["osm2pgsql"] = _osm2pgsql_version()
    return out | {"git": _git(), "date": dt.datetime.now(dt.UTC).strftime("%Y-%m-%d %H:%M UTC")}


def db_name(url: str) -> str:
    """The database a URL names, as the reports quote it."""
    return str(conninfo_to_dict(url).get("dbname", "?"))


# --- report (markdown helpers shared by benchmarks/report_*.py) ---------------------------------------------


def markdown_table(header: Sequence[str], rows: Iterable[Sequence[object]], align: str) -> list[str]:
    """Markdown table; ``align`` has one l/r per column."""
    if len(align) != len(header):
        raise ValueError("one alignment per column")
    out = ["| " + " | ".join(header) + " |", "|" + "|".join("---:" if c == "r" else "---" for c in align) + "|"]
    for row in rows:
        if len(row) != len(header):
            raise ValueError("one cell per column")
        out.append("| " + " | ".join(str(c) for c in row) + " |")
    return out


def machine_section(mach: dict[str, str]) -> list[str]:
    """The ``## Machine`` heading and table of a report."""
    return ["## Machine", "", *markdown_table(["", ""], [[k, v] for k, v in mach.items()], "ll")]


def pass_mark(ok: bool) -> str:
    return "**pass**" if ok else "**FAIL**"


def section_bench(
    argv: list[str] | None, prog: str, doc: str, default_osm: Path, db: str, measure: Any, section: Any, heading: str
) -> int:
    """The command line of a bench that measures one section on one extract in a database of its own (soak_bench,
    update_bench): --osm, --json (the figures), --write (replace the report's section whose heading starts with
    ``heading``), --keep (the database)."""
    import argparse

    from core import cluster

    p = argparse.ArgumentParser(prog=prog, description=doc.splitlines()[0])
    p.add_argument("--osm", type=Path, default=default_osm)
    p.add_argument("--json", type=Path, help="write the figures here")
    p.add_argument("--write", type=Path, help=f"replace this report's {heading[3:]} section (e.g. BENCHMARKS.md)")
    p.add_argument("--keep", action="store_true", help=f"keep {db}")
    a = p.parse_args(argv)
    cluster.ensure()
    admin_url = cluster.database_url("postgres")
    try:
        figures = {**measure(a.osm.resolve(), admin_url), "machine": cpu()}
    finally:
        if not a.keep:
            drop_db(admin_url, db)
    text = json.dumps(figures, indent=1)
    if a.json:
        a.json.parent.mkdir(parents=True, exist_ok=True)
        a.json.write_text(text)
    if a.write:
        splice(a.write, section(figures), heading)
        log(f"wrote the {heading[3:]} section of {a.write}")
    print(text)
    return 0


def splice(path: Path, lines: list[str], heading: str) -> None:
    """Replace (or add, before "## How to read this") the section of the report at ``path`` whose heading starts
    with ``heading``."""
    text = path.read_text().splitlines()
    start = next((i for i, t in enumerate(text) if t.startswith(heading)), None)
    if start is None:
        start = end = next((i for i, t in enumerate(text) if t.startswith("## How to read")), len(text))
    else:
        end = next((i for i in range(start + 1, len(text)) if text[i].startswith("## ")), len(text))
    path.write_text("\n".join([*text[:start], *lines, *text[end:]]) + "\n")
