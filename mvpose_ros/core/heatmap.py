"""Per-person joint heatmaps H_{c,i}: per joint a grid of cells over the image region holding
that joint's evidence, with bilinear look-up (the CRF's data term) and sampling as a pmf (the
3D hypotheses)."""
from __future__ import annotations

from dataclasses import dataclass
from typing import Sequence

import numpy as np

from mvpose_ros.core.compiled import kernel

MARGIN_SIGMAS = 3.0  # a rendered Gaussian is cut this many sigmas from its centre


@dataclass
class PersonHeatmap:
    """J heatmaps of h x w cells each: cell [r, c] of map j is centred at pixel
    origin[j] + stride * (c, r). Each map has its own origin, so that it covers only the region
    of its joint (a person-sized grid per joint is ~99% zeros, and every step downstream, the
    wire included, pays for its size)."""

    maps: np.ndarray  # (J, h, w) float32 in [0, 1]
    origin: np.ndarray  # (J, 2) pixel (u, v) of the centre of cell [0, 0] of each map; (2,) = shared
    stride: float  # pixels per cell

    def __post_init__(self) -> None:
        self.origin = np.broadcast_to(np.asarray(self.origin, dtype=np.float64), (len(self.maps), 2))

    def lookup(self, uv: np.ndarray) -> np.ndarray:
        """Bilinear value (J, N) of joint j's map at pixel uv[j, n] (uv: (J, N, 2)); 0 outside
        the grid of cell centres and for NaN pixels."""
        return HeatmapStack.of([self]).lookup(np.asarray(uv)[None])[0]

    def sample(self, rng: np.random.Generator, n: int) -> np.ndarray:
        """Draw n pixels per joint (J, n, 2) with each map as a pmf over its cells (probability
        proportional to the value), jittered uniformly within the cell; NaN rows for empty maps."""
        n_j = len(self.maps)
        u = rng.random((1, n_j, n))
        return HeatmapStack.of([self]).sample(u, rng.random((1, n_j, n, 2)))[0]

    def peak(self) -> np.ndarray:
        """(J, 3): pixel u, v of the centre of each map's maximal cell and the maximum; an empty
        map gives (NaN, NaN, 0), the keypoint convention for a missing joint."""
        return HeatmapStack.of([self]).peak()[0]


