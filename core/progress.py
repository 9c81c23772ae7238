"""Progress for long work: periodic counts with a rate on stderr, and the one-line stage summary with the
stage's balance (in = out + rejected)."""

from __future__ import annotations

import sys
import time
from dataclasses import dataclass


class Progress:
    """``update(n)`` as work proceeds; prints ``label: 12,345 objects (4,567/s)`` at most every ``every`` s."""

    def __init__(self, label: str, unit: str = "objects", every: float = 2.0, total: int | None = None):
        self.label = label
        self.unit = unit
        self.every = every
        self.total = total
        self.count = 0
        self.start = time.perf_counter()
        self._last = self.start

    def update(self, n: int = 1) -> None:
        self.count += n
        now = time.perf_counter()
        if now - self._last >= self.every:
            self._last = now
            self._print(now)

    def _print(self, now: float) -> None:
        rate = self.count / max(now - self.start, 1e-9)
        of = f"/{self.total:,}" if self.total else ""
        pct = f" {100 * self.count / self.total:5.1f}%" if self.total else ""
        print(f"  {self.label}: {self.count:,}{of} {self.unit}{pct} ({rate:,.0f}/s)", file=sys.stderr, flush=True)

    @property
    def elapsed(self) -> float:
        return time.perf_counter() - self.start


class BalanceError(RuntimeError):
    """A stage's output and rejects do not add up to its input: something was lost (or counted twice)."""


@dataclass(frozen=True)
class Balance:
    """What a stage took in and where all of it went: ``in = out + rejected``, checked when made.

    ``out`` names the parts of the output in the stage's own words (lod: drawn, outlines drawn by their
    parts); ``rejected`` are the ones recorded with their reason (osm.reject, tex.failure, ...). Both sides are
    counted from what the stage read and wrote, never one derived from the other, so the check can fail."""

    unit: str
    n_in: int
    out: dict[str, int]
    rejected: int = 0

    def __post_init__(self) -> None:
        if self.n_in != self.n_out + self.rejected:
            raise BalanceError(f"{self.unit} lost: {self.text()} does not add up ({self.n_out + self.rejected:,})")

    @property
    def n_out(self) -> int:
        return sum(self.out.values())

    def text(self) -> str:
        """``in 17,790 buildings and parts = 17,789 loaded + rejected 1``."""
        outs = " + ".join(f"{n:,} {name}" for name, n in self.out.items())
        return f"in {self.n_in:,} {self.unit} = {outs} + rejected {self.rejected:,}"

    def counts(self) -> dict[str, object]:
        """The balance as meta.pipeline_run.counts carries it (etl/runs.py refuses an ok run without it)."""
        return {
            "in": self.n_in,
            "out": self.n_out,
            "rejected": self.rejected,
            "unit": self.unit,
            "out_by_kind": dict(self.out),
        }


def summary(stage: str, balance: Balance, details: str, seconds: float, buildings: int) -> str:
    """The closing line every stage prints: its balance, what it made, seconds, buildings/s."""
    rate = buildings / seconds if seconds > 0 else 0.0
    line = f"{stage}: {balance.text()} | {details} | {seconds:.2f} s | {rate:,.0f} buildings/s"
    print(line, flush=True)
    return line
