"""Reading an OSM extract for ingest: two streaming passes with pyosmium, node locations in libosmium's index
(never a Python dict):

  A. relations only: type=building relations and their members (outline/part roles);
  B. everything, C++-filtered to objects with building / building:part keys: closed ways become rows with
     their ring as a linestring; multipolygon relations come out of libosmium's area assembler with holes.

Every candidate (a way or multipolygon relation whose building or building:part is not "no") becomes exactly
one row for osm.building_import, a reject row when its geometry cannot be built here (unclosed way, missing
nodes, failed assembly). Pure: a file in, rows out; no database.
"""

from __future__ import annotations

import bz2
import contextlib
import gzip
import html
import json
import re
import struct
from collections.abc import Callable, Iterable, Iterator
from contextlib import AbstractContextManager
from dataclasses import dataclass
from pathlib import Path
from typing import Literal

import osmium
import osmium.geom

from core.settings import Settings
from etl.geom.tags import BuildingTags, building_kind, parse_building_tags

_IMPORT_COLUMNS = (
    "osm_type",
    "osm_id",
    "kind",
    "building",
    "part",
    "name",
    "height",
    "min_height",
    "levels",
    "min_level",
    "roof_levels",
    "roof_height",
    "roof_angle",
    "roof_shape",
    "roof_direction",
    "roof_orientation",
    "building_colour",
    "roof_colour",
    "building_material",
    "roof_material",
    "tags",
    "tag_issues",
    "geom_kind",
    "geom",
    "reject_reason",
    "reject_detail",
)
COPY_IMPORT = f"COPY osm.building_import ({', '.join(_IMPORT_COLUMNS)}) FROM STDIN"

_TYPE_CHAR = {"n": "N", "w": "W", "r": "R"}


@dataclass(frozen=True)
class ChangeIds:
    """The nodes and ways change files create, modify or delete: what an update's ingest reads again
    (read_buildings: a way is staged again when it is one of ``ways`` or uses one of ``nodes``; every relation
    is, whatever the files name)."""

    nodes: frozenset[int]
    ways: frozenset[int]


@dataclass
class IngestCounts:
    candidates: int = 0
    ways: int = 0
    relations: int = 0
    building_relations: int = 0
    nodes_skipped: int = 0


def _row(
    osm_type: str,
    osm_id: int,
    parsed: BuildingTags,
    tags: dict[str, str],
    geom_kind: str | None,
    geom_hex: str | None,
    reject: tuple[str, str] | None = None,
) -> tuple[object, ...]:
    issues = json.dumps([i.as_dict() for i in parsed.issues]) if parsed.issues else None
    return (
        osm_type,
        osm_id,
        parsed.kind,
        parsed.building,
        parsed.part,
        parsed.name,
        parsed.height,
        parsed.min_height,
        parsed.levels,
        parsed.min_level,
        parsed.roof_levels,
        parsed.roof_height,
        parsed.roof_angle,
        parsed.roof_shape,
        parsed.roof_direction,
        parsed.roof_orientation,
        parsed.building_colour,
        parsed.roof_colour,
        parsed.building_material,
        parsed.roof_material,
        json.dumps(tags, ensure_ascii=False),
        issues,
        geom_kind,
        # EWKB hex with SRID 4326, which the geometry column's input function accepts as text.
        None if geom_hex is None else _ewkb_4326(geom_hex),
        reject[0] if reject else None,
        reject[1] if reject else None,
    )


def _ewkb_4326(wkb_hex: str) -> str:
    """Add SRID 4326 to little-endian ISO WKB hex from osmium (sets the EWKB SRID flag on the type)."""
    # byte order (1 byte) + type (uint32 LE); osmium writes little-endian without SRID.
    assert wkb_hex[:2] == "01"
    gtype = int.from_bytes(bytes.fromhex(wkb_hex[2:10]), "little") | 0x20000000
    return "01" + gtype.to_bytes(4, "little").hex() + (4326).to_bytes(4, "little").hex() + wkb_hex[10:]


