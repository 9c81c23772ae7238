"""tests/support/history.py on a history file written here: the state at a moment is each object's last version by
then unless it deletes the object, and the change between two moments creates, modifies and deletes exactly what
differs between their states."""

from __future__ import annotations

import datetime as dt
from pathlib import Path

import osmium

from etl.update.osc import apply_changes
from tests.support.history import changes, read_history, states

HISTORY = """<?xml version="1.0" encoding="UTF-8"?>
<osm version="0.6">
 <node id="1" version="1" visible="true" timestamp="2010-01-01T00:00:00Z" lat="1.0" lon="2.0"/>
 <node id="1" version="2" visible="true" timestamp="2012-01-01T00:00:00Z" lat="1.5" lon="2.0"/>
 <node id="2" version="1" visible="true" timestamp="2010-01-01T00:00:00Z" lat="1.0" lon="2.1"/>
 <node id="2" version="2" visible="false" timestamp="2012-06-01T00:00:00Z"/>
 <node id="3" version="1" visible="true" timestamp="2011-06-01T00:00:00Z" lat="1.1" lon="2.1"/>
 <node id="4" version="1" visible="true" timestamp="2013-01-01T00:00:00Z" lat="1.2" lon="2.2"/>
 <way id="10" version="1" visible="true" timestamp="2011-06-01T00:00:00Z"><nd ref="1"/><nd ref="3"/></way>
 <way id="10" version="2" visible="true" timestamp="2012-02-01T00:00:00Z"><nd ref="1"/><nd ref="3"/>
  <tag k="building" v="yes"/></way>
</osm>
"""
T = [dt.datetime(y, 1, 1, tzinfo=dt.UTC) for y in (2011, 2013)]


def contents(path: Path) -> set[tuple]:
    out = set()
    for o in osmium.FileProcessor(str(path)):
        if o.is_node():
            out.add(("n", o.id, o.version, round(o.location.lat, 7)))
        else:
            out.add(("w", o.id, o.version, tuple(n.ref for n in o.nodes), tuple(sorted(dict(o.tags).items()))))
    return out


def test_states_and_the_change_between_them(tmp_path: Path) -> None:
    src = tmp_path / "history.osm"
    src.write_text(HISTORY)
    h = read_history(src)
    assert states(h, T[0], tmp_path / "a.osm") == 2
    assert contents(tmp_path / "a.osm") == {("n", 1, 1, 1.0), ("n", 2, 1, 1.0)}
    assert states(h, T[1], tmp_path / "b.osm") == 4
    assert contents(tmp_path / "b.osm") == {
        ("n", 1, 2, 1.5),
        ("n", 3, 1, 1.1),
        ("n", 4, 1, 1.2),
        ("w", 10, 2, (1, 3), (("building", "yes"),)),
    }
    made = changes(h, T[0], T[1], tmp_path / "c.osc")
    assert made == {
        "create": {"node": 2, "way": 1, "relation": 0},
        "modify": {"node": 1, "way": 0, "relation": 0},
        "delete": {"node": 1, "way": 0, "relation": 0},
    }
    # the change applied to the first state is the second one (libosmium, as `python -m etl update` applies it)
    apply_changes(tmp_path / "a.osm", [tmp_path / "c.osc"], tmp_path / "merged.osm.pbf")
    assert contents(tmp_path / "merged.osm.pbf") == contents(tmp_path / "b.osm")
    # node 3 and the way, created and changed between the moments, are one creation each, at their last version
    assert '<way id="10" version="2"' in (tmp_path / "c.osc").read_text()
