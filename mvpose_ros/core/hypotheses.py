"""Discrete 3D hypotheses for each joint, sampled from the heatmaps of several views.

For every subset (size >= 2) of the cameras that see a joint, pixels are drawn from each
camera's heatmap taken as a probability mass function, back-projected to rays, and the point
closest to the rays is a hypothesis (paper section 3.2). The M hypotheses of a joint are spread
over its subsets. Beyond the paper, each subset can also contribute the triangulation of the
heatmap peaks, so the most likely point is never left to chance.
"""
from __future__ import annotations

import functools
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

    # every camera's m sampled pixels per joint plus its peak as draw m: one back-projection each
    pixels = [np.concatenate([hm.sample(rng, m), p[:, None, :2]], axis=1) for (_, hm), p in zip(views, peaks)]
    rays = [cam.rays(px) for (cam, _), px in zip(views, pixels)]
    origins = np.stack([r[0] for r in rays])  # (C, J, m + 1, 3)
    dirs = np.stack([r[1] for r in rays])

    for cams, joints in patterns.items():
        if len(cams) >= 2:
            cam_of, draw, weight = _plan(len(cams), m, config.peak_hypotheses)  # (m, K) each
            view = np.asarray(cams)[cam_of][None]
            jj = np.asarray(joints)[:, None, None]
            out[joints] = closest_point_to_rays(origins[view, jj, draw[None]], dirs[view, jj, draw[None]], weight)
    if np.all(np.isnan(out)):
        return None
    centre = np.nanmean(out.reshape(-1, 3), axis=0)
    for cams, joints in patterns.items():
        if len(cams) == 1:
            origin, direction = origins[cams[0], joints, :m], dirs[cams[0], joints, :m]
            depth = np.einsum('jmd,jmd->jm', centre - origin, direction)
            out[joints] = origin + depth[..., None] * direction
        elif not cams:
            out[joints] = centre
    return out


@functools.lru_cache(maxsize=64)
def _plan(n_cams: int, m: int, with_peaks: bool) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Which rays make each of the m hypotheses of a joint seen by cameras 0..n_cams-1: camera
    (m, K) and draw (m, K) indices (draw m is the peak's ray) and weights (m, K), 0 where a
    subset smaller than K = n_cams is padded. First one peak triangulation per subset (when they
    fit in m), then the m - peaks draws shared evenly over the subsets, each camera's draws used
    once."""
    subsets = camera_subsets(range(n_cams))
    n_peaks = len(subsets) if with_peaks and len(subsets) <= m else 0
    rows = [(s, [m] * len(s)) for s in subsets[:n_peaks]]
    used = [0] * n_cams
    for subset, n in zip(subsets, split_draws(m - n_peaks, len(subsets))):
        rows += [(subset, [used[c] + k for c in subset]) for k in range(n)]
        for c in subset:
            used[c] += n
    cam_of = np.zeros((m, n_cams), dtype=np.intp)
    draw = np.zeros((m, n_cams), dtype=np.intp)
    weight = np.zeros((m, n_cams))
    for i, (subset, draws) in enumerate(rows):
        cam_of[i, :len(subset)] = subset
        draw[i, :len(subset)] = draws
        weight[i, :len(subset)] = 1.0
    return cam_of, draw, weight
