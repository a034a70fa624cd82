"""Where people are expected, from the previous set's 3D skeletons projected into each camera: a
box around each person's joints where they are and where his motion since the skeletons before
takes them by the next set (predicted_joints), and the ears (which only MoveNet MultiPose gives)
carried from the camera's previous people along with their neck.

Between two runs of MultiPose on a camera's whole image (every `person_detector_every`-th set, the
cameras taking turns), the crop model works on these boxes as its crops, or, with heatmaps
'multipose', MultiPose searches only the region around them (people_region). A camera where a
whole-image run found someone no skeleton explains (unexplained) stays on whole-image runs until
the 3D stage takes him up.
The rules in full: docs/crop_models.md#tracked-crops."""
from __future__ import annotations

from typing import Sequence

import numpy as np

from mvpose_ros.core.geometry.body import L_EAR, NECK, NUM_INFERENCE_JOINTS, R_EAR
from mvpose_ros.core.geometry.camera import Camera
from mvpose_ros.core.types import Person2D

# A box around joint centres is tighter than MultiPose's box around the body: each side moves
# out by this fraction of the box's size (then the detector's box_margin applies, as to any box).
# 0.1 gave crops of about MultiPose's size on Shelf frame 572 (median side ratio 1.0 to 1.1).
JOINT_BOX_MARGIN = 0.1
MIN_JOINTS_IN_VIEW = 4  # fewer projected joints in the image: the person is left to MultiPose
# a previous person's ears follow the nearest previous neck within this fraction of the crop's size
EAR_GATE = 0.25
# a MultiPose person of a camera is explained by the skeleton matched to him (unexplained) when the
# median distance of their limb joints in the image is at most this fraction of his size
UNEXPLAINED_GAP = 0.5
LIMB_JOINTS = 12  # the first joints of the inference and the dataset joint orders alike


def predicted_joints(joints: np.ndarray, ids: np.ndarray, before: np.ndarray, before_ids: np.ndarray) -> np.ndarray:
    """(P, J, 3) each person's joints (P, J, 3) (world metres, NaN where missing) moved on by his
    motion since the skeletons before, before (R, J, 3) with ids before_ids (R,): joints +
    (joints - before) of the same id, per joint; unmoved where the id or the joint is not in
    before (ids (P,))."""
    joints = np.asarray(joints, dtype=np.float64)
    out = joints.copy()
    index = {int(i): r for r, i in enumerate(np.asarray(before_ids).tolist())}
    for p, i in enumerate(np.asarray(ids).tolist()):
        r = index.get(int(i))
        if r is None:
            continue
        step = joints[p] - before[r]
        moved = np.isfinite(step).all(axis=-1)
        out[p, moved] += step[moved]
    return out


def unexplained(keypoints: np.ndarray, projected: np.ndarray, gap: float = UNEXPLAINED_GAP,
                min_joints: int = MIN_JOINTS_IN_VIEW) -> np.ndarray:
    """(P,) whether each of a camera's people, inference keypoints (P, 16, 3) u, v, score, with at
    least min_joints limb joints detected, is no skeleton's. The people and the skeletons projected
    into the camera, projected (Q, J >= 12, 2) pixels (NaN where missing), are matched one to one,
    closest pair first, by the median distance over the 12 limb joints both have (at least
    min_joints) as a fraction of the person's size (the diagonal of his limb keypoints' box): a
    person is explained by a match within gap. One to one, since neighbours in a crowd overlap in
    the image (on Shelf frame 572 a neighbour's skeleton lay as close as 0.15, a person's own as
    far as 0.21)."""
    keypoints = np.asarray(keypoints, dtype=np.float64)
    if len(keypoints) == 0:
        return np.zeros(0, dtype=bool)
    limbs = keypoints[:, :LIMB_JOINTS]
    seen = limbs[..., 2] > 0  # (P, 12)
    enough = seen.sum(axis=1) >= min_joints
    uv = np.where(seen[..., None], limbs[..., :2], np.nan)
    lo = np.where(seen[..., None], uv, np.inf).min(axis=1)
    hi = np.where(seen[..., None], uv, -np.inf).max(axis=1)
    size = np.where(enough, np.hypot(*(hi - lo).T), np.nan)  # (P,)
    projected = np.asarray(projected, dtype=np.float64)[:, :LIMB_JOINTS]
    distance = np.linalg.norm(uv[:, None] - projected[None], axis=-1)  # (P, Q, 12), NaN where either lacks it
    shared = np.isfinite(distance).sum(axis=-1) >= min_joints
    median = np.full(shared.shape, np.inf)
    if shared.any():
        median[shared] = np.nanmedian(distance[shared], axis=-1)
    gaps = median / size[:, None]  # NaN (no match) for a person with too few joints
    gaps[~np.isfinite(gaps)] = np.inf
    matched = np.zeros(len(keypoints), dtype=bool)
    while gaps.size and gaps.min() <= gap:
        p, q = np.unravel_index(np.argmin(gaps), gaps.shape)
        matched[p] = True
        gaps[p, :] = gaps[:, q] = np.inf
    return enough & ~matched


