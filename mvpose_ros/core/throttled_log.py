"""One way for every node to log a problem that repeats (every frame, every message): the first
of its kind at once, then at most once per `period` seconds with how many were not logged since,
and the totals kept for the node's final summary and its diagnostics. ROS-free: the logger is
anything with error / warning / info methods taking a string (an rclpy logger)."""
from __future__ import annotations

import threading
import time
from collections import Counter
from typing import Any, Callable

THROTTLE_S = 5.0  # s between two lines about the same problem
# Causes told apart per subject, and the characters of one: junk can make every cause new (random
# sizes, frame_ids), and neither the log nor the counts may grow with a flood of it.
MAX_CAUSES = 32
MAX_CAUSE_CHARS = 300
OTHER_CAUSES = f'other causes (beyond {MAX_CAUSES} distinct ones)'


def short_cause(cause: str) -> str:
    """A cause on one line, at most MAX_CAUSE_CHARS long."""
    return ' '.join(cause[:4 * MAX_CAUSE_CHARS].split())[:MAX_CAUSE_CHARS]


class ThrottledLog:
    """Per key (subject, cause): log the first occurrence, then at most one line every `period` s,
    saying how many more there were since the last line. At most MAX_CAUSES causes per subject are
    told apart (the rest are counted as OTHER_CAUSES) and a line is cut to MAX_CAUSE_CHARS past its
    cause. Safe to call from several threads."""

    def __init__(self, logger: Any, period: float = THROTTLE_S, clock: Callable[[], float] = time.monotonic) -> None:
        self._logger = logger
        self.period = period
        self._clock = clock
        self.counts: Counter[tuple[str, str]] = Counter()  # every occurrence, by key
        self._said: dict[tuple[str, str], float] = {}  # key -> when last logged
        self._unsaid: Counter[tuple[str, str]] = Counter()  # key -> occurrences not logged since
        self._causes: Counter[str] = Counter()  # subject -> distinct causes counted
        self._lock = threading.Lock()

    def log(self, key: tuple[str, str], text: str, level: str = 'warning') -> bool:
        """Count one occurrence of `key`; log `text` at `level` unless the key was logged less than
        `period` s ago. Returns whether it was logged."""
        now = self._clock()
        subject, cause = key[0], short_cause(key[1])
        text = text[:2 * MAX_CAUSE_CHARS]
        with self._lock:
            if (subject, cause) not in self.counts:
                if self._causes[subject] >= MAX_CAUSES:
                    cause = OTHER_CAUSES
                else:
                    self._causes[subject] += 1
            key = (subject, cause)
            self.counts[key] += 1
            if now - self._said.get(key, -float('inf')) < self.period:
                self._unsaid[key] += 1
                return False
            more = self._unsaid.pop(key, 0)
            self._said[key] = now
        line = text + (f' ({more} more like it in the last {self.period:g} s)' if more else '')
        # one call site per severity: rclpy refuses another severity from a call site it has seen
        if level == 'error':
            self._logger.error(line)
        elif level == 'warning':
            self._logger.warning(line)
        else:
            self._logger.info(line)
        return True

    def summary(self) -> str:
        """'<subject>: <n> x <cause>; ...' of every key so far, or 'none'."""
        with self._lock:
            items = sorted(self.counts.items())
        return '; '.join(f'{subject}: {n} x {cause}' for (subject, cause), n in items) or 'none'
