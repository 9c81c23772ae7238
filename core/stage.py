"""The stage contract: every stage is ``run(ctx: Context) -> Result``.

The command line (etl/runner.py) makes the context once the stage is found stale and its run is recorded in
meta.pipeline_run; the update (etl/update/) makes the same contexts in update mode. A stage reads tables,
writes tables in one transaction on ``ctx.conn``, and returns its counts (with its balance: in = out +
rejected) and, when it knows it whole, what it changed, which the runs of the stages after it read back as
``ctx.changed`` (core/changes.py).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING, Any, Literal

if TYPE_CHECKING:
    import psycopg

    from .changes import Changes
    from .settings import Settings

Mode = Literal["full", "update"]


@dataclass(frozen=True)
class Context:
    #: the stage's own connection: everything it writes, in one transaction it commits
    conn: psycopg.Connection
    #: the database, for connections of its own (a reader beside the writer, worker processes)
    url: str
    settings: Settings
    #: its meta.pipeline_run row
    run_id: int
    #: the stage's code and the settings it reads, as its run records them (etl/staleness.py): the seed of its
    #: fingerprints, so new code never keeps what old code made
    code: str = ""
    #: "full": everything from the stage's input; "update": the output of the last run stays where its input
    #: did not change (core/reuse.py), and only the rest is made again
    mode: Mode = "full"
    #: what the runs of the stages it reads changed since its last successful run began, when that is known
    #: whole (an update of a stage that was current before it); None: anything may have changed
    changed: Changes | None = None
    #: that last successful run (of the export: into the same directory), None when there is none
    last_run: int | None = None
    #: what this stage alone takes: ingest its input file, export its directory and stream
    options: Any = None

    @property
    def update(self) -> bool:
        return self.mode == "update"


@dataclass
class Result:
    #: recorded in meta.pipeline_run.counts; must hold the balance (core/progress.py)
    counts: dict[str, object]
    #: what the run changed (buildings, tiles), when it knows it whole; an update records it (meta.run_dirty)
    changed: Changes | None = None
    #: what the run wrote outside the database (the export's tileset), recorded when it ends well
    output: dict[str, object] | None = None
