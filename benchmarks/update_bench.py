"""``python -m benchmarks.update_bench``: what an OSM change file touching 1 % of the buildings costs
(``python -m etl update --osc ... --out ...``) against the full rebuild of the same extract.

1. a fresh database with every stage on the benchmark extract and an export (the full rebuild: its stages'
   wall seconds, each stage in its own process as make runs them);
2. a change file written here for 1 % of the extract's building ways, the ones nearest the centre of the data
   (a mapper's edits are local): every other one gets a new height (a tag edit), the others have one node
   moved by half a metre (a geometry edit: every building drawn with that node moves);
3. ``python -m etl update --osc that --out the export`` in one process, timed, with its stages' own seconds
   (meta.pipeline_run) and what the export published anew;
4. a real change (tests/support/history.py): the extract as it was on HISTORY_BEFORE, as far as its own versions
   and timestamps tell, built in full in another database and exported, then updated with the change file of
   what mappers created since, timed the same way and compared with the full rebuild of step 1.

``--json PATH`` writes the figures; ``--write BENCHMARKS.md`` replaces its "## Updates" section. ``--larger``
(with ``--osm`` a larger city, e.g. the scale bench's six copies of the extract) measures steps 1 to 3 alone into
the section "## Updates at scale".
"""

from __future__ import annotations

import contextlib
import datetime as dt
import math
import os
import sys
import time
from pathlib import Path
from typing import Any
from xml.sax.saxutils import quoteattr

import osmium
import psycopg

from benchmarks.common import (
    LOG_DIR,
    OUT_ROOT,
    PIPELINE,
    build_pipeline_db,
    drop_db,
    extract_name,
    log,
    markdown_table,
    run_child,
    section_bench,
)
from tests.support.equivalence import Reader, differences, tileset_differences
from tests.support.history import split

UPDATE_DB = "citylod_bench_update"
DEFAULT_OSM = Path(__file__).resolve().parents[2] / "shared" / "data" / "osm" / "liechtenstein_2022-07-24.osm.pbf"
SHARE = 0.01
#: the real change's start (step 4): Liechtenstein's buildings created from here to the extract (2022-07-24) are
#: about 1 % of them
HISTORY_BEFORE = dt.datetime(2022, 5, 7, tzinfo=dt.UTC)
STAGES = (*PIPELINE, "export")


class _Ways(osmium.SimpleHandler):
    """Building ways (id, version, tags, node refs) and the locations of their nodes."""

    def __init__(self) -> None:
        super().__init__()
        self.ways: list[tuple[int, int, dict[str, str], list[int], tuple[float, float]]] = []
        self.nodes: dict[int, tuple[int, float, float]] = {}

    def way(self, w: osmium.osm.Way) -> None:
        if "building" not in w.tags or not w.is_closed():
            return
        try:
            pts = [(n.location.lon, n.location.lat) for n in w.nodes]
        except osmium.InvalidLocationError:
            return
        centre = (sum(p[0] for p in pts) / len(pts), sum(p[1] for p in pts) / len(pts))
        self.ways.append((w.id, w.version, dict(w.tags), [n.ref for n in w.nodes], centre))


class _Nodes(osmium.SimpleHandler):
    def __init__(self, wanted: set[int]) -> None:
        super().__init__()
        self.wanted, self.found = wanted, {}

    def node(self, n: osmium.osm.Node) -> None:
        if n.id in self.wanted:
            self.found[n.id] = (n.version, n.location.lon, n.location.lat, dict(n.tags))


def _tags(tags: dict[str, str]) -> str:
    return "".join(f"<tag k={quoteattr(k)} v={quoteattr(v)}/>" for k, v in sorted(tags.items()))


