"""The one in-memory cache helper: a small thread-safe LRU on :class:`cachetools.LRUCache`.

Layer 0: imports only the standard library and :mod:`cachetools`. Used for the per-spec
sessions of :mod:`gaintune.verification.context` and the API's caches of checked specs,
serialized reports and the compute workers' known objects.
"""

from __future__ import annotations

import threading
from collections.abc import Callable, Hashable, Iterator
from typing import Generic, TypeVar

from cachetools import Cache, LRUCache

__all__ = ["LRU"]

K = TypeVar("K", bound=Hashable)
V = TypeVar("V")


class _Flight:
    """One key's build in :meth:`LRU.get_or_build`: the lock its builders queue on, and how many hold or wait."""

    __slots__ = ("lock", "users")

    def __init__(self) -> None:
        self.lock = threading.Lock()
        self.users = 0


class LRU(Generic[K, V]):
    """A least-recently-used cache of at most ``maxsize`` entries, safe to share between threads.

    Reading an entry (:meth:`get`, ``lru[key]``, a hit of :meth:`get_or_build`) or writing
    it (:meth:`put`) makes it the most recently used; inserting into a full cache evicts
    the least recently used entry. ``key in lru``, ``len(lru)`` and iteration leave the
    order alone.

    Parameters
    ----------
    maxsize : int
        Entries kept. ``0`` (or less) disables the cache: :meth:`put` stores nothing and
        :meth:`get_or_build` builds on every call.
    """

    def __init__(self, maxsize: int) -> None:
        self._maxsize = max(int(maxsize), 0)
        # cachetools refuses an item in a maxsize-0 cache; keep a 1-slot one and never write to it
        self._data: LRUCache = LRUCache(maxsize=max(self._maxsize, 1))
        self._lock = threading.Lock()
        self._building: dict[K, _Flight] = {}  # keys being built by get_or_build, with their waiters

    @property
    def maxsize(self) -> int:
        """Entries kept (0: the cache is off)."""
        return self._maxsize

    def get(self, key: K, default: V | None = None) -> V | None:
        """The entry under ``key`` (now the most recently used), else ``default``."""
        with self._lock:
            return self._data.get(key, default)

    def __getitem__(self, key: K) -> V:
        """The entry under ``key`` (now the most recently used); KeyError when absent."""
        with self._lock:
            return self._data[key]

    def put(self, key: K, value: V) -> None:
        """Store ``value`` under ``key`` as the most recently used, evicting the least recently used if full."""
        if self._maxsize <= 0:
            return
        with self._lock:
            self._data[key] = value

    __setitem__ = put

    def get_or_build(self, key: K, build: Callable[[], V]) -> V:
        """The entry under ``key``, built by ``build()`` and stored on a miss.

        ``build`` runs outside the cache's lock, so other keys stay available while it runs
        (it may be slow). Threads missing the same key at once wait for one build (a per-key
        lock) rather than each building. If an entry appears under ``key`` while ``build``
        runs (a :meth:`put`), the first stored wins and is returned. A ``build`` that raises
        stores nothing; the next caller builds again.
        """
        if self._maxsize <= 0:
            return build()
        with self._lock:
            if key in self._data:
                return self._data[key]
            flight = self._building.get(key)
            if flight is None:
                flight = self._building[key] = _Flight()
            flight.users += 1
        try:
            with flight.lock:
                with self._lock:
                    if key in self._data:  # built by the thread we waited for
                        return self._peek(key)
                value = build()
                with self._lock:
                    if key in self._data:  # stored meanwhile: keep the first
                        return self._peek(key)
                    self._data[key] = value
                return value
        finally:
            with self._lock:
                flight.users -= 1
                if not flight.users:
                    del self._building[key]

    def _peek(self, key: K) -> V:
        # the base-class lookup does not reorder: an entry stored a moment ago stays where it is
        return Cache.__getitem__(self._data, key)

    def pop(self, key: K, default: V | None = None) -> V | None:
        """Remove the entry under ``key`` and return it, else ``default``."""
        with self._lock:
            return self._data.pop(key, default)

    def clear(self) -> None:
        """Remove every entry."""
        with self._lock:
            self._data.clear()

    def __contains__(self, key: object) -> bool:
        with self._lock:
            return key in self._data

    def __len__(self) -> int:
        with self._lock:
            return len(self._data)

    def __iter__(self) -> Iterator[K]:
        """The keys at the time of the call (a snapshot; order unspecified)."""
        with self._lock:
            return iter(list(self._data))

    def __repr__(self) -> str:
        return f"LRU(maxsize={self._maxsize}, len={len(self)})"
