"""The test harness' own guards: a subprocess that hangs fails its test with the stacks of every Python process
it started, instead of hanging the suite until CI's time limit; a test reads a shared extract only when marked
``extracts``, and a missing one fails it with one line that says how to get it."""

from __future__ import annotations

import textwrap

import pytest

from tests.conftest import EXTRACTS, extract_path, run_py

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


class _Marked:
    """A test item marked ``extracts``."""

    nodeid = "tests/db/test_x.py::test_x"

    def get_closest_marker(self, name: str):
        return pytest.mark.extracts.mark if name == "extracts" else None


def test_an_unmarked_test_may_not_read_an_extract_even_when_it_is_there(request, tmp_path) -> None:
    (tmp_path / EXTRACTS["munich"]).write_bytes(b"")
    with pytest.raises(pytest.fail.Exception, match="test_harness.py::.* reads the munich extract but is not marked"):
        extract_path("munich", request.node, tmp_path)


def test_a_missing_extract_fails_with_one_line_saying_how_to_get_it(tmp_path) -> None:
    with pytest.raises(pytest.fail.Exception) as err:
        extract_path("london", _Marked(), tmp_path)
    msg = str(err.value)
    assert "\n" not in msg and not err.value.pytrace
    assert msg.startswith(f"test data missing: {tmp_path / 'london_city.osm.pbf'}")
    assert "../shared/data/osm" in msg and "CITYLOD_SHARED_DATA=" in msg
    (tmp_path / "london_city.osm.pbf").write_bytes(b"")
    assert extract_path("london", _Marked(), tmp_path) == tmp_path / "london_city.osm.pbf"
