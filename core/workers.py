"""Units of work as Dask tasks that one hung or crashed unit cannot stop: ``imap_isolated(fn, items, ...)``.

The engine is Dask distributed: by default a ``LocalCluster`` of ``workers`` single-threaded worker processes
(spawned, never forked: the caller holds database connections and native thread pools), or the existing cluster
whose scheduler ``CITYLOD_DASK_SCHEDULER=tcp://host:port`` names (its workers run this repository's code in the
same environment and reach the same PostGIS; ``workers`` is then the cluster's business). Every item is one
task; ``fn`` gets it on whichever worker the scheduler picks, after ``initializer(*initargs)`` has run once in
that worker process (e.g. to open its database connection).

What a stage needs beyond a pool, kept from the process pool this replaced:

* a hung unit loses only itself: each task arms faulthandler's watchdog (a C thread, so it fires inside native
  code holding the GIL too), which prints the worker's Python stacks to its stderr and ends the process after
  ``timeout`` seconds; a task still running ``GRACE_S`` later (its watchdog did not fire) has its worker
  restarted by its nanny from here, and one that returns past ``timeout`` (its watchdog thread got no core in
  time on a loaded machine) ends its worker as the watchdog would have: the limit decides, not the load;
* a crashed unit (a signal, an abort in native code) loses only itself;
* a worker that dies is replaced and its task is run once more on another worker
  (``distributed.scheduler.allowed-failures`` = ``ALLOWED_FAILURES`` on the local cluster), so a worker killed
  from outside loses nothing; a task whose workers die ``ALLOWED_FAILURES + 1`` times comes back as a ``Lost``,
  "hung" when its last attempt ran past the time limit, "crashed" otherwise, and the caller records its units;
* results come back in item order, but a worker that finishes is given the next item at once (finished items
  wait in a bounded buffer), so one long item does not idle the others;
* an exception raised by ``fn`` is the caller's bug and is raised here as a ``WorkerError`` with the worker's
  traceback;
* within ``shared_cluster(workers)`` (an update runs its stages in one process) every call uses
  one local cluster, its workers warm with the stages' imports, instead of starting and stopping its own (about
  1 s each); it starts in a thread while the caller goes on; a call still runs at most ``workers`` of its items
  at once;
* the local cluster is closed at the end, its worker processes killed if they will not exit; a local worker
  whose stage process died (kill -9: no cleanup runs) ends with it, as Dask's worker processes watch their
  parent (tests/db/test_crash.py).
"""

from __future__ import annotations

import concurrent.futures
import contextlib
import faulthandler
import hashlib
import importlib
import logging
import multiprocessing
import os
import pickle
import sys
import threading
import time
import traceback
import uuid
from collections.abc import Callable, Iterable, Iterator
from dataclasses import dataclass
from typing import Any

SCHEDULER_ENV = "CITYLOD_DASK_SCHEDULER"
ALLOWED_FAILURES = 1  # a task is run again once after its worker died; the second death loses it
GRACE_S = 30.0  # after the watchdog's own exit should have happened
EXIT_WAIT_S = 10.0
POLL_S = 0.2
NO_WORKER_S = 120.0
SLOW_S = 120.0  # a unit running this long is named on stderr (once): the stream waits for it
BUFFER_PER_THREAD = 16  # finished items held for in-order yield, per cluster thread, when no window is given
_END = object()
_SHARED: dict[str, Any] = {}  # "client": the future of the shared_cluster of this process, while one is open


@dataclass(frozen=True)
class Lost:
    """An item whose worker died on it: ``reason`` "hung" (past the timeout) or "crashed"."""

    reason: str
    seconds: float

    @property
    def detail(self) -> str:
        if self.reason == "hung":
            return f"its worker ran {self.seconds:.0f} s, past the time limit; its stacks went to stderr"
        return f"its worker died after {self.seconds:.1f} s, on every attempt; its stacks went to the worker's stderr"


class WorkerError(RuntimeError):
    """``fn`` raised in a worker (the item is not lost: the caller's code is at fault); carries its traceback."""


# --- in the worker process ---------------------------------------------------------------------------------

_READY: set[str] = set()


