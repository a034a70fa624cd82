"""Loopy BP against brute-force enumeration of the same factor graph."""
from __future__ import annotations

import itertools

import numpy as np
import pytest

from mvpose_ros.core.inference.bp import ChainBP, Messages, PairwiseGroup, loopy_bp


def brute_force(data, temporal, groups):
    """Exact marginals (T, J, M) by enumerating every joint assignment."""
    t_len, n_joints, m = data.shape
    n_vars = t_len * n_joints
    marg = np.zeros_like(data, dtype=np.float64)
    for states in itertools.product(range(m), repeat=n_vars):
        s = np.array(states).reshape(t_len, n_joints)
        p = np.prod(data[np.arange(t_len)[:, None], np.arange(n_joints)[None, :], s])
        for t, table in enumerate(temporal):
            if table is not None:
                for j in range(n_joints):
                    p *= table[j, s[t - 1, j], s[t + 1, j], s[t, j]]
        for g in groups:
            for t in range(t_len):
                for e, (a, b) in enumerate(g.edges):
                    p *= g.tables[t, e, s[t, a], s[t, b]]
        for t in range(t_len):
            for j in range(n_joints):
                marg[t, j, s[t, j]] += p
    return marg / marg.sum(axis=-1, keepdims=True)


def random_problem(rng, t_len, n_joints, m, informative):
    """Random potentials; pairwise factors outside `informative` (t, group, edge) are flat."""
    data = rng.uniform(0.05, 1.0, (t_len, n_joints, m))
    temporal = [None] + [rng.uniform(0.05, 1.0, (n_joints, m, m, m)) for _ in range(t_len - 2)] + [None]
    groups = []
    for name, edges in (('collision', np.array([[0, 1]])), ('limb', np.array([[1, 2]]))):
        if edges.max() >= n_joints:
            continue
        tables = np.ones((t_len, len(edges), m, m))
        for t, g, e in informative:
            if g == name:
                tables[t, e] = rng.uniform(0.05, 1.0, (m, m))
        groups.append(PairwiseGroup(name, edges, tables))
    return data, temporal, groups


def test_bp_is_exact_on_a_tree():
    rng = np.random.default_rng(0)
    # T=3, J=3: ternary factors per joint plus collision (0,1) at t=1 and limb (1,2) at t=0
    # form a tree, where sum-product is exact.
    data, temporal, groups = random_problem(rng, 3, 3, 3, [(1, 'collision', 0), (0, 'limb', 0)])
    marg, _ = loopy_bp(data, temporal, groups, iterations=5)
    np.testing.assert_allclose(marg, brute_force(data, temporal, groups), atol=1e-10)


def test_bp_without_pairwise_factors_on_single_temporal_factor():
    rng = np.random.default_rng(1)
    data, temporal, _ = random_problem(rng, 3, 2, 4, [])
    marg, _ = loopy_bp(data, temporal, (), iterations=2)
    np.testing.assert_allclose(marg, brute_force(data, temporal, ()), atol=1e-10)


def test_bp_converges_on_a_loopy_graph_and_ranks_like_brute_force():
    rng = np.random.default_rng(2)
    # Overlapping ternary factors (T=4) and collisions at every frame: many loops.
    informative = [(t, 'collision', 0) for t in range(4)]
    data, temporal, groups = random_problem(rng, 4, 2, 2, informative)
    marg, msgs = loopy_bp(data, temporal, groups, iterations=30)
    again, _ = loopy_bp(data, temporal, groups, iterations=1, messages=msgs)
    assert np.abs(again - marg).max() < 1e-6  # a fixed point
    exact = brute_force(data, temporal, groups)
    assert np.abs(marg - exact).max() < 0.1
    confident = np.abs(exact[..., 0] - 0.5) > 0.1
    assert np.array_equal(marg.argmax(-1)[confident], exact.argmax(-1)[confident])


def test_scaling_a_factor_does_not_change_marginals():
    rng = np.random.default_rng(3)
    data, temporal, groups = random_problem(rng, 4, 3, 3, [(1, 'collision', 0), (2, 'limb', 0)])
    marg, _ = loopy_bp(data, temporal, groups)
    scaled = [None if x is None else 7.5 * x for x in temporal]
    groups2 = [PairwiseGroup(g.name, g.edges, g.tables * 0.01) for g in groups]
    marg2, _ = loopy_bp(data * 3.0, scaled, groups2)
    np.testing.assert_allclose(marg, marg2, atol=1e-12)


