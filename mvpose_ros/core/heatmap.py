"""Per-person joint heatmaps H_{c,i}: per joint a grid of cells over the image region holding
that joint's evidence, with bilinear look-up (the CRF's data term) and sampling as a pmf (the
3D hypotheses)."""
from __future__ import annotations

from dataclasses import dataclass
from typing import Sequence

import numpy as np

from mvpose_ros.core.compiled import kernel, kernel_array

MARGIN_SIGMAS = 3.0  # a rendered Gaussian is cut this many sigmas from its centre


class PersonHeatmap:
    """J heatmaps; map j is a grid of shape[j] = (h_j, w_j) cells whose cell [r, c] is centred at
    pixel origin[j] + stride * (c, r). Each map has its own origin and size, so that it covers
    only the region of its joint (a person-sized grid per joint is ~99% zeros, and every step
    downstream, the wire included, pays for its size).

    cells: (S,) every map's cells, map after map, row-major within a map (S = sum of h_j * w_j),
    float32 in [0, 1]; shape: (J, 2) int; origin: (J, 2) pixels; stride: pixels per cell.
    """

    __slots__ = ('cells', 'shape', 'origin', 'stride')

    def __init__(self, maps: np.ndarray, origin: np.ndarray, stride: float) -> None:
        """maps: (J, h, w), one grid size for every map; origin: (J, 2), or (2,) shared."""
        maps = np.asarray(maps)
        if maps.ndim != 3:
            raise ValueError(f'heatmap maps: expected (J, h, w), got shape {maps.shape}')
        origin = np.asarray(origin, dtype=np.float64)
        # broadcast only a shared origin: a decoder makes a heatmap per person and view each frame
        origin = origin if origin.shape == (len(maps), 2) else np.broadcast_to(origin, (len(maps), 2))
        self._set(maps.reshape(-1), np.tile(np.array(maps.shape[1:], dtype=np.int64), (len(maps), 1)),
                  origin, stride)

    @classmethod
    def from_cells(cls, cells: np.ndarray, shape: np.ndarray, origin: np.ndarray, stride: float) -> PersonHeatmap:
        """A heatmap of maps of their own sizes: cells (S,), shape (J, 2), origin (J, 2) as the
        attributes."""
        heatmap = cls.__new__(cls)
        heatmap._set(np.asarray(cells), np.asarray(shape, dtype=np.int64), np.asarray(origin, dtype=np.float64),
                     stride)
        return heatmap

    def _set(self, cells: np.ndarray, shape: np.ndarray, origin: np.ndarray, stride: float) -> None:
        if shape.ndim != 2 or shape.shape[1] != 2 or origin.shape != shape.shape:
            raise ValueError(f'heatmap shape {shape.shape} and origin {origin.shape}: expected (J, 2) each')
        if cells.ndim != 1 or len(cells) != int((shape[:, 0] * shape[:, 1]).sum()):
            raise ValueError(f'heatmap cells {cells.shape}: expected ({int((shape[:, 0] * shape[:, 1]).sum())},), '
                             f'the cells of maps of shape {shape.tolist()}')
        self.cells, self.shape, self.origin, self.stride = cells, shape, origin, float(stride)

    def __len__(self) -> int:
        """J, the number of maps."""
        return len(self.shape)

    @property
    def maps(self) -> np.ndarray:
        """(J, h, w) every map on the largest grid, padded with zeros at the bottom and right."""
        if len(self.shape) == 0:
            return np.zeros((0, 0, 0), dtype=self.cells.dtype)
        h, w = self.shape.max(axis=0)
        if (self.shape == (h, w)).all():
            return self.cells.reshape(len(self.shape), h, w)
        out = np.zeros((len(self.shape), h, w), dtype=self.cells.dtype)
        start = 0
        for j, (mh, mw) in enumerate(self.shape):
            out[j, :mh, :mw] = self.cells[start:start + mh * mw].reshape(mh, mw)
            start += mh * mw
        return out

    def lookup(self, uv: np.ndarray) -> np.ndarray:
        """Bilinear value (J, N) of joint j's map at pixel uv[j, n] (uv: (J, N, 2)); 0 outside
        the grid of cell centres and for NaN pixels."""
        return HeatmapStack.of([self]).lookup(np.asarray(uv)[None])[0]

    def sample(self, rng: np.random.Generator, n: int) -> np.ndarray:
        """Draw n pixels per joint (J, n, 2) with each map as a pmf over its cells (probability
        proportional to the value), jittered uniformly within the cell; NaN rows for empty maps."""
        u = rng.random((1, len(self), n))
        return HeatmapStack.of([self]).sample(u, rng.random((1, len(self), n, 2)))[0]

    def peak(self) -> np.ndarray:
        """(J, 3): pixel u, v of the centre of each map's maximal cell and the maximum; an empty
        map gives (NaN, NaN, 0), the keypoint convention for a missing joint."""
        return HeatmapStack.of([self]).peak()[0]

    def trimmed(self) -> PersonHeatmap:
        """This heatmap with each map cut to its evidence (HeatmapStack.trimmed: the same look-ups
        and draws)."""
        stack = HeatmapStack.of([self]).trimmed()
        return PersonHeatmap.from_cells(stack.values, stack.shape[0], stack.origin[0], self.stride)


