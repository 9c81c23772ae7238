"""Stage update: OSM change files (.osc, .osc.gz, as osmosis, osmium and osm2pgsql-replication write them) applied
to the database, and what they changed derived again.

The OSM *state* is the base file a full ingest read plus the change files applied since, in order
(meta.osm_change keeps their paths and sha256s: what a full rebuild needs to give this database). libosmium
applies a change to the previous state (pyosmium's MergeInputReader: creates, modifies and deletes of nodes,
ways and relations; the highest version of an object wins) into a new state file under build/osm/, named after
the chain's sha256; a state file that is missing (another machine, a cleaned build/) is made again from the
base file and the recorded changes, each checked against its sha256.

Ingest then reads the new state in update mode (osm.finish_ingest with p_update): the buildings are assembled
exactly as a full ingest would, compared with osm.building, and only the rows that differ are replaced, so a
moved node moves every building drawn with it, a tag edit re-derives that building, and a multipolygon that lost
a member is assembled again; osm.building_change lists them. When the database's last ingest read the state
before the change files (same code and settings), only the ways the change files name or whose nodes they name,
and every relation, are read again (change_ids; etl/ingest/stage.py), unless a footprint the change moved
reaches the edge of the data (the working CRS comes from its extent).
"""

from __future__ import annotations

import gzip
import hashlib
import os
import xml.etree.ElementTree as ET
from collections.abc import Iterable, Iterator
from dataclasses import dataclass, field
from pathlib import Path

import osmium
import osmium.io
import psycopg

from core.settings import REPO
from etl.ingest.read import ChangeIds
from etl.runs import sha256_file

STATE_DIR = REPO / "build" / "osm"
ACTIONS = ("create", "modify", "delete")
TYPES = ("node", "way", "relation")


class ChangeFileError(ValueError):
    pass


@dataclass(frozen=True)
class Change:
    seq: int
    path: Path
    sha256: str
    state_sha256: str


@dataclass
class Chain:
    """The base file and the changes applied to it, as meta.osm_change records them."""

    base_file: Path
    base_sha256: str
    changes: list[Change] = field(default_factory=list)

    @property
    def state_sha256(self) -> str:
        return self.changes[-1].state_sha256 if self.changes else self.base_sha256


def next_state_sha256(state_sha256: str, change_sha256: str) -> str:
    return hashlib.sha256(f"{state_sha256}\n{change_sha256}\n".encode()).hexdigest()


def _objects(path: Path) -> Iterator[tuple[str, str, int]]:
    """(action, type, id) of every object of an osmChange file, in file order. Refuses a file that is not an
    osmChange document, naming the file and the reason."""
    opener = gzip.open if path.name.endswith(".gz") else open
    action: str | None = None
    depth = 0
    try:
        with opener(path, "rb") as fh:
            for event, el in ET.iterparse(fh, events=("start", "end")):
                if event == "start":
                    depth += 1
                    if depth == 1 and el.tag != "osmChange":
                        raise ChangeFileError(
                            f"{path}: not an OSM change file (its root element is <{el.tag}>, not <osmChange>)"
                        )
                    if depth == 2:
                        action = el.tag if el.tag in ACTIONS else None
                    elif depth == 3 and action is not None and el.tag in TYPES:
                        yield action, el.tag, int(el.get("id", "0"))
                else:
                    depth -= 1
                    if depth <= 2:
                        el.clear()
    except (ET.ParseError, OSError, EOFError, ValueError) as e:
        if isinstance(e, ChangeFileError):
            raise
        raise ChangeFileError(f"{path}: cannot be read as an OSM change file: {e}") from e


def count_change(path: Path) -> dict[str, dict[str, int]]:
    """Objects by action and type: {"create": {"node": n, "way": n, "relation": n}, "modify": ..., "delete": ...}.
    Refuses a file that is not an osmChange document, naming the file and the reason."""
    counts = {a: dict.fromkeys(TYPES, 0) for a in ACTIONS}
    for action, kind, _ in _objects(path):
        counts[action][kind] += 1
    return counts


