"""Per-frame multi-view association: tracking in each camera, matching across cameras, 3D ids.

This is the work of the association node: it turns each camera's 2D skeletons of one instant
into people seen by at least two cameras, each with a stable id, and (single_view_people) into
the people two cameras saw within the last `id_memory` seconds of frames that one camera alone sees now.
"""
from __future__ import annotations

import itertools
from dataclasses import dataclass, field
from typing import Generic, Sequence, TypeVar

import numpy as np

from mvpose_ros.core.compiled import kernel, kernel_array, pairwise_sum
from mvpose_ros.core.geometry.camera import Camera
from mvpose_ros.core.geometry.rays import line_terms_into, solve_line_terms_into
from mvpose_ros.core.association.identity import IdentityKeeper
from mvpose_ros.core.association.matching import MatchingConfig, ViewRays, all_view_distances, cluster_views
from mvpose_ros.core.types import Keypoints2D
from mvpose_ros.core.association.tracking import IouTracker
from mvpose_ros.core.association.view_consistency import consistent_views


@dataclass(frozen=True)
class AssociationConfig:
    """track_iou: the paper's 0.7; max_jump (m), max_speed (m/s), id_memory (s): how far from where
    it was last seen a person keeps its id, and how long the frames may go without an id before it
    is forgotten (identity);
    max_view_residual: a matched view the others contradict by more than this share of its size is
    left out (view_consistency; 0: every matched view kept); single_view_people: a view no other
    camera's matches keeps the id its track had (identity.IdentityKeeper.continue_alone), so that a
    person one camera alone sees for a while is still there (the solver places him from where he
    was)."""

    track_iou: float = 0.7
    matching: MatchingConfig = field(default_factory=MatchingConfig)
    max_jump: float = 0.5
    max_speed: float = 2.5
    id_memory: float = 1.0
    max_view_residual: float = 0.1
    single_view_people: bool = True

    def __post_init__(self) -> None:
        if not 0 < self.track_iou <= 1:
            raise ValueError(f'track_iou must be in (0, 1], got {self.track_iou}')
        if not (self.max_jump > 0 and self.max_speed >= 0 and self.id_memory >= 0):
            raise ValueError(f'max_jump must be > 0, max_speed and id_memory >= 0, got {self.max_jump}, '
                             f'{self.max_speed}, {self.id_memory}')
        if not self.max_view_residual >= 0:
            raise ValueError(f'max_view_residual must be >= 0, got {self.max_view_residual}')


P = TypeVar('P', bound=Keypoints2D)  # the 2D people associated: Person2D, or as they came on the wire


@dataclass
class PersonObservation(Generic[P]):
    """One person at one instant: the skeleton seen by each camera (index into the rig) and the
    rough 3D centre (metres; NaN for a person one camera alone sees: single_view_people)."""

    person_id: int
    views: dict[int, P]
    centre: np.ndarray


@kernel('float64[:, ::1](float64[:, :, ::1], float64[:, ::1], float64[:, :, ::1], int64[:, ::1], float64)')
def _rough_centres(keypoints, origins, dirs, idx, min_score):
    """rough_centres of people's views idx (P, K) (-1: padding) of the rays of ViewRays, with the
    arithmetic of rays.closest_point_to_rays (directions normalised again, each term summed
    over the K lines in numpy's pairwise order), so the same bits."""
    n_people, width = idx.shape
    n_joints = keypoints.shape[1]
    out = np.empty((n_people, 3))
    direction = np.empty(3)
    terms = np.zeros((width, 9))  # each line's share (0: not seen)
    column = np.empty(width)
    summed = np.empty(9)
    point = np.empty(3)
    for p in range(n_people):
        total = np.zeros(3)
        located = 0
        for j in range(n_joints):
            terms[:] = 0.0
            seen = 0
            for k in range(width):
                row = idx[p, k]
                if row >= 0 and keypoints[row, j, 2] > min_score:
                    d = dirs[row, j]
                    norm = np.sqrt(d[0] * d[0] + d[1] * d[1] + d[2] * d[2])
                    for i in range(3):
                        direction[i] = d[i] / norm
                    line_terms_into(origins[row], direction, terms[k])
                    seen += 1
            if seen < 2:
                continue
            for i in range(9):
                column[:] = terms[:, i]
                summed[i] = pairwise_sum(column)
            solve_line_terms_into(summed, 1e-12 * width ** 3, point)
            for i in range(3):
                total[i] += point[i]
            located += 1
        out[p] = total / (located if located else np.nan)
    return out