def read_building_relations(path: Path) -> Iterator[tuple[int, dict[str, str], list[tuple[str, int, str]]]]:
    """Pass A: (relation id, tags, members) of every type=building relation."""
    fp = osmium.FileProcessor(str(path), osmium.osm.RELATION).with_filter(osmium.filter.TagFilter(("type", "building")))
    for rel in fp:
        assert isinstance(rel, osmium.osm.Relation)  # the processor reads relations alone
        members = [(_TYPE_CHAR[m.type], m.ref, m.role) for m in rel.members]
        yield rel.id, {t.k: t.v for t in rel.tags}, members


#: opens an OSM XML file (plain, .gz or .bz2) for its lines as bytes
_Opener = Callable[[Path, Literal["rb"]], AbstractContextManager[Iterable[bytes]]]
_MAX_STRING = 1024  # libosmium's osmium::max_osm_string_length: longer keys, values, roles, user names are refused
_XML_TOKEN = re.compile(rb'<(node|way|relation)\b[^>]*?\bid="(-?\d+)"|\b(k|v|role|user)="([^"]*)"')


def locate_long_string(path: Path) -> str:
    """Where the first string longer than libosmium's limit sits in an OSM XML file (plain, .gz or .bz2): "line
    3, way 7: the value of tag 'note' has 10,000 bytes"; '' for other formats or when none is found. libosmium refuses
    the whole file on such a string without saying where, so the user could not find it to fix or filter it."""
    name = path.name.lower()
    openers: dict[str, _Opener] = {".gz": gzip.open, ".bz2": bz2.open}
    opener = openers.get(path.suffix.lower(), open)
    if not re.search(r"\.(osm|xml|osc)(\.gz|\.bz2)?$", name):
        return ""
    obj, key = "the file header", ""
    with opener(path, "rb") as f:
        for lineno, line in enumerate(f, 1):
            for m in _XML_TOKEN.finditer(line):
                if m[1]:
                    obj, key = f"{m[1].decode()} {m[2].decode()}", ""
                    continue
                attr, raw = m[3].decode(), html.unescape(m[4].decode("utf-8", "replace")).encode()
                if attr == "k" and len(raw) <= _MAX_STRING:
                    key = raw.decode()
                elif len(raw) > _MAX_STRING:
                    what = {
                        "k": "a tag key",
                        "v": f"the value of tag {key!r}",
                        "role": "a member role",
                        "user": "the user name",
                    }[attr]
                    return f"line {lineno}, {obj}: {what} has {len(raw):,} bytes"
    return ""


@contextlib.contextmanager
def reading(path: Path) -> Iterator[None]:
    """libosmium's refusals of the whole file (truncated or corrupt PBF, malformed XML, unknown format: a
    RuntimeError; a string over its limit: a ValueError) as one RuntimeError naming the file, and for a long
    string where and what it is when that can be found."""
    try:
        yield
    except (RuntimeError, ValueError) as e:
        if isinstance(e, ValueError) and "too long" not in str(e):
            raise  # not libosmium's
        msg = f"cannot read {path}: {e}"
        if "too long" in str(e):
            where = locate_long_string(path)
            msg += (
                f" ({where}; libosmium reads at most {_MAX_STRING:,} bytes)"
                if where
                else f" (libosmium reads at most {_MAX_STRING:,} bytes in a key, value, role or user name)"
            )
            msg += ": shorten or drop that tag first (README: bad input)"
        raise RuntimeError(msg) from e


def negative_node_locations(path: Path) -> dict[int, tuple[float, float]]:
    """(lon, lat) of every node with a negative id (JOSM writes unsaved objects so); one pass over the nodes."""
    out: dict[int, tuple[float, float]] = {}
    for n in osmium.FileProcessor(str(path), osmium.osm.NODE):
        assert isinstance(n, osmium.osm.Node)  # the processor reads nodes alone
        if n.id < 0 and n.location.valid():
            out[n.id] = (n.location.lon, n.location.lat)
    return out


