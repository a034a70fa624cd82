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

from mvpose_ros.core.geometry.camera import Camera, line_terms, solve_line_terms
from mvpose_ros.core.heatmap import HeatmapStack, PersonHeatmap


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


View = tuple[Camera, PersonHeatmap]


def sample_people(people: Sequence[Sequence[View]], stack: HeatmapStack,
                  rngs: Sequence[np.random.Generator], config: SamplingConfig) -> list[np.ndarray | None]:
    """Hypotheses (J, M, 3) in metres of each person of a frame (None when no joint of theirs is
    seen twice), all people batched. people[p]: person p's views (camera, heatmap); stack: every
    view's heatmap, person after person; rngs[p]: person p's generator (draws per view in order,
    so a person's hypotheses do not depend on who else is in the frame).

    A joint seen by a single camera gets points on that camera's sampled rays at the depth
    closest to the person's centre (so it stays near the body instead of being dropped); a joint
    seen by none gets the centre itself.
    """
    m = config.hypotheses
    n_views, n_joints = stack.start.shape
    first_view = np.concatenate([[0], np.cumsum([len(v) for v in people])]).astype(np.intp)
    draws = [(rng.random((n_joints, m)), rng.random((n_joints, m, 2)))
             for rng, views in zip(rngs, people) for _ in views]
    if not draws:
        return []
    peaks = stack.peak()  # (V, J, 3)
    # every view's m sampled pixels per joint plus its peak as draw m: one back-projection per camera
    pixels = np.concatenate([stack.sample(np.stack([u for u, _ in draws]), np.stack([j for _, j in draws])),
                             peaks[:, :, None, :2]], axis=2)  # (V, J, m + 1, 2)
    dirs = np.empty(pixels.shape[:-1] + (3,))
    centres = np.empty((n_views, 3))
    cameras = [cam for views in people for cam, _ in views]
    for cam in {id(c): c for c in cameras}.values():
        idx = [v for v, c in enumerate(cameras) if c is cam]
        dirs[idx] = cam.directions(pixels[idx])
        centres[idx] = cam.centre

    # every (person, joint) seen by >= 2 cameras: its m rays per hypothesis, padded to K cameras
    seen = peaks[..., 2] > 0  # (V, J)
    groups: list[tuple[int, np.ndarray, np.ndarray]] = []  # (person, its views seeing the joints, joints)
    for p in range(len(people)):
        mine = seen[first_view[p]:first_view[p + 1]]
        key = (mine << np.arange(len(mine))[:, None]).sum(axis=0)  # (J,) bit c: view c sees the joint
        for pattern in np.unique(key):
            groups.append((p, first_view[p] + np.flatnonzero(mine[:, key == pattern][:, 0]),
                           np.flatnonzero(key == pattern)))
    width = max((len(cams) for _, cams, _ in groups), default=0)
    view_idx, draw_idx, joint_idx, rows = [], [], [], []
    for p, cams, joints in groups:
        if len(cams) >= 2:
            cam_of, draw = _plan(len(cams), m, config.peak_hypotheses, width)  # (m, K) each
            shape = (len(joints), m, width)
            view_idx.append(np.broadcast_to(cams[cam_of], shape))
            draw_idx.append(np.broadcast_to(draw, shape))
            joint_idx.append(joints)
            rows.append(np.stack([np.full(len(joints), p), joints], axis=1))
    out = np.full((len(people), n_joints, m, 3), np.nan)
    if rows:
        # each ray's share of the normal equations once, then per hypothesis the sum of its rays'
        # shares and one solve for the whole frame; the last column is no ray at all (zeros), for
        # the slots where a subset is padded to K cameras
        terms = np.zeros((9, dirs[..., 0].size + 1))
        rays = terms[:, :-1].reshape((9,) + dirs.shape[:-1])  # a view: each row's rays are contiguous
        assert np.shares_memory(rays, terms)
        line_terms(centres[:, None, None], dirs, out=rays)
        draw = np.concatenate(draw_idx)  # (Q, m, K)
        ray = (np.concatenate(view_idx) * n_joints + np.concatenate(joint_idx)[:, None, None]) * (m + 1) + draw
        ray[draw < 0] = -1
        ray = np.ascontiguousarray(np.moveaxis(ray, -1, 0))  # (K, Q, m): one gather per camera slot
        summed = terms[:, ray[0]]  # (9, Q, m)
        for slot in ray[1:]:
            summed += terms[:, slot]
        pp, pj = np.concatenate(rows).T
        out[pp, pj] = solve_line_terms(summed, width)  # (Q, m, 3)

    results: list[np.ndarray | None] = []
    for p in range(len(people)):
        hyp = out[p]
        if np.all(np.isnan(hyp)):
            results.append(None)
            continue
        centre = np.nanmean(hyp.reshape(-1, 3), axis=0)
        for q, cams, joints in groups:
            if q != p:
                continue
            if len(cams) == 1:
                origin, direction = centres[cams[0]], dirs[cams[0], joints, :m]
                depth = direction @ (centre - origin)
                hyp[joints] = origin + depth[..., None] * direction
            elif len(cams) == 0:
                hyp[joints] = centre
        results.append(hyp)
    return results


@functools.lru_cache(maxsize=256)
def _plan(n_cams: int, m: int, with_peaks: bool, width: int) -> tuple[np.ndarray, np.ndarray]:
    """Which rays make each of the m hypotheses of a joint seen by cameras 0..n_cams-1: camera
    (m, K) and draw (m, K) indices (draw m is the peak's ray; -1 where a subset smaller than
    K = width (>= n_cams) is padded). First one peak triangulation per subset (when they fit in
    m), then the m - peaks draws shared evenly over the subsets, each camera's draws used once."""
    subsets = camera_subsets(range(n_cams))
    n_peaks = len(subsets) if with_peaks and len(subsets) <= m else 0
    rows = [(s, [m] * len(s)) for s in subsets[:n_peaks]]
    used = [0] * n_cams
    for subset, n in zip(subsets, split_draws(m - n_peaks, len(subsets))):
        rows += [(subset, [used[c] + k for c in subset]) for k in range(n)]
        for c in subset:
            used[c] += n
    cam_of = np.zeros((m, width), dtype=np.intp)
    draw = np.full((m, width), -1, dtype=np.intp)
    for i, (subset, draws) in enumerate(rows):
        cam_of[i, :len(subset)] = subset
        draw[i, :len(subset)] = draws
    return cam_of, draw
