"""The balance every stage prints and records, in = out + rejected (core/progress.py Balance, etl/runs.py)."""

from __future__ import annotations

import pytest

from core.progress import Balance, BalanceError, summary
from etl.runs import check_balance


def test_a_balance_that_adds_up_prints_and_records_itself(capsys) -> None:
    b = Balance("buildings and parts", 17_790, {"drawn": 17_700, "outlines drawn by their parts": 80}, 10)
    assert b.n_out == 17_780
    assert b.text() == "in 17,790 buildings and parts = 17,700 drawn + 80 outlines drawn by their parts + rejected 10"
    assert b.counts() == {
        "in": 17_790,
        "out": 17_780,
        "rejected": 10,
        "unit": "buildings and parts",
        "out_by_kind": {"drawn": 17_700, "outlines drawn by their parts": 80},
    }
    line = summary("lod", b, "triangles 1,234", 2.0, 17_790)
    assert line == (
        "lod: in 17,790 buildings and parts = 17,700 drawn + 80 outlines drawn by their parts + "
        "rejected 10 | triangles 1,234 | 2.00 s | 8,895 buildings/s"
    )
    assert capsys.readouterr().out == line + "\n"
    check_balance("lod", b.counts())


@pytest.mark.parametrize(("n_in", "out", "rejected"), [(10, {"a": 9}, 0), (10, {"a": 9, "b": 2}, 0), (10, {}, 11)])
def test_a_balance_that_does_not_add_up_is_an_error(n_in: int, out: dict[str, int], rejected: int) -> None:
    with pytest.raises(BalanceError, match="lost"):
        Balance("features", n_in, out, rejected)


@pytest.mark.parametrize(
    "counts", [{}, {"in": 3, "out": 3}, {"in": 3, "out": 2, "rejected": 0}, {"in": "x", "out": 1, "rejected": 0}]
)
def test_a_run_without_a_balance_that_adds_up_is_refused(counts: dict[str, object]) -> None:
    with pytest.raises(BalanceError):
        check_balance("tiles", counts)
