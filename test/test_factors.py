"""CRF factor tables: temporal (constant velocity), left/right collision, limb length."""
from __future__ import annotations

import numpy as np
import pytest

from mvpose_ros.core.geometry.camera import Camera
from mvpose_ros.core.heatmap import HeatmapStack, render_heatmaps
from mvpose_ros.core.inference.factors import (TEMPORAL_FORMS, FactorConfig, collision_table, data_terms, limb_table,
                                               pair_distances, temporal_table)


def _reference_temporal(prev, cur, nxt, config) -> np.ndarray:
    """Direct (J, M, M, M) [j, a, c, b] table, normalised per joint."""
    mid = 0.5 * (prev[:, :, None, None] + nxt[:, None, :, None])  # (J, a, c, 1, 3)
    d = np.linalg.norm(cur[:, None, None, :] - mid, axis=-1)  # (J, a, c, b)
    if config.temporal_form == 'laplace':
        table = np.exp(-d / config.temporal_scale)
    else:
        table = np.exp(-d ** 2 / (2 * config.temporal_scale ** 2))
    return table / table.sum(axis=(1, 2, 3), keepdims=True)


@pytest.mark.parametrize('form', TEMPORAL_FORMS)
def test_temporal_peaks_at_constant_velocity(form):
    config = FactorConfig(temporal_form=form)
    rng = np.random.default_rng(0)
    prev, nxt = rng.normal(scale=0.3, size=(2, 3, 5, 3))
    cur = rng.normal(scale=0.3, size=(3, 6, 3))
    cur[:, 4] = 0.5 * (prev[:, 1] + nxt[:, 3])  # b = 4 is the midpoint of a = 1, c = 3
    table = temporal_table(prev, cur, nxt, config)
    assert table.shape == (3, 5, 5, 6) and table.dtype == np.float32
    np.testing.assert_allclose(table.sum(axis=(1, 2, 3)), 1.0, rtol=1e-5)
    for j in range(3):
        assert np.unravel_index(np.argmax(table[j]), table[j].shape) == (1, 3, 4)
        assert np.argmax(table[j, 1, 3]) == 4
    np.testing.assert_allclose(table, _reference_temporal(prev, cur, nxt, config),
                               rtol=1e-4, atol=1e-9)


def test_temporal_entry_by_hand():
    """[j, a, c, b]: prev a=1 at (1, 0, 0), next c=0 at (0, 0, 0), so the midpoint is
    (0.5, 0, 0); cur b=1 at (0.5, 0, 0.3) is 0.3 m from it."""
    prev = np.array([[[0.0, 0.0, 0.0], [1.0, 0.0, 0.0]]])
    nxt = np.array([[[0.0, 0.0, 0.0], [0.0, 2.0, 0.0]]])
    cur = np.array([[[0.0, 0.0, 0.0], [0.5, 0.0, 0.3]]])
    laplace = temporal_table(prev, cur, nxt, FactorConfig(temporal_form='laplace',
                                                          temporal_scale=0.5))
    gauss = temporal_table(prev, cur, nxt, FactorConfig(temporal_form='gauss', temporal_scale=0.5))
    # [0, 0, 0, 0] is an exact constant-velocity triple (all at the origin): kernel value 1
    assert laplace[0, 1, 0, 1] / laplace[0, 0, 0, 0] == pytest.approx(np.exp(-0.3 / 0.5), rel=1e-5)
    assert gauss[0, 1, 0, 1] / gauss[0, 0, 0, 0] == pytest.approx(np.exp(-0.09 / 0.5), rel=1e-5)
    # swapping a and c changes the midpoint to (0, 1, 0): a different entry
    d = np.linalg.norm([0.5, -1.0, 0.3])
    assert laplace[0, 0, 1, 1] / laplace[0, 0, 0, 0] == pytest.approx(np.exp(-d / 0.5), rel=1e-5)


