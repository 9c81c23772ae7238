"""``python -m exporter serve | check``: serve a tileset and the viewer, or check a tileset.json against the
3D Tiles 1.1 rules citylod enforces. The export itself is a stage: ``python -m etl export`` (make export), which
records its run."""

from __future__ import annotations

import argparse
import sys

from core.settings import Settings
from exporter import cli


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="python -m exporter", description=__doc__)
    sub = p.add_subparsers(dest="command", required=True)
    srv = sub.add_parser("serve", help=cli.SERVE_HELP)
    cli.serve_arguments(srv)
    srv.set_defaults(fn=cli.serve)
    ck = sub.add_parser("check", help="check a tileset.json against the 3D Tiles 1.1 rules citylod enforces")
    ck.add_argument("tileset", help="path to tileset.json")
    ck.set_defaults(fn=cli.check)
    args = p.parse_args(argv)
    return cli.guarded(args.command, lambda: args.fn(args, Settings.from_env()))


if __name__ == "__main__":
    sys.exit(main())
