"""Identity of 2D skeletons over time within one camera, by bounding-box overlap (paper: IoU >= 0.7),
each pair's boxes over the keypoints both skeletons detect, less the fifth that moved most."""
from __future__ import annotations

from typing import Sequence

import numpy as np
from scipy.optimize import linear_sum_assignment

from mvpose_ros.core.compiled import kernel, kernel_array
from mvpose_ros.core.types import Keypoints2D


@kernel('float64[:, ::1](float64[:, ::1], float64[:, ::1])')
def _box_iou(a, b):
    """box_iou of C-contiguous float boxes; a NaN anywhere in a pair gives 0, as in numpy's
    formulation (its union is NaN, not > 0)."""
    out = np.zeros((len(a), len(b)))
    for i in range(len(a)):
        area_a = (a[i, 2] - a[i, 0]) * (a[i, 3] - a[i, 1])
        for k in range(len(b)):
            if np.isnan(a[i, 0] + a[i, 1] + a[i, 2] + a[i, 3] + b[k, 0] + b[k, 1] + b[k, 2] + b[k, 3]):
                continue
            w = min(a[i, 2], b[k, 2]) - max(a[i, 0], b[k, 0])
            h = min(a[i, 3], b[k, 3]) - max(a[i, 1], b[k, 1])
            inter = (w if w > 0 else 0.0) * (h if h > 0 else 0.0)
            union = area_a + (b[k, 2] - b[k, 0]) * (b[k, 3] - b[k, 1]) - inter
            if union > 0:
                out[i, k] = inter / union
    return out


def box_iou(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Pairwise IoU of boxes (N, 4) and (K, 4) as u0, v0, u1, v1 -> (N, K)."""
    return _box_iou(kernel_array(a, np.float64).reshape(-1, 4),
                    kernel_array(b, np.float64).reshape(-1, 4))


@kernel('float64[:, ::1](float64[:, :, ::1], float64[:, :, ::1])')
def _shared_iou(a, b):
    """shared_box_iou of C-contiguous keypoints; a displacement that is NaN counts as the largest,
    and a NaN coordinate left in makes that side of its box NaN, and the pair's IoU 0 (box_iou)."""
    out = np.zeros((len(a), len(b)))
    box_a, box_b = np.empty((1, 4)), np.empty((1, 4))
    n_joints = a.shape[1]
    shared = np.empty(n_joints, dtype=np.int64)
    moved = np.empty(n_joints)
    for i in range(len(a)):
        for k in range(len(b)):
            n = 0
            for j in range(n_joints):
                if a[i, j, 2] > 0 and b[k, j, 2] > 0:
                    du, dv = a[i, j, 0] - b[k, j, 0], a[i, j, 1] - b[k, j, 1]
                    d = du * du + dv * dv
                    moved[n] = d if d == d else np.inf
                    shared[n] = j
                    n += 1
            if n == 0:
                continue
            kept = shared[:n][np.argsort(moved[:n], kind='mergesort')[:n - n // 5]]
            for m, j in enumerate(kept):
                for box, kp in ((box_a, a[i, j]), (box_b, b[k, j])):
                    if m == 0:
                        box[0, 0] = box[0, 2] = kp[0]
                        box[0, 1] = box[0, 3] = kp[1]
                    else:  # a NaN coordinate makes that side NaN, as numpy's min and max do
                        box[0, 0] = kp[0] if kp[0] != kp[0] or kp[0] < box[0, 0] else box[0, 0]
                        box[0, 1] = kp[1] if kp[1] != kp[1] or kp[1] < box[0, 1] else box[0, 1]
                        box[0, 2] = kp[0] if kp[0] != kp[0] or kp[0] > box[0, 2] else box[0, 2]
                        box[0, 3] = kp[1] if kp[1] != kp[1] or kp[1] > box[0, 3] else box[0, 3]
            out[i, k] = _box_iou(box_a, box_b)[0, 0]
    return out


def shared_box_iou(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """(N, K) IoU of the boxes of each pair of skeletons a (N, J, 3) and b (K, J, 3) over the
    keypoints both detect (score > 0), less the fifth of them (n // 5 of n) that moved most
    between the two; 0 for a pair sharing none. A joint that one of the two misses (it left the
    image, or is hidden) changes neither box, and one keypoint of a detector's gone astray (on
    another person, 60 px off) does not break a track."""
    return _shared_iou(kernel_array(a, np.float64), kernel_array(b, np.float64))


class IouTracker:
    """Gives each skeleton the track id of the previous frame's skeleton it overlaps enough, the
    boxes of each pair over the keypoints both detect less the fifth that moved most
    (shared_box_iou): a person walking out of the image, whose box over all his keypoints shrinks as
    joints leave it, or with a keypoint astray, keeps his track. min_iou: the overlap that continues a
    track (its default is the association's track_iou)."""

    def __init__(self, min_iou: float) -> None:
        self.min_iou = min_iou
        self._keypoints = np.zeros((0, 0, 3))
        self._ids: list[int] = []
        self._next_id = 0

    def update(self, people: Sequence[Keypoints2D]) -> None:
        """Set `track_id` on each person of the new frame (one-to-one, highest total IoU)."""
        keypoints = np.array([p.keypoints for p in people], dtype=np.float64) if len(people) else np.zeros((0, 0, 3))
        ids = [-1] * len(people)
        if len(people) and len(self._ids):
            iou = shared_box_iou(keypoints, self._keypoints)
            rows, cols = linear_sum_assignment(-iou)
            for r, c in zip(rows.tolist(), cols.tolist()):
                if iou[r, c] >= self.min_iou:
                    ids[r] = self._ids[c]
        for i, person in enumerate(people):
            if ids[i] < 0:  # fresh ids in list order
                ids[i] = self._next_id
                self._next_id += 1
            person.track_id = ids[i]
        self._keypoints, self._ids = keypoints, ids