@dataclass
class HeatmapStack:
    """N person heatmaps of J maps each (every person in every view of a frame), their cells
    flattened into one array, so that sampling, peaks and look-ups for all of them take one
    compiled call instead of a few per heatmap. Every map has its own grid size."""

    values: np.ndarray  # (S,) every cell, map after map, row-major within a map
    start: np.ndarray  # (N, J) index in values of cell [0, 0] of each map
    shape: np.ndarray  # (N, J, 2) rows h, columns w of each map's grid
    origin: np.ndarray  # (N, J, 2)
    stride: np.ndarray  # (N,)

    @classmethod
    def of(cls, heatmaps: Sequence[PersonHeatmap]) -> HeatmapStack:
        if not heatmaps:  # a frame with nobody in it
            return cls(np.zeros(0, np.float32), np.zeros((0, 0), np.intp), np.zeros((0, 0, 2), np.intp),
                       np.zeros((0, 0, 2)), np.zeros(0))
        n_j = len(heatmaps[0])
        if any(len(hm) != n_j for hm in heatmaps):
            raise ValueError('heatmaps of a stack must have the same number of joints')
        shape = np.concatenate([hm.shape for hm in heatmaps]).reshape(-1, n_j, 2)
        size = (shape[..., 0] * shape[..., 1]).ravel()
        start = np.zeros(len(size), dtype=np.intp)
        np.cumsum(size[:-1], out=start[1:])
        return cls(values=np.concatenate([hm.cells for hm in heatmaps]),
                   start=start.reshape(-1, n_j),
                   shape=shape,
                   origin=np.array([hm.origin for hm in heatmaps], dtype=np.float64).reshape(-1, n_j, 2),
                   stride=np.array([hm.stride for hm in heatmaps], dtype=np.float64))

    def trimmed(self) -> HeatmapStack:
        """The stack with each map cut to the rows and columns of its non-zero cells plus one zero
        cell on each side where its grid has one (so bilinear look-ups and every draw are those of
        the whole map); an empty map keeps one cell. What goes are the zeros around a map's
        evidence: the rest of a crop (the ONNX path), or padding to a common grid."""
        n, n_j = self.start.shape
        lo = np.empty((n * n_j, 2), dtype=np.int64)
        shape = np.empty((n * n_j, 2), dtype=np.int64)
        cut = _trim(*self._flat(), lo, shape)
        size = shape[:, 0] * shape[:, 1]
        start = np.zeros(len(size), dtype=np.intp)
        np.cumsum(size[:-1], out=start[1:])
        origin = self.origin + self.stride[:, None, None] * lo[:, ::-1].reshape(n, n_j, 2)
        return HeatmapStack(cut, start.reshape(n, n_j), shape.reshape(n, n_j, 2), origin, self.stride)

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
                kernel_array(self.shape[..., 0], np.int64).reshape(-1),
                kernel_array(self.shape[..., 1], np.int64).reshape(-1),
                kernel_array(self.origin, np.float64).reshape(-1, 2),
                kernel_array(np.repeat(self.stride, n_j), np.float64))


# a stack as the kernels take it (HeatmapStack._flat), cells float32 (as rendered) or float64
_STACKS = [f'{cells}[::1], int64[::1], int64[::1], int64[::1], float64[:, ::1], float64[::1]'
           for cells in ('float32', 'float64')]


@kernel(*(f'{cells}[::1]({stack}, int64[:, ::1], int64[:, ::1])'
          for cells, stack in zip(('float32', 'float64'), _STACKS)))