def test_long_window_does_not_underflow():
    rng = np.random.default_rng(4)
    t_len, n_joints, m = 200, 2, 8
    data = rng.uniform(1e-8, 1e-6, (t_len, n_joints, m))
    temporal = [None] + [rng.uniform(1e-9, 1e-7, (n_joints, m, m, m)) for _ in range(t_len - 2)] + [None]
    marg, _ = loopy_bp(data, temporal, (), iterations=5)
    assert np.all(np.isfinite(marg))
    np.testing.assert_allclose(marg.sum(-1), 1.0)


def test_sliding_messages_keep_overlap_and_reset_new_frames():
    msgs = Messages.uniform((5, 2, 3), [1])
    msgs.temporal[:] = np.arange(5)[None, :, None, None]
    msgs.pairwise[0][:] = np.arange(5)[:, None, None, None]
    slid = msgs.slid(drop=2, add=2)
    assert slid.temporal.shape == (3, 5, 2, 3)
    assert np.all(slid.temporal[:, :3] == np.arange(2, 5)[None, :, None, None])
    assert np.all(slid.temporal[:, 3:] == 0) and np.all(slid.pairwise[0][3:] == 0)


def test_temporal_entries_must_match_frames():
    with pytest.raises(ValueError):
        loopy_bp(np.ones((3, 1, 2)), [None, None], ())


def test_chain_grown_frame_by_frame_reaches_the_batch_fixed_point():
    """Appending frames one at a time (with a few iterations after each) and iterating to
    convergence lands on the same beliefs as a batch solve of the whole chain."""
    rng = np.random.default_rng(5)
    informative = [(t, 'collision', 0) for t in range(6)] + [(t, 'limb', 0) for t in range(0, 6, 2)]
    data, temporal, groups = random_problem(rng, 6, 3, 3, informative)
    batch, _ = loopy_bp(data, temporal, groups, iterations=60)
    chain = ChainBP.build(data[:1], [None], [PairwiseGroup(g.name, g.edges, g.tables[:1]) for g in groups])
    for t in range(1, 6):
        chain.append(data[t], temporal[t - 1], [g.tables[t] for g in groups])
        chain.run(2)
    assert not np.allclose(chain.marginals(), batch, atol=1e-6)  # two iterations a frame: not there yet
    chain.run(60)
    np.testing.assert_allclose(chain.marginals(), batch, atol=1e-6)


def test_dropped_frames_leave_with_their_factors():
    """After drop_front the kept frames' beliefs hold nothing of the factors that touched a
    dropped frame: iterated, the chain reaches the fixed point of the kept frames alone (it
    remembers its window only), where keeping their messages as a prior would not."""
    rng = np.random.default_rng(6)
    data, temporal, groups = random_problem(rng, 5, 2, 3, [])
    chain = ChainBP.build(data, temporal, groups)
    chain.run(5)
    chain.drop_front(2)
    assert len(chain) == 3 and chain.temporal[0] is None and chain.messages.temporal.shape[1] == 3
    assert not chain.messages.temporal[1:, 0].any()  # the factor centred at the new first frame is gone
    kept = [PairwiseGroup(g.name, g.edges, g.tables[2:]) for g in groups]
    plain, _ = loopy_bp(data[2:], [None, temporal[3], None], kept, iterations=60)
    chain.run(60)
    np.testing.assert_allclose(chain.marginals(), plain, atol=1e-6)