def write_change(osm: Path, out: Path, share: float = SHARE) -> dict[str, int]:
    """The change file for ``share`` of the building ways of ``osm`` nearest its centre (see the module doc)."""
    h = _Ways()
    h.apply_file(str(osm), locations=True)
    cx = sum(c[0] for *_, c in h.ways) / len(h.ways)
    cy = sum(c[1] for *_, c in h.ways) / len(h.ways)
    scale = math.cos(math.radians(cy))
    chosen = sorted(h.ways, key=lambda w: ((w[4][0] - cx) * scale) ** 2 + (w[4][1] - cy) ** 2)
    chosen = chosen[: max(1, round(share * len(h.ways)))]
    moved = {w[3][0] for i, w in enumerate(chosen) if i % 2}
    nodes = _Nodes(moved)
    nodes.apply_file(str(osm))
    lines = [
        '<?xml version="1.0" encoding="UTF-8"?>',
        '<osmChange version="0.6" generator="citylod update_bench">',
        "<modify>",
    ]
    for nid in sorted(moved):
        v, lon, lat, tags = nodes.found[nid]
        lines.append(
            f'<node id="{nid}" version="{v + 1}" lat="{lat + 0.5 / 111_320:.7f}" lon="{lon:.7f}">{_tags(tags)}</node>'
        )
    n_tags = 0
    for i, (wid, v, tags, refs, _) in enumerate(chosen):
        if i % 2:
            continue
        n_tags += 1
        try:
            height = float(tags.get("height", "").split()[0]) + 2
        except (ValueError, IndexError):
            height = 12.0
        tags = {**tags, "height": f"{height:g}"}
        lines.append(
            f'<way id="{wid}" version="{v + 1}">' + "".join(f'<nd ref="{r}"/>' for r in refs) + _tags(tags) + "</way>"
        )
    lines += ["</modify>", "</osmChange>", ""]
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text("\n".join(lines))
    return {"building_ways": len(h.ways), "chosen": len(chosen), "tag_edits": n_tags, "nodes_moved": len(moved)}


def stage_seconds(url: str, since: int) -> dict[str, float]:
    with psycopg.connect(url) as conn:
        return {
            s: round(float(d), 2)
            for s, d in conn.execute(
                "SELECT stage, duration_s FROM meta.pipeline_run WHERE run_id > %s AND status = 'ok' ORDER BY run_id",
                (since,),
            )
        }


def _centre(url: str) -> tuple[float, float]:
    with psycopg.connect(url) as conn:
        row = conn.execute(
            "SELECT ST_X(c), ST_Y(c) FROM (SELECT ST_Centroid(bbox) AS c FROM meta.dataset) s"
        ).fetchone()
    assert row is not None
    return float(row[0]), float(row[1])


def _state_file(url: str) -> str | None:
    with psycopg.connect(url) as conn:
        row = conn.execute("SELECT source_file FROM meta.dataset").fetchone()
    return row[0] if row else None


def _reused(url: str, last: int) -> dict[str, Any]:
    """What each stage of the update after run ``last`` computed and what it copied."""
    with psycopg.connect(url) as conn:
        runs = dict(
            conn.execute(
                "SELECT DISTINCT ON (stage) stage, counts FROM meta.pipeline_run "
                "WHERE run_id > %s AND status = 'ok' ORDER BY stage, run_id",
                (last,),
            ).fetchall()
        )
    gen = runs.get("generalize", {})
    return {
        "ingest": {k: runs.get("ingest", {}).get(k) for k in ("in", "staged", "partial")},
        "generalize": gen.get("batches") and {**gen["batches"], "hierarchy_tiles": gen.get("hierarchy_tiles")},
        "textures": {
            k: runs.get("textures", {}).get(k)
            for k in ("tiles", "tiles_kept", "tiles_redrawn", "tiles_fingerprinted", "features", "features_textured")
        },
        "export": {
            k: runs.get("export", {}).get(k)
            for k in ("glb", "glb_built", "glb_copied", "glb_fingerprinted", "features", "features_built")
        },
    }


def _changed(url: str) -> dict[str, int]:
    with psycopg.connect(url) as conn:
        return dict(conn.execute("SELECT change, count(*) FROM osm.building_change GROUP BY 1").fetchall())


