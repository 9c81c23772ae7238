"""etl/textures/xatlas_run.py: an xatlas atlas is destroyed only once its worker threads wait, so xatlas::Destroy
never misses a sleeping worker (its join hung for ever: a texturing unit stuck until its watchdog)."""

from __future__ import annotations

import subprocess
import sys
import threading
import time
from pathlib import Path

import numpy as np
import pytest

from etl.textures import xatlas_run
from etl.textures.procedural import chart_uvs

REPO = Path(__file__).resolve().parents[2]

# Many small atlases, back to back, from two processes on a busy machine: each atlas's destruction is a chance
# for the lost wake-up. Without the wait, each of four such loops on a busy 2-core machine hung: after the 668th,
# 730th, 1,138th and 93,557th atlas. About 0.2 ms an atlas.
ATLASES = 20_000
STRESS = """
import sys
import numpy as np, xatlas
from etl.textures.xatlas_run import generate
v = np.array([[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0], [0.5, 0.5, 0.7]], np.float32)
f = np.array([[0, 1, 4], [1, 2, 4], [2, 3, 4], [3, 0, 4]], np.uint32)
po = xatlas.PackOptions(); po.resolution = 0; po.texels_per_unit = 8.0
for _ in range(int(sys.argv[1])):
    generate(lambda a: a.add_mesh(v, f), lambda a: a.get_mesh(0), pack_options=po)
print("done")
"""


def test_an_atlas_is_destroyed_once_its_workers_sleep(monkeypatch: pytest.MonkeyPatch) -> None:
    before = xatlas_run._threads()
    seen: list[str | None] = []
    workers: set[str] = set()
    real = xatlas_run.wait_asleep

    def wait(tids: set[str], limit_s: float = xatlas_run.PARK_WAIT_S) -> bool:
        ok = real(tids, limit_s)
        seen.extend(xatlas_run.thread_state(t) for t in tids)
        workers.update(tids)
        return ok

    monkeypatch.setattr(xatlas_run, "wait_asleep", wait)
    v = np.array([[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0], [0.5, 0.5, 0.7]], float)
    c = chart_uvs(v, np.array([[0, 1, 4], [1, 2, 4], [2, 3, 4], [3, 0, 4]]), texels_per_metre=8.0)
    assert len(c.faces) == 4 and c.size_m[0] > 0
    # the atlas started its workers (hardware_concurrency - 1, at least one); all were asleep when it was let go,
    # and are joined now
    assert seen and all(s == "S" for s in seen), seen
    # (its own threads: one a session fixture's cluster or pool starts meanwhile is not the atlas's). pthread_join
    # returns once the kernel cleared the thread's id, a moment before /proc/self/task drops it: give it that
    # moment (a worker never joined sleeps on and stays listed)
    assert workers and not workers & before
    deadline = time.monotonic() + 10.0
    while workers & xatlas_run._threads() and time.monotonic() < deadline:
        time.sleep(0.01)
    assert not workers & xatlas_run._threads()


def test_thread_state_reads_the_kernels_letter() -> None:
    main = str(threading.get_native_id())
    assert xatlas_run.thread_state(main) == "R"  # this thread, reading its own state
    assert xatlas_run.thread_state("0") is None
    assert xatlas_run.wait_asleep({"0"}, 0.1)  # gone counts as asleep
    assert not xatlas_run.wait_asleep({main}, 0.05)  # a running thread is waited for, then given up


def test_many_atlases_never_hang() -> None:
    procs = [
        subprocess.Popen([sys.executable, "-c", STRESS, str(ATLASES)], cwd=REPO, stdout=subprocess.PIPE, text=True)
        for _ in range(2)
    ]
    try:
        for p in procs:
            out, _ = p.communicate(timeout=300)  # a hung Destroy never returns: TimeoutExpired fails the test
            assert p.returncode == 0 and out.strip() == "done"
    finally:
        for p in procs:
            p.kill()
