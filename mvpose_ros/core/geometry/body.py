"""The 14-joint Shelf/Campus body and its mapping from 2D detector formats (BODY25, COCO-17,
MPII-16).

The limb joints (ankles ... wrists) map one-to-one; the two head joints are derived by a head
model: 'paper' (neck and nose, shifted up 10 cm in 3D afterwards, as Schwarcz & Pollard score
it), 'anatomical' (a head centre from the ears and the neck, as VoxelPose/mvpose derive it),
'facing' (the top a fixed offset forward and up from the bottom, the convention of 4D
Association's Shelf evaluation) or 'direct' (detectors that give the head top, like MPII-16).
Head models work in 3D, on the 16 inference joints, so every view contributes the same physical
points.
"""
from __future__ import annotations

import numpy as np

JOINT_NAMES: tuple[str, ...] = (
    'r_ankle', 'r_knee', 'r_hip', 'l_hip', 'l_knee', 'l_ankle',
    'r_wrist', 'r_elbow', 'r_shoulder', 'l_shoulder', 'l_elbow', 'l_wrist',
    'bottom_head', 'top_head',
)
NUM_JOINTS = len(JOINT_NAMES)
BOTTOM_HEAD = 12
TOP_HEAD = 13

BONES: tuple[tuple[int, int], ...] = (
    (0, 1), (1, 2), (2, 3), (3, 4), (4, 5),
    (6, 7), (7, 8), (8, 9), (9, 10), (10, 11),
    (8, 12), (9, 12), (12, 13), (2, 8), (3, 9),
)
# (right, left): ankles, knees, hips, wrists, elbows, shoulders
SYMMETRIC_PAIRS: tuple[tuple[int, int], ...] = ((0, 5), (1, 4), (2, 3), (6, 11), (7, 10), (8, 9))


def _mirror() -> np.ndarray:
    out = np.arange(NUM_JOINTS)
    right, left = np.array(SYMMETRIC_PAIRS).T
    out[right], out[left] = left, right
    return out


MIRROR = _mirror()  # (14,) each joint's left/right counterpart; the head joints map to themselves

BODY25_NAMES: tuple[str, ...] = (
    'nose', 'neck', 'r_shoulder', 'r_elbow', 'r_wrist', 'l_shoulder', 'l_elbow', 'l_wrist',
    'mid_hip', 'r_hip', 'r_knee', 'r_ankle', 'l_hip', 'l_knee', 'l_ankle',
    'r_eye', 'l_eye', 'r_ear', 'l_ear',
    'l_big_toe', 'l_small_toe', 'l_heel', 'r_big_toe', 'r_small_toe', 'r_heel',
)
COCO17_NAMES: tuple[str, ...] = (
    'nose', 'l_eye', 'r_eye', 'l_ear', 'r_ear', 'l_shoulder', 'r_shoulder', 'l_elbow',
    'r_elbow', 'l_wrist', 'r_wrist', 'l_hip', 'r_hip', 'l_knee', 'r_knee', 'l_ankle', 'r_ankle',
)
# EfficientPose channel order (see shared/README.md), not the original MPII annotation order
MPII16_NAMES: tuple[str, ...] = (
    'head_top', 'upper_neck', 'r_shoulder', 'r_elbow', 'r_wrist', 'thorax', 'l_shoulder',
    'l_elbow', 'l_wrist', 'pelvis', 'r_hip', 'r_knee', 'r_ankle', 'l_hip', 'l_knee', 'l_ankle',
)
FORMAT_NAMES: dict[str, tuple[str, ...]] = {
    'body25': BODY25_NAMES, 'coco17': COCO17_NAMES, 'mpii16': MPII16_NAMES,
}


# The joints the 3D stage infers: the 12 limb joints, then what detectors actually see of the
# head. The dataset's bottom_head / top_head are derived from these in 3D by a head model.
INFERENCE_NAMES: tuple[str, ...] = JOINT_NAMES[:12] + ('neck', 'head', 'r_ear', 'l_ear')
NUM_INFERENCE_JOINTS = len(INFERENCE_NAMES)
NECK, HEAD, R_EAR, L_EAR = 12, 13, 14, 15

# Source keypoint of each inference joint per format; None where the format has no such point
# (COCO's neck is the shoulder midpoint; MPII has no ears, and its 'head' is the head top).
_SOURCES: dict[str, tuple[str | None, ...]] = {
    'body25': JOINT_NAMES[:12] + ('neck', 'nose', 'r_ear', 'l_ear'),
    'coco17': JOINT_NAMES[:12] + (None, 'nose', 'r_ear', 'l_ear'),
    'mpii16': JOINT_NAMES[:12] + ('upper_neck', 'head_top', None, None),
}
SOURCE_INDEX: dict[str, np.ndarray] = {
    fmt: np.array([FORMAT_NAMES[fmt].index(n) if n else -1 for n in names]) for fmt, names in _SOURCES.items()
}
BODY25_INFERENCE_JOINTS = SOURCE_INDEX['body25']  # (16,) BODY25 index of each inference joint


