"""Views of a matched person that the other views contradict, left out before 3D.

A camera that sees a person half hidden behind someone else can give a skeleton drawn partly on
the other body: close enough on average to match, yet its joints tens of pixels from where the
other views put them; with few views it outvotes the truth. For a person seen by three or more
cameras, the view whose removal leaves the others most consistent is left out when its residual
(median pixel distance to the others' triangulation, over its size) exceeds `max_residual` and
theirs; the check repeats while three or more views remain. Why and how it was chosen:
docs/method.md#views-the-others-contradict."""
from __future__ import annotations

from typing import Sequence

import numpy as np

from mvpose_ros.core.association.matching import ViewRays
from mvpose_ros.core.compiled import kernel, kernel_array
from mvpose_ros.core.geometry.camera import Camera
from mvpose_ros.core.geometry.projection import project_point, rig_model
from mvpose_ros.core.geometry.rays import line_terms_into, solve_line_terms_into


@kernel('float64(float64[::1])')
def _median(values):
    """The median of values (sorted in place); NaN when there are none. By insertion: for the few
    joints of a skeleton, numba's sort costs ten times as much (it allocates its stack)."""
    n = len(values)
    if n == 0:
        return np.nan
    for i in range(1, n):
        x = values[i]
        k = i
        while k > 0 and values[k - 1] > x:
            values[k] = values[k - 1]
            k -= 1
        values[k] = x
    return 0.5 * (values[(n - 1) // 2] + values[n // 2])


@kernel('void(float64[:, :, ::1], int64[::1], float64[:, ::1], float64[:, :, ::1], int64[::1], int64, float64, '
        'float64[:, ::1], float64[:, ::1])')
def _person_residuals(keypoints, owner, origins, dirs, views, width, min_score, model, out):
    """leave_one_out_residuals of one person into out[:width, :width], its views the rows
    views[:width] of the rays of ViewRays (-1: padding), and the rig's projection.rig_model (C, 27).
    width: the most views of any person of the call (it scales the singularity threshold)."""
    n_joints = keypoints.shape[1]
    seen = np.zeros((width, n_joints), dtype=np.bool_)
    terms = np.zeros((width, n_joints, 9))
    total = np.zeros((n_joints, 9))
    without = np.empty(9)
    points = np.empty((n_joints, 3))
    size = np.full(width, np.nan)
    error = np.empty(n_joints)
    for k in range(width):
        row = views[k]
        if row < 0:
            continue
        lo_u = lo_v = np.inf
        hi_u = hi_v = -np.inf
        for j in range(n_joints):
            if keypoints[row, j, 2] > min_score:
                seen[k, j] = True
                line_terms_into(origins[row], dirs[row, j], terms[k, j])
                for i in range(9):
                    total[j, i] += terms[k, j, i]
                u, v = keypoints[row, j, 0], keypoints[row, j, 1]
                if u == u:  # NaN skipped, as fmin / fmax do
                    lo_u, hi_u = min(lo_u, u), max(hi_u, u)
                if v == v:
                    lo_v, hi_v = min(lo_v, v), max(hi_v, v)
        if hi_u >= lo_u and hi_v >= lo_v:
            extent = np.hypot(hi_u - lo_u, hi_v - lo_v)
            if extent > 0:
                size[k] = extent
    for left_out in range(width):  # a padding one leaves nothing out
        for j in range(n_joints):
            others = 0  # views seeing joint j besides left_out
            for k in range(width):
                if seen[k, j] and k != left_out:
                    others += 1
            if others < 2:
                points[j] = np.nan
            else:
                for i in range(9):
                    without[i] = total[j, i] - terms[left_out, j, i]
                solve_line_terms_into(without, 1e-12 * width ** 3, points[j])
        for k in range(width):
            row = views[k]
            if row < 0:
                out[left_out, k] = np.nan
                continue
            c = owner[row]
            n = 0
            for j in range(n_joints):
                if seen[k, j]:
                    u, v = project_point(model, c, points[j, 0], points[j, 1], points[j, 2])
                    du, dv = u - keypoints[row, j, 0], v - keypoints[row, j, 1]
                    e = np.sqrt(du * du + dv * dv)
                    if np.isfinite(e):
                        error[n] = e
                        n += 1
            out[left_out, k] = _median(error[:n]) / size[k]


@kernel('void(float64[:, :, ::1], int64[::1], float64[:, ::1], float64[:, :, ::1], int64[:, ::1], float64, '
        'float64[:, ::1], float64[:, :, ::1])')
def _residuals(keypoints, owner, origins, dirs, idx, min_score, model, out):
    """leave_one_out_residuals into out (P, K, K) of people's views idx (P, K) (-1: padding)."""
    for p in range(len(idx)):
        _person_residuals(keypoints, owner, origins, dirs, idx[p], idx.shape[1], min_score, model, out[p])


@kernel('void(float64[:, :, ::1], int64[::1], float64[:, ::1], float64[:, :, ::1], int64[:, ::1], int64[::1], '
        'float64, float64, float64[:, ::1])')
def _leave_out_contradicted(keypoints, owner, origins, dirs, idx, lengths, min_score, max_residual, model):
    """consistent_views on people's views idx (P, K) (-1: padding), lengths (P,) views each: both
    updated in place. Each round decides for every person still checked at once, with the
    residuals of a batch as wide as its widest person (as leave_one_out_residuals of them)."""
    n_people, most = idx.shape
    r = np.empty((most, most))
    left_out = np.empty(most)
    spread = np.empty(most)
    active = lengths >= 3
    while active.any():
        width = 0
        for p in range(n_people):
            if active[p]:
                width = max(width, lengths[p])
        for p in range(n_people):
            if not active[p]:
                continue
            _person_residuals(keypoints, owner, origins, dirs, idx[p], width, min_score, model, r)
            worst = -1  # the view whose leaving out leaves the others most consistent
            for k in range(width):
                left_out[k] = r[k, k]
                spread[k] = -np.inf  # worst residual of the rest
                for v in range(width):
                    if v != k and not np.isnan(r[k, v]):
                        spread[k] = max(spread[k], r[k, v])
                if np.isfinite(left_out[k]) and np.isfinite(spread[k]) and (worst < 0 or spread[k] < spread[worst]):
                    worst = k
            active[p] = False
            if worst >= 0 and left_out[worst] > max_residual and spread[worst] < left_out[worst]:
                idx[p, worst:most - 1] = idx[p, worst + 1:].copy()
                idx[p, most - 1] = -1
                lengths[p] -= 1
                active[p] = lengths[p] >= 3


def leave_one_out_residuals(cameras: Sequence[Camera], rays: ViewRays, people: Sequence[Sequence[int]],
                            min_score: float) -> np.ndarray:
    """(P, K, K) residuals of each person's views (people[p]: the rows of `rays` of its views, K the
    most views of any person) against its joints triangulated without one view: [p, out, v] is the
    median over view v's joints scoring > min_score of the pixel distance between its keypoint and
    the joint triangulated from the views other than `out`, divided by view v's size (its keypoints'
    box diagonal); NaN for padding and where no such joint is seen twice without `out`."""
    width = max((len(v) for v in people), default=0)
    out = np.empty((len(people), width, width))
    if width == 0:
        return out
    idx = np.full((len(people), width), -1, dtype=np.int64)
    for p, views in enumerate(people):
        idx[p, :len(views)] = views
    _residuals(*_ray_arrays(rays), idx, float(min_score), rig_model(cameras), out)
    return out


def _ray_arrays(rays: ViewRays) -> tuple[np.ndarray, ...]:
    """keypoints, owner, origins and dirs of rays as the kernels take them."""
    return (kernel_array(rays.keypoints, np.float64), rays.owner.astype(np.int64),
            kernel_array(rays.origins, np.float64), kernel_array(rays.dirs, np.float64))


def consistent_views(cameras: Sequence[Camera], rays: ViewRays, people: Sequence[Sequence[int]],
                     min_score: float, max_residual: float) -> list[list[int]]:
    """people[p] (rows of `rays`, one per camera) without the views the others contradict (module
    docstring); each keeps at least two. max_residual <= 0 keeps every view."""
    if max_residual <= 0 or not any(len(v) >= 3 for v in people):
        return [list(v) for v in people]
    idx = np.full((len(people), max(len(v) for v in people)), -1, dtype=np.int64)
    for p, views in enumerate(people):
        idx[p, :len(views)] = views
    lengths = np.array([len(v) for v in people], dtype=np.int64)
    _leave_out_contradicted(*_ray_arrays(rays), idx, lengths, float(min_score), float(max_residual),
                            rig_model(cameras))
    return [row[:n] for row, n in zip(idx.tolist(), lengths.tolist())]
