"""A whole rig's inputs detected in synchronised sets, one set at a time (the heatmap_detector
node's whole-rig mode, without ROS).

Inputs are grouped into sets (core.association.approximate_sync: stamps within `max_skew`, a
missing camera waited for at most `sync_timeout`); a worker thread detects one set at a time. While
it is busy only the newest `waiting_sets` released sets wait (core.detection.newest_queue): an
older one is dropped whole and counted, so latency stays bounded by about two sets' detection time
and no queue grows; the synchroniser keeps at most a sync_timeout's worth of frames per camera. A
set that reaches the association from no camera (dropped whole, short of `min_cameras`, or none of
its inputs usable) is reported as lost, so that a subscriber waiting for every frame stops waiting.
The caller publishes, logs and counts through SetCallbacks.
"""
from __future__ import annotations

import math
import threading
import time
import traceback
from collections import Counter
from dataclasses import dataclass
from typing import Any, Callable, Mapping, Sequence

from mvpose_ros.core.association.approximate_sync import ApproximateSync, SyncedSet
from mvpose_ros.core.detection.newest_queue import NewestQueue
from mvpose_ros.core.health.monitor import InputMonitor, NodeMonitor
from mvpose_ros.core.throttled_log import ThrottledLog

# an unmatched or overflowing input's reason -> what it means for the camera
_CAUSES = {'unmatched': 'its set had fewer than min_cameras cameras',
           'overflow': 'too many frames pending synchronisation (a camera stamping far ahead?)'}


@dataclass(frozen=True)
class SetSettings:
    """frame_rate: the cameras' (Hz); sync_timeout: s a set waits for a missing camera; max_skew: s
    between the oldest and newest stamp of a set; min_cameras: smaller sets are dropped;
    waiting_sets: released sets that wait while one is detected."""

    frame_rate: float
    sync_timeout: float
    max_skew: float
    min_cameras: int
    waiting_sets: int

    def check(self, cameras: int) -> None:
        """ValueError naming the parameters unless they suit a rig of `cameras` cameras."""
        if not (self.sync_timeout > 0 and self.max_skew >= 0 and 1 <= self.min_cameras <= cameras
                and self.waiting_sets >= 1):
            raise ValueError(f'parameters sync_timeout, max_skew, min_cameras, waiting_sets: need sync_timeout > 0, '
                             f'max_skew >= 0, 1 <= min_cameras <= {cameras} and waiting_sets >= 1, got '
                             f'{self.sync_timeout}, {self.max_skew}, {self.min_cameras}, {self.waiting_sets}')


@dataclass(frozen=True)
class SetCallbacks:
    """What RigSets has the caller do. detect: detect a set and send its people, returning how many
    cameras were sent (on the worker thread); dropped(camera, stamp ns, cause): an input left out
    of every set; lost(stamp ns): a set none of whose cameras reaches the association;
    delivered(stamps ns, released (monotonic s), seconds): a set detected; error(text): a set whose
    detection raised."""

    detect: Callable[[SyncedSet], int]
    dropped: Callable[[int, int, str], None]
    lost: Callable[[int], None]
    delivered: Callable[[list[int], float, float], None]
    error: Callable[[str], None]


