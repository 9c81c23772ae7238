"""benchmarks/replicate.py: N shifted copies of an OSM file, valid and sorted, read back with libosmium."""

from pathlib import Path

import osmium
import pytest

from benchmarks import replicate as rp
from tests.conftest import SPINE_FILES, merge_osm


def read(path: Path) -> dict[str, list]:
    out: dict[str, list] = {"n": [], "w": [], "r": []}
    for o in osmium.FileProcessor(str(path)):
        t = o.type_str()
        if t == "n":
            out[t].append((o.id, round(o.location.lon, 7), round(o.location.lat, 7), dict(o.tags)))
        elif t == "w":
            out[t].append((o.id, [n.ref for n in o.nodes], dict(o.tags)))
        else:
            out[t].append((o.id, [(m.type, m.ref, m.role) for m in o.members], dict(o.tags)))
    return out


@pytest.fixture(scope="module")
def spine(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return merge_osm(SPINE_FILES, tmp_path_factory.mktemp("replicate") / "spine.osm")


def test_id_step_is_the_power_of_ten_above_the_largest_id() -> None:
    assert rp.id_step(999) == 1000
    assert rp.id_step(1000) == 10_000
    assert rp.id_step(9_901_312_927) == 10**10  # a node id of a 2022 extract


def test_layout_is_a_near_square_grid_that_must_fit_on_the_globe() -> None:
    lay = rp.layout(5_000, (9.0, 47.0, 9.2, 47.1), 6)
    assert (lay.step, lay.columns) == (10_000, 3)
    assert lay.shift(0) == (0.0, 0.0)
    assert lay.shift(4) == pytest.approx((0.2 * 1.05, 0.1 * 1.05))
    with pytest.raises(ValueError, match="do not fit"):
        rp.layout(5_000, (179.0, 0.0, 179.9, 1.0), 4)


def test_copies_are_sorted_offset_and_reference_their_own_copy(spine: Path, tmp_path: Path) -> None:
    src = read(spine)
    out = tmp_path / "x3.osm.pbf"
    r = rp.replicate(spine, 3, out)
    got = read(out)
    assert (r["nodes"], r["ways"], r["relations"]) == (3 * len(src["n"]), 3 * len(src["w"]), 3 * len(src["r"]))
    max_id, bounds = rp.scan(spine)
    lay = rp.layout(max_id, bounds, 3)
    assert lay.step == r["id_step"] > max_id
    for t in ("n", "w", "r"):
        ids = [o[0] for o in got[t]]
        assert ids == sorted(ids) and len(set(ids)) == len(ids), f"{t}: not sorted by id"
    nodes = {o[0]: o for o in got["n"]}
    for k in range(3):
        off, (dx, dy) = k * lay.step, lay.shift(k)
        for nid, lon, lat, tags in src["n"]:
            gid, glon, glat, gtags = nodes[nid + off]
            assert (glon, glat, gtags) == (pytest.approx(lon + dx, abs=1e-7), pytest.approx(lat + dy, abs=1e-7), tags)
    ways = {o[0]: o for o in got["w"]}
    for k in range(3):
        off = k * lay.step
        for wid, refs, tags in src["w"]:
            assert ways[wid + off][1:] == ([ref + off for ref in refs], tags)
    rels = {o[0]: o for o in got["r"]}
    for k in range(3):
        off = k * lay.step
        for rid, members, tags in src["r"]:
            assert rels[rid + off][1:] == ([(t, ref + off, role) for t, ref, role in members], tags)
    # copies side by side, never on top of each other
    lons = sorted({round(lon, 3) for _, lon, _, _ in got["n"]})
    assert min(lons) == pytest.approx(bounds[0], abs=1e-3)
    assert max(lons) == pytest.approx(bounds[2] + lay.dlon, abs=1e-3)


def test_negative_ids_keep_their_sign(tmp_path: Path) -> None:
    src = tmp_path / "josm.osm"
    src.write_text(
        '<?xml version="1.0"?><osm version="0.6" generator="JOSM">'
        '<node id="-3" lat="47.0" lon="9.0"/><node id="-2" lat="47.0" lon="9.001"/>'
        '<node id="-1" lat="47.001" lon="9.0"/>'
        '<way id="-5"><nd ref="-3"/><nd ref="-2"/><nd ref="-1"/><nd ref="-3"/><tag k="building" v="yes"/></way>'
        "</osm>"
    )
    out = tmp_path / "josm2.osm"
    rp.replicate(src, 2, out)
    got = read(out)
    assert sorted(o[0] for o in got["n"]) == [-13, -12, -11, -3, -2, -1]
    assert sorted((o[0], tuple(o[1])) for o in got["w"]) == [(-15, (-13, -12, -11, -13)), (-5, (-3, -2, -1, -3))]