def test_temporal_scale_sharpens():
    rng = np.random.default_rng(1)
    prev, cur, nxt = rng.normal(scale=0.2, size=(3, 2, 4, 3))
    cur[:, 0] = 0.5 * (prev[:, 0] + nxt[:, 0])
    wide = temporal_table(prev, cur, nxt, FactorConfig(temporal_scale=0.5))
    narrow = temporal_table(prev, cur, nxt, FactorConfig(temporal_scale=0.02))
    assert np.all(narrow[:, 0, 0, 0] > wide[:, 0, 0, 0])


def _evenly_spaced_temporal(prev, cur, nxt, config) -> np.ndarray:
    """The evenly spaced temporal table as numpy computed it before the factor knew about time steps
    (midpoint, temporal_scale), operation for operation."""
    mid = 0.5 * (prev[:, :, None, :] + nxt[:, None, :, :])
    j, ma, mc = mid.shape[:3]
    mid = mid.reshape(j, ma * mc, 3)
    sq = (np.einsum('jkd,jkd->jk', mid, mid)[:, :, None] + np.einsum('jbd,jbd->jb', cur, cur)[:, None, :]
          - 2.0 * mid @ cur.transpose(0, 2, 1))
    sq = np.maximum(sq, 0.0, out=sq).astype(np.float32)
    if config.temporal_form == 'laplace':
        table = np.exp(np.sqrt(sq) * np.float32(-1.0 / config.temporal_scale))
    else:
        table = np.exp(sq * np.float32(-0.5 / config.temporal_scale ** 2))
    table = table.reshape(j, ma, mc, cur.shape[1])
    total = table.sum(axis=(1, 2, 3), keepdims=True)
    return (table / np.maximum(total, np.finfo(np.float32).tiny)).astype(np.float32)


@pytest.mark.parametrize('form', TEMPORAL_FORMS)
def test_unit_steps_reproduce_the_evenly_spaced_table_exactly(form):
    config = FactorConfig(temporal_form=form)
    prev, cur, nxt = np.random.default_rng(5).normal(scale=0.3, size=(3, 4, 7, 3))
    table = temporal_table(prev, cur, nxt, config)
    np.testing.assert_array_equal(temporal_table(prev, cur, nxt, config, (1.0, 1.0)), table)
    # numpy's table to float32 rounding (the kernel takes the squared distance directly, not by
    # its expansion, and sums in float64); entries below 1e-30 only where numpy's are
    old = _evenly_spaced_temporal(prev, cur, nxt, config)
    np.testing.assert_allclose(table, old, rtol=1e-6, atol=1e-30)
    # equal steps of two periods: the same midpoint, the kernel twice as wide
    wide = FactorConfig(temporal_form=form, temporal_scale=2 * config.temporal_scale)
    np.testing.assert_array_equal(temporal_table(prev, cur, nxt, config, (2.0, 2.0)),
                                  temporal_table(prev, cur, nxt, wide))
    np.testing.assert_allclose(temporal_table(prev, cur, nxt, wide), _evenly_spaced_temporal(prev, cur, nxt, wide),
                               rtol=1e-6, atol=1e-30)


@pytest.mark.parametrize('shape', [(0, 5), (3, 1), (2, 16)])
def test_temporal_table_of_no_joints_one_hypothesis_and_float32_points(shape):
    """Edge cases against numpy: no joints, a single hypothesis (the table is 1), float32 input."""
    j, m = shape
    prev, cur, nxt = np.random.default_rng(7).normal(scale=0.3, size=(3, j, m, 3)).astype(np.float32)
    config = FactorConfig()
    table = temporal_table(prev, cur, nxt, config)
    assert table.shape == (j, m, m, m) and table.dtype == np.float32 and table.flags.c_contiguous
    np.testing.assert_allclose(table, _evenly_spaced_temporal(*(h.astype(np.float64) for h in (prev, cur, nxt)),
                                                              config), rtol=1e-6, atol=1e-30)