def _last_run(url: str) -> int:
    with psycopg.connect(url) as conn:
        (last,) = conn.execute("SELECT max(run_id) FROM meta.pipeline_run").fetchone()  # type: ignore[misc]
    return int(last)


def _n_files(d: Path) -> int:
    return sum(1 for p in d.rglob("*") if p.is_file())


def measure_history(
    osm: Path, admin_url: str, db: str, full_url: str, full_out: Path, verify: bool = True
) -> dict[str, Any]:
    """Step 4 of the module doc: ``full_url`` and ``full_out`` are the full rebuild of ``osm`` and its export."""
    name = extract_name(osm)
    day = HISTORY_BEFORE.date().isoformat()
    base = OUT_ROOT / "update" / f"{name}-{day}.osm.pbf"
    change = OUT_ROOT / "update" / f"{name}-since-{day}.osc"
    made = split(osm, HISTORY_BEFORE, base, change)
    log(f"{name}: as it was on {day}, then updated with what mappers created since ({made})")
    logs = LOG_DIR / name / "update-history"
    out = OUT_ROOT / "update" / f"{name}-history"
    url, env, full, _ = _full_build(base, admin_url, db + "_history", "update-history", out, logs)
    last, wall, _ = _apply(change, url, env, out, logs)
    res: dict[str, Any] = {
        "before": day,
        "created": made,
        "changed": _changed(url),
        "full_s": full,
        "full_total_s": round(sum(full.values()), 1),
        "update_wall_s": round(wall, 1),
        "update_s": stage_seconds(url, last),
        "reused": _reused(url, last),
    }
    if verify:
        res["verified"] = {
            "tables_differing": differences(url, full_url),
            "tiles_differing": tileset_differences(out, full_out),
            "tiles": _n_files(out),
        }
    drop_db(admin_url, db + "_history")
    return res


def _wal_mark(url: str) -> str:
    """The cluster's WAL position after a checkpoint (when the role may ask for one): what follows writes each
    page it changes whole once, as the first change after any checkpoint does."""
    with psycopg.connect(url, autocommit=True) as conn:
        with contextlib.suppress(psycopg.Error):  # a role that may not ask for one measures from where it is
            conn.execute("CHECKPOINT")
        return str(conn.execute("SELECT pg_current_wal_lsn()::text").fetchone()[0])  # type: ignore[index]


def _wal_since(url: str, mark: str) -> int:
    """Bytes of WAL the cluster wrote since ``mark`` (the bench runs alone: they are the command's)."""
    with psycopg.connect(url) as conn:
        return int(conn.execute("SELECT pg_wal_lsn_diff(pg_current_wal_lsn(), %s::pg_lsn)", (mark,)).fetchone()[0])  # type: ignore[index]


def _full_build(
    osm: Path, admin_url: str, db: str, logs_sub: str, out: Path, logs: Path
) -> tuple[str, dict[str, str], dict[str, float], int]:
    """``osm`` through every stage into ``db`` and exported to ``out``; (url, env, each stage's s, WAL bytes)."""
    mark = _wal_mark(admin_url)
    url = build_pipeline_db(osm, admin_url, db, logs_sub)
    env = {**os.environ, "DATABASE_URL": url}
    run_child([sys.executable, "-m", "etl", "export", "--out", str(out)], env, logs / "export.log")
    full = stage_seconds(url, 0)
    full.pop("migrate", None)
    return url, env, full, _wal_since(url, mark)


def _apply(change: Path, url: str, env: dict[str, str], out: Path, logs: Path) -> tuple[int, float, int]:
    """``python -m etl update`` of ``change`` with the export to ``out``; (the last run before it, wall s, WAL
    bytes)."""
    last = _last_run(url)
    mark = _wal_mark(url)
    wall = _run_update(change, env, out, logs / "update.log")
    return last, wall, _wal_since(url, mark)


def _run_update(change: Path, env: dict[str, str], out: Path, log: Path) -> float:
    """``python -m etl update`` of ``change`` with the export to ``out``, its output to ``log``; wall s."""
    wall, _ = run_child([sys.executable, "-m", "etl", "update", "--osc", str(change), "--out", str(out)], env, log)
    return wall


