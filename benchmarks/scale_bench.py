"""``python -m benchmarks.scale_bench``: the whole pipeline on an extract and on its replicas (make bench's Scale
section; ``make bench-scale`` adds the ~1M replica).

    python -m benchmarks.scale_bench [--extract PATH] [--copies 1 6 56] [--json OUT.json]

For every copy count N the extract is replicated N times by benchmarks/replicate.py (N = 1 is the extract
itself), loaded into a fresh database ``citylod_scale_xN`` and taken through every stage, ingest to export, each
stage one child process as make runs it. Per stage: wall seconds, the client's peak RSS (the stage process and
its workers' largest, from wait4), and the server's peak private memory (RssAnon summed over the database's
backends and parallel workers, sampled every 0.2 s; shared buffers are not counted, they are fixed by the
configuration). Per run: the database's size after the export, the tileset's bytes on disk, buildings/s end to
end. Between consecutive sizes, each stage's growth exponent: log(t₂/t₁) / log(b₂/b₁) over loaded buildings, 1
for a linear stage. The databases are dropped afterwards unless --keep.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import sys
import threading
from pathlib import Path
from typing import Any

import psycopg

from benchmarks.common import (
    LOG_DIR,
    O2P_DB,
    OUT_ROOT,
    drop_db,
    extract_name,
    last_run,
    log,
    markdown_table,
    osm2pgsql_cmd,
    recreate_db,
    run_child,
)
from benchmarks.replicate import replicate

STAGES = ("ingest", "lod", "landmarks", "tiles", "generalize", "textures", "export")
#: the issue-19 targets
EXPONENT_TARGET = 1.05
RSS_TARGET_MIB = 1024.0
THROUGHPUT_TARGET = 1100.0  # buildings/s end to end


class ServerMemory:
    """Samples the private memory (RssAnon) of one database's backends and their parallel workers."""

    def __init__(self, dbname: str, period: float = 0.2) -> None:
        self.dbname = dbname.encode()
        self.period = period
        self.peak_kib = 0
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, daemon=True)

    def _sample(self) -> int:
        procs: dict[str, bytes] = {}
        for pid in os.listdir("/proc"):
            if pid.isdigit():
                try:
                    cmd = Path(f"/proc/{pid}/cmdline").read_bytes()
                except OSError:  # the process ended between listdir and read
                    continue
                if cmd.startswith(b"postgres: "):
                    procs[pid] = cmd
        backends = {pid for pid, cmd in procs.items() if self.dbname in cmd.split(b" ")}
        # a parallel worker names its leader: "postgres: parallel worker for PID <pid>"
        ours = backends | {
            pid
            for pid, cmd in procs.items()
            if cmd.rstrip(b"\0 ").rsplit(b" ", 1)[-1].decode(errors="replace") in backends
            and b"parallel worker for PID" in cmd
        }
        total = 0
        for pid in ours:
            try:
                for line in Path(f"/proc/{pid}/status").read_text().splitlines():
                    if line.startswith("RssAnon:"):
                        total += int(line.split()[1])
                        break
            except OSError:
                continue
        return total

    def _run(self) -> None:
        while not self._stop.is_set():
            self.peak_kib = max(self.peak_kib, self._sample())
            self._stop.wait(self.period)

    def __enter__(self) -> ServerMemory:
        self._thread.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self._stop.set()
        self._thread.join()

    @property
    def peak_mib(self) -> float:
        return self.peak_kib / 1024


def _dir_bytes(path: Path) -> int:
    return sum(f.stat().st_size for f in path.rglob("*") if f.is_file())


