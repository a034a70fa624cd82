"""CPU time of the graph's processes from /proc and the share of a core each took while playing."""
from __future__ import annotations

import os
import time

import pytest

from mvpose_ros.graph import cpu
from mvpose_ros.graph.cpu import CpuLog, cpu_seconds

GONE = 2 ** 22 + 12345  # beyond pid_max: no such process


def test_cpu_time_of_a_process_grows_with_its_work_and_a_gone_one_has_none():
    before = cpu_seconds(os.getpid())
    deadline = time.process_time() + 0.2
    while time.process_time() < deadline:
        pass
    assert cpu_seconds(os.getpid()) - before >= 0.15
    with pytest.raises(ProcessLookupError, match=str(GONE)):
        cpu_seconds(GONE)


def test_each_process_share_is_over_its_own_sampled_stretch(monkeypatch):
    clock = iter([10.0, 12.0, 14.0])
    used = {1: iter([5.0, 5.5, 6.0]), 2: iter([1.0, 1.0, 2.0])}
    monkeypatch.setattr(cpu.time, 'monotonic', lambda: next(clock))
    monkeypatch.setattr(cpu, 'cpu_seconds', lambda pid: next(used[pid]) if pid in used else cpu_seconds(GONE))
    log = CpuLog()
    log.sample({'a': 1, 'b': 2, 'gone': GONE})
    log.sample({'a': 1, 'b': 2})
    log.sample({'a': 1, 'b': 2})
    assert log.shares() == {'a': 0.25, 'b': 0.25}
    assert log.total_line() == 'CPU while playing: 50% of a core in 2 processes; per process: a 25%, b 25%'


def test_a_process_sampled_once_has_no_share():
    log = CpuLog()
    log.sample({'me': os.getpid()})
    assert log.shares() == {}
