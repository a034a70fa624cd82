"""Sum-product loopy belief propagation over one person's joints in a window of frames.

Variables are y[t, j] (frame t, joint j), each with M discrete 3D hypotheses. Factors: the
unary data term, one ternary temporal factor per joint and inner frame, and groups of
pairwise factors within a frame (collision pairs, limbs). The schedule is the paper's: every
iteration updates all messages of one factor type before the next; temporal messages sweep
forward through the window, then backward. Messages live in the log domain, normalised, so long
windows neither underflow nor drift.
"""
from __future__ import annotations

from collections import defaultdict
from dataclasses import dataclass, field, replace
from typing import Sequence

import numpy as np


@dataclass(frozen=True)
class PairwiseGroup:
    """One type of within-frame pairwise factor.

    edges: (E, 2) joint indices; tables: (T, E, M, M) potentials indexed [state of edges[e, 0],
    state of edges[e, 1]].
    """

    name: str
    edges: np.ndarray
    tables: np.ndarray


@dataclass
class Messages:
    """Factor-to-variable log messages, kept between calls to warm-start a sliding window.

    temporal: (3, T, J, M): from the factor centred at frame t to y[t-1], y[t], y[t+1].
    pairwise: per group (T, E, 2, M): to edges[e, 0] and to edges[e, 1].
    """

    temporal: np.ndarray
    pairwise: list[np.ndarray] = field(default_factory=list)

    @classmethod
    def uniform(cls, shape: tuple[int, int, int], edge_counts: Sequence[int]) -> Messages:
        t, j, m = shape
        return cls(np.zeros((3, t, j, m)), [np.zeros((t, e, 2, m)) for e in edge_counts])

    def slid(self, drop: int, add: int) -> Messages:
        """Messages of a window moved forward: the first `drop` frames leave, `add` new frames
        start uniform."""

        def move(a: np.ndarray, axis: int) -> np.ndarray:
            kept = a[(slice(None),) * axis + (slice(drop, None),)]
            if not add:
                return kept
            shape = list(a.shape)
            shape[axis] = add
            return np.concatenate([kept, np.zeros(shape, dtype=a.dtype)], axis=axis)

        return Messages(move(self.temporal, 1), [move(p, 0) for p in self.pairwise])


def _softmax(x: np.ndarray) -> np.ndarray:
    e = np.exp(x - x.max(axis=-1, keepdims=True))
    return e / e.sum(axis=-1, keepdims=True)


def _log_message(m: np.ndarray) -> np.ndarray:
    """Log of a non-negative message normalised to sum to one (in the linear domain: messages
    are products of normalised beliefs and tables, so the sum neither over- nor underflows)."""
    tiny = np.finfo(np.float64).tiny
    return np.log(np.maximum(m / np.maximum(m.sum(axis=-1, keepdims=True), tiny), tiny))


