"""core/workers.py: a hung or crashed item loses only itself, in item order, with its stacks on stderr; an
exception in the item's code is raised; a worker that hangs on its way out is killed, never waited on."""

from __future__ import annotations

import atexit
import faulthandler
import multiprocessing
import os
import threading
import time

import pytest

from core import workers as W


def behave(item: tuple[str, int]) -> int:
    kind, value = item
    if kind == "hang":
        time.sleep(3600)
    elif kind == "stubborn":  # as if the watchdog could not end it: the parent must
        faulthandler.cancel_dump_traceback_later()
        time.sleep(3600)
    elif kind == "late":  # as if the watchdog thread got no core before the item returned, past its limit
        faulthandler.cancel_dump_traceback_later()
        time.sleep(1.5)
    elif kind == "abort":
        os.abort()
    elif kind == "raise":
        raise ValueError(f"bad item {value}")
    return value * 2


def wait_for(item: tuple[str, str]) -> str:
    """("wait", path): until ``path`` exists (up to 20 s); ("touch", path): create it."""
    kind, path = item
    if kind == "touch":
        open(path, "w").close()
        return "touched"
    deadline = time.monotonic() + 20.0
    while time.monotonic() < deadline:
        if os.path.exists(path):
            return "released"
        time.sleep(0.05)
    return "never released"


def hang_at_exit() -> None:
    atexit.register(time.sleep, 3600)


def test_hung_and_crashed_items_are_lost_alone_in_order(capfd: pytest.CaptureFixture[str]) -> None:
    items = [("ok", 1), ("hang", 0), ("ok", 2), ("abort", 0), ("ok", 3), ("ok", 4), ("ok", 5)]
    # a limit well above the seconds a loaded machine takes to notice a dead worker, which count as running
    out = list(W.imap_isolated(behave, items, workers=2, timeout=6.0, window=3))
    assert out[0] == 2 and out[2] == 4 and out[4:] == [6, 8, 10]
    hung, crashed = out[1], out[3]
    assert isinstance(hung, W.Lost) and hung.reason == "hung" and hung.seconds >= 6.0 - 2 * W.POLL_S
    assert isinstance(crashed, W.Lost) and crashed.reason == "crashed"
    assert "time limit" in hung.detail and "died" in crashed.detail
    err = capfd.readouterr().err
    # faulthandler in the workers: the watchdog's dump of the hung item, the fatal-signal dump of the abort
    assert "Timeout (0:00:06)" in err and "Fatal Python error: Aborted" in err
    assert err.count("in behave") >= 2
    assert not multiprocessing.active_children()


def test_the_parent_kills_a_hung_worker_its_watchdog_did_not_end(
    monkeypatch: pytest.MonkeyPatch, capfd: pytest.CaptureFixture[str]
) -> None:
    monkeypatch.setattr(W, "GRACE_S", 1.0)
    monkeypatch.setattr(W, "SLOW_S", 0.5)
    out = list(W.imap_isolated(behave, [("stubborn", 0), ("ok", 1)], workers=1, timeout=1.0))
    assert isinstance(out[0], W.Lost) and out[0].reason == "hung" and out[0].seconds >= 1.0 and out[1] == 2
    assert not multiprocessing.active_children()
    # what held the stream up is in the log: the slow item once, then its restart
    err = capfd.readouterr().err
    assert err.count("workers: item 0 has run") >= 2 and "(still running)" in err
    assert "past the limit: restarting it" in err


def test_an_item_that_returns_past_its_limit_is_lost_as_hung() -> None:
    """The limit decides, not whether the watchdog thread got a core in time on a loaded machine (CI once drew
    3 of Helsinki's lod batches under a 1 ms limit that way)."""
    out = list(W.imap_isolated(behave, [("late", 5), ("ok", 1)], workers=1, timeout=1.0))
    assert isinstance(out[0], W.Lost) and out[0].reason == "hung" and out[1] == 2, out
    assert not multiprocessing.active_children()


def test_an_exception_in_the_items_code_is_raised_with_its_traceback() -> None:
    with pytest.raises(W.WorkerError, match=r"ValueError: bad item 7"):
        list(W.imap_isolated(behave, [("ok", 1), ("raise", 7), ("ok", 2)], workers=2, timeout=30.0))
    assert not multiprocessing.active_children()


