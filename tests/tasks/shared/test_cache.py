"""BoundedCache: least recently used dropped first, a get is a use, each key made once under concurrent callers."""

from __future__ import annotations

import threading
import time

import pytest

from mocapflow.tasks.shared.cache import BoundedCache


def test_the_least_recently_put_is_dropped_first():
    cache = BoundedCache(3)
    for key in "abcd":
        cache.put(key, key.upper())
    assert cache.keys() == ["b", "c", "d"]
    assert cache.get("a") is None and cache.get("a", "gone") == "gone"
    assert [cache.get(k) for k in "bcd"] == ["B", "C", "D"]
    cache.put("e", "E")
    assert cache.keys() == ["c", "d", "e"] and len(cache) == 3


def test_a_get_refreshes_a_key_so_the_next_put_drops_another():
    cache = BoundedCache(3)
    for key in "abc":
        cache.put(key, key.upper())
    assert cache.get("a") == "A"  # a is now the most recently used
    cache.put("d", "D")
    assert "b" not in cache and cache.keys() == ["c", "a", "d"]
    assert "c" in cache and cache.keys() == ["c", "a", "d"]  # a membership test is not a use
    assert cache.get_or_make("c", lambda: pytest.fail("c is kept: nothing to make")) == "C"  # a use
    cache.put("e", "E")
    assert cache.keys() == ["d", "c", "e"]


def test_put_replaces_a_value_and_makes_it_the_most_recently_used():
    cache = BoundedCache(2)
    cache.put("a", 1)
    cache.put("b", 2)
    cache.put("a", 10)
    cache.put("c", 3)
    assert cache.keys() == ["a", "c"] and cache.get("a") == 10
    cache.clear()
    assert len(cache) == 0 and cache.get("a") is None


def test_get_or_make_keeps_what_it_made_and_makes_only_missing_keys():
    cache = BoundedCache(2)
    made = []

    def maker(key):
        return lambda: made.append(key) or key * 2

    assert cache.get_or_make("x", maker("x")) == "xx"
    assert cache.get_or_make("x", maker("x")) == "xx"
    assert cache.get_or_make("y", maker("y")) == "yy"
    assert cache.get_or_make("z", maker("z")) == "zz"  # drops x
    assert cache.get_or_make("x", maker("x")) == "xx"
    assert made == ["x", "y", "z", "x"] and cache.keys() == ["z", "x"]


def test_a_failed_make_keeps_nothing_and_the_next_caller_makes_again():
    cache = BoundedCache(2)

    def broken():
        raise OSError("disk gone")

    with pytest.raises(OSError, match="disk gone"):
        cache.get_or_make("k", broken)
    assert "k" not in cache
    assert cache.get_or_make("k", lambda: 7) == 7


def test_concurrent_get_or_make_makes_each_key_once():
    cache = BoundedCache(8)
    calls: dict[str, int] = {}
    calls_lock = threading.Lock()
    start = threading.Barrier(16)

    def make(key):
        def build():
            with calls_lock:
                calls[key] = calls.get(key, 0) + 1
            time.sleep(0.05)  # long enough for every other thread to ask for the key meanwhile
            return object()
        return build

    results: dict[int, list] = {}

    def worker(i):
        start.wait()
        results[i] = [cache.get_or_make(key, make(key)) for key in ("a", "b", "c", "d")]

    threads = [threading.Thread(target=worker, args=(i,)) for i in range(16)]
    for t in threads:
        t.start()
    for t in threads:
        t.join(timeout=30)
    assert not any(t.is_alive() for t in threads)
    assert calls == {"a": 1, "b": 1, "c": 1, "d": 1}
    first = results[0]
    assert all(r[k] is first[k] for r in results.values() for k in range(4))  # every thread got the one value made
    assert len({id(v) for v in first}) == 4


def test_different_keys_are_made_at_the_same_time():
    cache = BoundedCache(4)
    both_inside = threading.Barrier(2, timeout=10)  # breaks (raises) unless both makes run at once

    def make():
        both_inside.wait()
        return True

    out = []
    threads = [threading.Thread(target=lambda k=k: out.append(cache.get_or_make(k, make))) for k in ("p", "q")]
    for t in threads:
        t.start()
    for t in threads:
        t.join(timeout=30)
    assert out == [True, True]


@pytest.mark.parametrize("bad", [0, -1, 2.5, True, None])
def test_max_entries_must_be_a_positive_integer(bad):
    with pytest.raises(ValueError, match=f"max_entries must be a positive integer, got {bad!r}"):
        BoundedCache(bad)
