"""The test harness' own guard: a subprocess that hangs fails its test with the stacks of every Python process
it started, instead of hanging the suite until CI's time limit."""

from __future__ import annotations

import textwrap

import pytest

from tests.conftest import run_py

HUNG = textwrap.dedent("""
    import subprocess, sys, time

    CHILD = "import time\\ndef child_sleeps():\\n    time.sleep(600)\\nchild_sleeps()"

    def parent_waits_for_child():
        subprocess.run([sys.executable, "-c", CHILD])

    parent_waits_for_child()
""")


def test_a_hung_run_fails_with_the_stacks_of_its_process_group() -> None:
    with pytest.raises(AssertionError) as err:
        run_py(["-c", HUNG], timeout=3)
    msg = str(err.value)
    assert "did not finish in 3 s" in msg
    # faulthandler's dump of both processes: the stage-like parent and the worker-like child it waits on
    assert "parent_waits_for_child" in msg and "child_sleeps" in msg


def test_a_finished_run_returns_its_output_and_a_failed_one_raises() -> None:
    done = run_py(["-c", "print('out'); import sys; print('err', file=sys.stderr)"])
    assert (done.returncode, done.stdout, done.stderr) == (0, "out\n", "err\n")
    with pytest.raises(AssertionError, match=r"failed \(3\)"):
        run_py(["-c", "raise SystemExit(3)"])
    assert run_py(["-c", "raise SystemExit(3)"], check=False).returncode == 3