def _timed_update(change: Path, url: str, env: dict[str, str], out: Path, log: Path) -> tuple[float, dict[str, float]]:
    """_run_update, and the seconds of each stage it ran or carried over."""
    last = _last_run(url)
    return _run_update(change, env, out, log), stage_seconds(url, last)


def _update_one_percent(
    osm: Path, url: str, env: dict[str, str], out: Path, logs: Path
) -> tuple[dict[str, int], int, float, int]:
    """Steps 2 and 3: the 1 % change written and applied; (what it changed, the last run before, wall s, WAL
    bytes)."""
    name = extract_name(osm)
    change = OUT_ROOT / "update" / f"{name}-1pct.osc"
    made = write_change(osm, change)
    log(f"{name}: update with {made['chosen']:,} of {made['building_ways']:,} building ways changed")
    return (made, *_apply(change, url, env, out, logs))


def measure(osm: Path, admin_url: str, db: str = UPDATE_DB, verify: bool = True) -> dict[str, Any]:
    name = extract_name(osm)
    logs = LOG_DIR / name / "update"
    t0 = time.perf_counter()
    out = OUT_ROOT / "update" / name
    url, env, full, full_wal = _full_build(osm, admin_url, db, "update", out, logs)
    full_wall = time.perf_counter() - t0
    history = measure_history(osm, admin_url, db, url, out, verify)
    made, last, wall, wal = _update_one_percent(osm, url, env, out, logs)
    update_s = stage_seconds(url, last)  # now: the no-building update below records the same stages again
    reused = _reused(url, last)
    changed = _changed(url)
    with psycopg.connect(url) as conn:
        (buildings,) = conn.execute("SELECT count(*) FROM osm.building").fetchone()  # type: ignore[misc]
        pub = conn.execute(
            "SELECT n_files, n_new_files, n_new_bytes FROM pub.generation ORDER BY generation DESC LIMIT 1"
        ).fetchone()
    state = Path(params_osm) if (params_osm := _state_file(url)) else None
    verified: dict[str, object] | None = None
    if verify and state is not None:
        log(f"{name}: a full rebuild from the update's state file, to compare")
        full_url = build_pipeline_db(state, admin_url, db + "_full", "update-full")
        run_child(
            [sys.executable, "-m", "etl", "export", "--out", str(out.with_name(name + "-full"))],
            {**env, "DATABASE_URL": full_url},
            logs / "export-full.log",
        )
        verified = {
            "tables_differing": differences(url, full_url),
            "tiles_differing": tileset_differences(out, out.with_name(name + "-full")),
            "tiles": _n_files(out),
        }
        drop_db(admin_url, db + "_full")
    # then a change that touches no building (a new tagged node): the stages are carried over, the export reruns
    quiet = OUT_ROOT / "update" / f"{name}-no-building.osc"
    quiet.write_text(
        '<?xml version="1.0" encoding="UTF-8"?>\n<osmChange version="0.6"><create>'
        f'<node id="{10**12}" version="1" lat="{_centre(url)[1]:.7f}" lon="{_centre(url)[0]:.7f}">'
        '<tag k="amenity" v="bench"/></node></create></osmChange>\n'
    )
    quiet_wall, quiet_s = _timed_update(quiet, url, env, out, logs / "update-no-building.log")
    # then a change of one building (a height edit, the building nearest the centre): about what every update pays
    # whatever it changes, which a live database following minutely diffs pays again and again
    one = OUT_ROOT / "update" / f"{name}-one-building.osc"
    before_one = _state_file(url)
    assert before_one is not None
    write_change(Path(before_one), one, share=0.0)
    one_wall, one_s = _timed_update(one, url, env, out, logs / "update-one-building.log")
    # then another 1 % change, the same buildings edited again, with an analyst reading every table meanwhile
    # (not timed: the reader takes a core)
    again = OUT_ROOT / "update" / f"{name}-1pct-again.osc"
    now = _state_file(url)  # the state after the updates above
    assert now is not None
    write_change(Path(now), again)
    with Reader(url) as reader:
        _run_update(again, env, out, logs / "update-read.log")
    return {
        "extract": name,
        "buildings": int(buildings),
        "change": made,
        "changed": changed,
        "verified": verified,
        "no_building_wall_s": round(quiet_wall, 1),
        "no_building_s": quiet_s,
        "one_building_wall_s": round(one_wall, 1),
        "one_building_s": one_s,
        "full_s": full,
        "full_total_s": round(sum(full.values()), 1),
        "full_wall_s": round(full_wall, 1),
        "update_wall_s": round(wall, 1),
        "update_s": update_s,
        "reused": reused,
        "history": history,
        "full_wal_bytes": full_wal,
        "update_wal_bytes": wal,
        "readers": reader.report(),
        "published": {"files": pub[0], "new_files": pub[1], "new_bytes": pub[2]} if pub else None,
    }


