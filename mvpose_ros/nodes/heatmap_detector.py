"""The heatmap_detector node: one camera's 2D people with their joint heatmaps.

Run one per camera, in namespace cam<camera>, so its topics resolve to /cam<c>/...: backend
'openpose' turns the raw OpenPose output on `openpose` (PointCloud2, encoding A), backend 'onnx'
the camera image on `image_raw` (sensor_msgs/Image, bgr8 or rgb8; MoveNet MultiPose and
EfficientPose on onnxruntime, core.onnx_detector) into people on `people2d` (PointCloud2,
encoding B), one output per input frame, empty when nobody is seen. A message that cannot be
used is logged with its stamp and the reason. `camera_info` is checked against the calibration
parameter; a contradiction is logged (once per distinct problem) and the calibration kept.
"""
from __future__ import annotations

import time
from pathlib import Path
from typing import Any

from rclpy.node import Node
from sensor_msgs.msg import CameraInfo, Image, PointCloud2

from msg_adapters.camera_info_msg import check_info
from msg_adapters.image_msg import msg_to_image
from msg_adapters.openpose_msg import msg_to_openpose
from msg_adapters.people_msg import people_to_msg
from msg_adapters.stamp import stamp_ns
from mvpose_ros.core.evaluation.datasets import data_root
from mvpose_ros.core.detection.onnx_detector import MODELS, OnnxDetectorConfig, OnnxPoseDetector
from mvpose_ros.core.detection.openpose_detector import OpenPoseDetectorConfig, detect_people
from mvpose_ros.nodes.runtime import DATA_QOS, StartupError, declare, load_rig_parameter, rig_parameters, run

# backend -> its input topic (relative to the camera namespace)
INPUT_TOPICS = {'openpose': 'openpose', 'onnx': 'image_raw'}
BACKENDS = tuple(INPUT_TOPICS)


