"""Stage ingest: an OSM extract (.osm.pbf / .osm) into osm.building, osm.reject and osm.building_relation.

Two streaming passes with pyosmium, node locations in libosmium's index (never a Python dict):
  A. relations only: type=building relations and their members (outline/part roles);
  B. everything, C++-filtered to objects with building / building:part keys: closed ways become rows with
     their ring as a linestring; multipolygon relations come out of libosmium's area assembler with holes.
Every candidate (a way or multipolygon relation whose building or building:part is not "no") becomes exactly
one COPY row into osm.building_import, a reject row when its geometry cannot be built in Python (unclosed
way, missing nodes, failed assembly). osm.finish_ingest() then builds, repairs and links set-based in SQL.
The whole stage is one transaction: re-running it on the same file gives the same database.
"""

from __future__ import annotations

import bz2
import contextlib
import gzip
import html
import json
import re
import struct
import sys
import time
from collections.abc import Callable, Iterable, Iterator
from dataclasses import dataclass
from pathlib import Path

import osmium
import osmium.geom
import psycopg

from core.progress import Balance, Progress, summary
from core.settings import Settings
from etl.geom.tags import BuildingTags, building_kind, parse_building_tags

_IMPORT_COLUMNS = (
    "osm_type", "osm_id", "kind", "building", "part", "name", "height", "min_height", "levels", "min_level",
    "roof_levels", "roof_height", "roof_angle", "roof_shape", "roof_direction", "roof_orientation",
    "building_colour", "roof_colour", "building_material", "roof_material", "tags", "tag_issues",
    "geom_kind", "geom", "reject_reason", "reject_detail",
)
_COPY_IMPORT = f"COPY osm.building_import ({', '.join(_IMPORT_COLUMNS)}) FROM STDIN"

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
        osm_type, osm_id, parsed.kind, parsed.building, parsed.part, parsed.name, parsed.height,
        parsed.min_height, parsed.levels, parsed.min_level, parsed.roof_levels, parsed.roof_height,
        parsed.roof_angle, parsed.roof_shape, parsed.roof_direction, parsed.roof_orientation,
        parsed.building_colour, parsed.roof_colour, parsed.building_material, parsed.roof_material,
        json.dumps(tags, ensure_ascii=False), issues, geom_kind,
        # EWKB hex with SRID 4326, which the geometry column's input function accepts as text.
        None if geom_hex is None else _ewkb_4326(geom_hex),
        reject[0] if reject else None, reject[1] if reject else None,
    )


def _ewkb_4326(wkb_hex: str) -> str:
    """Add SRID 4326 to little-endian ISO WKB hex from osmium (sets the EWKB SRID flag on the type)."""
    # byte order (1 byte) + type (uint32 LE); osmium writes little-endian without SRID.
    assert wkb_hex[:2] == "01"
    gtype = int.from_bytes(bytes.fromhex(wkb_hex[2:10]), "little") | 0x20000000
    return "01" + gtype.to_bytes(4, "little").hex() + (4326).to_bytes(4, "little").hex() + wkb_hex[10:]


def read_building_relations(path: Path) -> Iterator[tuple[int, dict[str, str], list[tuple[str, int, str]]]]:
    """Pass A: (relation id, tags, members) of every type=building relation."""
    fp = osmium.FileProcessor(str(path), osmium.osm.RELATION).with_filter(
        osmium.filter.TagFilter(("type", "building"))
    )
    for rel in fp:
        members = [(_TYPE_CHAR[m.type], m.ref, m.role) for m in rel.members]
        yield rel.id, {t.k: t.v for t in rel.tags}, members


_MAX_STRING = 1024  # libosmium's osmium::max_osm_string_length: longer keys, values, roles, user names are refused
_XML_TOKEN = re.compile(rb'<(node|way|relation)\b[^>]*?\bid="(-?\d+)"|\b(k|v|role|user)="([^"]*)"')


