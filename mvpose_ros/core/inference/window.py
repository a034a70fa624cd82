"""Temporal inference over a sliding window of frames (or over a whole clip), per person.

Frames are pushed as they arrive; every pushed frame comes out exactly once, `lag` frames later
(or at `flush`), with the decoded 3D joints of each person present in it. Each frame has a time
(seconds; by default its number over the nominal frame rate). A person's chain is the run of
successive pushed frames in which that person is present, with no more than `max_gap` seconds
between two of them: an absence or a longer gap breaks it. Frames need not be evenly spaced: the
temporal factor predicts with constant velocity over the real times (factors.temporal_table).
Factor tables depend only on hypotheses, so they are computed once per frame. With
`slide_iterations`, each person keeps one BP state per chain (bp.ChainBP) that every new frame
extends and warm-starts, so a slide costs a fraction of a solve; without it every window is solved
again from uniform messages with `iterations` iterations (the reference)."""
from __future__ import annotations

import time
from collections import deque
from dataclasses import dataclass, field

import numpy as np

from mvpose_ros.core.compiled import kernel, kernel_array, pairwise_sum
from mvpose_ros.core.defaults import FRAME_RATE
from mvpose_ros.core.geometry.body import NUM_INFERENCE_JOINTS
from mvpose_ros.core.inference.bp import ChainBP, PairwiseGroup, loopy_bp, run_chains
from mvpose_ros.core.inference.confidence import joint_confidence
from mvpose_ros.core.inference.factors import FactorConfig, collision_table, limb_table, pair_distances, temporal_table
from mvpose_ros.core.timing import StageTimer
from mvpose_ros.core.types import FrameResult, PersonFrame
from mvpose_ros.core.workers import Workers

TERMS = ('data', 'temp', 'col', 'limb')


@dataclass(frozen=True)
class InferenceConfig:
    """terms: factors to use; window: frames per window (None = the whole clip); lag: frames
    between a frame's arrival and its output; bp_hypotheses: keep only this many hypotheses per
    joint (those with the highest data term) inside BP, None = all M; slide_iterations: in window
    mode, warm-start each slide from the previous one with this many iterations (None: re-solve
    every window from scratch with `iterations`); frame_rate: nominal frames per second, the
    period the temporal factor's scale is defined for, and the time of a frame pushed without one
    (frame / frame_rate s); max_gap: seconds between two successive frames beyond which every
    chain breaks (no temporal link across it); threads: threads solving people's chains and
    temporal tables side by side (core.workers; the results do not depend on it)."""

    terms: tuple[str, ...] = ('data', 'temp', 'col', 'limb')
    window: int | None = 15
    lag: int = 7
    iterations: int = 5
    bp_hypotheses: int | None = 16
    slide_iterations: int | None = 1
    factors: FactorConfig = field(default_factory=FactorConfig)
    frame_rate: float = FRAME_RATE
    max_gap: float = 0.2
    threads: int = 2

    def __post_init__(self) -> None:
        unknown = set(self.terms) - set(TERMS)
        if unknown or 'data' not in self.terms:
            raise ValueError(f'terms must include data and come from {TERMS}, got {self.terms}')
        if self.window is not None and not 0 <= self.lag < self.window:
            raise ValueError(f'lag must be in [0, window), got lag={self.lag} window={self.window}')
        if self.bp_hypotheses is not None and self.bp_hypotheses < 1:
            raise ValueError(f'bp_hypotheses must be >= 1 or None, got {self.bp_hypotheses}')
        if self.iterations < 1:
            raise ValueError(f'iterations must be >= 1, got {self.iterations}')
        if self.slide_iterations is not None and self.slide_iterations < 1:
            raise ValueError(f'slide_iterations must be >= 1 or None, got {self.slide_iterations}')
        if self.threads < 1:
            raise ValueError(f'threads must be >= 1, got {self.threads}')
        if not (0 < self.frame_rate < float('inf') and self.max_gap > 0):
            raise ValueError(f'frame_rate and max_gap must be positive, got {self.frame_rate}, {self.max_gap}')