def change_ids(paths: Iterable[Path]) -> ChangeIds:
    ids: dict[str, set[int]] = {t: set() for t in TYPES}
    for path in paths:
        for _, kind, i in _objects(path):
            ids[kind].add(i)
    return ChangeIds(frozenset(ids["node"]), frozenset(ids["way"]))


def file_input(chain: Chain, shas: list[str]) -> dict[str, object]:
    """What an ingest of the state ``chain``'s base file plus the changes ``shas`` records as its input file (as a
    full ingest of the base file records it when there are none)."""
    return {"path": str(chain.base_file), "sha256": chain.base_sha256, **({"changes": shas} if shas else {})}


def read_chain(conn: psycopg.Connection) -> Chain:
    """The base file and the changes applied so far. Refuses a database that was never ingested."""
    rows = conn.execute(
        "SELECT seq, path, sha256, state_sha256, base_file, base_sha256 FROM meta.osm_change ORDER BY seq"
    ).fetchall()
    if rows:
        return Chain(Path(rows[0][4]), rows[0][5], [Change(s, Path(p), h, st) for s, p, h, st, _, _ in rows])
    row = conn.execute("SELECT source_file, source_sha256 FROM meta.dataset").fetchone()
    if row is None or row[0] is None or row[1] is None:
        raise RuntimeError("nothing to update: no file was ingested into this database (make ingest OSM=file first)")
    return Chain(Path(row[0]), row[1])


def state_path(state_sha256: str) -> Path:
    return STATE_DIR / f"state-{state_sha256[:20]}.osm.pbf"


def apply_changes(previous: Path, changes: Iterable[Path], out: Path) -> None:
    """``previous`` with ``changes`` applied in order, written to ``out`` (in one step: a crash leaves no half
    file under that name)."""
    merge = osmium.MergeInputReader()
    for c in changes:
        merge.add_file(str(c))
    out.parent.mkdir(parents=True, exist_ok=True)
    tmp = out.with_name(out.name + f".{os.getpid()}.tmp.osm.pbf")
    tmp.unlink(missing_ok=True)
    reader = osmium.io.Reader(str(previous))
    writer = osmium.io.Writer(osmium.io.File(str(tmp)), osmium.io.Header())
    try:
        merge.apply_to_reader(reader, writer, False)
    finally:
        reader.close()
        writer.close()
    tmp.replace(out)


def drop_previous_state(chain: Chain, current: Path) -> bool:
    """Remove the state file of ``chain``, the one the database just left, once the update's ingest has committed
    the new chain ending at ``current``: a service following minutely changes would otherwise keep a whole copy of
    the city per change file. Never the base file (a chain without changes: its state is the user's file, even a
    state file another database was built from); another database still at that state makes it again from its
    base file and changes when it next needs it (ensure_state)."""
    if not chain.changes:
        return False
    left = state_path(chain.state_sha256)
    if left.resolve() == current.resolve():
        return False
    left.unlink(missing_ok=True)
    return True


def _check(path: Path, sha: str, what: str) -> None:
    if not path.is_file():
        raise FileNotFoundError(
            f"{what} {path} is missing: it is needed to rebuild the OSM state (keep the base "
            "file and every applied change file, or ingest a new base file)"
        )
    if sha256_file(path) != sha:
        raise RuntimeError(f"{what} {path} is not the file that was applied (its sha256 changed)")


def ensure_state(chain: Chain) -> Path:
    """The state file of ``chain`` (the base file itself when no change was applied), made again when missing."""
    if not chain.changes:
        _check(chain.base_file, chain.base_sha256, "the base file")
        return chain.base_file
    path = state_path(chain.state_sha256)
    if path.is_file():
        return path
    _check(chain.base_file, chain.base_sha256, "the base file")
    for c in chain.changes:
        _check(c.path, c.sha256, f"change file {c.seq}")
    apply_changes(chain.base_file, [c.path for c in chain.changes], path)
    return path
