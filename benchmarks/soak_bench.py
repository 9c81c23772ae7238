"""``python -m benchmarks.soak_bench``: ``serve --db`` under the soak client (tests/support/soak.py, 200 requests per
second) while every stage rebuilds the benchmark extract's database and the export publishes a new generation.

1. a fresh database with the pipeline on the extract (ingest ... textures) and an export that publishes it;
2. the export's cost of publishing: the same export with ``--no-publish`` and again with publishing (now every blob
   is in the database already, so only the listing is written);
3. ``python -m etl serve --db`` in its own process, the soak client on a thread of this one, and a watcher that
   samples pg_stat_activity every 10 ms for a server connection waiting on a lock; then ingest (from the same
   file), lod, landmarks, tiles, generalize, textures and export run again, one after the other, as ``make``
   would after a change to the file.

``--json PATH`` writes the figures; ``--write BENCHMARKS.md`` replaces its "## Soak" section with them
(``python -m benchmarks.bench --soak-json PATH`` renders the same section in a full report).
"""

from __future__ import annotations

import os
import sys
import threading
import time
from pathlib import Path
from typing import Any

import psycopg

from benchmarks.common import (
    LOG_DIR,
    OUT_ROOT,
    PIPELINE,
    build_pipeline_db,
    extract_name,
    last_run,
    log,
    markdown_table,
    run_child,
    section_bench,
)
from exporter.publish import tileset_name
from exporter.serve.reader import READER_ROLE
from tests.support.servers import spawned
from tests.support.soak import RATE, soak

SOAK_DB = "citylod_bench_soak"
DEFAULT_OSM = Path(__file__).resolve().parents[2] / "shared" / "data" / "osm" / "liechtenstein_2022-07-24.osm.pbf"


def measure(osm: Path, admin_url: str, db: str = SOAK_DB, rate: float = RATE) -> dict[str, Any]:
    name = extract_name(osm)
    url = build_pipeline_db(osm, admin_url, db, "soak")
    env = {**os.environ, "DATABASE_URL": url}
    env.pop("CITYLOD_READER_URL", None)
    logs = LOG_DIR / name / "soak"
    out = OUT_ROOT / "soak" / tileset_name(Path(name))
    export = [sys.executable, "-m", "etl", "export", "--out", str(out)]

    def export_s(*extra: str, tag: str) -> tuple[float, dict[str, Any]]:
        run_child([*export, *extra], env, logs / f"export-{tag}.log")
        counts, seconds = last_run(url, "export")
        return float(seconds or 0.0), counts

    log(f"{name}: export and publish")
    first_s, first = export_s(tag="first")
    plain_s, _ = export_s("--no-publish", tag="no-publish")
    again_s, again = export_s(tag="again")

    dbname = psycopg.conninfo.conninfo_to_dict(url)["dbname"]
    phases: dict[str, dict[str, Any]] = {}
    with spawned(["etl", "serve", "--db", "--tileset", out.name, "--port", "0"], env, timeout=120) as (base, _, _e):

        def rebuild() -> dict[str, float]:
            stages: dict[str, float] = {}
            for stage in (*PIPELINE, "export"):
                log(f"{name}: {stage} under load")
                extra = ["--osm", str(osm)] if stage == "ingest" else ["--out", str(out)] if stage == "export" else []
                stages[stage] = round(
                    run_child([sys.executable, "-m", "etl", stage, *extra], env, logs / f"rebuild-{stage}.log")[0], 1
                )
            return stages

        def update() -> dict[str, float]:
            from benchmarks.update_bench import write_change

            change = OUT_ROOT / "soak" / f"{name}-1pct.osc"
            write_change(osm, change)
            log(f"{name}: update under load")
            return {
                "update": round(
                    run_child(
                        [sys.executable, "-m", "etl", "update", "--osc", str(change), "--out", str(out)],
                        env,
                        logs / "update.log",
                    )[0],
                    1,
                )
            }

        for phase, action in (("rebuild", rebuild), ("update", update)):
            phases[phase] = _under_load(base, url, dbname, rate, action)
    return {
        "extract": name,
        "rate": rate,
        **phases,
        "publish": {
            "export_s": round(first_s, 2),
            "export_no_publish_s": round(plain_s, 2),
            "export_again_s": round(again_s, 2),
            "files": first.get("published_files"),
            "bytes": first.get("published_bytes"),
            "again_new_files": again.get("published_new_files"),
            "again_new_bytes": again.get("published_new_bytes"),
        },
    }