STEP_TOLERANCE = 1e-6  # relative: steps this close to a nominal period (or to each other) are taken as equal


@dataclass
class _Slot:
    """A pushed frame; linked: it follows the frame pushed before it within max_gap."""

    frame: int
    time: float
    linked: bool
    people: dict[int, PersonFrame]
    temporal: dict[int, np.ndarray] = field(default_factory=dict)
    collision: dict[int, np.ndarray] = field(default_factory=dict)
    limb: dict[int, np.ndarray] = field(default_factory=dict)


@dataclass
class _Chain:
    """Warm-started BP of one person over the linked frames `frames` (one per BP row); support:
    each frame's (J,)."""

    frames: deque[int] = field(default_factory=deque)
    bp: ChainBP | None = None
    hypotheses: deque[np.ndarray] = field(default_factory=deque)
    support: deque[np.ndarray] = field(default_factory=deque)

    @property
    def last(self) -> int:
        return self.frames[-1]


class SlidingWindow:
    """Sliding-window sum-product BP over the CRF of each person."""

    def __init__(self, config: InferenceConfig, symmetric_pairs: np.ndarray, bones: np.ndarray,
                 lengths: np.ndarray, timer: StageTimer | None = None) -> None:
        """symmetric_pairs (S, 2): the joints of the collision factors; bones (E, 2) and their
        typical lengths (E,) m: the limb factors; timer: where the time of 'factors' (tables), 'bp'
        (messages) and 'decoding' goes."""
        self.config = config
        self.timer = timer or StageTimer()
        self.symmetric_pairs = np.asarray(symmetric_pairs)
        self.bones = np.asarray(bones)
        self.lengths = np.asarray(lengths, dtype=np.float64)
        self._slots: deque[_Slot] = deque()
        self._unsent = 0
        self._chains: dict[int, _Chain] = {}  # warm-started mode: each present person's chain
        self._ended: list[tuple[int, _Chain]] = []  # (person id, chain) broken, with frames still to output
        self._workers = Workers(config.threads)

    @property
    def _warm(self) -> bool:
        return self.config.window is not None and self.config.slide_iterations is not None

    def push(self, frame: int, people: list[PersonFrame], time_s: float | None = None) -> list[FrameResult]:
        """Add a frame taken at time_s seconds (None: frame / frame_rate); frames and times must
        increase, and a gap of more than max_gap seconds breaks every chain. Returns the frames
        whose output is due (at most one in window mode)."""
        time_s = frame / self.config.frame_rate if time_s is None else float(time_s)
        last = self._slots[-1] if self._slots else None
        if last is not None and frame <= last.frame:
            raise ValueError(f'frame {frame} pushed after frame {last.frame}: frames must increase')
        if last is not None and not time_s > last.time:
            raise ValueError(f'frame {frame} at {time_s} s pushed after frame {last.frame} at {last.time} s: '
                             f'times must increase')
        linked = last is not None and time_s - last.time <= self.config.max_gap * (1 + STEP_TOLERANCE)
        k = self.config.bp_hypotheses
        slot = _Slot(frame, time_s, linked, {p.person_id: _pruned(p, k) if k else p for p in people})
        self._slots.append(slot)
        self._unsent += 1
        if 'temp' in self.config.terms and len(self._slots) >= 3:
            t0 = time.perf_counter()
            self._add_temporal(len(self._slots) - 2)
            self.timer.add('factors', t0)
        if self.config.window is None:
            return []
        if self._warm:
            self._slide(len(self._slots) - 1)
        while len(self._slots) > self.config.window:
            self._slots.popleft()
        if self._unsent <= self.config.lag:
            return []
        self._unsent -= 1
        return [self._decode_at(len(self._slots) - 1 - self.config.lag)]

    def live(self) -> FrameResult | None:
        """The newest frame decoded now, from the frames up to it only (the causal estimate, with no
        lag; None before the first frame). In window mode the lagged output of the same frame comes
        later and has seen the frames after it."""
        if not self._slots:
            return None
        return self._decode_at(len(self._slots) - 1, forget=False)

    def flush(self) -> list[FrameResult]:
        """Output every frame not yet output (end of stream)."""
        start = len(self._slots) - self._unsent
        if self.config.window is None:
            out = self._decode_all()[start:]
        else:
            out = [self._decode_at(i) for i in range(start, len(self._slots))]
        self._unsent = 0
        return out

    def _slide(self, i: int) -> None:
        """Extend each present person's chain with the frame at buffer position i and warm-start
        its BP; a person absent here, or back after a gap, ends its chain."""
        slot = self._slots[i]
        before = self._slots[i - 1].frame if i > 0 and slot.linked else None
        for pid in list(self._chains):
            if pid not in slot.people or self._chains[pid].last != before:
                self._ended.append((pid, self._chains.pop(pid)))
        for pid, p in slot.people.items():
            chain = self._chains.get(pid)
            if chain is None:
                chain = self._chains[pid] = _Chain()
            chain.frames.append(slot.frame)
            chain.hypotheses.append(p.hypotheses)
            chain.support.append(p.support)
            t0 = time.perf_counter()
            groups = self._groups(pid, i)
            t0 = self.timer.add('factors', t0)
            if chain.bp is None:
                chain.bp = ChainBP.build(p.data[None], [None], groups)
            else:
                chain.bp.append(p.data, self._slots[i - 1].temporal.get(pid), [g.tables[0] for g in groups])
            excess = len(chain.bp) - self.config.window
            if excess > 0:
                chain.bp.drop_front(excess)
                for _ in range(excess):
                    chain.frames.popleft()
                    chain.hypotheses.popleft()
                    chain.support.popleft()
            self.timer.add('bp', t0)
        t0 = time.perf_counter()
        run_chains([self._chains[pid].bp for pid in sorted(slot.people)], self.config.slide_iterations, self._workers)
        self.timer.add('bp', t0)

    def _groups(self, pid: int, i: int) -> list[PairwiseGroup]:
        """The pairwise groups of person pid at buffer position i, as one-frame tables."""
        groups = []
        if 'col' in self.config.terms:
            groups.append(PairwiseGroup('collision', self.symmetric_pairs, self._collision(pid, i)[None]))
        if 'limb' in self.config.terms:
            groups.append(PairwiseGroup('limb', self.bones, self._limb(pid, i)[None]))
        return groups

    def _add_temporal(self, i: int) -> None:
        """Temporal tables of the frame at buffer position i, now that its successor is in; none
        across a gap (max_gap). The steps are the real times between the three frames."""
        prev, cur, nxt = self._slots[i - 1], self._slots[i], self._slots[i + 1]
        if not (cur.linked and nxt.linked):
            return
        pids = sorted(cur.people.keys() & prev.people.keys() & nxt.people.keys())
        if not pids:
            return
        # each worker's people's joints in one call: the table of a joint depends on that joint alone
        steps = _steps(cur.time - prev.time, nxt.time - cur.time, self.config.frame_rate)

        def tables(part: list[int]) -> np.ndarray:
            return temporal_table(*(np.concatenate([s.people[pid].hypotheses for pid in part])
                                    for s in (prev, cur, nxt)), self.config.factors, steps)

        parts = self._workers.split(pids)
        for part, table in zip(parts, self._workers.map(tables, parts)):
            for k, joints in enumerate(np.split(table, len(part))):
                cur.temporal[part[k]] = joints

    def _run(self, pid: int, i: int) -> range:
        """Buffer positions of the chain of person pid through position i (linked frames)."""
        s = self._slots
        lo, hi = i, i
        while lo > 0 and pid in s[lo - 1].people and s[lo].linked:
            lo -= 1
        while hi + 1 < len(s) and pid in s[hi + 1].people and s[hi + 1].linked:
            hi += 1
        return range(lo, hi + 1)

    def _decode_at(self, i: int, forget: bool = True) -> FrameResult:
        """The frame at buffer position i decoded; forget: it is output, so the chains that ended
        before it are no longer needed."""
        slot = self._slots[i]
        ids = sorted(slot.people)
        if self._warm:
            t0 = time.perf_counter()
            decoded = [self._decode_warm(pid, slot.frame) for pid in ids]
            if forget:
                self._ended = [(q, c) for q, c in self._ended if c.last > slot.frame]
            self.timer.add('decoding', t0)
        else:
            decoded = []
            for pid in ids:
                run = self._run(pid, i)
                joints, confidence = self._solve(pid, run)
                decoded.append((joints[i - run.start], confidence[i - run.start]))
        return _result(slot.frame, ids, decoded)

    def _decode_warm(self, pid: int, frame: int) -> tuple[np.ndarray, np.ndarray]:
        """Joints (J, 3) and their confidence (J,) of person pid at `frame` from the current beliefs
        of its chain."""
        chains = [c for q, c in self._ended if q == pid] + ([self._chains[pid]] if pid in self._chains else [])
        chain = next(c for c in chains if c.frames[0] <= frame <= c.last)
        row = chain.frames.index(frame)
        best = chain.bp.total[row].argmax(axis=-1)  # (J,)
        hyp = chain.hypotheses[row]
        confidence = joint_confidence(chain.bp.marginals_at(row), hyp, best, chain.support[row])
        return hyp[np.arange(len(best)), best], confidence

    def _decode_all(self) -> list[FrameResult]:
        decoded: dict[tuple[int, int], tuple[np.ndarray, np.ndarray]] = {}
        for i, slot in enumerate(self._slots):
            for pid in slot.people:
                if (pid, i) not in decoded:
                    run = self._run(pid, i)
                    for pos, joints, confidence in zip(run, *self._solve(pid, run)):
                        decoded[(pid, pos)] = joints, confidence
        return [_result(s.frame, sorted(s.people), [decoded[(pid, i)] for pid in sorted(s.people)])
                for i, s in enumerate(self._slots)]

    def _solve(self, pid: int, run: range) -> tuple[np.ndarray, np.ndarray]:
        """Decoded joints (T, J, 3) of person pid over the buffer positions `run`, and their
        confidence (T, J)."""
        t0 = time.perf_counter()
        frames = [self._slots[i].people[pid] for i in run]
        hyp = np.stack([f.hypotheses for f in frames])  # (T, J, M, 3)
        data = np.stack([f.data for f in frames])
        terms = self.config.terms
        temporal = [None] * len(run)
        if 'temp' in terms:
            for t, i in enumerate(run):
                if 0 < t < len(run) - 1:
                    temporal[t] = self._slots[i].temporal[pid]
        groups = []
        if 'col' in terms:
            groups.append(PairwiseGroup('collision', self.symmetric_pairs,
                                        np.stack([self._collision(pid, i) for i in run])))
        if 'limb' in terms:
            groups.append(PairwiseGroup('limb', self.bones, np.stack([self._limb(pid, i) for i in run])))
        t0 = self.timer.add('factors', t0)
        if not groups and not any(t is not None for t in temporal):
            marginals = data
        else:
            marginals, _ = loopy_bp(data, temporal, groups, self.config.iterations)
        t0 = self.timer.add('bp', t0)
        best = marginals.argmax(axis=-1)  # (T, J)
        out = np.take_along_axis(hyp, best[..., None, None], axis=2)[:, :, 0]
        confidence = joint_confidence(marginals, hyp, best, np.stack([f.support for f in frames]))
        self.timer.add('decoding', t0)
        return out, confidence

    def _frame_tables(self, i: int) -> None:
        """The collision and limb tables of every person at buffer position i not yet made, each
        kind in one call for all of them (a person's tables depend on their own hypotheses only), as
        one call per person costs more."""
        slot = self._slots[i]
        terms = self.config.terms
        pids = [pid for pid in sorted(slot.people)
                if ('col' in terms and pid not in slot.collision) or ('limb' in terms and pid not in slot.limb)]
        if not pids:
            return
        h = np.stack([slot.people[pid].hypotheses for pid in pids])  # (P, J, M, 3)
        if 'col' in terms:
            pairs = self.symmetric_pairs
            slot.collision.update(zip(pids, collision_table(h[:, pairs[:, 0]], h[:, pairs[:, 1]], self.config.factors)))
        if 'limb' in terms:
            slot.limb.update(zip(pids, limb_table(pair_distances(h[:, self.bones[:, 0]], h[:, self.bones[:, 1]]),
                                                  self.lengths, self.config.factors)))

    def _collision(self, pid: int, i: int) -> np.ndarray:
        self._frame_tables(i)
        return self._slots[i].collision[pid]

    def _limb(self, pid: int, i: int) -> np.ndarray:
        self._frame_tables(i)
        return self._slots[i].limb[pid]


