"""Per-person joint heatmaps H_{c,i}: per joint a grid of cells over the image region holding
that joint's evidence, with bilinear look-up (the CRF's data term) and sampling as a pmf (the
3D hypotheses)."""
from __future__ import annotations

from dataclasses import dataclass
from types import ModuleType
from typing import Sequence

import numpy as np

MARGIN_SIGMAS = 3.0  # a rendered Gaussian is cut this many sigmas from its centre


def compiled() -> ModuleType:
    """core.compiled, and numba with it, imported at the first computation on a heatmap: decoding
    and drawing people (the overlay node) then loads neither."""
    from mvpose_ros.core import compiled as module
    return module


def load_kernels() -> None:
    """Load the compiled kernels now, at the start of a node that computes on heatmaps: its first
    frame must not wait for numba to load them."""
    heatmap_kernels()


def heatmap_kernels() -> ModuleType:
    """core.heatmap_kernels, imported at the first computation on a heatmap (see compiled)."""
    from mvpose_ros.core import heatmap_kernels as module
    return module


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
        """The stack of heatmaps, each of the same number of maps (none: an empty stack)."""
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
        cut = heatmap_kernels().trim(*self._flat(), lo, shape)
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
        kernel_array = compiled().kernel_array
        jitter = kernel_array(jitter, np.float64).reshape(-1, 2)
        heatmap_kernels().sample(*self._flat(), kernel_array(maps, np.int64), kernel_array(u, np.float64),
                                 jitter, out)
        return out

    def peak(self) -> np.ndarray:
        """(N, J, 3): pixel u, v of the centre of each map's maximal cell (the first, on ties)
        and the maximum; an empty map gives (NaN, NaN, 0)."""
        out = np.empty(self.start.shape + (3,))
        heatmap_kernels().peak(*self._flat(), out.reshape(-1, 3))
        return out

    def lookup(self, uv: np.ndarray) -> np.ndarray:
        """Bilinear values (N, J, K) of each map at pixels uv (N, J, K, 2); 0 outside the grid
        of cell centres and for NaN pixels."""
        uv = compiled().kernel_array(uv, np.float64)
        out = np.empty(uv.shape[:-1])
        heatmap_kernels().lookup(*self._flat(), uv.reshape(-1, 2), uv.shape[-2], out.reshape(-1))
        return out

    def _flat(self) -> tuple[np.ndarray, ...]:
        """The stack as the kernels take it, per map (N * J,): cells (S,) (float32, or else
        float64), first cell, rows h, columns w, origin (N * J, 2), stride."""
        n_j = self.start.shape[1]
        cells = np.float32 if self.values.dtype == np.float32 else np.float64
        kernel_array = compiled().kernel_array
        return (kernel_array(self.values, cells),
                kernel_array(self.start, np.int64).reshape(-1),
                kernel_array(self.shape[..., 0], np.int64).reshape(-1),
                kernel_array(self.shape[..., 1], np.int64).reshape(-1),
                kernel_array(self.origin, np.float64).reshape(-1, 2),
                kernel_array(np.repeat(self.stride, n_j), np.float64))


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
    centres = compiled().kernel_array(centres, np.float64)
    if len(centres) == 0:
        return []
    n_p, n_j = centres.shape[:2]
    lo = np.empty((n_p, n_j, 2))
    shape = np.empty((n_p * n_j, 2), dtype=np.int64)
    # Compiled: the layout and, for each row that counts, its Gaussian's exponents within the cut,
    # then the maps. numpy takes the exponentials: the compiled float32 exp differs from numpy's
    # in the last bits.
    kernels = heatmap_kernels()
    exponents, rows, weight = kernels.gaussian_exponents(centres, float(stride), MARGIN_SIGMAS * sigma,
                                                         np.float32(-0.5 / sigma ** 2), lo, shape)
    np.exp(exponents, out=exponents)
    size = shape[:, 0] * shape[:, 1]
    start = np.zeros(len(size), dtype=np.int64)
    np.cumsum(size[:-1], out=start[1:])
    cells = kernels.max_of_gaussians(exponents, rows, weight, n_j, start, shape[:, 1].copy(), int(size.sum()))
    first = start.reshape(n_p, n_j)[:, 0]
    end = np.append(first[1:], len(cells))
    shape = shape.reshape(n_p, n_j, 2)
    return [PersonHeatmap.from_cells(cells[first[p]:end[p]], shape[p], lo[p], stride) for p in range(n_p)]
