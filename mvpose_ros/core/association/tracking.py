"""Identity of 2D skeletons over time within one camera, by bounding-box overlap (paper: IoU >= 0.7)."""
from __future__ import annotations

from typing import Sequence

import numpy as np
from scipy.optimize import linear_sum_assignment

from mvpose_ros.core.types import Person2D


def box_iou(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Pairwise IoU of boxes (N, 4) and (K, 4) as u0, v0, u1, v1 -> (N, K)."""
    lo = np.maximum(a[:, None, :2], b[None, :, :2])
    hi = np.minimum(a[:, None, 2:], b[None, :, 2:])
    inter = np.prod(np.clip(hi - lo, 0.0, None), axis=-1)
    area_a = np.prod(a[:, 2:] - a[:, :2], axis=-1)
    area_b = np.prod(b[:, 2:] - b[:, :2], axis=-1)
    union = area_a[:, None] + area_b[None, :] - inter
    return np.where(union > 0, inter / np.where(union > 0, union, 1.0), 0.0)


def keypoint_boxes(keypoints: np.ndarray) -> np.ndarray:
    """(P, 4) u_min, v_min, u_max, v_max over each person's detected keypoints (P, J, 3) (score
    > 0), as Person2D.bbox; NaN for a person with none."""
    detected = (keypoints[..., 2] > 0)[..., None]
    with np.errstate(invalid='ignore'):
        lo = np.where(detected, keypoints[..., :2], np.inf).min(axis=1)
        hi = np.where(detected, keypoints[..., :2], -np.inf).max(axis=1)
    return np.where(detected.any(axis=1), np.concatenate([lo, hi], axis=-1), np.nan)


class IouTracker:
    """Gives each skeleton the track id of the previous frame's skeleton it overlaps enough."""

    def __init__(self, min_iou: float = 0.7) -> None:
        self.min_iou = min_iou
        self._boxes = np.zeros((0, 4))
        self._ids = np.zeros(0, dtype=int)
        self._next_id = 0

    def update(self, people: Sequence[Person2D]) -> None:
        """Set `track_id` on each person of the new frame (one-to-one, highest total IoU)."""
        boxes = keypoint_boxes(np.array([p.keypoints for p in people])) if len(people) else np.zeros((0, 4))
        ids = np.full(len(people), -1)
        if len(people) and len(self._ids):
            iou = box_iou(boxes, self._boxes)
            rows, cols = linear_sum_assignment(-iou)
            keep = iou[rows, cols] >= self.min_iou
            ids[rows[keep]] = self._ids[cols[keep]]
        fresh = ids < 0
        ids[fresh] = self._next_id + np.arange(fresh.sum())
        self._next_id += int(fresh.sum())
        for person, track_id in zip(people, ids):
            person.track_id = int(track_id)
        self._boxes, self._ids = boxes, ids
