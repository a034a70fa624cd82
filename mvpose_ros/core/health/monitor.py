"""Rolling statistics of a node, taken over the last `window` seconds (monotonic clock): per input
its rate, drops by reason, sync offset and silence; per node the time of each stage per item,
the latency in the node and from the capture stamp. `input_statuses` and `node_status` judge them
by HealthThresholds."""
from __future__ import annotations

from collections import Counter, deque
from dataclasses import dataclass, field
from typing import Mapping, Sequence

import numpy as np

from mvpose_ros.core.association.approximate_sync import FRAME_RATE_EFFECT, rate_differs
from mvpose_ros.core.health.status import Level, Status, judged
from mvpose_ros.core.health.thresholds import HealthThresholds

# A capture stamp this far from the node's clock is on another clock (a replayed recording):
# the latency from it is reported but not judged.
CLOCK_MISMATCH_S = 3600.0


class _Recent:
    """(time, value) pairs; since() forgets those before the start it is asked for."""

    def __init__(self) -> None:
        self.items: deque[tuple[float, object]] = deque()

    def add(self, now: float, value: object) -> None:
        self.items.append((now, value))

    def since(self, start: float) -> list:
        while self.items and self.items[0][0] < start:
            self.items.popleft()
        return [v for _, v in self.items]


@dataclass
class InputStats:
    """One input over the window: rate (Hz), messages received and dropped (by reason), the
    dropped total since the start, seconds since its last message (since the monitor started if
    none came), the median offset of its stamps from their set's stamp (s; None: not synchronised),
    and its newest stamp (ns; None: none yet)."""

    name: str
    rate: float
    received: int
    dropped: Counter = field(default_factory=Counter)
    dropped_total: int = 0
    silent: float = 0.0
    ever: bool = False
    offset: float | None = None
    newest_stamp: int | None = None


class InputMonitor:
    """One input stream (a camera's messages). Calls come from the node's callbacks (and worker)."""

    def __init__(self, name: str, now: float) -> None:
        self.name = name
        self._start = now
        self._last: float | None = None
        self._arrivals = _Recent()
        self._drops = _Recent()
        self._offsets = _Recent()
        self.dropped_total = 0
        self.newest_stamp: int | None = None

    def received(self, now: float, stamp_ns: int | None = None) -> None:
        """A message arrived (used or not)."""
        self._last = now
        self._arrivals.add(now, stamp_ns)
        if stamp_ns is not None:
            self.newest_stamp = stamp_ns if self.newest_stamp is None else max(self.newest_stamp, stamp_ns)

    def stamps(self, now: float, window: float) -> list[int]:
        """The stamps (ns) of its messages of the last `window` s, as they came."""
        return [s for t, s in self._arrivals.items if t >= now - window and s is not None]

    def typical_interval(self, now: float, window: float) -> float | None:
        """Median time (s) between its arrivals of the last `window` s; None with fewer than two."""
        times = np.array([t for t, _ in self._arrivals.items if t >= now - window])
        return float(np.median(np.diff(times))) if times.size > 1 else None

    def dropped(self, now: float, reason: str) -> None:
        """One of its messages was dropped (late, malformed, ...)."""
        self._drops.add(now, reason)
        self.dropped_total += 1

    def synchronised(self, now: float, offset_s: float) -> None:
        """One of its messages went into a set, offset_s after the set's stamp."""
        self._offsets.add(now, offset_s)

    def stats(self, now: float, window: float) -> InputStats:
        """The figures of the last `window` s."""
        start = now - window
        arrivals = self._arrivals.since(start)
        offsets = self._offsets.since(start)
        span = min(window, now - self._start)
        return InputStats(self.name, len(arrivals) / span if span > 0 else 0.0, len(arrivals),
                          Counter(self._drops.since(start)), self.dropped_total,
                          now - (self._last if self._last is not None else self._start), self._last is not None,
                          float(np.median(offsets)) if offsets else None, self.newest_stamp)