def locate_long_string(path: Path) -> str:
    """Where the first string longer than libosmium's limit sits in an OSM XML file (plain, .gz or .bz2): "line
    3, way 7: the value of tag 'note' has 10,000 bytes"; '' for other formats or when none is found. libosmium refuses
    the whole file on such a string without saying where, so the user could not find it to fix or filter it."""
    name = path.name.lower()
    opener = {".gz": gzip.open, ".bz2": bz2.open}.get(path.suffix.lower(), open)
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
                    what = {"k": "a tag key", "v": f"the value of tag {key!r}", "role": "a member role",
                            "user": "the user name"}[attr]
                    return f"line {lineno}, {obj}: {what} has {len(raw):,} bytes"
    return ""


@contextlib.contextmanager
def _reading(path: Path) -> Iterator[None]:
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
            msg += (f" ({where}; libosmium reads at most {_MAX_STRING:,} bytes)" if where else
                    f" (libosmium reads at most {_MAX_STRING:,} bytes in a key, value, role or user name)")
            msg += ": shorten or drop that tag first (README: bad input)"
        raise RuntimeError(msg) from e


def negative_node_locations(path: Path) -> dict[int, tuple[float, float]]:
    """(lon, lat) of every node with a negative id (JOSM writes unsaved objects so); one pass over the nodes."""
    out: dict[int, tuple[float, float]] = {}
    for n in osmium.FileProcessor(str(path), osmium.osm.NODE):
        if n.id < 0 and n.location.valid():
            out[n.id] = (n.location.lon, n.location.lat)
    return out


def _line_from(nodes: object, negative: dict[int, tuple[float, float]]) -> str | None:
    """The way's linestring as libosmium's WKB hex (little-endian, no SRID), its positive nodes from the
    location index and its negative ones from ``negative``; None when a node is still missing. Consecutive
    repeated nodes are dropped, as libosmium does."""
    coords: list[tuple[float, float]] = []
    for n in nodes:  # type: ignore[attr-defined]
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
    return (b"\x01" + struct.pack("<II", 2, len(coords)) + struct.pack(f"<{2 * len(coords)}d",
                                                                      *(c for xy in coords for c in xy))).hex()


