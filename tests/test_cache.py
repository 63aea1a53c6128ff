"""gaintune.cache.LRU: eviction order, get_or_build under threads, clear, a disabled (size-0) cache."""

from __future__ import annotations

import threading
import time

import pytest

from gaintune.cache import LRU


def test_least_recently_used_is_evicted_first():
    lru: LRU[str, int] = LRU(3)
    for i, k in enumerate("abc"):
        lru.put(k, i)
    assert lru.get("a") == 0  # a read: "a" is now the most recently used, "b" the least
    lru.put("d", 3)
    assert "b" not in lru and set(lru) == {"a", "c", "d"} and len(lru) == 3
    lru["c"] = 20  # a rewrite refreshes too: "a" is now the least recently used
    lru.put("e", 4)
    assert set(lru) == {"c", "d", "e"} and lru["c"] == 20
    assert lru.maxsize == 3


def test_membership_and_length_do_not_reorder():
    lru: LRU[str, int] = LRU(2)
    lru.put("a", 1)
    lru.put("b", 2)
    assert "a" in lru and len(lru) == 2 and sorted(lru) == ["a", "b"]
    lru.put("c", 3)  # "a" was only tested for, not read: it is still the least recently used
    assert set(lru) == {"b", "c"}


def test_get_getitem_pop_on_missing_keys():
    lru: LRU[str, object] = LRU(2)
    lru.put("none", None)
    assert lru.get("x") is None and lru.get("x", 7) == 7
    assert lru["none"] is None  # a stored None is an entry
    with pytest.raises(KeyError):
        lru["x"]
    assert lru.pop("none", "gone") is None and lru.pop("none", "gone") == "gone"
    assert len(lru) == 0


def test_clear_empties_the_cache():
    lru: LRU[int, int] = LRU(4)
    for k in range(4):
        lru.put(k, k)
    lru.clear()
    assert len(lru) == 0 and list(lru) == [] and lru.get(0) is None
    assert lru.get_or_build(0, lambda: 10) == 10  # rebuilt after a clear


def test_size_zero_stores_nothing_and_builds_every_time():
    lru: LRU[str, int] = LRU(0)
    lru.put("a", 1)
    assert len(lru) == 0 and lru.get("a") is None
    calls = []
    assert lru.get_or_build("a", lambda: calls.append(1) or 5) == 5
    assert lru.get_or_build("a", lambda: calls.append(1) or 6) == 6
    assert len(calls) == 2 and lru.maxsize == 0


def test_get_or_build_hits_reorder_and_misses_evict():
    lru: LRU[str, str] = LRU(2)
    lru.get_or_build("a", lambda: "A")
    lru.get_or_build("b", lambda: "B")
    assert lru.get_or_build("a", lambda: pytest.fail("a hit must not build")) == "A"
    lru.get_or_build("c", lambda: "C")  # evicts "b", the least recently used
    assert set(lru) == {"a", "c"}


def test_get_or_build_builds_once_per_key_under_threads():
    lru: LRU[str, object] = LRU(8)
    builds: dict[str, int] = {}
    count_lock = threading.Lock()
    n_threads = 16
    start = threading.Barrier(n_threads)
    results: list[tuple[str, object]] = []

    def build(key: str) -> object:
        with count_lock:
            builds[key] = builds.get(key, 0) + 1
        time.sleep(0.05)  # slow enough that every thread misses while the first build runs
        return object()

    def worker(i: int) -> None:
        key = "ab"[i % 2]
        start.wait()
        results.append((key, lru.get_or_build(key, lambda: build(key))))

    threads = [threading.Thread(target=worker, args=(i,)) for i in range(n_threads)]
    for t in threads:
        t.start()
    for t in threads:
        t.join(timeout=10)
    assert not any(t.is_alive() for t in threads)
    assert builds == {"a": 1, "b": 1}
    for key in "ab":
        assert len({id(v) for k, v in results if k == key}) == 1  # every caller got the one built
        assert lru.get(key) is next(v for k, v in results if k == key)
    assert lru._building == {}  # no per-key build lock left behind


def test_get_or_build_builds_outside_the_lock():
    """A build may use the same cache (other keys stay available while it runs)."""
    lru: LRU[str, int] = LRU(4)
    lru.put("other", 1)
    out: list[int] = []
    t = threading.Thread(target=lambda: out.append(lru.get_or_build("k", lambda: lru.get("other") + 1)), daemon=True)
    t.start()
    t.join(timeout=5)
    assert not t.is_alive() and out == [2]


def test_get_or_build_first_writer_wins():
    lru: LRU[str, str] = LRU(4)

    def build() -> str:
        lru.put("k", "first")  # stored by someone else while this build ran
        return "second"

    assert lru.get_or_build("k", build) == "first"
    assert lru.get("k") == "first"


def test_a_failed_build_stores_nothing():
    lru: LRU[str, int] = LRU(4)

    def boom() -> int:
        raise RuntimeError("no")

    with pytest.raises(RuntimeError):
        lru.get_or_build("k", boom)
    assert "k" not in lru and lru._building == {}
    assert lru.get_or_build("k", lambda: 3) == 3