def input_statuses(node: str, inputs: Sequence[InputStats], t: HealthThresholds) -> list[Status]:
    """One status per input: ERROR when silent for stale_error s while another input sends,
    WARN when every input is that silent; WARN when its rate is below rate_warn_ratio x the median
    of the others'; WARN / ERROR when more than drop_warn / drop_error of its messages were dropped."""
    statuses = []
    for i, s in enumerate(inputs):
        others = [o for j, o in enumerate(inputs) if j != i]
        live = [o for o in others if o.silent <= t.stale_error]
        checks: list[tuple[Level, str]] = []
        silence = f'no message for {s.silent:.1f} s' if s.ever else f'no message yet ({s.silent:.1f} s)'
        if s.silent > t.stale_error:
            checks.append((Level.ERROR, f'{silence} while {", ".join(o.name for o in live)} send') if live
                          else (Level.WARN, f'{silence}; no input of this node sends'))
        elif live:
            median = float(np.median([o.rate for o in live]))
            if median > 0 and s.rate < t.rate_warn_ratio * median:
                checks.append((Level.WARN, f'rate {s.rate:.1f} Hz, below {t.rate_warn_ratio:g} x the others\' '
                                           f'median {median:.1f} Hz'))
        dropped = sum(s.dropped.values())
        if dropped:
            fraction = min(1.0, dropped / max(s.received, 1))
            reasons = ', '.join(f'{k} {n}' for k, n in sorted(s.dropped.items()))
            level = Level.ERROR if fraction > t.drop_error else Level.WARN if fraction > t.drop_warn else Level.OK
            checks.append((level, f'{fraction:.0%} of its messages dropped in the last {t.window:g} s ({reasons})'))
        level, message = judged(checks, f'{s.rate:.1f} Hz')
        values = {
            'rate (Hz)': f'{s.rate:.2f}',
            'messages in window': str(s.received),
            'dropped in window': str(dropped),
            'dropped in window by reason': ', '.join(f'{k} {n}' for k, n in sorted(s.dropped.items())) or 'none',
            'dropped since start': str(s.dropped_total),
            'late in window': str(s.dropped.get('late', 0)),
            'seconds since last message': f'{s.silent:.2f}' if s.ever else 'never',
            'sync offset from set stamp (ms, median)': '' if s.offset is None else f'{1e3 * s.offset:.1f}',
            'newest stamp (ns)': '' if s.newest_stamp is None else str(s.newest_stamp),
        }
        statuses.append(Status(f'{node}: input {s.name}', level, message, values, s.name))
    return statuses


def frame_rate_status(node: str, camera_hz: float | None, frame_rate: float) -> Status:
    """WARN when the cameras (stamp_rate of their stamps: the capture rate, whatever the pace of
    a replay) run at another rate than the frame_rate parameter: max_skew's default, half its
    period, may then group frames of different captures or split one capture, and bp_solver's
    nominal step is off."""
    values = {'camera rate from stamps (Hz)': '' if camera_hz is None else f'{camera_hz:.2f}',
              'frame_rate parameter (Hz)': f'{frame_rate:g}'}
    name = f'{node}: frame_rate'
    if camera_hz is None:
        return Status(name, Level.OK, f'frame_rate {frame_rate:g} Hz; camera rate not known yet', values)
    if not rate_differs(camera_hz, frame_rate):
        return Status(name, Level.OK, f'cameras at {camera_hz:.1f} Hz, frame_rate {frame_rate:g} Hz', values)
    return Status(name, Level.WARN,
                  f'the cameras run at {camera_hz:.1f} Hz (their stamps), the frame_rate parameter is {frame_rate:g} '
                  f"Hz: {FRAME_RATE_EFFECT}; set it to {camera_hz:.1f} (the parameter file's /** section)", values)


@dataclass
class NodeStats:
    """A node over the window: items processed, mean ms per item of each stage, latency in the node
    and from the capture stamp (s: median, max; None: no item), the median skew of its sets (s)."""

    items: int
    stage_ms: dict[str, float]
    latency: tuple[float, float] | None
    stamp_latency: tuple[float, float] | None
    skew: tuple[float, float] | None


