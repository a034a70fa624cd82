"""2D people from stored OpenPose BODY25 output: grouped skeletons mapped to the 16 inference joints,
with per-joint heatmaps rebuilt from the candidates (the files hold peaks, not the maps)."""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from mvpose_ros.core.compiled import kernel, kernel_array
from mvpose_ros.core.geometry.body import BODY25_INFERENCE_JOINTS, INFERENCE_MIRROR, to_inference
from mvpose_ros.core.detection.grouping import group_body25
from mvpose_ros.core.heatmap import render_heatmaps
from mvpose_ros.core.detection.openpose import OpenPoseFrame
from mvpose_ros.core.types import Person2D


@dataclass
class OpenPoseDetectorConfig:
    """stride, sigma: heatmap cell size and Gaussian std (px).
    secondary_radius: other candidates of a joint's BODY25 type within this fraction of the
    person's bbox diagonal of its own candidate also go into the map, with weight
    secondary_weight * score. mirror_weight: factor on the person's own left/right counterpart
    candidate, put into the map too (left/right swaps survive until the views are fused). Off
    by default: on Shelf it costs PCP (lenient actor average, all terms: 95.97 at 0, 94.41 at
    0.2, 91.20 at 0.5), because where a joint is occluded in most views the counterpart's
    evidence, consistent across those views, outvotes the few views that see the joint.
    paf_power, min_paf, min_joints, min_mean_score: grouping.group_body25."""

    stride: float = 4.0
    sigma: float = 6.0
    secondary_radius: float = 0.25
    secondary_weight: float = 1.0
    mirror_weight: float = 0.0
    paf_power: float = 0.2
    min_paf: float = 0.05
    min_joints: int = 4
    min_mean_score: float = 0.3


def grouped_keypoints(frame: OpenPoseFrame, groups: np.ndarray) -> np.ndarray:
    """(P, 25, 3) u, v, score of the grouped candidates (groups: (P, 25) index or -1); missing
    joints are (NaN, NaN, 0)."""
    first = np.array([0] + [len(c) for c in frame.candidates[:-1]]).cumsum()
    rows = np.concatenate(frame.candidates + [_MISSING])
    return rows[np.where(groups >= 0, first + groups, len(rows) - 1)]


_MISSING = np.array([[np.nan, np.nan, 0.0]])  # grouped_keypoints' row for a joint without candidate


def _centres(frame: OpenPoseFrame, groups: np.ndarray, keypoints: np.ndarray,
             config: OpenPoseDetectorConfig) -> np.ndarray:
    """Heatmap centres (P, 16, n, 3) [u, v, weight] of each person's 16 inference joints
    (groups: (P, 25) candidate indices; keypoints: (P, 16, 3) inference keypoints); rows of
    weight 0 are padding. Per joint: its own candidate, the other candidates of its BODY25 type
    within secondary_radius of the person's keypoint-box diagonal, and with mirror_weight > 0
    its left/right counterpart's own candidate."""
    # the radius in numpy (np.hypot is libm's), the rows compiled; fmax, fmin skip missing joints
    span = np.fmax.reduce(keypoints[..., :2], axis=1) - np.fmin.reduce(keypoints[..., :2], axis=1)
    radius = config.secondary_radius * np.hypot(span[:, 0], span[:, 1])  # (P,)
    cand = kernel_array(np.concatenate(frame.candidates), np.float64)
    n_cand = np.array([len(c) for c in frame.candidates])
    return _centre_rows(cand, n_cand, kernel_array(groups, np.int64), radius,
                        float(config.secondary_weight), float(config.mirror_weight))


_TYPES = np.asarray(BODY25_INFERENCE_JOINTS, dtype=np.int64)  # BODY25 joint of each inference joint
_MIRROR = np.asarray(INFERENCE_MIRROR, dtype=np.int64)


@kernel('float64[:, :, :, ::1](float64[:, ::1], int64[::1], int64[:, ::1], float64[::1], float64, float64)')
def _centre_rows(cand, n_cand, groups, radius, secondary_weight, mirror_weight):
    """_centres' rows from cand (C, 3), every candidate joint after joint (n_cand (25,) per joint),
    and radius (P,): per person and joint, row 0 its own candidate, row 1 + c its BODY25 type's
    candidate c when a secondary one, the last row (with mirror_weight > 0) its counterpart's."""
    first = np.zeros(len(n_cand) + 1, dtype=np.int64)
    first[1:] = np.cumsum(n_cand)
    width = 1
    for b in _TYPES:
        width = max(width, n_cand[b])
    if len(groups) == 0:
        return np.zeros((0, len(_TYPES), 1, 3))
    mirror = mirror_weight > 0
    out = np.zeros((len(groups), len(_TYPES), 1 + width + int(mirror), 3))
    for p in range(len(groups)):
        for j in range(len(_TYPES)):
            b = _TYPES[j]
            if groups[p, b] >= 0:
                own = first[b] + groups[p, b]
                out[p, j, 0] = cand[own]
                for c in range(n_cand[b]):
                    du, dv = cand[first[b] + c, 0] - cand[own, 0], cand[first[b] + c, 1] - cand[own, 1]
                    if c != groups[p, b] and np.sqrt(du * du + dv * dv) <= radius[p]:
                        out[p, j, 1 + c, 0] = cand[first[b] + c, 0]
                        out[p, j, 1 + c, 1] = cand[first[b] + c, 1]
                        out[p, j, 1 + c, 2] = cand[first[b] + c, 2] * secondary_weight
            # the counterpart's evidence, also where the joint itself is missing
            m = _TYPES[_MIRROR[j]]
            if mirror and m != b and groups[p, m] >= 0:
                counterpart = first[m] + groups[p, m]
                out[p, j, -1, 0] = cand[counterpart, 0]
                out[p, j, -1, 1] = cand[counterpart, 1]
                out[p, j, -1, 2] = cand[counterpart, 2] * mirror_weight
    return out


def detect_people(frame: OpenPoseFrame, config: OpenPoseDetectorConfig) -> list[Person2D]:
    """Group one camera frame's candidates into people and build each one's 16 keypoints and
    heatmaps (16 of each); each map covers its own candidates (heatmap.render_heatmaps)."""
    return detect_grouped(frame, config)[1]


def detect_grouped(frame: OpenPoseFrame, config: OpenPoseDetectorConfig) -> tuple[np.ndarray, list[Person2D]]:
    """detect_people's people and, row p for people[p], their BODY25 candidate indices (P, 25)
    (-1: no candidate), for callers that work on the candidates themselves."""
    groups = group_body25(frame, paf_power=config.paf_power, min_paf=config.min_paf,
                          min_joints=config.min_joints, min_mean_score=config.min_mean_score)
    keypoints = to_inference(grouped_keypoints(frame, groups), 'body25')
    # none of the 16 joints (e.g. a feet-only fragment): not a person for the 3D stage
    keep = (keypoints[..., 2] > 0).any(axis=1)
    groups, keypoints = groups[keep], keypoints[keep]
    heatmaps = render_heatmaps(_centres(frame, groups, keypoints, config), config.stride, config.sigma)
    return groups, [Person2D(keypoints=kp, heatmap=hm) for kp, hm in zip(keypoints, heatmaps)]
