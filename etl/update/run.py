"""The update: OSM change files applied to the database, then every stage below ingest run again in update mode
through the stage contract (etl/runner.py), each recorded as its own run, and the export.

1. The change files not applied yet are applied to the OSM state (etl/update/osc.py), which meta.osm_change
   records with ingest's run.
2. Ingest reads the new state in update mode: only the buildings that differ are replaced (osm.building_change).
   When the database's last ingest read the state before these changes with this code and these settings, only
   what the change files touched is read again.
3. No building changed (and the working CRS stayed): every stage current before is carried over
   (runner.carry_over), the others run. Else the stages run in the steps of the stage graph
   (core/pipeline.py ``update_steps``: landmarks and tiles side by side); a stage current before the update
   knows what changed since its last run (``ctx.changed``) and redoes only that; each keeps what its last run
   made where its input did not change (core/reuse.py).
4. With an output directory, the export, which copies the glbs of the tiles no change reached.

One Dask cluster serves every stage's workers (started while ingest reads the state, warm with their imports).
"""

from __future__ import annotations

import concurrent.futures
import contextlib
import importlib
import os
import sys
import threading
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

import psycopg
from psycopg.types.json import Jsonb

from core.db import connect
from core.pipeline import BY_NAME, FIRST, update_steps
from core.settings import Settings
from core.workers import shared_cluster
from etl import runner
from etl.ingest.stage import Input
from etl.runs import sha256_file
from etl.update import osc
from exporter.export import Options as ExportOptions

#: The stages whose functions an update sends to the workers (imported there while ingest runs).
WARM_WORKERS = ("lod", "generalize", "textures")
#: The stages run in this process whose import is on the update's critical path: landmarks (scipy: about 0.6 s,
#: while tiles, beside it, waits on PostgreSQL), imported in a thread while ingest reads the state file.
WARM_HERE = ("landmarks",)


@dataclass(frozen=True)
class New:
    """A change file not applied yet, its sha256, its objects by action and type, and its meta.osm_change row."""

    path: Path
    sha256: str
    counts: dict[str, dict[str, int]]
    seq: int = 0
    state_sha256: str = ""


def _new_changes(files: list[Path], chain: osc.Chain) -> list[New]:
    """The files not applied yet, numbered after the chain, each with the sha256 of the state it leads to."""
    applied = {c.sha256: c.seq for c in chain.changes}
    new: list[New] = []
    state = chain.state_sha256
    for f in files:
        sha = sha256_file(f)
        if sha in applied:
            print(f"update: {f} was applied already (change {applied[sha]}): skipped", file=sys.stderr)
            continue
        state = osc.next_state_sha256(state, sha)
        new.append(New(f, sha, osc.count_change(f), len(chain.changes) + len(new) + 1, state))
    return new


def _only_nodes_created(new: list[New]) -> bool:
    """No way or relation of the state can refer to nodes just created: no building changes."""
    return all(
        n == 0
        for c in new
        for action, by_type in c.counts.items()
        for kind, n in by_type.items()
        if (action, kind) != ("create", "node")
    )


def _import_all(stages: tuple[str, ...]) -> None:
    for s in stages:
        with contextlib.suppress(Exception):  # a warm-up: an import that fails fails the stage that needs it
            importlib.import_module(BY_NAME[s].module)


@contextlib.contextmanager
def _workers(settings: Settings, skip: bool) -> Iterator[None]:
    """One cluster for the stages' workers, not one started and stopped by each (about 1 s apiece), started
    while ingest reads the OSM state and closed while the export runs; not for a change that only adds nodes:
    the stages are carried over (a cluster started for nothing took 2.1 s more of such an update, its start
    competing with ingest for the cores)."""
    if skip:
        yield
        return
    n = max(min(4, os.cpu_count() or 1), settings.lod_workers, settings.gen_workers, settings.tex_workers)
    with shared_cluster(n, warm=tuple(BY_NAME[s].module for s in WARM_WORKERS), close_later=True):
        # the stages that run in this process import their modules while ingest reads the state file
        threading.Thread(target=_import_all, args=(WARM_HERE,), name="citylod-warm", daemon=True).start()
        yield


