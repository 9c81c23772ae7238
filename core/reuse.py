"""Keep or make again: the one mechanism by which a stage keeps what its last run made where its input did not
change (generalize's batches and block tiles, textures' tiles, the export's glbs).

A stage's work is cut into units. A unit's fingerprint is a sha256 of the run's seed (the stage's code and
settings as its run records them, and whatever else every unit shares) and of what the unit reads, which the
stage gives as a few values per unit (usually an md5 the database computes over the unit's rows, so no row
travels). The last run recorded each unit's fingerprint beside its output (gen.unit_input, tex.tile_input,
pub.file.input_digest). A unit whose fingerprint is the recorded one, and whose output is still all there
(``whole``), is kept; the others are made again. When an update knows what changed since the last run
(core/changes.py), a unit no change reached keeps its recorded fingerprint without its input being read.
"""

from __future__ import annotations

from collections.abc import Callable, Container, Hashable, Mapping, Sequence
from dataclasses import dataclass
from typing import Generic, TypeVar

from .fingerprint import Fingerprint

U = TypeVar("U", bound=Hashable)


def fingerprint(seed: str, *parts: object) -> str:
    """sha256 hex of ``seed`` and ``parts``, each length-prefixed (core/fingerprint.py)."""
    f = Fingerprint(seed)
    for p in parts:
        f.put(p)
    return f.hexdigest()


@dataclass
class Plan(Generic[U]):
    #: every unit's fingerprint in this run (the recorded one where its input was not read)
    prints: dict[U, str]
    #: the units whose output stays as the last run made it, in the units' order
    keep: list[U]
    #: the units to make again, in the units' order
    make: list[U]
    #: the units whose input was read (fingerprinted); the others no change reached
    read: list[U]


def fingerprints(
    units: Sequence[U],
    seed: str,
    recorded: Mapping[U, str] | None,
    parts: Callable[[list[U]], Mapping[U, Sequence[object]]],
    reached: Container[U] | None = None,
) -> tuple[dict[U, str], list[U]]:
    """(every unit's fingerprint, the units whose input was read). ``parts(units)``: what each of those units
    reads, the values its fingerprint is made of; ``reached``: the units a change reached (None: any may have
    changed), the others keep their ``recorded`` fingerprint unread."""
    known = (
        {}
        if recorded is None or reached is None
        else {u: recorded[u] for u in units if u in recorded and u not in reached}
    )
    read = [u for u in units if u not in known]
    got = parts(read) if read else {}
    return {u: known[u] if u in known else fingerprint(seed, *got[u]) for u in units}, read


def decide(
    units: Sequence[U],
    prints: Mapping[U, str],
    recorded: Mapping[U, str] | None,
    whole: Callable[[list[U]], Container[U]] | None = None,
) -> tuple[list[U], list[U]]:
    """(the units to keep, the units to make again), each in the units' order: a unit is kept when its
    fingerprint is the one the last run recorded (``recorded`` None: a full run, nothing is kept) and, of those,
    ``whole(units)`` finds its recorded output all still there (default: all)."""
    same = [] if recorded is None else [u for u in units if recorded.get(u) == prints[u]]
    if whole is not None and same:
        there = whole(same)
        same = [u for u in same if u in there]
    kept = set(same)
    return same, [u for u in units if u not in kept]


def plan(
    units: Sequence[U],
    seed: str,
    recorded: Mapping[U, str] | None,
    parts: Callable[[list[U]], Mapping[U, Sequence[object]]],
    *,
    reached: Container[U] | None = None,
    whole: Callable[[list[U]], Container[U]] | None = None,
) -> Plan[U]:
    """Which of ``units`` to keep and which to make again: ``fingerprints``, then ``decide``."""
    prints, read = fingerprints(units, seed, recorded, parts, reached)
    keep, make = decide(units, prints, recorded, whole)
    return Plan(prints, keep, make, read)