def _run_item(
    fn: Callable[[Any], Any],
    initializer: Callable[..., None] | None,
    initargs: tuple,
    token: str,
    timeout: float,
    item: Any,
) -> Any:
    if token not in _READY:
        faulthandler.enable()  # a fatal signal in native code prints the Python stacks too
        if initializer is not None:
            initializer(*initargs)
        _READY.add(token)
    t0 = time.monotonic()
    faulthandler.dump_traceback_later(timeout, exit=True)
    try:
        out = fn(item)
    finally:
        faulthandler.cancel_dump_traceback_later()
    if time.monotonic() - t0 > timeout:
        # past the limit, but the watchdog thread did not get a core in time (a loaded machine): the item ends as
        # the watchdog would have ended it, so the limit decides, not the scheduler (stacks: this one, as it ends)
        faulthandler.dump_traceback(all_threads=False)
        os._exit(1)
    return out


# --- in the caller -----------------------------------------------------------------------------------------


@contextlib.contextmanager
def dask_client(workers: int) -> Iterator[Any]:
    """A Client on ``CITYLOD_DASK_SCHEDULER``'s cluster, else on shared_cluster's, else on a fresh LocalCluster of
    ``workers`` processes."""
    from distributed import Client

    address = os.environ.get(SCHEDULER_ENV)
    if not address and "client" in _SHARED:
        yield _SHARED["client"].result()  # shared_cluster's, once started (it closes it)
        return
    if address:
        client = Client(address, timeout=30)
        try:
            yield client
        finally:
            client.close()
        return
    with _local_client(workers) as client:
        yield client


@contextlib.contextmanager
def _local_client(workers: int) -> Iterator[Any]:
    """A Client on a fresh LocalCluster of ``workers`` processes, closed (its processes killed if need be) at the
    end."""
    import dask
    from distributed import Client, LocalCluster

    with dask.config.set(
        {
            "distributed.scheduler.allowed-failures": ALLOWED_FAILURES,
            "distributed.worker.multiprocessing-method": "spawn",
            "distributed.worker.daemon": True,
            "distributed.scheduler.worker-saturation": 1.0,
            # Dask's default adds MALLOC_TRIM_THRESHOLD_, which turns off glibc's dynamic mmap
            # threshold: every large numpy temporary is then a fresh mmap, page-faulted and
            # unmapped again (the textures stage ran 1.5x slower per unit, measured)
            "distributed.nanny.pre-spawn-environ": {
                "OMP_NUM_THREADS": 1,
                "MKL_NUM_THREADS": 1,
                "OPENBLAS_NUM_THREADS": 1,
            },
            # a worker's own sampling competes with its task for the GIL and the cores
            "distributed.worker.profile.enabled": False,
            "distributed.worker.memory.monitor-interval": "1s",
            "distributed.admin.system-monitor.interval": "2s",
        }
    ):
        before = {p.pid for p in multiprocessing.active_children()}
        cluster = LocalCluster(
            n_workers=workers,
            threads_per_worker=1,
            processes=True,
            dashboard_address=":0",
            silence_logs=logging.CRITICAL,
            scheduler_port=0,
        )
        client = Client(cluster)
        try:  # within the settings: a nanny reads them again when it restarts its worker
            yield client
        finally:
            client.close()
            _close_cluster(cluster, before)


def _import(names: tuple[str, ...]) -> None:
    """In a worker: import ``names`` (a warm-up, so the first task does not pay for them)."""
    for name in names:
        importlib.import_module(name)


@contextlib.contextmanager
def shared_cluster(workers: int, warm: tuple[str, ...] = (), close_later: bool = False) -> Iterator[None]:
    """Within: every imap_isolated of this process runs on one local cluster of ``workers`` processes (none is
    started when CITYLOD_DASK_SCHEDULER names a cluster: the calls use that one as always). The cluster starts
    in a thread while the caller goes on (an update reads its OSM file meanwhile: about 1.3 s to start it and
    0.7 s for a worker's first imports, measured), its workers importing the modules ``warm`` names; a call
    waits for it only when it needs it. ``close_later``: the cluster closes in a thread after the block (about
    0.4 s) while the caller goes on; the interpreter waits for that thread before it exits."""
    if os.environ.get(SCHEDULER_ENV) or "client" in _SHARED:
        yield
        return
    stack = contextlib.ExitStack()

    def start() -> Any:
        client = stack.enter_context(_local_client(workers))
        if warm:
            with contextlib.suppress(Exception):  # a warm-up: an import that fails fails the task that needs it
                client.run(_import, tuple(warm))
        return client

    pool = concurrent.futures.ThreadPoolExecutor(1, thread_name_prefix="citylod-cluster")
    future = pool.submit(start)
    pool.shutdown(wait=False)
    _SHARED["client"] = future
    try:
        yield
    finally:
        _SHARED.pop("client", None)

        def close() -> None:
            with contextlib.suppress(Exception):  # a cluster that failed to start: its error went to its users
                future.result()
            stack.close()

        if close_later:
            threading.Thread(target=close, name="citylod-cluster-close").start()  # not a daemon: joined at exit
        else:
            close()


