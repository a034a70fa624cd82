"""Resident memory of processes (Linux /proc), and its log over a soak run: is any node growing?"""
from __future__ import annotations

import resource
import time
from dataclasses import dataclass, field
from typing import Mapping


def rss_kib(pid: int | None = None) -> int:
    """Current resident set size (VmRSS) in KiB of process `pid`; None = this process.

    Where /proc cannot be read, this process falls back to its peak so far (ru_maxrss); another
    process that is gone, a zombie or unreadable is a ProcessLookupError.
    """
    path = '/proc/self/status' if pid is None else f'/proc/{int(pid)}/status'
    try:
        with open(path, encoding='ascii') as f:
            for line in f:
                if line.startswith('VmRSS:'):
                    return int(line.split()[1])
    except (OSError, ValueError, IndexError):
        pass
    if pid is None:
        return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    raise ProcessLookupError(f'no resident size for process {pid}')


def pss_kib(pid: int) -> int | None:
    """Proportional set size in KiB of process `pid`: its resident pages, each shared page divided
    by the processes sharing it (libraries, the DDS shared-memory segments), so that the sizes of
    a graph's processes add up to the memory they take together; None where /proc cannot tell."""
    try:
        with open(f'/proc/{int(pid)}/smaps_rollup', encoding='ascii') as f:
            for line in f:
                if line.startswith('Pss:'):
                    return int(line.split()[1])
    except (OSError, ValueError, IndexError):
        pass
    return None


@dataclass
class MemoryLog:
    """Per process, its resident size (bytes) when the first `baseline_after` outputs had arrived
    (the first loop of a soak: caches and DDS buffers are warm by then), the largest and the last;
    and every sample: (system clock ns, process -> bytes), for the report by period of the run."""

    baseline_after: int
    baseline: dict[str, int] = field(default_factory=dict)
    peak: dict[str, int] = field(default_factory=dict)
    last: dict[str, int] = field(default_factory=dict)
    history: list[tuple[int, dict[str, int]]] = field(default_factory=list)
    peak_pss: dict[str, int] = field(default_factory=dict)

    def sample(self, pids: Mapping[str, int], outputs: int) -> None:
        """Record every live process's size; outputs: frames output so far."""
        sizes: dict[str, int] = {}
        self.history.append((time.time_ns(), sizes))
        for name, pid in pids.items():
            try:
                rss = rss_kib(pid) * 1024
            except ProcessLookupError:
                continue
            sizes[name] = self.last[name] = rss
            self.peak[name] = max(rss, self.peak.get(name, 0))
            pss = pss_kib(pid)
            if pss is not None:
                self.peak_pss[name] = max(pss * 1024, self.peak_pss.get(name, 0))
            if outputs >= self.baseline_after and name not in self.baseline:
                self.baseline[name] = rss

    def growth(self) -> dict[str, float]:
        """Per process with a baseline: (last - baseline) / baseline."""
        return {name: (self.last[name] - base) / base for name, base in self.baseline.items() if base}

    def lines(self) -> list[str]:
        """One line per process: 'name: 85.1 MiB after loop 1 -> 86.0 MiB at the end (max 86.2), +1.1%'."""
        mib = 1 / 2 ** 20
        growth = self.growth()
        return [f'{name}: {base * mib:.1f} MiB after loop 1 -> {self.last[name] * mib:.1f} MiB at the end '
                f'(max {self.peak[name] * mib:.1f}), {100 * growth[name]:+.1f}%'
                for name, base in sorted(self.baseline.items())]

    def total_line(self) -> str:
        """'resident memory: 1234.5 MiB in 8 processes (the sum of each one's largest RSS), 801.2 MiB
        proportional (PSS: shared pages counted once); per process RSS / PSS, MiB: a 301.2 / 180.3, ...'."""
        mib = 1 / 2 ** 20
        per = ', '.join(f'{name} {size * mib:.1f} / {self.peak_pss.get(name, 0) * mib:.1f}'
                        for name, size in sorted(self.peak.items()))
        return (f'resident memory: {sum(self.peak.values()) * mib:.1f} MiB in {len(self.peak)} processes (the sum of '
                f'each one\'s largest RSS), {sum(self.peak_pss.values()) * mib:.1f} MiB proportional (PSS: shared '
                f'pages counted once); per process RSS / PSS, MiB: {per}')
