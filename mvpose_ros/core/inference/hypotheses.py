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

from mvpose_ros.core.geometry.body import INFERENCE_PARENT, PRIOR_BONE_LENGTH
from mvpose_ros.core.geometry.camera import Camera, line_terms, solve_line_terms
from mvpose_ros.core.heatmap import HeatmapStack, PersonHeatmap


SINGLE_VIEW_DEPTHS = ('centre', 'limb')


@dataclass(frozen=True)
class SamplingConfig:
    """hypotheses: M per joint; peak_hypotheses: add one peak triangulation per camera subset;
    single_view_depth: where on its rays a joint seen by one camera is put, 'centre' (the depth
    nearest the person's centre) or 'limb' (where the ray meets the sphere of the bone's typical
    length around the parent joint, when the parent is seen twice; else as 'centre')."""

    hypotheses: int = 64
    peak_hypotheses: bool = True
    single_view_depth: str = 'limb'

    def __post_init__(self) -> None:
        if self.hypotheses < 1:
            raise ValueError(f'hypotheses must be >= 1, got {self.hypotheses}')
        if self.single_view_depth not in SINGLE_VIEW_DEPTHS:
            raise ValueError(f'single_view_depth must be one of {SINGLE_VIEW_DEPTHS}, got {self.single_view_depth!r}')


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
    closest to the person's centre (so it stays near the body instead of being dropped) or, with
    single_view_depth 'limb', at its bone's length from its parent; a joint seen by none gets the
    centre itself.
    """
    m = config.hypotheses
    n_views, n_joints = stack.start.shape
    if n_views == 0:
        return []
    n_maps = n_views * n_joints
    first_view = np.concatenate([[0], np.cumsum([len(v) for v in people])]).astype(np.intp)
    # each view's draws in order, u (J, m) then jitter (J, m, 2), from its person's generator: one
    # call per person gives the same stream as a call per array
    u = np.empty((n_views, n_joints, m))
    jitter = np.empty((n_views, n_joints, m, 2))
    for p, rng in enumerate(rngs):
        lo, hi = first_view[p], first_view[p + 1]
        draws = rng.random((hi - lo, 3 * n_joints * m))
        u[lo:hi] = draws[:, :n_joints * m].reshape(-1, n_joints, m)
        jitter[lo:hi] = draws[:, n_joints * m:].reshape(-1, n_joints, m, 2)
    peaks = stack.peak()  # (V, J, 3)

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
    # Rays are made only for the draws a hypothesis uses (a camera of a joint seen by 5 uses ~23
    # of its m): first every map's peak (ray v * J + j), then each map's first need[v, j] draws.
    need = np.zeros((n_views, n_joints), dtype=np.intp)
    plans = []
    for p, cams, joints in groups:
        if len(cams) >= 2:
            plan = _plan(len(cams), m, config.peak_hypotheses, width)
            need[cams[:, None], joints] = plan[2][:, None]
            plans.append((p, cams, joints, plan))
        elif len(cams) == 1:
            need[cams[0], joints] = m  # every draw, for the rays of a single view (below)
    first_draw = n_maps + np.concatenate([[0], np.cumsum(need.ravel())[:-1]]).reshape(n_views, n_joints)
    maps = np.repeat(np.arange(n_maps), need.ravel())
    k = np.arange(len(maps)) - (first_draw.ravel() - n_maps)[maps]  # each draw's index within its map
    pixels = np.concatenate([peaks[..., :2].reshape(-1, 2),
                             stack.sample_at(maps, u.reshape(n_maps, m)[maps, k],
                                             jitter.reshape(n_maps, m, 2)[maps, k])])  # (R, 2)
    view = np.concatenate([np.arange(n_maps), maps]) // n_joints  # (R,)
    dirs = np.empty((len(pixels), 3))
    centres = np.empty((n_views, 3))
    cameras = [cam for views in people for cam, _ in views]
    rig = list({id(c): c for c in cameras}.values())
    camera_of = np.array([next(i for i, r in enumerate(rig) if r is c) for c in cameras])[view]  # (R,)
    for i, cam in enumerate(rig):
        mine = camera_of == i
        dirs[mine] = cam.directions(pixels[mine])
        centres[[v for v, c in enumerate(cameras) if c is cam]] = cam.centre

    out = np.full((len(people), n_joints, m, 3), np.nan)
    if plans:
        # each ray's share of the normal equations once, then per hypothesis the sum of its rays'
        # shares and one solve for the whole frame; the last column is no ray at all (zeros), for
        # the slots where a subset is padded to K cameras
        terms = np.zeros((9, len(dirs) + 1))
        line_terms(centres[view], dirs, out=terms[:, :-1])
        ray = np.concatenate([_rays(cams[cam_of], joints, draw, m, n_joints, first_draw)
                              for _, cams, joints, (cam_of, draw, _) in plans])  # (Q, m, K)
        ray = np.ascontiguousarray(np.moveaxis(ray, -1, 0))  # (K, Q, m): one gather per camera slot
        summed = terms[:, ray[0]]  # (9, Q, m)
        for slot in ray[1:]:
            summed += terms[:, slot]
        pp = np.concatenate([np.full(len(joints), p) for p, _, joints, _ in plans])
        pj = np.concatenate([joints for _, _, joints, _ in plans])
        out[pp, pj] = solve_line_terms(summed, width)  # (Q, m, 3)

    results: list[np.ndarray | None] = []
    for p in range(len(people)):
        hyp = out[p]
        if np.all(np.isnan(hyp)):
            results.append(None)
            continue
        centre = np.nanmean(hyp.reshape(-1, 3), axis=0)
        anchors = _anchors(hyp, config) if config.single_view_depth == 'limb' else None
        for q, cams, joints in groups:
            if q != p:
                continue
            if len(cams) == 1:
                origin = centres[cams[0]]
                direction = dirs[first_draw[cams[0], joints][:, None] + np.arange(m)]  # (joints, m, 3)
                depth = direction @ (centre - origin)
                if config.single_view_depth == 'limb':
                    depth = _limb_depths(depth, direction, origin, joints, anchors)
                hyp[joints] = origin + depth[..., None] * direction
            elif len(cams) == 0:
                hyp[joints] = centre
        results.append(hyp)
    return results


def _anchors(hyp: np.ndarray, config: SamplingConfig) -> np.ndarray:
    """(J, 3) best single point of each joint seen by >= 2 cameras (NaN for the others): with
    peaks, its first hypothesis (the peak triangulation of all its cameras when the peaks fit in
    M), else the median of its hypotheses."""
    if config.peak_hypotheses:
        return hyp[:, 0].copy()
    out = np.full((len(hyp), 3), np.nan)
    seen = ~np.isnan(hyp[:, 0, 0])
    out[seen] = np.median(hyp[seen], axis=1)
    return out


def _limb_depths(depth: np.ndarray, direction: np.ndarray, origin: np.ndarray, joints: np.ndarray,
                 anchors: np.ndarray) -> np.ndarray:
    """Depths (n, m) along single-view rays direction (n, m, 3) from origin (3,) of `joints` (n,)
    where each ray meets the sphere of its bone's length around its parent's anchor (anchors
    (J, 3)); of the two, the one nearer the given depth (the person's centre). A ray missing the
    sphere takes its point nearest the parent; a joint without a located parent keeps `depth`."""
    parent = INFERENCE_PARENT[joints]
    length = PRIOR_BONE_LENGTH[joints]
    anchor = anchors[np.maximum(parent, 0)]  # (n, 3)
    rel = anchor - origin
    mid = np.einsum('nmd,nd->nm', direction, rel)  # depth of the point nearest the parent
    half = np.sqrt(np.maximum(mid ** 2 - np.einsum('nd,nd->n', rel, rel)[:, None] + length[:, None] ** 2, 0.0))
    near, far = mid - half, mid + half
    limb = np.where(np.abs(near - depth) <= np.abs(far - depth), near, far)
    located = (parent >= 0) & ~np.isnan(anchor[:, 0]) & ~np.isnan(length)
    return np.where(located[:, None], limb, depth)


def _rays(views: np.ndarray, joints: np.ndarray, draw: np.ndarray, m: int, n_joints: int,
          first_draw: np.ndarray) -> np.ndarray:
    """Ray indices (joints, m, K) of the hypotheses of `joints` from a plan's views (m, K) and
    draws (m, K) (draw m: the peak, ray v * J + j; -1: padding, the zero column -1)."""
    j = joints[:, None, None]
    ray = np.where(draw == m, views * n_joints + j, first_draw[views, j] + draw)
    return np.where(draw < 0, -1, ray)


@functools.lru_cache(maxsize=256)
def _plan(n_cams: int, m: int, with_peaks: bool, width: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Which rays make each of the m hypotheses of a joint seen by cameras 0..n_cams-1: camera
    (m, K) and draw (m, K) indices (draw m is the peak's ray; -1 where a subset smaller than
    K = width (>= n_cams) is padded), and how many draws of each camera are used (n_cams,):
    draws 0 .. used - 1. First one peak triangulation per subset (when they fit in m), then the
    m - peaks draws shared evenly over the subsets, each camera's draws used once."""
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
    return cam_of, draw, np.array(used, dtype=np.intp)