def test_a_worker_that_hangs_at_exit_is_killed(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(W, "EXIT_WAIT_S", 1.0)
    out = list(
        W.imap_isolated(behave, [("ok", i) for i in range(5)], workers=2, timeout=30.0, initializer=hang_at_exit)
    )
    assert out == [0, 2, 4, 6, 8]
    assert not multiprocessing.active_children()


def test_more_workers_than_items_and_bad_arguments() -> None:
    assert list(W.imap_isolated(behave, [("ok", 21)], workers=4, timeout=30.0)) == [42]
    assert list(W.imap_isolated(behave, [], workers=2, timeout=30.0)) == []
    with pytest.raises(ValueError):
        list(W.imap_isolated(behave, [("ok", 1)], workers=0, timeout=30.0))


def test_items_are_read_as_the_window_moves() -> None:
    pulled: list[int] = []

    def stream():
        for i in range(8):
            pulled.append(i)
            yield ("ok", i)

    seen = [(out, len(pulled)) for out in W.imap_isolated(behave, stream(), workers=1, timeout=30.0, window=2)]
    assert [o for o, _ in seen] == [2 * i for i in range(8)]
    # when result k is handed out, at most the window (2) past it plus the one read ahead have been read
    assert all(n <= k + 4 for k, (_, n) in enumerate(seen)), seen
    with pytest.raises(ValueError):
        list(W.imap_isolated(behave, stream(), workers=1, timeout=30.0, window=0))


def test_a_free_worker_takes_the_next_items_while_an_earlier_one_runs(tmp_path) -> None:
    # item 0 runs until the last item has run: only a worker that is refilled as soon as it finishes, not when
    # the first item in order is yielded, reaches the last item while item 0 still runs
    flag = str(tmp_path / "flag")
    items = [("wait", flag)] + [("wait", "/")] * 4 + [("touch", flag)]
    out = list(W.imap_isolated(wait_for, items, workers=2, timeout=60.0))
    assert out == ["released"] * 5 + ["touched"]


def pid(_: object) -> int:
    return os.getpid()


def running(item: tuple[str, int]) -> int:
    """Creates ``path.N`` while it runs (N: its index), and returns how many of them existed at once at most."""
    path, i = item
    mine = f"{path}.{i}"
    open(mine, "w").close()
    most = 0
    for _ in range(10):
        most = max(most, sum(1 for f in os.listdir(os.path.dirname(path)) if f.startswith(os.path.basename(path))))
        time.sleep(0.05)
    os.unlink(mine)
    return most


def test_calls_within_a_shared_cluster_use_its_warm_workers_and_keep_their_own_limit(tmp_path) -> None:
    apart = [set(W.imap_isolated(pid, range(4), workers=2, timeout=30.0)) for _ in range(2)]
    assert not apart[0] & apart[1], "each call outside a shared cluster starts workers of its own"
    with W.shared_cluster(2):
        calls = [set(W.imap_isolated(pid, range(6), workers=2, timeout=30.0)) for _ in range(3)]
        one = list(W.imap_isolated(running, [(str(tmp_path / "run"), i) for i in range(4)], workers=1, timeout=30.0))
    # three calls, one cluster: its two worker processes ran every item (three own clusters: six processes)
    assert len(set.union(*calls)) <= 2 and os.getpid() not in set.union(*calls), calls
    assert max(one) == 1, "a call asking for one worker runs one item at a time on a cluster of two"
    assert "client" not in W._SHARED


def imported(names: tuple[str, ...]) -> list[bool]:
    """Which of ``names`` the worker running this has imported."""
    import sys

    return [n in sys.modules for n in names]


def test_a_shared_cluster_starts_while_its_caller_goes_on_and_closes_after_it() -> None:
    # a module no task imports: only the warm-up can have brought it into the workers
    warm = ("xml.dom.minidom",)
    before = {p.pid for p in multiprocessing.active_children()}
    with W.shared_cluster(2, warm=warm, close_later=True):
        started = W._SHARED["client"]
        assert not started.done(), "the block runs while the cluster starts, not after"
        seen = list(W.imap_isolated(imported, [warm] * 4, workers=2, timeout=30.0))
        workers = {p.pid for p in multiprocessing.active_children()} - before
    assert seen == [[True]] * 4, "the workers imported the warm modules before their first task"
    closing = [t for t in threading.enumerate() if t.name == "citylod-cluster-close"]
    assert closing and "client" not in W._SHARED, "the cluster closes in a thread while the caller goes on"
    for t in closing:
        t.join(30.0)
    assert workers and not workers & {p.pid for p in multiprocessing.active_children()}, "its workers are gone"
