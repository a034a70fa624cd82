"""Approximate-time synchronisation of N cameras' messages (the semantics of message_filters'
ApproximateTime policy, which PyPI lacks, with a timeout so that a silent camera cannot stall the
rig). A drop-in for stamp_sync.StampSync: the same add / expire / flush calls, released sets are
SyncedFrames (with more fields), and with max_skew = 0 the sets are exactly StampSync's frames.

Stamps are integer nanoseconds; times are monotonic seconds passed in by the caller. A set holds
at most one message per camera, their stamps within `max_skew` of each other; its stamp is its
earliest member's, and sets are numbered in release order. Each message is used at most once, and
every dropped one is counted by reason ('late', 'duplicate', 'unmatched', 'overflow'). max_skew
must cover the rig's stamp offsets plus their jitter: cameras offset by more form separate sets.
The rules (pivot, release, timeouts, drops): docs/method.md#camera-synchronisation."""
from __future__ import annotations

import bisect
from collections import Counter
from dataclasses import dataclass, field
from typing import Any, Sequence

import numpy as np

from mvpose_ros.core.association.stamp_sync import SyncedFrame

REASONS = ('late', 'duplicate', 'unmatched', 'overflow')


def stamp_rate(stamps: Sequence[Sequence[int]]) -> float | None:
    """Frames per second of cameras from each one's stamps (ns, any order): the median interval of
    each camera with at least three, then the median over those cameras; None when none has.
    Medians: a dropped frame or a late start does not move it."""
    intervals = [np.median(np.diff(u)) for u in map(np.unique, stamps) if u.size >= 3]
    return 1e9 / float(np.median(intervals)) if intervals else None


RATE_TOLERANCE = 0.1  # relative: cameras this far off the nodes' frame_rate run at another rate
# what a frame_rate off the cameras' rate puts wrong, as the bag check and the live check say it
FRAME_RATE_EFFECT = "max_skew's default (half its period) and bp_solver's nominal step follow frame_rate"


def rate_differs(camera_hz: float | None, frame_rate: float) -> bool:
    """Whether cameras at camera_hz (stamp_rate) run more than RATE_TOLERANCE off frame_rate, the
    rate max_skew's default and bp_solver's nominal step assume (False when not known)."""
    return camera_hz is not None and abs(camera_hz - frame_rate) > RATE_TOLERANCE * frame_rate


@dataclass
class SyncedSet(SyncedFrame):
    """A released set. stamp_ns: the earliest member stamp; items[c]: camera c's message or None
    (missing); index: the set's number in release order, from 0; stamps[c]: camera c's own stamp
    (ns) or None; skew_ns: newest minus oldest member stamp."""

    index: int = 0
    stamps: list[int | None] = field(default_factory=list)
    skew_ns: int = 0


@dataclass(frozen=True)
class Drop:
    """One dropped message: camera index, its stamp (ns) and why (one of REASONS)."""

    camera: int
    stamp_ns: int
    reason: str


@dataclass
class _Message:
    stamp: int
    arrival: float
    item: Any


