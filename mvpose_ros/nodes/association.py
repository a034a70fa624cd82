"""The association node: gathers every camera's 2D people of a stamp, tracks them per camera,
matches them across views and publishes the people seen by at least two cameras, each with a
stable 3D id, as one bundle message per stamp (people/bundles, PointCloud2 encoding C).

A camera missing from a stamp is waited for at most `sync_timeout` seconds; the frame then goes
on without it (logged). Every stamp that arrives yields exactly one bundle message, empty when
nobody is seen twice.
"""
from __future__ import annotations

import time
from functools import partial

from rclpy.node import Node
from sensor_msgs.msg import PointCloud2
from std_msgs.msg import Header

from msg_adapters.people_msg import bundles_to_msg, msg_to_people
from msg_adapters.stamp import frame_of_stamp, stamp_ns
from mvpose_ros import topics
from mvpose_ros.core.association.associator import Associator
from mvpose_ros.core.association.stamp_sync import StampSync, SyncedFrame
from mvpose_ros.core.evaluation.datasets import FRAME_RATE
from mvpose_ros.core.stage import ASSOCIATION_PARAMETERS, StageConfig, parameter_specs
from mvpose_ros.nodes.runtime import DATA_QOS, StartupError, declare, load_rig_parameter, rig_parameters, run

EXPIRE_PERIOD_S = 0.05


class AssociationNode(Node):
    """cam<c>/people2d of every camera in, people/bundles out (names relative: see topics)."""

    def __init__(self) -> None:
        super().__init__('association')
        p = declare(self, [
            *rig_parameters(),
            ('sync_timeout', 0.5, 's to wait for a camera missing from a stamp before going on without it'),
            *parameter_specs(ASSOCIATION_PARAMETERS),
            ('frame_rate', FRAME_RATE, 'frames per second of the stamp timeline (frame = stamp * rate)'),
        ])
        self._cameras = load_rig_parameter(p)
        if not (p['sync_timeout'] > 0 and p['frame_rate'] > 0):
            raise StartupError('parameters sync_timeout, frame_rate: must be > 0')
        try:
            config = StageConfig.from_params(p).association
        except ValueError as exc:
            raise StartupError(f'parameters: {exc}') from None
        self._rate = p['frame_rate']
        self._associator = Associator(self._cameras, config)
        self._sync = StampSync(len(self._cameras), p['sync_timeout'])
        self._publisher = self.create_publisher(PointCloud2, topics.BUNDLES, DATA_QOS)
        for c in range(len(self._cameras)):
            self.create_subscription(PointCloud2, topics.camera_topic(c, topics.PEOPLE2D), partial(self._on_people, c),
                                     DATA_QOS)
        self.create_timer(EXPIRE_PERIOD_S, self._on_timer)
        self._last_frame: int | None = None
        self.get_logger().info(f'{len(self._cameras)} cameras, sync timeout {p["sync_timeout"]} s')

    def _on_people(self, camera: int, msg: PointCloud2) -> None:
        stamp = stamp_ns(msg.header.stamp)
        try:
            if msg.header.frame_id != f'cam{camera}':
                raise ValueError(f'frame_id {msg.header.frame_id!r} on the topic of cam{camera}')
            people = msg_to_people(msg)
            released = self._sync.add(stamp, camera, (msg.header, people), time.monotonic())
        except ValueError as exc:
            self.get_logger().error(f'cam{camera} people2d stamp {stamp} ns dropped: {exc}')
            return
        for frame in released:
            self._publish(frame)

    def _on_timer(self) -> None:
        for frame in self._sync.expire(time.monotonic()):
            self._publish(frame)

    def _publish(self, synced: SyncedFrame) -> None:
        header = next(item[0] for item in synced.items if item is not None)
        frame = frame_of_stamp(header.stamp, self._rate)
        if synced.missing:
            self.get_logger().warning(f'stamp {synced.stamp_ns} ns (frame {frame}): no data from '
                                      f'{", ".join(f"cam{c}" for c in synced.missing)}; going on without')
        people = [item[1] if item is not None else None for item in synced.items]
        if self._last_frame is not None and frame <= self._last_frame:
            self.get_logger().error(f'stamp {synced.stamp_ns} ns maps to frame {frame}, not after frame '
                                    f'{self._last_frame}; published empty')
            observations = []
        else:
            observations = self._associator.update(frame, people)
            self._last_frame = frame
        bundles = [(obs.person_id, obs.views) for obs in observations]
        self._publisher.publish(bundles_to_msg(bundles, Header(stamp=header.stamp, frame_id='world')))


def main(args: list[str] | None = None) -> None:
    run(AssociationNode, args)


if __name__ == '__main__':
    main()
