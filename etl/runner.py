"""Running a stage through its contract (core/stage.py): the staleness check, the run record, the context.

``run(call, settings)`` is what ``python -m etl <stage>`` and the update (etl/update/) do for every stage: compare
the inputs the stage's last successful run recorded with today's (etl/staleness.py; with ``if_stale`` a current
stage is skipped in one line, before its module is imported, so a skip costs no numpy), record the run in
meta.pipeline_run (etl/runs.py), make the context, call the stage's ``run(ctx)`` and record what it returns: its
counts and, in an update, what it changed (core/changes.py), after the stage's commit.
"""

from __future__ import annotations

import importlib
import json
import sys
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from core import changes, cluster
from core.db import connect
from core.pipeline import BY_NAME
from core.settings import Settings
from core.stage import Context, Mode, Result
from etl import staleness
from etl.runs import pipeline_run


@dataclass(frozen=True)
class Call:
    """One stage to run, with what it alone takes."""

    stage: str
    #: the stage's ``ctx.options`` (ingest: its Input; export: its Options)
    options: Any = None
    #: recorded with the run's inputs: the input file (ingest) and the options (export) a later run compares
    file: dict[str, object] | None = None
    recorded_options: dict[str, object] | None = None
    #: what the stage reads, when not its graph's (a one-LOD export reads up to generalize)
    reads: tuple[str, ...] | None = None
    #: the export's directory: its files are part of being current, and its last run is the last one into it
    out: Path | None = None
    #: recorded in meta.pipeline_run.params besides the settings
    params: dict[str, object] = field(default_factory=dict)
    #: recorded in meta.pipeline_run.input_file / input_sha256
    input_file: Path | None = None
    input_sha256: str | None = None


def url_of(settings: Settings) -> str:
    return cluster.ensure(settings)


def inputs(call: Call, settings: Settings) -> dict[str, object]:
    """What the run of ``call`` records as its inputs now (etl/staleness.py)."""
    with connect(url_of(settings), autocommit=True) as conn:
        return staleness.inputs(
            conn, call.stage, settings, reads=call.reads, file=call.file, options=call.recorded_options
        )


def is_current(call: Call, settings: Settings) -> bool:
    with connect(url_of(settings), autocommit=True) as conn:
        return staleness.verdict(conn, call.stage, inputs(call, settings), call.out)[0]


def run(
    call: Call, settings: Settings, *, if_stale: bool = False, mode: Mode = "full", knows_changes: bool = False
) -> Result | None:
    """Run ``call``'s stage and record it; None when ``if_stale`` finds it current. ``knows_changes`` (an
    update of a stage that was current before it): the context carries what the runs since its last one
    changed (core/changes.py), so the stage may redo only that."""
    url = url_of(settings)
    stage = call.stage
    with connect(url, autocommit=True) as conn:
        now = staleness.inputs(conn, stage, settings, reads=call.reads, file=call.file, options=call.recorded_options)
        if if_stale:
            current, line = staleness.verdict(conn, stage, now, call.out)
            print(f"{line}; {'skipped' if current else 'running'}", flush=True)
            if current:
                return None
        last = staleness.last_run(conn, stage, str(call.out) if call.out else None)
        last_run = last.run_id if last else None
        changed = changes.since(conn, stage, last_run) if mode == "update" and knows_changes else None
    module = importlib.import_module(BY_NAME[stage].module)  # after the check: a skip imports no numpy
    params = {**settings.as_dict(), **({"update": True} if mode == "update" else {}), **call.params}
    with (
        pipeline_run(url, stage, params, call.input_file, input_sha256=call.input_sha256, inputs=now) as rec,
        connect(url) as conn,
    ):
        ctx = Context(
            conn,
            url,
            settings,
            rec.run_id,
            code=json.dumps([now["code"], now["settings"]], sort_keys=True),
            mode=mode,
            changed=changed,
            last_run=last_run,
            options=call.options,
        )
        result: Result = module.run(ctx)
        # what an update's run changed, for the stages after it (a stage says it only when it knows it whole)
        if mode == "update" and result.changed is not None:
            changes.record(conn, rec.run_id, result.changed)
            conn.commit()
        rec.counts = result.counts
        rec.output = result.output
    return result


def carry_over(stage: str, settings: Settings) -> None:
    """Record ``stage``'s last successful run again, with the inputs it has now, instead of doing its work
    again: an update that changed no building leaves what the stage derived as it is. It changed nothing."""
    url = url_of(settings)
    with connect(url, autocommit=True) as conn:
        now = staleness.inputs(conn, stage, settings)
        last = staleness.last_run(conn, stage)
    assert last is not None
    with (
        pipeline_run(url, stage, {"carried_from": last.run_id}, inputs=now) as carried,
        connect(url, autocommit=True) as conn,
    ):
        carried.counts = {**(last.counts or {}), "carried_from": last.run_id}
        changes.record(conn, carried.run_id, changes.Changes())
    print(f"{stage}: unchanged by the update; run {last.run_id} carried over", file=sys.stderr)
