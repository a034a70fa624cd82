"""The bp_solver node: per-person 3D hypotheses from the bundles' heatmaps and sliding-window
belief propagation; publishes every frame's 3D skeletons `lag` frames after it arrives, and its
causal estimate at once.

In: people/bundles. Out: skeletons (`lag` frames late, for analysis) and skeletons/live (at once,
for a robot that reacts), PointCloud2 encoding D in the rig's world frame with the bundle's stamp,
one message per bundle; skeletons/markers and cameras/markers for RViz; skeletons/dropped for a
bundle that waited longer than `max_wait` (solving slower than the input), so the queue and the
latency stay bounded. Frames are numbered by arrival; the temporal term uses the real time
between stamps, so frames dropped upstream are bridged.
Behaviour in detail (bad input, idle flush, intrinsics): docs/operations.md#bp_solver."""
from __future__ import annotations

import time
from typing import Any

import numpy as np
import rclpy.logging
from builtin_interfaces.msg import Time
from rclpy.node import Node
from sensor_msgs.msg import PointCloud2
from std_msgs.msg import Header
from visualization_msgs.msg import MarkerArray

from msg_adapters.cdr_header import CLOUD_OVERHEAD, Oversize, deserialise_cloud, header_stamp_ns
from msg_adapters.markers import camera_markers, skeleton_markers
from msg_adapters.people_msg import MAX_PEOPLE, max_bundles_bytes, msg_to_bundles
from msg_adapters.skeleton_msg import skeletons_to_msg
from msg_adapters.stamp import stamp_ns, stamp_of_ns
from mvpose_ros import topics
from mvpose_ros.core.geometry.body import NUM_JOINTS
from mvpose_ros.core.heatmap import load_kernels
from mvpose_ros.core.health.monitor import InputMonitor, NodeMonitor, input_statuses, node_status
from mvpose_ros.core.health.residual import ResidualMonitor, frame_residuals, residual_levels
from mvpose_ros.core.health.status import Status
from mvpose_ros.core.health.thresholds import HealthThresholds
from mvpose_ros.core.inference.solver import Inference3D
from mvpose_ros.core.parameters import Param
from mvpose_ros.core.stage import SOLVER_PARAMETERS, LiveStageParameters, StageConfig, parameter_specs
from mvpose_ros.core.throttled_log import ThrottledLog
from mvpose_ros.core.types import Bundle, FrameResult
from mvpose_ros.nodes.health import NodeHealth
from mvpose_ros.nodes.runtime import (DATA_QOS, LATCHED_QOS, RigIntrinsics, StartupError, declare, live_parameters,
                                      load_rig_parameter, rig_parameters, run)

IDLE_CHECK_S = 0.1
# automatic idle_flush: the pending frames are output after this many typical input intervals
# without input (3: a set or two lost upstream, and the jitter of a loaded graph, do not trigger it)
IDLE_PERIODS = 3
PACE_WINDOW_S = 5.0  # s of receipts the typical interval is the median over
REPORT_EVERY = 100  # frames between timing lines


class _NotReady(ValueError):
    """A bundle with a camera whose CameraInfo has not come yet (logged throttled)."""


# its skeletons callback takes the message info (the DDS receipt time), which the events executor cannot give
EVENTS_EXECUTOR = False


