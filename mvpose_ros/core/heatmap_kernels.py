"""The compiled kernels of core.heatmap: a stack's trimming, draws, peaks and bilinear look-ups,
and the rendering of Gaussian maps. core.heatmap imports them where a heatmap is computed on, so
that code that only decodes and draws people (the overlay node) loads no numba."""
from __future__ import annotations

import numpy as np

from mvpose_ros.core.compiled import kernel

# a stack as the kernels take it (HeatmapStack._flat), cells float32 (as rendered) or float64
_STACKS = [f'{cells}[::1], int64[::1], int64[::1], int64[::1], float64[:, ::1], float64[::1]'
           for cells in ('float32', 'float64')]


@kernel(*(f'{cells}[::1]({stack}, int64[:, ::1], int64[:, ::1])'
          for cells, stack in zip(('float32', 'float64'), _STACKS)))
def trim(values, start, rows, cols, origin, stride, lo, shape):
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
def sample(values, start, rows, cols, origin, stride, maps, u, jitter, out):
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
def peak(values, start, rows, cols, origin, stride, out):
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
def lookup(values, start, rows, cols, origin, stride, uv, per_map, out):
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


@kernel('Tuple((float32[::1], int64[:, ::1], float32[::1]))(float64[:, :, :, ::1], float64, float64, float32, '
        'float64[:, :, ::1], int64[:, ::1])')
def gaussian_exponents(centres, stride, margin, inv, lo, shape):
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
def max_of_gaussians(gauss, rows, weight, n_j, start, cols, total):
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