class HeatmapDetectorNode(Node):
    """Raw detections of one camera in, 2D people with heatmaps out."""

    def __init__(self) -> None:
        super().__init__('heatmap_detector')
        defaults = OpenPoseDetectorConfig()
        onnx = OnnxDetectorConfig(model_dir=Path())  # its defaults
        p = declare(self, [
            ('camera', 0, 'index of this camera in the calibration rig; its frame_id is cam<camera>'),
            ('backend', 'openpose', f'2D detector: one of {", ".join(BACKENDS)} (input topic '
             f'{", ".join(f"{b}: {t}" for b, t in INPUT_TOPICS.items())})'),
            ('stride', defaults.stride, 'heatmap cell size, pixels'),
            ('sigma', defaults.sigma, 'std of the Gaussian rendered at each candidate (onnx: at each COCO ear), '
             'pixels'),
            ('secondary_radius', defaults.secondary_radius,
             "openpose: other candidates within this fraction of the person's box diagonal also enter its map"),
            ('model', onnx.model, f'onnx: EfficientPose variant, {" or ".join(MODELS)} (<data_root>/models/'
             'efficientpose_<model>.onnx)'),
            ('providers', list(onnx.providers), 'onnx: onnxruntime execution providers, in order of preference'),
            ('threads', onnx.threads, 'onnx: intra-op threads per model (0 = one per core)'),
            ('input_size', onnx.input_size, 'onnx: MultiPose square input side, pixels, a multiple of 32'),
            ('box_margin', onnx.box_margin,
             "onnx: each side of a person's box grows by this fraction of its size before the EfficientPose crop"),
            ('min_person_score', onnx.min_person_score, 'onnx: MultiPose people scoring less are dropped'),
            ('min_joint_score', onnx.min_joint_score,
             'onnx: a joint whose heatmap peak is lower is not detected (empty map)'),
            ('heatmap_floor', onnx.heatmap_floor, "onnx: heatmap cells below this fraction of their map's peak are 0"),
            ('ears', onnx.ears, "onnx: fill the ear joints from MultiPose's COCO ears (the anatomical head model "
             'needs them)'),
            *rig_parameters(),
        ])
        if p['backend'] not in BACKENDS:
            raise StartupError(f'parameter backend: {p["backend"]!r} is not one of {", ".join(BACKENDS)}')
        cameras = load_rig_parameter(p)
        if not 0 <= p['camera'] < len(cameras):
            raise StartupError(f'parameter camera: {p["camera"]} is not in 0..{len(cameras) - 1} '
                               f'({p["calibration"]} has {len(cameras)} cameras)')
        if not (p['stride'] > 0 and p['sigma'] > 0):
            raise StartupError(f'parameters stride, sigma: must be > 0, got {p["stride"]}, {p["sigma"]}')
        self._camera = cameras[p['camera']]
        self._frame_id = f'cam{p["camera"]}'
        self._config = OpenPoseDetectorConfig(stride=p['stride'], sigma=p['sigma'],
                                              secondary_radius=p['secondary_radius'])
        if p['backend'] == 'onnx':
            self._detector = self._onnx_detector(p)  # before subscribing: the graph connects when it is ready
        self._publisher = self.create_publisher(PointCloud2, 'people2d', DATA_QOS)
        topic = INPUT_TOPICS[p['backend']]
        if p['backend'] == 'onnx':
            self.create_subscription(Image, topic, self._on_image, DATA_QOS)
        else:
            self.create_subscription(PointCloud2, topic, self._on_openpose, DATA_QOS)
        # The calibration parameter is what the 3D stage uses; a CameraInfo that disagrees means a
        # wrong file or a re-calibrated camera: said once per distinct problem, never acted on.
        self._info_problems: set[str] = set()
        self.create_subscription(CameraInfo, 'camera_info', self._on_info, DATA_QOS)
        self.get_logger().info(f'{self._frame_id}: backend {p["backend"]}, '
                               f'{self.resolve_topic_name(topic)} -> {self.resolve_topic_name("people2d")}')

    def _on_info(self, msg: CameraInfo) -> None:
        try:
            if msg.header.frame_id != self._frame_id:
                raise ValueError(f'frame_id {msg.header.frame_id!r} is not this camera ({self._frame_id!r})')
            check_info(msg, self._camera)
        except ValueError as exc:
            problem = str(exc)
            if problem not in self._info_problems:
                self._info_problems.add(problem)
                self.get_logger().error(f'camera_info stamp {stamp_ns(msg.header.stamp)} ns contradicts the '
                                        f'calibration parameter: {problem}; the calibration is kept '
                                        f'(said once per problem)')

    @staticmethod
    def _onnx_detector(p: dict[str, Any]) -> OnnxPoseDetector:
        """Both ONNX sessions, created once; a bad value or model file is a StartupError."""
        try:
            config = OnnxDetectorConfig(
                model_dir=data_root(p['data_root'] or None) / 'models', model=p['model'],
                providers=tuple(p['providers']), threads=p['threads'], input_size=p['input_size'],
                box_margin=p['box_margin'], min_person_score=p['min_person_score'],
                min_joint_score=p['min_joint_score'], heatmap_floor=p['heatmap_floor'], stride=p['stride'],
                ears=p['ears'], sigma=p['sigma'])
            return OnnxPoseDetector(config)
        except (FileNotFoundError, ValueError) as exc:  # ModelError is a ValueError
            raise StartupError(f'backend onnx: {" ".join(str(exc).split())}') from None

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

    def _on_image(self, msg: Image) -> None:
        t0 = time.perf_counter()
        try:
            if msg.header.frame_id != self._frame_id:
                raise ValueError(f'frame_id {msg.header.frame_id!r} is not this camera ({self._frame_id!r})')
            bgr = msg_to_image(msg)
            cam = self._camera
            if bgr.shape[:2] != (cam.height, cam.width):
                raise ValueError(f'image size {bgr.shape[1]}x{bgr.shape[0]} is not the calibrated '
                                 f'{cam.width}x{cam.height}')
            out = people_to_msg(self._detector.detect(bgr), msg.header)
        except ValueError as exc:
            self.get_logger().error(f'image stamp {stamp_ns(msg.header.stamp)} ns dropped: {exc}')
            return
        self._publisher.publish(out)
        t = self._detector.timing
        self.get_logger().debug(f'image stamp {stamp_ns(msg.header.stamp)} ns: {t.people} people, MultiPose '
                                f'{1e3 * t.multipose:.0f} ms, EfficientPose {1e3 * t.efficientpose:.0f} ms, '
                                f'in-to-out {1e3 * (time.perf_counter() - t0):.0f} ms')


def main(args: list[str] | None = None) -> None:
    run(HeatmapDetectorNode, args)


if __name__ == '__main__':
    main()
