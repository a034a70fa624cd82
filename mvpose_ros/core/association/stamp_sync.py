"""Exact-stamp synchronisation of several cameras' messages (message_filters' exact-time policy,
which PyPI lacks, plus a timeout so a dead camera cannot stall the graph).

A frame is released, in stamp order, once every camera has delivered its stamp or moved past it
(a camera's messages arrive in order, so a later stamp means this one is never coming), or once
`timeout` seconds have passed since its first message. Released frames list the cameras that
never delivered.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any


@dataclass
class SyncedFrame:
    """items[c]: camera c's message for this stamp, None where it is missing."""

    stamp_ns: int
    items: list[Any]

    @property
    def missing(self) -> list[int]:
        """The cameras without a member in the set."""
        return [c for c, item in enumerate(self.items) if item is None]


@dataclass
class _Pending:
    first_seen: float
    items: list[Any]


@dataclass
class StampSync:
    """Groups per-camera messages by header stamp (integer nanoseconds)."""

    cameras: int
    timeout: float
    _pending: dict[int, _Pending] = field(default_factory=dict)
    _newest: list[int | None] = field(init=False)
    _released: int | None = None  # newest stamp already released

    def __post_init__(self) -> None:
        if self.cameras < 1 or not self.timeout > 0:
            raise ValueError(f'StampSync needs cameras >= 1 and timeout > 0, got {self.cameras}, {self.timeout}')
        self._newest = [None] * self.cameras

    def add(self, stamp_ns: int, camera: int, item: Any, now: float) -> list[SyncedFrame]:
        """Take camera's message for stamp_ns (now: a monotonic time in seconds); returns the
        frames this releases. Raises ValueError for a stamp already released (late) or already
        delivered by this camera (duplicate), and for an unknown camera."""
        if not 0 <= camera < self.cameras:
            raise ValueError(f'camera {camera} is not in 0..{self.cameras - 1}')
        if self._released is not None and stamp_ns <= self._released:
            raise ValueError(f'camera {camera} stamp {stamp_ns} ns arrived after that frame was released '
                             f'(newest released {self._released} ns)')
        pending = self._pending.setdefault(stamp_ns, _Pending(now, [None] * self.cameras))
        if pending.items[camera] is not None:
            raise ValueError(f'camera {camera} delivered stamp {stamp_ns} ns twice')
        pending.items[camera] = item
        newest = self._newest[camera]
        self._newest[camera] = stamp_ns if newest is None else max(newest, stamp_ns)
        return self._release(now)

    def expire(self, now: float) -> list[SyncedFrame]:
        """Frames released because their timeout ran out (call this periodically)."""
        return self._release(now)

    def flush(self) -> list[SyncedFrame]:
        """Release everything pending (end of stream)."""
        return self._release(float('inf'))

    def _ready(self, stamp: int, pending: _Pending, now: float) -> bool:
        if now - pending.first_seen >= self.timeout:
            return True
        return all(item is not None or (newest is not None and newest > stamp)
                   for item, newest in zip(pending.items, self._newest))

    def _release(self, now: float) -> list[SyncedFrame]:
        out = []
        ready = [s for s in sorted(self._pending) if self._ready(s, self._pending[s], now)]
        if ready:
            # everything older than a ready frame goes too, so frames leave in stamp order
            for stamp in [s for s in sorted(self._pending) if s <= ready[-1]]:
                out.append(SyncedFrame(stamp, self._pending.pop(stamp).items))
            self._released = out[-1].stamp_ns
        return out