def section(s: dict[str, Any] | None) -> list[str]:
    if not s:
        return []
    c, u, f = s["change"], s["update_s"], s["full_s"]
    ratio = s["update_wall_s"] / s["full_total_s"]
    out = [
        "## Updates: a change file against the full rebuild",
        "",
        f"{s['extract']}: a change file for {c['chosen']:,} of its {c['building_ways']:,} building ways (1 %, "
        f"the ones nearest the centre of the data: {c['tag_edits']:,} height edits, {c['nodes_moved']:,} nodes "
        f"moved by 0.5 m) applied with `python -m etl update --osc … --out …` to the database the full "
        f"pipeline built. Command: `python -m benchmarks.update_bench --write BENCHMARKS.md`"
        + (f" (machine: {s['machine']})" if s.get("machine") else "")
        + ". Target: the "
        f"update ≤ 5 % of the full rebuild. Measured: {s['update_wall_s']:.1f} s against "
        f"{s['full_total_s']:.1f} s, {100 * ratio:.1f} %. osm.building_change: "
        + ", ".join(f"{n:,} {k}" for k, n in sorted(s["changed"].items()))
        + "."
        + _wal(s),
        "",
    ]
    out += markdown_table(
        ["stage", "full rebuild s", "update s"], [[st, f.get(st, ""), u.get(st, "")] for st in STAGES], "lrr"
    )
    v = s.get("verified")
    if v is not None:
        same = not v["tables_differing"] and not v["tiles_differing"]
        out += [
            "",
            "Equivalence: a full rebuild from the update's OSM state file (the base file with the change "
            "applied) into another database, then compared: "
            + (
                "every table row for row and all " + f"{v['tiles']:,} files of the tileset byte for byte equal."
                if same
                else f"tables that differ (rows): {v['tables_differing']}; files that differ: "
                f"{len(v['tiles_differing'])} of {v['tiles']:,} ({', '.join(v['tiles_differing'][:3])}, ...)."
            ),
        ]
    if "no_building_wall_s" in s:
        q = s["no_building_s"]
        out += [
            "",
            "A change that touches no building (one new tagged node) after it: "
            f"{s['no_building_wall_s']:.1f} s (ingest {q.get('ingest', '?')} s, export {q.get('export', '?')} "
            "s; lod ... textures carried over, not run).",
        ]
    if "one_building_wall_s" in s:
        o = s["one_building_s"]
        out += [
            "",
            "A change of one building (a height edit, the building nearest the centre) after that: "
            f"{s['one_building_wall_s']:.1f} s, {100 * s['one_building_wall_s'] / s['full_total_s']:.0f} % of "
            "the full rebuild (" + ", ".join(f"{st} {o[st]} s" for st in STAGES if st in o) + "): about what any "
            "update pays before the work its change brings (one building's tiles are a few): the stages' passes "
            "over the whole city and their fixed costs.",
        ]
    if rd := s.get("readers"):
        odd = rd["odd_counts"]
        out += [
            "",
            "An analyst meanwhile (`Reader` in benchmarks/update_bench.py): while another such change was "
            f"applied (not timed), one connection counted the rows of the {rd['tables']} tables the stages "
            "write and the root tile's content (api.buildings_for_tile) over and over, each read giving up "
            f"after {Reader.LOCK_TIMEOUT_MS} ms on a lock: {rd['rounds']:,} rounds, {rd['lock_timeouts']:,} reads "
            "gave up, "
            + (
                "no table seen emptied or half written (every count the one before or the one after the update)"
                if not odd
                else f"tables seen with other counts: {odd}"
            )
            + f"; stages seen running: {', '.join(rd['running'])}.",
        ]
    pub = s.get("published") or {}
    r = s.get("reused") or {}
    g, t, e = r.get("generalize") or {}, r.get("textures") or {}, r.get("export") or {}
    i = r.get("ingest") or {}
    read = (
        f"reads the OSM state again (libosmium's pass over the whole file) but stages only the candidates the "
        f"change touched ({_n(i.get('staged'))} of {_n(i.get('in'))}: the ways it names or whose nodes it moved, "
        "and every relation)"
        if i.get("partial")
        else "reads the whole OSM state"
    )

    def batches(step: str) -> str:
        b = g.get(step) or {}
        return f"{b.get('computed', '?')} of {b.get('computed', 0) + b.get('kept', 0) or '?'}"

    out += [
        "",
        "Seconds are each stage's own (meta.pipeline_run.duration_s); the update's total is the wall time "
        f"of its one process, applying the change file included. The update: ingest {read} "
        "and replaces only the rows that differ; lod draws those buildings (with their outlines and parts) "
        "alone; landmarks and tiles run over the whole city again; generalize computes the footprint and "
        f"decimation batches and the block tiles whose input changed ({batches('footprints')}, "
        f"{batches('decimation')} and {batches('blocks')}; the others' rows stay as they are, as do, in the "
        f"block tiles made again, the {_n(g.get('blocks_kept'))} blocks whose inputs did not change) and the "
        f"hierarchy of the {g.get('hierarchy_tiles', '?')} tiles the update's runs reached (ARCHITECTURE.md, "
        f"Updates, step 9); textures fingerprints those ({t.get('tiles_fingerprinted', '?')}) and textures the "
        f"tiles whose input changed ({(t.get('tiles') or 0) - (t.get('tiles_kept') or 0) or '?'} of "
        f"{t.get('tiles', '?')}, and draws {t.get('tiles_redrawn', '?')} kept ones again for a chart cache); "
        f"the export fingerprints {e.get('glb_fingerprinted', '?')} glbs and builds those whose input changed "
        f"({e.get('glb_built', '?')} of {e.get('glb', '?')}; the others are copied) and publishes "
        f"{pub.get('new_files', '?')} new files of {pub.get('files', '?')}.",
        "",
    ]
    out += _floor(s)
    return out + history_section(s.get("history"))


