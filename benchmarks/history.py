"""An extract as it was before a date, and the change file that brings it to the extract: OSM's own history,
as far as one extract holds it.

An extract with metadata carries each object's version and timestamp. Every object at version 1 stamped after
``before`` was created after that date, so the extract without those objects, plus a change file that creates
them, is two real states of the area and the real change between them, restricted to creations: objects
modified or deleted since ``before`` are not in the change (an extract holds only their last version), so they
stand in the earlier state as they are now. A node created after ``before`` stays in the earlier state when a
kept way uses it (the way was modified to use it; its earlier node list is unknown).

``python -m benchmarks.history EXTRACT --before 2022-05-07 --base A.osm.pbf --change A-to-B.osc`` writes both.
"""

from __future__ import annotations

import argparse
import datetime as dt
import sys
from pathlib import Path
from xml.sax.saxutils import quoteattr

import osmium


def _tags(tags: osmium.osm.TagList) -> str:
    return "".join(f"<tag k={quoteattr(t.k)} v={quoteattr(t.v)}/>" for t in tags)


def _ts(o: osmium.osm.OSMObject) -> str:
    return o.timestamp.strftime("%Y-%m-%dT%H:%M:%SZ")


class _Scan(osmium.SimpleHandler):
    """Which objects were created after ``before``, and which nodes the other ways use."""

    def __init__(self, before: dt.datetime) -> None:
        super().__init__()
        self.before = before
        self.new_nodes: set[int] = set()
        self.new_ways: set[int] = set()
        self.new_relations: set[int] = set()
        self.used: set[int] = set()  # nodes of the ways that stay

    def _new(self, o: osmium.osm.OSMObject) -> bool:
        return o.version == 1 and o.timestamp > self.before

    def node(self, n: osmium.osm.Node) -> None:
        if self._new(n):
            self.new_nodes.add(n.id)

    def way(self, w: osmium.osm.Way) -> None:
        if self._new(w):
            self.new_ways.add(w.id)
        else:
            self.used.update(r.ref for r in w.nodes)

    def relation(self, r: osmium.osm.Relation) -> None:
        if self._new(r):
            self.new_relations.add(r.id)


class _Split(osmium.SimpleHandler):
    """Writes the kept objects to ``writer`` and the created ones as osmChange XML lines."""

    def __init__(self, writer: osmium.SimpleWriter, nodes: set[int], ways: set[int], relations: set[int]) -> None:
        super().__init__()
        self.writer, self.nodes, self.ways, self.relations = writer, nodes, ways, relations
        self.lines: list[str] = []

    def node(self, n: osmium.osm.Node) -> None:
        if n.id not in self.nodes:
            self.writer.add_node(n)
            return
        self.lines.append(f'<node id="{n.id}" version="1" timestamp="{_ts(n)}" lat="{n.location.lat:.7f}" '
                          f'lon="{n.location.lon:.7f}">{_tags(n.tags)}</node>')

    def way(self, w: osmium.osm.Way) -> None:
        if w.id not in self.ways:
            self.writer.add_way(w)
            return
        self.lines.append(f'<way id="{w.id}" version="1" timestamp="{_ts(w)}">'
                          + "".join(f'<nd ref="{r.ref}"/>' for r in w.nodes) + _tags(w.tags) + "</way>")

    def relation(self, r: osmium.osm.Relation) -> None:
        if r.id not in self.relations:
            self.writer.add_relation(r)
            return
        kinds = {"n": "node", "w": "way", "r": "relation"}
        self.lines.append(f'<relation id="{r.id}" version="1" timestamp="{_ts(r)}">'
                          + "".join(f'<member type="{kinds[m.type]}" ref="{m.ref}" role={quoteattr(m.role)}/>'
                                    for m in r.members) + _tags(r.tags) + "</relation>")


def split(osm: Path, before: dt.datetime, base: Path, change: Path) -> dict[str, int]:
    """Writes ``base`` (``osm`` before ``before``) and ``change`` (its creations since); returns their counts."""
    scan = _Scan(before)
    scan.apply_file(str(osm))
    nodes = scan.new_nodes - scan.used
    base.parent.mkdir(parents=True, exist_ok=True)
    base.unlink(missing_ok=True)
    writer = osmium.SimpleWriter(str(base))
    try:
        s = _Split(writer, nodes, scan.new_ways, scan.new_relations)
        s.apply_file(str(osm))
    finally:
        writer.close()
    change.parent.mkdir(parents=True, exist_ok=True)
    change.write_text("\n".join(['<?xml version="1.0" encoding="UTF-8"?>',
                                 '<osmChange version="0.6" generator="citylod benchmarks.history">', "<create>",
                                 *s.lines, "</create>", "</osmChange>", ""]))
    return {"nodes": len(nodes), "ways": len(scan.new_ways), "relations": len(scan.new_relations)}


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="python -m benchmarks.history", description=__doc__.split("\n\n")[0])
    p.add_argument("osm", type=Path)
    p.add_argument("--before", required=True, type=dt.date.fromisoformat, help="YYYY-MM-DD (UTC midnight)")
    p.add_argument("--base", required=True, type=Path)
    p.add_argument("--change", required=True, type=Path)
    a = p.parse_args(argv)
    made = split(a.osm, dt.datetime.combine(a.before, dt.time(), dt.UTC), a.base, a.change)
    print(f"{a.base}: {a.osm} before {a.before}; {a.change} creates {made}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