def _inference_mirror() -> np.ndarray:
    out = np.arange(NUM_INFERENCE_JOINTS)
    pairs = np.array(SYMMETRIC_PAIRS + ((R_EAR, L_EAR),))
    out[pairs[:, 0]], out[pairs[:, 1]] = pairs[:, 1], pairs[:, 0]
    return out


INFERENCE_MIRROR = _inference_mirror()  # (16,) left/right counterpart of each inference joint

# The limb joints' parents towards the torso and the typical length of the bone between them
# (adult anthropometry: Winter, Biomechanics and Motor Control of Human Movement, segment lengths
# as fractions of a 1.75 m stature; not fitted to any dataset). The hips, neck, head and ears have
# no parent here (-1, length NaN): giving the head and ears one measured worse on Shelf.
_PARENTS: dict[str, tuple[str, float]] = {
    'r_ankle': ('r_knee', 0.43), 'r_knee': ('r_hip', 0.43), 'l_knee': ('l_hip', 0.43), 'l_ankle': ('l_knee', 0.43),
    'r_wrist': ('r_elbow', 0.26), 'r_elbow': ('r_shoulder', 0.33), 'r_shoulder': ('neck', 0.20),
    'l_shoulder': ('neck', 0.20), 'l_elbow': ('l_shoulder', 0.33), 'l_wrist': ('l_elbow', 0.26),
}
INFERENCE_PARENT = np.array([INFERENCE_NAMES.index(_PARENTS[n][0]) if n in _PARENTS else -1
                             for n in INFERENCE_NAMES])  # (16,)
PRIOR_BONE_LENGTH = np.array([_PARENTS[n][1] if n in _PARENTS else np.nan for n in INFERENCE_NAMES])  # (16,) m
# The joints below their parent in a standing, walking or sitting person: knees below hips, ankles below knees
HANGING = np.isin(INFERENCE_NAMES, ('r_knee', 'l_knee', 'r_ankle', 'l_ankle'))  # (16,)
# Where the body puts a joint no camera sees, and near which a joint seen by one camera without a
# parent to hang from takes its depth (hypotheses.py, unseen_joints 'body'): above or below the
# point between two others (the same joint twice for one), by a typical adult length along up
# (metres, negative: below). Legs and arms hang their bone's length from their parent, a hip is
# the trunk's length (0.50 m: Winter's shoulder and hip heights, 0.818 and 0.530 of stature) below
# its shoulder, the neck is the shoulders' midpoint (COCO's neck), and the head point (nose, or
# MPII's head top) stands a head's height above the neck: Shelf's anatomical heads measure
# 0.20-0.22 m from neck to ear midpoint. An ear stands as high above the point between the neck
# and its own shoulder: ears are to the side. A shoulder stands the trunk's length above its hip,
# but only above a hip a camera sees (UNSEEN_FROM_SEEN): hips hang from shoulders, and the two
# rules may not feed each other.
_UNSEEN: dict[str, tuple[str, str, float]] = {
    **{n: (_PARENTS[n][0], _PARENTS[n][0], -_PARENTS[n][1]) for n in ('r_ankle', 'r_knee', 'l_knee', 'l_ankle',
                                                                      'r_wrist', 'r_elbow', 'l_elbow', 'l_wrist')},
    'r_hip': ('r_shoulder', 'r_shoulder', -0.50), 'l_hip': ('l_shoulder', 'l_shoulder', -0.50),
    'r_shoulder': ('r_hip', 'r_hip', 0.50), 'l_shoulder': ('l_hip', 'l_hip', 0.50),
    'neck': ('r_shoulder', 'l_shoulder', 0.0),
    'head': ('neck', 'neck', 0.20), 'r_ear': ('neck', 'r_shoulder', 0.20), 'l_ear': ('neck', 'l_shoulder', 0.20),
}
UNSEEN_FROM = np.array([[INFERENCE_NAMES.index(a) for a in _UNSEEN[n][:2]] if n in _UNSEEN else [-1, -1]
                        for n in INFERENCE_NAMES])  # (16, 2)
UNSEEN_RISE = np.array([_UNSEEN[n][2] if n in _UNSEEN else np.nan for n in INFERENCE_NAMES])  # (16,) m along up
UNSEEN_FROM_SEEN = np.isin(INFERENCE_NAMES, ('r_shoulder', 'l_shoulder'))  # (16,) placed from seen sources only
# How far a person's bones may be from the typical lengths above, as a factor: people of 0.8 to 2.3 m,
# children too, and the spread of where detectors put joints
PLAUSIBLE_BONE_SCALE = (0.45, 1.3)
# The bones above as (joint, parent) pairs of inference joints (10, 2), and their typical lengths (10,) m
LIMB_BONES = np.array([(j, p) for j, p in enumerate(INFERENCE_PARENT) if p >= 0])
LIMB_LENGTHS = PRIOR_BONE_LENGTH[LIMB_BONES[:, 0]]

