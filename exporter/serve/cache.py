"""The DB mode's tile cache: an LRU of Payloads bounded by their total size, shared by the event loop (which
only peeks) and the worker threads (which build on a miss)."""

from __future__ import annotations

import threading
from collections import OrderedDict
from collections.abc import Callable, Hashable
from concurrent.futures import Future

from exporter.serve.payload import Payload


class ByteLru:
    """A thread-safe LRU of Payloads bounded by their total size, with single flight: concurrent misses of
    one key build it once and share the result (or the exception). Every method holds the lock only for a
    few dictionary operations, so the event loop may call ``peek`` without stalling."""

    def __init__(self, budget: int) -> None:
        self.budget = budget
        self._items: OrderedDict[Hashable, Payload] = OrderedDict()
        self._inflight: dict[Hashable, Future[Payload]] = {}
        self._bytes = 0
        self._lock = threading.Lock()
        self.hits = self.misses = self.evictions = 0

    def _hit(self, key: Hashable) -> Payload | None:
        """The cached value, now the most recently used (a hit), or None; under the lock."""
        item = self._items.get(key)
        if item is not None:
            self._items.move_to_end(key)
            self.hits += 1
        return item

    def peek(self, key: Hashable) -> Payload | None:
        """The cached value (a hit), or None without counting a miss: the caller goes on to get_or_build."""
        with self._lock:
            return self._hit(key)

    def get_or_build(self, key: Hashable, build: Callable[[], Payload]) -> Payload:
        """The cached value, else ``build()``'s, built once however many threads ask for it at the same time.
        Blocks: never call it on the event loop."""
        with self._lock:
            if (item := self._hit(key)) is not None:
                return item
            fut = self._inflight.get(key)
            owner = fut is None
            if fut is None:
                fut = self._inflight[key] = Future()
                self.misses += 1
        if not owner:
            return fut.result()
        try:
            value = build()
        except BaseException as e:
            with self._lock:
                del self._inflight[key]
            fut.set_exception(e)
            raise
        with self._lock:
            del self._inflight[key]
            self._put(key, value)
        fut.set_result(value)
        return value

    def _put(self, key: Hashable, value: Payload) -> None:
        if value.size > self.budget:
            return  # larger than the whole budget: served, never kept
        old = self._items.pop(key, None)
        if old is not None:
            self._bytes -= old.size
        self._items[key] = value
        self._bytes += value.size
        while self._bytes > self.budget:
            _, dropped = self._items.popitem(last=False)
            self._bytes -= dropped.size
            self.evictions += 1

    def clear(self) -> None:
        with self._lock:
            self._items.clear()
            self._bytes = 0

    def stats(self) -> dict[str, int]:
        with self._lock:
            return {
                "entries": len(self._items),
                "bytes": self._bytes,
                "budget": self.budget,
                "hits": self.hits,
                "misses": self.misses,
                "evictions": self.evictions,
            }
