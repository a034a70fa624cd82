"""Rendering, look-up, sampling and peaks of per-person heatmaps."""
from __future__ import annotations

import numpy as np
import pytest

from mvpose_ros.core.heatmap import MARGIN_SIGMAS, HeatmapStack, PersonHeatmap, render_heatmap, render_heatmaps

STRIDE, SIGMA = 4.0, 6.0


def _single(u: float, v: float, weight: float = 1.0, sigma: float = SIGMA) -> PersonHeatmap:
    return render_heatmap([np.array([[u, v, weight]])], STRIDE, sigma)


def test_each_map_covers_its_own_centres_plus_margin():
    centres = [np.array([[200.0, 200.0, 1.0]]), np.array([[120.0, 390.0, 0.5], [150.0, 330.0, 0.5]])]
    hm = render_heatmap(centres, STRIDE, SIGMA)
    margin = MARGIN_SIGMAS * SIGMA
    # on the image's lattice of STRIDE px, at most one cell before centre - margin
    low = np.array([[200.0, 200.0], [120.0, 330.0]]) - margin
    assert np.all(hm.origin <= low) and np.all(hm.origin > low - STRIDE)
    np.testing.assert_array_equal(hm.origin % STRIDE, 0.0)
    # each map's grid is just big enough for its own spread, plus one zero column and row
    for j, top in enumerate([(200.0, 200.0), (150.0, 390.0)]):
        h, w = hm.shape[j]
        last = hm.origin[j] + STRIDE * np.array([w - 2, h - 2])
        assert np.all(last >= np.array(top) + margin) and np.all(last < np.array(top) + margin + STRIDE)
        assert not hm.maps[j, h - 1, :w].any() and not hm.maps[j, :h, w - 1].any()
    assert (hm.shape[0] < hm.shape[1]).all()
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
    hm = render_heatmap(centres, STRIDE, SIGMA)
    at = hm.lookup(np.array([[[200.0, 200.0]], [[151.3, 333.7]]]))
    np.testing.assert_allclose(at[:, 0], [0.8, 0.6], rtol=0.1)
    # beyond a map's grid, NaN pixels, and the other joint's evidence read 0
    probe = np.array([[[50.0, 200.0], [200.0, 500.0], [np.nan, 200.0], [151.3, 333.7]],
                      [[50.0, 200.0], [200.0, 500.0], [np.nan, 200.0], [200.0, 200.0]]])
    np.testing.assert_array_equal(hm.lookup(probe), 0.0)
    # bilinear: exact at cell centres, each map on its own grid
    r, c = 3, 5
    cell = hm.origin + STRIDE * np.array([c, r])  # (2, 2)
    np.testing.assert_allclose(hm.lookup(cell[:, None])[:, 0], hm.maps[:, r, c], rtol=1e-6)


def test_max_combination_keeps_each_weight():
    rows = np.array([[202.0, 200.0, 0.5], [202.0, 200.0, 0.3], [202.0, 260.0, 1.7]])
    hm = render_heatmap([rows], STRIDE, SIGMA)
    # at cell centres the map is exactly the largest weighted Gaussian (weights clipped to 1)
    r, c = np.mgrid[:hm.maps.shape[1], :hm.maps.shape[2]]
    cells = hm.origin[0] + STRIDE * np.stack([c, r], axis=-1).reshape(-1, 2)
    d2 = ((cells[:, None] - rows[:, :2]) ** 2).sum(-1)
    inside = (np.abs(cells[:, None] - rows[:, :2]) <= MARGIN_SIGMAS * SIGMA).all(-1)
    expected = np.max(np.where(inside, np.minimum(rows[:, 2], 1) * np.exp(-d2 / (2 * SIGMA ** 2)), 0), axis=1)
    np.testing.assert_allclose(hm.lookup(cells[None])[0], expected, rtol=1e-5, atol=1e-7)
    assert 0.45 < hm.lookup(np.array([[[202.0, 200.0]]]))[0, 0] <= 0.5  # max, not sum
    assert 0.9 < hm.lookup(np.array([[[202.0, 260.0]]]))[0, 0] <= 1.0  # 2 px off the cell centre


