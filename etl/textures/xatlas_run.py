"""xatlas runs whose atlas is destroyed only once its worker threads sleep: ``generate(add, read, **options)``.

Every xatlas ``Atlas`` starts a task scheduler with hardware_concurrency() - 1 worker threads (at least one).
Destroying the atlas sets a shutdown flag, then sets each worker's wake-up flag and notifies its condition
variable *without holding the worker's mutex*, then joins the worker. A worker that has just found no task and
checked its wake-up flag, but is not yet waiting, misses that notification and waits for ever: the join never
returns, and it holds the GIL (xatlas 0.0.11, the jpcy/xatlas TaskScheduler it builds). Seen as a texturing
unit stuck in ``xatlas::Destroy`` until its watchdog ended the worker (491 s lost in a scale bench run; likely
too the test that once took 600 s, the unit time-out, longer than usual); four loops of small atlases on a busy
2-core machine hung after 668 to 93,557 atlases (loops like tests/unit/test_textures_xatlas_run.py's).

After ``generate()`` has returned every task has finished, so a worker thread the kernel reports as sleeping
is waiting on its condition variable (the only place it sleeps), registered there, and the notification will
wake it: ``generate`` waits for that (a few microseconds; ``PARK_WAIT_S`` at most) before letting the atlas go.
The worker threads are the ones the atlas's constructor started (/proc/self/task before and after). Without
/proc (not Linux) nothing is waited for.
"""

from __future__ import annotations

import os
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any, TypeVar

T = TypeVar("T")

PARK_WAIT_S = 2.0  # then the atlas is destroyed anyway: a thread that never sleeps is not an xatlas worker
_TASKS = Path("/proc/self/task")


def _threads() -> set[str]:
    try:
        return set(os.listdir(_TASKS))
    except OSError:
        return set()


def thread_state(tid: str) -> str | None:
    """The kernel's one-letter state of thread ``tid`` of this process (R running, S sleeping, ...), None when
    it is gone."""
    try:
        stat = (_TASKS / tid / "stat").read_bytes()
    except OSError:
        return None
    return chr(stat[stat.rindex(b")") + 2])  # "tid (comm) S ...": comm may hold spaces and parentheses


def wait_asleep(tids: set[str], limit_s: float = PARK_WAIT_S) -> bool:
    """Wait until every thread of ``tids`` sleeps or is gone; False if one still ran after ``limit_s``."""
    deadline = time.monotonic() + limit_s
    while True:
        if all(thread_state(t) in (None, "S", "Z", "X") for t in tids):
            return True
        if time.monotonic() > deadline:
            return False
        os.sched_yield()


def generate(add: Callable[[Any], None], read: Callable[[Any], T], **options: Any) -> T:
    """A new xatlas Atlas: ``add(atlas)`` adds its meshes, ``atlas.generate(**options)`` charts and packs them,
    ``read(atlas)`` returns what the caller needs (never the atlas itself: it is destroyed here)."""
    import xatlas

    before = _threads()
    atlas = xatlas.Atlas()
    workers = _threads() - before
    try:
        add(atlas)
        atlas.generate(**options)
        return read(atlas)
    finally:
        wait_asleep(workers)
        del atlas  # the only reference: xatlas::Destroy runs here, its workers waiting to be woken