def read_buildings(
    path: Path, settings: Settings, counts: IngestCounts, changed: ChangeIds | None = None
) -> Iterator[tuple[object, ...]]:
    """Pass B: one staging row per candidate building/part; with ``changed`` (a partial update) only the ways it
    names or whose nodes it names, and every relation (libosmium assembles their rings from member ways the
    Python side never sees)."""
    wkb = osmium.geom.WKBFactory()
    key_filter = osmium.filter.KeyFilter("building", "building:part")
    fp = (
        osmium.FileProcessor(str(path))
        .with_locations(settings.location_index)
        .with_areas(key_filter)
        .with_filter(osmium.filter.KeyFilter("building", "building:part"))
    )
    mp_candidates: dict[int, tuple[BuildingTags, dict[str, str]]] = {}
    assembled: set[int] = set()
    negative: dict[int, tuple[float, float]] | None = None
    for obj in fp:
        if obj.is_area():
            if obj.from_way():
                continue  # ways are built from their node list below, so broken ones can be reported
            rid = obj.orig_id()
            tags = {t.k: t.v for t in obj.tags}
            parsed = parse_building_tags(tags, settings.max_height_m, settings.max_levels)
            if parsed is None:
                continue
            try:
                geom_hex = wkb.create_multipolygon(obj)
            except Exception as e:  # noqa: BLE001 - libosmium raises several types; all mean "no geometry"
                assembled.add(rid)
                yield _reject("R", rid, parsed, tags, "multipolygon_assembly_failed", str(e))
                continue
            assembled.add(rid)
            yield _row("R", rid, parsed, tags, "M", geom_hex)
        elif obj.is_way():
            if changed is not None and obj.id not in changed.ways and changed.nodes.isdisjoint(
                    n.ref for n in obj.nodes):
                continue  # as it was: its row stays
            tags = {t.k: t.v for t in obj.tags}
            parsed = parse_building_tags(tags, settings.max_height_m, settings.max_levels)
            if parsed is None:
                continue
            counts.candidates += 1
            counts.ways += 1
            nodes = obj.nodes
            if len(nodes) < 2 or not obj.is_closed():
                first = nodes[0].ref if len(nodes) else None
                last = nodes[-1].ref if len(nodes) else None
                yield _reject("W", obj.id, parsed, tags, "unclosed_way",
                              f"{len(nodes)} nodes, first node {first} != last node {last}")
                continue
            try:
                line = wkb.create_linestring(obj)
            except (osmium.InvalidLocationError, RuntimeError) as e:
                # the nodes are only walked in Python for the rare way that needs it; with every node missing
                # libosmium says "need at least two points", as it does for a ring of one repeated point
                missing = [n.ref for n in nodes if not n.location.valid()]
                if missing and min(missing) < 0:
                    # libosmium's location index keeps positive ids only: negative ones (unsaved JOSM data) are
                    # looked up in their own table, read from the file the first time a way needs it
                    if negative is None:
                        negative = negative_node_locations(path)
                    line = _line_from(nodes, negative)
                    if line is not None:
                        yield _row("W", obj.id, parsed, tags, "L", line)
                        continue
                    missing = [n.ref for n in nodes if not n.location.valid() and n.ref not in negative]
                if missing:
                    shown = ", ".join(str(r) for r in missing[:10]) + (" …" if len(missing) > 10 else "")
                    yield _reject("W", obj.id, parsed, tags, "missing_nodes",
                                  f"{len(missing)} of {len(nodes)} nodes not in the file: {shown}")
                else:  # e.g. every node at one spot: no linestring, let alone a ring
                    yield _reject("W", obj.id, parsed, tags, "degenerate_ring", str(e))
                continue
            yield _row("W", obj.id, parsed, tags, "L", line)
        elif obj.is_node():
            counts.nodes_skipped += 1  # building=* on a node has no footprint; not a candidate
        elif obj.is_relation():
            tags = {t.k: t.v for t in obj.tags}
            if building_kind(tags) is None:
                continue
            rtype = tags.get("type")
            if rtype == "building":
                continue  # a grouping relation (pass A), not a geometry
            parsed = parse_building_tags(tags, settings.max_height_m, settings.max_levels)
            assert parsed is not None
            counts.candidates += 1
            counts.relations += 1
            if rtype in ("multipolygon", "boundary"):  # the two types libosmium assembles
                mp_candidates[obj.id] = (parsed, tags)
            else:
                yield _reject("R", obj.id, parsed, tags, "unsupported_relation",
                              f"type={rtype!r}: only multipolygon relations have a building geometry")
    # Multipolygon relations libosmium could not assemble (missing members, rings that do not close, ...).
    for rid in sorted(set(mp_candidates) - assembled):
        parsed, tags = mp_candidates[rid]
        yield _reject("R", rid, parsed, tags, "multipolygon_assembly_failed",
                      "libosmium could not assemble the rings (member ways missing from the file, "
                      "or rings that do not close)")
    # Areas seen for relations that were not candidates cannot happen (same key filter); keep counts honest.
    stray = assembled - set(mp_candidates)
    if stray:
        raise RuntimeError(f"areas for {len(stray)} relations that were never seen as candidates")


def _reject(
    osm_type: str, osm_id: int, parsed: BuildingTags, tags: dict[str, str], reason: str, detail: str,
) -> tuple[object, ...]:
    return _row(osm_type, osm_id, parsed, tags, None, None, (reason, detail))


