"""core/fingerprint.py: rows that differ in any value, in where bytes split or in a column's name hash apart."""

from __future__ import annotations

from core.fingerprint import Fingerprint


def digest(rows: list[dict[str, object]], seed: str = "s") -> str:
    f = Fingerprint(seed)
    f.rows(rows)
    return f.hexdigest()


def test_rows_hash_apart_on_any_difference() -> None:
    row = {"id": 1, "mesh": b"\x01\x02\x03", "tags": b"ab", "height": 7.5, "name": None}
    same = digest([row, {**row, "id": 2}])
    assert digest([dict(reversed(list(row.items()))), {**row, "id": 2}]) == same, "by name, not dict order"
    assert digest([row, {**row, "id": 2}], seed="t") != same
    assert digest([row, {**row, "id": 3}]) != same
    assert digest([row, {**row, "id": 2, "height": 7.50001}]) != same
    # a byte moved from one bytes column to the next: the lengths tell them apart
    assert digest([{**row, "mesh": b"\x01\x02", "tags": b"\x03ab"}, {**row, "id": 2}]) != same
    assert digest([{**row, "name": "x"}, {**row, "id": 2}]) != same
    renamed = {("label" if k == "name" else k): v for k, v in row.items()}
    assert digest([renamed, {**renamed, "id": 2}]) != same
    assert digest([row]) != same and digest([]) != same
    assert digest([{**row, "mesh": memoryview(b"\x01\x02\x03")}, {**row, "id": 2}]) == same
