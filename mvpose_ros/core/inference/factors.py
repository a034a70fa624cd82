"""CRF factors over discrete 3D joint hypotheses: data, temporal, collision, limb length.

Every table is returned as float32 and scaled to sum to one (the paper normalises each factor
to a probability for numerical stability; a constant scale does not change BP marginals).
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Sequence

import numpy as np

from mvpose_ros.core.compiled import kernel, kernel_array, pairwise_sum
from mvpose_ros.core.geometry.body import PLAUSIBLE_BONE_SCALE
from mvpose_ros.core.geometry.camera import Camera
from mvpose_ros.core.geometry.projection import rig_project
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
    limb_range times its typical adult length (body.PLAUSIBLE_BONE_SCALE), and falls off as a
    Gaussian of std limb_sigma beyond (limb_table).
    """

    temporal_form: str = 'laplace'
    temporal_scale: float = 0.08
    collision_centre: float = 0.15
    collision_width: float = 0.10
    limb_sigma: float = 0.05
    limb_range: tuple[float, float] = PLAUSIBLE_BONE_SCALE

    def __post_init__(self) -> None:
        if self.temporal_form not in TEMPORAL_FORMS:
            raise ValueError(f'temporal_form must be one of {TEMPORAL_FORMS}, got {self.temporal_form!r}')
        low, high = self.limb_range
        if not 0 <= low <= high:
            raise ValueError(f'limb_range must be (low, high) with 0 <= low <= high, got {self.limb_range}')
        for name in ('temporal_scale', 'collision_width', 'limb_sigma'):
            if not getattr(self, name) > 0:
                raise ValueError(f'{name} must be positive, got {getattr(self, name)}')


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
                    total += pairwise_sum(values[first + 1:first + counts[p], j, k])
                elif counts[p] > 1:  # fewer than 8 to reduce: pairwise_sum's plain loop, inline
                    rest = 0.0
                    for v in range(first + 1, first + counts[p]):
                        rest += values[v, j, k]
                    total += rest
                row[k] = total / max(counts[p], 1)
            total = pairwise_sum(row)
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
    state is last so that BP sums along contiguous rows (bp._update_temporal).
    """
    s0, s1 = (float(s) for s in steps)
    if not (s0 > 0 and s1 > 0):
        raise ValueError(f'temporal steps must be positive, got {steps}')
    scale = config.temporal_scale if s0 == s1 == 1.0 else config.temporal_scale * 0.5 * (s0 + s1)
    laplace = config.temporal_form == 'laplace'
    coef = np.float32(-1.0 / scale) if laplace else np.float32(-0.5 / scale ** 2)
    return _temporal_table(*(kernel_array(h, np.float64) for h in (prev, cur, nxt)),
                           s0 == s1, s0 / (s0 + s1), coef, laplace)


@kernel('void(float32[::1], float64[::1], float64[::1])')
def _exp(x, poly, scale):
    """x[:] = exp(x) in place, evaluated in float64 and rounded to float32 (so mostly libm's
    correctly rounded expf), as loops that compile to vector instructions, which a call of expf
    per entry does not: exp(r) 2^k with k = round(x / ln 2), r = x - k ln 2 (|r| <= ln 2 / 2) by
    its Taylor series to r^10 (relative error below 5e-13 in float64), 2^k from its bits. poly, scale: (N,) scratch.
    Arguments below -700 (exp < 1e-304, 0 in float32) are taken as -700."""
    n = len(x)
    for i in range(n):
        y = max(np.float64(x[i]), -700.0)
        k = np.floor(y * 1.4426950408889634 + 0.5)
        r = (y - k * 0.6931471803691238) - k * 1.9082149292705877e-10
        p = 1.0 / 3628800.0
        p = p * r + 1.0 / 362880.0
        p = p * r + 1.0 / 40320.0
        p = p * r + 1.0 / 5040.0
        p = p * r + 1.0 / 720.0
        p = p * r + 1.0 / 120.0
        p = p * r + 1.0 / 24.0
        p = p * r + 1.0 / 6.0
        p = p * r + 0.5
        p = p * r + 1.0
        poly[i] = p * r + 1.0
        # k + 1023 as the low bits of a float64 in [2^52, 2^53): moved to the exponent field, 2^k
        scale[i] = k + (4503599627370496.0 + 1023.0)
    bits = scale[:n].view(np.int64)
    for i in range(n):
        bits[i] = (bits[i] - 0x4330000000000000) << 52
    for i in range(n):
        x[i] = np.float32(poly[i] * scale[i])


@kernel('float32[:, :, :, ::1](float64[:, :, ::1], float64[:, :, ::1], float64[:, :, ::1], boolean, float64, '
        'float32, boolean)')
def _temporal_table(prev, cur, nxt, even, w, coef, laplace):
    """temporal_table's (J, Ma, Mc, Mb) table, entry by entry in float32 from the squared
    distance in float64: exp(coef sqrt(d^2)) (laplace) or exp(coef d^2), each joint's table
    scaled to sum to one (summed in float64). even: the midpoint (a + c) / 2, else a + w (c - a)."""
    n_j, ma, mb, mc = prev.shape[0], prev.shape[1], cur.shape[1], nxt.shape[1]
    out = np.empty((n_j, ma, mc, mb), np.float32)
    size = ma * mc * mb
    scratch = np.empty((2, size))
    tiny = np.finfo(np.float32).tiny
    coords = np.empty((3, mb))  # cur[j] by coordinate: contiguous rows
    xs, ys, zs = coords[0], coords[1], coords[2]
    for j in range(n_j):
        for b in range(mb):
            xs[b], ys[b], zs[b] = cur[j, b, 0], cur[j, b, 1], cur[j, b, 2]
        for a in range(ma):
            for c in range(mc):
                row = out[j, a, c]
                p, n = prev[j, a], nxt[j, c]
                if even:
                    mx, my, mz = 0.5 * (p[0] + n[0]), 0.5 * (p[1] + n[1]), 0.5 * (p[2] + n[2])
                else:
                    mx, my, mz = p[0] + w * (n[0] - p[0]), p[1] + w * (n[1] - p[1]), p[2] + w * (n[2] - p[2])
                for b in range(mb):
                    dx = xs[b] - mx
                    dy = ys[b] - my
                    dz = zs[b] - mz
                    row[b] = np.float32(dx * dx + dy * dy + dz * dz)
        flat = out[j].reshape(size)
        if laplace:
            for i in range(size):
                flat[i] = np.sqrt(flat[i]) * coef
        else:
            for i in range(size):
                flat[i] *= coef
        _exp(flat, scratch[0], scratch[1])
        lanes = scratch[0, :mb]
        lanes[:] = 0.0
        for i in range(0, size, mb):
            for b in range(mb):
                lanes[b] += flat[i + b]
        total = max(np.float32(lanes.sum()), tiny)
        for i in range(size):
            flat[i] /= total
    return out


def pair_distances(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """All distances between the hypotheses of two joints: (..., M, 3) x (..., N, 3) -> (..., M, N)."""
    lead = np.broadcast_shapes(a.shape[:-2], b.shape[:-2])
    n = math.prod(lead)
    a, b = (kernel_array(x if x.shape[:-2] == lead else np.broadcast_to(x, lead + x.shape[-2:]),
                         np.float64).reshape(n, x.shape[-2], 3) for x in (a, b))
    return _pair_distances(a, b).reshape(lead + (a.shape[1], b.shape[1]))


@kernel('float64[:, :, ::1](float64[:, :, ::1], float64[:, :, ::1])')
def _pair_distances(a, b):
    """(N, M, K) distances between (N, M, 3) and (N, K, 3), their squares summed x, y, z in turn."""
    n, m, k = a.shape[0], a.shape[1], b.shape[1]
    out = np.empty((n, m, k))
    for i in range(n):
        for x in range(m):
            for y in range(k):
                dx = a[i, x, 0] - b[i, y, 0]
                dy = a[i, x, 1] - b[i, y, 1]
                dz = a[i, x, 2] - b[i, y, 2]
                out[i, x, y] = np.sqrt(dx * dx + dy * dy + dz * dz)
    return out


@kernel('void(float64[::1], float32[::1])')
def _normalise_into(table, out):
    """out = table / its sum (at least float32's tiny), in float32: one factor's (S,) table scaled
    to sum to one, numpy's sum to the bit."""
    total = max(pairwise_sum(table), np.float64(np.finfo(np.float32).tiny))
    for i in range(len(table)):
        out[i] = table[i] / total


def collision_table(right: np.ndarray, left: np.ndarray, config: FactorConfig) -> np.ndarray:
    """Sigmoid repulsion between a left/right joint pair: ~0 when they coincide, ~1 far apart.

    right, left: (..., M, 3). Returns (..., M, M) indexed [right state, left state].
    """
    d = pair_distances(right, left)
    return _collision_table(d.reshape((math.prod(d.shape[:-2]),) + d.shape[-2:]), config.collision_centre,
                            config.collision_width).reshape(d.shape)


@kernel('float32[:, :, ::1](float64[:, :, ::1], float64, float64)')
def _collision_table(d, centre, width):
    """collision_table of (N, M, K) distances, each (M, K) table normalised."""
    n, size = d.shape[0], d.shape[1] * d.shape[2]
    out = np.empty(d.shape, np.float32)
    table = np.empty(size)
    for i in range(n):
        flat = d[i].reshape(size)
        for x in range(size):
            table[x] = 1.0 / (1.0 + np.exp((centre - flat[x]) / width))
        _normalise_into(table, out[i].reshape(size))
    return out


def limb_table(d: np.ndarray, length: np.ndarray, config: FactorConfig) -> np.ndarray:
    """Plausible bone lengths between two connected joints: flat within config.limb_range times
    the bone's typical length, a Gaussian of std limb_sigma in the excess beyond. It does not pull
    a limb to a length, it rules out impossible ones (a wrist 0.5 m from its elbow: two views
    agreeing on a wrong keypoint).

    d: (..., E, M, M) distances between the hypotheses of each bone's endpoints (pair_distances);
    length: (E,) typical bone lengths in metres (body.LIMB_LENGTHS). Returns (..., E, M, M).
    """
    low, high = config.limb_range
    flat = kernel_array(d, np.float64).reshape((math.prod(d.shape[:-3]),) + d.shape[-3:])
    return _limb_table(flat, kernel_array(length, np.float64), low, high,
                       config.limb_sigma).reshape(d.shape)


@kernel('float32[:, :, :, ::1](float64[:, :, :, ::1], float64[::1], float64, float64, float64)')
def _limb_table(d, length, low, high, sigma):
    """limb_table of (N, E, M, K) distances, each (M, K) table normalised."""
    n, n_e, size = d.shape[0], d.shape[1], d.shape[2] * d.shape[3]
    out = np.empty(d.shape, np.float32)
    table = np.empty(size)
    for i in range(n):
        for e in range(n_e):
            flat = d[i, e].reshape(size)
            longest, shortest = high * length[e], low * length[e]
            for x in range(size):
                excess = max(max(flat[x] - longest, shortest - flat[x]), 0.0)
                q = excess / sigma
                table[x] = np.exp(-0.5 * (q * q))
            _normalise_into(table, out[i, e].reshape(size))
    return out