@pytest.mark.parametrize('form', TEMPORAL_FORMS)
def test_a_doubled_step_is_the_constant_velocity_prediction_over_two_steps(form):
    """Frame t+1 dropped: t-1, t, t+2 with steps (1, 2). The factor is largest (kernel 1) where
    y^{t+2} = y^t + 2 (y^t - y^{t-1}), and it is the Laplace / Gauss kernel of the distance to
    that prediction with the scale of the mean step (1.5 periods)."""
    config = FactorConfig(temporal_form=form)
    rng = np.random.default_rng(6)
    prev = rng.normal(scale=0.3, size=(2, 5, 3))
    cur = rng.normal(scale=0.3, size=(2, 4, 3))
    nxt = rng.normal(scale=0.3, size=(2, 6, 3))
    nxt[:, 2] = cur[:, 3] + 2 * (cur[:, 3] - prev[:, 1])  # a = 1, b = 3, c = 2 move at constant velocity
    table = temporal_table(prev, cur, nxt, config, (1.0, 2.0))
    for j in range(2):
        assert np.unravel_index(np.argmax(table[j]), table[j].shape) == (1, 2, 3)
    mid = prev[:, :, None, None] + (nxt[:, None, :, None] - prev[:, :, None, None]) / 3  # (J, a, c, 1, 3)
    d = np.linalg.norm(cur[:, None, None, :] - mid, axis=-1)
    scale = 1.5 * config.temporal_scale
    kernel = np.exp(-d / scale) if form == 'laplace' else np.exp(-d ** 2 / (2 * scale ** 2))
    np.testing.assert_allclose(table, kernel / kernel.sum(axis=(1, 2, 3), keepdims=True), rtol=1e-4, atol=1e-9)
    # blind to the times, the midpoint would be predicted instead: a different, wrong peak
    assert not np.array_equal(temporal_table(prev, cur, nxt, config), table)
    with pytest.raises(ValueError, match='positive'):
        temporal_table(prev, cur, nxt, config, (0.0, 1.0))


def test_pair_distances():
    a = np.array([[[0.0, 0.0, 0.0], [1.0, 0.0, 0.0]]])  # (1, 2, 3)
    b = np.array([[[0.0, 3.0, 4.0], [1.0, 0.0, 0.0], [0.0, 0.0, 0.0]]])  # (1, 3, 3)
    d = pair_distances(a, b)
    assert d.shape == (1, 2, 3)
    np.testing.assert_allclose(d[0], [[5.0, 1.0, 0.0], [np.sqrt(26.0), 0.0, 1.0]])


def test_collision_repels_coinciding_pairs():
    config = FactorConfig()
    right = np.array([[[0.0, 0.0, 1.0], [0.5, 0.0, 1.0], [0.0, 0.5, 1.0]]] * 2)  # (2, 3, 3)
    left = np.array([[[0.0, 0.0, 1.0], [1.0, 0.0, 1.0]]] * 2)  # (2, 2, 3)
    table = collision_table(right, left, config)
    assert table.shape == (2, 3, 2) and table.dtype == np.float32  # [right state, left state]
    np.testing.assert_allclose(table.sum(axis=(-2, -1)), 1.0, rtol=1e-5)
    rel = table[0] / table[0].max()
    assert rel[0, 0] < 0.2  # right 0 and left 0 coincide
    assert rel[0, 1] > 0.99  # 1 m apart
    # the sigmoid of the distance, up to the normalisation
    d = pair_distances(right, left)[0]
    raw = 1.0 / (1.0 + np.exp((config.collision_centre - d) / config.collision_width))
    np.testing.assert_allclose(table[0], raw / raw.sum(), rtol=1e-5)
    assert table[0, 0, 0] < table[0, 1, 0] < table[0, 0, 1]


