"""Views of a matched person that the other views contradict, left out before 3D.

Matching accepts a view when its rays pass within `match_distance` of the person's other views on
average, a bound loose enough for calibration error and for people near the image edge. A camera
that sees the person half hidden behind someone else can give a skeleton drawn partly on the
other body: close enough on average to match, yet its joints sit tens of pixels from where the other
views put them. With many views the data term outvotes it; with few, two views that agree by chance
(the bad one and one other) make hypotheses the data term prefers to the true point, which three
views see only roughly (frame 572 of Shelf without camera 3: actor 3's hip and knee 0.36-0.44 m off).

For a person seen by three or more cameras, its joints are triangulated once without each view
and every view is measured against each such triangulation: the median pixel distance between
its keypoints and the projected joints, over its size (the diagonal of its keypoints' box). The
view whose removal leaves the others most consistent (the smallest worst residual among them) is
left out when its own residual exceeds `max_residual` and theirs. Measuring each view only
against the others' triangulation would blame a good view: the bad one drags that triangulation
too. The check repeats while three or more views remain.
"""
from __future__ import annotations

from typing import Sequence

import numpy as np

from mvpose_ros.core.association.matching import ViewRays
from mvpose_ros.core.compiled import kernel
from mvpose_ros.core.geometry.camera import Camera

_NO_CAMERA = Camera('none', np.eye(3), np.eye(3), np.zeros(3), np.zeros(5), 1, 1)


@kernel('void(float64[::1], float64[::1], float64[::1])')
def _line_terms(origin, direction, out):
    """camera.line_terms of one line (origin, unit direction (3,)) into out (9,): I - d d^T as
    xx, xy, xz, yy, yz, zz, then o - d (d . o); the same arithmetic, so the same bits."""
    dx, dy, dz = direction[0], direction[1], direction[2]
    along = dx * origin[0] + dy * origin[1] + dz * origin[2]
    out[0] = -(dx * dx) + 1.0
    out[1] = -(dx * dy)
    out[2] = -(dx * dz)
    out[3] = -(dy * dy) + 1.0
    out[4] = -(dy * dz)
    out[5] = -(dz * dz) + 1.0
    out[6] = origin[0] - dx * along
    out[7] = origin[1] - dy * along
    out[8] = origin[2] - dz * along


@kernel('void(float64[::1], int64, float64[::1])')
def _solve_line_terms(terms, n_lines, out):
    """camera.solve_line_terms of summed terms (9,) into out (3,): the closest point by Cramer's
    rule, NaN where degenerate (n_lines: the most lines in any sum of the call)."""
    a00, a01, a02, a11, a12, a22, b0, b1, b2 = (terms[0], terms[1], terms[2], terms[3], terms[4], terms[5],
                                                terms[6], terms[7], terms[8])
    c00, c01, c02 = a11 * a22 - a12 * a12, a02 * a12 - a01 * a22, a01 * a12 - a02 * a11
    c11, c12, c22 = a00 * a22 - a02 * a02, a01 * a02 - a00 * a12, a00 * a11 - a01 * a01
    det = a00 * c00 + a01 * c01 + a02 * c02
    if not (np.isfinite(det) and np.isfinite(b0 + b1 + b2) and abs(det) > 1e-12 * n_lines ** 3):
        out[:] = np.nan
        return
    inv = 1.0 / det
    out[0] = (c00 * b0 + c01 * b1 + c02 * b2) * inv
    out[1] = (c01 * b0 + c11 * b1 + c12 * b2) * inv
    out[2] = (c02 * b0 + c12 * b1 + c22 * b2) * inv


@kernel('void(float64[::1], float64[:, ::1], float64[::1], float64[:, ::1], float64[::1], float64[::1])')
def _project(point, R, t, K, dist, out):
    """Camera.project of one point (3,) into out (2,) pixels, for a camera R (3, 3), t (3,), K (3, 3),
    dist (5,) k1, k2, p1, p2, k3: the same arithmetic, so the same bits; NaN at or behind it."""
    x, y, z = point[0], point[1], point[2]
    depth = R[2, 0] * x + R[2, 1] * y + R[2, 2] * z + t[2]
    inv = 1.0 / depth if depth > 0 else np.nan
    xn = (R[0, 0] * x + R[0, 1] * y + R[0, 2] * z + t[0]) * inv
    yn = (R[1, 0] * x + R[1, 1] * y + R[1, 2] * z + t[1]) * inv
    if np.any(dist != 0):
        k1, k2, p1, p2, k3 = dist[0], dist[1], dist[2], dist[3], dist[4]
        r2 = xn * xn + yn * yn
        radial = 1 + r2 * (k1 + r2 * (k2 + r2 * k3))
        xn, yn = (xn * radial + 2 * p1 * xn * yn + p2 * (r2 + 2 * xn * xn),
                  yn * radial + p1 * (r2 + 2 * yn * yn) + 2 * p2 * xn * yn)
    out[0] = K[0, 0] * xn + K[0, 1] * yn + K[0, 2]
    out[1] = K[1, 0] * xn + K[1, 1] * yn + K[1, 2]