@dataclass
class HeatmapStack:
    """N person heatmaps of J maps each (every person in every view of a frame), their cells
    flattened into one array, so that sampling, peaks and look-ups for all of them take a fixed
    number of numpy calls instead of a few per heatmap. Grids may differ in size."""

    values: np.ndarray  # (S,) every cell, map after map, row-major within a map
    start: np.ndarray  # (N, J) index in values of cell [0, 0] of each map
    shape: np.ndarray  # (N, 2) rows h, columns w of each heatmap's grid
    origin: np.ndarray  # (N, J, 2)
    stride: np.ndarray  # (N,)

    @classmethod
    def of(cls, heatmaps: Sequence[PersonHeatmap]) -> HeatmapStack:
        if not heatmaps:  # a frame with nobody in it
            return cls(np.zeros(0, np.float32), np.zeros((0, 0), np.intp), np.zeros((0, 2), np.intp),
                       np.zeros((0, 0, 2)), np.zeros(0))
        n_j = len(heatmaps[0].maps)
        if any(len(hm.maps) != n_j for hm in heatmaps):
            raise ValueError('heatmaps of a stack must have the same number of joints')
        shape = np.array([hm.maps.shape[1:] for hm in heatmaps], dtype=np.intp).reshape(-1, 2)
        size = shape[:, 0] * shape[:, 1]
        first = np.concatenate([[0], np.cumsum(size * n_j)[:-1]]).astype(np.intp)
        return cls(values=np.concatenate([hm.maps.ravel() for hm in heatmaps]),
                   start=first[:, None] + size[:, None] * np.arange(n_j),
                   shape=shape,
                   origin=np.array([hm.origin for hm in heatmaps], dtype=np.float64).reshape(-1, n_j, 2),
                   stride=np.array([hm.stride for hm in heatmaps], dtype=np.float64))

    def _size(self) -> np.ndarray:
        return np.broadcast_to((self.shape[:, 0] * self.shape[:, 1])[:, None], self.start.shape)

    def _pixels(self, cell: np.ndarray, offset: np.ndarray) -> np.ndarray:
        """Pixels (N, J, K, 2) of cells (N, J, K) (index within their map), plus offset (..., 2)
        in cells."""
        row, col = np.divmod(cell, self.shape[:, 1, None, None])
        cr = np.stack([col, row], axis=-1) + offset
        return self.origin[:, :, None] + self.stride[:, None, None, None] * cr

    def sample(self, u: np.ndarray, jitter: np.ndarray) -> np.ndarray:
        """Pixels (N, J, K, 2) drawn from each map as a pmf over its cells, from uniform numbers
        u (N, J, K) in [0, 1) and jitter (N, J, K, 2) in [0, 1) (the position within the drawn
        cell); NaN for empty maps."""
        n, n_j, k = u.shape
        maps = np.repeat(np.arange(n * n_j), k)
        return self.sample_at(maps, u.ravel(), jitter.reshape(-1, 2)).reshape(n, n_j, k, 2)

    def sample_at(self, maps: np.ndarray, u: np.ndarray, jitter: np.ndarray) -> np.ndarray:
        """Pixels (Q, 2), one draw from each of maps (Q,) (map j of heatmap i is i * J + j) as a
        pmf over its cells, from uniform numbers u (Q,) and jitter (Q, 2) in [0, 1) (the position
        within the drawn cell); NaN for empty maps. Only the draws asked for are made."""
        # Only non-zero cells can be drawn, and maps are mostly zero: one CDF over the non-zero
        # cells of every map, each map drawing inside its own stretch.
        nz = np.flatnonzero(self.values)
        cum = np.concatenate([[0.0], np.cumsum(self.values[nz], dtype=np.float64)])
        start = self.start.ravel()
        first = np.searchsorted(nz, start)[maps]
        end = np.searchsorted(nz, start + self._size().ravel())[maps]
        before = cum[first]
        q = before + u * (cum[end] - before)
        idx = np.searchsorted(cum, q, side='right') - 1
        # rounding can step past a map's stretch; empty maps point anywhere (NaN below)
        idx = np.clip(idx, first, np.maximum(end - 1, first))
        idx = np.minimum(idx, max(len(nz) - 1, 0))
        cell = (nz[idx] if len(nz) else np.zeros_like(idx)) - start[maps]
        heatmap = maps // self.start.shape[1]
        row, col = np.divmod(cell, self.shape[heatmap, 1])
        stride = self.stride[heatmap]
        origin = self.origin.reshape(-1, 2)[maps]
        uv = np.empty((len(maps), 2))
        uv[:, 0] = origin[:, 0] + stride * (col + (jitter[:, 0] - 0.5))
        uv[:, 1] = origin[:, 1] + stride * (row + (jitter[:, 1] - 0.5))
        uv[end == first] = np.nan
        return uv

    def peak(self) -> np.ndarray:
        """(N, J, 3): pixel u, v of the centre of each map's maximal cell (the first, on ties)
        and the maximum; an empty map gives (NaN, NaN, 0)."""
        n, n_j = self.start.shape
        out = np.full((n, n_j, 3), np.nan)
        out[..., 2] = 0.0
        if n == 0:
            return out
        flat_start = self.start.ravel()
        best = np.maximum.reduceat(self.values, flat_start)  # every map has >= 1 cell
        at_max = np.flatnonzero(self.values == np.repeat(best, self._size().ravel()))
        cell = at_max[np.searchsorted(at_max, flat_start)] - flat_start  # first maximal cell of each map
        uv = self._pixels(cell.reshape(n, n_j, 1), np.zeros(2))[:, :, 0]
        has = best.reshape(n, n_j) > 0
        out[has, :2] = uv[has]
        out[..., 2] = np.maximum(best.reshape(n, n_j), 0.0)
        return out

    def lookup(self, uv: np.ndarray) -> np.ndarray:
        """Bilinear values (N, J, K) of each map at pixels uv (N, J, K, 2); 0 outside the grid
        of cell centres and for NaN pixels."""
        uv = np.asarray(uv, dtype=np.float64)
        # u and v apart: broadcasts over a last axis of 2 are slow
        inv = 1.0 / self.stride[:, None, None]
        c = (uv[..., 0] - self.origin[:, :, None, 0]) * inv
        r = (uv[..., 1] - self.origin[:, :, None, 1]) * inv
        h = self.shape[:, 0, None, None]
        w = self.shape[:, 1, None, None]
        inside = (c >= 0) & (c <= w - 1) & (r >= 0) & (r <= h - 1)  # False for NaN
        c = np.where(inside, c, 0.0)
        r = np.where(inside, r, 0.0)
        c0 = np.minimum(c.astype(np.intp), np.maximum(w - 2, 0))
        r0 = np.minimum(r.astype(np.intp), np.maximum(h - 2, 0))
        fc, fr = c - c0, r - r0
        base = self.start[..., None] + r0 * w + c0
        right = np.minimum(c0 + 1, w - 1) - c0
        down = (np.minimum(r0 + 1, h - 1) - r0) * w
        v = self.values
        top = v[base] * (1 - fc) + v[base + right] * fc
        bottom = v[base + down] * (1 - fc) + v[base + down + right] * fc
        return np.where(inside, top * (1 - fr) + bottom * fr, 0.0)