def run_copies(extract: Path, copies: int, admin_url: str, keep: bool = False, dask: bool = False) -> dict[str, Any]:
    """The pipeline on ``copies`` replicas of ``extract``: one result row of the Scale section (with ``dask``,
    then the Dask stages again on 1 and 2 workers: dask_speedup)."""
    from core import cluster

    name = extract_name(extract)
    work = OUT_ROOT / "scale"
    work.mkdir(parents=True, exist_ok=True)
    if copies == 1:
        osm, rep = extract, None
    else:
        osm = work / f"{name}-x{copies}.osm.pbf"
        log(f"scale: replicating {name} × {copies}")
        rep = replicate(extract, copies, osm)
    dbname = f"citylod_scale_x{copies}"
    url = cluster.database_url(dbname)
    env = {**os.environ, "DATABASE_URL": url}
    logs = LOG_DIR / "scale" / f"x{copies}"
    tiles = work / f"tiles-x{copies}"
    recreate_db(admin_url, dbname)
    try:
        run_child([sys.executable, "-m", "etl", "migrate"], env, logs / "migrate.log")
        stages: dict[str, dict[str, float]] = {}
        for stage in STAGES:
            args = {"ingest": ["--osm", str(osm)], "export": ["--out", str(tiles)]}.get(stage, [])
            with ServerMemory(dbname) as mem:
                seconds, rss = run_child([sys.executable, "-m", "etl", stage, *args], env, logs / f"{stage}.log")
            _, stage_s = last_run(url, stage)  # its own seconds, without the interpreter's start and the imports
            stages[stage] = {
                "s": round(seconds, 2),
                "client_rss_mib": round(rss, 1),
                "server_rss_mib": round(mem.peak_mib, 1),
            }
            if stage_s is not None:
                stages[stage]["stage_s"] = round(stage_s, 2)
            log(f"scale x{copies} {stage:<10} {seconds:8.1f} s  client {rss:6.0f} MiB  server {mem.peak_mib:6.0f} MiB")
        with psycopg.connect(url) as conn:
            row = conn.execute(
                "SELECT (SELECT count(*) FROM osm.building), pg_database_size(current_database())"
            ).fetchone()
            assert row is not None
            buildings, db_bytes = int(row[0]), int(row[1])
        speedup = dask_speedup(url, env, logs, tiles) if dask else None
    finally:
        if not keep:
            drop_db(admin_url, dbname)
    o2p = _osm2pgsql(osm, admin_url, logs / "osm2pgsql.log")
    total = sum(s["s"] for s in stages.values())
    return {
        "copies": copies,
        "osm": str(osm),
        "osm_bytes": osm.stat().st_size,
        "buildings": buildings,
        "replicate_s": rep["seconds"] if rep else 0.0,
        "stages": stages,
        "total_s": round(total, 1),
        "buildings_per_s": round(buildings / total, 1),
        "db_bytes": db_bytes,
        "tileset_bytes": _dir_bytes(tiles),
        "osm2pgsql_s": o2p,
        "dask": speedup,
    }


#: The stages whose units run as Dask tasks, and the setting that gives their worker count.
DASK_STAGES = {
    "lod": "CITYLOD_LOD_WORKERS",
    "generalize": "CITYLOD_GEN_WORKERS",
    "textures": "CITYLOD_TEX_WORKERS",
    "export": "CITYLOD_EXPORT_WORKERS",
}


def dask_speedup(url: str, env: dict[str, str], logs: Path, tiles: Path) -> dict[str, dict[str, float]]:
    """Each Dask stage run again with 1 worker (its units in the stage's own process) and on a LocalCluster of 2
    workers, in pipeline order on the built database (tiles again after lod, which empties them): the stage's
    own seconds and the speedup 1 -> 2."""
    out: dict[str, dict[str, float]] = {}
    for stage, var in DASK_STAGES.items():
        row: dict[str, float] = {}
        for n in (1, 2):
            args = ["--out", str(tiles)] if stage == "export" else []
            run_child([sys.executable, "-m", "etl", stage, *args], {**env, var: str(n)}, logs / f"{stage}-w{n}.log")
            _, stage_s = last_run(url, stage)
            row[f"w{n}_s"] = round(float(stage_s or 0.0), 2)
        row["speedup"] = round(row["w1_s"] / row["w2_s"], 2) if row["w2_s"] else 0.0
        out[stage] = row
        log(
            f"scale dask {stage:<10} 1 worker {row['w1_s']:7.1f} s  2 workers {row['w2_s']:7.1f} s  "
            f"x{row['speedup']:.2f}"
        )
        if stage == "lod":
            run_child([sys.executable, "-m", "etl", "tiles"], env, logs / "tiles-again.log")
    return out


