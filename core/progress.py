"""Progress for long work: periodic counts with a rate on stderr, and the one-line stage summary."""

from __future__ import annotations

import sys
import time


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


def summary(stage: str, parts: str, seconds: float, buildings: int) -> str:
    """The closing line every stage prints: counts, seconds, buildings/s."""
    rate = buildings / seconds if seconds > 0 else 0.0
    line = f"{stage}: {parts} | {seconds:.2f} s | {rate:,.0f} buildings/s"
    print(line, flush=True)
    return line
