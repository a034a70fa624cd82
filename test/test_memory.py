"""The soak run's memory log: resident sizes from /proc and growth after the first loop; the total of a
run and its start-up time."""
from __future__ import annotations

import os
import resource
import subprocess
import sys
import textwrap
import time

import pytest

from mvpose_ros.graph import memory
from mvpose_ros.graph.memory import MemoryLog, pss_kib, rss_kib
from mvpose_ros.graph.startup import process_start_ns, startup_line

GONE = 2 ** 22 + 12345  # beyond pid_max: no such process


def test_rss_of_a_process_of_this_one_and_of_none():
    # a fresh process that makes 128 MiB resident (this one may reuse memory it already holds)
    child = subprocess.Popen([sys.executable, '-c', 'import sys, time\n'
                              'block = bytearray(128 * 2 ** 20)\n'
                              'block[::4096] = b"x" * len(block[::4096])\n'
                              'print("ready", flush=True)\n'
                              'time.sleep(30)'], stdout=subprocess.PIPE, text=True)
    try:
        assert child.stdout.readline().strip() == 'ready'
        assert rss_kib(child.pid) > 128 * 2 ** 10
        assert 0 < rss_kib()
        assert 0 < rss_kib(os.getpid())
    finally:
        child.kill()
        child.wait()
    with pytest.raises(ProcessLookupError):
        rss_kib(child.pid)  # gone
    with pytest.raises(ProcessLookupError):
        rss_kib(GONE)


def test_this_process_falls_back_to_its_peak_without_proc(monkeypatch):
    def no_proc(*args, **kwargs):
        raise FileNotFoundError('/proc')

    monkeypatch.setattr(memory, 'open', no_proc, raising=False)
    assert rss_kib() == resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    with pytest.raises(ProcessLookupError):
        rss_kib(os.getpid())


def test_growth_is_measured_from_the_first_loop():
    log = MemoryLog(baseline_after=100)
    log.sample({'a': os.getpid()}, outputs=10)
    assert log.baseline == {}  # warm-up: before the first loop ended
    log.sample({'a': os.getpid()}, outputs=100)
    base = log.baseline['a']
    log.last['a'] = int(base * 1.05)  # as if it had grown 5%
    assert abs(log.growth()['a'] - 0.05) < 1e-6
    assert log.lines()[0].startswith('a: ') and log.lines()[0].endswith('+5.0%')
    log.sample({'gone': GONE}, outputs=200)
    assert 'gone' not in log.baseline


def test_the_total_adds_every_process_largest_size_resident_and_proportional():
    log = MemoryLog(baseline_after=0)
    log.sample({'me': os.getpid()}, 1)
    mib = 2 ** 20
    log.peak, log.peak_pss = {'a': 100 * mib, 'b': 50 * mib}, {'a': 60 * mib, 'b': 20 * mib}
    line = log.total_line()
    assert line.startswith('resident memory: 150.0 MiB in 2 processes')
    assert '80.0 MiB proportional' in line and 'a 100.0 / 60.0, b 50.0 / 20.0' in line


def test_pss_of_a_live_process_is_at_most_its_rss():
    assert 0 < pss_kib(os.getpid()) <= rss_kib(os.getpid())


def test_startup_counts_from_the_command_to_the_first_skeleton():
    started = process_start_ns()
    assert started <= time.time_ns()
    s = 1_000_000_000
    line = startup_line(started, {1: started + 9 * s, 2: started + 10 * s}, {2: started + 12 * s, 1: started + 11 * s})
    assert line == 'start-up: 11.0 s from the command to the first skeleton (first frame played at 9.0 s)'
    assert startup_line(started, {}, {}) is None


def test_a_node_process_gives_the_heap_it_freed_back_to_the_system():
    """What a start frees (a bag read into memory, say) leaves the process's resident size once
    run_nodes has built its nodes; a fragmented heap keeps it otherwise."""
    code = textwrap.dedent('''
        from mvpose_ros.graph.memory import rss_kib
        from mvpose_ros.nodes.runtime import release_free_heap
        blocks = [bytes(1000 + i % 7) for i in range(100_000)]
        kept = blocks[::100]  # the survivors pin the freed space between them
        del blocks
        before = rss_kib()
        release_free_heap()
        print(before - rss_kib())
    ''')
    freed_kib = int(subprocess.run([sys.executable, '-c', code], capture_output=True, text=True, check=True).stdout)
    assert freed_kib > 50 * 1024