def _trim(values, start, rows, cols, origin, stride, lo, shape):
    """HeatmapStack.trimmed's cells: writes each map's first kept row and column lo (N * J, 2) and
    its kept rows and columns shape (N * J, 2); returns the kept cells, map after map."""
    n_maps = len(start)
    empty = np.zeros(n_maps, np.bool_)
    total = 0
    for m in range(n_maps):
        h, w = rows[m], cols[m]
        r0, r1, c0, c1 = h, -1, w, -1
        for r in range(h):
            for c in range(w):
                if values[start[m] + r * w + c] != 0:
                    r0, r1 = min(r0, r), max(r1, r)
                    c0, c1 = min(c0, c), max(c1, c)
        if r1 < 0:  # an empty map keeps one zero cell at its origin
            empty[m] = True
            r0, r1, c0, c1 = 0, 0, 0, 0
        else:
            r0, r1, c0, c1 = max(r0 - 1, 0), min(r1 + 1, h - 1), max(c0 - 1, 0), min(c1 + 1, w - 1)
        lo[m, 0], lo[m, 1] = r0, c0
        shape[m, 0], shape[m, 1] = r1 - r0 + 1, c1 - c0 + 1
        total += shape[m, 0] * shape[m, 1]
    out = np.zeros(total, values.dtype)
    k = 0
    for m in range(n_maps):
        if empty[m]:
            k += 1
            continue
        for r in range(lo[m, 0], lo[m, 0] + shape[m, 0]):
            first = start[m] + r * cols[m] + lo[m, 1]
            out[k:k + shape[m, 1]] = values[first:first + shape[m, 1]]
            k += shape[m, 1]
    return out


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
    exactly 0 away from its evidence; each map's grid covers its centres plus that margin and
    one more column and row, in cells of stride px centred on multiples of stride (a map without
    evidence: one cell).

    Max (not sum) so that a map's value at a candidate is that candidate's own weight:
    overlapping evidence does not inflate the data term and values stay in [0, 1]. The extra
    column and row are zero, so a map looks up as it would inside any larger grid of zeros."""
    centres = kernel_array(centres, np.float64)
    if len(centres) == 0:
        return []
    n_p, n_j = centres.shape[:2]
    lo = np.empty((n_p, n_j, 2))
    shape = np.empty((n_p * n_j, 2), dtype=np.int64)
    # Compiled: the layout and, for each row that counts, its Gaussian's exponents within the cut,
    # then the maps. numpy takes the exponentials: the compiled float32 exp differs from numpy's
    # in the last bits.
    exponents, rows, weight = _gaussian_exponents(centres, float(stride), MARGIN_SIGMAS * sigma,
                                                  np.float32(-0.5 / sigma ** 2), lo, shape)
    np.exp(exponents, out=exponents)
    size = shape[:, 0] * shape[:, 1]
    start = np.zeros(len(size), dtype=np.int64)
    np.cumsum(size[:-1], out=start[1:])
    cells = _max_of_gaussians(exponents, rows, weight, n_j, start, shape[:, 1].copy(), int(size.sum()))
    first = start.reshape(n_p, n_j)[:, 0]
    end = np.append(first[1:], len(cells))
    shape = shape.reshape(n_p, n_j, 2)
    return [PersonHeatmap.from_cells(cells[first[p]:end[p]], shape[p], lo[p], stride) for p in range(n_p)]


@kernel('Tuple((float32[::1], int64[:, ::1], float32[::1]))(float64[:, :, :, ::1], float64, float64, float32, '
        'float64[:, :, ::1], int64[:, ::1])')
def _gaussian_exponents(centres, stride, margin, inv, lo, shape):
    """render_heatmaps' layout and Gaussian exponents. Writes each map's origin lo (P, J, 2) and
    grid rows, columns shape (P * J, 2); returns the float32 exponents, as numpy computed them, of
    each row that counts (weight > 0, finite) along u at the cell columns u0:u1 within the cut,
    then along v at the cell rows v0:v1; per such row (R, 7) p, j, u0, u1, v0, v1, start of its
    exponents, and (R,) its weight clipped to 1, in float32."""
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
    longest = 1
    for p in range(n_p):
        for j in range(n_j):
            for i in range(2):
                lo[p, j, i] = np.floor(lo[p, j, i] / stride) * stride  # cells on the image's lattice
                # the cells up to the margin, and one more: zero, as past a larger grid's end
                cells = int(np.ceil((hi[p, j, i] - lo[p, j, i]) / stride)) + 2 if has[p, j] else 1
                shape[p * n_j + j, 1 - i] = cells
                longest = max(longest, cells)
    stride32, cut = np.float32(stride), np.float32(margin)
    rows = np.empty((n_rows, 7), dtype=np.int64)
    weight = np.empty(n_rows, dtype=np.float32)
    exponents = np.empty(n_rows * 2 * longest, dtype=np.float32)
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
                    size = shape[p * n_j + j, 1 - i]
                    first, last = size, 0
                    for x in range(size):
                        d = stride32 * np.float32(x) - rel
                        if abs(d) <= cut:  # |d| grows away from rel: the cells within are a range
                            exponents[end] = inv * (d * d)
                            end += 1
                            first, last = min(first, x), x + 1
                    rows[r, 2 + 2 * i], rows[r, 3 + 2 * i] = first, max(last, first)
                weight[r] = np.float32(min(wt, 1.0))
                r += 1
    return exponents[:end], rows, weight


@kernel('float32[::1](float32[::1], int64[:, ::1], float32[::1], int64, int64[::1], int64[::1], int64)')
def _max_of_gaussians(gauss, rows, weight, n_j, start, cols, total):
    """Cells (total,) of maps whose first cell is start[m] and columns cols[m] (map m = p * n_j +
    j): the max over the rows (_gaussian_exponents' (R, 7) and weight (R,)) of the outer product
    of weight * the row's Gaussian along v and its Gaussian along u (gauss: their values); cells
    outside the row's cut are left alone (its Gaussian is 0 there)."""
    cells = np.zeros(total, dtype=np.float32)
    for i in range(len(rows)):
        p, j, u0, u1, v0, v1, first = rows[i]
        m = p * n_j + j
        for r in range(v0, v1):
            a = weight[i] * gauss[first + (u1 - u0) + (r - v0)]
            if a == 0:
                continue
            for c in range(u0, u1):
                value = a * gauss[first + (c - u0)]
                at = start[m] + r * cols[m] + c
                if value > cells[at]:
                    cells[at] = value
    return cells
