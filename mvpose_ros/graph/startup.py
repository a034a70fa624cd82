"""Start-up of a graph run: from the command (this process's start) to the first skeleton, with
the moment the first frame was played, so that what the nodes' start costs (imports, compiled
kernels loaded, DDS discovery) stands apart from the first frame's own latency."""
from __future__ import annotations

import os
import time
from typing import Mapping


def process_start_ns() -> int:
    """This process's start on the system clock (ns), from /proc (10 ms steps); where /proc cannot
    be read, the time of this call."""
    try:
        with open('/proc/self/stat', encoding='ascii') as f:
            ticks = int(f.read().rpartition(')')[2].split()[19])  # field 22, starttime: clock ticks after boot
    except (OSError, ValueError, IndexError):
        return time.time_ns()
    since_boot_ns = ticks * 1_000_000_000 // os.sysconf('SC_CLK_TCK')
    return time.time_ns() - (time.clock_gettime_ns(time.CLOCK_BOOTTIME) - since_boot_ns)


def startup_line(started_ns: int, played_at: Mapping[int, int], output_at: Mapping[int, int]) -> str | None:
    """'start-up: 9.8 s from the command to the first skeleton (first frame played at 9.6 s)';
    played_at, output_at: stamp -> system clock ns of the frame's camera_info and skeletons
    receipt. None before any skeleton came."""
    if not output_at:
        return None
    line = f'start-up: {1e-9 * (min(output_at.values()) - started_ns):.1f} s from the command to the first skeleton'
    if played_at:
        line += f' (first frame played at {1e-9 * (min(played_at.values()) - started_ns):.1f} s)'
    return line