def _line_from(nodes: osmium.osm.WayNodeList, negative: dict[int, tuple[float, float]]) -> str | None:
    """The way's linestring as libosmium's WKB hex (little-endian, no SRID), its positive nodes from the
    location index and its negative ones from ``negative``; None when a node is still missing. Consecutive
    repeated nodes are dropped, as libosmium does."""
    coords: list[tuple[float, float]] = []
    for n in nodes:
        if n.location.valid():
            xy = (n.location.lon, n.location.lat)
        elif n.ref in negative:
            xy = negative[n.ref]
        else:
            return None
        if not coords or coords[-1] != xy:
            coords.append(xy)
    if len(coords) < 2:
        return None
    return (
        b"\x01"
        + struct.pack("<II", 2, len(coords))
        + struct.pack(f"<{2 * len(coords)}d", *(c for xy in coords for c in xy))
    ).hex()


class _PassB:
    """Pass B's state: the multipolygon candidates and what libosmium assembled, the nodes of negative id."""

    def __init__(self, path: Path, settings: Settings, counts: IngestCounts, changed: ChangeIds | None) -> None:
        self.path, self.settings, self.counts, self.changed = path, settings, counts, changed
        self.wkb = osmium.geom.WKBFactory()
        self.mp_candidates: dict[int, tuple[BuildingTags, dict[str, str]]] = {}
        self.assembled: set[int] = set()
        self.negative: dict[int, tuple[float, float]] | None = None

    def _parse(self, tags: dict[str, str]) -> BuildingTags | None:
        return parse_building_tags(tags, self.settings.max_height_m, self.settings.max_levels)

    def area(self, obj: osmium.osm.Area) -> Iterator[tuple[object, ...]]:
        if obj.from_way():
            return  # ways are built from their node list (way), so broken ones can be reported
        rid = obj.orig_id()
        tags = {t.k: t.v for t in obj.tags}
        parsed = self._parse(tags)
        if parsed is None:
            return
        self.assembled.add(rid)
        try:
            geom_hex = self.wkb.create_multipolygon(obj)
        except Exception as e:  # noqa: BLE001 - libosmium raises several types; all mean "no geometry"
            yield _reject("R", rid, parsed, tags, "multipolygon_assembly_failed", str(e))
            return
        yield _row("R", rid, parsed, tags, "M", geom_hex)

    def way(self, obj: osmium.osm.Way) -> Iterator[tuple[object, ...]]:
        changed = self.changed
        if changed is not None and obj.id not in changed.ways and changed.nodes.isdisjoint(n.ref for n in obj.nodes):
            return  # as it was: its row stays
        tags = {t.k: t.v for t in obj.tags}
        parsed = self._parse(tags)
        if parsed is None:
            return
        self.counts.candidates += 1
        self.counts.ways += 1
        nodes = obj.nodes
        if len(nodes) < 2 or not obj.is_closed():
            first = nodes[0].ref if len(nodes) else None
            last = nodes[-1].ref if len(nodes) else None
            yield _reject(
                "W", obj.id, parsed, tags, "unclosed_way", f"{len(nodes)} nodes, first node {first} != last node {last}"
            )
            return
        try:
            line = self.wkb.create_linestring(obj)
        except (osmium.InvalidLocationError, RuntimeError) as e:
            yield self._broken_way(obj, parsed, tags, e)
            return
        yield _row("W", obj.id, parsed, tags, "L", line)

    def _broken_way(
        self, obj: osmium.osm.Way, parsed: BuildingTags, tags: dict[str, str], e: Exception
    ) -> tuple[object, ...]:
        """A way libosmium made no linestring of: the nodes are only walked in Python for the rare way that
        needs it; with every node missing libosmium says "need at least two points", as it does for a ring of
        one repeated point."""
        nodes = obj.nodes
        missing = [n.ref for n in nodes if not n.location.valid()]
        if missing and min(missing) < 0:
            # libosmium's location index keeps positive ids only: negative ones (unsaved JOSM data) are looked
            # up in their own table, read from the file the first time a way needs it
            if self.negative is None:
                self.negative = negative_node_locations(self.path)
            line = _line_from(nodes, self.negative)
            if line is not None:
                return _row("W", obj.id, parsed, tags, "L", line)
            missing = [n.ref for n in nodes if not n.location.valid() and n.ref not in self.negative]
        if missing:
            shown = ", ".join(str(r) for r in missing[:10]) + (" …" if len(missing) > 10 else "")
            return _reject(
                "W",
                obj.id,
                parsed,
                tags,
                "missing_nodes",
                f"{len(missing)} of {len(nodes)} nodes not in the file: {shown}",
            )
        # e.g. every node at one spot: no linestring, let alone a ring
        return _reject("W", obj.id, parsed, tags, "degenerate_ring", str(e))

    def relation(self, obj: osmium.osm.Relation) -> Iterator[tuple[object, ...]]:
        tags = {t.k: t.v for t in obj.tags}
        if building_kind(tags) is None:
            return
        rtype = tags.get("type")
        if rtype == "building":
            return  # a grouping relation (pass A), not a geometry
        parsed = self._parse(tags)
        assert parsed is not None
        self.counts.candidates += 1
        self.counts.relations += 1
        if rtype in ("multipolygon", "boundary"):  # the two types libosmium assembles
            self.mp_candidates[obj.id] = (parsed, tags)
        else:
            yield _reject(
                "R",
                obj.id,
                parsed,
                tags,
                "unsupported_relation",
                f"type={rtype!r}: only multipolygon relations have a building geometry",
            )

    def unassembled(self) -> Iterator[tuple[object, ...]]:
        """Multipolygon relations libosmium could not assemble (missing members, rings that do not close, ...)."""
        for rid in sorted(set(self.mp_candidates) - self.assembled):
            parsed, tags = self.mp_candidates[rid]
            yield _reject(
                "R",
                rid,
                parsed,
                tags,
                "multipolygon_assembly_failed",
                "libosmium could not assemble the rings (member ways missing from the file, "
                "or rings that do not close)",
            )
        # areas seen for relations that were not candidates cannot happen (same key filter); keep counts honest
        stray = self.assembled - set(self.mp_candidates)
        if stray:
            raise RuntimeError(f"areas for {len(stray)} relations that were never seen as candidates")