def render_heatmap(centres: list[np.ndarray], stride: float, sigma: float) -> PersonHeatmap:
    """One person's J maps from centres[j] ((n_j, 3) rows [u, v, weight], n_j may be 0): see
    render_heatmaps."""
    padded = np.zeros((1, len(centres), max([len(c) for c in centres] + [1]), 3))
    for j, cj in enumerate(centres):
        padded[0, j, :len(cj)] = cj
    return render_heatmaps(padded, stride, sigma)[0]


def render_heatmaps(centres: np.ndarray, stride: float, sigma: float) -> list[PersonHeatmap]:
    """Render the J maps of P people at once: map j of person p is the pointwise max of
    isotropic Gaussians (std sigma px) with peak weight (clipped to 1) at each row [u, v, weight]
    of centres[p, j] ((P, J, n, 3); rows with NaN or weight <= 0 are ignored, so padding is
    weight 0). Each Gaussian is cut to 0 beyond MARGIN_SIGMAS * sigma along u or v, so a map is
    exactly 0 away from its evidence; a map's grid covers its centres plus that margin, in
    cells of stride px centred on multiples of stride, all maps padded to the largest grid.

    Max (not sum) so that a map's value at a candidate is that candidate's own weight:
    overlapping evidence does not inflate the data term and values stay in [0, 1]."""
    centres = np.ascontiguousarray(centres, dtype=np.float64)
    if len(centres) == 0:
        return []
    lo = np.empty(centres.shape[:2] + (2,))
    # Compiled: the layout and, for each row that counts, its Gaussian's exponents within the cut,
    # then the maps. numpy takes the exponentials: the compiled float32 exp differs from numpy's
    # in the last bits.
    exponents, rows, weight, w, h = _gaussian_exponents(centres, float(stride), MARGIN_SIGMAS * sigma,
                                                        np.float32(-0.5 / sigma ** 2), lo)
    np.exp(exponents, out=exponents)
    maps = _max_of_gaussians(exponents, rows, weight, len(centres), centres.shape[1], h, w)
    return [PersonHeatmap(maps=maps[p], origin=lo[p], stride=float(stride)) for p in range(len(maps))]


@kernel('Tuple((float32[::1], int64[:, ::1], float32[::1], int64, int64))(float64[:, :, :, ::1], float64, float64, '
        'float32, float64[:, :, ::1])')
