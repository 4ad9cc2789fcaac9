"""A bounded, thread-safe least-recently-used cache: the one kept per process for opened artifacts, loaded
weights and built studio rigs.

    rigs = BoundedCache(4)
    rig = rigs.get_or_make(fingerprint, lambda: build_rig(spec))   # built once, however many threads ask

``get`` and ``get_or_make`` count as a use; when a ``put`` (or a ``get_or_make`` that makes) would hold more than
``max_entries`` values, the least recently used is dropped. ``get_or_make`` calls ``make`` outside the lock, so
different keys are made at the same time, and one key is made once: threads asking for a key being made wait for
it. If ``make`` raises, its caller gets the error, nothing is kept, and the next caller makes the key again.
"""

from __future__ import annotations

import threading
from collections import OrderedDict
from typing import Callable, Generic, Hashable, TypeVar

K = TypeVar("K", bound=Hashable)
V = TypeVar("V")

__all__ = ["BoundedCache"]


class _Making:
    """A key being made by one thread; the others wait on ``done``."""

    def __init__(self) -> None:
        self.done = threading.Event()
        self.value = None
        self.failed = False


class BoundedCache(Generic[K, V]):
    """At most ``max_entries`` values by key, the least recently used dropped first; safe to share between threads."""

    def __init__(self, max_entries: int):
        if isinstance(max_entries, bool) or not isinstance(max_entries, int) or max_entries < 1:
            raise ValueError(f"BoundedCache max_entries must be a positive integer, got {max_entries!r}")
        self.max_entries = max_entries
        self._entries: OrderedDict[K, V] = OrderedDict()
        self._making: dict[K, _Making] = {}
        self._lock = threading.Lock()

    def get(self, key: K, default: V | None = None) -> V | None:
        """The value kept for ``key`` (now the most recently used), else ``default``."""
        with self._lock:
            if key not in self._entries:
                return default
            self._entries.move_to_end(key)
            return self._entries[key]

    def put(self, key: K, value: V) -> None:
        """Keep ``value`` for ``key`` (replacing any) as the most recently used; drop the least recently used over
        ``max_entries``."""
        with self._lock:
            self._keep(key, value)

    def get_or_make(self, key: K, make: Callable[[], V]) -> V:
        """The value kept for ``key``, else ``make()``'s, kept; ``make`` runs once per key while others wait."""
        while True:
            with self._lock:
                if key in self._entries:
                    self._entries.move_to_end(key)
                    return self._entries[key]
                making = self._making.get(key)
                mine = making is None
                if mine:
                    making = self._making[key] = _Making()
            if mine:
                return self._make(key, make, making)
            making.done.wait()
            if not making.failed:
                return making.value
            # the maker failed: try again (this thread may make it)

    def __len__(self) -> int:
        with self._lock:
            return len(self._entries)

    def __contains__(self, key: object) -> bool:
        """Whether ``key`` is kept (not a use: the order is left as it is)."""
        with self._lock:
            return key in self._entries

    def keys(self) -> list[K]:
        """The kept keys, least recently used first."""
        with self._lock:
            return list(self._entries)

    def clear(self) -> None:
        with self._lock:
            self._entries.clear()

    def _make(self, key: K, make: Callable[[], V], making: _Making) -> V:
        try:
            value = make()
        except BaseException:
            making.failed = True
            with self._lock:
                del self._making[key]
            making.done.set()
            raise
        making.value = value
        with self._lock:
            self._keep(key, value)
            del self._making[key]
        making.done.set()
        return value

    def _keep(self, key: K, value: V) -> None:
        self._entries[key] = value
        self._entries.move_to_end(key)
        while len(self._entries) > self.max_entries:
            self._entries.popitem(last=False)