# 'paper': bottom/top head = neck/nose + 10 cm up (Schwarcz & Pollard's scoring), up being the
#   world's (a rig file's `up`; +z in Shelf and Campus).
# 'anatomical': from the 3D ears and neck, as VoxelPose and mvpose derive it for COCO: head
#   centre = ear midpoint, bottom = midway between neck and head centre, top = as far above the
#   centre as the bottom is below it.
# 'facing': bottom as 'anatomical'; top = bottom + FACING_TOP_M along (the body's facing direction,
#   up): facing is the spine (hip midpoint to neck) x the shoulder line (left to right). The
#   offsets are those of 4D Association's Shelf evaluation (Zhang et al., CVPR 2020), to score
#   with the head convention a peer is scored with.
# 'direct': the detector already gives bottom/top head (MPII upper_neck / head_top).
HEAD_MODELS = ('paper', 'anatomical', 'facing', 'direct')
HEAD_SHIFT_M = 0.10
FACING_TOP_M = (0.125, 0.145)  # forward, up
UP = np.array([0.0, 0.0, 1.0])  # the Shelf and Campus worlds have z up; a rig file's default


def to_inference(keypoints: np.ndarray, fmt: str) -> np.ndarray:
    """Map 2D keypoints (..., K, 3) [u, v, score] of format fmt ('body25', 'coco17', 'mpii16') to
    the 16 inference joints (..., 16, 3). A joint is missing when its score is <= 0 (or NaN) and
    is then returned as (NaN, NaN, 0)."""
    if fmt not in FORMAT_NAMES:
        raise ValueError(f'unknown keypoint format {fmt!r}; expected one of {sorted(FORMAT_NAMES)}')
    keypoints = np.asarray(keypoints, dtype=np.float64)
    if keypoints.shape[-2:] != (len(FORMAT_NAMES[fmt]), 3):
        raise ValueError(f'{fmt} keypoints must be (..., {len(FORMAT_NAMES[fmt])}, 3), '
                         f'got {keypoints.shape}')
    index = SOURCE_INDEX[fmt]
    out = keypoints[..., np.maximum(index, 0), :].copy()
    out[..., index < 0, :] = (np.nan, np.nan, 0.0)
    if fmt == 'coco17':
        names = FORMAT_NAMES[fmt]
        right = keypoints[..., names.index('r_shoulder'), :]
        left = keypoints[..., names.index('l_shoulder'), :]
        out[..., NECK, :2] = 0.5 * (right[..., :2] + left[..., :2])
        out[..., NECK, 2] = np.minimum(right[..., 2], left[..., 2])
    out[~(out[..., 2] > 0)] = (np.nan, np.nan, 0.0)  # one convention for 'missing' downstream
    return out


def finalize_head(joints: np.ndarray, head_model: str, up: np.ndarray = UP) -> np.ndarray:
    """The dataset's 14 joints (..., 14, 3) from the 16 inferred 3D joints (..., 16, 3), metres;
    up (3,): the world's up, a unit vector."""
    if head_model not in HEAD_MODELS:
        raise ValueError(f'unknown head model {head_model!r}; expected one of {HEAD_MODELS}')
    joints = np.asarray(joints, dtype=np.float64)
    out = joints[..., :NUM_JOINTS, :].copy()
    if head_model == 'paper':
        out[..., [BOTTOM_HEAD, TOP_HEAD], :] += HEAD_SHIFT_M * np.asarray(up, dtype=np.float64)
    elif head_model in ('anatomical', 'facing'):
        centre = 0.5 * (joints[..., R_EAR, :] + joints[..., L_EAR, :])
        out[..., BOTTOM_HEAD, :] = 0.5 * (joints[..., NECK, :] + centre)
        out[..., TOP_HEAD, :] = 2.0 * centre - out[..., BOTTOM_HEAD, :]
    if head_model == 'facing':
        hips = 0.5 * (joints[..., 2, :] + joints[..., 3, :])
        facing = np.cross(joints[..., NECK, :] - hips, joints[..., 8, :] - joints[..., 9, :])
        facing /= np.maximum(np.linalg.norm(facing, axis=-1, keepdims=True), np.finfo(np.float64).tiny)
        forward, rise = FACING_TOP_M
        out[..., TOP_HEAD, :] = out[..., BOTTOM_HEAD, :] + forward * facing + rise * np.asarray(up, dtype=np.float64)
    return out


def finalize_confidence(confidence: np.ndarray, head_model: str) -> np.ndarray:
    """Confidence (..., 14) of the dataset's joints from that of the 16 inferred ones (..., 16): a
    derived head joint is as sure as the least sure joint it is made from."""
    if head_model not in HEAD_MODELS:
        raise ValueError(f'unknown head model {head_model!r}; expected one of {HEAD_MODELS}')
    confidence = np.asarray(confidence, dtype=np.float64)
    out = confidence[..., :NUM_JOINTS].copy()
    if head_model == 'anatomical':
        out[..., [BOTTOM_HEAD, TOP_HEAD]] = confidence[..., [NECK, R_EAR, L_EAR]].min(axis=-1, keepdims=True)
    elif head_model == 'facing':
        out[..., BOTTOM_HEAD] = confidence[..., [NECK, R_EAR, L_EAR]].min(axis=-1)
        out[..., TOP_HEAD] = confidence[..., [NECK, R_EAR, L_EAR, 2, 3, 8, 9]].min(axis=-1)
    return out
