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
import math
from dataclasses import dataclass
from typing import Sequence

import numpy as np

from mvpose_ros.core.compiled import kernel, kernel_array
from mvpose_ros.core.geometry.body import (HANGING, INFERENCE_MIRROR, INFERENCE_PARENT, PLAUSIBLE_BONE_SCALE,
                                           PRIOR_BONE_LENGTH, UNSEEN_FROM, UNSEEN_FROM_SEEN, UNSEEN_RISE, UP)
from mvpose_ros.core.geometry.camera import Camera
from mvpose_ros.core.geometry.projection import rig_directions
from mvpose_ros.core.geometry.rays import closest_points_of_ray_sets
from mvpose_ros.core.heatmap import HeatmapStack, PersonHeatmap


SINGLE_VIEW_DEPTHS = ('centre', 'limb', 'own_limb')
UNSEEN_JOINTS = ('centre', 'body')


@dataclass(frozen=True)
class SamplingConfig:
    """hypotheses: M per joint; peak_hypotheses: add one peak triangulation per camera subset
    (with more subsets than M, of the largest ones, filling half of M);
    single_view_depth: where on its rays a joint seen by one camera is put, 'centre' (the depth
    nearest the person's centre), 'limb' (where the ray meets the sphere of the bone's typical
    adult length around the parent joint: around its best point when it is seen twice, around its
    hypothesis of the same index when it is seen once; else as 'centre', or as unseen_joints
    'body' below) or
    'own_limb' (as 'limb', with the person's own bone length: own_bone_lengths). Of the sphere's two
    crossings the one nearer the person's centre is taken, but with hanging_legs the lower one
    (along up) for a knee or ankle (body.HANGING);
    unseen_joints: where a joint no camera sees (out of every picture, or hidden in every view) is
    put, 'centre' (the person's centre) or 'body' (body.UNSEEN_RISE: a leg or arm joint hangs its
    bone's length straight down from its parent, the neck is the shoulders' midpoint, the nose or
    head top a head's height above the neck and each ear as high beside it, a shoulder the trunk's
    length above a hip a camera sees; lengths scaled to the person as for 'own_limb'; each of its
    hypotheses from its sources' hypotheses of the same index, wherever they are: an unseen
    shoulder whose hip no camera sees takes the centre). With 'body', a joint seen by one camera
    without a parent to hang from (hips, neck, head, ears; a shoulder whose neck no two cameras
    see) takes the depth on its rays nearest where that rule puts it from its sources' best points,
    when they are seen twice, instead of the depth nearest the centre."""

    hypotheses: int = 64
    peak_hypotheses: bool = True
    single_view_depth: str = 'own_limb'
    hanging_legs: bool = True
    unseen_joints: str = 'body'

    def __post_init__(self) -> None:
        if self.hypotheses < 1:
            raise ValueError(f'hypotheses must be >= 1, got {self.hypotheses}')
        if self.single_view_depth not in SINGLE_VIEW_DEPTHS:
            raise ValueError(f'single_view_depth must be one of {SINGLE_VIEW_DEPTHS}, got {self.single_view_depth!r}')
        if self.unseen_joints not in UNSEEN_JOINTS:
            raise ValueError(f'unseen_joints must be one of {UNSEEN_JOINTS}, got {self.unseen_joints!r}')


def camera_subsets(cameras: Sequence[int], min_size: int = 2, limit: int | None = None) -> list[tuple[int, ...]]:
    """The subsets of `cameras` with at least `min_size` members, largest first; with `limit`, only
    the first `limit` of them (a rig of n cameras has about 2^n)."""
    every = (s for k in range(len(cameras), min_size - 1, -1) for s in itertools.combinations(cameras, k))
    return list(itertools.islice(every, limit))


def subset_count(n_cameras: int, min_size: int = 2) -> int:
    """How many subsets of n_cameras cameras have at least `min_size` members."""
    return sum(math.comb(n_cameras, k) for k in range(min_size, n_cameras + 1))