def _reference_render(centres: np.ndarray, stride: float, sigma: float) -> list[tuple[list[np.ndarray], np.ndarray]]:
    """render_heatmaps written out map by map, cell by cell: per person (its maps, origin)."""
    margin = MARGIN_SIGMAS * sigma
    out = []
    for person in centres:
        rows = [c[np.isfinite(c).all(axis=1) & (c[:, 2] > 0)] for c in person]
        lo = np.array([r[:, :2].min(axis=0) - margin if len(r) else (np.inf, np.inf) for r in rows])
        hi = np.array([r[:, :2].max(axis=0) + margin if len(r) else (np.inf, np.inf) for r in rows])
        anchor = lo.min(axis=0)
        anchor[~np.isfinite(anchor)] = 0.0
        empty = np.array([len(r) == 0 for r in rows])
        lo[empty], hi[empty] = anchor, anchor
        lo = np.floor(lo / stride) * stride
        maps = []
        for j, r in enumerate(rows):
            w, h = np.ceil((hi[j] - lo[j]) / stride).astype(int) + 2 if len(r) else (1, 1)
            m = np.zeros((h, w), np.float32)
            for u, v, weight in r:
                for row in range(h):
                    for col in range(w):
                        du, dv = stride * col - (u - lo[j, 0]), stride * row - (v - lo[j, 1])
                        if abs(du) <= margin and abs(dv) <= margin:
                            g = min(weight, 1.0) * np.exp(-(du ** 2 + dv ** 2) / (2 * sigma ** 2))
                            m[row, col] = max(m[row, col], g)
            maps.append(m)
        out.append((maps, lo))
    return out


@pytest.mark.parametrize('seed', range(6))
def test_render_heatmaps_matches_the_cell_by_cell_formulation(seed):
    """Random people of 3 maps of up to 4 rows each: weights above 1, 0 and negative, NaN rows,
    empty maps and a person without any evidence."""
    rng = np.random.default_rng(seed)
    n_p, n_j, n = rng.integers(1, 4), 3, rng.integers(1, 5)
    centres = np.c_[rng.uniform(0, 120, (n_p * n_j * n, 2)), rng.uniform(-0.5, 1.5, n_p * n_j * n)]
    centres = centres.reshape(n_p, n_j, n, 3)
    centres[rng.random((n_p, n_j, n)) < 0.2, 0] = np.nan
    centres[rng.random((n_p, n_j)) < 0.3] = 0.0
    if seed == 0:
        centres[-1, ..., 2] = 0.0
    heatmaps = render_heatmaps(centres, STRIDE, SIGMA)
    assert len(heatmaps) == n_p
    for hm, (maps, origin) in zip(heatmaps, _reference_render(centres, STRIDE, SIGMA)):
        assert hm.cells.dtype == np.float32 and hm.stride == STRIDE
        np.testing.assert_array_equal(hm.shape, [m.shape for m in maps])
        np.testing.assert_array_equal(hm.origin, origin)
        np.testing.assert_allclose(hm.cells, np.concatenate([m.ravel() for m in maps]), rtol=1e-5, atol=1e-7)


def test_render_heatmaps_of_nobody():
    assert render_heatmaps(np.zeros((0, 16, 1, 3)), STRIDE, SIGMA) == []


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
                         np.array([[200.0, 200.0, 0.0]])], STRIDE, SIGMA)
    xy = hm.sample(np.random.default_rng(1), 100)
    assert np.all(np.isnan(xy[0])) and np.all(np.isnan(xy[2]))
    assert np.all(np.isfinite(xy[1]))
    peak = hm.peak()
    assert peak[0, 2] == 0 and np.all(np.isnan(peak[0, :2]))


def test_sample_counts_follow_weights():
    weights = np.array([0.9, 0.3])
    centres = np.array([[150.0, 100.0], [250.0, 350.0]])
    hm = render_heatmap([np.c_[centres, weights]] * 3, STRIDE, SIGMA)
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