class RigSets:
    """add() each admitted input, expire() every few tens of ms; close() stops the worker. inputs:
    each camera's InputMonitor, monitor: the node's (their synchronisation offsets and skews)."""

    def __init__(self, settings: SetSettings, inputs: Sequence[InputMonitor], monitor: NodeMonitor,
                 log: ThrottledLog, callbacks: SetCallbacks) -> None:
        settings.check(len(inputs))
        # pending messages per camera: a sync_timeout's worth of frames, twice (more only from a
        # camera stamping far ahead of the others: its oldest are dropped as 'overflow', counted)
        queue = math.ceil(2 * settings.sync_timeout * settings.frame_rate) + 2
        # a camera that has sent nothing yet (one starting late) holds a set back one frame period at most
        self.sync = ApproximateSync(len(inputs), settings.sync_timeout, settings.max_skew, settings.min_cameras,
                                    queue, first_wait=1.0 / settings.frame_rate)
        self.waiting: NewestQueue[SyncedSet] = NewestQueue(settings.waiting_sets)
        self.processed = 0
        self._inputs = list(inputs)
        self._monitor = monitor
        self._log = log
        self._callbacks = callbacks
        self._released: dict[int, float] = {}  # set index -> when released (monotonic)
        self._stopping = False
        self._worker = threading.Thread(target=self._work, name='heatmap_detector_sets', daemon=True)
        self._worker.start()

    @property
    def pending(self) -> int:
        """Inputs and sets not yet detected: waiting sets and inputs held by the synchroniser."""
        return len(self.waiting) + self.sync.pending

    def add(self, camera: int, stamp: int, item: Any, now: float) -> None:
        """An admitted input of `camera` (rig order) stamped `stamp` ns, arrived at `now` (monotonic)."""
        before = Counter(self.sync.dropped)
        try:
            released = self.sync.add(stamp, camera, item, now)
        except ValueError as exc:
            reason = next(iter(self.sync.dropped - before), 'rejected')
            self._callbacks.dropped(camera, stamp, f'not synchronised ({reason}): {without_numbers(str(exc))}')
            return
        self._offer(released, now)

    def expire(self, now: float) -> None:
        """Release the sets whose wait for a missing camera is over."""
        self._offer(self.sync.expire(now), now)

    def sync_settings(self, changes: Mapping[str, Any]) -> tuple[float, float]:
        """(sync_timeout, max_skew) with the live changes of either; ValueError when invalid."""
        timeout = changes.get('sync_timeout', self.sync.timeout)
        max_skew = changes.get('max_skew', self.sync.max_skew_ns / 1e9)
        ApproximateSync(1, timeout, max_skew)
        return timeout, max_skew

    def retune(self, changes: Mapping[str, Any]) -> None:
        """Apply live changes of sync_timeout and max_skew (ValueError when invalid, nothing changed)."""
        self.sync.retune(*self.sync_settings(changes))

    def statistics(self) -> dict[str, str]:
        """The set counts, for diagnostics."""
        return {'sets released': str(self.waiting.put_count), 'sets detected': str(self.processed),
                'sets dropped whole while detecting': str(self.waiting.dropped)}

    def close(self) -> str:
        """Stop the worker (waiting for the set it detects); returns the totals, one line."""
        self._stopping = True
        self.waiting.close()
        self._worker.join(10.0)
        return (f'sets: {self.waiting.put_count} released, {self.processed} detected, {self.waiting.dropped} dropped '
                f'whole while detecting; sync drops {dict(self.sync.dropped) or "none"}')

    def _offer(self, released: list[SyncedSet], now: float) -> None:
        for drop in self.sync.take_drops():
            self._callbacks.dropped(drop.camera, drop.stamp_ns,
                                    f'not synchronised ({drop.reason}): {_CAUSES.get(drop.reason, drop.reason)}')
        for stamp in self.sync.take_lost():
            self._callbacks.lost(stamp)
        for synced in released:
            for c, s in enumerate(synced.stamps):
                if s is not None:
                    self._inputs[c].synchronised(now, (s - synced.stamp_ns) / 1e9)
            self._monitor.set_skew(now, synced.skew_ns / 1e9)
            self._released[synced.index] = now
            for old in self.waiting.put(synced):
                self._released.pop(old.index, None)
                self._callbacks.lost(old.stamp_ns)
                self._log.log(('sets', 'dropped whole while detecting'),
                              f'detection is slower than the cameras: {self.waiting.dropped} of '
                              f'{self.waiting.put_count} sets dropped whole so far (the newest wait)')

    def _work(self) -> None:
        while (synced := self.waiting.take()) is not None:
            t0 = time.perf_counter()
            try:
                sent = self._callbacks.detect(synced)
            except Exception:  # the worker must survive a bug in one set; a shutdown ends it quietly
                if self._stopping:
                    return
                self._callbacks.error(f'set {synced.index}: {traceback.format_exc(limit=3)}')
                continue
            if not sent:
                self._callbacks.lost(synced.stamp_ns)
            self._callbacks.delivered([s for s in synced.stamps if s is not None],
                                      self._released.pop(synced.index, time.monotonic()), time.perf_counter() - t0)
            self.processed += 1


def without_numbers(text: str) -> str:
    """A cause without the stamps and counts in it (so that it names the cause, not the message)."""
    return ' '.join('<n>' if word.strip('(),:;').isdigit() else word for word in text.split())
