"""Per-frame multi-view association: tracking in each camera, matching across cameras, 3D ids.

This is the work of the association node: it turns each camera's 2D skeletons of one instant
into people seen by at least two cameras, each with a stable id.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import Sequence

import numpy as np

from mvpose_ros.core.camera import Camera, closest_point_to_rays
from mvpose_ros.core.identity import IdentityKeeper
from mvpose_ros.core.matching import MatchingConfig, cluster_views
from mvpose_ros.core.person2d import Person2D
from mvpose_ros.core.tracking import IouTracker


@dataclass(frozen=True)
class AssociationConfig:
    """track_iou: the paper's 0.7; max_jump / max_age: how an id is recovered after occlusion."""

    track_iou: float = 0.7
    matching: MatchingConfig = field(default_factory=MatchingConfig)
    max_jump: float = 0.5
    max_age: int = 25


@dataclass
class PersonObservation:
    """One person at one instant: the skeleton seen by each camera (index into the rig)."""

    person_id: int
    views: dict[int, Person2D]
    centre: np.ndarray


def rough_centre(cameras: Sequence[Camera], views: dict[int, Person2D], min_score: float) -> np.ndarray:
    """Mean of the joints triangulated from the keypoints of every view (3,), metres."""
    cams = list(views)
    kp = np.stack([views[c].keypoints for c in cams])  # (V, J, 3)
    rays = [cameras[c].rays(views[c].keypoints[:, :2]) for c in cams]
    origins = np.stack([r[0] for r in rays], axis=1)  # (J, V, 3)
    dirs = np.stack([r[1] for r in rays], axis=1)
    seen = (kp[..., 2] > min_score).T  # (J, V)
    twice = seen.sum(axis=1) >= 2
    if not twice.any():
        return np.full(3, np.nan)
    points = closest_point_to_rays(origins[twice], dirs[twice], seen[twice])
    return np.nanmean(points, axis=0)


class Associator:
    """Stateful association over a stream of synchronised frames from a fixed rig."""

    def __init__(self, cameras: Sequence[Camera], config: AssociationConfig) -> None:
        self.cameras = list(cameras)
        self.config = config
        self._trackers = [IouTracker(config.track_iou) for _ in self.cameras]
        self._ids = IdentityKeeper(config.max_jump, config.max_age)

    def update(self, frame: int, people: Sequence[Sequence[Person2D] | None]) -> list[PersonObservation]:
        """people[c]: camera c's skeletons at this instant, or None when that camera is missing."""
        present = [list(p) if p is not None else [] for p in people]
        for tracker, skeletons, raw in zip(self._trackers, present, people):
            if raw is not None:
                tracker.update(skeletons)
        clusters = cluster_views(self.cameras, present, self.config.matching)
        views = [{c: present[c][i] for c, i in cl.items()} for cl in clusters]
        centres = np.array([rough_centre(self.cameras, v, self.config.matching.min_score) for v in views])
        keep = [i for i in range(len(views)) if np.all(np.isfinite(centres[i]))]
        views, centres = [views[i] for i in keep], centres[keep].reshape(-1, 3)
        members = [{(c, p.track_id) for c, p in v.items()} for v in views]
        ids = self._ids.assign(frame, members, centres)
        return [PersonObservation(i, v, c) for i, v, c in zip(ids, views, centres)]