def _floor(s: dict[str, Any]) -> list[str]:
    """What the update cannot skip while a tile is what textures and the export make again: the features of the
    tiles the change reaches, at the full rebuild's seconds per feature of those two stages; and what stands
    between the update and the 5 % target: that floor when it is above, else the rest of the update."""
    r = s.get("reused") or {}
    t, e, f = r.get("textures") or {}, r.get("export") or {}, s["full_s"]
    if not (
        t.get("features")
        and t.get("features_textured") is not None
        and e.get("features")
        and e.get("features_built") is not None
        and f.get("textures")
        and f.get("export")
    ):
        return []
    share_t, share_e = t["features_textured"] / t["features"], e["features_built"] / e["features"]
    floor = f["textures"] * share_t + f["export"] * share_e
    share = floor / s["full_total_s"]
    if share > 0.05:
        then = (
            "the target needs less work than making those tiles again (pages that survive a change of their tile "
            "would keep about half of those pages: ARCHITECTURE.md, Updates, step 8), not a faster pass over "
            "the city."
        )
    else:
        u = s["update_s"]
        passes = ", ".join(f"{st} {u[st]:.1f} s" for st in ("ingest", "landmarks", "tiles") if st in u)
        then = (
            f"here that is within the target; the other {s['update_wall_s'] - floor:.1f} s of the update hold "
            f"what stands between it and the target, the stages' passes over the whole city ({passes}, and "
            f"part of generalize's {u.get('generalize', 0):.1f} s: each reads every building again to find or "
            "place what changed), which a change-driven design (the changed tiles handed from stage to stage) "
            "would leave out."
        )
    return [
        f"What a tile-by-tile update cannot skip: the tiles the change reaches (its leaves, their LOD2 and LOD1 "
        "tiles and every block tile up to the root) hold "
        f"{t['features_textured']:,} of the {t['features']:,} features textures handles ({100 * share_t:.1f} %; "
        f"the glbs built {e['features_built']:,} of {e['features']:,}, {100 * share_e:.1f} %). Texturing and "
        f"exporting those alone, at the full rebuild's seconds per feature, takes {floor:.1f} s, "
        f"{100 * share:.1f} % of the full rebuild, before any other stage: " + then,
        "",
    ]


