"""Worker processes that one hung or crashed item cannot stop: ``imap_isolated(fn, items, ...)``.

A stage that hands its items to native code (xatlas, OpenImageIO) in worker processes needs what
concurrent.futures cannot give: to know which item a dead worker was on, and to go on without it. Here each
worker takes one item at a time over its own pipe, so the parent always knows it; a worker that dies (a
signal, an abort in native code) or runs past ``timeout`` loses only that item, which comes back as a
``Lost``; a fresh worker takes the next one. Hangs are caught twice: faulthandler's watchdog thread in the
worker (it needs no GIL, so it fires inside native code too) prints every thread's Python stack to stderr
and exits, and the parent kills a worker that is still on its item ``GRACE_S`` later. A worker that will not
exit at the end (static destructors of native libraries have hung process exits) is killed too, so the
caller never waits on a process it no longer needs.

Workers are spawned, never forked: the parent holds database connections and native thread pools.
"""

from __future__ import annotations

import contextlib
import faulthandler
import multiprocessing
import time
import traceback
from collections import deque
from collections.abc import Callable, Iterable, Iterator
from dataclasses import dataclass
from multiprocessing.connection import Connection, wait
from typing import Any

GRACE_S = 30.0  # after the watchdog's own exit should have happened
EXIT_WAIT_S = 10.0


@dataclass(frozen=True)
class Lost:
    """An item whose worker died on it: ``reason`` "hung" (past the timeout) or "crashed"."""

    reason: str
    exitcode: int | None
    seconds: float

    @property
    def detail(self) -> str:
        if self.reason == "hung":
            return f"its worker ran {self.seconds:.0f} s, past the time limit; its stacks went to stderr"
        return f"its worker died (exit code {self.exitcode}) after {self.seconds:.1f} s; its stacks went to stderr"


class WorkerError(RuntimeError):
    """``fn`` raised in a worker (the item is not lost: the caller's code is at fault); carries its traceback."""


def _serve(conn: Connection, fn: Callable[[Any], Any], initializer: Callable[..., None] | None,
           initargs: tuple, timeout: float) -> None:
    faulthandler.enable()  # a fatal signal in native code prints the Python stacks too
    if initializer is not None:
        initializer(*initargs)
    while (msg := conn.recv()) is not None:
        i, item = msg
        faulthandler.dump_traceback_later(timeout, exit=True)
        try:
            out = (i, True, fn(item))
        except Exception:  # noqa: BLE001 -- sent to the parent, which raises it
            out = (i, False, traceback.format_exc())
        finally:
            faulthandler.cancel_dump_traceback_later()
        conn.send(out)
    conn.close()


@dataclass
class _Worker:
    proc: multiprocessing.process.BaseProcess
    conn: Connection
    item: int | None = None
    since: float = 0.0


def imap_isolated(fn: Callable[[Any], Any], items: Iterable[Any], workers: int, timeout: float,
                  initializer: Callable[..., None] | None = None, initargs: tuple = ()) -> Iterator[Any]:
    """``fn(item)`` for every item in ``workers`` spawned processes, yielded in item order; an item whose
    worker hung (past ``timeout`` seconds) or died yields a ``Lost`` instead. ``fn`` and ``initializer``
    must be importable module-level functions. An exception raised by ``fn`` is re-raised as WorkerError."""
    if workers < 1 or timeout <= 0:
        raise ValueError("workers must be >= 1 and timeout > 0")
    ctx = multiprocessing.get_context("spawn")
    todo = deque(enumerate(items))
    n = len(todo)
    done: dict[int, Any] = {}
    pool: list[_Worker] = []

    def start() -> None:
        parent, child = ctx.Pipe()
        proc = ctx.Process(target=_serve, args=(child, fn, initializer, initargs, timeout), daemon=True)
        proc.start()
        child.close()
        pool.append(_Worker(proc, parent))

    def feed(w: _Worker) -> None:
        if not todo:
            return
        i, item = todo.popleft()
        w.item, w.since = i, time.monotonic()
        try:
            w.conn.send((i, item))
        except OSError:  # it died between items: the item was never its own
            todo.appendleft((i, item))
            w.item = None
            lose(w, "crashed")

    def lose(w: _Worker, reason: str) -> None:
        w.proc.kill()
        w.proc.join()
        w.conn.close()
        pool.remove(w)
        if w.item is not None:
            done[w.item] = Lost(reason, w.proc.exitcode, time.monotonic() - w.since)
        if todo:
            start()
            feed(pool[-1])

    try:
        for _ in range(min(workers, n)):
            start()
        for w in pool:
            feed(w)
        nxt = 0
        while nxt < n:
            while nxt in done:
                yield done.pop(nxt)
                nxt += 1
            if nxt >= n:
                break
            busy = [w for w in pool if w.item is not None]
            now = time.monotonic()
            limit = min(w.since + timeout + GRACE_S for w in busy) - now
            ready = wait([w.conn for w in busy], timeout=max(limit, 0.0))
            for w in [w for w in busy if w.conn in ready]:
                try:
                    i, ok, out = w.conn.recv()
                except (EOFError, OSError):
                    lose(w, "hung" if time.monotonic() - w.since >= timeout else "crashed")
                    continue
                if not ok:
                    raise WorkerError(f"item {i} raised in its worker:\n{out}")
                done[i] = out
                w.item = None
                feed(w)
            for w in [w for w in busy if w.conn not in ready and time.monotonic() - w.since > timeout + GRACE_S]:
                lose(w, "hung")
    finally:
        for w in pool:
            with contextlib.suppress(OSError):
                w.conn.send(None)
        deadline = time.monotonic() + EXIT_WAIT_S
        for w in pool:
            w.proc.join(max(0.0, deadline - time.monotonic()))
            if w.proc.is_alive():
                w.proc.kill()
                w.proc.join()
            w.conn.close()
