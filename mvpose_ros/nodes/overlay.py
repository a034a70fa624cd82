"""The overlay node: each camera's image with what the graph made of it, for rqt_image_view or
RViz's Image display, while the graph runs.

Per camera, `<camera>/overlay/compressed` (CompressedImage, jpeg; the image's own stamp and
frame_id): the image of a skeleton set with its 2D people as detected (thin, white) and the set's
`skeletons/live` reprojected (each person in its RViz colour, with its id). Skeletons that land on
a camera's people show that detection and calibration agree; skeletons beside them show a camera
that has moved. Every input is best effort, so the node never slows the graph down.
Which image goes with a set, and the limits on held and drawn images: docs/own_cameras.md#steps
(step 5) and docs/operations.md#overlay."""
from __future__ import annotations

import time
from collections import Counter
from functools import partial
from typing import Any

import cv2
import numpy as np
import rclpy.logging
from rclpy.node import Node
from rclpy.parameter import Parameter
from sensor_msgs.msg import CompressedImage, PointCloud2
from std_msgs.msg import Header

from msg_adapters.cdr_header import deserialise, header_stamp_ns
from msg_adapters.image_msg import image_to_compressed_msg, to_bgr
from msg_adapters.people_msg import msg_to_people
from msg_adapters.skeleton_msg import msg_to_skeletons
from msg_adapters.stamp import stamp_ns
from mvpose_ros import topics
from mvpose_ros.core.defaults import FRAME_RATE, max_skew_or_default
from mvpose_ros.core.drawing.colours import person_colour
from mvpose_ros.core.drawing.overlay import draw_caption, overlay
from mvpose_ros.core.geometry.body import NUM_JOINTS
from mvpose_ros.core.geometry.camera import Camera
from mvpose_ros.core.health.monitor import NodeMonitor, node_status
from mvpose_ros.core.health.status import Status
from mvpose_ros.core.health.thresholds import HealthThresholds
from mvpose_ros.core.overlay_sets import Member, RecentByStamp, due, set_members
from mvpose_ros.core.parameters import Param
from mvpose_ros.core.throttled_log import ThrottledLog
from mvpose_ros.nodes.health import NodeHealth
from mvpose_ros.nodes.image_topics import ImageTypes
from mvpose_ros.nodes.runtime import (VIEWER_QOS, RigIntrinsics, StartupError, camera_subscription, declare,
                                      live_parameters, load_rig_parameter, rig_parameters, run)

LIVE = ('max_rate', 'jpeg_quality')


