"""The exporter's command-line pieces: the stream options every command that writes or serves tiles takes, and
the ``serve`` and ``check`` commands. ``python -m exporter serve | check`` and ``python -m etl`` (which adds the
stages and ``export`` around them) share these definitions."""

from __future__ import annotations

import argparse
import json
import os
import sys
from collections.abc import Callable
from pathlib import Path

from core import cluster
from core.settings import REPO, Settings
from exporter.stream import GEOMETRY, TABLES, TEXTURES, TILING, StreamOptions

DEFAULT_OUT = REPO / "build" / "tiles" / "demo"


def stream_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument(
        "--geometry",
        choices=GEOMETRY,
        default=GEOMETRY[0],
        help="compact: quantized, meshopt-compressed (KHR_mesh_quantization, KHR_meshopt_compression); "
        "compact-ext: the same through EXT_meshopt_compression, for loaders without the KHR one; "
        "plain: float32 (default: %(default)s)",
    )
    p.add_argument(
        "--textures",
        choices=TEXTURES,
        default=TEXTURES[0],
        help="ktx2: Basis Universal with mipmaps (KHR_texture_basisu); webp: EXT_texture_webp (default: %(default)s)",
    )
    p.add_argument(
        "--tiling",
        choices=TILING,
        default=TILING[0],
        help="implicit: implicitTiling with subtree files; explicit: every tile in tileset.json (default: %(default)s)",
    )
    p.add_argument(
        "--tables",
        choices=TABLES,
        default=TABLES[0],
        help="compact geometry's property tables: plain, readable without a meshopt decoder (the 3D Tiles "
        "validator); meshopt: compressed like the geometry (default: %(default)s)",
    )


def stream_options(args: argparse.Namespace) -> StreamOptions:
    return StreamOptions(geometry=args.geometry, textures=args.textures, tiling=args.tiling, tables=args.tables)


def serve_arguments(srv: argparse.ArgumentParser) -> None:
    src = srv.add_mutually_exclusive_group()
    src.add_argument("--dir", default=str(DEFAULT_OUT), help="tileset directory")
    src.add_argument(
        "--db",
        action="store_true",
        help="stream the tileset published into the database by export (the live generation of "
        "--tileset; a rebuild or a new export never interrupts it), as the read-only role "
        "citylod_reader: CITYLOD_READER_URL, else DATABASE_URL / the local cluster with that user",
    )
    srv.add_argument(
        "--tileset",
        default="demo",
        help="with --db: the published tileset's name (export's --publish; default: %(default)s, the "
        "name of the default output directory)",
    )
    srv.add_argument(
        "--live",
        action="store_true",
        help="with --db: build tileset.json and each glb on request from the stage tables instead "
        "(cached; no export needed, but answered 503 while a stage rebuilds them)",
    )
    srv.add_argument(
        "--lod",
        type=int,
        choices=(1, 2, 3),
        default=None,
        help="with --db --live: one level of detail for every building, as `export --lod` (default: "
        "the generalized hierarchy)",
    )
    stream_arguments(srv)
    srv.add_argument("--cache-mb", type=float, default=256.0, help="with --db: tile cache budget (MiB)")
    srv.add_argument("--host", default="127.0.0.1")
    srv.add_argument("--port", type=int, default=8765, help="0 picks a free port")


SERVE_HELP = (
    "serve the tileset (a directory, or --db straight from the database) and the CesiumJS viewer (Ctrl-C stops)"
)


def serve(args: argparse.Namespace, settings: Settings) -> int:
    if args.db:
        from exporter.serve.reader import reader_url
        from exporter.serve.run import serve_db, serve_published

        url, cache_bytes = reader_url(cluster.ensure(settings)), int(args.cache_mb * 2**20)
        if args.live:
            serve_db(
                url,
                args.host,
                args.port,
                lod=args.lod,
                stream=stream_options(args),
                base_height=settings.base_height_m,
                cache_bytes=cache_bytes,
            )
            return 0
        if args.lod is not None:
            print("serve: --lod needs --live (a published tileset holds the LOD it was exported with)", file=sys.stderr)
            return 2
        serve_published(url, args.tileset, args.host, args.port, cache_bytes=cache_bytes)
        return 0
    if args.lod is not None or args.live:
        print(
            "serve: --lod and --live need --db (a tileset directory holds the LOD it was exported with)",
            file=sys.stderr,
        )
        return 2
    from exporter.serve.run import serve as serve_dir

    serve_dir(Path(args.dir).resolve(), args.host, args.port)
    return 0


def check(args: argparse.Namespace, settings: Settings) -> int:
    from exporter.checks import check_tileset

    problems = check_tileset(Path(args.tileset))
    print(json.dumps({"tileset": args.tileset, "errors": problems}, indent=1))
    return 1 if problems else 0


def guarded(command: str, call: Callable[[], int], note: Callable[[], str] = lambda: "") -> int:
    """``call()``'s exit code; an error as one clear line for users (``note()`` may add a line), Ctrl-C as 130.
    CITYLOD_DEBUG=1 shows the traceback instead."""
    try:
        return int(call())
    except KeyboardInterrupt:
        print(f"{command}: interrupted", file=sys.stderr)
        return 130
    except Exception as e:  # noqa: BLE001 - one clear line for users; CITYLOD_DEBUG=1 shows the traceback
        if os.environ.get("CITYLOD_DEBUG") == "1":
            raise
        print(f"{command}: error: {e}", file=sys.stderr)
        print(f"  ({note() or ''}{'; ' if note() else ''}CITYLOD_DEBUG=1 shows the traceback)", file=sys.stderr)
        return 1
