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
from mvpose_ros.core.geometry.camera import Camera, line_terms, solve_line_terms


def leave_one_out_residuals(cameras: Sequence[Camera], rays: ViewRays, people: Sequence[Sequence[int]],
                            min_score: float) -> np.ndarray:
    """(P, K, K) residuals of each person's views (people[p]: the rows of `rays` of its views, K the
    most views of any person) against its joints triangulated without one view: [p, out, v] is the
    median over view v's joints scoring > min_score of the pixel distance between its keypoint and
    the joint triangulated from the views other than `out`, divided by view v's size (its keypoints'
    box diagonal); NaN for padding and where no such joint is seen twice without `out`."""
    width = max((len(v) for v in people), default=0)
    if width == 0:
        return np.zeros((len(people), 0, 0))
    idx = np.full((len(people), width), -1)
    for p, views in enumerate(people):
        idx[p, :len(views)] = views
    used = idx >= 0  # (P, K)
    kp = np.where(used[..., None, None], rays.keypoints[idx], np.nan)  # (P, K, J, 3)
    seen = used[..., None] & (kp[..., 2] > min_score)  # (P, K, J)
    # every line's share of the closest-point system once; without `out` = all minus its own
    terms = line_terms(rays.origins[idx][:, :, None], np.where(seen[..., None], rays.dirs[idx], 0.0))  # (9, P, K, J)
    terms *= seen
    points = solve_line_terms(terms.sum(axis=2, keepdims=True) - terms, width)  # (P, out, J, 3)
    points[seen.sum(axis=1, keepdims=True) - seen < 2] = np.nan
    camera = np.where(used, rays.owner[np.maximum(idx, 0)], -1)  # (P, K)
    pixels = np.full((len(people), width, width, seen.shape[2], 2), np.nan)  # (P, out, view, J, 2)
    for c, cam in enumerate(cameras):
        p, v = np.nonzero(camera == c)
        if len(p):
            pixels[p, :, v] = cam.project(points[p])
    error = np.linalg.norm(pixels - kp[:, None, ..., :2], axis=-1)  # (P, out, view, J)
    error = np.where(seen[:, None] & np.isfinite(error), error, np.inf)
    extent = [np.fmax.reduce(x, axis=-1) - np.fmin.reduce(x, axis=-1)
              for x in np.where(seen, np.moveaxis(kp[..., :2], -1, 0), np.nan)]  # u, v: (P, K) each
    size = np.hypot(*extent)
    return _median(error) / np.where(size > 0, size, np.nan)[:, None]


def _median(values: np.ndarray) -> np.ndarray:
    """Median over the last axis of the finite values (inf marks a missing one); NaN where none is.
    nanmedian goes through masked arrays: slower than the whole residual computation here."""
    ordered = np.sort(values, axis=-1)
    n = np.isfinite(ordered).sum(axis=-1)
    lo = np.take_along_axis(ordered, np.maximum((n - 1) // 2, 0)[..., None], axis=-1)[..., 0]
    hi = np.take_along_axis(ordered, (n // 2)[..., None], axis=-1)[..., 0]
    return np.where(n > 0, 0.5 * (lo + hi), np.nan)


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
