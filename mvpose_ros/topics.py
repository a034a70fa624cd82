"""The graph's topic names, defined once.

Every name is relative, so a rig's whole graph runs in a namespace of its own
(`--ros-args -r __ns:=/rig1`). A camera's topics live under its own namespace, `cam<c>` for
rig camera c (or the camera's name in the rig file): the detector of a camera runs in that
namespace and uses the bare names.
"""
from __future__ import annotations

# per camera, relative to the camera's namespace
OPENPOSE = 'openpose'  # raw OpenPose output (PointCloud2 encoding A)
IMAGE = 'image_raw'  # sensor_msgs/Image
CAMERA_INFO = 'camera_info'
PEOPLE2D = 'people2d'  # 2D people with heatmaps (encoding B)
OVERLAY = 'overlay/compressed'  # sensor_msgs/CompressedImage: the image with its people and skeletons drawn

# the rig's
BUNDLES = 'people/bundles'  # associated people, every view (encoding C)
SKELETONS = 'skeletons'  # 3D skeletons (encoding D), `lag` frames late
SKELETONS_LIVE = 'skeletons/live'  # the same with no lag: each frame's causal estimate
# std_msgs/Header of a frame that gets no skeletons: a set a whole-rig detector dropped, one short of
# min_cameras (association), or one dropped unsolved (bp_solver, max_wait)
SKELETONS_DROPPED = 'skeletons/dropped'
MARKERS = 'skeletons/markers'  # visualization_msgs/MarkerArray for RViz
CAMERA_MARKERS = 'cameras/markers'  # the rig's camera frusta (MarkerArray), published once, transient local

# The one absolute name: every ROS tool (diagnostic_aggregator, rqt_robot_monitor) listens on
# /diagnostics; each status names its node by its fully qualified name, namespace included.
DIAGNOSTICS = '/diagnostics'  # diagnostic_msgs/DiagnosticArray


def camera_namespace(camera: int | str) -> str:
    """The namespace of a rig camera, relative: its name in the rig file, or for an index c of a
    calibration rig 'cam<c>' (the names such rigs get)."""
    return camera if isinstance(camera, str) else f'cam{camera}'


def camera_topic(camera: int | str, name: str) -> str:
    """A camera's topic relative to the rig's namespace, e.g. camera_topic(0, PEOPLE2D) = 'cam0/people2d'."""
    return f'{camera_namespace(camera)}/{name}'