class NodeMonitor:
    """A node's processing: what each item cost per stage, and how late its output was."""

    def __init__(self) -> None:
        self._stages = _Recent()
        self._latency = _Recent()
        self._stamp_latency = _Recent()
        self._skews = _Recent()
        self._totals: dict[str, float] = {}

    def processed(self, now: float, stage_seconds: Mapping[str, float]) -> None:
        """One item done: seconds per stage."""
        self._stages.add(now, dict(stage_seconds))

    def processed_totals(self, now: float, totals: Mapping[str, float]) -> None:
        """As processed(), from accumulated seconds per stage (a StageTimer's): the increments
        since the last call are this item's."""
        step = {k: v - self._totals.get(k, 0.0) for k, v in totals.items()}
        self._totals = dict(totals)
        self.processed(now, {k: v for k, v in step.items() if v > 0})

    def delivered(self, now: float, latency_s: float | None, stamp_latency_s: float | None) -> None:
        """One output went out: s from its input's arrival (None: not known), and s from its
        capture stamp to now on the node's clock (None: not known)."""
        if latency_s is not None:
            self._latency.add(now, latency_s)
        if stamp_latency_s is not None:
            self._stamp_latency.add(now, stamp_latency_s)

    def set_skew(self, now: float, skew_s: float) -> None:
        """A synchronised set went out with this spread of stamps."""
        self._skews.add(now, skew_s)

    def stats(self, now: float, window: float) -> NodeStats:
        """The figures of the last `window` s."""
        start = now - window
        stages = self._stages.since(start)
        ms = {}
        for item in stages:
            for name, seconds in item.items():
                ms[name] = ms.get(name, 0.0) + 1e3 * seconds
        return NodeStats(len(stages), {k: v / len(stages) for k, v in ms.items()},
                         _median_max(self._latency.since(start)), _median_max(self._stamp_latency.since(start)),
                         _median_max(self._skews.since(start)))


def _median_max(values: list) -> tuple[float, float] | None:
    return (float(np.median(values)), float(np.max(values))) if values else None


def node_status(node: str, s: NodeStats, queue_depth: int, t: HealthThresholds,
                extra: Mapping[str, str] | None = None) -> Status:
    """The node's own status: WARN / ERROR when the median latency (in the node, and from the
    capture stamp when that is within CLOCK_MISMATCH_S of the node's clock) exceeds
    latency_warn / latency_error."""
    checks: list[tuple[Level, str]] = []
    stamp_on_clock = s.stamp_latency is not None and abs(s.stamp_latency[0]) < CLOCK_MISMATCH_S
    for what, latency in (('in the node', s.latency), ('from the capture stamp', s.stamp_latency if stamp_on_clock
                                                       else None)):
        if latency is not None:
            level = (Level.ERROR if latency[0] > t.latency_error else Level.WARN if latency[0] > t.latency_warn
                     else Level.OK)
            checks.append((level, f'latency {what} {1e3 * latency[0]:.0f} ms (median)'))
    rate = s.items / t.window
    level, message = judged(checks, f'{rate:.1f} items/s, queue {queue_depth}')
    stamp = ('' if s.stamp_latency is None else f'{1e3 * s.stamp_latency[0]:.1f} / {1e3 * s.stamp_latency[1]:.1f}'
             if stamp_on_clock else 'not judged: the stamps are not on this clock (a replayed recording?)')
    values = {
        'items in window': str(s.items),
        **{f'{name} (ms per item)': f'{ms:.2f}' for name, ms in s.stage_ms.items()},
        'queue depth': str(queue_depth),
        'latency in node (ms, median / max)': '' if s.latency is None else
        f'{1e3 * s.latency[0]:.1f} / {1e3 * s.latency[1]:.1f}',
        'latency from capture stamp (ms, median / max)': stamp,
        **({} if s.skew is None else {'sync skew of sets (ms, median / max)':
                                      f'{1e3 * s.skew[0]:.1f} / {1e3 * s.skew[1]:.1f}'}),
        **(extra or {}),
    }
    return Status(f'{node}: node', level, message, values)
