"""CRF factors over discrete 3D joint hypotheses: data, temporal, collision, limb length.

Every table is returned as float32 and scaled to sum to one (the paper normalises each factor
to a probability for numerical stability; a constant scale does not change BP marginals).
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Sequence

import numpy as np

from mvpose_ros.core.compiled import kernel
from mvpose_ros.core.geometry.camera import Camera, rig_project
from mvpose_ros.core.heatmap import HeatmapStack, PersonHeatmap

TEMPORAL_FORMS = ('laplace', 'gauss')


@dataclass(frozen=True)
class FactorConfig:
    """Parameters of the factors, in metres.

    The paper writes the temporal factor as exp(-||d|| / (2 sigma^2)) with sigma = 2 cm, which is
    only dimensionally sensible with ||d|| in centimetres: a Laplace kernel exp(-||d|| / 8 cm).
    `temporal_form='laplace', temporal_scale=0.08` is that reading; 'gauss' uses
    exp(-||d||^2 / (2 scale^2)). temporal_scale holds for frames one nominal period apart
    (window.InferenceConfig.frame_rate) and grows with the real step (temporal_table). The
    collision sigmoid is 1 / (1 + exp((centre - d) / width)). A limb is plausible between
    limb_range times its typical length (adults of 1.2 to 2.3 m, and the spread of where detectors
    put joints), and falls off as a Gaussian of std limb_sigma beyond (limb_table).
    """

    temporal_form: str = 'laplace'
    temporal_scale: float = 0.08
    collision_centre: float = 0.15
    collision_width: float = 0.10
    limb_sigma: float = 0.05
    limb_range: tuple[float, float] = (0.7, 1.3)

    def __post_init__(self) -> None:
        if self.temporal_form not in TEMPORAL_FORMS:
            raise ValueError(f'temporal_form must be one of {TEMPORAL_FORMS}, got {self.temporal_form!r}')
        low, high = self.limb_range
        if not 0 <= low <= high:
            raise ValueError(f'limb_range must be (low, high) with 0 <= low <= high, got {self.limb_range}')
        for name in ('temporal_scale', 'collision_width', 'limb_sigma'):
            if not getattr(self, name) > 0:
                raise ValueError(f'{name} must be positive, got {getattr(self, name)}')


def _normalised(table: np.ndarray, axes: tuple[int, ...]) -> np.ndarray:
    total = table.sum(axis=axes, keepdims=True)
    return (table / np.maximum(total, np.finfo(np.float32).tiny)).astype(np.float32, copy=False)


def data_terms(hypotheses: Sequence[np.ndarray], people: Sequence[Sequence[tuple[Camera, PersonHeatmap]]],
               stack: HeatmapStack) -> list[np.ndarray]:
    """The data term of every person of a frame: per hypothesis, the mean heatmap value at its
    projections, normalised per joint. hypotheses[p]: (J, M, 3) world points of person p, seen by
    the views people[p] (camera, that person's heatmaps in it); stack: every view's heatmap,
    person after person (as for sampling). Returns (J, M) per person, each row summing to one
    (uniform where no view has any evidence)."""
    if not people:
        return []
    cameras = [cam for views in people for cam, _ in views]
    counts = np.array([len(v) for v in people], dtype=np.int64)
    points = np.stack(hypotheses)  # (P, J, M, 3)
    n_people, n_joints, m = points.shape[:3]
    rig = list({id(c): c for c in cameras}.values())
    which = [next(i for i, r in enumerate(rig) if r is c) for c in cameras]  # (V,) each view's camera
    uv = rig_project(rig, which, points.reshape(n_people, -1, 3), np.repeat(np.arange(n_people), counts))
    values = stack.lookup(uv.reshape(stack.start.shape + (m, 2)))  # (V, J, M); NaN projections give 0
    out = np.empty((n_people, n_joints, m))
    _mean_over_views(values, counts, out)
    return list(out)


@kernel('float64(float64[:])')
def _pairwise_sum(x):
    # numpy's summation of a row by add.reduce (pairwise: eight partial sums within blocks of 128)
    n = len(x)
    if n < 8:
        total = 0.0
        for i in range(n):
            total += x[i]
        return total
    if n > 128:
        half = n // 2
        half -= half % 8
        return _pairwise_sum(x[:half]) + _pairwise_sum(x[half:])
    r = x[:8].copy()
    i = 8
    while i < n - n % 8:
        for k in range(8):
            r[k] += x[i + k]
        i += 8
    total = ((r[0] + r[1]) + (r[2] + r[3])) + ((r[4] + r[5]) + (r[6] + r[7]))
    for k in range(i, n):
        total += x[k]
    return total


@kernel('void(float64[:, :, ::1], int64[::1], float64[:, :, ::1])')
def _mean_over_views(values, counts, out):
    # values (V, J, M), views person after person -> out (P, J, M): each person's mean over its
    # views, each row scaled to sum to one (uniform where it sums to 0). numpy's order of sums
    # (add.reduceat: the first view plus the reduction of the others; then a row's reduction).
    first = 0
    for p in range(len(counts)):
        for j in range(out.shape[1]):
            row = out[p, j]
            for k in range(len(row)):
                total = 0.0
                if counts[p] > 0:
                    total = values[first, j, k]
                if counts[p] > 8:
                    total += _pairwise_sum(values[first + 1:first + counts[p], j, k])
                elif counts[p] > 1:  # fewer than 8 to reduce: _pairwise_sum's plain loop, inline
                    rest = 0.0
                    for v in range(first + 1, first + counts[p]):
                        rest += values[v, j, k]
                    total += rest
                row[k] = total / max(counts[p], 1)
            total = _pairwise_sum(row)
            for k in range(len(row)):
                row[k] = row[k] / total if total > 0 else 1.0 / len(row)
        first += counts[p]


def temporal_table(prev: np.ndarray, cur: np.ndarray, nxt: np.ndarray, config: FactorConfig,
                   steps: tuple[float, float] = (1.0, 1.0)) -> np.ndarray:
    """Ternary constant-velocity factor f(a, b, c) on (y^{t-1}=a, y^t=b, y^{t+1}=c).

    prev, cur, nxt: (J, M, 3) hypotheses of frames t-1, t, t+1. steps: the times from t-1 to t
    and from t to t+1, in nominal frame periods (the period temporal_scale is defined for). The
    prediction of y^t is the constant-velocity point between a and c at the time of t,
    a + s0 / (s0 + s1) (c - a), and the kernel scale is temporal_scale x (s0 + s1) / 2, so a
    longer step tolerates a proportionally larger deviation; steps (1, 1) is the evenly spaced
    factor, midpoint and temporal_scale. Returns (J, M, M, M) indexed [j, a, c, b]: the centre
    state is last so that messages contract with plain matmuls.
    """
    s0, s1 = (float(s) for s in steps)
    if not (s0 > 0 and s1 > 0):
        raise ValueError(f'temporal steps must be positive, got {steps}')
    if s0 == s1:
        mid = 0.5 * (prev[:, :, None, :] + nxt[:, None, :, :])  # (J, Ma, Mc, 3)
    else:
        w = s0 / (s0 + s1)
        mid = prev[:, :, None, :] + w * (nxt[:, None, :, :] - prev[:, :, None, :])
    scale = config.temporal_scale if s0 == s1 == 1.0 else config.temporal_scale * 0.5 * (s0 + s1)
    j, ma, mc = mid.shape[:3]
    mid = mid.reshape(j, ma * mc, 3)
    mb = cur.shape[1]
    # |b - mid|^2 = [mid, |mid|^2, 1] . [-2b, 1, |b|^2]: the whole M^3 part is one batched matmul
    # (sums and broadcasts over rows of only M elements took longer than the product)
    left = np.empty((j, ma * mc, 5))
    left[..., :3] = mid
    left[..., 3] = np.einsum('jkd,jkd->jk', mid, mid)
    left[..., 4] = 1.0
    right = np.empty((j, 5, mb))
    right[:, :3] = -2.0 * cur.transpose(0, 2, 1)
    right[:, 3] = 1.0
    right[:, 4] = np.einsum('jbd,jbd->jb', cur, cur)
    sq = left @ right  # every M^3 step below works in place, the arrays being large
    # squared distances in float64 (the expansion cancels), the kernel in float32 like the table
    table = np.maximum(sq, 0.0, out=sq).astype(np.float32)
    if config.temporal_form == 'laplace':
        np.sqrt(table, out=table)
        table *= np.float32(-1.0 / scale)
    else:
        table *= np.float32(-0.5 / scale ** 2)
    np.exp(table, out=table)
    return _normalised(table.reshape(j, ma, mc, mb), axes=(1, 2, 3))


def pair_distances(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """All distances between the hypotheses of two joints: (..., M, 3) x (..., N, 3) -> (..., M, N).
    Coordinate by coordinate, each step on whole (..., M, N) arrays: a norm over a last axis of 3
    took 3.5 times as long (the same sums, in the same order)."""
    a, b = np.moveaxis(a, -1, 0), np.moveaxis(b, -1, 0)
    d = a[0][..., :, None] - b[0][..., None, :]
    sq = d * d
    for k in (1, 2):
        np.subtract(a[k][..., :, None], b[k][..., None, :], out=d)
        d *= d
        sq += d
    return np.sqrt(sq, out=sq)


def collision_table(right: np.ndarray, left: np.ndarray, config: FactorConfig) -> np.ndarray:
    """Sigmoid repulsion between a left/right joint pair: ~0 when they coincide, ~1 far apart.

    right, left: (..., M, 3). Returns (..., M, M) indexed [right state, left state].
    """
    d = pair_distances(right, left)
    table = 1.0 / (1.0 + np.exp((config.collision_centre - d) / config.collision_width))
    return _normalised(table, axes=(-2, -1))


def limb_table(d: np.ndarray, length: np.ndarray, config: FactorConfig) -> np.ndarray:
    """Plausible bone lengths between two connected joints: flat within config.limb_range times
    the bone's typical length, a Gaussian of std limb_sigma in the excess beyond. It does not pull
    a limb to a length, it rules out impossible ones (a wrist 0.5 m from its elbow: two views
    agreeing on a wrong keypoint).

    d: (..., E, M, M) distances between the hypotheses of each bone's endpoints (pair_distances);
    length: (E,) typical bone lengths in metres (body.LIMB_LENGTHS). Returns (..., E, M, M).
    """
    low, high = config.limb_range
    excess = np.maximum(np.maximum(d - high * length[:, None, None], low * length[:, None, None] - d), 0.0)
    return _normalised(np.exp(-0.5 * (excess / config.limb_sigma) ** 2), axes=(-2, -1))
