"""Per-person joint heatmaps H_{c,i}: a grid of cells over one person's image region, with
bilinear look-up (the CRF's data term) and sampling as a pmf (the 3D hypotheses)."""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

MARGIN_SIGMAS = 3.0  # the rendered grid extends this many sigmas beyond the box


@dataclass
class PersonHeatmap:
    """J heatmaps on a common grid: cell [r, c] is centred at pixel origin + stride * (c, r)."""

    maps: np.ndarray  # (J, h, w) float32 in [0, 1]
    origin: np.ndarray  # (2,) pixel (u, v) of the centre of cell [0, 0]
    stride: float  # pixels per cell

    def _cells(self, uv: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Fractional (column, row) grid coordinates of pixels uv (..., 2)."""
        cr = (np.asarray(uv, dtype=np.float64) - self.origin) / self.stride
        return cr[..., 0], cr[..., 1]

    def lookup(self, uv: np.ndarray) -> np.ndarray:
        """Bilinear value (J, N) of joint j's map at pixel uv[j, n] (uv: (J, N, 2)); 0 outside
        the grid of cell centres and for NaN pixels."""
        n_j, h, w = self.maps.shape
        c, r = self._cells(uv)
        inside = (c >= 0) & (c <= w - 1) & (r >= 0) & (r <= h - 1)  # False for NaN
        c = np.where(inside, c, 0.0)
        r = np.where(inside, r, 0.0)
        c0 = np.minimum(np.floor(c).astype(np.intp), max(w - 2, 0))
        r0 = np.minimum(np.floor(r).astype(np.intp), max(h - 2, 0))
        c1 = np.minimum(c0 + 1, w - 1)
        r1 = np.minimum(r0 + 1, h - 1)
        fc, fr = c - c0, r - r0
        j = np.arange(n_j)[:, None]
        m = self.maps
        top = m[j, r0, c0] * (1 - fc) + m[j, r0, c1] * fc
        bottom = m[j, r1, c0] * (1 - fc) + m[j, r1, c1] * fc
        return np.where(inside, top * (1 - fr) + bottom * fr, 0.0)

    def sample(self, rng: np.random.Generator, n: int) -> np.ndarray:
        """Draw n pixels per joint (J, n, 2) with each map as a pmf over its cells (probability
        proportional to the value), jittered uniformly within the cell; NaN rows for empty maps."""
        n_j, h, w = self.maps.shape
        flat = self.maps.reshape(n_j, -1)
        # Only non-zero cells can be drawn, and maps are mostly zero: one CDF over the non-zero
        # cells of every joint (in joint order), each joint drawing inside its own stretch.
        joint, cell = np.nonzero(flat)
        if len(cell) == 0:
            return np.full((n_j, n, 2), np.nan)
        cum = np.cumsum(flat[joint, cell], dtype=np.float64)
        first = np.searchsorted(joint, np.arange(n_j))
        end = np.searchsorted(joint, np.arange(n_j), side='right')
        before = np.concatenate([[0.0], cum])[first]  # (J,) mass of the joints before j
        total = np.concatenate([[0.0], cum])[end] - before
        q = before[:, None] + rng.random((n_j, n)) * total[:, None]
        idx = np.searchsorted(cum, q, side='right')
        empty = end == first
        # rounding can step past a joint's stretch; empty joints point anywhere (NaN below)
        idx = np.minimum(np.clip(idx, first[:, None], np.maximum(end - 1, first)[:, None]), len(cell) - 1)
        row, col = np.divmod(cell[idx], w)
        jitter = rng.random((n_j, n, 2)) - 0.5
        uv = self.origin + self.stride * (np.stack([col, row], axis=-1) + jitter)
        uv[empty] = np.nan
        return uv

    def peak(self) -> np.ndarray:
        """(J, 3): pixel u, v of the centre of each map's maximal cell and the maximum; an empty
        map gives (NaN, NaN, 0), the keypoint convention for a missing joint."""
        n_j, h, w = self.maps.shape
        flat = self.maps.reshape(n_j, -1)
        best = np.argmax(flat, axis=1)
        row, col = np.divmod(best, w)
        value = flat[np.arange(n_j), best].astype(np.float64)
        uv = self.origin + self.stride * np.stack([col, row], axis=-1)
        uv[value <= 0] = np.nan
        return np.concatenate([uv, value[:, None]], axis=1)


def render_heatmap(centres: list[np.ndarray], box: np.ndarray, stride: float,
                   sigma: float) -> PersonHeatmap:
    """Render J maps: map j is the pointwise max of isotropic Gaussians (std sigma px) with peak
    weight (clipped to 1) at each row [u, v, weight] of centres[j] ((n_j, 3), n_j may be 0; rows
    with NaN or weight <= 0 are ignored). Each Gaussian is cut to 0 beyond MARGIN_SIGMAS * sigma
    along u or v, so a map is exactly 0 away from its evidence; the grid covers box (4,) u0, v0,
    u1, v1 plus that margin on each side (a Gaussian centred in the box fits whole), in cells of
    stride px.

    Max (not sum) so that a map's value at a candidate is that candidate's own weight:
    overlapping evidence does not inflate the data term and values stay in [0, 1]."""
    box = np.asarray(box, dtype=np.float64)
    margin = MARGIN_SIGMAS * sigma
    origin = box[:2] - margin
    w, h = np.ceil((box[2:] - box[:2] + 2 * margin) / stride).astype(int) + 1
    # all joints at once: centres padded to a common count with weight 0
    n_max = max([len(c) for c in centres] + [1])
    padded = np.zeros((len(centres), n_max, 3))
    for j, cj in enumerate(centres):
        padded[j, :len(cj)] = cj
    valid = np.isfinite(padded).all(axis=-1) & (padded[..., 2] > 0)
    padded[~valid] = 0.0
    rel = (padded[..., :2] - origin).astype(np.float32)  # (J, n, 2) pixels from cell [0, 0]
    us = np.float32(stride) * np.arange(w, dtype=np.float32)
    vs = np.float32(stride) * np.arange(h, dtype=np.float32)
    inv = np.float32(-0.5 / sigma ** 2)
    cut = np.float32(MARGIN_SIGMAS * sigma)
    du, dv = us - rel[..., :1], vs - rel[..., 1:]
    gu = np.where(np.abs(du) <= cut, np.exp(inv * du ** 2), 0)  # (J, n, w)
    weight = np.minimum(padded[..., 2:], 1.0).astype(np.float32)
    gv = weight * np.where(np.abs(dv) <= cut, np.exp(inv * dv ** 2), 0)  # (J, n, h)
    maps = np.max(gv[..., :, None] * gu[..., None, :], axis=1)  # outer products (J, n, h, w)
    return PersonHeatmap(maps=maps, origin=origin, stride=float(stride))