def _under_load(base: str, url: str, dbname: str, rate: float, action: Any) -> dict[str, Any]:
    """``action()`` (the stages' seconds) while the soak client asks ``base`` for tiles and a watcher samples the
    server's connections for lock waits; then the client's figures."""
    waits: list[tuple[str, str]] = []
    samples = [0]
    stop = threading.Event()
    result: dict[str, Any] = {}

    def watch() -> None:
        with psycopg.connect(url, autocommit=True) as admin:
            while not stop.is_set():
                waits.extend(
                    admin.execute(
                        "SELECT wait_event, query FROM pg_stat_activity WHERE usename = %s AND datname = %s "
                        "AND wait_event_type = 'Lock'",
                        (READER_ROLE, dbname),
                    ).fetchall()
                )
                samples[0] += 1
                time.sleep(0.01)

    def client() -> None:
        result["soak"] = soak(base, stop, rate)

    threads = [threading.Thread(target=watch), threading.Thread(target=client)]
    for t in threads:
        t.start()
    t0 = time.perf_counter()
    try:
        stages = action()
        time.sleep(2 * 2.0)  # the client re-reads tileset.json every 2 s
    finally:
        stop.set()
        for t in threads:
            t.join(120)
    return {
        "seconds": round(time.perf_counter() - t0, 1),
        "stages_s": stages,
        "soak": result["soak"].as_dict(),
        "lock_waits": len(waits),
        "lock_samples": samples[0],
        "lock_examples": [list(w) for w in waits[:3]],
    }


def section(s: dict[str, Any] | None) -> list[str]:
    if not s:
        return []
    p = s["publish"]
    out = [
        "## Soak: serving while the database is rebuilt and updated",
        "",
        f"`python -m etl serve --db` (the tileset the export published into `pub.*`) under the soak client "
        f"(tests/support/soak.py: {s['rate']:.0f} requests/s, open loop, 16 keep-alive connections, every third a "
        f"revalidation) while every stage and the export ran again on {s['extract']}, then while `python -m "
        "etl update` applied a change file touching 1 % of its buildings (benchmarks/update_bench.py writes "
        "it) and published again. Command: `python -m benchmarks.soak_bench --write BENCHMARKS.md`. Target: "
        "0 responses 5xx or 503, no server connection waiting on a lock over 100 ms.",
        "",
    ]
    rows = []
    for phase in ("rebuild", "update"):
        if phase not in s:
            continue
        f = s[phase]
        k = f["soak"]
        statuses = ", ".join(f"{n:,} × {code}" for code, n in k["statuses"].items())
        rows.append(
            [
                f"{'full rebuild' if phase == 'rebuild' else 'update'} ({f['seconds']:.0f} s)",
                f"{k['requests']:,}",
                statuses,
                k["failures"],
                k["bad_etags"],
                k["p50_ms"],
                k["p99_ms"],
                k["max_ms"],
                f"{f['lock_waits']} in {f['lock_samples']:,} samples",
            ]
        )
    out += markdown_table(
        [
            "during",
            "requests",
            "answers",
            "5xx + errors",
            "body ≠ ETag",
            "p50 ms",
            "p99 ms",
            "max ms",
            "lock waits seen",
        ],
        rows,
        "lrllrrrrl",
    )
    out += [
        "",
        "Latencies are wall clock on the machine above, the client, the server and the stages sharing its "
        "cores; a lock wait is a server connection seen in pg_stat_activity with wait_event_type Lock, sampled "
        "every 10 ms.",
        "",
    ]
    if "rebuild" in s:
        out += [
            "Stages under load (s): " + ", ".join(f"{st} {v}" for st, v in s["rebuild"]["stages_s"].items()) + ".",
            "",
        ]
    out += [
        f"Publishing: the export with it {p['export_s']} s, without (`--no-publish`) {p['export_no_publish_s']} s "
        f"({p['files']:,} files, {p['bytes'] / 1e6:.1f} MB stored once by content); the same export again "
        f"{p['export_again_s']} s, storing {p['again_new_files']} new files ({p['again_new_bytes']:,} bytes): "
        "an unchanged tile keeps its blob and its ETag.",
        "",
    ]
    return out


def main(argv: list[str] | None = None) -> int:
    return section_bench(
        argv, "python -m benchmarks.soak_bench", __doc__ or "", DEFAULT_OSM, SOAK_DB, measure, section, "## Soak"
    )


if __name__ == "__main__":
    raise SystemExit(main())
