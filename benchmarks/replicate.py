"""N shifted copies of a real OSM extract, written as one valid, sorted OSM file (the scale bench's input).

    python -m benchmarks.replicate EXTRACT.osm.pbf N OUT.osm.pbf

Copy k (0 ≤ k < N) is the whole extract (every node, way and relation, tags and all) moved by a whole number
of the extract's own extents on a near-square grid, so copies never overlap and real shapes stay real; every
id of copy k is offset by k × step, where step is the smallest power of ten above the largest id in the file
(recent extracts have node ids above 10^10), and every reference (way nodes, relation members) follows its
copy. The output is sorted as OSM files are (nodes, then ways, then relations, each by id): the file is
streamed once per object type and copy, so memory stays flat whatever N.
"""

from __future__ import annotations

import argparse
import math
import sys
import time
from dataclasses import dataclass
from pathlib import Path

import osmium
import osmium.osm

# Space between copies, as a share of the extract's extent: copies stay separate cities.
GAP = 0.05


@dataclass(frozen=True)
class Layout:
    """Where copy k goes: its id offset and its shift in degrees."""

    step: int
    columns: int
    dlon: float
    dlat: float

    def offset(self, k: int) -> int:
        return k * self.step

    def shift(self, k: int) -> tuple[float, float]:
        return (k % self.columns) * self.dlon, (k // self.columns) * self.dlat


def id_step(max_id: int) -> int:
    """The smallest power of ten above max_id: copy k's ids read as k followed by the original id."""
    return 10 ** len(str(max(max_id, 1)))


def layout(max_id: int, bounds: tuple[float, float, float, float], n: int) -> Layout:
    """Copies on a near-square grid of the extract's extent (w, s, e, n in degrees) plus GAP."""
    w, s, e, nn = bounds
    columns = max(1, math.ceil(math.sqrt(n)))
    rows = math.ceil(n / columns)
    dlon = (e - w) * (1 + GAP)
    dlat = (nn - s) * (1 + GAP)
    # The last row and column must stay on the globe (a Mercator-safe latitude and the antimeridian).
    if e + (columns - 1) * dlon > 180.0 or nn + (rows - 1) * dlat > 85.0:
        raise ValueError(
            f"{n} copies of an extract {e - w:.3f}° × {nn - s:.3f}° at ({w:.3f}, {s:.3f}) "
            "do not fit east and north of it on the globe"
        )
    return Layout(id_step(max_id), columns, dlon, dlat)


def scan(path: Path) -> tuple[int, tuple[float, float, float, float]]:
    """Largest id of any object and the bounds of every node (one pass)."""
    max_id = 0
    w = s = math.inf
    e = n = -math.inf
    for obj in osmium.FileProcessor(str(path)):
        max_id = max(max_id, abs(obj.id))
        if obj.is_node() and obj.location.valid():
            lon, lat = obj.location.lon, obj.location.lat
            w, e = min(w, lon), max(e, lon)
            s, n = min(s, lat), max(n, lat)
    if w == math.inf:
        raise ValueError(f"{path}: no node with a location")
    return max_id, (w, s, e, n)


def _shift_ref(ref: int, off: int) -> int:
    # negative ids (unsaved JOSM data) move away from zero, so they keep their sign and their order
    return ref - off if ref < 0 else ref + off


def replicate(src: Path, n: int, dst: Path) -> dict[str, float]:
    """Write n copies of src to dst; returns counts per type and the seconds it took."""
    if n < 1:
        raise ValueError("n must be at least 1")
    t0 = time.perf_counter()
    max_id, bounds = scan(src)
    lay = layout(max_id, bounds, n)
    if dst.exists():
        dst.unlink()
    counts = {"nodes": 0, "ways": 0, "relations": 0}
    writer = osmium.SimpleWriter(str(dst))
    try:
        for k in range(n):
            off = lay.offset(k)
            dx, dy = lay.shift(k)
            for node in osmium.FileProcessor(str(src), osmium.osm.NODE):
                loc = node.location
                writer.add_node(
                    node.replace(
                        id=_shift_ref(node.id, off),
                        location=(loc.lon + dx, loc.lat + dy) if loc.valid() else loc,
                    )
                )
                counts["nodes"] += 1
        for k in range(n):
            off = lay.offset(k)
            for way in osmium.FileProcessor(str(src), osmium.osm.WAY):
                writer.add_way(
                    way.replace(id=_shift_ref(way.id, off), nodes=[_shift_ref(r.ref, off) for r in way.nodes])
                )
                counts["ways"] += 1
        for k in range(n):
            off = lay.offset(k)
            for rel in osmium.FileProcessor(str(src), osmium.osm.RELATION):
                writer.add_relation(
                    rel.replace(
                        id=_shift_ref(rel.id, off),
                        members=[(m.type, _shift_ref(m.ref, off), m.role) for m in rel.members],
                    )
                )
                counts["relations"] += 1
    finally:
        writer.close()
    return {**counts, "copies": n, "id_step": lay.step, "seconds": round(time.perf_counter() - t0, 2)}


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("extract", type=Path)
    ap.add_argument("copies", type=int)
    ap.add_argument("out", type=Path)
    args = ap.parse_args(argv)
    r = replicate(args.extract, args.copies, args.out)
    print(
        f"{args.out}: {r['copies']} copies, {r['nodes']:,} nodes, {r['ways']:,} ways, "
        f"{r['relations']:,} relations, id step {r['id_step']:,}, {r['seconds']} s",
        file=sys.stderr,
    )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
