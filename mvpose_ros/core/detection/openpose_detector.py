"""2D people from stored OpenPose BODY25 output: grouped skeletons mapped to the 16 inference joints,
with per-joint heatmaps rebuilt from the candidates (the files hold peaks, not the maps)."""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

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
    sizes = [len(c) for c in frame.candidates]
    first = np.concatenate([[0], np.cumsum(sizes)[:-1]]).astype(np.intp)
    rows = np.concatenate(frame.candidates + [np.array([[np.nan, np.nan, 0.0]])])  # last row: missing
    return rows[np.where(groups >= 0, first + groups, len(rows) - 1)]


def _centres(frame: OpenPoseFrame, groups: np.ndarray, keypoints: np.ndarray,
             config: OpenPoseDetectorConfig) -> np.ndarray:
    """Heatmap centres (P, 16, n, 3) [u, v, weight] of each person's 16 inference joints
    (groups: (P, 25) candidate indices; keypoints: (P, 16, 3) inference keypoints); rows of
    weight 0 are padding. Per joint: its own candidate, the other candidates of its BODY25 type
    within secondary_radius of the person's keypoint-box diagonal, and with mirror_weight > 0
    its left/right counterpart's own candidate."""
    n_p = len(groups)
    types = BODY25_INFERENCE_JOINTS
    n_cand = max([len(frame.candidates[b]) for b in types] + [1])
    cand = np.zeros((len(types), n_cand, 3))  # (16, C, 3) every candidate of each joint's type
    for j, b in enumerate(types):
        cand[j, :len(frame.candidates[b])] = frame.candidates[b]
    own = groups[:, types]  # (P, 16)
    has = own >= 0
    own_rows = np.where(has[..., None], cand[np.arange(len(types)), np.maximum(own, 0)], 0.0)  # (P, 16, 3)
    with np.errstate(invalid='ignore'):  # people without keypoints never reach here
        span = np.nanmax(keypoints[..., :2], axis=1) - np.nanmin(keypoints[..., :2], axis=1)
    radius = config.secondary_radius * np.hypot(span[:, 0], span[:, 1])  # (P,)
    near = np.linalg.norm(cand[None, :, :, :2] - own_rows[:, :, None, :2], axis=-1) <= radius[:, None, None]
    near &= has[..., None] & (np.arange(n_cand) != own[..., None])
    secondary = np.where(near[..., None], cand[None] * (1.0, 1.0, config.secondary_weight), 0.0)
    parts = [own_rows[:, :, None], secondary]
    if config.mirror_weight > 0:
        mirror = own_rows[:, INFERENCE_MIRROR] * (1.0, 1.0, config.mirror_weight)
        mirror[:, types[INFERENCE_MIRROR] == types] = 0.0  # joints that are their own counterpart
        parts.append(mirror[:, :, None])
    return np.concatenate(parts, axis=2) if n_p else np.zeros((0, len(types), 1, 3))


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