def _gaussian_exponents(centres, stride, margin, inv, lo):
    """render_heatmaps' layout and Gaussian exponents. Writes each map's origin lo (P, J, 2);
    returns the float32 exponents, as numpy computed them, of each row that counts (weight > 0,
    finite) along u at the cell columns u0:u1 within the cut, then along v at the cell rows v0:v1;
    per such row (R, 7) p, j, u0, u1, v0, v1, start of its exponents, and (R,) its weight clipped
    to 1, in float32; and the grid's w, h."""
    n_p, n_j, n = centres.shape[:3]
    hi = np.empty((n_p, n_j, 2))
    has = np.zeros((n_p, n_j), dtype=np.bool_)
    n_rows = 0
    for p in range(n_p):
        anchor = np.array([np.inf, np.inf])
        for j in range(n_j):
            low = np.array([np.inf, np.inf])
            high = np.array([-np.inf, -np.inf])
            for k in range(n):
                u, v, wt = centres[p, j, k]
                if np.isfinite(u) and np.isfinite(v) and np.isfinite(wt) and wt > 0:
                    low[0], low[1] = min(low[0], u), min(low[1], v)
                    high[0], high[1] = max(high[0], u), max(high[1], v)
                    has[p, j] = True
                    n_rows += 1
            lo[p, j] = low - margin
            hi[p, j] = high + margin
            if has[p, j]:
                anchor = np.minimum(anchor, lo[p, j])
        # a map without evidence sits at its person's first evidence (it is all zeros anyway)
        for i in range(2):
            if not np.isfinite(anchor[i]):
                anchor[i] = 0.0
        for j in range(n_j):
            if not has[p, j]:
                lo[p, j] = anchor
                hi[p, j] = anchor
    grid = np.zeros(2, dtype=np.int64)
    for p in range(n_p):
        for j in range(n_j):
            for i in range(2):
                lo[p, j, i] = np.floor(lo[p, j, i] / stride) * stride  # cells on the image's lattice
                grid[i] = max(grid[i], int(np.ceil((hi[p, j, i] - lo[p, j, i]) / stride)))
    size = grid + 1  # w, h
    stride32, cut = np.float32(stride), np.float32(margin)
    rows = np.empty((n_rows, 7), dtype=np.int64)
    weight = np.empty(n_rows, dtype=np.float32)
    exponents = np.empty(n_rows * (size[0] + size[1]), dtype=np.float32)
    r, end = 0, 0
    for p in range(n_p):
        for j in range(n_j):
            for k in range(n):
                u, v, wt = centres[p, j, k]
                if not (np.isfinite(u) and np.isfinite(v) and np.isfinite(wt) and wt > 0):
                    continue
                rows[r, 0], rows[r, 1], rows[r, 6] = p, j, end
                for i in range(2):
                    rel = np.float32((u if i == 0 else v) - lo[p, j, i])  # pixels from cell [0, 0]
                    first, last = size[i], 0
                    for x in range(size[i]):
                        d = stride32 * np.float32(x) - rel
                        if abs(d) <= cut:  # |d| grows away from rel: the cells within are a range
                            exponents[end] = inv * (d * d)
                            end += 1
                            first, last = min(first, x), x + 1
                    rows[r, 2 + 2 * i], rows[r, 3 + 2 * i] = first, max(last, first)
                weight[r] = np.float32(min(wt, 1.0))
                r += 1
    return exponents[:end], rows, weight, size[0], size[1]


@kernel('float32[:, :, :, ::1](float32[::1], int64[:, ::1], float32[::1], int64, int64, int64, int64)')
def _max_of_gaussians(gauss, rows, weight, n_p, n_j, h, w):
    """Maps (P, J, h, w): the max over the rows (_gaussian_exponents' (R, 7) and weight (R,)) of
    the outer product of weight * the row's Gaussian along v and its Gaussian along u (gauss:
    their values); cells outside the row's cut are left alone (its Gaussian is 0 there)."""
    maps = np.zeros((n_p, n_j, h, w), dtype=np.float32)
    for i in range(len(rows)):
        p, j, u0, u1, v0, v1, start = rows[i]
        for r in range(v0, v1):
            a = weight[i] * gauss[start + (u1 - u0) + (r - v0)]
            if a == 0:
                continue
            for c in range(u0, u1):
                value = a * gauss[start + (c - u0)]
                if value > maps[p, j, r, c]:
                    maps[p, j, r, c] = value
    return maps
