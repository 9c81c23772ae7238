"""sha256 fingerprints of what a unit of work read, so an update can tell which units it must compute again."""

from __future__ import annotations

import hashlib
import json


def run_seed(*parts: object) -> str:
    """sha256 hex of ``parts`` as JSON (keys sorted): what every fingerprint of a run starts from (its settings,
    its code as etl/staleness.py records it, and whatever else all its units share)."""
    return hashlib.sha256(json.dumps(list(parts), sort_keys=True, default=str).encode()).hexdigest()


class Fingerprint:
    """A sha256 fed values one at a time, each length-prefixed (bytes as they are, anything else as its repr), so
    two different sequences of values never hash alike by running into each other."""

    def __init__(self, seed: str) -> None:
        self._h = hashlib.sha256(seed.encode())

    def put(self, v: object) -> None:
        b = bytes(v) if isinstance(v, bytes | bytearray | memoryview) else repr(v).encode()
        self._h.update(len(b).to_bytes(8, "little"))
        self._h.update(b)

    def rows(self, rows: list[dict[str, object]]) -> None:
        """Every column of every row, by name, in order. The rows share their columns (one query's): the names
        are hashed once, then per row its bytes values each length-prefixed and the others in one repr."""
        if not rows:
            return
        keys = sorted(rows[0])
        self.put(keys)
        h = self._h
        for r in rows:
            scalars: list[object] = []
            for k in keys:
                v = r[k]
                if isinstance(v, bytes | bytearray | memoryview):
                    b = v if isinstance(v, bytes) else bytes(v)
                    h.update(len(b).to_bytes(8, "little"))
                    h.update(b)
                    scalars.append(...)  # where a bytes value was: no value a query returns reads as Ellipsis
                else:
                    scalars.append(v)
            self.put(scalars)

    def hexdigest(self) -> str:
        return self._h.hexdigest()
