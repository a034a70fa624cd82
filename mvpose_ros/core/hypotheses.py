"""Discrete 3D hypotheses for each joint, sampled from the heatmaps of several views.

For every subset (size >= 2) of the cameras that see a joint, pixels are drawn from each
camera's heatmap taken as a probability mass function, back-projected to rays, and the point
closest to the rays is a hypothesis (paper section 3.2). The M hypotheses of a joint are spread
over its subsets. Beyond the paper, each subset can also contribute the triangulation of the
heatmap peaks, so the most likely point is never left to chance.
"""
from __future__ import annotations

import itertools
from dataclasses import dataclass
from typing import Sequence

import numpy as np

from mvpose_ros.core.camera import Camera, closest_point_to_rays
from mvpose_ros.core.heatmap import PersonHeatmap


@dataclass(frozen=True)
class SamplingConfig:
    """hypotheses: M per joint; peak_hypotheses: add one peak triangulation per camera subset."""

    hypotheses: int = 64
    peak_hypotheses: bool = True

    def __post_init__(self) -> None:
        if self.hypotheses < 1:
            raise ValueError(f'hypotheses must be >= 1, got {self.hypotheses}')


def camera_subsets(cameras: Sequence[int], min_size: int = 2) -> list[tuple[int, ...]]:
    """All subsets of `cameras` with at least `min_size` members, largest first."""
    return [s for k in range(len(cameras), min_size - 1, -1) for s in itertools.combinations(cameras, k)]


def split_draws(total: int, n_subsets: int) -> np.ndarray:
    """Share `total` draws over subsets as evenly as possible, the remainder to the first ones."""
    counts = np.full(n_subsets, total // n_subsets)
    counts[: total % n_subsets] += 1
    return counts


def sample_hypotheses(
    views: Sequence[tuple[Camera, PersonHeatmap]],
    rng: np.random.Generator,
    config: SamplingConfig,
) -> np.ndarray | None:
    """Hypotheses (J, M, 3) in metres for one person, or None when no joint is seen twice.

    A joint seen by a single camera gets points on that camera's sampled rays at the depth
    closest to the person's centre (so it stays near the body instead of being dropped); a joint
    seen by none gets the centre itself.
    """
    m = config.hypotheses
    peaks = np.stack([hm.peak() for _, hm in views])  # (C, J, 3)
    n_joints = peaks.shape[1]
    seen = peaks[..., 2] > 0  # (C, J)
    out = np.full((n_joints, m, 3), np.nan)
    patterns: dict[tuple[int, ...], list[int]] = {}
    for j in range(n_joints):
        patterns.setdefault(tuple(np.flatnonzero(seen[:, j])), []).append(j)

    pools = [hm.sample(rng, m) for _, hm in views]  # (J, m, 2) per camera
    rays = [cam.rays(pool) for (cam, _), pool in zip(views, pools)]
    peak_rays = [cam.rays(p[:, :2]) for (cam, _), p in zip(views, peaks)]

    for cams, joints in patterns.items():
        if len(cams) >= 2:
            out[joints] = _triangulate_subsets(cams, joints, rays, peak_rays, m, config.peak_hypotheses)
    if np.all(np.isnan(out)):
        return None
    centre = np.nanmean(out.reshape(-1, 3), axis=0)
    for cams, joints in patterns.items():
        if len(cams) == 1:
            origin, direction = (r[joints] for r in rays[cams[0]])
            depth = np.einsum('jmd,jmd->jm', centre - origin, direction)
            out[joints] = origin + depth[..., None] * direction
        elif not cams:
            out[joints] = centre
    return out


def _triangulate_subsets(cams, joints, rays, peak_rays, m, with_peaks) -> np.ndarray:
    """(len(joints), m, 3) hypotheses of joints that share the camera set `cams`."""
    subsets = camera_subsets(cams)
    n_peaks = len(subsets) if with_peaks and len(subsets) <= m else 0
    counts = split_draws(m - n_peaks, len(subsets))
    used = dict.fromkeys(cams, 0)
    by_size: dict[int, list[tuple[np.ndarray, np.ndarray]]] = {}
    for subset, n in zip(subsets, counts):
        if n == 0:
            continue
        o = np.stack([rays[c][0][joints, used[c]:used[c] + n] for c in subset], axis=-2)
        d = np.stack([rays[c][1][joints, used[c]:used[c] + n] for c in subset], axis=-2)
        for c in subset:
            used[c] += n
        by_size.setdefault(len(subset), []).append((o, d))
    parts = [closest_point_to_rays(np.concatenate([o for o, _ in group], axis=1),
                                   np.concatenate([d for _, d in group], axis=1))
             for group in by_size.values()]
    peaks = []
    if n_peaks:
        o = np.stack([r[0][joints] for r in peak_rays], axis=1)  # (J', V, 3)
        d = np.stack([r[1][joints] for r in peak_rays], axis=1)
        # one solve per subset size; subsets come largest first, so their order is kept
        for size in sorted({len(s) for s in subsets}, reverse=True):
            same = np.array([s for s in subsets if len(s) == size])  # (S, size)
            peaks.append(closest_point_to_rays(o[:, same], d[:, same]))  # (J', S, 3)
    return np.concatenate(peaks + parts, axis=1)