def projected_boxes(joints: np.ndarray, camera: Camera, margin: float = JOINT_BOX_MARGIN,
                    min_joints: int = MIN_JOINTS_IN_VIEW) -> np.ndarray:
    """(Q, 4) boxes u0, v0, u1, v1 (pixel-centre coordinates, as MultiPose's) around the joints
    (P, J, 3) (world metres, NaN where missing) projected into camera, each side moved out by
    margin times the box's size, then cut to the image (a person partly out of view gets the
    crop up to the image's edge). A person with fewer than min_joints joints in front of the
    camera and inside the image gives no box (Q <= P, in joints' order)."""
    uv = camera.project(np.asarray(joints, dtype=np.float64))  # (P, J, 2), NaN behind the camera or missing
    edge = np.array([camera.width, camera.height], dtype=np.float64) - 0.5
    finite = np.isfinite(uv).all(axis=-1)
    inside = finite & (uv >= -0.5).all(axis=-1) & (uv <= edge).all(axis=-1)
    keep = inside.sum(axis=1) >= min_joints
    if not keep.any():
        return np.zeros((0, 4))
    uv, finite = uv[keep], finite[keep]
    lo = np.where(finite[..., None], uv, np.inf).min(axis=1)
    hi = np.where(finite[..., None], uv, -np.inf).max(axis=1)
    grow = margin * (hi - lo)
    return np.concatenate([np.maximum(lo - grow, -0.5), np.minimum(hi + grow, edge)], axis=1)


def grown_boxes(boxes: np.ndarray, margin: float) -> np.ndarray:
    """Boxes (P, 4) u0, v0, u1, v1 with each side moved out by margin times the box's size."""
    size = boxes[:, 2:] - boxes[:, :2]
    return np.concatenate([boxes[:, :2] - margin * size, boxes[:, 2:] + margin * size], axis=1)


def people_region(boxes: np.ndarray, size: tuple[int, int], margin: float) -> np.ndarray:
    """(4,) u0, v0, u1, v1: the part of a camera's (width, height) image MultiPose searches for
    people expected in boxes (Q >= 1, 4) (projected_boxes): each box grown on every side by margin
    times its size (their motion since), then the box around them all, cut to the image."""
    boxes = np.asarray(boxes, dtype=np.float64).reshape(-1, 4)
    grow = margin * (boxes[:, 2:] - boxes[:, :2])
    lo, hi = (boxes[:, :2] - grow).min(axis=0), (boxes[:, 2:] + grow).max(axis=0)
    return np.concatenate([np.maximum(lo, -0.5), np.minimum(hi, np.array(size, dtype=np.float64) - 0.5)])


def carried_ears(neck: np.ndarray, previous: np.ndarray, size: float, gate: float = EAR_GATE) -> np.ndarray:
    """(2, 3) r_ear, l_ear keypoints (u, v, score) of a person whose neck is now at neck (3,) (u, v,
    score), from the camera's previous people's inference keypoints previous (Q, 16, 3): the ears
    of the previous person whose neck is nearest, within gate * size pixels, moved by that neck's
    shift, with their scores. Score 0 (and NaN u, v) when the neck is not detected, no previous
    neck is near enough, or that person had no ears."""
    out = np.full((2, 3), np.nan)
    out[:, 2] = 0.0
    previous = np.asarray(previous, dtype=np.float64)
    if not (neck[2] > 0) or len(previous) == 0:
        return out
    has = previous[:, NECK, 2] > 0
    distance = np.where(has, np.linalg.norm(previous[:, NECK, :2] - neck[:2], axis=1), np.inf)
    best = int(np.argmin(distance))
    if not distance[best] <= gate * size:
        return out
    ears = previous[best, [R_EAR, L_EAR]].copy()
    seen = ears[:, 2] > 0
    ears[seen, :2] += neck[:2] - previous[best, NECK, :2]
    ears[~seen] = (np.nan, np.nan, 0.0)
    return ears


