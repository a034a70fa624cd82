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
from mvpose_ros.core.geometry.camera import Camera, line_terms, rig_directions, solve_line_terms
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
    n_people, n_maps = len(people), n_views * n_joints
    counts = np.array([len(v) for v in people], dtype=np.intp)
    first_view = np.concatenate([[0], np.cumsum(counts)]).astype(np.intp)
    owner = np.repeat(np.arange(n_people), counts)  # (V,) each view's person
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

    # each (person, joint): how many of the person's views see it, and those views in order
    sees = np.zeros((n_people, counts.max(), n_joints), dtype=bool)
    sees[owner, np.arange(n_views) - first_view[owner]] = peaks[..., 2] > 0
    n_seen = sees.sum(axis=1)  # (P, J)
    seeing = first_view[:-1, None, None] + np.argsort(~sees, axis=1, kind='stable')  # (P, K, J) views, seeing first
    width = int(n_seen.max())
    # Rays are made only for the draws a hypothesis uses (a camera of a joint seen by 5 uses ~23
    # of its m): first every map's peak (ray v * J + j), then each map's first need[v, j] draws.
    # The joints seen by n >= 2 views share one plan of which rays make each hypothesis.
    need = np.zeros((n_views, n_joints), dtype=np.intp)
    plans = []  # (plan, persons (Q,), joints (Q,), views (Q, n)) per n
    for n in range(2, width + 1):
        pp, pj = np.nonzero(n_seen == n)
        if len(pp):
            views = seeing[pp, :n, pj]
            plan = _plan(n, m, config.peak_hypotheses, width)
            need[views, pj[:, None]] = plan[2]
            plans.append((plan, pp, pj, views))
    single_p, single_j = np.nonzero(n_seen == 1)
    single_view = seeing[single_p, 0, single_j]
    need[single_view, single_j] = m  # every draw, for the rays of a single view (below)
    first_draw = n_maps + np.concatenate([[0], np.cumsum(need.ravel())[:-1]]).reshape(n_views, n_joints)
    maps = np.repeat(np.arange(n_maps), need.ravel())
    k = np.arange(len(maps)) - (first_draw.ravel() - n_maps)[maps]  # each draw's index within its map
    pixels = np.concatenate([peaks[..., :2].reshape(-1, 2),
                             stack.sample_at(maps, u.reshape(n_maps, m)[maps, k],
                                             jitter.reshape(n_maps, m, 2)[maps, k])])  # (R, 2)
    view = np.concatenate([np.arange(n_maps), maps]) // n_joints  # (R,)
    cameras = [cam for views in people for cam, _ in views]
    rig = list({id(c): c for c in cameras}.values())
    camera_of_view = np.array([next(i for i, r in enumerate(rig) if r is c) for c in cameras])  # (V,)
    dirs = rig_directions(rig, camera_of_view[view], pixels)  # (R, 3)
    centres = np.stack([cam.centre for cam in rig])[camera_of_view]  # (V, 3)

    out = np.full((n_people, n_joints, m, 3), np.nan)
    if plans:
        # each ray's share of the normal equations once, then per hypothesis the sum of its rays'
        # shares and one solve for the whole frame; the last column is no ray at all (zeros), for
        # the slots where a subset is padded to K cameras
        terms = np.zeros((9, len(dirs) + 1))
        line_terms(centres[view], dirs, out=terms[:, :-1])
        ray = np.concatenate([_rays(plan_views[:, cam_of], plan_joints, draw, m, n_joints, first_draw)
                              for (cam_of, draw, _), _, plan_joints, plan_views in plans])  # (Q, m, K)
        ray = np.ascontiguousarray(np.moveaxis(ray, -1, 0))  # (K, Q, m): one gather per camera slot
        summed = terms[:, ray[0]]  # (9, Q, m)
        for slot in ray[1:]:
            summed += terms[:, slot]
        persons = np.concatenate([plan_persons for _, plan_persons, _, _ in plans])
        joints = np.concatenate([plan_joints for _, _, plan_joints, _ in plans])
        out[persons, joints] = solve_line_terms(summed, width)  # (Q, m, 3)

    located = ~np.isnan(out).all(axis=(1, 2, 3))  # (P,) anyone with a joint seen twice
    centre = np.full((n_people, 3), np.nan)
    centre[located] = np.nanmean(out[located].reshape(-1, n_joints * m, 3), axis=1)
    # a joint seen by a single camera: its m rays, each at a depth chosen below
    keep = located[single_p]
    single_p, single_j, single_view = single_p[keep], single_j[keep], single_view[keep]
    origin = centres[single_view]  # (S, 3)
    direction = dirs[first_draw[single_view, single_j][:, None] + np.arange(m)]  # (S, m, 3)
    depth = np.einsum('smd,sd->sm', direction, centre[single_p] - origin)
    if config.single_view_depth == 'limb':
        depth = _limb_depths(depth, direction, origin, single_p, single_j, _anchors(out, config))
    out[single_p, single_j] = origin[:, None] + depth[..., None] * direction
    unseen_p, unseen_j = np.nonzero((n_seen == 0) & located[:, None])
    out[unseen_p, unseen_j] = centre[unseen_p, None]
    return [out[p] if located[p] else None for p in range(n_people)]


def _anchors(hyp: np.ndarray, config: SamplingConfig) -> np.ndarray:
    """(P, J, 3) best single point of each joint seen by >= 2 cameras (NaN for the others) of
    hypotheses (P, J, M, 3): with peaks, its first hypothesis (the peak triangulation of all its
    cameras when the peaks fit in M), else the median of its hypotheses."""
    if config.peak_hypotheses:
        return hyp[:, :, 0].copy()
    out = np.full(hyp.shape[:2] + (3,), np.nan)
    seen = ~np.isnan(hyp[:, :, 0, 0])
    out[seen] = np.median(hyp[seen], axis=1)
    return out


def _limb_depths(depth: np.ndarray, direction: np.ndarray, origin: np.ndarray, persons: np.ndarray,
                 joints: np.ndarray, anchors: np.ndarray) -> np.ndarray:
    """Depths (n, m) along single-view rays direction (n, m, 3) from origin (n, 3) of joints
    `joints` (n,) of `persons` (n,) where each ray meets the sphere of its bone's length around its
    parent's anchor (anchors (P, J, 3)); of the two, the one nearer the given depth (the person's
    centre). A ray missing the sphere takes its point nearest the parent; a joint without a
    located parent keeps `depth`."""
    parent = INFERENCE_PARENT[joints]
    length = PRIOR_BONE_LENGTH[joints]
    anchor = anchors[persons, np.maximum(parent, 0)]  # (n, 3)
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