def _steps(dt_prev: float, dt_next: float, rate: float) -> tuple[float, float]:
    """Two successive time steps (s) in nominal periods; steps within STEP_TOLERANCE of one period
    are exactly 1 and nearly equal steps exactly equal, so evenly spaced frames give the evenly
    spaced factor bit for bit whatever the rounding of their times."""
    steps = [dt * rate for dt in (dt_prev, dt_next)]
    steps = [1.0 if abs(s - 1.0) <= STEP_TOLERANCE else s for s in steps]
    if abs(steps[0] - steps[1]) <= STEP_TOLERANCE * max(steps):
        steps[1] = steps[0]
    return steps[0], steps[1]


def _pruned(p: PersonFrame, k: int) -> PersonFrame:
    """Person p with the k hypotheses of each joint of highest data term (ties: the first), the
    data term renormalised."""
    if k >= p.data.shape[1]:
        return p
    data, hypotheses = _top_hypotheses(kernel_array(p.data, np.float64),
                                       kernel_array(p.hypotheses, np.float64), k)
    return PersonFrame(p.person_id, hypotheses, data, p.support)


@kernel('Tuple((float64[:, ::1], float64[:, :, ::1]))(float64[:, ::1], float64[:, :, ::1], int64)')
def _top_hypotheses(data, hypotheses, k):
    """_pruned's data (J, k) and hypotheses (J, k, 3) from (J, M) and (J, M, 3), 0 < k < M: per
    joint the k largest by insertion in a sorted list, an equal value after those before it (the
    order of numpy's stable argsort of -data)."""
    n_j, m = data.shape
    kept = np.empty((n_j, k))
    points = np.empty((n_j, k, 3))
    order = np.empty(k, np.int64)
    tiny = np.finfo(np.float64).tiny
    for j in range(n_j):
        values = kept[j]
        n = 0
        for i in range(m):
            v = data[j, i]
            if n == k:
                if not v > values[k - 1]:
                    continue
                n -= 1  # the smallest kept leaves
            r = n
            while r > 0 and values[r - 1] < v:
                values[r] = values[r - 1]
                order[r] = order[r - 1]
                r -= 1
            values[r] = v
            order[r] = i
            n += 1
        for r in range(k):
            points[j, r] = hypotheses[j, order[r]]
        total = max(pairwise_sum(values), tiny)
        for r in range(k):
            values[r] /= total
    return kept, points


def _result(frame: int, ids: list[int], decoded: list[tuple[np.ndarray, np.ndarray]]) -> FrameResult:
    """A frame's result from each person's (joints (J, 3), confidence (J,))."""
    if not decoded:
        return FrameResult(frame, ids, np.zeros((0, NUM_INFERENCE_JOINTS, 3)), np.zeros((0, NUM_INFERENCE_JOINTS)))
    return FrameResult(frame, ids, np.stack([j for j, _ in decoded]), np.stack([c for _, c in decoded]))