def _n(v: object) -> str:
    return f"{v:,}" if isinstance(v, int) else "?"


def history_section(h: dict[str, Any] | None) -> list[str]:
    """The real change's paragraph and table (measure_history)."""
    if not h:
        return []
    c, t = h["created"], (h.get("reused") or {}).get("textures") or {}
    e = (h.get("reused") or {}).get("export") or {}
    out = [
        "### A real change",
        "",
        f"The same extract as it was on {h['before']}, as far as its own versions and timestamps tell "
        "(`python -m tests.support.history`: every object at version 1 stamped after that day left out), built in "
        f"full in another database, then updated with the change file of what mappers created since "
        f"({c['ways']:,} ways, {c['relations']:,} relations, {c['nodes']:,} nodes; osm.building_change: "
        + ", ".join(f"{n:,} {k}" for k, n in sorted(h["changed"].items()))
        + "). "
        f"Measured: {h['update_wall_s']:.1f} s against that full rebuild's {h['full_total_s']:.1f} s, "
        f"{100 * h['update_wall_s'] / h['full_total_s']:.0f} %; textures made "
        f"{(t.get('tiles') or 0) - (t.get('tiles_kept') or 0)} of {t.get('tiles', '?')} tiles again (and drew "
        f"{t.get('tiles_redrawn', '?')} kept ones again for a chart cache), the export built "
        f"{e.get('glb_built', '?')} of {e.get('glb', '?')} glbs. Unlike the 1 % above, these edits are spread "
        "over the whole extract, as two and a half months of a country's mapping are: the tiles they touch, "
        "and their ancestors, are what an update makes again.",
        "",
    ]
    out += markdown_table(
        ["stage", "full rebuild s", "update s"],
        [[st, h["full_s"].get(st, ""), h["update_s"].get(st, "")] for st in STAGES],
        "lrr",
    )
    v = h.get("verified")
    if v is not None:
        same = not v["tables_differing"] and not v["tiles_differing"]
        out += [
            "",
            "Equivalence with the full rebuild of the extract itself (the first one above, before its own "
            "update): "
            + (
                f"every table row for row and all {v['tiles']:,} files equal (tileset.json but for "
                "its tilesetVersion, the sha256 of the OSM file read)."
                if same
                else f"tables that differ (rows): {v['tables_differing']}; files that differ: "
                f"{v['tiles_differing'][:5]}."
            ),
            "",
        ]
    return out


