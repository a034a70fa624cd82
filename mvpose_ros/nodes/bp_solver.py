"""The bp_solver node: per-person 3D hypotheses from the bundles' heatmaps and sliding-window
belief propagation; publishes every frame's 3D skeletons `lag` frames after it arrives.

In: people/bundles. Out: skeletons (PointCloud2 encoding D, frame world: one record per person
joint, empty when nobody is seen) and skeletons/markers (MarkerArray for RViz), both with the input frame's
stamp. Every bundle message yields exactly one skeleton message, but for a late one (a frame not
after the last one taken: a duplicate, or out of order), which is logged and dropped. A gap in
the frame numbers breaks the temporal chains. With no input for `idle_flush` seconds (the end of
a replay, or a stalled graph) every pending frame is decoded and published.
"""
from __future__ import annotations

import time

import numpy as np
from builtin_interfaces.msg import Time
from rclpy.node import Node
from sensor_msgs.msg import PointCloud2
from std_msgs.msg import Header
from visualization_msgs.msg import MarkerArray

from msg_adapters.markers import skeleton_markers
from msg_adapters.people_msg import msg_to_bundles
from msg_adapters.skeleton_msg import skeletons_to_msg
from msg_adapters.stamp import frame_of_stamp, stamp_ns
from mvpose_ros import topics
from mvpose_ros.core.evaluation.datasets import FRAME_RATE
from mvpose_ros.core.geometry.body import NUM_JOINTS
from mvpose_ros.core.inference.solver import Inference3D
from mvpose_ros.core.stage import SOLVER_PARAMETERS, StageConfig, parameter_specs
from mvpose_ros.core.types import FrameResult
from mvpose_ros.nodes.runtime import DATA_QOS, StartupError, declare, load_rig_parameter, rig_parameters, run

IDLE_CHECK_S = 0.1
REPORT_EVERY = 100  # frames between timing lines


class BpSolverNode(Node):
    """people/bundles in, skeletons and skeletons/markers out (names relative: see topics)."""

    def __init__(self) -> None:
        super().__init__('bp_solver')
        p = declare(self, [
            *rig_parameters(),
            *parameter_specs(SOLVER_PARAMETERS),
            ('frame_rate', FRAME_RATE, 'frames per second of the stamp timeline (frame = stamp * rate)'),
            ('idle_flush', 1.0, 's without input after which every pending frame is output'),
        ])
        cameras = load_rig_parameter(p)
        if not (p['frame_rate'] > 0 and p['idle_flush'] > 0):
            raise StartupError('parameters frame_rate, idle_flush: must be > 0')
        try:
            config = StageConfig.from_params(p)
        except ValueError as exc:
            raise StartupError(f'parameters: {exc}') from None
        if config.solver.inference.window is None:
            raise StartupError('parameter window: must be >= 1 (0, the whole clip, is for offline runs)')
        self._n_cameras = len(cameras)
        self._rate = p['frame_rate']
        self._idle = p['idle_flush']
        self._inference = Inference3D(cameras, config.solver)
        self._stamps: dict[int, Time] = {}  # frames pushed, not yet output
        self._last_frame: int | None = None  # the last frame pushed
        self._last_input = time.monotonic()
        self._frames_out = 0
        self._skeletons = self.create_publisher(PointCloud2, topics.SKELETONS, DATA_QOS)
        self._markers = self.create_publisher(MarkerArray, topics.MARKERS, DATA_QOS)
        self.create_subscription(PointCloud2, topics.BUNDLES, self._on_bundles, DATA_QOS)
        self.create_timer(IDLE_CHECK_S, self._on_timer)
        self.get_logger().info(f'window {p["window"]}, lag {p["lag"]}, terms {",".join(p["terms"])}, '
                               f'M={p["hypotheses"]}, {len(cameras)} cameras')

    def _on_bundles(self, msg: PointCloud2) -> None:
        self._last_input = time.monotonic()
        frame = frame_of_stamp(msg.header.stamp, self._rate)
        try:
            bundles = msg_to_bundles(msg)
            for pid, views in bundles:
                bad = [c for c in views if c >= self._n_cameras]
                if bad:
                    raise ValueError(f'person {pid}: camera {bad[0]} is not in the rig of {self._n_cameras}')
            if self._last_frame is not None and frame <= self._last_frame:
                # its output exists or is pending (a duplicate), or the window has moved past it
                self.get_logger().error(f'bundles stamp {stamp_ns(msg.header.stamp)} ns (frame {frame}) came after '
                                        f'frame {self._last_frame}: late or duplicate, dropped')
                return
            results = self._inference.push(frame, bundles)
            self._last_frame = frame
        except ValueError as exc:
            self.get_logger().error(f'bundles stamp {stamp_ns(msg.header.stamp)} ns (frame {frame}): {exc}; '
                                    f'published with no people')
            self._publish(FrameResult(frame, [], np.zeros((0, NUM_JOINTS, 3))), msg.header.stamp)
            return
        self._stamps[frame] = msg.header.stamp
        for result in results:
            self._publish(result, self._stamps.pop(result.frame))

    def _on_timer(self) -> None:
        if self._stamps and time.monotonic() - self._last_input >= self._idle:
            results = self._inference.flush()
            self.get_logger().info(f'no input for {self._idle} s: output the {len(results)} pending frames')
            for result in results:
                self._publish(result, self._stamps.pop(result.frame))

    def _publish(self, result: FrameResult, stamp: Time) -> None:
        header = Header(stamp=stamp, frame_id='world')
        ids = np.asarray(result.person_ids, dtype=np.int64)
        self._skeletons.publish(skeletons_to_msg(ids, result.joints, header))
        self._markers.publish(skeleton_markers(ids, result.joints, header))
        self._frames_out += 1
        if self._frames_out % REPORT_EVERY == 0:
            seconds = self._inference.timer.seconds
            per_frame = ', '.join(f'{name} {1e3 * s / self._frames_out:.1f}' for name, s in seconds.items())
            self.get_logger().info(f'{self._frames_out} frames out; ms per frame: {per_frame}')


def main(args: list[str] | None = None) -> None:
    run(BpSolverNode, args)


if __name__ == '__main__':
    main()