@dataclass
class ChainBP:
    """BP state over one person's chain of consecutive frames, kept between calls so that a
    sliding window warm-starts: frames are appended at the end and forgotten at the front.

    total: (T, J, M) log beliefs, the log data term plus every factor's current message.
    """

    temporal: list[np.ndarray | None]
    groups: list[PairwiseGroup]
    messages: Messages
    total: np.ndarray

    @classmethod
    def build(cls, data: np.ndarray, temporal: Sequence[np.ndarray | None],
              groups: Sequence[PairwiseGroup] = (), messages: Messages | None = None) -> ChainBP:
        """data: (T, J, M) non-negative unary potentials; temporal and groups as in loopy_bp."""
        t_len = len(data)
        if len(temporal) != t_len or (t_len and (temporal[0] is not None or temporal[-1] is not None)):
            raise ValueError('temporal needs one entry per frame, None at both ends')
        msgs = messages or Messages.uniform(data.shape, [len(g.edges) for g in groups])
        tm = msgs.temporal
        total = _log(data)
        total[:-1] += tm[0, 1:]
        total += tm[1]
        total[1:] += tm[2, :-1]
        for group, pm in zip(groups, msgs.pairwise):
            np.add.at(total, (slice(None), group.edges[:, 0]), pm[:, :, 0])
            np.add.at(total, (slice(None), group.edges[:, 1]), pm[:, :, 1])
        return cls(list(temporal), list(groups), msgs, total)

    def __len__(self) -> int:
        return len(self.total)

    def append(self, data: np.ndarray, temporal_prev: np.ndarray | None,
               tables: Sequence[np.ndarray] = ()) -> None:
        """Add a frame at the end. data: (J, M) its unary potentials; temporal_prev: the (J, M, M,
        M) factor centred at the previous last frame, which needed this one (None: no factor);
        tables: this frame's (E, M, M) table for each pairwise group. New messages start uniform."""
        if self.temporal:
            self.temporal[-1] = temporal_prev
        self.temporal.append(None)
        self.groups = [replace(g, tables=np.concatenate([g.tables, t[None]])) for g, t in zip(self.groups, tables)]
        self.messages = self.messages.slid(0, 1)
        self.total = np.concatenate([self.total, _log(data)[None]])

    def drop_front(self, n: int) -> None:
        """Forget the first n frames, and with them the temporal factors that touched them (centred
        at frames 1..n): their messages leave the kept frames' beliefs. So the chain remembers its
        window only: a wrong mode that evidence no longer supports cannot outlive the frames that
        supported it (kept as a prior, it held a wrist 0.5 m off for as long as the evidence
        stayed ambiguous). The other messages are recomputed by the next iterations."""
        if n <= 0:
            return
        if n < len(self.total):
            tm = self.messages.temporal
            self.total[n] -= tm[2, n - 1] + tm[1, n]
            if n + 1 < len(self.total):
                self.total[n + 1] -= tm[2, n]
            tm[1:, n] = 0.0
        self.temporal = self.temporal[n:]
        if self.temporal:
            self.temporal[0] = None
        self.groups = [replace(g, tables=g.tables[n:]) for g in self.groups]
        self.messages = self.messages.slid(n, 0)
        self.total = self.total[n:]

    def run(self, iterations: int) -> None:
        """The paper's schedule: per iteration, temporal factors forward then backward through the
        chain, then each pairwise type over all frames."""
        tm = self.messages.temporal
        inner = [t for t in range(1, len(self) - 1) if self.temporal[t] is not None]
        for _ in range(iterations):
            for sweep in (inner, inner[::-1]):
                for t in sweep:
                    _update_temporal(t, self.temporal[t], self.total, tm)
            for group, pm in zip(self.groups, self.messages.pairwise):
                _update_pairwise(group, self.total, pm)

    def marginals(self) -> np.ndarray:
        """(T, J, M) normalised beliefs."""
        return _softmax(self.total)

    def marginals_at(self, row: int) -> np.ndarray:
        """(J, M) normalised beliefs of one frame of the chain."""
        return _softmax(self.total[row])


def run_chains(chains: Sequence[ChainBP], iterations: int) -> None:
    """ChainBP.run of every chain, with the chains of one shape stacked along the joint axis so
    that each message update is one set of numpy calls for all of them (chains are independent:
    the messages are exactly those of running each on its own)."""
    alike: dict[tuple, list[ChainBP]] = defaultdict(list)
    for chain in chains:
        key = (chain.total.shape, tuple(t is None for t in chain.temporal),
               tuple((g.name, len(g.edges)) for g in chain.groups))
        alike[key].append(chain)
    for group in alike.values():
        if len(group) == 1:
            group[0].run(iterations)
            continue
        joint = _stacked(group)
        joint.run(iterations)
        n_j = group[0].total.shape[1]
        for p, chain in enumerate(group):
            joints = slice(p * n_j, (p + 1) * n_j)
            chain.total = joint.total[:, joints]
            chain.messages = Messages(joint.messages.temporal[:, :, joints],
                                      [pm[:, p * len(g.edges):(p + 1) * len(g.edges)]
                                       for pm, g in zip(joint.messages.pairwise, chain.groups)])


def _stacked(chains: Sequence[ChainBP]) -> ChainBP:
    """One chain whose joints are those of every chain in turn (same length and factor layout)."""
    n_j = chains[0].total.shape[1]
    temporal = [None if t is None else _joined([c.temporal[i] for c in chains])
                for i, t in enumerate(chains[0].temporal)]
    groups = [PairwiseGroup(g.name, np.concatenate([c.groups[k].edges + p * n_j for p, c in enumerate(chains)]),
                            np.concatenate([c.groups[k].tables for c in chains], axis=1))
              for k, g in enumerate(chains[0].groups)]
    messages = Messages(np.concatenate([c.messages.temporal for c in chains], axis=2),
                        [np.concatenate([c.messages.pairwise[k] for c in chains], axis=1)
                         for k in range(len(groups))])
    return ChainBP(temporal, groups, messages, np.concatenate([c.total for c in chains], axis=1))