class BpSolverNode(Node):
    """people/bundles in; skeletons, skeletons/live and skeletons/markers out (names relative: see topics)."""

    def __init__(self, **options: Any) -> None:
        """options: rclpy Node's (cli_args: this node's own --ros-args, as in a composed process)."""
        super().__init__('bp_solver', **options)
        load_kernels()
        p = declare(self, [
            *rig_parameters(),
            *parameter_specs(SOLVER_PARAMETERS),
            Param('idle_flush', 0.0, 's without input after which every pending frame is output (0: '
                                     f'{IDLE_PERIODS} x the median time between the inputs of the last '
                                     f'{PACE_WINDOW_S:g} s, at least {IDLE_PERIODS} / frame_rate)', 0.0, 3600.0,
                  live=True),
            Param('marker_lifetime', 1.0, 's a skeleton marker stays in RViz without a newer one (0: forever); '
                                          'keep it above the time between two frames', 0.0, 3600.0, live=True),
            Param('max_wait', 5.0, 's a bundle may wait after DDS received it; an older one is dropped unsolved '
                                   '(logged, counted): bounds the queue when solving is slower than the input '
                                   '(0: never)', 0.0, 3600.0, live=True),
        ])
        rig = load_rig_parameter(p)
        try:
            config = StageConfig.from_params(p)
        except ValueError as exc:
            raise StartupError(f'parameters: {exc}') from None
        if config.solver.inference.window is None:
            raise StartupError('parameter window: must be >= 1 (0, the whole clip, is for offline runs)')
        self._live = LiveStageParameters(p)
        self._world_frame = rig.world_frame
        self._n_cameras = len(rig.cameras)
        self._names = rig.names
        self._intrinsics = None if rig.calibrated else RigIntrinsics(self, rig)
        self._inference = Inference3D(rig.calibrated_cameras() if rig.calibrated else self._intrinsics.known,
                                      config.solver, rig.up)
        self._byte_limit: int | None = None  # of a bundles message, once every camera's size is known
        self._idle = p['idle_flush']
        self._period = 1.0 / p['frame_rate']
        self._marker_lifetime = p['marker_lifetime']
        self._max_wait = p['max_wait']
        self._cameras_sent = False
        self._stamps: dict[int, Time] = {}  # frames pushed, not yet output
        self._next_frame = 0  # the number of the next frame pushed: arrival order
        self._first_ns: int | None = None  # stamp of the first frame pushed: times are relative to it
        self._last_ns: int | None = None  # stamp of the last frame pushed
        self._last_input = time.monotonic()
        self._log = ThrottledLog(self.get_logger())
        self._frames_out = 0
        self._inputs: dict[int, tuple[list[Bundle], float]] = {}  # frames pushed: bundles, arrival (monotonic)
        self._bundles_in = InputMonitor('bundles', time.monotonic())
        self._monitor = NodeMonitor()
        self._health = NodeHealth(self, self._statuses, residual=True)
        self._residuals = ResidualMonitor(self._n_cameras, self._health.thresholds.residual_frames)
        live_names = [s.name for s in parameter_specs(SOLVER_PARAMETERS) if s.live] + ['idle_flush', 'marker_lifetime',
                                                                                       'max_wait']
        live_parameters(self, live_names,
                        self._live.refusal, self._retune)
        self._skeletons = self.create_publisher(PointCloud2, topics.SKELETONS, DATA_QOS)
        self._live_skeletons = self.create_publisher(PointCloud2, topics.SKELETONS_LIVE, DATA_QOS)
        self._dropped = self.create_publisher(Header, topics.SKELETONS_DROPPED, DATA_QOS)
        self._lag = config.solver.inference.lag
        self._markers = self.create_publisher(MarkerArray, topics.MARKERS, DATA_QOS)
        self._camera_markers = self.create_publisher(MarkerArray, topics.CAMERA_MARKERS, LATCHED_QOS)
        self.create_subscription(PointCloud2, topics.BUNDLES, self._on_bundles, DATA_QOS, raw=True)
        self.create_timer(IDLE_CHECK_S, self._on_timer)
        self.get_logger().info(f'window {p["window"]}, lag {p["lag"]}, terms {",".join(p["terms"])}, '
                               f'M={p["hypotheses"]}, {self._n_cameras} cameras, max gap {p["max_gap"]} s'
                               + ('' if rig.calibrated else ', intrinsics from CameraInfo'))

    def _unknown(self, cameras: set[int]) -> list[str]:
        """Names of the given cameras whose intrinsics are still unknown (taking in those now known)."""
        for c in cameras:
            if self._inference.cameras[c] is None:
                self._inference.cameras[c] = self._intrinsics.known[c]
        return [self._names[c] for c in sorted(cameras) if self._inference.cameras[c] is None]

    def _retune(self, changes: dict[str, Any]) -> None:
        config = self._live.apply(changes)
        p = self._live.values
        self._idle = p['idle_flush']
        self._marker_lifetime = p['marker_lifetime']
        self._max_wait = p['max_wait']
        # the stage's live parameters (collision_*, max_gap) take effect through the window's config
        self._inference.window.config = config.solver.inference

    def _on_bundles(self, cdr: bytes, info: dict[str, int]) -> None:
        """A bundles message as bytes with its DDS receipt time: dropped unread when it waited longer
        than max_wait (so a backlog drains at once) or came late, answered with no people unread when
        its bytes exceed what the rig's cameras can send, else deserialised and solved. The input
        counts as idle from the end of this call: a slow solve is not a silent input."""
        try:
            self._take(cdr, info)
        finally:
            self._last_input = time.monotonic()

    def _take(self, cdr: bytes, info: dict[str, int]) -> None:
        arrival = time.monotonic()
        waited = (time.time_ns() - info['received_timestamp']) / 1e9
        received = arrival - max(0.0, waited)  # the input's own pace, not the pace this node takes it at
        try:
            stamp = header_stamp_ns(cdr)
        except ValueError as exc:
            self._bundles_in.received(received, None)
            self._drop_malformed(arrival, cdr, None, exc)
            return
        self._bundles_in.received(received, stamp)
        if self._max_wait and waited > self._max_wait:
            self._bundles_in.dropped(arrival, 'behind')
            self._log.log(('bundles', 'behind'), f'bundles stamp {stamp} ns waited {waited:.2f} s since it was '
                                                 f'received, more than max_wait {self._max_wait:g} s: solving is '
                                                 f'slower than the input; dropped unsolved')
            self._dropped.publish(Header(stamp=stamp_of_ns(stamp), frame_id=self._world_frame))
            return
        if self._last_ns is not None and stamp <= self._last_ns:
            # its output exists or is pending (a duplicate), or the window has moved past it
            cause = 'duplicate' if stamp == self._last_ns else 'late'
            self._bundles_in.dropped(arrival, cause)
            self._log.log(('bundles', cause), f'bundles stamp {stamp} ns came after stamp {self._last_ns} ns: late or '
                                              f'duplicate, dropped', 'error')
            return
        try:  # before deserialising: the message's data would be copied
            self._check_size(len(cdr), CLOUD_OVERHEAD, 'serialised bytes')
        except Oversize as exc:
            self._answer_nobody(stamp, arrival, 'oversize', exc)
            return
        except _NotReady:
            pass  # said once the message is read
        try:
            msg = deserialise_cloud(cdr)
        except ValueError as exc:
            self._drop_malformed(arrival, cdr, stamp, exc)
            return
        self._solve(msg, arrival)

    def _drop_malformed(self, arrival: float, cdr: bytes, stamp: int | None, exc: Exception) -> None:
        self._bundles_in.dropped(arrival, 'malformed')
        self._log.log(('bundles', 'malformed'), f'bundles of {len(cdr)} bytes (stamp {stamp}): {exc}; dropped',
                      'error')

    def _answer_nobody(self, stamp: int, arrival: float, cause: str, exc: Exception) -> None:
        """A bundle that cannot be solved: counted, logged, and answered with no people."""
        self._bundles_in.dropped(arrival, cause)
        self._log.log(('bundles', cause), f'bundles stamp {stamp} ns: {exc}; published with no people', 'error')
        nobody = FrameResult(-1, [], np.zeros((0, NUM_JOINTS, 3)), np.zeros((0, NUM_JOINTS)))
        self._publish_live(nobody, stamp_of_ns(stamp))
        self._publish(nobody, stamp_of_ns(stamp))

    def _solve(self, msg: PointCloud2, arrival: float) -> None:
        """Solve one bundles message (not late: _on_bundles) and publish what is due: its causal
        estimate, and the frame `lag` frames before it (or no people, for a message that cannot be
        solved: logged)."""
        stamp = stamp_ns(msg.header.stamp)
        try:
            self._check_size(len(msg.data))
            bundles = msg_to_bundles(msg)
            for pid, views in bundles:
                bad = [c for c in views if c >= self._n_cameras]
                if bad:
                    raise ValueError(f'person {pid}: camera {bad[0]} is not in the rig of {self._n_cameras}')
            unknown = self._unknown({c for _, views in bundles for c in views})
            if unknown:
                raise _NotReady(f'intrinsics of {", ".join(unknown)} not known yet (no CameraInfo)')
            first = stamp if self._first_ns is None else self._first_ns
            frame = self._next_frame
            results = self._inference.push(frame, bundles, (stamp - first) / 1e9)
            self._first_ns, self._last_ns = first, stamp
            self._next_frame += 1
        except ValueError as exc:
            cause = {_NotReady: 'no intrinsics', Oversize: 'oversize'}.get(type(exc), 'malformed')
            self._answer_nobody(stamp, arrival, cause, exc)
            return
        self._inputs[frame] = (bundles, arrival)
        self._stamps[frame] = msg.header.stamp
        due = [(result, self._stamps.pop(result.frame)) for result in results]
        # the lagged frame first: its budget past the lag is the tighter one (docs/results.md, the lag dial)
        for result, stamp in due:
            self._publish_skeletons(result, stamp)
        # with no lag the output is the causal estimate itself
        self._publish_live(results[0] if self._lag == 0 else self._inference.live(), msg.header.stamp)
        self._monitor.processed_totals(time.monotonic(), self._inference.timer.seconds)
        for result, stamp in due:
            self._after_output(result, stamp)

    def _check_size(self, size: int, slack: int = 0, what: str = 'data bytes') -> None:
        """Oversize for more than `slack` bytes over the data the rig's views of
        people_msg.MAX_PEOPLE people take (a camera whose size is not known yet counts as the largest
        known one); _NotReady before any is known. The bound is computed once every camera is known,
        not per message."""
        limit = self._byte_limit
        if limit is None:
            cameras = self._inference.cameras if self._intrinsics is None else self._intrinsics.known
            sizes = [(c.width, c.height) for c in cameras if c is not None]
            if not sizes:
                raise _NotReady('intrinsics of every camera not known yet (no CameraInfo)')
            missing = self._n_cameras - len(sizes)
            limit = max_bundles_bytes(sizes + [max(sizes, key=lambda s: s[0] * s[1])] * missing)
            if not missing:
                self._byte_limit = limit
        if size > limit + slack:
            raise Oversize(f'{size} {what}, more than the views of {MAX_PEOPLE} people in every camera take '
                           f'({limit}{f" + {slack}" if slack else ""})')

    def _on_timer(self) -> None:
        if not self._cameras_sent:
            self._publish_cameras()
        if not self._stamps:
            return
        now = time.monotonic()
        # never below the nominal period: messages a reader takes in only once it has matched the
        # writer come together at start-up, and would make the input look faster than it is
        typical = max(self._bundles_in.typical_interval(now, PACE_WINDOW_S) or 0.0, self._period)
        idle = self._idle or IDLE_PERIODS * typical
        if now - self._last_input >= idle:
            results = self._inference.flush()
            self.get_logger().info(f'no input for {idle:.2f} s: output the {len(results)} pending frames')
            for result in results:
                self._publish(result, self._stamps.pop(result.frame))

    def _publish_live(self, result: FrameResult, stamp: Time) -> None:
        header = Header(stamp=stamp, frame_id=self._world_frame)
        ids = np.asarray(result.person_ids, dtype=np.int64)
        self._live_skeletons.publish(skeletons_to_msg(ids, result.joints, header, confidence=result.confidence))

    def _publish_cameras(self) -> None:
        """The rig's frusta, once every camera's intrinsics are known."""
        cameras = self._inference.cameras if self._intrinsics is None else self._intrinsics.known
        if any(c is None for c in cameras):
            return
        header = Header(stamp=self.get_clock().now().to_msg(), frame_id=self._world_frame)
        self._camera_markers.publish(camera_markers(cameras, self._names, header))
        self._cameras_sent = True

    def _publish(self, result: FrameResult, stamp: Time) -> None:
        self._publish_skeletons(result, stamp)
        self._after_output(result, stamp)

    def _publish_skeletons(self, result: FrameResult, stamp: Time) -> None:
        header = Header(stamp=stamp, frame_id=self._world_frame)
        ids = np.asarray(result.person_ids, dtype=np.int64)
        self._skeletons.publish(skeletons_to_msg(ids, result.joints, header, confidence=result.confidence))

    def _after_output(self, result: FrameResult, stamp: Time) -> None:
        """What follows an output frame, off the latency path: its markers (while anyone subscribes),
        diagnostics and counts."""
        if self._markers.get_subscription_count():
            ids = np.asarray(result.person_ids, dtype=np.int64)
            self._markers.publish(skeleton_markers(ids, result.joints, Header(stamp=stamp, frame_id=self._world_frame),
                                                   confidence=result.confidence, lifetime_s=self._marker_lifetime))
        self._observe(result, stamp)
        self._frames_out += 1
        if self._frames_out % REPORT_EVERY == 0 and self._inference is not None:
            seconds = self._inference.timer.seconds
            per_frame = ', '.join(f'{name} {1e3 * s / self._frames_out:.1f}' for name, s in seconds.items())
            self.get_logger().info(f'{self._frames_out} frames out; ms per frame: {per_frame}')

    def _observe(self, result: FrameResult, stamp: Time) -> None:
        """Diagnostics of one output frame: its latency and, for a solved frame, the residuals."""
        now = time.monotonic()
        bundles, arrival = self._inputs.pop(result.frame, (None, None))
        capture = (self.get_clock().now().nanoseconds - stamp_ns(stamp)) / 1e9
        self._monitor.delivered(now, None if arrival is None else now - arrival, capture)
        if bundles is not None:
            self._residuals.add(frame_residuals(self._inference.cameras, result.person_ids, result.joints, bundles,
                                                self._health.thresholds.residual_min_score), stamp_ns(stamp))

    def _statuses(self, now: float, t: HealthThresholds) -> list[Status]:
        node = self._health.prefix()
        medians, counts = self._residuals.medians()
        residuals = [
            Status(f'{node}: camera {name} reprojection', level, message,
                   {'residual (px, median)': '' if np.isnan(value) else f'{value:.2f}',
                    'frames with data': str(count), 'of recent frames': str(t.residual_frames),
                    'newest stamp (ns)': '' if self._residuals.newest_stamp is None
                    else str(self._residuals.newest_stamp)}, name)
            for name, value, count, (level, message) in zip(
                self._names, medians, counts, residual_levels(medians, t.residual_ratio, t.residual_floor))]
        return [*input_statuses(node, [self._bundles_in.stats(now, t.window)], t),
                node_status(node, self._monitor.stats(now, t.window), len(self._stamps), t,
                            {'frames out': str(self._frames_out)}),
                *residuals]

    def destroy_node(self) -> None:
        """Log the totals of the problems logged throttled, then destroy the node."""
        if hasattr(self, '_log') and self._log.counts:
            rclpy.logging.get_logger(f'{self.get_logger().name}.totals').info(f'problems: {self._log.summary()}')
        super().destroy_node()


def main(args: list[str] | None = None) -> None:
    """Entry point of `ros2 run mvpose_ros bp_solver`."""
    run(BpSolverNode, args, events=EVENTS_EXECUTOR)


if __name__ == '__main__':
    main()
