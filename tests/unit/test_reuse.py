"""core/reuse.py, the one keep-or-make-again mechanism of generalize, textures and the export: a unit is kept
exactly when its fingerprint is the recorded one and its output is whole; a unit no change reached is not read."""

from __future__ import annotations

from core.reuse import fingerprint, plan


def _parts(inputs: dict[str, str], asked: list[list[str]]):
    def parts(units: list[str]) -> dict[str, tuple[object, ...]]:
        asked.append(list(units))
        return {u: (u, inputs[u]) for u in units}

    return parts


def test_a_unit_is_kept_only_when_its_input_and_seed_are_the_recorded_ones() -> None:
    inputs = {"a": "1", "b": "2", "c": "3"}
    recorded = {u: fingerprint("seed", u, v) for u, v in inputs.items()}
    asked: list[list[str]] = []
    p = plan(["a", "b", "c"], "seed", recorded, _parts({**inputs, "b": "changed"}, asked))
    assert p.keep == ["a", "c"] and p.make == ["b"] and p.read == ["a", "b", "c"] and asked == [["a", "b", "c"]]
    # another seed (new code, other settings) keeps nothing; a full run (nothing recorded) makes everything
    assert plan(["a", "b"], "other", recorded, _parts(inputs, [])).make == ["a", "b"]
    assert plan(["a", "b"], "seed", None, _parts(inputs, [])).keep == []
    # a unit recorded with its fingerprint but whose output is gone is made again
    p = plan(["a", "b", "c"], "seed", recorded, _parts(inputs, []), whole=lambda same: set(same) - {"c"})
    assert p.keep == ["a", "b"] and p.make == ["c"]


def test_a_unit_no_change_reached_keeps_its_recorded_fingerprint_unread() -> None:
    inputs = {"a": "1", "b": "2", "c": "3"}
    recorded = {u: fingerprint("seed", u, v) for u, v in inputs.items() if u != "c"}
    asked: list[list[str]] = []
    # b was reached (and changed); a was not (read nothing of it); c has no record, so it is read
    p = plan(["a", "b", "c"], "seed", recorded, _parts({**inputs, "b": "changed"}, asked), reached={"b"})
    assert asked == [["b", "c"]] and p.read == ["b", "c"]
    assert p.keep == ["a"] and p.make == ["b", "c"] and p.prints["a"] == recorded["a"]
    # with reached None (anything may have changed) every unit is read
    asked.clear()
    plan(["a", "b"], "seed", recorded, _parts(inputs, asked), reached=None)
    assert asked == [["a", "b"]]
