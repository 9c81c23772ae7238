"""An extract as it was before a date, and the change file that brings it to the extract: OSM's own history,
as far as one extract holds it.

An extract with metadata carries each object's version and timestamp. Every object at version 1 stamped after
``before`` was created after that date, so the extract without those objects, plus a change file that creates
them, is two real states of the area and the real change between them, restricted to creations: objects
modified or deleted since ``before`` are not in the change (an extract holds only their last version), so they
stand in the earlier state as they are now. A node created after ``before`` stays in the earlier state when a
kept way uses it (the way was modified to use it; its earlier node list is unknown).

``python -m tests.support.history EXTRACT --before 2022-05-07 --base A.osm.pbf --change A-to-B.osc`` writes both.

A *history* file (every version of every object, deleted ones with visible="false", as the API's
``/history`` calls and .osh files give them) holds more: the area as it stood at any moment (each object's last
version stamped by then, unless that version deletes it; states()) and the real change between two moments,
with its creations, modifications and deletions (changes()): ``python -m tests.support.history HISTORY.osh --history
--before 2014-10-01 --to 2016-12-31 --base A.osm --change A-to-B.osc`` (an .osh of an area: ``osmium extract
--with-history`` of a history planet).
"""

from __future__ import annotations

import argparse
import datetime as dt
import hashlib
import io
import os
import sys
import urllib.request
import zipfile
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


_KINDS = {"n": "node", "w": "way", "r": "relation"}


def _xml(o: osmium.osm.OSMObject, kind: str) -> str:
    """``o`` as an OSM XML element (its id, version, timestamp, and location, node list or members)."""
    head = f'<{_KINDS[kind]} id="{o.id}" version="{o.version}" timestamp="{_ts(o)}"'
    if kind == "n":
        return f'{head} lat="{o.location.lat:.7f}" lon="{o.location.lon:.7f}">{_tags(o.tags)}</node>'
    if kind == "w":
        return head + ">" + "".join(f'<nd ref="{r.ref}"/>' for r in o.nodes) + _tags(o.tags) + "</way>"
    return (
        head
        + ">"
        + "".join(f'<member type="{_KINDS[m.type]}" ref="{m.ref}" role={quoteattr(m.role)}/>' for m in o.members)
        + _tags(o.tags)
        + "</relation>"
    )


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
        self.lines.append(_xml(n, "n"))  # created: version 1

    def way(self, w: osmium.osm.Way) -> None:
        if w.id not in self.ways:
            self.writer.add_way(w)
            return
        self.lines.append(_xml(w, "w"))

    def relation(self, r: osmium.osm.Relation) -> None:
        if r.id not in self.relations:
            self.writer.add_relation(r)
            return
        self.lines.append(_xml(r, "r"))


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
    change.write_text(
        "\n".join(
            [
                '<?xml version="1.0" encoding="UTF-8"?>',
                '<osmChange version="0.6" generator="citylod tests.support.history">',
                "<create>",
                *s.lines,
                "</create>",
                "</osmChange>",
                "",
            ]
        )
    )
    return {"nodes": len(nodes), "ways": len(scan.new_ways), "relations": len(scan.new_relations)}


#: A real history file: every version (2007-2016) of an associatedStreet relation in Oakland, California (Broadway,
#: relation 4017808) and of its members and their nodes, buildings among them; OpenStreetMap data (ODbL), test data
#: of the Go module github.com/paulmach/osm, fetched from the Go module proxy (fetch_history), never committed here
HISTORY_MODULE = "github.com/paulmach/osm/@v/v0.8.0.zip"
HISTORY_MODULE_SHA256 = "20c840390b139a0f21db4900cd29e08d92b9268ecc7bdc57d739dddb465b6c36"
HISTORY_MEMBER = "github.com/paulmach/osm@v0.8.0/annotate/testdata/relation_4017808.osm"
HISTORY_SHA256 = "0e8c0e4afac3de4711a79f248c4e12f9f797ba8e45bcf141b0413dcee72aa0ee"


def fetch_history(dest: Path) -> Path:
    """HISTORY_MEMBER, unzipped to ``dest`` from the module zip (11 MB) the Go module proxy serves (the first one
    of $GOPROXY, else proxy.golang.org); both sha256s are pinned, so a changed upstream file is noticed."""
    if dest.exists() and hashlib.sha256(dest.read_bytes()).hexdigest() == HISTORY_SHA256:
        return dest
    proxies = [p for p in os.environ.get("GOPROXY", "").replace("|", ",").split(",") if p.startswith("http")]
    url = f"{(proxies or ['https://proxy.golang.org'])[0].rstrip('/')}/{HISTORY_MODULE}"
    with urllib.request.urlopen(url, timeout=120) as r:  # noqa: S310 -- a pinned https URL
        data = r.read()
    if hashlib.sha256(data).hexdigest() != HISTORY_MODULE_SHA256:
        raise RuntimeError(f"{url} does not have the pinned sha256 {HISTORY_MODULE_SHA256}")
    member = zipfile.ZipFile(io.BytesIO(data)).read(HISTORY_MEMBER)
    if hashlib.sha256(member).hexdigest() != HISTORY_SHA256:
        raise RuntimeError(f"{HISTORY_MEMBER} in {url} does not have the pinned sha256 {HISTORY_SHA256}")
    dest.parent.mkdir(parents=True, exist_ok=True)
    part = dest.with_name(dest.name + ".part")
    part.write_bytes(member)
    part.replace(dest)
    return dest