#: A partial update keeps the working CRS, which the centre of the footprints' extent chose, and the extent: true
#: when every footprint the change touched whose box moved (the box ST_Extent takes of it, as the full ingest's
#: extent is made of them), before (a staged or changed way's row, every relation's, their rejects') and after it
#: (a staged geometry), lies strictly inside the extent meta.dataset records, and none of those before was
#: repaired (a repaired footprint's box need not be its ring's). Else the update stages every candidate.
_EXTENT_KEPT = """
WITH box AS (SELECT ST_XMin(bbox) AS x0, ST_YMin(bbox) AS y0, ST_XMax(bbox) AS x1, ST_YMax(bbox) AS y1
             FROM meta.dataset WHERE bbox IS NOT NULL),
new AS (SELECT i.osm_type, i.osm_id, ST_XMin(e.b) AS x0, ST_YMin(e.b) AS y0, ST_XMax(e.b) AS x1, ST_YMax(e.b) AS y1
        FROM osm.building_import i CROSS JOIN LATERAL (SELECT ST_Extent(x.g) AS b FROM (SELECT i.geom) x(g)) e
        WHERE i.geom IS NOT NULL),
old AS (SELECT o.osm_type, o.osm_id, o.repaired, ST_XMin(e.b) AS x0, ST_YMin(e.b) AS y0, ST_XMax(e.b) AS x1,
               ST_YMax(e.b) AS y1
        FROM (SELECT osm_type, osm_id, geom, repaired FROM osm.building
              UNION ALL SELECT osm_type, osm_id, geom, false FROM osm.reject WHERE stage = 'ingest') o
        CROSS JOIN LATERAL (SELECT ST_Extent(x.g) AS b FROM (SELECT o.geom) x(g)) e
        WHERE o.geom IS NOT NULL AND (o.osm_type = 'R' OR (o.osm_type = 'W' AND o.osm_id = ANY(%(ways)s))
                                      OR (o.osm_type, o.osm_id) IN (SELECT osm_type, osm_id FROM new))),
same AS (SELECT n.osm_type, n.osm_id FROM new n JOIN old o USING (osm_type, osm_id, x0, y0, x1, y1)
         WHERE NOT o.repaired),
moved AS (SELECT x0, y0, x1, y1, false AS repaired FROM new WHERE (osm_type, osm_id) NOT IN (SELECT * FROM same)
          UNION ALL
          SELECT x0, y0, x1, y1, repaired FROM old WHERE (osm_type, osm_id) NOT IN (SELECT * FROM same))
SELECT EXISTS (SELECT 1 FROM box)
   AND NOT EXISTS (SELECT 1 FROM moved m, box
                   WHERE m.repaired OR NOT (m.x0 > box.x0 AND m.x1 < box.x1 AND m.y0 > box.y0 AND m.y1 < box.y1))
"""


def _copy_rows(cur: psycopg.Cursor, statement: str, rows: Iterable[tuple[object, ...]], progress: Progress) -> None:
    with cur.copy(statement) as copy:  # type: ignore[arg-type]
        for row in rows:
            copy.write_row(row)
            progress.update()


