"""The newest-per-key mailbox (swarm/protocol/mailbox.py): one value per key, keys in turn,
bounded keys, counts; and from many threads at once, no value lost or served twice."""

from __future__ import annotations

import threading
import time

import pytest

from swarm.protocol.mailbox import Mailbox, Posted


def test_a_newer_value_replaces_the_older_and_its_key_keeps_its_place():
    box: Mailbox[str, str] = Mailbox(max_keys=2)
    assert box.put("r1", "a") == Posted(accepted=True, replaced=None, first=True)
    assert box.put("r2", "b") == Posted(accepted=True, replaced=None, first=False)
    assert box.put("r1", "c") == Posted(accepted=True, replaced="a", first=False)
    assert box.put("r3", "d") == Posted(accepted=False)  # two keys wait already
    assert box.take(0.1) == ("r1", "c") and box.take(0.1) == ("r2", "b")
    assert box.take(0.01) is None and len(box) == 0
    assert (box.replaced, box.dropped) == (1, 1)
    assert box.put("r3", "e").first  # room again, and empty before it


def test_take_all_empties_the_mailbox_in_the_order_keys_first_came():
    box: Mailbox[str, int] = Mailbox(max_keys=8)
    for key, value in (("b", 1), ("a", 2), ("b", 3), ("c", 4)):
        box.put(key, value)
    assert list(box.take_all().items()) == [("b", 3), ("a", 2), ("c", 4)]
    assert box.take_all() == {} and box.take() is None


def test_bad_bounds_and_none_values_are_refused():
    with pytest.raises(ValueError, match="max_keys must be >= 1"):
        Mailbox(max_keys=0)
    with pytest.raises(ValueError, match="must not be None"):
        Mailbox(1).put("k", None)


def test_a_waiting_consumer_wakes_for_a_value_put_from_another_thread():
    box: Mailbox[str, bytes] = Mailbox(max_keys=1)
    threading.Timer(0.05, box.put, args=("frame", b"x")).start()
    start = time.monotonic()
    assert box.take(timeout=5.0) == ("frame", b"x")
    assert time.monotonic() - start < 2.0
    start = time.monotonic()
    assert box.take(timeout=0.1) is None and time.monotonic() - start >= 0.09


def test_many_producers_and_one_consumer_lose_nothing_but_what_was_replaced():
    """Eight threads put 2,000 increasing values each under their own key while a consumer takes;
    every value is taken once or counted replaced (none lost, none twice), each key's values
    come out in increasing order, and each key's last value is taken."""
    producers, per_producer = 8, 2000
    box: Mailbox[int, int] = Mailbox(max_keys=producers)
    taken: dict[int, list[int]] = {k: [] for k in range(producers)}
    done = threading.Event()

    def produce(key: int) -> None:
        for value in range(per_producer):
            assert box.put(key, value).accepted

    def consume() -> None:
        while not (done.is_set() and len(box) == 0):
            got = box.take(timeout=0.01)
            if got is not None:
                taken[got[0]].append(got[1])

    consumer = threading.Thread(target=consume)
    consumer.start()
    threads = [threading.Thread(target=produce, args=(k,)) for k in range(producers)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    done.set()
    consumer.join(timeout=30.0)
    assert not consumer.is_alive()
    assert sum(len(v) for v in taken.values()) + box.replaced == producers * per_producer
    for values in taken.values():
        assert values == sorted(set(values)) and values[-1] == per_producer - 1
    assert box.dropped == 0


def test_keys_beyond_the_bound_are_dropped_and_counted_under_contention():
    """Sixteen threads each put under their own key into room for four: exactly four keys
    are kept, every other put is counted dropped, whatever the interleaving."""
    box: Mailbox[int, int] = Mailbox(max_keys=4)
    barrier = threading.Barrier(16)
    results: list[bool] = []
    lock = threading.Lock()

    def put(key: int) -> None:
        barrier.wait()
        for value in range(100):
            accepted = box.put(key, value).accepted
            with lock:
                results.append(accepted)

    threads = [threading.Thread(target=put, args=(k,)) for k in range(16)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    kept = box.take_all()
    assert len(kept) == 4 and all(v == 99 for v in kept.values())
    assert box.dropped == results.count(False) == 12 * 100
    assert box.replaced == 4 * 99