def _numpy_bp(data, temporal, groups, iterations):
    """The numpy formulation the kernels replace, each update a few whole-array numpy calls, with the
    paper's schedule in full: its backward sweep repeats the forward sweep's last update, which
    ChainBP.run leaves out, so the messages agree only if that repeat changes nothing."""
    def softmax(x):
        e = np.exp(x - x.max(axis=-1, keepdims=True))
        return e / e.sum(axis=-1, keepdims=True)

    def log_message(m):
        tiny = np.finfo(np.float64).tiny
        return np.log(np.maximum(m / np.maximum(m.sum(axis=-1, keepdims=True), tiny), tiny))

    total = np.log(np.maximum(data, np.finfo(np.float64).tiny))
    tm = np.zeros((3,) + data.shape)
    pms = [np.zeros((len(data), len(g.edges), 2, data.shape[-1])) for g in groups]
    inner = [t for t in range(1, len(data) - 1) if temporal[t] is not None]
    for _ in range(iterations):
        for t in inner + inner[::-1]:
            table = temporal[t]
            n_prev, n_cur, n_next = softmax(total[t - 1:t + 2] - tm[:, t]).astype(table.dtype)
            new = log_message(np.stack([np.einsum('jacb,jc,jb->ja', table, n_next, n_cur),
                                        np.einsum('jacb,ja,jc->jb', table, n_prev, n_next),
                                        np.einsum('jacb,ja,jb->jc', table, n_prev, n_cur)]))
            total[t - 1:t + 2] += new - tm[:, t]
            tm[:, t] = new
        for g, pm in zip(groups, pms):
            i, k = g.edges[:, 0], g.edges[:, 1]
            n_i = softmax(total[:, i] - pm[:, :, 0]).astype(g.tables.dtype)
            n_k = softmax(total[:, k] - pm[:, :, 1]).astype(g.tables.dtype)
            to_i = log_message(np.einsum('texy,tey->tex', g.tables, n_k))
            to_k = log_message(np.einsum('texy,tex->tey', g.tables, n_i))
            for e, (a, b) in enumerate(g.edges):
                total[:, a] += to_i[:, e] - pm[:, e, 0]
                total[:, b] += to_k[:, e] - pm[:, e, 1]
            pm[:, :, 0], pm[:, :, 1] = to_i, to_k
    return softmax(total), tm, pms


@pytest.mark.parametrize('t_len, n_joints, m', [(5, 3, 16), (4, 3, 1), (2, 3, 4), (4, 0, 5), (3, 2, 7)])
@pytest.mark.parametrize('dtype', [np.float32, np.float64])
def test_kernels_give_the_numpy_messages(t_len, n_joints, m, dtype):
    """The compiled updates against the numpy formulation, in the factors' float32 and in float64:
    the same messages up to the order of sums (one hypothesis, no inner frame, no joints too), with
    a joint in two edges of one group."""
    rng = np.random.default_rng(7)
    data = rng.uniform(0.05, 1.0, (t_len, n_joints, m))
    temporal = [None] + [rng.uniform(0.05, 1.0, (n_joints, m, m, m)).astype(dtype) for _ in range(t_len - 2)] + [None]
    edges = np.array([[0, 1], [1, 2], [2, 0]]) if n_joints == 3 else np.zeros((0, 2), dtype=int)
    groups = [PairwiseGroup('limb', edges, rng.uniform(0.05, 1.0, (t_len, len(edges), m, m)).astype(dtype))]
    marg, msgs = loopy_bp(data, temporal, groups, iterations=3)
    ref, tm, pms = _numpy_bp(data, temporal, groups, 3)
    tol = 1e-5 if dtype == np.float32 else 1e-12
    np.testing.assert_allclose(marg, ref, rtol=tol, atol=tol)
    np.testing.assert_allclose(msgs.temporal, tm, rtol=tol, atol=tol)
    np.testing.assert_allclose(msgs.pairwise[0], pms[0], rtol=tol, atol=tol)


@pytest.mark.parametrize('shape', [(4, 3, 16), (2, 0, 5), (1, 2, 1)])
def test_marginals_are_numpys_softmax_to_an_ulp_of_exp(shape):
    """numpy's arithmetic; only exp may round differently: numpy's vectorised exp on AVX-512 CPUs
    differs from libm's (the kernel's) by an ulp for about 5% of values, so a few ulps are allowed."""
    rng = np.random.default_rng(8)
    data = rng.uniform(1e-3, 1.0, shape)
    chain = ChainBP.build(data, [None] * shape[0])
    x = chain.total
    e = np.exp(x - x.max(axis=-1, keepdims=True))
    np.testing.assert_array_max_ulp(chain.marginals(), e / e.sum(axis=-1, keepdims=True), maxulp=4)
    np.testing.assert_array_max_ulp(chain.marginals_at(shape[0] - 1), (e / e.sum(axis=-1, keepdims=True))[-1],
                                    maxulp=4)
