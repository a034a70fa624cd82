"""A rig's camera frames for TF: per camera, the static transform from the rig's world_frame to its
frame_id, as tf2_ros's static_transform_publisher takes it (launch/rig.launch.py tf:=true starts
one per camera). The graph publishes no TF itself: tf2_msgs is not on PyPI."""
from __future__ import annotations

from mvpose_ros.core.geometry.rig import Rig

TF_PACKAGE = 'tf2_ros'
TF_EXECUTABLE = 'static_transform_publisher'
_TRANSLATION = ('--x', '--y', '--z')
_ROTATION = ('--qx', '--qy', '--qz', '--qw')


def static_transform_nodes(rig: Rig) -> list[dict[str, object]]:
    """One static_transform_publisher per camera, in rig order, as launch_ros Node keyword
    arguments (package, executable, name, arguments). The arguments are its named form (Humble
    on): the camera's position (metres) and orientation (world <- optical, x y z w) as the
    transform world_frame -> frame_id, each number the repr of its float64 (exact). ValueError for a
    camera whose frame_id the rig file leaves to its messages: TF needs it before any comes."""
    nodes = []
    for cam in rig.cameras:
        if cam.frame_id is None:
            raise ValueError(f'{rig.path or "the rig"}: camera {cam.name!r}: tf needs its frame_id in the rig file '
                             f'(the frame its driver stamps, e.g. {cam.name}_optical_frame)')
        pose = [*zip(_TRANSLATION, cam.position), *zip(_ROTATION, cam.orientation)]
        arguments = [text for flag, value in pose for text in (flag, repr(float(value)))]
        nodes.append({'package': TF_PACKAGE, 'executable': TF_EXECUTABLE, 'name': f'{cam.name}_frame',
                      'arguments': [*arguments, '--frame-id', rig.world_frame, '--child-frame-id', cam.frame_id]})
    return nodes