#: One version of an object: (version, timestamp, visible, XML)
Version = tuple[int, dt.datetime, bool, str]
#: An object of a history file: (type "n"|"w"|"r", id) -> its versions, by version
History = dict[tuple[str, int], list[Version]]


def read_history(path: Path) -> History:
    """Every version of every object of the history file ``path`` (in any order), sorted by version."""
    out: History = {}
    for o in osmium.FileProcessor(str(path)):
        kind = "n" if o.is_node() else "w" if o.is_way() else "r"
        out.setdefault((kind, o.id), []).append((o.version, o.timestamp, o.visible, _xml(o, kind) if o.visible else ""))
    for versions in out.values():
        versions.sort()
    return out


def _at(versions: list[Version], when: dt.datetime) -> Version | None:
    """The version in force at ``when``, None before the object existed."""
    return next((v for v in reversed(versions) if v[1] <= when), None)


def _order(key: tuple[str, int]) -> tuple[int, int]:
    return ("nwr".index(key[0]), key[1])


def states(history: History, when: dt.datetime, out: Path) -> int:
    """Writes ``out`` (OSM XML, objects sorted by type and id): the area as it stood at ``when``; returns how
    many objects it holds."""
    rows = []
    for key in sorted(history, key=_order):
        now = _at(history[key], when)
        if now is not None and now[2]:
            rows.append(now[3])
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(
        "\n".join(
            [
                '<?xml version="1.0" encoding="UTF-8"?>',
                '<osm version="0.6" generator="citylod tests.support.history">',
                *rows,
                "</osm>",
                "",
            ]
        )
    )
    return len(rows)


def changes(history: History, start: dt.datetime, end: dt.datetime, out: Path) -> dict[str, dict[str, int]]:
    """Writes ``out``, the osmChange document that brings the area from ``start`` to ``end``: an object that
    appeared is created, one whose version changed is modified (to the version in force at ``end``), one that
    disappeared is deleted (by the version that deleted it). Returns the counts by action and type."""
    acts: dict[str, list[str]] = {"create": [], "modify": [], "delete": []}
    for key in sorted(history, key=_order):
        a, b = _at(history[key], start), _at(history[key], end)
        was = a is not None and a[2]
        now = b is not None and b[2]
        if now and not was:
            acts["create"].append(b[3])  # type: ignore[index]
        elif now and was and a[0] != b[0]:  # type: ignore[index]
            acts["modify"].append(b[3])  # type: ignore[index]
        elif was and not now:  # b is the version that deleted it
            kind, oid = key
            acts["delete"].append(
                f'<{_KINDS[kind]} id="{oid}" version="{b[0]}" '  # type: ignore[index]
                f'timestamp="{b[1].strftime("%Y-%m-%dT%H:%M:%SZ")}"/>'
            )  # type: ignore[index]
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(
        "\n".join(
            [
                '<?xml version="1.0" encoding="UTF-8"?>',
                '<osmChange version="0.6" generator="citylod tests.support.history">',
                *(f"<{a}>\n" + "\n".join(rows) + f"\n</{a}>" for a, rows in acts.items() if rows),
                "</osmChange>",
                "",
            ]
        )
    )
    return {
        a: {_KINDS[k]: sum(1 for r in rows if r.startswith(f"<{_KINDS[k]} ")) for k in _KINDS}
        for a, rows in acts.items()
    }


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="python -m tests.support.history", description=__doc__.split("\n\n")[0])
    p.add_argument("osm", type=Path, help="an extract with metadata, or with --history a history file")
    p.add_argument("--before", type=dt.date.fromisoformat, help="YYYY-MM-DD (UTC midnight): the extract before it")
    p.add_argument("--base", required=True, type=Path, help="the earlier state (an .osm file with --history)")
    p.add_argument("--change", required=True, type=Path, help="the change from it to the extract or --to")
    p.add_argument(
        "--history",
        action="store_true",
        help="OSM is a history file: --base is the state at --before, --change the change to --to",
    )
    p.add_argument("--to", type=dt.date.fromisoformat, help="with --history: YYYY-MM-DD (UTC midnight)")
    a = p.parse_args(argv)
    if a.before is None or a.history and a.to is None:
        p.error("--before is required, and --to with --history")
    start = dt.datetime.combine(a.before, dt.time(), dt.UTC)
    if a.history:
        h = read_history(a.osm)
        n = states(h, start, a.base)
        made = changes(h, start, dt.datetime.combine(a.to, dt.time(), dt.UTC), a.change)
        print(f"{a.base}: {n:,} objects of {a.osm} on {a.before}; {a.change} to {a.to}: {made}")
        return 0
    made = split(a.osm, start, a.base, a.change)
    print(f"{a.base}: {a.osm} before {a.before}; {a.change} creates {made}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
