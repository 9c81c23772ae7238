"""A stage killed with kill -9 leaves no run 'running' for ever and no worker behind: its Dask workers end
themselves, and the next stage to start records the run as failed at its last heartbeat (etl/runs.py,
meta.reap_dead_runs); a command that fails before any run is written does not claim to have recorded one."""

import os
import signal
import subprocess
import sys
import time

import psutil

from tests.conftest import REPO, run_etl


def _wait(cond, timeout: float, what: str) -> None:
    deadline = time.monotonic() + timeout
    while not cond():
        if time.monotonic() > deadline:
            raise AssertionError(f"no {what} after {timeout:g} s")
        time.sleep(0.1)


def _alive(pids: list[int]) -> list[int]:
    out = []
    for pid in pids:
        try:
            if psutil.Process(pid).status() != psutil.STATUS_ZOMBIE:
                out.append(pid)
        except psutil.NoSuchProcess:
            pass
    return out


def test_a_killed_stage_is_failed_at_its_last_heartbeat_and_its_workers_end(city, conn_of, tmp_path) -> None:
    c = city("fixtures")
    conn = conn_of(c.url)
    watch = conn_of(c.url)
    # export's Dask workers read the landmarks; its own process does not (without publishing: a publishing export
    # first fingerprints every tile itself): with lm.building locked, the stage waits in its workers, alive,
    # until it is killed
    locker = conn_of(c.url)
    locker.autocommit = False
    locker.execute("LOCK TABLE lm.building IN ACCESS EXCLUSIVE MODE")
    before = watch.execute("SELECT coalesce(max(run_id), 0) FROM meta.pipeline_run").fetchone()[0]
    proc = subprocess.Popen(
        [sys.executable, "-m", "etl", "export", "--out", str(tmp_path / "tiles"), "--no-publish"],
        cwd=REPO,
        env={**os.environ, "DATABASE_URL": c.url, "CITYLOD_EXPORT_WORKERS": "2"},
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
        start_new_session=True,
    )
    try:
        stage = psutil.Process(proc.pid)
        _wait(
            lambda: (
                watch.execute(
                    "SELECT count(*) FROM pg_locks WHERE relation = 'lm.building'::regclass AND NOT granted"
                ).fetchone()[0]
                >= 1
            ),
            120,
            "worker waiting on lm.building",
        )
        run_id, status = watch.execute(
            "SELECT run_id, status FROM meta.pipeline_run WHERE run_id > %s AND stage = 'export'", (before,)
        ).fetchone()
        assert status == "running"
        workers = [p.pid for p in stage.children(recursive=True)]
        assert _alive(workers)
        time.sleep(6)  # a heartbeat after the first
        killed_at = watch.execute("SELECT now()").fetchone()[0]
        os.kill(proc.pid, signal.SIGKILL)
        proc.wait(10)
        # the workers notice their stage is gone and end themselves (their connections with them)
        _wait(lambda: not _alive(workers), 20, "end of the killed stage's workers")
    finally:
        locker.rollback()
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGKILL)
    assert conn.execute("SELECT status FROM meta.pipeline_run WHERE run_id = %s", (run_id,)).fetchone()[0] == "running"
    run_etl(c.url, "export", "--out", str(tmp_path / "again"))  # the next stage to start records it
    status, finished, beat, started, err = conn.execute(
        "SELECT status, finished_at, heartbeat_at, started_at, error FROM meta.pipeline_run WHERE run_id = %s",
        (run_id,),
    ).fetchone()
    assert status == "failed" and "died without recording its end" in err
    assert finished == beat and started < beat <= killed_at
    assert (killed_at - beat).total_seconds() < 5 + 2  # within a heartbeat of its death
    assert conn.execute("SELECT count(*) FROM meta.pipeline_run WHERE status = 'running'").fetchone()[0] == 0


def test_a_stage_that_reaches_no_database_claims_no_record(tmp_path) -> None:
    proc = run_etl(f"postgresql://nobody@/none?host={tmp_path}", "lod", check=False)
    assert proc.returncode != 0
    assert "recorded as failed" not in proc.stderr and "CITYLOD_DEBUG=1 shows the traceback" in proc.stderr


def test_a_failed_stage_says_it_was_recorded(new_db) -> None:
    url = new_db("crash_record")
    proc = run_etl(url, "lod", check=False)  # nothing ingested: lod refuses, and its run says so
    assert proc.returncode != 0 and "recorded as failed in meta.pipeline_run" in proc.stderr
