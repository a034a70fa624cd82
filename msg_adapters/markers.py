"""RViz markers: 3D skeletons (per person a sphere list of its joints and a line list of its
bones, coloured by person id so a person keeps its colour over time, each joint and bone as
opaque as it is sure) and the rig's cameras (a frustum and a name each)."""
from __future__ import annotations

from typing import Sequence

import numpy as np
from builtin_interfaces.msg import Duration
from geometry_msgs.msg import Point, Vector3
from std_msgs.msg import ColorRGBA, Header
from visualization_msgs.msg import Marker, MarkerArray

from msg_adapters.skeleton_msg import check_skeletons
from mvpose_ros.core.drawing.colours import (BONE_WIDTH_M, JOINT_DIAMETER_M, TEXT_HEIGHT_M, confidence_alpha,
                                             person_colour)
from mvpose_ros.core.geometry.body import BONES
from mvpose_ros.core.geometry.camera import Camera, image_corners

MAX_MARKER_ID = (1 << 31) - 1  # Marker.id is INT32
_BONE_ENDS = np.array(BONES).ravel()  # (2 * bones,) joint of each LINE_LIST point
FRUSTUM_DEPTH_M = 0.5  # how far from its centre a camera's frustum is drawn
MIN_AXIS_COSINE = 0.5  # corners further out than 60 degrees from the axis are drawn at that distance
CAMERA_RGB = (0.85, 0.85, 0.85)


def _points(xyz: np.ndarray) -> list[Point]:
    return [Point(x=x, y=y, z=z) for x, y, z in xyz.tolist()]


def _duration(seconds: float) -> Duration:
    ns = round(seconds * 1e9)
    return Duration(sec=ns // 1_000_000_000, nanosec=ns % 1_000_000_000)


def skeleton_markers(ids: np.ndarray, joints: np.ndarray, header: Header, *, confidence: np.ndarray,
                     lifetime_s: float) -> MarkerArray:
    """Markers for people ids (P,) with joints (P, 14, 3) metres and their confidence (P, 14)
    (header: the skeletons' header, frame 'world'): DELETEALL first (people who left disappear),
    then per person in increasing id a SPHERE_LIST (ns 'joints', a joint's alpha from its
    confidence) and a LINE_LIST over body.BONES (ns 'bones', a bone's alpha from the less sure of
    its ends), marker id = person id. lifetime_s: RViz drops them after this long without a newer
    message (0: never), so a solver that stops leaves no skeletons behind."""
    ids, joints, confidence = check_skeletons(ids, joints, confidence)
    if ids.size and ids.max() > MAX_MARKER_ID:
        raise ValueError(f'skeleton ids: {ids.max()} exceeds the INT32 marker id range')
    lifetime = _duration(lifetime_s)
    markers = [Marker(header=header, action=Marker.DELETEALL)]
    bone_conf = confidence[:, np.array(BONES)].min(axis=-1)  # (P, B)
    for person_id, xyz, joint_alpha, bone_alpha in zip(ids.tolist(), joints, confidence_alpha(confidence),
                                                       confidence_alpha(bone_conf)):
        r, g, b = person_colour(person_id)
        for ns, kind, scale, points, alpha in (
                ('joints', Marker.SPHERE_LIST,
                 Vector3(x=JOINT_DIAMETER_M, y=JOINT_DIAMETER_M, z=JOINT_DIAMETER_M), xyz, joint_alpha),
                ('bones', Marker.LINE_LIST, Vector3(x=BONE_WIDTH_M), xyz[_BONE_ENDS], np.repeat(bone_alpha, 2))):
            marker = Marker(header=header, ns=ns, id=person_id, type=kind, action=Marker.ADD,
                            scale=scale, color=ColorRGBA(r=r, g=g, b=b, a=1.0), lifetime=lifetime,
                            points=_points(points), colors=[ColorRGBA(r=r, g=g, b=b, a=a) for a in alpha.tolist()])
            marker.pose.orientation.w = 1.0  # identity; RViz rejects a zero quaternion
            markers.append(marker)
    return MarkerArray(markers=markers)


def frustum(camera: Camera, depth: float = FRUSTUM_DEPTH_M) -> np.ndarray:
    """(5, 3) world points: the camera's centre, then its image corners (top left, top right,
    bottom right, bottom left) at `depth` metres along the optical axis (a corner more than
    60 degrees out, as a fisheye has, at twice `depth` along its ray)."""
    rays = camera.directions(image_corners(camera.width, camera.height))  # (4, 3) unit
    # cosine to the optical axis; a fisheye's corners can lie 90 degrees out: drawn as if at 60
    along_axis = np.maximum(rays @ camera.R[2], MIN_AXIS_COSINE)
    return np.concatenate([camera.centre[None], camera.centre + rays * (depth / along_axis)[:, None]])


def camera_markers(cameras: Sequence[Camera], names: Sequence[str], header: Header) -> MarkerArray:
    """Per camera c a LINE_LIST frustum (ns 'frusta', id c) and its name above the centre (ns
    'camera names', id c); they never expire (publish them once, transient local)."""
    markers = []
    r, g, b = CAMERA_RGB
    colour = ColorRGBA(r=r, g=g, b=b, a=1.0)
    edges = np.array([(0, 1), (0, 2), (0, 3), (0, 4), (1, 2), (2, 3), (3, 4), (4, 1)]).ravel()
    for c, (camera, name) in enumerate(zip(cameras, names)):
        corners = frustum(camera)
        lines = Marker(header=header, ns='frusta', id=c, type=Marker.LINE_LIST, action=Marker.ADD,
                       scale=Vector3(x=0.01), color=colour, points=_points(corners[edges]))
        text = Marker(header=header, ns='camera names', id=c, type=Marker.TEXT_VIEW_FACING, action=Marker.ADD,
                      scale=Vector3(z=TEXT_HEIGHT_M), color=colour, text=name)
        text.pose.position.x, text.pose.position.y, text.pose.position.z = (corners[0] + [0, 0, TEXT_HEIGHT_M]).tolist()
        for marker in (lines, text):
            marker.pose.orientation.w = 1.0
            markers.append(marker)
    return MarkerArray(markers=markers)
