"""3D skeletons as a Foxglove scene (foxglove.messages.SceneUpdate), without ROS: per person one
entity with a sphere per joint, a line list over body.BONES and its id as a label above its
head, in its person colour (as RViz markers, overlays and videos draw it), each joint and bone
as opaque as it is sure (the bone: the less sure of its ends).

An update first deletes every entity older than its stamp, so that people who left disappear,
then sets the people of this frame (Foxglove applies an update's deletions before its entities).
"""
from __future__ import annotations

import numpy as np
from foxglove.messages import (Color, Duration, KeyValuePair, LinePrimitive, LinePrimitiveLineType, Point3, Pose,
                               Quaternion, SceneEntity, SceneEntityDeletion, SceneEntityDeletionType, SceneUpdate,
                               SpherePrimitive, TextPrimitive, Timestamp, Vector3)

from mvpose_ros.core.drawing.colours import (BONE_WIDTH_M, JOINT_DIAMETER_M, TEXT_HEIGHT_M, confidence_alpha,
                                             person_colour)
from mvpose_ros.core.geometry.body import BONES, NUM_JOINTS, UP

LABEL_CLEARANCE_M = 0.15  # the id label this far above the person's highest joint
_BONE_ENDS = np.array(BONES).ravel()  # (2 * bones,) joint of each line-list point
_IDENTITY = Quaternion(x=0.0, y=0.0, z=0.0, w=1.0)
_SIZE = Vector3(x=JOINT_DIAMETER_M, y=JOINT_DIAMETER_M, z=JOINT_DIAMETER_M)


def entity_id(person_id: int) -> str:
    """The scene entity of a person: it replaces that person's earlier one."""
    return f'person {int(person_id)}'


def _timestamp(stamp_ns: int) -> Timestamp:
    sec, nsec = divmod(int(stamp_ns), 1_000_000_000)
    return Timestamp(sec, nsec)


def _pose(xyz) -> Pose:
    return Pose(position=Vector3(x=xyz[0], y=xyz[1], z=xyz[2]), orientation=_IDENTITY)


def skeleton_scene(ids: np.ndarray, joints: np.ndarray, confidence: np.ndarray, stamp_ns: int,
                   frame_id: str = 'world', lifetime_s: float = 0.0, up: np.ndarray = UP) -> SceneUpdate:
    """The scene update of one frame: people ids (P,), joints (P, 14, 3) metres in frame_id,
    confidence (P, 14) in [0, 1], stamped stamp_ns (ns). lifetime_s: Foxglove removes an entity
    this long after its stamp without a newer one (0: never), so that a stopped solver leaves no
    people behind; up (3,): the world's up, where the label goes. ValueError on shapes that do
    not fit."""
    ids = np.asarray(ids)
    joints = np.asarray(joints, dtype=np.float64)
    confidence = np.asarray(confidence, dtype=np.float64)
    if joints.shape != (len(ids), NUM_JOINTS, 3) or confidence.shape != (len(ids), NUM_JOINTS):
        raise ValueError(f'skeletons: expected joints ({len(ids)}, {NUM_JOINTS}, 3) and confidence '
                         f'({len(ids)}, {NUM_JOINTS}), got {joints.shape} and {confidence.shape}')
    stamp = _timestamp(stamp_ns)
    lifetime = Duration.from_secs(lifetime_s)
    up = np.asarray(up, dtype=np.float64)
    joint_alpha = confidence_alpha(confidence).tolist()  # (P, 14)
    bone_alpha = confidence_alpha(confidence[:, np.array(BONES)].min(axis=-1)).tolist()  # (P, B)
    label_at = joints[np.arange(len(ids)), np.argmax(joints @ up, axis=1)] + LABEL_CLEARANCE_M * up  # (P, 3)
    entities = []
    for k, person_id in enumerate(ids.tolist()):
        r, g, b = person_colour(person_id)
        xyz = joints[k].tolist()
        spheres = [SpherePrimitive(pose=_pose(p), size=_SIZE, color=Color(r=r, g=g, b=b, a=a))
                   for p, a in zip(xyz, joint_alpha[k])]
        bones = LinePrimitive(type=LinePrimitiveLineType.LineList, pose=_pose((0.0, 0.0, 0.0)),
                              thickness=BONE_WIDTH_M, scale_invariant=False,
                              points=[Point3(x=p[0], y=p[1], z=p[2]) for p in joints[k][_BONE_ENDS].tolist()],
                              colors=[Color(r=r, g=g, b=b, a=a) for a in np.repeat(bone_alpha[k], 2).tolist()])
        label = TextPrimitive(pose=_pose(label_at[k].tolist()), billboard=True, font_size=TEXT_HEIGHT_M,
                              scale_invariant=False, color=Color(r=r, g=g, b=b, a=1.0), text=str(person_id))
        entities.append(SceneEntity(timestamp=stamp, frame_id=frame_id, id=entity_id(person_id), lifetime=lifetime,
                                    frame_locked=False, metadata=[KeyValuePair(key='id', value=str(person_id))],
                                    spheres=spheres, lines=[bones], texts=[label]))
    return SceneUpdate(deletions=[SceneEntityDeletion(timestamp=stamp, type=SceneEntityDeletionType.All)],
                       entities=entities)