def _ingest(chain: osc.Chain, new: list[New], state: Path, settings: Settings) -> dict[str, object]:
    """Ingest the new state in update mode, meta.osm_change's new rows in its transaction; its counts."""
    shas = [c.sha256 for c in chain.changes] + [n.sha256 for n in new]
    # the ingest that made the database read the state before these changes, with this code and these settings:
    # only what the changes touched need be read again (etl/ingest/stage.py)
    before = runner.Call(FIRST, file=osc.file_input(chain, [c.sha256 for c in chain.changes]))
    touched = osc.change_ids(n.path for n in new) if runner.is_current(before, settings) else None

    def record(cur: psycopg.Cursor, run_id: int) -> None:
        for n in new:
            cur.execute(
                "INSERT INTO meta.osm_change (seq, path, sha256, base_file, base_sha256, state_sha256, "
                "run_id, counts) VALUES (%s, %s, %s, %s, %s, %s, %s, %s)",
                (
                    n.seq,
                    str(n.path),
                    n.sha256,
                    str(chain.base_file),
                    chain.base_sha256,
                    n.state_sha256,
                    run_id,
                    Jsonb(n.counts),
                ),
            )

    file_sha = sha256_file(state)  # the dataset's sha256, as a full ingest of this file records it
    call = runner.Call(
        FIRST,
        options=Input(state, file_sha, touched, record),
        file=osc.file_input(chain, shas),
        params={"osm": str(state), "update": [n.seq for n in new]},
        input_file=state,
        input_sha256=file_sha,
    )
    result = runner.run(call, settings, mode="update")
    assert result is not None
    return result.counts


def apply(settings: Settings, files: list[Path], export: ExportOptions | None = None) -> int:
    """Apply the change files ``files`` in order and derive again what they changed; with ``export``, export
    (and publish) the tileset too."""
    for f in files:
        if not f.is_file():
            print(f"update: change file not found: {f}", file=sys.stderr)
            return 2
    url = runner.url_of(settings)
    with connect(url, autocommit=True) as conn:
        chain = osc.read_chain(conn)
        srid = conn.execute("SELECT srid FROM meta.dataset").fetchone()
    new = _new_changes(files, chain)
    if not new:
        print("update: nothing new to apply")
        return 0
    previous = osc.ensure_state(chain)
    state = osc.state_path(new[-1].state_sha256)
    osc.apply_changes(previous, [n.path for n in new], state)
    below = [s for step in update_steps() for s in step]
    # the stages current before the update (same upstream runs, settings and code): only these may redo just
    # what the update changed, or be carried over
    current = {s for s in below if runner.is_current(runner.Call(s), settings)}
    with _workers(settings, skip=_only_nodes_created(new)):
        counts = _ingest(chain, new, state, settings)
        osc.drop_previous_state(chain, state)  # the chain now ends at ``state``
        with connect(url, autocommit=True) as conn:
            same_srid = conn.execute("SELECT srid FROM meta.dataset").fetchone() == srid
        changed = counts["changed"]
        assert isinstance(changed, dict)
        if not any(changed.values()) and same_srid:
            _carry(below, current, settings)
        else:
            _steps(current, settings)
    if export is not None:
        runner.run(export_call(export), settings, if_stale=True, mode="update")
    return 0


def _carry(below: list[str], current: set[str], settings: Settings) -> None:
    """No building changed: what the stages below derived stands as it is (they read osm.building and the
    working CRS, nothing else ingest writes); each current one is recorded again, with the inputs it has now,
    instead of doing its work again. A stage that was not current runs, and so does every stage after it."""
    print("update: no building changed", file=sys.stderr)
    for i, stage in enumerate(below):
        if stage not in current:
            for rest in below[i:]:
                runner.run(runner.Call(rest), settings, if_stale=True)
            return
        runner.carry_over(stage, settings)


def _steps(current: set[str], settings: Settings) -> None:
    """The stages in the steps of the stage graph, each in update mode; the stages of a step side by side (none
    reads another's tables: on the two cores of a small machine, a whole-city pass each)."""

    def one(stage: str) -> None:
        runner.run(runner.Call(stage), settings, if_stale=True, mode="update", knows_changes=stage in current)

    for step in update_steps():
        with concurrent.futures.ThreadPoolExecutor(len(step)) as pool:
            list(pool.map(one, step))


def export_call(o: ExportOptions) -> runner.Call:
    """The export of ``o`` as the command line and the update run it: what its run records and compares."""
    stream = o.stream.as_dict()
    return runner.Call(
        "export",
        options=o,
        out=o.out,
        recorded_options={"out": str(o.out), "lod": o.lod, **stream, "publish": o.publish_as},
        # a one-LOD tileset has no textures (exporter/export.py): it reads up to generalize
        reads=("generalize",) if o.lod else None,
        params={"out": str(o.out), "lod": o.lod, **stream, "publish": o.publish_as},
    )