def rough_centres(rays: ViewRays, people: Sequence[Sequence[int]], min_score: float) -> np.ndarray:
    """(P, 3) per person (the indices in `rays` of its views): the mean of the joints triangulated
    from the keypoints of every view, metres; NaN where no joint is seen twice. All people in one
    call."""
    width = max((len(v) for v in people), default=0)
    if width == 0:
        return np.full((len(people), 3), np.nan)
    idx = np.full((len(people), width), -1, dtype=np.int64)
    for p, views in enumerate(people):
        idx[p, :len(views)] = views
    return _rough_centres(kernel_array(rays.keypoints, np.float64),
                          kernel_array(rays.origins, np.float64),
                          kernel_array(rays.dirs, np.float64), idx, float(min_score))


class Associator:
    """Stateful association over a stream of synchronised frames from a fixed rig."""

    def __init__(self, cameras: Sequence[Camera | None], config: AssociationConfig) -> None:
        """cameras: the rig in order; None for a camera not known yet (its people must be None),
        to be filled in `cameras` once it is."""
        self.cameras = list(cameras)
        self.config = config
        self._trackers = [IouTracker(config.track_iou) for _ in self.cameras]
        self._ids = IdentityKeeper(config.max_jump, config.max_speed, config.id_memory)

    def retune(self, config: AssociationConfig) -> None:
        """New thresholds for the frames after this; the tracks and identities so far are kept."""
        self.config = config
        for tracker in self._trackers:
            tracker.min_iou = config.track_iou

    def update(self, time_s: float, people: Sequence[Sequence[P] | None]) -> list[PersonObservation[P]]:
        """people[c]: camera c's skeletons at this instant, time_s seconds (non-decreasing), or None
        when that camera is missing."""
        present = [list(p) if p is not None else [] for p in people]
        for tracker, skeletons, raw in zip(self._trackers, present, people):
            if raw is not None:
                tracker.update(skeletons)
        rays = ViewRays.of(self.cameras, present)
        dist = all_view_distances(self.cameras, present, self.config.matching, rays)
        clusters = cluster_views(self.cameras, present, self.config.matching, rays, dist)
        first = [0, *itertools.accumulate(len(p) for p in present)]
        rows = consistent_views(self.cameras, rays, [[first[c] + i for c, i in cl.items()] for cl in clusters],
                                self.config.matching.min_score, self.config.max_view_residual)
        skeleton = [p for ps in present for p in ps]  # by row of rays
        owner = rays.owner.tolist()
        centres = rough_centres(rays, rows, self.config.matching.min_score)
        keep = np.flatnonzero(np.isfinite(centres).all(axis=1)).tolist()
        rows, centres = [rows[i] for i in keep], centres[keep].reshape(-1, 3)
        members = [{(owner[r], skeleton[r].track_id) for r in rs} for rs in rows]
        ids = self._ids.assign(time_s, members, centres)
        if len(set(ids)) < len(ids):
            rows, centres, ids = self._merge_seen_twice(dist, rays, rows, ids)
        if self.config.single_view_people:  # views no other camera's matched (not those the view check left)
            matched = {first[c] + i for cl in clusters for c, i in cl.items()}
            alone = [r for r in range(len(skeleton)) if r not in matched]
            kept = self._ids.continue_alone([(owner[r], skeleton[r].track_id) for r in alone], set(ids))
            alone, kept = [r for r, pid in zip(alone, kept) if pid >= 0], [pid for pid in kept if pid >= 0]
            rows, ids = rows + [[r] for r in alone], ids + kept
            centres = np.vstack([centres, np.full((len(alone), 3), np.nan)])
        return [PersonObservation(i, {owner[r]: skeleton[r] for r in rs}, c) for i, rs, c in zip(ids, rows, centres)]

    def _merge_seen_twice(self, dist: np.ndarray, rays: ViewRays, rows: list[list[int]],
                          ids: list[int]) -> tuple[list[list[int]], np.ndarray, list[int]]:
        """The people sharing an id (one person seen twice: identity) as one: every camera's view,
        and of a camera with two the one whose rays pass closer to the other cameras' on average
        (dist: the frame's all_view_distances)."""
        owner = rays.owner
        merged: dict[int, list[int]] = {}
        for pid, rs in zip(ids, rows):
            merged.setdefault(pid, []).extend(rs)
        out = []
        for views in merged.values():
            kept = []
            for camera in dict.fromkeys(owner[views].tolist()):
                mine = [v for v in views if owner[v] == camera]
                others = [v for v in views if owner[v] != camera]
                near = dist[np.ix_(mine, others)]
                finite = np.isfinite(near)
                counts = finite.sum(axis=1)
                mean = np.where(counts > 0, np.where(finite, near, 0.0).sum(axis=1) / np.maximum(counts, 1), np.inf)
                kept.append(mine[int(np.argmin(mean))])
            out.append(kept)
        new_centres = rough_centres(rays, out, self.config.matching.min_score)
        return out, new_centres, list(merged)

    @property
    def identities(self) -> IdentityKeeper:
        """The person ids' keeper (its state outlives a restart: IdentityKeeper.state / restore)."""
        return self._ids