def _close_cluster(cluster: Any, before: set[int | None]) -> None:
    """Close the local cluster; worker processes that do not exit in time (static destructors of native
    libraries have hung process exits) are killed, so the caller never waits on a process it no longer needs.
    Only this cluster's: the worker processes spawned since it was made (``before``: the children then)."""
    with contextlib.suppress(Exception):
        cluster.close(timeout=EXIT_WAIT_S)
    # the nannies' processes, spawned from here; a restart still under way can start one late
    deadline = time.monotonic() + EXIT_WAIT_S
    while time.monotonic() < deadline:
        left = [
            p
            for p in multiprocessing.active_children()
            if p.name.startswith("Dask Worker process") and p.pid not in before
        ]
        if not left:
            break
        for proc in left:
            proc.kill()
            proc.join(1.0)
        time.sleep(POLL_S)


def worker_count(setting: int, default: int) -> int:
    """How many workers a stage asks for: its setting when given; else 2 when CITYLOD_DASK_SCHEDULER names a
    cluster (any count above one uses it: its workers, not this count, do the work); else ``default``."""
    if setting:
        return setting
    return 2 if os.environ.get(SCHEDULER_ENV) else default


def _token(fn: Callable[..., Any], initializer: Callable[..., None] | None, initargs: tuple) -> str:
    blob = pickle.dumps((fn.__module__, fn.__qualname__, initializer and initializer.__qualname__, initargs))
    return hashlib.sha1(blob).hexdigest()[:12]


def imap_isolated(
    fn: Callable[[Any], Any],
    items: Iterable[Any],
    workers: int,
    timeout: float,
    initializer: Callable[..., None] | None = None,
    initargs: tuple = (),
    window: int | None = None,
) -> Iterator[Any]:
    """``fn(item)`` for every item as Dask tasks, yielded in item order; an item whose worker hung (past
    ``timeout`` seconds) or died on every attempt yields a ``Lost`` instead. ``fn`` and ``initializer``
    must be importable module-level functions. An exception raised by ``fn`` is re-raised as WorkerError.
    ``items`` is read lazily: at most ``window`` items (None: ``BUFFER_PER_THREAD`` per cluster thread) are
    running or finished and not yet yielded, so a stream of batches is never held whole, while a worker that
    finishes is given the next item at once instead of waiting for an earlier, longer item to be yielded."""
    if workers < 1 or timeout <= 0 or (window is not None and window < 1):
        raise ValueError("workers must be >= 1, timeout > 0 and window >= 1")
    source = iter(items)
    first = next(source, _END)
    if first is _END:
        return
    from distributed import wait

    token = _token(fn, initializer, initargs)
    prefix = f"citylod-{fn.__name__}-{uuid.uuid4().hex[:8]}-"  # this run's task keys
    with dask_client(workers) as client:
        flight: dict[int, tuple[str, Any]] = {}  # item index -> (key, future)
        done: dict[int, Any] = {}  # item index -> result or Lost, finished out of order, not yet yielded
        submitted = 0
        pending: Any = first

        def submit() -> None:
            # never more in flight than the cluster has threads: a task queued behind another on a worker would
            # die with that worker (and count a failure) and be timed from when it was queued
            nonlocal submitted, pending
            threads = max(1, sum(client.nthreads().values()))
            if "client" in _SHARED:  # a shared cluster may have more workers than this call asked for
                threads = min(threads, workers)
            held = window if window is not None else BUFFER_PER_THREAD * threads
            while pending is not _END and len(flight) < threads and len(flight) + len(done) < held:
                key = f"{prefix}{submitted}"
                flight[submitted] = (
                    key,
                    client.submit(_run_item, fn, initializer, initargs, token, timeout, pending, key=key, pure=False),
                )
                submitted += 1
                pending = next(source, _END)

        started: dict[str, tuple[str, float]] = {}  # key -> (worker, when this attempt was first seen running)
        ran: dict[str, float] = {}  # key -> how long its last finished attempt was seen running
        alive = [time.monotonic()]  # when the cluster last had a worker
        slow: set[str] = set()  # keys said to be slow
        i = 0
        try:
            submit()
            while flight or done:
                if i in done:
                    out = done.pop(i)
                    i += 1
                    submit()
                    yield out
                    continue
                with contextlib.suppress(TimeoutError):
                    wait([f for _, f in flight.values()], timeout=POLL_S, return_when="FIRST_COMPLETED")
                _watch(client, started, ran, timeout, alive, prefix, slow)
                for j, (key, fut) in list(flight.items()):
                    if fut.done():
                        done[j] = _settle(key, fut, j, started, ran, timeout)
                        del flight[j]
                        fut.release()  # its result leaves the cluster once taken
                submit()
        finally:
            client.cancel([f for _, f in flight.values()])