class CropPlanner:
    """Which cameras of the next set run MultiPose on the whole image and which get crops from
    skeletons. Each camera's whole image is searched once every `every` sets, the cameras' turns
    spread over those sets (camera c of N at the n-th set detected when (n + c * every // N) % every == 0), so
    that a set costs about the same as the next and a new person is looked for within `every`
    sets in every camera. Every camera searches while no skeletons are known (or the last ones held
    nobody), and a camera whose last search found someone the skeletons do not explain searches at
    every set until they do (see the module docstring). The others get the projected_boxes of the
    skeletons where they are and where their motion takes them (a camera whose intrinsics are not
    known yet, None in `cameras`, searches)."""

    def __init__(self, cameras: Sequence[Camera | None], every: int = 1) -> None:
        if every < 1:
            raise ValueError(f'person_detector_every {every} must be >= 1')
        self.cameras = list(cameras)
        self.every = every
        self._joints = np.zeros((0, 0, 3))
        self._ids = np.zeros(0, dtype=np.int64)
        self._predicted = self._joints  # where the skeletons' motion takes them by the next set
        self._found: list[np.ndarray | None] = [None] * len(self.cameras)  # MultiPose's people, not yet checked
        self.unexplained = [False] * len(self.cameras)
        self._sets = 0  # sets detected so far (update)
        self.previous = [np.zeros((0, NUM_INFERENCE_JOINTS, 3)) for _ in self.cameras]

    def plan(self) -> list[np.ndarray | None]:
        """Per camera, None (run MultiPose on its whole image) or the boxes (Q, 4) of the next
        set's crops."""
        n = self._sets
        if len(self._joints) == 0:
            return [None] * len(self.cameras)
        both = np.concatenate([self._joints, self._predicted], axis=1)  # (P, 2J, 3): a box holds where he goes
        turn = [(n + c * self.every // len(self.cameras)) % self.every == 0 for c in range(len(self.cameras))]
        return [None if camera is None or self.unexplained[c] or turn[c] else projected_boxes(both, camera)
                for c, camera in enumerate(self.cameras)]

    def update(self, plan: Sequence[np.ndarray | None], people: Sequence[Sequence[Person2D] | None]) -> None:
        """After a set was detected with `plan`: its people per camera (None: no image), whose
        keypoints carry the ears into the next set."""
        self._sets += 1
        for c, found in enumerate(people):
            if found is not None:
                self.previous[c] = np.array([p.keypoints for p in found]).reshape(-1, NUM_INFERENCE_JOINTS, 3)
                if plan[c] is None:
                    self._found[c] = self.previous[c]

    def skeletons(self, joints: np.ndarray, ids: np.ndarray | None = None) -> None:
        """The latest 3D skeletons (P, J, 3), world metres (NaN where missing), with their ids (P,)
        (None: no motion is predicted). The same skeletons given again keep the motion of the ones
        before. Each camera's people of its last MultiPose run are checked against them."""
        joints = np.asarray(joints, dtype=np.float64)
        ids = np.asarray(ids if ids is not None else [], dtype=np.int64)
        if ids.size and len(ids) != len(joints):
            raise ValueError(f'skeletons: {len(ids)} ids for {len(joints)} people')
        if not (joints.shape == self._joints.shape and np.array_equal(joints, self._joints, equal_nan=True)
                and np.array_equal(ids, self._ids)):
            self._predicted = (predicted_joints(joints, ids, self._joints, self._ids)
                               if ids.size and self._ids.size and joints.shape[1:] == self._joints.shape[1:]
                               else joints)
            self._joints, self._ids = joints, ids
        for c, found in enumerate(self._found):
            camera = self.cameras[c]
            if found is None or camera is None:
                continue
            projected = camera.project(self._joints) if len(self._joints) else np.zeros((0, LIMB_JOINTS, 2))
            self.unexplained[c] = bool(unexplained(found, projected).any())
            self._found[c] = None
