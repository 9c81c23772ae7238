"""``python -m exporter export | check | serve``."""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

from etl.settings import REPO


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="python -m exporter", description=__doc__)
    sub = p.add_subparsers(dest="command", required=True)

    ex = sub.add_parser("export", help="write the tileset (the same as python -m etl export)")
    ex.add_argument("--out", default=str(REPO / "build" / "tiles" / "demo"))
    ex.add_argument("--lod", type=int, choices=(1, 2, 3), default=2)

    ck = sub.add_parser("check", help="check a tileset.json against the 3D Tiles 1.1 rules citylod enforces")
    ck.add_argument("tileset", help="path to tileset.json")

    sv = sub.add_parser("serve", help="serve a tileset directory and the CesiumJS viewer")
    sv.add_argument("--dir", default=str(REPO / "build" / "tiles" / "demo"), help="tileset directory")
    sv.add_argument("--host", default="127.0.0.1")
    sv.add_argument("--port", type=int, default=8765)

    args = p.parse_args(argv)
    if args.command == "export":
        from etl.__main__ import main as etl_main

        return etl_main(["export", "--out", args.out, "--lod", str(args.lod)])
    if args.command == "check":
        from .checks import check_tileset

        problems = check_tileset(Path(args.tileset))
        print(json.dumps({"tileset": args.tileset, "errors": problems}, indent=1))
        return 1 if problems else 0
    if args.command == "serve":
        from .serve import serve

        serve(Path(args.dir).resolve(), args.host, args.port)
        return 0
    return 2


if __name__ == "__main__":
    sys.exit(main())