def _settle(
    key: str, fut: Any, index: int, started: dict[str, tuple[str, float]], ran: dict[str, float], timeout: float
) -> Any:
    """A finished task's result, or a Lost when its workers died on every attempt."""
    from distributed import KilledWorker

    try:
        return fut.result()
    except KilledWorker:
        seconds = time.monotonic() - started[key][1] if key in started else ran.get(key, 0.0)
        # seen running up to a poll late: a watchdog exit at the limit must not read as a crash
        return Lost("hung" if seconds + 2 * POLL_S >= timeout else "crashed", seconds)
    except Exception as e:  # noqa: BLE001 -- the caller's code raised in the worker
        tb = "".join(traceback.format_exception(type(e), e, e.__traceback__))
        raise WorkerError(f"item {index} raised in its worker:\n{tb}") from None
    finally:
        started.pop(key, None)
        ran.pop(key, None)


def _watch(
    client: Any,
    started: dict[str, tuple[str, float]],
    ran: dict[str, float],
    timeout: float,
    alive: list[float],
    prefix: str,
    slow: set[str],
) -> None:
    """Note when each running task started and how long its last attempt ran (a retry runs on another worker),
    and restart the worker of a task past ``timeout`` + GRACE_S, whose watchdog should have ended it. A cluster
    left without any worker for NO_WORKER_S (a nanny that could not start its replacement on a machine under
    heavy load) fails the run with that message instead of waiting forever."""
    now = time.monotonic()
    try:
        processing = client.processing()
    except Exception:  # noqa: BLE001 -- the scheduler is busy replacing a worker; look again next poll
        processing = None
    if processing:
        alive[0] = now
    elif now - alive[0] > NO_WORKER_S:  # no worker, or no answer from the scheduler, for that long
        raise RuntimeError(
            f"the Dask cluster has had no worker for {NO_WORKER_S:.0f} s "
            f"({os.environ.get(SCHEDULER_ENV) or 'the local cluster'}): its workers died and none "
            "came back; the unit's stacks are in the workers' stderr"
        )
    if processing is None:
        return
    running = {str(k) for keys in processing.values() for k in keys if str(k).startswith(prefix)}
    for key in [k for k in started if k not in running]:
        ran[key] = now - started.pop(key)[1]
    for worker, keys in processing.items():
        for key in keys:
            if not str(key).startswith(prefix):  # another run's, on a shared cluster
                continue
            seen = started.get(key)
            item = str(key)[len(prefix) :]
            if seen is None or seen[0] != worker:
                if seen is not None:
                    ran[key] = now - seen[1]
                    _say(f"item {item} moved to {worker} after {now - seen[1]:.0f} s on {seen[0]} (retried)")
                started[key] = (worker, now)
            elif now - seen[1] > timeout + GRACE_S:
                _say(f"item {item} has run {now - seen[1]:.0f} s on {worker}, past the limit: restarting it")
                with contextlib.suppress(Exception):
                    client.restart_workers([worker], timeout=EXIT_WAIT_S)
                started[key] = (worker, now - timeout)  # its next attempt, if any, is judged from here
            elif now - seen[1] > SLOW_S and key not in slow:
                slow.add(key)  # said once: a stall of the in-order stream is then explained in the log
                _say(f"item {item} has run {now - seen[1]:.0f} s on {worker} (still running)")


def _say(line: str) -> None:
    print(f"  workers: {line}", file=sys.stderr, flush=True)