def test_limb_table_is_flat_over_plausible_lengths_and_falls_off_beyond():
    config = FactorConfig(limb_sigma=0.05, limb_range=(0.7, 1.3))
    lengths = np.array([0.30, 0.44])
    start = np.zeros((2, 1, 3))  # one state for each bone's first joint, at the origin
    end = np.zeros((2, 31, 3))
    end[..., 0] = np.linspace(0.0, 0.6, 31)  # 2 cm steps along x
    d = pair_distances(start, end)  # (2, 1, 31)
    table = limb_table(d, lengths, config)
    assert table.shape == (2, 1, 31) and table.dtype == np.float32
    np.testing.assert_allclose(table.sum(axis=(-2, -1)), 1.0, rtol=1e-5)
    # 0.30 m: flat from 0.21 to 0.39 m (steps 11-19), a Gaussian of the excess outside
    row = table[0, 0]
    np.testing.assert_allclose(row[11:20], row[15], rtol=1e-6)
    assert row[20] / row[15] == pytest.approx(np.exp(-0.5 * (0.01 / 0.05) ** 2), rel=1e-4)  # 0.40 m
    assert row[27] / row[15] == pytest.approx(np.exp(-0.5 * (0.15 / 0.05) ** 2), rel=1e-3)  # 0.54 m
    assert row[5] / row[15] == pytest.approx(np.exp(-0.5 * (0.11 / 0.05) ** 2), rel=1e-3)  # 0.10 m
    # batched over leading axes (e.g. people)
    batched = limb_table(np.stack([d, d]), lengths, config)
    np.testing.assert_allclose(batched[1], table)


@pytest.mark.parametrize('kwargs', [
    {'temporal_form': 'cauchy'},
    {'temporal_scale': 0.0},
    {'temporal_scale': -0.08},
    {'collision_width': 0.0},
    {'limb_sigma': -0.05},
    {'limb_sigma': float('nan')},
    {'limb_range': (1.3, 0.7)},
    {'limb_range': (-0.1, 1.0)},
])
def test_factor_config_rejects_bad_values(kwargs):
    with pytest.raises(ValueError):
        FactorConfig(**kwargs)


def test_factor_config_defaults():
    config = FactorConfig()
    assert config.temporal_form == 'laplace' and config.temporal_scale == pytest.approx(0.08)
    assert set(TEMPORAL_FORMS) == {'laplace', 'gauss'}


def _numpy_data_terms(hypotheses, people, stack) -> list[np.ndarray]:
    """data_terms as numpy on whole arrays (the formulation the kernels replaced)."""
    cameras = [cam for views in people for cam, _ in views]
    counts = np.array([len(v) for v in people])
    owner = np.repeat(np.arange(len(people)), counts)
    points = np.stack(hypotheses)
    uv = np.empty(stack.start.shape + (points.shape[2], 2))
    for v, cam in enumerate(cameras):
        uv[v] = cam.project(points[owner[v]])
    values = stack.lookup(uv)
    total = np.zeros((len(people),) + values.shape[1:])
    seen = counts > 0
    total[seen] = np.add.reduceat(values, np.concatenate([[0], np.cumsum(counts)[:-1]])[seen], axis=0)
    total /= np.maximum(counts, 1)[:, None, None]
    rows = total.sum(axis=-1, keepdims=True)
    return list(np.where(rows > 0, total / np.where(rows > 0, rows, 1.0), 1.0 / total.shape[-1]))


