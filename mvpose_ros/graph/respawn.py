"""Respawn of the graph's node processes (`mvpose-graph --respawn`): a node that died is started
again after a delay, unless it died more than `limit` times within a minute (it would only spin:
a bad parameter, a missing file), and every restart is kept for the report.
"""
from __future__ import annotations

import signal
import time
from collections import deque
from dataclasses import dataclass, field
from typing import Callable

RESPAWN_DELAY_S = 1.0
RESPAWN_LIMIT = 5  # restarts of one node within RESPAWN_WINDOW_S; the next death ends the run
RESPAWN_WINDOW_S = 60.0


def exit_cause(code: int) -> str:
    """'killed by SIGKILL' for a negative return code, else 'exited with code 3'."""
    if code < 0:
        try:
            return f'killed by {signal.Signals(-code).name}'
        except ValueError:
            return f'killed by signal {-code}'
    return f'exited with code {code}'


@dataclass
class Restart:
    """One death of a node and its restart. died_ns: system clock (the recorder's receipt times'
    clock) when the runner saw the exit; restarted_ns: when it was started again (None: not yet);
    count: the node's restarts so far, this one included."""

    node: str
    cause: str
    count: int
    died_ns: int
    restarted_ns: int | None = None


@dataclass
class Respawner:
    """Which dead node to start again and when. `exited` records a death and schedules the
    restart `delay` s later; `due` gives the nodes whose time has come; every death and restart is
    logged with `log` (one line each) as it happens, with the end of the node's log."""

    delay: float = RESPAWN_DELAY_S
    limit: int = RESPAWN_LIMIT
    log: Callable[[str], None] | None = None
    window: float = RESPAWN_WINDOW_S
    restarts: list[Restart] = field(default_factory=list)
    _pending: dict[str, tuple[float, Restart]] = field(default_factory=dict)  # node -> (monotonic due, its restart)
    _recent: dict[str, deque[float]] = field(default_factory=dict)  # node -> monotonic times of its deaths

    def __post_init__(self) -> None:
        if not self.delay >= 0 or self.limit < 1:
            raise ValueError(f'respawn delay must be >= 0 s and limit >= 1; got {self.delay}, {self.limit}')

    def pending(self, node: str) -> bool:
        """Whether node's death is recorded and its restart not yet made."""
        return node in self._pending

    def exited(self, node: str, code: int, log_tail: str = '', now: float | None = None) -> str | None:
        """Record that node exited with code; None when it will be restarted, else why not."""
        now = time.monotonic() if now is None else now
        recent = self._recent.setdefault(node, deque())
        while recent and now - recent[0] > self.window:
            recent.popleft()
        cause = exit_cause(code)
        if len(recent) >= self.limit:
            return f'{cause} after {len(recent)} restarts within {self.window:g} s: not restarted again'
        recent.append(now)
        restart = Restart(node, cause, sum(r.node == node for r in self.restarts) + 1, time.time_ns())
        self.restarts.append(restart)
        self._pending[node] = (now + self.delay, restart)
        self._print(f'node {node} {cause}; restart {restart.count} in {self.delay:g} s'
                    f' ({len(recent)} within {self.window:g} s, at most {self.limit})')
        for line in log_tail.splitlines():
            self._print(f'  | {line}')
        return None

    def due(self, now: float | None = None) -> list[Restart]:
        """The restarts that are due (pending until `restarted` says the node was started)."""
        now = time.monotonic() if now is None else now
        return [restart for at, restart in self._pending.values() if at <= now]

    def restarted(self, node: str) -> None:
        """node has been started again."""
        _, restart = self._pending.pop(node)
        restart.restarted_ns = time.time_ns()
        self._print(f'node {node} started again (restart {restart.count})')

    def _print(self, text: str) -> None:
        if self.log is not None:
            self.log(text)