def run(conn: psycopg.Connection, path: Path, settings: Settings, sha256: str | None, update: bool = False,
        also: Callable[[psycopg.Cursor], None] | None = None, changed: ChangeIds | None = None) -> dict[str, object]:
    """Ingest ``path`` in one transaction. Returns the counts recorded in meta.pipeline_run. A full ingest starts
    the database afresh; with ``update`` (``path`` is the OSM state after change files, etl/update/osc.py)
    only the buildings that differ are replaced and listed in osm.building_change, and what is derived from the
    others is kept. ``also`` runs in the same transaction at its end (the update's meta.osm_change rows).
    ``changed`` (an update of a database ingested from the state before the change files, with this code and
    these settings): only the candidates those files touched are read again (read_buildings), unless one reaches
    the edge of the extent (_EXTENT_KEPT): then every candidate is."""
    if not path.exists():
        raise FileNotFoundError(f"OSM file not found: {path}")
    t0 = time.perf_counter()
    counts = IngestCounts()
    with conn.transaction(), conn.cursor() as cur:
        if update:
            # not TRUNCATE: readers see the rows of before until the commit and never wait for it
            cur.execute("TRUNCATE osm.building_import")  # the staging table, read by nobody else
            cur.execute("DELETE FROM osm.building_relation")  # its members with it (ON DELETE CASCADE)
        else:
            # Downstream tables hold derived data of the previous dataset; they are rebuilt by later stages.
            cur.execute(
                "TRUNCATE osm.building_import, osm.building, osm.building_relation, osm.building_relation_member,"
                " lod.building_mesh, tiles.building_tile, tiles.tile, tiles.grid CASCADE"
            )
            cur.execute("TRUNCATE osm.reject, meta.diagnostic RESTART IDENTITY")
            cur.execute("DELETE FROM meta.osm_change")  # a new base file: no change applied to it yet

        with _reading(path):
            rels = list(read_building_relations(path))  # few; needed before parts are linked
        counts.building_relations = len(rels)
        if rels:
            with cur.copy("COPY osm.building_relation (relation_id, name, tags) FROM STDIN") as copy:
                for rid, tags, _ in rels:
                    copy.write_row((rid, tags.get("name"), json.dumps(tags, ensure_ascii=False)))
            with cur.copy(
                "COPY osm.building_relation_member (relation_id, seq, member_type, member_id, role) FROM STDIN"
            ) as copy:
                for rid, _, members in rels:
                    for seq, (mtype, ref, role) in enumerate(members):
                        copy.write_row((rid, seq, mtype, ref, role))

        progress = Progress("ingest", "buildings")
        partial = update and changed is not None
        ways = sorted(changed.ways) if changed is not None else None
        with _reading(path):
            _copy_rows(cur, _COPY_IMPORT, read_buildings(path, settings, counts, changed if partial else None),
                       progress)
        if partial and not cur.execute(_EXTENT_KEPT, {"ways": ways}).fetchone()[0]:  # type: ignore[index]
            print("  ingest: the change reaches the edge of the data: every candidate is read again", file=sys.stderr)
            partial, counts = False, IngestCounts(building_relations=counts.building_relations)
            cur.execute("TRUNCATE osm.building_import")
            with _reading(path):
                _copy_rows(cur, _COPY_IMPORT, read_buildings(path, settings, counts), progress)
        if update and not partial:
            cur.execute("DELETE FROM osm.reject WHERE stage = 'ingest'")
            cur.execute("DELETE FROM meta.diagnostic WHERE stage = 'ingest'")
        print(f"  ingest: read {progress.count:,} candidates in {progress.elapsed:.2f} s, building in SQL…",
              file=sys.stderr, flush=True)
        staged = cur.execute("SELECT count(*) FROM osm.building_import").fetchone()
        assert staged is not None
        cur.execute("CALL osm.finish_ingest(%s, %s, %s, %s, %s)",
                    (settings.min_area_m2, str(path), sha256, update, ways if partial else None))
        loaded = cur.execute("SELECT count(*) FROM osm.building").fetchone()
        rejected = cur.execute(
            "SELECT reason, count(*) FROM osm.reject WHERE stage = 'ingest' GROUP BY reason ORDER BY reason"
        ).fetchall()
        by_kind = dict(cur.execute("SELECT kind, count(*) FROM osm.building GROUP BY kind").fetchall())
        repaired = cur.execute("SELECT count(*) FROM osm.building WHERE repaired").fetchone()
        srid = cur.execute("SELECT srid, srid_name FROM meta.dataset").fetchone()
        changes = dict(cur.execute("SELECT change, count(*) FROM osm.building_change GROUP BY change").fetchall())
        if also is not None:
            also(cur)
    assert loaded is not None and repaired is not None and srid is not None
    n_rejected = sum(n for _, n in rejected)
    if int(staged[0]) != counts.candidates:
        raise RuntimeError(f"ingest lost objects: {counts.candidates} candidates read, {staged[0]} staged")
    # a partial update read only some candidates: the others' rows are as they were, so the balance is the
    # database's (every candidate a building or a reject, as a full ingest checks it)
    n_in = int(loaded[0]) + n_rejected if partial else int(staged[0])
    balance = Balance("buildings and parts", n_in, {"loaded": int(loaded[0])}, n_rejected)
    seconds = time.perf_counter() - t0
    result: dict[str, object] = {
        **balance.counts(),
        "loaded": int(loaded[0]),
        "repaired": int(repaired[0]),
        "buildings": int(by_kind.get("building", 0)),
        "parts": int(by_kind.get("part", 0)),
        "from_ways": counts.ways,
        "from_relations": counts.relations,
        "building_relations": counts.building_relations,
        "building_nodes_skipped": counts.nodes_skipped,
        "rejected_by_reason": {r: int(n) for r, n in rejected},
        "srid": int(srid[0]),
        "seconds": round(seconds, 3),
    }
    if update:
        result["changed"] = {k: int(changes.get(k, 0)) for k in ("added", "modified", "deleted")}
        result["partial"] = partial  # only the candidates the change touched were read again
        result["staged"] = int(staged[0])
    reasons = ", ".join(f"{r} {n}" for r, n in rejected) or "none"
    print(f"  working CRS: EPSG:{srid[0]} ({srid[1]}); rejects: {reasons}", file=sys.stderr)
    summary(
        "ingest", balance,
        f"{by_kind.get('building', 0):,} buildings, {by_kind.get('part', 0):,} parts, {repaired[0]:,} repaired",
        seconds, n_in,
    )
    return result