class OverlayNode(Node):
    """Images, 2D people and skeletons in; one overlay image per drawn camera and set out."""

    def __init__(self) -> None:
        super().__init__('overlay')
        p = declare(self, [
            *rig_parameters(),
            # An empty list cannot type itself: declared by type, unset means every camera.
            Param('cameras', Parameter.Type.STRING_ARRAY, "names of the rig's cameras to draw; empty = all"),
            Param('max_rate', 2.0, 'images drawn per second per camera, at most (0: every set)', 0.0, 1000.0,
                  live=True),
            Param('reduce', 2, 'draw each image at 1 / reduce of its size (a jpeg is decoded so: cheaper)', 1, 8),
            Param('jpeg_quality', 80, 'quality of the overlay jpeg, 1..100', 1, 100, live=True),
            Param('keep', 2.0, "s an image waits for its set's skeletons (above the graph's latency)", 0.0, 60.0),
            Param('max_image_mib', 64.0, 'MiB of waiting images per camera, at most (oldest dropped first)',
                  0.0, 65536.0),
            Param('frame_rate', FRAME_RATE, "the cameras' frame rate, Hz (the default of max_skew)", 0.1, 1000.0),
            Param('max_skew', 0.0, "s between a set's stamp and its members' (0: half a frame period)", 0.0, 3600.0),
        ])
        rig = load_rig_parameter(p)
        wanted = list(p['cameras'] or [])
        unknown = sorted(set(wanted) - set(rig.names))
        if unknown:
            raise StartupError(f'parameter cameras: {", ".join(unknown)} not in the rig ({", ".join(rig.names)})')
        self._drawn = [c for c, name in enumerate(rig.names) if not wanted or name in wanted]
        self._names = rig.names
        self._intrinsics = RigIntrinsics(self, rig)
        self._period = 1.0 / p['max_rate'] if p['max_rate'] else 0.0
        self._reduce = p['reduce']
        self._quality = p['jpeg_quality']
        self._max_skew_ns = round(1e9 * max_skew_or_default(p['max_skew'], p['frame_rate']))
        keep_ns, max_bytes = round(1e9 * p['keep']), round(p['max_image_mib'] * 2 ** 20)
        n = len(rig.cameras)
        self._images = [RecentByStamp(keep_ns, max_bytes) for _ in range(n)]
        self._people = [RecentByStamp(keep_ns) for _ in range(n)]
        self._last_drawn = [-float('inf')] * n  # monotonic s
        self._outputs: dict[int, Any] = {}
        self._log = ThrottledLog(self.get_logger())
        self._monitor = NodeMonitor()
        self._counts: Counter[str] = Counter()
        self._image_types = ImageTypes(self, self._subscribe_image)
        self._image_subscriptions: dict[int, Any] = {}
        for c in self._drawn:
            rc = rig.cameras[c]
            image = self._image_types.add(c, rc.name, self.resolve_topic_name(rc.image))
            self._subscribe_image(c)
            self.create_subscription(PointCloud2, topics.camera_topic(rc.name, topics.PEOPLE2D),
                                     partial(self._on_people, c), VIEWER_QOS)
            self._outputs[c] = self.create_publisher(CompressedImage, topics.camera_topic(rc.name, topics.OVERLAY),
                                                     VIEWER_QOS)
            self.get_logger().info(f'{rc.name}: {image.topic} ({image.kind.__name__}, by {image.typed_by}) -> '
                                   f'{self._outputs[c].topic_name}')
        self.create_subscription(PointCloud2, topics.SKELETONS_LIVE, self._on_skeletons, VIEWER_QOS)
        self.create_subscription(Header, topics.SKELETONS_DROPPED, self._on_dropped, VIEWER_QOS)
        self._health = NodeHealth(self, self._statuses)
        live_parameters(self, LIVE, lambda _: None, self._retune)

    def _retune(self, changes: dict[str, Any]) -> None:
        if 'max_rate' in changes:
            self._period = 1.0 / changes['max_rate'] if changes['max_rate'] else 0.0
        self._quality = changes.get('jpeg_quality', self._quality)

    def _subscribe_image(self, camera: int) -> None:
        """Subscribe camera `camera`'s images with the type ImageTypes has for them (again, when it
        found the other type)."""
        if camera in self._image_subscriptions:
            self.destroy_subscription(self._image_subscriptions[camera])
        image = self._image_types.inputs[camera]
        self._image_subscriptions[camera] = camera_subscription(self, image.kind, image.topic,
                                                                partial(self._on_image, camera, image.kind), raw=True)

    def _on_image(self, camera: int, kind: type, cdr: bytes) -> None:
        # kept serialised, with its type: most are never drawn, and deserialising each cost about
        # as much as the rest of receiving it for raw images (docs/own_cameras.md)
        try:
            stamp = header_stamp_ns(cdr)
        except ValueError as exc:
            self._log.log((self._names[camera], 'image unreadable'), f'{self._names[camera]}: image not held: {exc}')
            return
        self._images[camera].add(stamp, (kind, cdr), len(cdr))

    def _on_people(self, camera: int, msg: PointCloud2) -> None:
        # kept as it came: most are never drawn, so most are never decoded
        self._people[camera].add(stamp_ns(msg.header.stamp), msg)

    def _detections(self, camera: int, msg: PointCloud2 | None) -> list:
        """The 2D people of a held people2d message (none when there is none, or it does not decode)."""
        if msg is None:
            return []
        try:
            return msg_to_people(msg)
        except ValueError as exc:
            self._log.log((self._names[camera], str(exc)), f'{self._names[camera]}: people2d not drawn: {exc}')
            return []

    def _on_skeletons(self, msg: PointCloud2) -> None:
        try:
            ids, joints, _ = msg_to_skeletons(msg)
        except ValueError as exc:
            self._log.log(('skeletons/live', str(exc)), f'skeletons/live not drawn: {exc}')
            return
        self._draw_set(stamp_ns(msg.header.stamp), ids, joints)

    def _on_dropped(self, msg: Header) -> None:
        self._draw_set(stamp_ns(msg.stamp), None, np.zeros((0, NUM_JOINTS, 3)))

    def _draw_set(self, stamp: int, ids: np.ndarray | None, joints: np.ndarray) -> None:
        """Draw the set stamped `stamp` in every drawn camera that is due; ids None: a dropped set."""
        start = time.monotonic()
        self._counts['sets'] += 1
        # most sets are due in no camera (max_rate): look their members up only for one that is
        now_due = [c for c in self._drawn if due(start, self._last_drawn[c], self._period, ids is None)]
        if not now_due:
            return
        members = {m.camera: m for m in set_members(stamp, self._max_skew_ns, self._images, self._people)}
        cameras = self._intrinsics.known
        drawn = 0
        for c in now_due:
            member = members.get(c)
            if member is None or cameras[c] is None:
                self._counts['no image held' if member is None else 'no intrinsics yet'] += 1
                continue
            try:
                image = self._draw(member, cameras[c], stamp, ids, joints)
            except ValueError as exc:
                name = self._names[c]
                self._log.log((name, str(exc)), f'{name}: image of stamp {member.stamp_ns} not drawn: {exc}')
                continue
            self._outputs[c].publish(image)
            self._last_drawn[c] = start
            drawn += 1
        self._counts['images drawn'] += drawn
        if drawn:
            self._monitor.processed(time.monotonic(), {'draw': (time.monotonic() - start) / drawn})

    def _draw(self, member: Member, camera: Camera, stamp: int, ids: np.ndarray | None,
              joints: np.ndarray) -> CompressedImage:
        """The overlay of one camera's member of a set (ValueError: its image does not deserialise or
        decode)."""
        kind, cdr = member.image
        image = deserialise(cdr, kind)
        bgr = to_bgr(image, (camera.width, camera.height), self._reduce)
        size = (round(camera.width / self._reduce), round(camera.height / self._reduce))
        if bgr.shape[1] > size[0]:  # raw images come whole
            bgr = cv2.resize(bgr, size, interpolation=cv2.INTER_AREA)
        people = [] if ids is None else ids.tolist()
        out = overlay(bgr, camera, self._detections(member.camera, member.people), joints,
                      [person_colour(i) for i in people],
                      scale=bgr.shape[1] / camera.width, labels=[f'id {i}' for i in people])
        draw_caption(out, f'{self._names[member.camera]}  set {stamp / 1e9:.3f} s  '
                     + ('no skeletons: set dropped' if ids is None else f'{len(people)} people'))
        return image_to_compressed_msg(out, image.header, 'jpeg', self._quality)

    def _statuses(self, now: float, t: HealthThresholds) -> list[Status]:
        counts = {k: str(v) for k, v in sorted(self._counts.items())}
        return [node_status(self._health.prefix(), self._monitor.stats(now, t.window), 0, t, counts)]

    def destroy_node(self) -> None:
        """Log what was drawn and the problems logged throttled, then destroy the node."""
        if hasattr(self, '_counts'):
            totals = ', '.join(f'{k} {v}' for k, v in sorted(self._counts.items())) or 'nothing'
            rclpy.logging.get_logger(f'{self.get_logger().name}.totals').info(
                f'{totals}; problems: {self._log.summary()}')
        super().destroy_node()


def main(args: list[str] | None = None) -> None:
    """Entry point of `ros2 run mvpose_ros overlay`."""
    run(OverlayNode, args)


if __name__ == '__main__':
    main()
