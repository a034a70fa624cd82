"""Sum-product loopy belief propagation over one person's joints in a window of frames.

Variables are y[t, j] (frame t, joint j), each with M discrete 3D hypotheses. Factors: the
unary data term, one ternary temporal factor per joint and inner frame, and groups of
pairwise factors within a frame (collision pairs, limbs). The schedule is the paper's: every
iteration updates all messages of one factor type before the next; temporal messages sweep
forward through the window, then backward. Messages live in the log domain, normalised, so long
windows neither underflow nor drift. Each factor's update is one compiled kernel.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Sequence

import numpy as np

from mvpose_ros.core.compiled import kernel, kernel_array, pairwise_sum
from mvpose_ros.core.workers import Workers


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
        """Uniform (all-zero log) messages: unary (3, T, J, M) for shape (T, J, M), and per pairwise
        factor kind k, (T, edge_counts[k], 2, M)."""
        t, j, m = shape
        return cls(np.zeros((3, t, j, m)), [np.zeros((t, e, 2, m)) for e in edge_counts])

    def slid(self, drop: int, add: int) -> Messages:
        """Messages of a window moved forward: the first `drop` frames leave, `add` new frames
        start uniform."""

        def move(a: np.ndarray, axis: int) -> np.ndarray:
            kept = a[(slice(None),) * axis + (slice(drop, None),)]
            if not add:
                return np.ascontiguousarray(kept)  # as the kernels take them
            shape = list(a.shape)
            shape[axis] = add
            return np.concatenate([kept, np.zeros(shape, dtype=a.dtype)], axis=axis)

        return Messages(move(self.temporal, 1), [move(p, 0) for p in self.pairwise])


def _softmax(x: np.ndarray) -> np.ndarray:
    """exp(x) normalised along the last axis (..., M)."""
    rows = kernel_array(x, np.float64).reshape(math.prod(x.shape[:-1]), x.shape[-1])
    return _softmax_rows(rows).reshape(x.shape)


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
        self.groups = [PairwiseGroup(g.name, g.edges, np.concatenate([g.tables, t[None]]))
                       for g, t in zip(self.groups, tables)]
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
        self.groups = [PairwiseGroup(g.name, g.edges, g.tables[n:]) for g in self.groups]
        self.messages = self.messages.slid(n, 0)
        self.total = self.total[n:]

    def run(self, iterations: int) -> None:
        """The paper's schedule: per iteration, temporal factors forward then backward through the
        chain, then each pairwise type over all frames."""
        tm = self.messages.temporal
        inner = [t for t in range(1, len(self) - 1) if self.temporal[t] is not None]
        edges = [kernel_array(g.edges, np.int64) for g in self.groups]
        # The backward sweep starts one factor early: the forward sweep's last update left that
        # factor's inputs (its cavities) as they were, so updating it again would resend its messages.
        schedule = inner + inner[-2::-1]
        for _ in range(iterations):
            for t in schedule:
                _update_temporal(self.temporal[t], self.total, tm, t)
            for group, e, pm in zip(self.groups, edges, self.messages.pairwise):
                _update_pairwise(e, group.tables, self.total, pm)

    def marginals(self) -> np.ndarray:
        """(T, J, M) normalised beliefs."""
        return _softmax(self.total)

    def marginals_at(self, row: int) -> np.ndarray:
        """(J, M) normalised beliefs of one frame of the chain."""
        return _softmax(self.total[row])


def run_chains(chains: Sequence[ChainBP], iterations: int, workers: Workers | None = None) -> None:
    """ChainBP.run of every chain. Chains are independent, so `workers` may run them side by side,
    split by length (a chain's cost grows with its frames)."""
    def run(part: Sequence[ChainBP]) -> None:
        for chain in part:
            chain.run(iterations)

    if workers is None:
        run(chains)
    else:
        workers.map(run, workers.split(chains, cost=len))


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


@kernel('float64[:, ::1](float64[:, ::1])')
def _softmax_rows(x):
    """Each row of x (N, M) exponentiated and normalised, numpy's arithmetic (exp is libm's: numpy's
    vectorised exp on AVX-512 CPUs rounds some values an ulp differently)."""
    out = np.empty_like(x)
    for i in range(x.shape[0]):
        top = x[i].max()
        for k in range(x.shape[1]):
            out[i, k] = np.exp(x[i, k] - top)
        s = pairwise_sum(out[i])
        for k in range(x.shape[1]):
            out[i, k] /= s
    return out


@kernel('void(float64[::1], float64[::1], float64[::1], float32[::1])',
        'void(float64[::1], float64[::1], float64[::1], float64[::1])')
def _cavity(total, own, scratch, out):
    """out (M,) = the normalised belief of a variable without one factor's message `own` to it,
    softmax(total - own) (as _softmax, in float64, then stored in out's precision); scratch: (M,)."""
    m = len(total)
    for k in range(m):
        scratch[k] = total[k] - own[k]
    top = scratch.max()
    for k in range(m):
        scratch[k] = np.exp(scratch[k] - top)
    s = pairwise_sum(scratch)
    for k in range(m):
        out[k] = scratch[k] / s


@kernel('void(float32[::1], float64[::1])', 'void(float64[::1], float64[::1])')
def _log_message_into(m, out):
    """out (M,): the log of a non-negative message m (M,) normalised to sum to one, m summed in
    its own precision, the rest in float64 (in the linear domain: messages are products of
    normalised beliefs and tables, so the sum neither over- nor underflows)."""
    tiny = np.finfo(np.float64).tiny
    s = max(np.float64(pairwise_sum(m)), tiny)
    for k in range(len(m)):
        out[k] = np.log(max(m[k] / s, tiny))


@kernel('void(float32[::1], float64[::1], float64[::1], float64[::1])',
        'void(float64[::1], float64[::1], float64[::1], float64[::1])')
def _send(msg, total, old, scratch):
    """Replace a factor's log message `old` (M,) to a variable by the log of msg (M,) normalised and update that
    variable's log belief `total` (M,) with the change; scratch: (M,)."""
    _log_message_into(msg, scratch)
    for x in range(len(msg)):
        total[x] += scratch[x] - old[x]
        old[x] = scratch[x]


@kernel('void(float32[:, :, :, ::1], float64[:, :, ::1], float64[:, :, :, ::1], int64)',
        'void(float64[:, :, :, ::1], float64[:, :, ::1], float64[:, :, :, ::1], int64)')
def _update_temporal(table, total, tm, t):
    """Recompute the three outgoing messages of the temporal factor centred at frame t.

    table: (J, Ma, Mc, Mb) indexed [j, a, c, b] (factors.temporal_table); total: (T, J, M) log
    beliefs; tm: (3, T, J, M) temporal messages (Messages.temporal); both updated in place. The
    beliefs of y[t-1], y[t], y[t+1] without this factor's messages are taken in the table's
    precision; the products with the table are np.dot, the BLAS matrix-vector products numpy's
    matmul makes of them (the same sums: the messages are numpy's to the bit):
      over[a, c] = sum_b f[a, c, b] n_cur[b]     to y[t-1] = over . n_next, to y[t+1] = n_prev . over
      to y[t] = sum_{a, c} n_prev[a] n_next[c] f[a, c, b]
    """
    n_j, ma, mc, mb = table.shape
    dtype = table.dtype
    n_prev, n_next, n_cur = np.empty(ma, dtype), np.empty(mc, dtype), np.empty(mb, dtype)
    pair = np.empty(ma * mc, dtype)
    over_flat = np.empty(ma * mc, dtype)
    over = over_flat.reshape(ma, mc)
    to_prev, to_cur, to_next = np.empty(ma, dtype), np.empty(mb, dtype), np.empty(mc, dtype)
    scratch = np.empty(max(ma, mb, mc))
    new = np.empty(max(ma, mb, mc))
    for j in range(n_j):
        _cavity(total[t - 1, j], tm[0, t, j], scratch[:ma], n_prev)
        _cavity(total[t, j], tm[1, t, j], scratch[:mb], n_cur)
        _cavity(total[t + 1, j], tm[2, t, j], scratch[:mc], n_next)
        flat = table[j].reshape(ma * mc, mb)
        for a in range(ma):
            for c in range(mc):
                pair[a * mc + c] = n_prev[a] * n_next[c]
        # into buffers made once: a product allocating its result cost as much as the product
        np.dot(flat, n_cur, over_flat)
        np.dot(over, n_next, to_prev)
        np.dot(pair, flat, to_cur)
        np.dot(n_prev, over, to_next)
        _send(to_prev, total[t - 1, j], tm[0, t, j], new[:ma])
        _send(to_cur, total[t, j], tm[1, t, j], new[:mb])
        _send(to_next, total[t + 1, j], tm[2, t, j], new[:mc])


@kernel('void(int64[:, ::1], float32[:, :, :, ::1], float64[:, :, ::1], float64[:, :, :, ::1])',
        'void(int64[:, ::1], float64[:, :, :, ::1], float64[:, :, ::1], float64[:, :, :, ::1])')
def _update_pairwise(edges, tables, total, pm):
    """Flooding update of every factor of one pairwise type, all frames at once.

    edges: (E, 2) joints; tables: (T, E, M, M) indexed [state of edges[e, 0], state of edges[e,
    1]]; total: (T, J, M) log beliefs; pm: (T, E, 2, M) the group's messages; both updated in
    place. Every message of a frame comes from its beliefs before the update; the changes are then
    added edge after edge, each edge's first joint before its second.
    """
    n_t, n_e, m = pm.shape[0], pm.shape[1], pm.shape[3]
    dtype = tables.dtype
    n_i, n_k = np.empty(m, dtype), np.empty(m, dtype)
    to_i, to_k = np.empty(m, dtype), np.empty(m, dtype)
    scratch = np.empty(m)
    new = np.empty((n_e, 2, m))
    for t in range(n_t):
        for e in range(n_e):
            _cavity(total[t, edges[e, 0]], pm[t, e, 0], scratch, n_i)
            _cavity(total[t, edges[e, 1]], pm[t, e, 1], scratch, n_k)
            np.dot(tables[t, e], n_k, to_i)  # BLAS, as numpy's matmul
            np.dot(n_i, tables[t, e], to_k)
            _log_message_into(to_i, new[e, 0])
            _log_message_into(to_k, new[e, 1])
        for e in range(n_e):
            for side in range(2):
                joint = edges[e, side]
                for x in range(m):
                    total[t, joint, x] += new[e, side, x] - pm[t, e, side, x]
                    pm[t, e, side, x] = new[e, side, x]
