"""The message type of a camera's image topic: sensor_msgs/Image or CompressedImage."""
from __future__ import annotations

from sensor_msgs.msg import CompressedImage, Image

IMAGE_TYPES = {'sensor_msgs/msg/Image': Image, 'sensor_msgs/msg/CompressedImage': CompressedImage}


def image_type_by_name(topic: str) -> type:
    """image_transport's naming: '<base>/compressed' carries CompressedImage, anything else Image."""
    return CompressedImage if topic.rstrip('/').endswith('/compressed') else Image


def image_type(topic: str, graph: list[tuple[str, list[str]]]) -> tuple[type, str]:
    """The message type of the image topic `topic` (resolved) and how it was decided: 'graph' when
    the graph (get_topic_names_and_types()) lists it with exactly one image type, else 'name'."""
    for name, types in graph:
        if name == topic:
            known = {IMAGE_TYPES[t] for t in types if t in IMAGE_TYPES}
            if len(known) == 1:
                return known.pop(), 'graph'
    return image_type_by_name(topic), 'name'
