"""The message type of a camera's image topic, sensor_msgs/Image or CompressedImage, and the
subscriptions that follow it."""
from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Callable, Hashable

from sensor_msgs.msg import CompressedImage, Image

IMAGE_TYPES = {'sensor_msgs/msg/Image': Image, 'sensor_msgs/msg/CompressedImage': CompressedImage}
TYPE_RECHECK_S = 2.0  # s between graph look-ups of an image topic typed by its name


def image_type_by_name(topic: str) -> type:
    """image_transport's naming: '<base>/compressed' carries CompressedImage, anything else Image."""
    return CompressedImage if topic.rstrip('/').endswith('/compressed') else Image


def image_type(topic: str, publisher_types: list[str]) -> tuple[type, str]:
    """The message type of the image topic `topic` and how it was decided: 'graph' when its
    publishers (the topic_type of get_publishers_info_by_topic; not the topic's types, which hold
    the subscribers' guesses too) use exactly one image type, else 'name'."""
    known = {IMAGE_TYPES[t] for t in publisher_types if t in IMAGE_TYPES}
    if len(known) == 1:
        return known.pop(), 'graph'
    return image_type_by_name(topic), 'name'


@dataclass
class ImageInput:
    """A camera's image topic (resolved), the type it is subscribed with, and how that was
    decided ('graph' or 'name')."""

    camera: str
    topic: str
    kind: type
    typed_by: str


class ImageTypes:
    """The types of a node's camera image topics, kept right while cameras come up: a topic no
    publisher shows yet (a driver started after the node) is typed by its name and looked up again
    every TYPE_RECHECK_S s until a publisher shows; when its publishers use the other type, the
    node's `resubscribe(key)` is called with the input's kind updated (logged)."""

    def __init__(self, node: Any, resubscribe: Callable[[Hashable], None]) -> None:
        """node: an rclpy Node (get_publishers_info_by_topic, create_timer, get_logger)."""
        self._node = node
        self._resubscribe = resubscribe
        self.inputs: dict[Hashable, ImageInput] = {}
        self._timer = None

    def add(self, key: Hashable, camera: str, topic: str) -> ImageInput:
        """Type camera `camera`'s image `topic` (resolved) by its publishers, or its name."""
        kind, how = image_type(topic, self._publisher_types(topic))
        self.inputs[key] = ImageInput(camera, topic, kind, how)
        if how == 'name' and self._timer is None:
            self._timer = self._node.create_timer(TYPE_RECHECK_S, self.recheck)
        return self.inputs[key]

    def recheck(self) -> None:
        """Look the topics typed by name up in the graph again; stops once none is left."""
        for key, image in self.inputs.items():
            if image.typed_by != 'name':
                continue
            found, how = image_type(image.topic, self._publisher_types(image.topic))
            if how != 'graph':
                continue
            image.typed_by = 'graph'
            if found is not image.kind:
                self._node.get_logger().warning(f'{image.camera}: {image.topic} carries {found.__name__}, not '
                                                f'{image.kind.__name__} as its name suggests: subscribing again')
                image.kind = found
                self._resubscribe(key)
        if self._timer is not None and all(i.typed_by != 'name' for i in self.inputs.values()):
            self._timer.cancel()

    def _publisher_types(self, topic: str) -> list[str]:
        return [info.topic_type for info in self._node.get_publishers_info_by_topic(topic)]