def _joined(arrays: Sequence[np.ndarray]) -> np.ndarray:
    """np.concatenate(arrays) along axis 0, as a view without copying when they are successive
    slices of one C-contiguous array (the temporal tables of one frame are made for every person
    at once, window.SlidingWindow._add_temporal, and chains are stacked in the same order)."""
    base = arrays[0].base
    if (isinstance(base, np.ndarray) and base.flags.c_contiguous and base.dtype == arrays[0].dtype
            and all(a.base is base and a.flags.c_contiguous for a in arrays)):
        start = [a.__array_interface__['data'][0] for a in arrays]
        if all(p + a.nbytes == q for p, a, q in zip(start, arrays, start[1:])):
            offset = (start[0] - base.__array_interface__['data'][0]) // base.itemsize
            size = sum(a.size for a in arrays)
            return base.reshape(-1)[offset:offset + size].reshape((-1,) + arrays[0].shape[1:])
    return np.concatenate(arrays)


def loopy_bp(
    data: np.ndarray,
    temporal: Sequence[np.ndarray | None],
    groups: Sequence[PairwiseGroup] = (),
    iterations: int = 5,
    messages: Messages | None = None,
) -> tuple[np.ndarray, Messages]:
    """Marginals of every joint hypothesis in a window.

    data: (T, J, M) non-negative unary potentials. temporal: T entries; entry t is None or the
    (J, M, M, M) table of the factor on (y[t-1], y[t], y[t+1]) indexed [j, a, c, b] (see
    factors.temporal_table); entries 0 and T-1 must be None. messages: a warm start of matching
    shape. Returns the marginals (T, J, M) and the final messages.
    """
    chain = ChainBP.build(data, temporal, groups, messages)
    chain.run(iterations)
    return chain.marginals(), chain.messages


def _log(data: np.ndarray) -> np.ndarray:
    return np.log(np.maximum(data, np.finfo(np.float64).tiny))


def _update_temporal(t: int, table: np.ndarray, total: np.ndarray, tm: np.ndarray) -> None:
    """Recompute the three outgoing messages of the temporal factor centred at frame t."""
    j, ma, mc, mb = table.shape
    # the beliefs of y[t-1], y[t], y[t+1] without this factor's own messages, at once, in the
    # table's precision (float32): mixing would convert the M^3 table every call
    n_prev, n_cur, n_next = _softmax(total[t - 1:t + 2] - tm[:, t]).astype(table.dtype)
    flat = table.reshape(j, ma * mc, mb)
    pair = (n_prev[:, :, None] * n_next[:, None, :]).reshape(j, 1, ma * mc)
    over_cur = (flat @ n_cur[:, :, None]).reshape(j, ma, mc)
    new = _log_message(np.stack([(over_cur @ n_next[:, :, None])[..., 0],  # to y[t-1]
                                 (pair @ flat)[:, 0],  # to y[t]
                                 (n_prev[:, None, :] @ over_cur)[:, 0]]))  # to y[t+1]
    total[t - 1:t + 2] += new - tm[:, t]
    tm[:, t] = new


def _update_pairwise(group: PairwiseGroup, total: np.ndarray, pm: np.ndarray) -> None:
    """Flooding update of every factor of one pairwise type, all frames at once."""
    i, k = group.edges[:, 0], group.edges[:, 1]
    n_i = _softmax(total[:, i] - pm[:, :, 0]).astype(group.tables.dtype)
    n_k = _softmax(total[:, k] - pm[:, :, 1]).astype(group.tables.dtype)
    to_i = _log_message((group.tables @ n_k[..., None])[..., 0])
    to_k = _log_message((n_i[..., None, :] @ group.tables)[..., 0, :])
    # one unbuffered scatter, edge after edge and each edge's first joint before its second: the
    # additions to a joint come in the order of a loop over the edges, so the sums are the same
    change = np.stack([to_i - pm[:, :, 0], to_k - pm[:, :, 1]], axis=2)  # (T, E, 2, M)
    np.add.at(total, (slice(None), group.edges.ravel()), change.reshape(len(total), -1, total.shape[-1]))
    pm[:, :, 0] = to_i
    pm[:, :, 1] = to_k
