"""ROS 2 message type names and their full message definitions (ros2msg text, dependencies
included as rosbag2 writes them), for writers that embed the schema: rosbag2 MCAP recordings and
the Foxglove WebSocket channels that carry ROS messages as they are (CDR)."""
from __future__ import annotations

import importlib
from functools import lru_cache

from rosbags.typesys import Stores, get_typestore

ROS2MSG = 'ros2msg'  # the schema encoding of a ROS 2 .msg definition in MCAP and Foxglove's protocol
CDR = 'cdr'  # the message encoding of a serialized ROS 2 message


@lru_cache(maxsize=1)
def typestore():
    """The ROS 2 Jazzy types the recordings are written with (rosbags' own copy of the definitions)."""
    return get_typestore(Stores.ROS2_JAZZY)


def type_name(msg_class: type) -> str:
    """'sensor_msgs/msg/PointCloud2' for rclpy's generated class sensor_msgs.msg.PointCloud2."""
    package = msg_class.__module__.split('.')[0]
    return f'{package}/msg/{msg_class.__name__}'


@lru_cache(maxsize=None)
def definition(name: str) -> str:
    """The ros2msg definition of type `name` ('visualization_msgs/msg/MarkerArray') with every
    type it uses after it; KeyError for a type the store does not know."""
    if name not in typestore().fielddefs:
        raise KeyError(f'no ROS 2 message definition for {name}')
    text, _ = typestore().generate_msgdef(name, ros_version=2)
    return text


def message_class(name: str) -> type:
    """rclpy's generated class of type `name` ('sensor_msgs/msg/Image'); ValueError when not installed."""
    package, _, cls = name.partition('/msg/')
    try:
        return getattr(importlib.import_module(f'{package}.msg'), cls)
    except (ImportError, AttributeError):
        raise ValueError(f'message type {name} is not installed') from None