def _random_stack(rng: np.random.Generator, dtype=np.float32) -> HeatmapStack:
    """Heatmaps of 7 joints on grids of different sizes (one of a single cell), mostly zeros,
    some maps empty, others with ties at their maximum."""
    heatmaps = []
    for h, w in [(5, 4), (1, 1), (3, 7), (6, 6)]:
        maps = np.where(rng.random((7, h, w)) < 0.3, rng.random((7, h, w)), 0.0).astype(dtype)
        maps[1] = 0.0
        maps[2, 0, 0] = maps[2, -1, -1] = 2.0
        heatmaps.append(PersonHeatmap(maps, rng.uniform(-50, 500, (7, 2)), float(rng.uniform(2, 8))))
    return HeatmapStack.of(heatmaps)


def _numpy_sample_at(stack: HeatmapStack, maps, u, jitter):
    """HeatmapStack.sample_at as numpy on whole arrays (the formulation the kernel replaced)."""
    nz = np.flatnonzero(stack.values)
    cum = np.concatenate([[0.0], np.cumsum(stack.values[nz], dtype=np.float64)])
    start = stack.start.ravel()
    size = (stack.shape[..., 0] * stack.shape[..., 1]).ravel()
    first = np.searchsorted(nz, start)[maps]
    end = np.searchsorted(nz, start + size)[maps]
    before = cum[first]
    idx = np.searchsorted(cum, before + u * (cum[end] - before), side='right') - 1
    idx = np.minimum(np.clip(idx, first, np.maximum(end - 1, first)), max(len(nz) - 1, 0))
    cell = (nz[idx] if len(nz) else np.zeros_like(idx)) - start[maps]
    heatmap = maps // stack.start.shape[1]
    row, col = np.divmod(cell, stack.shape.reshape(-1, 2)[maps, 1])
    origin = stack.origin.reshape(-1, 2)[maps]
    uv = np.stack([origin[:, 0] + stack.stride[heatmap] * (col + (jitter[:, 0] - 0.5)),
                   origin[:, 1] + stack.stride[heatmap] * (row + (jitter[:, 1] - 0.5))], axis=-1)
    uv[end == first] = np.nan
    return uv


def _numpy_lookup(stack: HeatmapStack, uv):
    """HeatmapStack.lookup as numpy on whole arrays (the formulation the kernel replaced)."""
    inv = 1.0 / stack.stride[:, None, None]
    c = (uv[..., 0] - stack.origin[:, :, None, 0]) * inv
    r = (uv[..., 1] - stack.origin[:, :, None, 1]) * inv
    h, w = stack.shape[..., 0, None], stack.shape[..., 1, None]
    inside = (c >= 0) & (c <= w - 1) & (r >= 0) & (r <= h - 1)
    c, r = np.where(inside, c, 0.0), np.where(inside, r, 0.0)
    c0 = np.minimum(c.astype(np.intp), np.maximum(w - 2, 0))
    r0 = np.minimum(r.astype(np.intp), np.maximum(h - 2, 0))
    fc, fr = c - c0, r - r0
    base = stack.start[..., None] + r0 * w + c0
    right = np.minimum(c0 + 1, w - 1) - c0
    down = (np.minimum(r0 + 1, h - 1) - r0) * w
    v = stack.values
    top = v[base] * (1 - fc) + v[base + right] * fc
    bottom = v[base + down] * (1 - fc) + v[base + down + right] * fc
    return np.where(inside, top * (1 - fr) + bottom * fr, 0.0)