class ApproximateSync:
    """Groups per-camera messages whose header stamps lie within max_skew (see the module)."""

    def __init__(self, cameras: int, timeout: float, max_skew: float, min_cameras: int = 1,
                 queue_size: int = 100, first_wait: float | None = None) -> None:
        """cameras: how many; timeout: seconds (> 0) a set waits for a camera and after which a
        silent camera is left out; max_skew: seconds (>= 0) between a set's oldest and newest
        stamps; min_cameras: smallest set released (smaller ones are dropped as 'unmatched');
        queue_size: messages pending per camera before its oldest is dropped as 'overflow';
        first_wait: seconds a set waits for a camera that has sent nothing yet, after its last
        member came (None: timeout)."""
        if cameras < 1 or not timeout > 0 or not max_skew >= 0 or not 1 <= min_cameras <= cameras \
                or queue_size < 1 or not (first_wait is None or first_wait > 0):
            raise ValueError(f'ApproximateSync needs cameras >= 1, timeout > 0, max_skew >= 0, '
                             f'1 <= min_cameras <= cameras, queue_size >= 1 and first_wait > 0, got {cameras}, '
                             f'{timeout}, {max_skew}, {min_cameras}, {queue_size}, {first_wait}')
        self.cameras = cameras
        self.timeout = float(timeout)
        self.first_wait = self.timeout if first_wait is None else float(first_wait)
        self.max_skew_ns = round(max_skew * 1e9)
        self.grace = float(max_skew)  # s an absent camera is waited for once the others are in
        self.min_cameras = min_cameras
        self.queue_size = queue_size
        self.sets = 0  # sets released so far (the next set's index)
        self.dropped: Counter[str] = Counter()
        self.dropped_by_camera: list[Counter[str]] = [Counter() for _ in range(cameras)]
        self._pending: list[list[_Message]] = [[] for _ in range(cameras)]  # by stamp
        self._newest: list[int | None] = [None] * cameras  # newest stamp seen per camera
        self._floor: list[int | None] = [None] * cameras  # stamps <= this are late
        self._absent: set[int] = set()  # cameras a set waited the timeout for, silent since
        self._drops: list[Drop] = []
        self._lost: list[int] = []  # stamps (ns) of the sets not released for want of min_cameras

    def retune(self, timeout: float, max_skew: float) -> None:
        """A new timeout and max_skew (seconds, as in the constructor) for what is released from now on."""
        if not (timeout > 0 and max_skew >= 0):
            raise ValueError(f'ApproximateSync needs timeout > 0 and max_skew >= 0, got {timeout}, {max_skew}')
        self.timeout = float(timeout)
        self.max_skew_ns = round(max_skew * 1e9)
        self.grace = float(max_skew)

    @property
    def pending(self) -> int:
        """Messages waiting for their set."""
        return sum(len(q) for q in self._pending)

    def add(self, stamp_ns: int, camera: int, item: Any, now: float) -> list[SyncedSet]:
        """Take camera's message stamped stamp_ns (now: monotonic seconds); returns the sets this
        releases. ValueError for an unknown camera, and for a late or duplicate message (counted)."""
        if not 0 <= camera < self.cameras:
            raise ValueError(f'camera {camera} is not in 0..{self.cameras - 1}')
        stamp_ns = int(stamp_ns)
        self._absent.discard(camera)  # it is sending again (even a late message says so)
        floor = self._floor[camera]
        if floor is not None and stamp_ns <= floor:
            self._count(camera, 'late')
            raise ValueError(f'camera {camera} stamp {stamp_ns} ns arrived after its set was released '
                             f'(late: this camera is past {floor} ns)')
        queue = self._pending[camera]
        i = bisect.bisect_left([m.stamp for m in queue], stamp_ns)
        if i < len(queue) and queue[i].stamp == stamp_ns:
            self._count(camera, 'duplicate')
            raise ValueError(f'camera {camera} delivered stamp {stamp_ns} ns twice (duplicate)')
        queue.insert(i, _Message(stamp_ns, now, item))
        newest = self._newest[camera]
        self._newest[camera] = stamp_ns if newest is None else max(newest, stamp_ns)
        if len(queue) > self.queue_size:
            oldest = queue.pop(0)
            self._count(camera, 'overflow')
            self._drops.append(Drop(camera, oldest.stamp, 'overflow'))
        return self._release(now)

    def expire(self, now: float) -> list[SyncedSet]:
        """Sets released because a wait ran out (call this periodically)."""
        return self._release(now)

    def flush(self) -> list[SyncedSet]:
        """Release everything pending (end of stream), in stamp order."""
        return self._release(float('inf'))

    def take_drops(self) -> list[Drop]:
        """The 'unmatched' and 'overflow' drops since the last call (add() raises for the others)."""
        drops, self._drops = self._drops, []
        return drops

    def take_lost(self) -> list[int]:
        """The stamps (ns) of the sets dropped as 'unmatched' since the last call, in stamp order."""
        lost, self._lost = self._lost, []
        return lost

    @property
    def absent(self) -> list[int]:
        """Cameras not waited for: a set went without them after the timeout, nothing since."""
        return sorted(self._absent)

    def _count(self, camera: int, reason: str) -> None:
        self.dropped[reason] += 1
        self.dropped_by_camera[camera][reason] += 1

    def _release(self, now: float) -> list[SyncedSet]:
        out: list[SyncedSet] = []
        while any(self._pending):
            pivot = min(q[0].stamp for q in self._pending if q)
            end = pivot + self.max_skew_ns
            members = [c for c, q in enumerate(self._pending) if q and q[0].stamp <= end]
            open_ = [c for c in range(self.cameras) if c not in members
                     and not (self._newest[c] is not None and self._newest[c] > end)]
            undecided = [c for c in open_ if c not in self._absent]
            first_arrival = min(self._pending[c][0].arrival for c in members)
            last_arrival = max(self._pending[c][0].arrival for c in members)
            heard = any(self._newest[c] is not None for c in undecided)
            if undecided and now - first_arrival < self.timeout and (heard or now - last_arrival < self.first_wait):
                break
            if open_ and not undecided and now - last_arrival < self.grace:
                break  # an absent camera coming back: its image comes about with the others'
            self._absent.update(undecided)
            messages = {c: self._pending[c].pop(0) for c in members}
            for c in range(self.cameras):
                passed = messages[c].stamp if c in messages else end
                self._floor[c] = passed if self._floor[c] is None else max(self._floor[c], passed)
            if len(members) < self.min_cameras:
                for c, m in messages.items():
                    self._count(c, 'unmatched')
                    self._drops.append(Drop(c, m.stamp, 'unmatched'))
                self._lost.append(pivot)
                continue
            stamps = [messages[c].stamp if c in messages else None for c in range(self.cameras)]
            items = [messages[c].item if c in messages else None for c in range(self.cameras)]
            present = [s for s in stamps if s is not None]
            out.append(SyncedSet(pivot, items, index=self.sets, stamps=stamps, skew_ns=max(present) - min(present)))
            self.sets += 1
        return out