def _osm2pgsql(osm: Path, admin_url: str, logfile: Path) -> float | None:
    """osm2pgsql 1.8 on the same file with make bench's style (benchmarks/osm2pgsql/buildings.lua), the loader
    ingest is compared with; None when it is not installed (make bench installs it)."""
    import shutil

    from core import cluster

    if shutil.which("osm2pgsql") is None:
        return None
    recreate_db(admin_url, O2P_DB)
    url = cluster.database_url(O2P_DB)
    try:
        with psycopg.connect(url, autocommit=True) as conn:
            conn.execute("CREATE EXTENSION IF NOT EXISTS postgis")
        cmd, env = osm2pgsql_cmd(url, osm)
        seconds, _ = run_child(cmd, env, logfile)
    finally:
        drop_db(admin_url, O2P_DB)
    return round(seconds, 2)


def _t(stage: dict[str, float]) -> float:
    """A stage's own seconds when recorded, else its process' wall time (which adds a fixed start-up)."""
    return stage.get("stage_s") or stage["s"]


def exponents(runs: list[dict[str, Any]]) -> list[dict[str, float]]:
    """Per consecutive pair of runs, each stage's (and the total's) growth exponent over buildings, on the
    stages' own seconds (a fixed start-up of a second would read as sublinear growth)."""
    out = []
    for a, b in zip(runs, runs[1:], strict=False):
        scale = math.log(b["buildings"] / a["buildings"])
        row = {st: round(math.log(_t(b["stages"][st]) / _t(a["stages"][st])) / scale, 2) for st in STAGES}
        row["total"] = round(math.log(b["total_s"] / a["total_s"]) / scale, 2)
        out.append(row)
    return out


def measure(extract: Path, copies: list[int], admin_url: str, keep: bool = False, dask: bool = True) -> dict[str, Any]:
    """Every copy count; the Dask speedup on the smallest (the extract) unless ``dask`` is False."""
    sizes = sorted(set(copies))
    runs = [run_copies(extract, n, admin_url, keep, dask and n == sizes[0]) for n in sizes]
    return {"extract": extract_name(extract), "runs": runs, "exponents": exponents(runs)}


SCALE_STAGES_NOTE = (
    "The benchmark extract and its replicas (benchmarks/replicate.py: N shifted copies of the extract in one "
    "valid sorted OSM file, every id offset per copy by a power of ten above the extract's largest id), each "
    "taken through every stage as make runs it, on a fresh database (benchmarks/scale_bench.py). *client MiB*: "
    "peak RSS of the stage process and its workers; *server MiB*: peak private memory (RssAnon) of the "
    "database's backends and parallel workers together, sampled every 0.2 s (shared buffers are fixed by the "
    "configuration and not counted). *s*: the stage process' wall time. *exponent*: log(t₂/t₁) / log(b₂/b₁) "
    "between consecutive sizes over the stage's own seconds in meta.pipeline_run when recorded (the process' "
    "wall time adds a fixed start-up that reads as sublinear growth), 1 for a linear stage. Targets (issue "
    "19): every exponent ≤ {exp}, client RSS flat and ≤ 1 GB at ~1M, ≥ {tput:,.0f} "
    "buildings/s end to end."
)


