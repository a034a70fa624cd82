"""Rendering, look-up, sampling and peaks of per-person heatmaps."""
from __future__ import annotations

import numpy as np
import pytest

from mvpose_ros.core.heatmap import MARGIN_SIGMAS, PersonHeatmap, render_heatmap

BOX = np.array([100.0, 50.0, 300.0, 400.0])
STRIDE, SIGMA = 4.0, 6.0


def _single(u: float, v: float, weight: float = 1.0, sigma: float = SIGMA) -> PersonHeatmap:
    return render_heatmap([np.array([[u, v, weight]])], BOX, STRIDE, sigma)


def test_grid_covers_box_plus_margin():
    hm = _single(200, 200)
    margin = MARGIN_SIGMAS * SIGMA
    np.testing.assert_allclose(hm.origin, BOX[:2] - margin)
    _, h, w = hm.maps.shape
    last = hm.origin + STRIDE * np.array([w - 1, h - 1])
    assert np.all(last >= BOX[2:] + margin) and np.all(last < BOX[2:] + margin + STRIDE)
    assert hm.maps.dtype == np.float32
    assert hm.maps.min() >= 0 and hm.maps.max() <= 1


@pytest.mark.parametrize('u, v', [(200.0, 200.0), (151.3, 333.7), (101.0, 52.5)])
def test_sharp_peak_is_found(u, v):
    hm = _single(u, v, 0.7, sigma=1.5)
    peak = hm.peak()
    assert peak.shape == (1, 3)
    assert np.all(np.abs(peak[0, :2] - (u, v)) <= STRIDE / 2)
    assert 0.2 < peak[0, 2] <= 0.7  # the peak cell may be up to half a cell off the centre


def test_lookup_at_centre_and_outside():
    centres = [np.array([[200.0, 200.0, 0.8]]), np.array([[151.3, 333.7, 0.6]])]
    hm = render_heatmap(centres, BOX, STRIDE, SIGMA)
    at = hm.lookup(np.array([[[200.0, 200.0]], [[151.3, 333.7]]]))
    np.testing.assert_allclose(at[:, 0], [0.8, 0.6], rtol=0.1)
    # beyond the grid (box + margin) and NaN pixels read 0; far inside the box too
    probe = np.array([[[50.0, 200.0], [200.0, 500.0], [np.nan, 200.0], [280.0, 60.0]]] * 2)
    np.testing.assert_array_equal(hm.lookup(probe), 0.0)
    # bilinear: exact at cell centres
    r, c = 40, 20
    cell = hm.origin + STRIDE * np.array([c, r])
    np.testing.assert_allclose(hm.lookup(np.broadcast_to(cell, (2, 1, 2)))[:, 0],
                               hm.maps[:, r, c], rtol=1e-6)


def test_max_combination_keeps_each_weight():
    # centres on cell centres (origin is BOX[:2] - 18 px), where the map is exact
    hm = render_heatmap([np.array([[202.0, 200.0, 0.5], [202.0, 200.0, 0.3],
                                   [202.0, 260.0, 1.7]])], BOX, STRIDE, SIGMA)
    got = hm.lookup(np.array([[[202.0, 200.0], [202.0, 260.0]]]))[0]
    np.testing.assert_allclose(got, [0.5, 1.0], rtol=1e-4)  # max, not sum; weights clipped to 1


def test_sample_single_gaussian_moments():
    hm = _single(203.3, 181.7)
    xy = hm.sample(np.random.default_rng(0), 20000)
    assert xy.shape == (1, 20000, 2)
    np.testing.assert_allclose(xy[0].mean(axis=0), [203.3, 181.7], atol=0.5)
    # cells of STRIDE px with uniform jitter add STRIDE**2 / 12 to the variance
    std = xy[0].std(axis=0)
    np.testing.assert_allclose(std, np.sqrt(SIGMA ** 2 + STRIDE ** 2 / 12), rtol=0.05)
    assert np.all(std > 0.95 * SIGMA)


def test_sample_empty_joints_are_nan():
    hm = render_heatmap([np.zeros((0, 3)), np.array([[200.0, 200.0, 1.0]]),
                         np.array([[200.0, 200.0, 0.0]])], BOX, STRIDE, SIGMA)
    xy = hm.sample(np.random.default_rng(1), 100)
    assert np.all(np.isnan(xy[0])) and np.all(np.isnan(xy[2]))
    assert np.all(np.isfinite(xy[1]))
    peak = hm.peak()
    assert peak[0, 2] == 0 and np.all(np.isnan(peak[0, :2]))


def test_sample_counts_follow_weights():
    weights = np.array([0.9, 0.3])
    centres = np.array([[150.0, 100.0], [250.0, 350.0]])
    hm = render_heatmap([np.c_[centres, weights]] * 3, BOX, STRIDE, SIGMA)
    n = 20000
    xy = hm.sample(np.random.default_rng(2), n)
    assert xy.shape == (3, n, 2)
    near_first = np.linalg.norm(xy - centres[0], axis=-1) < np.linalg.norm(xy - centres[1],
                                                                           axis=-1)
    counts = near_first.sum(axis=1)
    p = weights[0] / weights.sum()  # same-shape Gaussians: mass proportional to the weight
    sd = np.sqrt(n * p * (1 - p))
    assert np.all(np.abs(counts - n * p) < 4 * sd), counts
    assert len(np.unique(counts)) == 3  # joints draw independently