def split_draws(total: int, n_subsets: int) -> np.ndarray:
    """Share `total` draws over subsets as evenly as possible, the remainder to the first ones."""
    counts = np.full(n_subsets, total // n_subsets)
    counts[: total % n_subsets] += 1
    return counts


View = tuple[Camera, PersonHeatmap]


def sample_people(people: Sequence[Sequence[View]], stack: HeatmapStack,
                  rngs: Sequence[np.random.Generator], config: SamplingConfig,
                  up: np.ndarray = UP, before: np.ndarray | None = None) -> list[np.ndarray | None]:
    """Hypotheses (J, M, 3) in metres of each person of a frame (None when no joint of theirs is
    seen twice and `before` gives none), all people batched. people[p]: person p's views (camera,
    heatmap); stack: every view's heatmap, person after person; rngs[p]: person p's generator
    (draws per view in order, so a person's hypotheses do not depend on who else is in the frame);
    up: (3,) the world's up; before: (P, 3) where each person was (NaN: unknown), the centre of
    a person none of whose joints is seen twice (one camera alone sees him), whose joints then
    all take their depths from it as joints seen once do.

    A joint seen by a single camera gets points on that camera's sampled rays at the depth
    closest to the person's centre (so it stays near the body instead of being dropped) or, with
    single_view_depth 'limb' / 'own_limb', at its bone's length from its parent; a joint seen by
    none gets the centre itself, or with unseen_joints 'body' a place on the body (SamplingConfig).
    """
    m = config.hypotheses
    n_views, n_joints = stack.start.shape
    if n_views == 0:
        return []
    n_people, n_maps = len(people), n_views * n_joints
    counts = np.array([len(v) for v in people], dtype=np.int64)
    first_view = np.concatenate([[0], np.cumsum(counts)]).astype(np.int64)
    peaks = stack.peak()  # (V, J, 3)

    # each (person, joint): how many of the person's views see it, and those views in order
    n_seen = np.empty((n_people, n_joints), dtype=np.int64)
    seeing = np.empty((n_people, counts.max(), n_joints), dtype=np.int64)
    _seeing(peaks, first_view, n_seen, seeing)
    width = int(n_seen.max())
    # Rays are made only for the draws a hypothesis uses (a camera of a joint seen by 5 uses ~23
    # of its m): first every map's peak (ray v * J + j), then each map's first draws, as many as
    # the plan of its joint's number of views uses (all m for a single view: its rays, below).
    cam_of, draw, used = _plans(m, config.peak_hypotheses, width)
    need = np.empty((n_views, n_joints), dtype=np.int64)
    first_draw = np.empty((n_views, n_joints), dtype=np.int64)
    n_draws = _needs(n_seen, seeing, used, m, need, first_draw)
    maps = np.empty(n_draws, dtype=np.int64)
    u = np.empty(n_draws)
    jitter = np.empty((n_draws, 2))
    # each view's draws in order, u (J, m) then jitter (J, m, 2), from its person's generator (one
    # call per person gives the same stream as a call per array), into one buffer: those kept are
    # copied out before the next person's overwrite them
    draws = np.empty((counts.max(), 3 * n_joints * m))
    for p, rng in enumerate(rngs):
        rng.random(out=draws[:counts[p]])
        _keep_draws(draws[:counts[p]], first_view[p], need, first_draw, maps, u, jitter)
    pixels = np.concatenate([peaks[..., :2].reshape(-1, 2), stack.sample_at(maps, u, jitter)])  # (R, 2)
    view = np.concatenate([np.arange(n_maps), maps]) // n_joints  # (R,)
    cameras = [cam for views in people for cam, _ in views]
    rig = list({id(c): c for c in cameras}.values())
    camera_of_view = np.array([next(i for i, r in enumerate(rig) if r is c) for c in cameras])  # (V,)
    dirs = rig_directions(rig, np.take(camera_of_view, view), pixels)  # (R, 3)
    centres = np.stack([cam.centre for cam in rig])[camera_of_view]  # (V, 3)

    out = np.full((n_people, n_joints, m, 3), np.nan)
    persons, joints = np.nonzero(n_seen >= 2)
    if len(persons):
        # the rays of each hypothesis, then one least-squares solve for the whole frame
        sets = np.empty((len(persons) * m, width), dtype=np.int64)
        _ray_sets(n_seen, seeing, first_draw, cam_of, draw, sets)
        out[persons, joints] = closest_points_of_ray_sets(centres, view, dirs, sets).reshape(-1, m, 3)
    # the joints seen by one camera or none, from the person's centre (mean hypothesis) and
    # the anchors of the joints seen twice
    located = np.empty(n_people, dtype=np.bool_)
    given = np.full((n_people, 3), np.nan) if before is None else kernel_array(before, np.float64)
    anchors = _anchors(out, config)
    scales = bone_scales(anchors) if config.single_view_depth == 'own_limb' else np.ones((n_people, n_joints))
    up = kernel_array(up, np.float64)
    # NaN: no place on the body for the joints seen once without a parent to hang from
    body_rise = kernel_array(UNSEEN_RISE * scales if config.unseen_joints == 'body' else np.full_like(scales, np.nan),
                             np.float64)
    _complete(out, n_seen, seeing, first_draw, dirs, centres, anchors, config.single_view_depth != 'centre',
              _PARENT, kernel_array(PRIOR_BONE_LENGTH * scales, np.float64), HANGING & config.hanging_legs, up,
              _PARENTS_FIRST, _UNSEEN_FROM, body_rise, given, located)
    if config.unseen_joints == 'body':
        _place_unseen(out, n_seen, located, _UNSEEN_FROM, _UNSEEN_FROM_SEEN, body_rise, up, _UNSEEN_ORDER)
    return [out[p] if located[p] else None for p in range(n_people)]


_PARENT = INFERENCE_PARENT.astype(np.int64)


def _depth(sources: np.ndarray, j: int) -> int:
    """How many joints lie below j on its longest chain of sources (sources (J, K): each joint's
    sources, -1 for none)."""
    return 0 if sources[j, 0] < 0 else 1 + max(_depth(sources, int(s)) for s in sources[j])


def _sources_first(sources: np.ndarray) -> np.ndarray:
    """(J,) the joints, each after its sources."""
    return np.array(sorted(range(len(sources)), key=lambda j: _depth(sources, j)), dtype=np.int64)


# joints parents first, so that a joint seen once can hang from a parent seen once, and the joints
# after those they are placed from when no camera sees them
_PARENTS_FIRST = _sources_first(_PARENT[:, None])
_UNSEEN_FROM = UNSEEN_FROM.astype(np.int64)
_UNSEEN_FROM_SEEN = kernel_array(UNSEEN_FROM_SEEN, np.bool_)
_UNSEEN_ORDER = _sources_first(np.where(UNSEEN_FROM_SEEN[:, None], -1, _UNSEEN_FROM))  # seen sources wait for none


def own_bone_lengths(anchors: np.ndarray) -> np.ndarray:
    """(P, J) metres: each person's length of the bone from each limb joint to its parent (NaN for
    the joints without one), as far as this frame shows it: the typical length times bone_scales.
    anchors: (P, J, 3) best point of each joint seen by two or more cameras (NaN for the others)."""
    return PRIOR_BONE_LENGTH * bone_scales(anchors)


def bone_scales(anchors: np.ndarray) -> np.ndarray:
    """(P, J) each person's size against the typical adult's, per joint, as far as this frame shows
    it. anchors: (P, J, 3) best point of each joint seen by two or more cameras (NaN for the others).

    A limb bone whose two ends are anchored is measured. A joint seen once is not, so its bone takes
    the ratio of its left/right counterpart where that is measured, else the person's scale: the
    median ratio of their measured bones to the typical lengths, with at least two measured (else
    1); the joints without a bone take the person's scale. A measured bone beyond
    PLAUSIBLE_BONE_SCALE times its typical length (a wrong anchor) is not used. Children and tall
    people thus keep their own proportions, which the typical length alone misplaces by up to the
    bone's length along a ray.
    """
    has_parent = INFERENCE_PARENT >= 0
    ratio = np.full(anchors.shape[:2], np.nan)  # (P, J) measured / typical length
    bone = anchors[:, has_parent] - anchors[:, INFERENCE_PARENT[has_parent]]
    ratio[:, has_parent] = np.linalg.norm(bone, axis=-1) / PRIOR_BONE_LENGTH[has_parent]
    low, high = PLAUSIBLE_BONE_SCALE
    ratio[~((ratio >= low) & (ratio <= high))] = np.nan
    # each person's median measured ratio (np.nanmedian's value at a tenth of its cost: NaN sorts last)
    n = np.count_nonzero(~np.isnan(ratio), axis=1)
    ordered, rows = np.sort(ratio, axis=1), np.arange(len(ratio))
    median = 0.5 * (ordered[rows, np.maximum(n - 1, 0) // 2] + ordered[rows, n // 2])
    scale = np.where(n >= 2, median, 1.0)
    counterpart = ratio[:, INFERENCE_MIRROR]
    return np.where(np.isnan(counterpart), scale[:, None], counterpart)


@kernel('void(float64[:, :, ::1], int64[::1], int64[:, ::1], int64[:, :, ::1])')
def _seeing(peaks, first_view, n_seen, seeing):
    # peaks (V, J, 3) -> per (person, joint) the number of its views with a peak, and those
    # views (P, K, J), in order
    for p in range(len(first_view) - 1):
        for j in range(peaks.shape[1]):
            n = 0
            for v in range(first_view[p], first_view[p + 1]):
                if peaks[v, j, 2] > 0:
                    seeing[p, n, j] = v
                    n += 1
            n_seen[p, j] = n


@kernel('int64(int64[:, ::1], int64[:, :, ::1], int64[:, ::1], int64, int64[:, ::1], int64[:, ::1])')
def _needs(n_seen, seeing, used, m, need, first_draw):
    # how many draws each map (V, J) uses (used[n, c]: of the c-th of n cameras; all m of a single
    # view), where its rays start (after the V * J peaks); their number
    n_views, n_joints = need.shape
    need[:] = 0
    for p in range(n_seen.shape[0]):
        for j in range(n_joints):
            n = n_seen[p, j]
            if n == 1:
                need[seeing[p, 0, j], j] = m
            for c in range(n if n >= 2 else 0):
                need[seeing[p, c, j], j] = used[n, c]
    r = 0
    for v in range(n_views):
        for j in range(n_joints):
            first_draw[v, j] = n_views * n_joints + r
            r += need[v, j]
    return r


@kernel('void(float64[:, ::1], int64, int64[:, ::1], int64[:, ::1], int64[::1], float64[::1], float64[:, ::1])')
def _keep_draws(draws, first_view, need, first_draw, maps, u, jitter):
    # the draws used of views first_view.. (draws (K views, 3 J m): u (J, m) then jitter (J, m, 2) of
    # each): their maps, u and jitter, at their place among all (first_draw)
    n_views, n_joints = need.shape
    m = draws.shape[1] // (3 * n_joints)
    for v in range(first_view, first_view + len(draws)):
        for j in range(n_joints):
            r = first_draw[v, j] - n_views * n_joints
            row = draws[v - first_view]
            for k in range(need[v, j]):
                maps[r + k] = v * n_joints + j
                u[r + k] = row[j * m + k]
                jitter[r + k, 0] = row[n_joints * m + 2 * (j * m + k)]
                jitter[r + k, 1] = row[n_joints * m + 2 * (j * m + k) + 1]


@kernel('void(int64[:, ::1], int64[:, :, ::1], int64[:, ::1], int64[:, :, ::1], int64[:, :, ::1], int64[:, ::1])')
def _ray_sets(n_seen, seeing, first_draw, cam_of, draw, out):
    # out (Q * m, K): per joint seen by n >= 2 views (person-major) and hypothesis h, its rays by
    # its plan (cam_of[n], draw[n]: (m, K)): a view's peak ray, a draw's ray, or -1 (padding)
    n_joints = n_seen.shape[1]
    m, width = draw.shape[1], draw.shape[2]
    row = 0
    for p in range(n_seen.shape[0]):
        for j in range(n_joints):
            n = n_seen[p, j]
            if n < 2:
                continue
            for h in range(m):
                for slot in range(width):
                    d = draw[n, h, slot]
                    v = seeing[p, cam_of[n, h, slot], j]
                    out[row, slot] = -1 if d < 0 else v * n_joints + j if d == m else first_draw[v, j] + d
                row += 1


@kernel('void(float64[:, :, :, ::1], int64[:, ::1], int64[:, :, ::1], int64[:, ::1], float64[:, ::1], '
        'float64[:, ::1], float64[:, :, ::1], boolean, int64[::1], float64[:, ::1], boolean[::1], float64[::1], '
        'int64[::1], int64[:, ::1], float64[:, ::1], float64[:, ::1], boolean[::1])')
def _complete(out, n_seen, seeing, first_draw, dirs, centres, anchors, limb, parents, lengths, hanging, up, order,
              body_from, body_rise, given, located):
    # out (P, J, m, 3) holding the joints seen twice: a person is located if it has any; its
    # centre is their mean (NaN-skipping, summed in order as numpy's nanmean), or else the given
    # centre (P, 3), when there is one (not NaN); a joint seen by
    # one view gets its m rays (dirs from the view's centre) at the depth nearest the centre
    # or, with limb, where they meet the sphere of the bone's length (lengths (P, J)) around the parent's
    # anchor, or around the parent's k-th point when the parent is seen once (order: parents first)
    # (the nearer of the two to the centre's depth, the lower along up for a hanging joint; a ray
    # missing it: its point nearest the parent); a joint seen by none, the centre. A joint seen
    # once without a parent to hang from takes the depth nearest where the body puts it from its
    # anchored sources (body_from, body_rise: _place_unseen's rule), or else nearest the centre.
    n_joints, m = out.shape[1], out.shape[2]
    for p in range(out.shape[0]):
        total = np.zeros(3)
        count = np.zeros(3)
        for j in range(n_joints):
            for k in range(m):
                for c in range(3):
                    x = out[p, j, k, c]
                    if np.isnan(x):
                        total[c] += 0.0
                    else:
                        total[c] += x
                        count[c] += 1
        located[p] = count[0] > 0 or count[1] > 0 or count[2] > 0
        if located[p]:
            centre = total / count
        elif not np.isnan(given[p, 0]):
            located[p] = True
            centre = given[p].copy()
        else:
            continue
        for j in order:
            if n_seen[p, j] == 0:
                for k in range(m):
                    out[p, j, k] = centre
            if n_seen[p, j] != 1:
                continue
            v = seeing[p, 0, j]
            o = centres[v]
            to_centre = centre - o
            rel = np.zeros(3)  # from the view's centre to the parent's anchor, for 'limb'
            length = lengths[p, j]
            on_limb = limb and parents[j] >= 0 and not np.isnan(length)
            chained = False
            if on_limb:
                rel = anchors[p, parents[j]] - o
                chained = np.isnan(rel[0]) and n_seen[p, parents[j]] == 1
                on_limb = not np.isnan(rel[0]) or chained
            rel_sq = (rel[0] * rel[0] + rel[2] * rel[2]) + rel[1] * rel[1]
            to_body = to_centre
            a, b = body_from[j, 0], body_from[j, 1]
            if not on_limb and a >= 0 and not np.isnan(body_rise[p, j]) and not np.isnan(anchors[p, a, 0]) \
                    and not np.isnan(anchors[p, b, 0]):
                to_body = 0.5 * (anchors[p, a] + anchors[p, b]) + body_rise[p, j] * up - o
            for k in range(m):
                d = dirs[first_draw[v, j] + k]
                if chained:
                    rel = out[p, parents[j], k] - o
                    rel_sq = (rel[0] * rel[0] + rel[2] * rel[2]) + rel[1] * rel[1]
                # dot products summed x, z, then y: numpy's einsum, for the same bits
                depth = (d[0] * to_body[0] + d[2] * to_body[2]) + d[1] * to_body[1]  # to_centre on a limb
                if on_limb:
                    mid = (d[0] * rel[0] + d[2] * rel[2]) + d[1] * rel[1]
                    half = np.sqrt(max(mid * mid - rel_sq + length * length, 0.0))
                    near, far = mid - half, mid + half
                    if hanging[j]:
                        # their heights differ by (near - far) times the ray's rise along up
                        rise = (d[0] * up[0] + d[2] * up[2]) + d[1] * up[1]
                        depth = near if rise * (near - far) <= 0.0 else far
                    else:
                        depth = near if np.abs(near - depth) <= np.abs(far - depth) else far
                for c in range(3):
                    out[p, j, k, c] = o[c] + depth * d[c]


@kernel('void(float64[:, :, :, ::1], int64[:, ::1], boolean[::1], int64[:, ::1], boolean[::1], float64[:, ::1], '
        'float64[::1], int64[::1])')
def _place_unseen(out, n_seen, located, sources, from_seen, rise, up, order):
    # out (P, J, m, 3) completed: each joint no view sees that has sources (the same joint twice
    # for one; placed before it, by order) goes rise (P, J) metres along up from their midpoint,
    # hypothesis by hypothesis, wherever they are (seen, placed so, or at the centre); a joint
    # flagged in from_seen only from sources a view sees
    m = out.shape[2]
    for p in range(out.shape[0]):
        if not located[p]:
            continue
        for j in order:
            a, b = sources[j, 0], sources[j, 1]
            if n_seen[p, j] > 0 or a < 0 or (from_seen[j] and (n_seen[p, a] == 0 or n_seen[p, b] == 0)):
                continue
            for k in range(m):
                for c in range(3):
                    out[p, j, k, c] = 0.5 * (out[p, a, k, c] + out[p, b, k, c]) + rise[p, j] * up[c]


def _anchors(hyp: np.ndarray, config: SamplingConfig) -> np.ndarray:
    """(P, J, 3) best single point of each joint seen by >= 2 cameras (NaN for the others) of
    hypotheses (P, J, M, 3): with peaks, its first hypothesis (the peak triangulation of all its
    cameras), else the median of its hypotheses."""
    if config.peak_hypotheses:
        return hyp[:, :, 0].copy()
    out = np.full(hyp.shape[:2] + (3,), np.nan)
    seen = ~np.isnan(hyp[:, :, 0, 0])
    out[seen] = np.median(hyp[seen], axis=1)
    return out


@functools.lru_cache(maxsize=256)
def _plan(n_cams: int, m: int, with_peaks: bool, width: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Which rays make each of the m hypotheses of a joint seen by cameras 0..n_cams-1: camera
    (m, K) and draw (m, K) indices (draw m is the peak's ray; -1 where a subset smaller than
    K = width (>= n_cams) is padded), and how many draws of each camera are used (n_cams,):
    draws 0 .. used - 1. Subsets largest first: one peak triangulation per subset (when more
    subsets than m, of the first half of m), then the m - peaks draws shared evenly over the
    subsets, each camera's draws used once."""
    # at most m subsets get a peak or a draw: listing all 2^n would grow fourfold with every two
    # more cameras
    subsets = camera_subsets(range(n_cams), limit=m)
    # past 6 cameras (M 64) not every subset's peak fits: the largest subsets' come first, so the
    # all-camera triangulation is always one (the anchor of joints seen once), and draws fill half
    n_peaks = (len(subsets) if subset_count(n_cams) <= m else (m + 1) // 2) if with_peaks else 0
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


@functools.lru_cache(maxsize=64)
def _plans(m: int, with_peaks: bool, width: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The _plan of every camera count n <= width, stacked: camera (width + 1, m, width) and draw
    (width + 1, m, width) indices, draws used of each camera (width + 1, width)."""
    cam_of = np.zeros((width + 1, m, width), dtype=np.int64)
    draw = np.full((width + 1, m, width), -1, dtype=np.int64)
    used = np.zeros((width + 1, width), dtype=np.int64)
    for n in range(2, width + 1):
        cam_of[n], draw[n], used[n, :n] = _plan(n, m, with_peaks, width)
    return cam_of, draw, used
