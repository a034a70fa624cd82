"""The heatmap_detector node: one camera's 2D people with their joint heatmaps.

Run one per camera, in namespace cam<camera>, so its topics resolve to /cam<c>/...:
backend 'openpose' turns the raw OpenPose output on `openpose` (PointCloud2, encoding A) into
people on `people2d` (PointCloud2, encoding B), one output per input frame, empty when nobody is
seen. A message that cannot be used is logged with its stamp and the reason.
"""
from __future__ import annotations

from rclpy.node import Node
from sensor_msgs.msg import PointCloud2

from msg_adapters.openpose_msg import msg_to_openpose
from msg_adapters.people_msg import people_to_msg
from msg_adapters.stamp import stamp_ns
from mvpose_ros.core.openpose_detector import OpenPoseDetectorConfig, detect_people
from mvpose_ros.nodes.runtime import DATA_QOS, StartupError, declare, load_rig_parameter, rig_parameters, run

BACKENDS = ('openpose',)


class HeatmapDetectorNode(Node):
    """Raw detections of one camera in, 2D people with heatmaps out."""

    def __init__(self) -> None:
        super().__init__('heatmap_detector')
        defaults = OpenPoseDetectorConfig()
        p = declare(self, [
            ('camera', 0, 'index of this camera in the calibration rig; its frame_id is cam<camera>'),
            ('backend', 'openpose', f'2D detector: one of {", ".join(BACKENDS)}'),
            ('stride', defaults.stride, 'heatmap cell size, pixels'),
            ('sigma', defaults.sigma, 'std of the Gaussian rendered at each candidate, pixels'),
            ('secondary_radius', defaults.secondary_radius,
             "other candidates within this fraction of the person's box diagonal also enter its map"),
            *rig_parameters('data/shelf/calibration/calibration_shelf.json'),
        ])
        if p['backend'] not in BACKENDS:
            raise StartupError(f'parameter backend: {p["backend"]!r} is not one of {", ".join(BACKENDS)}')
        cameras = load_rig_parameter(p)
        if not 0 <= p['camera'] < len(cameras):
            raise StartupError(f'parameter camera: {p["camera"]} is not in 0..{len(cameras) - 1} '
                               f'({p["calibration"]} has {len(cameras)} cameras)')
        if not (p['stride'] > 0 and p['sigma'] > 0):
            raise StartupError(f'parameters stride, sigma: must be > 0, got {p["stride"]}, {p["sigma"]}')
        self._frame_id = f'cam{p["camera"]}'
        self._config = OpenPoseDetectorConfig(stride=p['stride'], sigma=p['sigma'],
                                              secondary_radius=p['secondary_radius'])
        self._publisher = self.create_publisher(PointCloud2, 'people2d', DATA_QOS)
        self.create_subscription(PointCloud2, 'openpose', self._on_openpose, DATA_QOS)
        self.get_logger().info(f'{self._frame_id}: backend {p["backend"]}, '
                               f'{self.resolve_topic_name("openpose")} -> {self.resolve_topic_name("people2d")}')

    def _on_openpose(self, msg: PointCloud2) -> None:
        try:
            if msg.header.frame_id != self._frame_id:
                raise ValueError(f'frame_id {msg.header.frame_id!r} is not this camera ({self._frame_id!r})')
            people = detect_people(msg_to_openpose(msg), self._config)
            out = people_to_msg(people, msg.header)
        except ValueError as exc:
            self.get_logger().error(f'openpose stamp {stamp_ns(msg.header.stamp)} ns dropped: {exc}')
            return
        self._publisher.publish(out)


def main(args: list[str] | None = None) -> None:
    run(HeatmapDetectorNode, args)


if __name__ == '__main__':
    main()
