"""meta.pipeline_run bookkeeping: one row per stage run, written at start and finished at the end, with the
inputs etl/staleness.py compares to decide whether the stage is current; a run is ok only with its balance
(in = out + rejected) in its counts."""

from __future__ import annotations

import hashlib
import json
import socket
import subprocess
import threading
import time
import traceback
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass, field
from pathlib import Path

import psycopg
from psycopg.types.json import Jsonb

from core.progress import BalanceError
from core.settings import REPO


def git_commit() -> str | None:
    try:
        sha = subprocess.run(
            ["git", "-C", str(REPO), "rev-parse", "HEAD"], capture_output=True, text=True, check=True
        ).stdout.strip()
        dirty = subprocess.run(
            ["git", "-C", str(REPO), "status", "--porcelain", "--untracked-files=no"],
            capture_output=True,
            text=True,
            check=True,
        ).stdout.strip()
        return sha + ("-dirty" if dirty else "")
    except (OSError, subprocess.CalledProcessError):
        return None


def sha256_file(path: Path, chunk: int = 1 << 20) -> str:
    h = hashlib.sha256()
    with path.open("rb") as fh:
        while block := fh.read(chunk):
            h.update(block)
    return h.hexdigest()


def _count(v: object) -> int:
    if not isinstance(v, int | float | str):
        raise TypeError(f"not a count: {v!r}")
    return int(v)


def check_balance(stage: str, counts: dict[str, object]) -> None:
    """A run ends well only with its balance recorded and adding up: ``in = out + rejected``
    (core.progress.Balance.counts)."""
    try:
        n_in, n_out, rejected = (_count(counts[k]) for k in ("in", "out", "rejected"))
    except (KeyError, TypeError, ValueError):
        raise BalanceError(f"{stage} recorded no balance (in, out, rejected) in its counts") from None
    if n_in != n_out + rejected:
        raise BalanceError(f"{stage}: in {n_in:,} != out {n_out:,} + rejected {rejected:,}")


@dataclass
class Run:
    run_id: int
    stage: str
    counts: dict[str, object] = field(default_factory=dict)
    #: what the run wrote outside the database (export), recorded when it ends well
    output: dict[str, object] | None = None
    started: float = field(default_factory=time.perf_counter)


#: advisory lock namespace of the runs ("clod"): a running stage holds (RUN_LOCK, run_id) while it lives
RUN_LOCK = int.from_bytes(b"clod", "big")
HEARTBEAT_S = 5.0
#: run_ids this process recorded as failed (the CLI says "recorded as failed" only for those)
recorded_failures: list[int] = []


def _heartbeat(conn: psycopg.Connection, run_id: int, stop: threading.Event) -> None:
    """heartbeat_at = now() every HEARTBEAT_S until ``stop``: the time a killed run is recorded as dying."""
    while not stop.wait(HEARTBEAT_S):
        try:
            conn.execute("UPDATE meta.pipeline_run SET heartbeat_at = now() WHERE run_id = %s", (run_id,))
        except psycopg.Error:  # the server went away: the run cannot be recorded now; the next start will
            return


@contextmanager
def pipeline_run(
    url: str,
    stage: str,
    params: dict[str, object],
    input_file: Path | None = None,
    input_sha256: str | None = None,
    inputs: dict[str, object] | None = None,
) -> Iterator[Run]:
    """Record a stage run. Uses its own autocommit connection so a failed stage still leaves its row.
    ``inputs`` (etl.staleness.inputs) is what a later --if-stale compares."""
    with psycopg.connect(url, autocommit=True) as conn:
        # runs whose process died without recording its end (kill -9, a server restart) are failed first
        conn.execute("SELECT * FROM meta.reap_dead_runs(%s)", (RUN_LOCK,))
        # the row is seen by others only once its lock is held: a reaper starting meanwhile must not fail it
        with conn.transaction():
            row = conn.execute(
                """INSERT INTO meta.pipeline_run (stage, status, params, input_file, input_sha256, git_commit,
                                                  host, inputs, heartbeat_at)
                   VALUES (%s, 'running', %s, %s, %s, %s, %s, %s, now()) RETURNING run_id""",
                (
                    stage,
                    Jsonb(json.loads(json.dumps(params, default=str))),
                    str(input_file) if input_file else None,
                    input_sha256 or (sha256_file(input_file) if input_file else None),
                    git_commit(),
                    socket.gethostname(),
                    Jsonb(inputs) if inputs is not None else None,
                ),
            ).fetchone()
            assert row is not None
            run = Run(run_id=row[0], stage=stage)
            # held by this connection until it ends, however it ends (a session lock outlives the transaction):
            # while it is held, the run is alive
            conn.execute("SELECT pg_advisory_lock(%s, %s)", (RUN_LOCK, run.run_id))
        stop = threading.Event()
        beat = threading.Thread(target=_heartbeat, args=(conn, run.run_id, stop), name="run-heartbeat", daemon=True)
        beat.start()
        try:
            try:
                yield run
            finally:
                stop.set()
                beat.join()
            check_balance(stage, run.counts)
        except BaseException as exc:
            conn.execute(
                """UPDATE meta.pipeline_run SET status = 'failed', finished_at = now(), duration_s = %s,
                   counts = %s, error = %s WHERE run_id = %s""",
                (
                    time.perf_counter() - run.started,
                    Jsonb(run.counts),
                    "".join(traceback.format_exception_only(type(exc), exc)).strip(),
                    run.run_id,
                ),
            )
            recorded_failures.append(run.run_id)
            raise
        conn.execute(
            """UPDATE meta.pipeline_run SET status = 'ok', finished_at = now(), duration_s = %s, counts = %s,
               output = %s WHERE run_id = %s""",
            (
                time.perf_counter() - run.started,
                Jsonb(run.counts),
                Jsonb(run.output) if run.output is not None else None,
                run.run_id,
            ),
        )
