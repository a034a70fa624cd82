"""Per-frame multi-view association: tracking in each camera, matching across cameras, 3D ids.

This is the work of the association node: it turns each camera's 2D skeletons of one instant
into people seen by at least two cameras, each with a stable id.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import Sequence

import numpy as np

from mvpose_ros.core.geometry.camera import Camera, closest_point_to_rays
from mvpose_ros.core.association.identity import IdentityKeeper
from mvpose_ros.core.association.matching import MatchingConfig, ViewRays, cluster_views
from mvpose_ros.core.types import Person2D
from mvpose_ros.core.association.tracking import IouTracker
from mvpose_ros.core.association.view_consistency import consistent_views


@dataclass(frozen=True)
class AssociationConfig:
    """track_iou: the paper's 0.7; max_jump / max_age: how an id is recovered after occlusion;
    max_view_residual: a matched view the others contradict by more than this share of its size is
    left out (view_consistency; 0: every matched view kept)."""

    track_iou: float = 0.7
    matching: MatchingConfig = field(default_factory=MatchingConfig)
    max_jump: float = 0.5
    max_age: int = 25
    max_view_residual: float = 0.1

    def __post_init__(self) -> None:
        if not 0 < self.track_iou <= 1:
            raise ValueError(f'track_iou must be in (0, 1], got {self.track_iou}')
        if not (self.max_jump > 0 and self.max_age >= 0):
            raise ValueError(f'max_jump must be > 0 and max_age >= 0, got {self.max_jump}, {self.max_age}')
        if not self.max_view_residual >= 0:
            raise ValueError(f'max_view_residual must be >= 0, got {self.max_view_residual}')


@dataclass
class PersonObservation:
    """One person at one instant: the skeleton seen by each camera (index into the rig)."""

    person_id: int
    views: dict[int, Person2D]
    centre: np.ndarray


def rough_centres(rays: ViewRays, people: Sequence[Sequence[int]], min_score: float) -> np.ndarray:
    """(P, 3) per person (the indices in `rays` of its views): the mean of the joints triangulated
    from the keypoints of every view, metres; NaN where no joint is seen twice. All people in one
    call."""
    width = max((len(v) for v in people), default=0)
    if width == 0:
        return np.full((len(people), 3), np.nan)
    idx = np.full((len(people), width), -1)
    for p, views in enumerate(people):
        idx[p, :len(views)] = views
    used = idx >= 0  # (P, K)
    n_j = rays.keypoints.shape[1]
    origins = np.broadcast_to(np.where(used[..., None], rays.origins[idx], 0.0)[:, None], (len(people), n_j, width, 3))
    dirs = np.where(used[:, :, None, None], rays.dirs[idx], 0.0).transpose(0, 2, 1, 3)  # (P, J, K, 3)
    seen = (used[:, :, None] & (rays.keypoints[idx, :, 2] > min_score)).transpose(0, 2, 1)  # (P, J, K)
    twice = seen.sum(axis=-1) >= 2  # (P, J)
    points = closest_point_to_rays(origins, dirs, seen)  # (P, J, 3)
    points[~twice] = np.nan
    with np.errstate(invalid='ignore'):
        total = np.where(twice[..., None], points, 0.0).sum(axis=1)
        return total / np.where(twice.any(axis=1), twice.sum(axis=1), np.nan)[:, None]


class Associator:
    """Stateful association over a stream of synchronised frames from a fixed rig."""

    def __init__(self, cameras: Sequence[Camera | None], config: AssociationConfig) -> None:
        """cameras: the rig in order; None for a camera not known yet (its people must be None),
        to be filled in `cameras` once it is."""
        self.cameras = list(cameras)
        self.config = config
        self._trackers = [IouTracker(config.track_iou) for _ in self.cameras]
        self._ids = IdentityKeeper(config.max_jump, config.max_age)

    def retune(self, config: AssociationConfig) -> None:
        """New thresholds for the frames after this; the tracks and identities so far are kept."""
        self.config = config
        for tracker in self._trackers:
            tracker.min_iou = config.track_iou

    def update(self, frame: int, people: Sequence[Sequence[Person2D] | None]) -> list[PersonObservation]:
        """people[c]: camera c's skeletons at this instant, or None when that camera is missing."""
        present = [list(p) if p is not None else [] for p in people]
        for tracker, skeletons, raw in zip(self._trackers, present, people):
            if raw is not None:
                tracker.update(skeletons)
        rays = ViewRays.of(self.cameras, present)
        clusters = cluster_views(self.cameras, present, self.config.matching, rays)
        first = np.concatenate([[0], np.cumsum([len(p) for p in present])])
        rows = consistent_views(self.cameras, rays, [[first[c] + i for c, i in cl.items()] for cl in clusters],
                                self.config.matching.min_score, self.config.max_view_residual)
        skeleton = [p for ps in present for p in ps]  # by row of rays
        views = [{int(rays.owner[r]): skeleton[r] for r in rs} for rs in rows]
        centres = rough_centres(rays, rows, self.config.matching.min_score)
        keep = [i for i in range(len(views)) if np.all(np.isfinite(centres[i]))]
        views, centres = [views[i] for i in keep], centres[keep].reshape(-1, 3)
        members = [{(c, p.track_id) for c, p in v.items()} for v in views]
        ids = self._ids.assign(frame, members, centres)
        return [PersonObservation(i, v, c) for i, v, c in zip(ids, views, centres)]

    @property
    def identities(self) -> IdentityKeeper:
        """The person ids' keeper (its state outlives a restart: IdentityKeeper.state / restore)."""
        return self._ids