def section(data: dict[str, Any] | None) -> list[str]:
    """BENCHMARKS.md's Scale section (empty without data)."""
    if not data or not data.get("runs"):
        return []
    runs = data["runs"]
    header = [
        "stage",
        *[f"×{r['copies']} s ({r['buildings']:,} bldg)" for r in runs],
        *[f"exponent ×{a['copies']}→×{b['copies']}" for a, b in zip(runs, runs[1:], strict=False)],
        *[f"client MiB ×{r['copies']}" for r in runs],
        *[f"server MiB ×{r['copies']}" for r in runs],
    ]
    rows = []
    for st in STAGES:
        rows.append(
            [
                st,
                *[f"{r['stages'][st]['s']:,.1f}" for r in runs],
                *[f"{e[st]:.2f}" for e in data["exponents"]],
                *[f"{r['stages'][st]['client_rss_mib']:,.0f}" for r in runs],
                *[f"{r['stages'][st]['server_rss_mib']:,.0f}" for r in runs],
            ]
        )
    rows.append(
        [
            "**total**",
            *[f"**{r['total_s']:,.1f}**" for r in runs],
            *[f"**{e['total']:.2f}**" for e in data["exponents"]],
            *[f"{max(s['client_rss_mib'] for s in r['stages'].values()):,.0f}" for r in runs],
            *[f"{max(s['server_rss_mib'] for s in r['stages'].values()):,.0f}" for r in runs],
        ]
    )
    out = [
        "",
        f"## Scale: {data['extract']} and its replicas, end to end",
        "",
        SCALE_STAGES_NOTE.format(exp=EXPONENT_TARGET, tput=THROUGHPUT_TARGET),
        "",
        *markdown_table(header, rows, "l" + "r" * (len(header) - 1)),
        "",
    ]

    def o2p(r: dict[str, Any]) -> list[str]:
        t = r.get("osm2pgsql_s")
        return ["–", "–"] if not t else [f"{t:,.2f}", f"{r['stages']['ingest']['s'] / t:.1f}×"]

    out += markdown_table(
        [
            "copies",
            "OSM file MB",
            "buildings",
            "end to end s",
            "buildings/s",
            "database MB",
            "tileset MB",
            "osm2pgsql s",
            "ingest / osm2pgsql",
        ],
        [
            [
                f"×{r['copies']}",
                f"{r['osm_bytes'] / 1e6:,.1f}",
                f"{r['buildings']:,}",
                f"{r['total_s']:,.1f}",
                f"{r['buildings_per_s']:,.0f}",
                f"{r['db_bytes'] / 1e6:,.0f}",
                f"{r['tileset_bytes'] / 1e6:,.1f}",
                *o2p(r),
            ]
            for r in runs
        ],
        "lrrrrrrrr",
    )
    dask = next((r for r in runs if r.get("dask")), None)
    if dask:
        out += [
            "",
            f"Dask ({dask['copies']}×, {dask['buildings']:,} buildings): each stage whose units are Dask "
            "tasks run again on the built database with 1 worker (its units in the stage's own process) and "
            "on a LocalCluster of 2 workers; the stage's own seconds (meta.pipeline_run). The machine has "
            f"{os.cpu_count()} cores, which the database shares.",
            "",
        ]
        out += markdown_table(
            ["stage", "1 worker s", "2 Dask workers s", "speedup"],
            [[st, f"{v['w1_s']:,.1f}", f"{v['w2_s']:,.1f}", f"{v['speedup']:.2f}×"] for st, v in dask["dask"].items()],
            "lrrr",
        )
    worst = max((e[st], st) for e in data["exponents"] for st in STAGES) if data["exponents"] else None
    if worst:
        out += [
            "",
            f"* Largest stage exponent: {worst[1]} {worst[0]:.2f} (target ≤ {EXPONENT_TARGET}); end to end "
            f"{runs[-1]['buildings_per_s']:,.0f} buildings/s at ×{runs[-1]['copies']} (target ≥ "
            f"{THROUGHPUT_TARGET:,.0f}).",
        ]
    return out


def main(argv: list[str] | None = None) -> int:
    from core import cluster

    here = Path(__file__).resolve().parent.parent
    p = argparse.ArgumentParser(prog="python -m benchmarks.scale_bench", description=__doc__.split("\n\n")[0])
    p.add_argument(
        "--extract", type=Path, default=here.parent / "shared" / "data" / "osm" / "liechtenstein_2022-07-24.osm.pbf"
    )
    p.add_argument("--copies", type=int, nargs="+", default=[1, 6])
    p.add_argument("--json", type=Path, help="write the measurements here (bench.py --scale-stages-json reads it)")
    p.add_argument("--keep", action="store_true", help="keep the citylod_scale_xN databases")
    p.add_argument("--no-dask", action="store_true", help="skip the Dask speedup (1 and 2 workers) on the extract")
    args = p.parse_args(argv)
    if not args.extract.exists():
        p.error(f"missing extract {args.extract}")
    cluster.ensure()
    data = measure(args.extract.resolve(), args.copies, cluster.database_url("postgres"), args.keep, not args.no_dask)
    text = json.dumps(data, indent=1)
    if args.json:
        args.json.parent.mkdir(parents=True, exist_ok=True)
        args.json.write_text(text)
    print("\n".join(section(data)))
    return 0


if __name__ == "__main__":
    sys.exit(main())