def read_buildings(
    path: Path, settings: Settings, counts: IngestCounts, changed: ChangeIds | None = None
) -> Iterator[tuple[object, ...]]:
    """Pass B: one staging row per candidate building/part; with ``changed`` (a partial update) only the ways it
    names or whose nodes it names, and every relation (libosmium assembles their rings from member ways the
    Python side never sees)."""
    key_filter = osmium.filter.KeyFilter("building", "building:part")
    fp = (
        osmium.FileProcessor(str(path))
        .with_locations(settings.location_index)
        .with_areas(key_filter)
        .with_filter(osmium.filter.KeyFilter("building", "building:part"))
    )
    b = _PassB(path, settings, counts, changed)
    for obj in fp:
        if isinstance(obj, osmium.osm.Area):
            yield from b.area(obj)
        elif isinstance(obj, osmium.osm.Way):
            yield from b.way(obj)
        elif isinstance(obj, osmium.osm.Node):
            counts.nodes_skipped += 1  # building=* on a node has no footprint; not a candidate
        elif isinstance(obj, osmium.osm.Relation):
            yield from b.relation(obj)
    yield from b.unassembled()


def _reject(
    osm_type: str,
    osm_id: int,
    parsed: BuildingTags,
    tags: dict[str, str],
    reason: str,
    detail: str,
) -> tuple[object, ...]:
    return _row(osm_type, osm_id, parsed, tags, None, None, (reason, detail))
