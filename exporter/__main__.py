"""``python -m exporter export | check | serve``. export and serve are ``python -m etl export | serve`` (one
definition of their options); check is the exporter's own."""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path


def main(argv: list[str] | None = None) -> int:
    argv = sys.argv[1:] if argv is None else argv
    if argv[:1] in (["export"], ["serve"]):
        from etl.__main__ import main as etl_main

        return etl_main(argv)
    p = argparse.ArgumentParser(prog="python -m exporter", description=__doc__)
    sub = p.add_subparsers(dest="command", required=True)
    sub.add_parser("export", help="write the tileset (python -m etl export; its --help lists the options)")
    sub.add_parser("serve", help="serve a tileset and the CesiumJS viewer (python -m etl serve)")
    ck = sub.add_parser("check", help="check a tileset.json against the 3D Tiles 1.1 rules citylod enforces")
    ck.add_argument("tileset", help="path to tileset.json")
    args = p.parse_args(argv)
    from exporter.checks import check_tileset

    problems = check_tileset(Path(args.tileset))
    print(json.dumps({"tileset": args.tileset, "errors": problems}, indent=1))
    return 1 if problems else 0


if __name__ == "__main__":
    sys.exit(main())
