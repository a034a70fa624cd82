"""Encoding D: 3D skeletons in the world frame, one PointCloud2 record per person joint (x, y, z
first, so RViz shows the message as a point cloud; confidence last, so readers that look fields
up by name, as the PointCloud2 iterators do, read the older layout's fields unchanged).

The API for subscribers: `msg_to_skeletons(msg)` gives `Skeletons(ids, joints, confidence)`,
joint names and bones in mvpose_ros.core.geometry.body (JOINT_NAMES, BONES).
"""
from __future__ import annotations

from typing import NamedTuple

import numpy as np
from sensor_msgs.msg import PointCloud2
from std_msgs.msg import Header

from msg_adapters.records import UINT32_MAX, from_cloud, to_cloud
from mvpose_ros.core.geometry.body import NUM_JOINTS

SKELETON_DTYPE = np.dtype([('x', '<f4'), ('y', '<f4'), ('z', '<f4'), ('person', '<u4'),
                           ('joint', 'u1'), ('confidence', '<f4')])


class Skeletons(NamedTuple):
    """The people of one message: ids (P,) int64 increasing, joints (P, 14, 3) float64 metres in
    the header's frame (body.JOINT_NAMES order), confidence (P, 14) float64 in [0, 1]."""

    ids: np.ndarray
    joints: np.ndarray
    confidence: np.ndarray


def check_skeletons(ids: np.ndarray, joints: np.ndarray, confidence: np.ndarray) -> Skeletons:
    """Validated ids (P,) int64 (distinct, in UINT32), joints (P, 14, 3) float64 (finite, metres)
    and confidence (P, 14) float64 (in [0, 1]), sorted by id."""
    ids = np.asarray(ids)
    joints = np.asarray(joints, dtype=np.float64)
    confidence = np.asarray(confidence, dtype=np.float64)
    if ids.ndim != 1 or (ids.size and ids.dtype.kind not in 'iu'):
        raise ValueError(f'skeleton ids: expected (P,) integers, got {ids.dtype} {ids.shape}')
    if joints.shape != (len(ids), NUM_JOINTS, 3):
        raise ValueError(f'skeleton joints: expected ({len(ids)}, {NUM_JOINTS}, 3), '
                         f'got {joints.shape}')
    if confidence.shape != (len(ids), NUM_JOINTS):
        raise ValueError(f'skeleton confidence: expected ({len(ids)}, {NUM_JOINTS}), got {confidence.shape}')
    ids = ids.astype(np.int64)
    if ids.size and (ids.min() < 0 or ids.max() > UINT32_MAX):
        raise ValueError(f'skeleton ids: outside UINT32 ({ids.min()}..{ids.max()})')
    order = np.argsort(ids, kind='stable')
    ids, joints, confidence = ids[order], joints[order], confidence[order]
    repeated = np.diff(ids) == 0
    if repeated.any():
        raise ValueError(f'skeleton ids: person {ids[np.argmax(repeated)]} given twice')
    bad = ~np.isfinite(joints).all(axis=-1)
    if bad.any():
        p, j = np.argwhere(bad)[0]
        raise ValueError(f'skeleton of person {ids[p]}: joint {j} not finite '
                         f'({joints[p, j].tolist()})')
    bad = ~((confidence >= 0) & (confidence <= 1))
    if bad.any():
        p, j = np.argwhere(bad)[0]
        raise ValueError(f'skeleton of person {ids[p]}: joint {j} confidence {confidence[p, j]} not in [0, 1]')
    return Skeletons(ids, joints, confidence)


def skeletons_to_msg(ids: np.ndarray, joints: np.ndarray, header: Header, *, confidence: np.ndarray) -> PointCloud2:
    """Encode people ids (P,) with joints (P, 14, 3) metres in the world frame and their
    confidence (P, 14) in [0, 1]; records go in increasing id, joints 0..13."""
    ids, joints, confidence = check_skeletons(ids, joints, confidence)
    records = np.zeros(len(ids) * NUM_JOINTS, dtype=SKELETON_DTYPE)
    xyz = joints.reshape(-1, 3).astype(np.float32)
    if not np.isfinite(xyz).all():
        raise ValueError('skeleton joints: beyond the FLOAT32 range')
    records['x'], records['y'], records['z'] = xyz.T
    records['person'] = np.repeat(ids, NUM_JOINTS)
    records['joint'] = np.tile(np.arange(NUM_JOINTS), len(ids))
    records['confidence'] = confidence.ravel()
    return to_cloud(records, header)


def msg_to_skeletons(msg: PointCloud2) -> Skeletons:
    """Decode encoding D. Every person needs its 14 joints in order 0..13 in one block, people in
    increasing id, finite coordinates, confidence in [0, 1]."""
    records = from_cloud(msg, SKELETON_DTYPE)
    person = records['person']
    ids, counts = np.unique(person, return_counts=True)
    wrong = counts != NUM_JOINTS
    if wrong.any():
        k = int(np.argmax(wrong))
        raise ValueError(f'skeletons: person {ids[k]} has {counts[k]} joint records, '
                         f'expected {NUM_JOINTS}')
    blocks = person.reshape(-1, NUM_JOINTS)
    if (blocks != ids[:, None]).any():
        raise ValueError('skeletons: records not grouped by person in increasing id')
    joint = records['joint'].reshape(-1, NUM_JOINTS)
    wrong = (joint != np.arange(NUM_JOINTS)).any(axis=1)
    if wrong.any():
        k = int(np.argmax(wrong))
        raise ValueError(f'skeletons: joints of person {ids[k]} are {joint[k].tolist()}, '
                         f'expected 0..{NUM_JOINTS - 1} in order')
    joints = np.stack([records['x'], records['y'], records['z']], axis=-1).astype(np.float64)
    return check_skeletons(ids.astype(np.int64), joints.reshape(-1, NUM_JOINTS, 3),
                           records['confidence'].astype(np.float64).reshape(-1, NUM_JOINTS))
