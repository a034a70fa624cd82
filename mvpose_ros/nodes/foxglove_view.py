"""The live view node: the graph's outputs over Foxglove's WebSocket protocol, for the Foxglove app
(no RViz needed), on `host`:`port` (default 127.0.0.1:8765: this machine only).

It serves the skeletons as a 3D scene (foxglove.SceneUpdate) and forwards the camera frusta,
/diagnostics and every overlay topic as they come. A channel's ROS subscription exists only while
a client listens to it, so without a client it costs the graph nothing.
Channels, parameters, cost and security: docs/visualize.md#the-live-view."""
from __future__ import annotations

import time
from dataclasses import dataclass
from typing import Any, Callable

import foxglove
from diagnostic_msgs.msg import DiagnosticArray
from foxglove.channels import SceneUpdateChannel
from rclpy.event_handler import SubscriptionEventCallbacks
from rclpy.node import Node
from rclpy.qos import QoSProfile
from rclpy.serialization import deserialize_message
from rclpy.subscription import Subscription
from sensor_msgs.msg import CompressedImage, PointCloud2
from visualization_msgs.msg import MarkerArray

from msg_adapters.definitions import CDR, ROS2MSG, definition, type_name
from msg_adapters.skeleton_msg import msg_to_skeletons
from msg_adapters.stamp import stamp_ns
from mvpose_ros.core.parameters import Param
from mvpose_ros.core.throttled_log import ThrottledLog
from mvpose_ros.nodes.health import DIAGNOSTICS_QOS
from mvpose_ros.nodes.runtime import LATCHED_QOS, VIEWER_QOS, StartupError, declare, run
from mvpose_ros.topics import CAMERA_MARKERS, DIAGNOSTICS, OVERLAY, SKELETONS
from mvpose_ros.view.scene import skeleton_scene

SCENE_SUFFIX = '/scene'
NO_EVENTS = SubscriptionEventCallbacks(use_default_callbacks=False)
PARAMETERS = [
    Param('host', '127.0.0.1', 'address the WebSocket server listens on; 0.0.0.0 opens it to every network '
                               'this machine is on (README, Security)'),
    Param('port', 8765, 'TCP port of the WebSocket server (0: any free one, logged)', low=0, high=65535),
    Param('skeletons', SKELETONS, 'the skeletons topic the 3D scene shows (skeletons/live: no lag)'),
    Param('lifetime', 1.0, 's a person stays in the scene without a newer frame (0: until replaced)', low=0.0),
    Param('poll_period', 0.2, 's between looks at which channels have a client', low=0.01),
    Param('discover_period', 2.0, 's between looks for overlay topics in the ROS graph', low=0.1),
]


@dataclass
class Feed:
    """A ROS topic behind a Foxglove channel: its message class and QoS, what a message becomes
    (`on`, given its CDR bytes), and its subscription while a client listens."""

    topic: str
    msg_class: type
    qos: QoSProfile
    channel: Any
    on: Callable[[bytes], None]
    subscription: Subscription | None = None


class FoxgloveView(Node):
    """The Foxglove WebSocket server and its feeds."""

    def __init__(self) -> None:
        super().__init__('foxglove_view')
        p = declare(self, PARAMETERS)
        self._lifetime = float(p['lifetime'])
        self._log = ThrottledLog(self.get_logger())
        self.sent: dict[str, int] = {}
        try:
            self._server = foxglove.start_server(name='mvpose_ros', host=p['host'], port=p['port'])
        except Exception as exc:  # the SDK raises its own error types (address in use, bad host)
            raise StartupError(f'foxglove server on {p["host"]}:{p["port"]}: {exc}') from None
        self.get_logger().info(f'Foxglove WebSocket server on ws://{p["host"]}:{self._server.port}')
        skeletons = self.resolve_topic_name(p['skeletons'])
        scene = SceneUpdateChannel(skeletons + SCENE_SUFFIX)
        self._feeds = [Feed(skeletons, PointCloud2, VIEWER_QOS, scene,
                            lambda cdr, c=scene: self._scene(c, cdr))]
        self._forward(self.resolve_topic_name(CAMERA_MARKERS), MarkerArray, LATCHED_QOS)
        self._forward(DIAGNOSTICS, DiagnosticArray, DIAGNOSTICS_QOS)
        self._discover()
        self.create_timer(p['poll_period'], self._poll)
        self.create_timer(p['discover_period'], self._discover)
        self._started_cpu = time.process_time()  # imports and start-up: the rest is what serving costs

    @property
    def port(self) -> int:
        """The server's TCP port (the one chosen, with port 0)."""
        return self._server.port

    def _forward(self, topic: str, msg_class: type, qos: QoSProfile) -> None:
        name = type_name(msg_class)
        schema = foxglove.Schema(name=name, encoding=ROS2MSG, data=definition(name).encode())
        channel = foxglove.Channel(topic, schema=schema, message_encoding=CDR)
        self._feeds.append(Feed(topic, msg_class, qos, channel, lambda cdr, c=channel: self._send(c, cdr)))

    def _discover(self) -> None:
        """A channel for every overlay topic the ROS graph shows that has none yet."""
        known = {f.topic for f in self._feeds}
        for topic, types in self.get_topic_names_and_types():
            if topic.endswith('/' + OVERLAY) and type_name(CompressedImage) in types and topic not in known:
                self._forward(topic, CompressedImage, VIEWER_QOS)

    def _poll(self) -> None:
        """Subscribe the feeds a client listens to, unsubscribe the others."""
        for feed in self._feeds:
            wanted = feed.channel.has_sinks()
            if wanted and feed.subscription is None:
                feed.subscription = self.create_subscription(feed.msg_class, feed.topic, feed.on, feed.qos,
                                                             raw=True, event_callbacks=NO_EVENTS)
            elif not wanted and feed.subscription is not None:
                self.destroy_subscription(feed.subscription)
                feed.subscription = None

    def _send(self, channel: Any, cdr: bytes) -> None:
        channel.log(cdr)
        self.sent[channel.topic()] = self.sent.get(channel.topic(), 0) + 1

    def _scene(self, channel: SceneUpdateChannel, cdr: bytes) -> None:
        msg = deserialize_message(cdr, PointCloud2)
        try:
            people = msg_to_skeletons(msg)
        except ValueError as exc:
            stamp = stamp_ns(msg.header.stamp)
            self._log.log(("skeletons", str(exc)), f"skeletons of stamp {stamp} ns not shown: {exc}")
            return
        channel.log(skeleton_scene(people.ids, people.joints, people.confidence, stamp_ns(msg.header.stamp),
                                   msg.header.frame_id, self._lifetime))
        self.sent[channel.topic()] = self.sent.get(channel.topic(), 0) + 1

    def destroy_node(self) -> None:
        """Stop the server; log what went out and this process's CPU time (the view's whole cost)."""
        server = getattr(self, '_server', None)
        if server is not None:
            server.stop()
            sent = ', '.join(f'{n} on {t}' for t, n in sorted(self.sent.items())) or 'nothing'
            cpu = time.process_time()
            self.get_logger().info(f'sent {sent}; CPU {cpu:.2f} s, {cpu - self._started_cpu:.2f} s after start-up')
        super().destroy_node()


def main(args: list[str] | None = None) -> None:
    run(FoxgloveView, args, events=False)  # feeds are subscribed while it spins


if __name__ == '__main__':
    main()