@pytest.mark.parametrize('dtype, trim', [(np.float32, False), (np.float64, False), (np.float32, True)])
def test_stack_kernels_are_numpys_arithmetic(dtype, trim):
    rng = np.random.default_rng(3)
    stack = _random_stack(rng, dtype)
    stack = stack.trimmed() if trim else stack  # maps of a heatmap on grids of their own sizes
    n_maps = stack.start.size
    maps = rng.integers(0, n_maps, 500)
    u, jitter = rng.random(500), rng.random((500, 2))
    np.testing.assert_array_equal(stack.sample_at(maps, u, jitter), _numpy_sample_at(stack, maps, u, jitter))
    # peaks: the first maximal cell's centre; empty maps (NaN, NaN, 0)
    peak = stack.peak()
    for i, (start, (h, w), origin, stride) in enumerate(zip(stack.start.ravel(), stack.shape.reshape(-1, 2),
                                                            stack.origin.reshape(-1, 2), np.repeat(stack.stride, 7))):
        cells = stack.values[start:start + h * w]
        best = int(np.argmax(cells))
        expected = ([*(origin + stride * np.array([best % w, best // w])), cells[best]] if cells[best] > 0
                    else [np.nan, np.nan, 0.0])
        np.testing.assert_array_equal(peak.reshape(-1, 3)[i], expected)
    # look-ups at cell centres, between them, on the grid's edges, outside and NaN
    uv = stack.origin[:, :, None] + stack.stride[:, None, None, None] * rng.uniform(-1, 7, (4, 7, 30, 2))
    uv[:, :, 0] = stack.origin  # cell [0, 0]
    uv[:, :, 1, 0] = np.nan
    np.testing.assert_array_equal(stack.lookup(uv), _numpy_lookup(stack, uv))


def test_trimmed_maps_look_up_peak_and_draw_as_the_whole_maps():
    rng = np.random.default_rng(4)
    stack = _random_stack(rng)
    cut = stack.trimmed()
    assert len(cut.values) < len(stack.values)
    assert (cut.shape <= stack.shape).all() and (cut.shape >= 1).all()
    assert (cut.shape[:, 1] == 1).all()  # the empty map: one zero cell
    np.testing.assert_allclose(cut.peak(), stack.peak(), rtol=1e-12)  # the origins moved by whole cells
    uv = stack.origin[:, :, None] + stack.stride[:, None, None, None] * rng.uniform(-1, 7, (4, 7, 300, 2))
    np.testing.assert_allclose(cut.lookup(uv), stack.lookup(uv), rtol=1e-6, atol=1e-12)
    maps = rng.integers(0, stack.start.size, 500)
    u, jitter = rng.random(500), rng.random((500, 2))
    np.testing.assert_allclose(cut.sample_at(maps, u, jitter), stack.sample_at(maps, u, jitter), rtol=1e-12)
    again = cut.trimmed()  # a map cut once keeps its zero ring
    np.testing.assert_array_equal(again.values, cut.values)
    np.testing.assert_array_equal(again.origin, cut.origin)


def test_a_person_heatmap_trimmed_is_its_stacks_trimmed():
    """PersonHeatmap.trimmed, as the ONNX backend cuts a crop's maps: the stack's cut of it, so it
    looks up as the whole maps."""
    maps = np.zeros((3, 20, 30), dtype=np.float32)
    maps[0, 4:7, 10:14] = 0.5
    maps[2, 15, 2] = 1.0
    whole = PersonHeatmap(maps, np.array([100.0, 40.0]), 4.0)
    cut = whole.trimmed()
    stack = HeatmapStack.of([whole]).trimmed()
    np.testing.assert_array_equal(cut.cells, stack.values)
    np.testing.assert_array_equal(cut.shape, stack.shape[0])
    np.testing.assert_array_equal(cut.origin, stack.origin[0])
    assert cut.shape.tolist() == [[5, 6], [1, 1], [3, 3]] and cut.stride == 4.0
    uv = np.random.default_rng(5).uniform([90.0, 30.0], [230.0, 130.0], (3, 200, 2))
    np.testing.assert_allclose(cut.lookup(uv), whole.lookup(uv), rtol=1e-6, atol=1e-12)


def test_an_empty_stack():
    stack = HeatmapStack.of([])
    assert stack.peak().shape == (0, 0, 3)
    assert stack.lookup(np.zeros((0, 0, 5, 2))).shape == (0, 0, 5)
    assert stack.sample_at(np.zeros(0, int), np.zeros(0), np.zeros((0, 2))).shape == (0, 2)