@pytest.mark.parametrize('m', [5, 64, 300])
def test_data_terms_are_numpys_arithmetic(m):
    rng = np.random.default_rng(4)
    K = np.array([[500.0, 0.0, 320.0], [0.0, 500.0, 240.0], [0.0, 0.0, 1.0]])
    # cameras on a circle 4 m around the origin, looking at it; one with distortion
    cameras = []
    for i, a in enumerate(np.linspace(0, 2 * np.pi, 4, endpoint=False)):
        z = -np.array([np.cos(a), np.sin(a), 0.0])
        x = np.cross(z, [0.0, 0.0, 1.0])
        R = np.stack([x, np.cross(z, x), z])
        dist = [0.1, -0.05, 0.001, 0.0, 0.0] if i == 3 else np.zeros(5)
        cameras.append(Camera(f'c{i}', K, R, -R @ (-4 * z), dist, 640, 480))
    # people seen by 3, 1, 9 (cameras again: above 8 views numpy sums them pairwise) and 0 views
    which = [[0, 1, 3], [2], [0, 1, 2, 3, 0, 1, 2, 3, 1], []]
    hypotheses = [rng.normal(0, 0.3, (4, m, 3)) for _ in which]
    hypotheses[0][1, :5] = cameras[0].centre  # at a camera: NaN pixels
    centres = np.stack([cameras[c].project(h.reshape(-1, 3)).reshape(4, m, 2)[:, :3]
                        for h, views in zip(hypotheses, which) for c in views])
    centres = np.concatenate([centres, rng.uniform(0.3, 1.0, centres.shape[:3] + (1,))], axis=-1)
    centres[:, 2] = 0.0  # joint 2 without evidence: uniform
    maps = render_heatmaps(centres, 8.0, 12.0)
    people = []
    for views in which:
        people.append([(cameras[c], maps.pop(0)) for c in views])
    stack = HeatmapStack.of([hm for views in people for _, hm in views])
    out = data_terms(hypotheses, people, stack)
    expected = _numpy_data_terms(hypotheses, people, stack)
    for got, want in zip(out, expected):
        np.testing.assert_array_equal(got, want)
    np.testing.assert_allclose(out[2].sum(axis=-1), 1.0)
    np.testing.assert_array_equal(out[3], 1.0 / m)
    assert np.ptp(out[0][0]) > 0 and np.ptp(out[2][1]) > 0  # evidence somewhere
    assert data_terms([], [], HeatmapStack.of([])) == []


@pytest.mark.parametrize('form', TEMPORAL_FORMS)
def test_temporal_table_far_and_coinciding_hypotheses(form):
    """Entries whose kernel underflows float32 (a hypothesis 100 m off) are 0, as numpy's; points at
    the midpoint give the largest entry."""
    rng = np.random.default_rng(8)
    prev, cur, nxt = rng.normal(scale=0.05, size=(3, 2, 6, 3))
    cur[:, 0] = 0.5 * (prev[:, 0] + nxt[:, 0])
    cur[:, 5] += 100.0
    config = FactorConfig(temporal_form=form)
    table = temporal_table(prev, cur, nxt, config)
    assert np.all(table[..., 5] == 0) and np.all(table[..., :5] > 0)
    np.testing.assert_allclose(table, _evenly_spaced_temporal(prev, cur, nxt, config), rtol=1e-6, atol=1e-30)
    assert np.all(table[:, 0, 0, 0] == table.max(axis=(1, 2, 3)))


def _numpy_pair_tables(right, left, d_limb, length, config):
    """collision_table and limb_table as numpy computed them (the same operations, whole arrays)."""
    def normalised(table):
        total = table.sum(axis=(-2, -1), keepdims=True)
        return (table / np.maximum(total, np.finfo(np.float32).tiny)).astype(np.float32)

    d = np.linalg.norm(right[..., :, None, :] - left[..., None, :, :], axis=-1)
    collision = normalised(1.0 / (1.0 + np.exp((config.collision_centre - d) / config.collision_width)))
    low, high = config.limb_range
    excess = np.maximum(np.maximum(d_limb - high * length[:, None, None], low * length[:, None, None] - d_limb), 0.0)
    return d, collision, normalised(np.exp(-0.5 * (excess / config.limb_sigma) ** 2))


@pytest.mark.parametrize('people, edges, m', [(3, 4, 16), (1, 2, 1), (0, 3, 8), (2, 0, 8), (2, 5, 9)])
def test_pair_tables_are_numpys_to_the_bit(people, edges, m):
    """pair_distances, collision_table and limb_table against numpy, batched over people (none, no
    edges, one hypothesis too)."""
    rng = np.random.default_rng(9)
    right, left = rng.normal(scale=0.4, size=(2, people, edges, m, 3))
    length = rng.uniform(0.1, 0.5, edges)
    config = FactorConfig()
    d = pair_distances(right, left)
    d_ref, collision, limb = _numpy_pair_tables(right, left, d, length, config)
    assert d.shape == (people, edges, m, m)
    np.testing.assert_array_equal(d, d_ref)
    for table, ref in ((collision_table(right, left, config), collision), (limb_table(d, length, config), limb)):
        assert table.dtype == np.float32 and table.flags.c_contiguous
        np.testing.assert_array_equal(table, ref)
