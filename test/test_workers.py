"""Worker threads: parts of about equal cost, run side by side, results in order, errors raised
once nothing runs any more."""
from __future__ import annotations

import threading
import time

import pytest

from mvpose_ros.core.workers import Workers


def test_split_balances_the_cost_over_at_most_threads_parts():
    workers = Workers(3)
    items = [5, 1, 4, 2, 3, 3]
    parts = workers.split(items, cost=float)
    assert len(parts) == 3 and all(parts)
    assert sorted(x for part in parts for x in part) == sorted(items)
    assert sorted(sum(part) for part in parts) == [6, 6, 6]
    assert workers.split([7]) == [[7]]
    assert workers.split([]) == []
    assert Workers(1).split([1, 2, 3]) == [[1, 2, 3]]


def test_parts_run_at_the_same_time_and_come_back_in_order():
    meet = threading.Barrier(3, timeout=10)  # passes only if the three parts run together

    def part(x: int) -> int:
        meet.wait()
        return x * 10

    assert Workers(3).map(part, [1, 2, 3]) == [10, 20, 30]
    alone = threading.Barrier(2, timeout=0.2)  # one thread: the first part waits in vain
    with pytest.raises(threading.BrokenBarrierError):
        Workers(1).map(lambda x: alone.wait(), [1, 2])


def test_an_error_is_raised_once_every_part_has_finished():
    raised = threading.Event()
    finished = []

    def part(x: int) -> None:
        if x == 0:
            raised.set()
            raise RuntimeError('part 0 failed')
        assert raised.wait(timeout=10)  # still running when part 0 has failed
        time.sleep(0.05)  # a map that did not wait would be back by now
        finished.append(x)

    with pytest.raises(RuntimeError, match='part 0 failed'):
        Workers(2).map(part, [0, 1])
    assert finished == [1]


def test_threads_must_be_positive():
    with pytest.raises(ValueError, match='threads must be >= 1'):
        Workers(0)
