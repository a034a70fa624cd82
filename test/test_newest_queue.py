"""The detector's hand-over queue: the newest items wait, older ones are dropped and counted."""
from __future__ import annotations

import threading

import pytest

from mvpose_ros.core.detection.newest_queue import NewestQueue


def test_only_the_newest_waits_with_capacity_one():
    queue = NewestQueue[int](1)
    assert queue.put(1) == [] and queue.put(2) == [1] and queue.put(3) == [2]
    assert queue.take() == 3 and (queue.put_count, queue.dropped) == (3, 2)


def test_a_larger_capacity_keeps_a_burst_in_order_and_drops_the_oldest():
    queue = NewestQueue[int](3)
    dropped = [d for k in range(5) for d in queue.put(k)]
    assert dropped == [0, 1] and [queue.take() for _ in range(3)] == [2, 3, 4] and queue.dropped == 2


def test_take_blocks_until_an_item_or_close():
    queue = NewestQueue[str](1)
    queue.put('a')
    got = []
    consumer = threading.Thread(target=lambda: got.extend([queue.take(), queue.take()]))
    consumer.start()
    consumer.join(timeout=0.2)
    assert consumer.is_alive()  # the second take waits for an item
    queue.close()
    consumer.join(timeout=5)
    assert not consumer.is_alive() and got == ['a', None]


def test_capacity_must_be_positive():
    with pytest.raises(ValueError, match='capacity'):
        NewestQueue(0)
