"""A recorded scene's OpenPose output with shifted copies of its people: a crowd for the node graph.

core.scenarios.crowd multiplies a scene at the level of 2D people, what the 3D stage takes; a
bag for the node graph carries what its detectors take, OpenPose candidates and part affinities.
Here the same copies (crowd.choose_offsets on the same associated people) are made of those: copy k of a
person moves each of the person's BODY25 candidates in a view by the pixel displacement of a 3D
joint of the person moved by offset d_k, project(X + d_k) - project(X): the candidate's own
inference joint, or for the BODY25 joints the 3D stage does not infer the nearest one (mid hip:
the mean of the hips; eyes: the nose; toes and heels: the ankle). A copy keeps each candidate's
score, and each limb's part affinity between two of its candidates is the original pair's; between
candidates of different people it is 0, so the detectors group every copy on its own. A view of a
copy is kept by copy_view's rule (enough of its candidates land inside the image).
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Sequence

import numpy as np

from mvpose_ros.core.association.associator import AssociationConfig
from mvpose_ros.core.detection.openpose import BODY25_NUM_JOINTS, BODY25_PAF_PAIRS, OpenPoseFrame
from mvpose_ros.core.detection.openpose_detector import OpenPoseDetectorConfig, detect_grouped
from mvpose_ros.core.geometry.body import BODY25_NAMES, INFERENCE_NAMES, SOURCE_INDEX
from mvpose_ros.core.geometry.camera import Camera
from mvpose_ros.core.scenarios.crowd import ScenePerson, choose_offsets, scene_people

# The inference joints whose displacement the BODY25 joints without one of their own take.
_BORROWED: dict[str, tuple[str, ...]] = {
    'mid_hip': ('r_hip', 'l_hip'), 'r_eye': ('head',), 'l_eye': ('head',),
    'l_big_toe': ('l_ankle',), 'l_small_toe': ('l_ankle',), 'l_heel': ('l_ankle',),
    'r_big_toe': ('r_ankle',), 'r_small_toe': ('r_ankle',), 'r_heel': ('r_ankle',),
}


def _anchors() -> np.ndarray:
    """(25, 2) the inference joints (twice the same for one) whose mean displacement each BODY25
    joint takes."""
    own = {int(b): i for i, b in enumerate(SOURCE_INDEX['body25']) if b >= 0}
    out = np.zeros((BODY25_NUM_JOINTS, 2), dtype=np.intp)
    for b, name in enumerate(BODY25_NAMES):
        names = _BORROWED.get(name)
        out[b] = (own[b], own[b]) if names is None else [INFERENCE_NAMES.index(n) for n in (names * 2)[:2]]
    return out


ANCHORS = _anchors()


@dataclass
class CrowdOpenPose:
    """frames[f][c]: camera c's OpenPose output of frame f with the copies; offsets (K, 3) metres,
    row 0 the original (zeros); expected and original: 3D people per frame with and without the
    copies (as core.scenarios.crowd.MultipliedScene)."""

    frames: list[list[OpenPoseFrame]]
    offsets: np.ndarray
    expected: float
    original: float


def candidate_displacements(camera: Camera, joints: np.ndarray, offset: np.ndarray) -> np.ndarray:
    """(25, 2) pixel displacement in `camera` of each BODY25 joint of the person whose 3D inference
    joints are `joints` (16, 3) when moved by `offset` (3,) metres; NaN where the anchoring joints
    are not triangulated or project behind the camera."""
    joints = np.asarray(joints, dtype=np.float64)
    moved = camera.project(joints + offset) - camera.project(joints)  # (16, 2)
    return moved[ANCHORS].mean(axis=1)


def copy_candidates(frame: OpenPoseFrame, camera: Camera, group: np.ndarray, shift: np.ndarray,
                    min_inside: float = 0.5) -> np.ndarray | None:
    """(25, 3) u, v, score of a copy of the person whose candidate indices in `frame` are `group`
    (25,) (-1: none), each candidate moved by shift (25, 2) pixels; NaN rows where the copy has no
    candidate (none in the original, no displacement, or outside the image). None when fewer than
    max(1, min_inside x the movable candidates) land inside."""
    out = np.full((BODY25_NUM_JOINTS, 3), np.nan)
    movable = (group >= 0) & np.isfinite(shift).all(axis=1)
    for b in np.flatnonzero(movable):
        out[b] = frame.candidates[b][group[b]]
        out[b, :2] += shift[b]
    with np.errstate(invalid='ignore'):
        inside = (movable & (out[:, 0] >= 0) & (out[:, 0] < camera.width)
                  & (out[:, 1] >= 0) & (out[:, 1] < camera.height))
    if inside.sum() < max(1, math.ceil(min_inside * movable.sum())):
        return None
    out[~inside] = np.nan
    return out


def with_copies(frame: OpenPoseFrame, copies: Sequence[tuple[np.ndarray, np.ndarray]]) -> OpenPoseFrame:
    """`frame` with the copied people appended: copies are (candidates (25, 3), NaN rows absent;
    the original's candidate indices (25,)). Each copy's candidates come after the frame's own, in
    order; a limb's affinity between two candidates of one copy is that of the original pair."""
    candidates = [list(c) for c in frame.candidates]
    index = np.full((len(copies), BODY25_NUM_JOINTS), -1, dtype=np.intp)  # each copy's new candidate indices
    for k, (rows, _) in enumerate(copies):
        for b in np.flatnonzero(np.isfinite(rows[:, 0])):
            index[k, b] = len(candidates[b])
            candidates[b].append(rows[b])
    pafs = []
    for limb, (a, b) in enumerate(BODY25_PAF_PAIRS):
        paf = np.zeros((len(candidates[a]), len(candidates[b])))
        old = frame.pafs[limb]
        paf[:old.shape[0], :old.shape[1]] = old
        for k, (_, group) in enumerate(copies):
            if index[k, a] >= 0 and index[k, b] >= 0:
                paf[index[k, a], index[k, b]] = old[group[a], group[b]]
        pafs.append(paf)
    return OpenPoseFrame([np.array(c, dtype=np.float64).reshape(-1, 3) for c in candidates], pafs)


def crowd_openpose(cameras: Sequence[Camera], raw: Sequence[Sequence[OpenPoseFrame]], target: float, *,
                   detector: OpenPoseDetectorConfig | None = None, config: AssociationConfig | None = None,
                   offsets: np.ndarray | None = None, min_inside: float = 0.5) -> CrowdOpenPose:
    """raw[f][c]: camera c's OpenPose output of frame f (f = 0, 1, ...: consecutive frames). The
    same with enough shifted copies for about `target` 3D people per frame (or with the given
    `offsets`, row 0 zeros): the people the detectors find (detector) and association groups
    (config) are copied; every original candidate stays."""
    detector = detector or OpenPoseDetectorConfig()
    grouped = [[detect_grouped(frame, detector) for frame in per_camera] for per_camera in raw]
    people = [[ps for _, ps in per_camera] for per_camera in grouped]
    scene = scene_people(cameras, range(len(raw)), people, config)
    original = sum(len(f) for f in scene) / max(len(scene), 1)
    if offsets is None:
        offsets, expected = choose_offsets(cameras, scene, target, config, min_inside=min_inside)
    else:
        offsets, expected = np.asarray(offsets, dtype=np.float64).reshape(-1, 3), float('nan')
    row_of = {id(p): row for per_camera in grouped for groups, ps in per_camera for row, p in zip(groups, ps)}
    frames = []
    for per_camera, persons in zip(raw, scene):
        copies: list[list[tuple[np.ndarray, np.ndarray]]] = [[] for _ in cameras]
        for d in offsets:
            if np.any(d):
                for person in persons:
                    _add_copy(cameras, person, d, row_of, per_camera, copies, min_inside)
        frames.append([with_copies(frame, mine) for frame, mine in zip(per_camera, copies)])
    return CrowdOpenPose(frames, offsets, expected, original)


def _add_copy(cameras: Sequence[Camera], person: ScenePerson, offset: np.ndarray, row_of: dict[int, np.ndarray],
              frames: Sequence[OpenPoseFrame], copies: list[list[tuple[np.ndarray, np.ndarray]]],
              min_inside: float) -> None:
    """Append to copies[c] the view in camera c of `person` moved by `offset`, for each camera that
    saw the person and still sees enough of the copy."""
    for c, view in sorted(person.views.items()):
        group = row_of[id(view)]
        rows = copy_candidates(frames[c], cameras[c], group,
                               candidate_displacements(cameras[c], person.joints, offset), min_inside)
        if rows is not None:
            copies[c].append((rows, group))
