"""RViz markers for 3D skeletons: per person a sphere list of its joints and a line list of its
bones, coloured by person id so a person keeps its colour over time."""
from __future__ import annotations

import colorsys

import numpy as np
from builtin_interfaces.msg import Duration
from geometry_msgs.msg import Point, Vector3
from std_msgs.msg import ColorRGBA, Header
from visualization_msgs.msg import Marker, MarkerArray

from msg_adapters.skeleton_msg import check_skeletons
from mvpose_ros.core.geometry.body import BONES

JOINT_DIAMETER_M = 0.06
BONE_WIDTH_M = 0.03
GOLDEN_RATIO_CONJUGATE = (5.0 ** 0.5 - 1.0) / 2.0
MAX_MARKER_ID = (1 << 31) - 1  # Marker.id is INT32
_BONE_ENDS = np.array(BONES).ravel()  # (2 * bones,) joint of each LINE_LIST point


def person_colour(person_id: int) -> tuple[float, float, float]:
    """(r, g, b) in [0, 1] for a person id: hues step by the golden ratio, so consecutive ids
    get far-apart hues and any few ids stay distinct."""
    r, g, b = colorsys.hsv_to_rgb((int(person_id) * GOLDEN_RATIO_CONJUGATE) % 1.0, 0.85, 0.95)
    return r, g, b


def _points(xyz: np.ndarray) -> list[Point]:
    return [Point(x=x, y=y, z=z) for x, y, z in xyz.tolist()]


def skeleton_markers(ids: np.ndarray, joints: np.ndarray, header: Header) -> MarkerArray:
    """Markers for people ids (P,) with joints (P, 14, 3) metres (header: the skeletons' header,
    frame 'world'): DELETEALL first (people who left disappear), then per person in increasing id a
    SPHERE_LIST (ns 'joints') and a LINE_LIST over body.BONES (ns 'bones'), marker id = person id."""
    ids, joints = check_skeletons(ids, joints)
    if ids.size and ids.max() > MAX_MARKER_ID:
        raise ValueError(f'skeleton ids: {ids.max()} exceeds the INT32 marker id range')
    markers = [Marker(header=header, action=Marker.DELETEALL)]
    for person_id, xyz in zip(ids.tolist(), joints):
        colour = ColorRGBA(a=1.0)
        colour.r, colour.g, colour.b = person_colour(person_id)
        for ns, kind, scale, points in (
                ('joints', Marker.SPHERE_LIST,
                 Vector3(x=JOINT_DIAMETER_M, y=JOINT_DIAMETER_M, z=JOINT_DIAMETER_M), xyz),
                ('bones', Marker.LINE_LIST, Vector3(x=BONE_WIDTH_M), xyz[_BONE_ENDS])):
            marker = Marker(header=header, ns=ns, id=person_id, type=kind, action=Marker.ADD,
                            scale=scale, color=colour, lifetime=Duration(),
                            points=_points(points))
            marker.pose.orientation.w = 1.0  # identity; RViz rejects a zero quaternion
            markers.append(marker)
    return MarkerArray(markers=markers)