@kernel('float64(float64[::1])')
def _median(values):
    """The median of values (sorted in place); NaN when there are none."""
    if len(values) == 0:
        return np.nan
    values.sort()
    n = len(values)
    return 0.5 * (values[(n - 1) // 2] + values[n // 2])


@kernel('void(float64[:, :, ::1], int64[::1], float64[:, ::1], float64[:, :, ::1], int64[:, ::1], float64, '
        'float64[:, :, ::1], float64[:, ::1], float64[:, :, ::1], float64[:, ::1], float64[:, :, ::1])')
def _residuals(keypoints, owner, origins, dirs, idx, min_score, R, t, K, dist, out):
    """leave_one_out_residuals into out (P, K, K), people's views idx (P, K) (-1: padding), the
    rays of ViewRays and the rig's R (C, 3, 3), t (C, 3), K (C, 3, 3), dist (C, 5)."""
    n_people, width = idx.shape
    n_joints = keypoints.shape[1]
    seen = np.zeros((width, n_joints), dtype=np.bool_)
    terms = np.zeros((width, n_joints, 9))
    total = np.zeros((n_joints, 9))
    without = np.empty(9)
    points = np.empty((n_joints, 3))
    pixel = np.empty(2)
    size = np.empty(width)
    error = np.empty(n_joints)
    for p in range(n_people):
        seen[:] = False
        terms[:] = 0.0
        total[:] = 0.0
        for k in range(width):
            row = idx[p, k]
            size[k] = np.nan
            if row < 0:
                continue
            lo_u = lo_v = np.inf
            hi_u = hi_v = -np.inf
            for j in range(n_joints):
                if keypoints[row, j, 2] > min_score:
                    seen[k, j] = True
                    _line_terms(origins[row], dirs[row, j], terms[k, j])
                    total[j] += terms[k, j]
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
                    without[:] = total[j] - terms[left_out, j]
                    _solve_line_terms(without, width, points[j])
            for k in range(width):
                row = idx[p, k]
                if row < 0:
                    out[p, left_out, k] = np.nan
                    continue
                c = owner[row]
                n = 0
                for j in range(n_joints):
                    if seen[k, j]:
                        _project(points[j], R[c], t[c], K[c], dist[c], pixel)
                        du, dv = pixel[0] - keypoints[row, j, 0], pixel[1] - keypoints[row, j, 1]
                        e = np.sqrt(du * du + dv * dv)
                        if np.isfinite(e):
                            error[n] = e
                            n += 1
                out[p, left_out, k] = _median(error[:n]) / size[k]


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
    rig = [cam if cam is not None else _NO_CAMERA for cam in cameras]  # one not known yet has no views
    _residuals(np.ascontiguousarray(rays.keypoints, dtype=np.float64), rays.owner.astype(np.int64),
               np.ascontiguousarray(rays.origins, dtype=np.float64), np.ascontiguousarray(rays.dirs, dtype=np.float64),
               idx, float(min_score), np.stack([cam.R for cam in rig]), np.stack([cam.t for cam in rig]),
               np.stack([cam.K for cam in rig]), np.stack([cam.dist for cam in rig]), out)
    return out


def consistent_views(cameras: Sequence[Camera], rays: ViewRays, people: Sequence[Sequence[int]],
                     min_score: float, max_residual: float) -> list[list[int]]:
    """people[p] (rows of `rays`, one per camera) without the views the others contradict (module
    docstring); each keeps at least two. max_residual <= 0 keeps every view."""
    kept = [list(v) for v in people]
    if max_residual <= 0:
        return kept
    active = [p for p, v in enumerate(kept) if len(v) >= 3]
    while active:
        r = leave_one_out_residuals(cameras, rays, [kept[p] for p in active], min_score)  # (A, out, view)
        left_out = np.diagonal(r, axis1=1, axis2=2)  # (A, K)
        spread = np.where(np.eye(r.shape[1], dtype=bool) | np.isnan(r), -np.inf, r).max(axis=2)  # worst of the rest
        candidate = np.isfinite(left_out) & np.isfinite(spread)
        worst = np.argmin(np.where(candidate, spread, np.inf), axis=1)  # (A,)
        out, rest = (np.take_along_axis(x, worst[:, None], axis=1)[:, 0] for x in (left_out, spread))
        drop = candidate.any(axis=1) & (out > max_residual) & (rest < out)
        for row in np.flatnonzero(drop):
            del kept[active[row]][worst[row]]
        active = [active[row] for row in np.flatnonzero(drop) if len(kept[active[row]]) >= 3]
    return kept
