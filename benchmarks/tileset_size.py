"""``python -m benchmarks.tileset_size [--url URL] [--lod N]``: how big tileset.json is, explicit and implicit,
and the implicit tileset's subtree files, from a database's tile records alone (api.tile_tree; no glb is built,
so it takes seconds even on the ~1M bench city, benchmarks/view_bench.py ``citylod_view_1m``).

The bytes are exactly what the export writes and the DB server serves (exporter/export.py tileset_files).
Prints one JSON object.
"""

from __future__ import annotations

import argparse
import json
import time
from typing import Any

from core import cluster
from core.db import connect
from core.tiles3d import read_subtree
from exporter.export import TILESET_JSON, load_records, tileset_files
from exporter.stream import StreamOptions


def measure(url: str, lod: int | None = None) -> dict[str, Any]:
    """Sizes of the tilesets the tile tree at ``url`` makes (``lod``: a single-LOD tileset)."""
    t0 = time.perf_counter()
    with connect(url) as conn:
        records = load_records(conn)
        t_read = time.perf_counter() - t0
        out: dict[str, Any] = {
            "tiles": len(records),
            "leaves": sum(r.is_leaf for r in records),
            "levels": max(r.level for r in records) + 1,
            "buildings": sum(r.n_features for r in records if r.is_leaf),
            "lod": lod or "all",
            "read_seconds": round(t_read, 2),
        }
        for tiling in ("explicit", "implicit"):
            t = time.perf_counter()
            files = tileset_files(conn, records, lod, StreamOptions(tiling=tiling))
            out[f"{tiling}_seconds"] = round(time.perf_counter() - t, 2)
            out[f"{tiling}_tileset_json_bytes"] = len(files[TILESET_JSON])
    subtrees = {u: b for u, b in files.items() if u != TILESET_JSON}
    implicit = json.loads(files[TILESET_JSON])["root"]["implicitTiling"]
    out.update(
        subtree_levels=implicit["subtreeLevels"],
        subtrees=len(subtrees),
        subtree_bytes=sum(len(b) for b in subtrees.values()),
        largest_subtree_bytes=max(len(b) for b in subtrees.values()),
        subtree_tiles=sum(read_subtree(b).json["tileAvailability"]["availableCount"] for b in subtrees.values()),
    )
    return out


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--url", default=None, help="database (default: DATABASE_URL, else the local cluster)")
    ap.add_argument("--lod", type=int, choices=(1, 2, 3), default=None, help="a single-LOD tileset")
    args = ap.parse_args(argv)
    print(json.dumps(measure(args.url or cluster.ensure(), args.lod)))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
