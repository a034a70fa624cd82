"""CPU time of the graph's processes (Linux /proc): the share of a core each one takes while the
bag plays, start-up left out."""
from __future__ import annotations

import os
import time
from dataclasses import dataclass, field
from typing import Mapping

TICK_S = 1.0 / os.sysconf('SC_CLK_TCK')


def cpu_seconds(pid: int) -> float:
    """User plus system CPU time (s) process `pid` has used so far; ProcessLookupError when it is
    gone or /proc cannot tell."""
    try:
        with open(f'/proc/{int(pid)}/stat', encoding='ascii') as f:
            # the fields after the command name, which may hold spaces, start after its ')'
            fields = f.read().rsplit(')', 1)[1].split()
        return (int(fields[11]) + int(fields[12])) * TICK_S  # utime, stime
    except (OSError, ValueError, IndexError):
        raise ProcessLookupError(f'no CPU time for process {pid}') from None


@dataclass
class CpuLog:
    """Per process, its (monotonic s, CPU s) at the first and the latest sample, so that the share
    of a core is taken over the same stretch for every process."""

    first: dict[str, tuple[float, float]] = field(default_factory=dict)
    last: dict[str, tuple[float, float]] = field(default_factory=dict)

    def sample(self, pids: Mapping[str, int]) -> None:
        """Record every live process's CPU time now."""
        now = time.monotonic()
        for name, pid in pids.items():
            try:
                used = cpu_seconds(pid)
            except ProcessLookupError:
                continue
            self.first.setdefault(name, (now, used))
            self.last[name] = (now, used)

    def shares(self) -> dict[str, float]:
        """Process -> CPU s per wall s between its first and latest sample (1.0: a whole core);
        only processes sampled over some time."""
        out = {}
        for name, (t0, c0) in self.first.items():
            t1, c1 = self.last[name]
            if t1 > t0:
                out[name] = (c1 - c0) / (t1 - t0)
        return out

    def total_line(self) -> str:
        """'CPU while playing: 61% of a core in 3 processes; per process: a 20%, ...'."""
        shares = self.shares()
        per = ', '.join(f'{name} {100 * share:.0f}%' for name, share in sorted(shares.items()))
        return (f'CPU while playing: {100 * sum(shares.values()):.0f}% of a core in {len(shares)} processes; '
                f'per process: {per}')
