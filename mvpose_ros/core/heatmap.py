"""Per-person joint heatmaps H_{c,i}: per joint a grid of cells over the image region holding
that joint's evidence, with bilinear look-up (the CRF's data term) and sampling as a pmf (the
3D hypotheses)."""
from __future__ import annotations

from dataclasses import dataclass
from typing import Sequence

import numpy as np

from mvpose_ros.core.compiled import kernel, kernel_array

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
        origin = np.asarray(self.origin, dtype=np.float64)
        shape = (len(self.maps), 2)
        # broadcast only a shared origin: a decoder makes a heatmap per person and view each frame
        self.origin = origin if origin.shape == shape else np.broadcast_to(origin, shape)

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
    flattened into one array, so that sampling, peaks and look-ups for all of them take one
    compiled call instead of a few per heatmap. Grids may differ in size."""

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
        out = np.empty((len(maps), 2))
        jitter = kernel_array(jitter, np.float64).reshape(-1, 2)
        _sample(*self._flat(), kernel_array(maps, np.int64), kernel_array(u, np.float64),
                jitter, out)
        return out

    def peak(self) -> np.ndarray:
        """(N, J, 3): pixel u, v of the centre of each map's maximal cell (the first, on ties)
        and the maximum; an empty map gives (NaN, NaN, 0)."""
        out = np.empty(self.start.shape + (3,))
        _peak(*self._flat(), out.reshape(-1, 3))
        return out

    def lookup(self, uv: np.ndarray) -> np.ndarray:
        """Bilinear values (N, J, K) of each map at pixels uv (N, J, K, 2); 0 outside the grid
        of cell centres and for NaN pixels."""
        uv = kernel_array(uv, np.float64)
        out = np.empty(uv.shape[:-1])
        _lookup(*self._flat(), uv.reshape(-1, 2), uv.shape[-2], out.reshape(-1))
        return out

    def _flat(self) -> tuple[np.ndarray, ...]:
        """The stack as the kernels take it, per map (N * J,): cells (S,) (float32, or else
        float64), first cell, rows h, columns w, origin (N * J, 2), stride."""
        n_j = self.start.shape[1]
        cells = np.float32 if self.values.dtype == np.float32 else np.float64
        return (kernel_array(self.values, cells),
                kernel_array(self.start, np.int64).reshape(-1),
                kernel_array(np.repeat(self.shape[:, 0], n_j), np.int64),
                kernel_array(np.repeat(self.shape[:, 1], n_j), np.int64),
                kernel_array(self.origin, np.float64).reshape(-1, 2),
                kernel_array(np.repeat(self.stride, n_j), np.float64))


# a stack as the kernels take it (HeatmapStack._flat), cells float32 (as rendered) or float64
_STACKS = [f'{cells}[::1], int64[::1], int64[::1], int64[::1], float64[:, ::1], float64[::1]'
           for cells in ('float32', 'float64')]


@kernel(*(f'void({stack}, int64[::1], float64[::1], float64[:, ::1], float64[:, ::1])' for stack in _STACKS))
def _sample(values, start, rows, cols, origin, stride, maps, u, jitter, out):
    # Only non-zero cells can be drawn: one CDF (float64, summed in cell order) over the non-zero
    # cells of every map, each map drawing inside its own stretch [first, end) of it. nz and cum
    # are sized for every cell, but only their first (non-zero) entries are ever touched.
    n_maps = len(start)
    nz = np.empty(len(values), np.int64)
    cum = np.empty(len(values) + 1)
    first = np.empty(n_maps, np.int64)
    end = np.empty(n_maps, np.int64)
    cum[0] = 0.0
    n = 0
    for m in range(n_maps):
        first[m] = n
        for c in range(start[m], start[m] + rows[m] * cols[m]):
            if values[c] != 0:
                nz[n] = c
                cum[n + 1] = cum[n] + np.float64(values[c])
                n += 1
        end[m] = n
    for i in range(len(maps)):
        m = maps[i]
        lo, hi = first[m], end[m]
        if hi == lo:
            out[i, 0] = np.nan
            out[i, 1] = np.nan
            continue
        before = cum[lo]
        q = before + u[i] * (cum[hi] - before)
        # the last cumulative sum <= q; rounding can step past the stretch, kept inside it
        a, b = lo, hi + 1
        while a < b:
            mid = (a + b) // 2
            if cum[mid] <= q:
                a = mid + 1
            else:
                b = mid
        idx = min(max(a - 1, lo), hi - 1)
        cell = nz[idx] - start[m]
        row, col = cell // cols[m], cell % cols[m]
        out[i, 0] = origin[m, 0] + stride[m] * (col + (jitter[i, 0] - 0.5))
        out[i, 1] = origin[m, 1] + stride[m] * (row + (jitter[i, 1] - 0.5))


@kernel(*(f'void({stack}, float64[:, ::1])' for stack in _STACKS))
def _peak(values, start, rows, cols, origin, stride, out):
    for m in range(len(start)):
        best_cell = 0
        best = values[start[m]]
        for c in range(1, rows[m] * cols[m]):
            if values[start[m] + c] > best:
                best, best_cell = values[start[m] + c], c
        if best > 0:
            out[m, 0] = origin[m, 0] + stride[m] * (best_cell % cols[m])
            out[m, 1] = origin[m, 1] + stride[m] * (best_cell // cols[m])
            out[m, 2] = best
        else:
            out[m, 0] = np.nan
            out[m, 1] = np.nan
            out[m, 2] = 0.0


@kernel(*(f'void({stack}, float64[:, ::1], int64, float64[::1])' for stack in _STACKS))
def _lookup(values, start, rows, cols, origin, stride, uv, per_map, out):
    # uv (N * J * K, 2): K pixels per map; the same arithmetic, in the same order, as numpy's
    # bilinear interpolation on whole arrays
    for m in range(len(start)):
        inv = 1.0 / stride[m]
        h, w = rows[m], cols[m]
        last_c, last_r = max(w - 2, 0), max(h - 2, 0)
        for i in range(m * per_map, (m + 1) * per_map):
            c = (uv[i, 0] - origin[m, 0]) * inv
            r = (uv[i, 1] - origin[m, 1]) * inv
            if not (c >= 0 and c <= w - 1 and r >= 0 and r <= h - 1):  # False for NaN
                out[i] = 0.0
                continue
            c0 = min(int(c), last_c)
            r0 = min(int(r), last_r)
            fc, fr = c - c0, r - r0
            base = start[m] + r0 * w + c0
            right = min(c0 + 1, w - 1) - c0
            down = (min(r0 + 1, h - 1) - r0) * w
            top = values[base] * (1 - fc) + values[base + right] * fc
            bottom = values[base + down] * (1 - fc) + values[base + down + right] * fc
            out[i] = top * (1 - fr) + bottom * fr


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
    centres = kernel_array(centres, np.float64)
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