def measure_larger(osm: Path, admin_url: str, db: str = UPDATE_DB + "_larger") -> dict[str, Any]:
    """Steps 1 to 3 of the module doc alone (no history, no equivalence check, no second update) on a larger
    city: how the update's share of the full rebuild moves with the city's size."""
    name = extract_name(osm)
    logs = LOG_DIR / name / "update-larger"
    out = OUT_ROOT / "update" / name
    url, env, full, full_wal = _full_build(osm, admin_url, db, "update-larger", out, logs)
    made, last, wall, wal = _update_one_percent(osm, url, env, out, logs)
    with psycopg.connect(url) as conn:
        (buildings,) = conn.execute("SELECT count(*) FROM osm.building").fetchone()  # type: ignore[misc]
    return {
        "extract": name,
        "buildings": int(buildings),
        "change": made,
        "changed": _changed(url),
        "full_s": full,
        "full_total_s": round(sum(full.values()), 1),
        "update_wall_s": round(wall, 1),
        "update_s": stage_seconds(url, last),
        "reused": _reused(url, last),
        "full_wal_bytes": full_wal,
        "update_wal_bytes": wal,
    }


def _wal(s: dict[str, Any]) -> str:
    """The WAL sentence, when the figures are there."""
    if not (s.get("update_wal_bytes") and s.get("full_wal_bytes")):
        return ""
    u, f = s["update_wal_bytes"], s["full_wal_bytes"]
    return (
        f" WAL written (each from a checkpoint, so every page's first change is written whole): the update "
        f"{u / 1e6:.0f} MB, the full rebuild {f / 1e6:.0f} MB ({100 * u / f:.0f} %)."
    )


def section_larger(s: dict[str, Any] | None) -> list[str]:
    if not s:
        return []
    c, u, f, r = s["change"], s["update_s"], s["full_s"], s["reused"]
    t, e = r.get("textures") or {}, r.get("export") or {}
    out = [
        "## Updates at scale: the same change on a larger city",
        "",
        f"{s['extract']} ({s['buildings']:,} buildings): the change of *Updates* made the same way for this "
        f"city ({c['chosen']:,} of its {c['building_ways']:,} building ways, 1 %, nearest the centre of the "
        f"data: {c['tag_edits']:,} height edits, {c['nodes_moved']:,} nodes moved by 0.5 m) and applied the "
        "same way, without the history, the equivalence check and the second update. Command: "
        "`python -m benchmarks.update_bench --larger --osm build/bench/scale/liechtenstein_2022-07-24-x6.osm.pbf "
        "--write BENCHMARKS.md`"
        + (f" (machine: {s['machine']})" if s.get("machine") else "")
        + " (the file: `python -m benchmarks.replicate "
        "../shared/data/osm/liechtenstein_2022-07-24.osm.pbf 6 …`, as the scale bench makes it). Measured: "
        f"{s['update_wall_s']:.1f} s against {s['full_total_s']:.1f} s, "
        f"{100 * s['update_wall_s'] / s['full_total_s']:.1f} % (target on the benchmark extract: ≤ 5 %); "
        f"textures made {(t.get('tiles') or 0) - (t.get('tiles_kept') or 0) or '?'} of {t.get('tiles', '?')} "
        f"tiles again, the export built {e.get('glb_built', '?')} of {e.get('glb', '?')} glbs." + _wal(s),
        "",
    ]
    out += markdown_table(
        ["stage", "full rebuild s", "update s"], [[st, f.get(st, ""), u.get(st, "")] for st in STAGES], "lrr"
    )
    return out + [""] + _floor(s)


def main(argv: list[str] | None = None) -> int:
    args = list(sys.argv[1:] if argv is None else argv)
    if "--larger" in args:  # steps 1 to 3 on a larger city, into a section of its own
        args.remove("--larger")
        return section_bench(
            args,
            "python -m benchmarks.update_bench --larger",
            __doc__ or "",
            DEFAULT_OSM,
            UPDATE_DB + "_larger",
            measure_larger,
            section_larger,
            "## Updates at scale",
        )
    return section_bench(
        args,
        "python -m benchmarks.update_bench",
        __doc__ or "",
        DEFAULT_OSM,
        UPDATE_DB,
        measure,
        section,
        "## Updates:",
    )


if __name__ == "__main__":
    raise SystemExit(main())
