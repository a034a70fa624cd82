"""The heatmap_detector node: the rig's cameras' 2D people with their joint heatmaps.

Backends: 'openpose' turns each camera's raw OpenPose output (`<camera>/openpose`, PointCloud2
encoding A, reliable keep-last as the recorded data it is) into people; 'onnx' detects them in the
camera image (core.detection.onnx_detector). People go out on `<camera>/people2d` (PointCloud2
encoding B) with the input's stamp and frame_id, one message per used input, empty when nobody is
seen. The detector's parameters are core.detection.detector_settings'.

Modes, by the parameter `camera`: one camera (its name in the rig file, or its index), each input
detected in its callback; or the whole rig ('' or 'all'), its inputs detected in synchronised
sets (core.detection.rig_sets; with the onnx backend core.detection.image_sets), the stamp of a
set that reaches the association from no camera published on `skeletons/dropped`.

Names: the rig file gives each camera's topics (absolute, or relative to the rig's namespace) and
frame_id (nodes.detector_cameras). Images are Image or CompressedImage, by their publishers' type
or the topic's name (nodes.image_topics); camera inputs are best effort, keep last `queue_depth`.
Intrinsics come from the rig file, else from the camera's first usable CameraInfo.

Bounded input: every input is checked once, on arrival, before it is queued or worked on, and
nothing is decoded before (DetectorCamera.admit, .openpose). An input that cannot be used is
logged once per camera and cause (core.throttled_log), counted on /diagnostics
(core.health.refusals: a camera every first input of which is refused is an ERROR), and nothing
is published for it: the synchronisation downstream leaves that camera out of its set.
"""
from __future__ import annotations

import threading
import time
from functools import partial
from pathlib import Path
from typing import TYPE_CHECKING, Any

import rclpy.logging
from rcl_interfaces.msg import ParameterDescriptor
from rclpy.exceptions import ParameterException
from rclpy.node import Node
from sensor_msgs.msg import CameraInfo, PointCloud2
from std_msgs.msg import Header

from msg_adapters.image_msg import CheckedImage
from msg_adapters.openpose_msg import msg_to_openpose
from msg_adapters.people_msg import people_to_msg
from msg_adapters.skeleton_msg import msg_to_skeletons
from msg_adapters.stamp import stamp_ns, stamp_of_ns
from mvpose_ros.core.association.approximate_sync import SyncedSet, stamp_rate
from mvpose_ros.core.defaults import FRAME_RATE, SYNC_TIMEOUT_S, data_root, default_max_skew
from mvpose_ros.core.detection.detector_settings import PARAMETERS, SPECS, DetectorConfig
from mvpose_ros.core.detection.image_sets import ImageSetDetector
from mvpose_ros.core.detection.openpose_detector import detect_people
from mvpose_ros.core.detection.rig_sets import RigSets, SetCallbacks, SetSettings
from mvpose_ros.core.heatmap import load_kernels
from mvpose_ros.core.health.monitor import (InputMonitor, NodeMonitor, frame_rate_status, input_statuses,
                                            node_status)
from mvpose_ros.core.health.refusals import Refusals
from mvpose_ros.core.health.status import Level, Status
from mvpose_ros.core.health.thresholds import HealthThresholds
from mvpose_ros.core.parameters import Param
from mvpose_ros.core.throttled_log import ThrottledLog, short_cause
from mvpose_ros.nodes.health import NodeHealth
from mvpose_ros.nodes.detector_cameras import (WHOLE_RIG, DetectorCamera, camera_indices, detector_cameras,
                                               in_namespace, rig_namespace)
from mvpose_ros.nodes.image_topics import ImageTypes
from mvpose_ros.nodes.runtime import (CAMERA_QUEUE_DEPTH, DATA_QOS, RECORDED_INPUT_QOS, RESTART,
                                      StartupError, camera_subscription, declare, live_parameters, load_rig_parameter,
                                      rig_parameters, run)
from mvpose_ros.topics import OPENPOSE, PEOPLE2D, SKELETONS_DROPPED, SKELETONS_LIVE, camera_topic

if TYPE_CHECKING:
    from mvpose_ros.core.detection.onnx_detector import OnnxPoseDetector

# backend -> its input topic in a Shelf-style rig (onnx: the rig camera's `image` topic)
INPUT_TOPICS = {'openpose': OPENPOSE, 'onnx': 'image_raw'}


class HeatmapDetectorNode(Node):
    """Raw detections or images of one camera, or of every rig camera, in; 2D people out."""

    def __init__(self, **options: Any) -> None:
        """options: rclpy Node's (cli_args: this node's own --ros-args, as in a composed process)."""
        super().__init__('heatmap_detector', **options)
        load_kernels()
        p = self._declare()
        self._settings = _settings(p)
        rig = load_rig_parameter(p)
        indices = camera_indices(p['camera'], rig)
        self._whole_rig = len(indices) != 1 or p['camera'] in WHOLE_RIG
        self._backend = self._settings.backend
        self._depth = p['queue_depth']
        if self._backend == 'onnx':
            self._detector = _onnx_detector(self._settings)  # before subscribing: the graph connects when ready
        self._log = ThrottledLog(self.get_logger())
        self._monitor = NodeMonitor()
        namespace = rig_namespace(self.get_namespace(), None if self._whole_rig else rig.cameras[indices[0]].name)
        self._image_types = ImageTypes(self, self._resubscribe)
        self._cameras = detector_cameras(rig, indices, namespace, self._backend, self._settings.upright)
        for cam in self._cameras:
            output = in_namespace(namespace, camera_topic(cam.rig.name, PEOPLE2D))
            cam.output = self.create_publisher(PointCloud2, output, DATA_QOS)
            if self._backend == 'onnx':
                cam.image = self._image_types.add(cam.index, cam.rig.name, cam.input_topic)
        now = time.monotonic()
        self._inputs = {cam.index: InputMonitor(cam.rig.name, now) for cam in self._cameras}
        if self._whole_rig:
            self._start_sets(p, rig.world_frame, namespace)
        for cam in self._cameras:
            self._subscribe(cam)
            camera_subscription(self, CameraInfo, cam.info_topic, partial(self._on_info_cdr, cam), self._depth,
                                raw=True)
            typed = f'{cam.image.kind.__name__}, by {cam.image.typed_by}' if cam.image else 'PointCloud2'
            turned = f', turned {90 * cam.turns} degrees counterclockwise to stand people up' if cam.turns else ''
            self.get_logger().info(f'{cam.rig.name}: backend {self._backend}, {cam.input_topic} ({typed}{turned}) -> '
                                   f'{self.resolve_topic_name(cam.output.topic_name)}')
        self._refusals = Refusals([cam.rig.name for cam in self._cameras], 'image' if self._backend == 'onnx'
                                  else 'openpose input')
        self._unusable: set[str] = set()  # cameras said to be unusable (logged once)
        self._health = NodeHealth(self, self._statuses)
        live_parameters(self, [*(s.name for s in PARAMETERS if s.live), 'sync_timeout', 'max_skew'], self._check,
                        self._retune)

    def _declare(self) -> dict[str, Any]:
        """Declare the parameters (the detector's table, the inputs', the whole rig's, the rig's);
        returns their values."""
        try:
            self.declare_parameter('camera', 0, ParameterDescriptor(
                dynamic_typing=True, read_only=True, additional_constraints=RESTART,
                description="this node's camera: its name in the rig, or its index there (an integer, or a string "
                            f"of digits); {' or '.join(repr(w) for w in WHOLE_RIG)}: every camera of the rig, "
                            'detected in synchronised sets'))
        except ParameterException as exc:
            raise StartupError(f'parameter camera: {exc}') from None
        p = declare(self, [
            *PARAMETERS,
            Param('queue_depth', CAMERA_QUEUE_DEPTH, 'camera inputs (images, CameraInfo): keep-last depth of the '
                  'best-effort subscriptions (a parameter file may override each topic: qos_overrides.<topic>...)',
                  1, 10000),
            Param('frame_rate', FRAME_RATE, 'whole rig: the cameras\' frame rate, Hz (the default of max_skew)',
                  0.1, 1000.0),
            Param('sync_timeout', SYNC_TIMEOUT_S, 'whole rig: s a set waits for a missing camera (not waited for '
                  'again until it sends)', 0.001, 3600.0, live=True),
            Param('min_cameras', 1, 'whole rig: sets with fewer cameras are dropped (counted as unmatched)', 1, 65535),
            Param('waiting_sets', 1, 'whole rig: sets that wait while one is detected; older ones are dropped whole '
                  '(1: only the newest, for live cameras; more for a replay that must lose none)', 1, 10000),
            *rig_parameters(),
        ])
        p |= declare(self, [Param('max_skew', default_max_skew(p['frame_rate']),
                                  'whole rig: s between the oldest and newest stamp of a set (default: half a frame '
                                  'period)', 0.0, 3600.0, live=True)])
        p['camera'] = self.get_parameter('camera').value
        return p

    # --- set-up -------------------------------------------------------------------------------

    def _start_sets(self, p: dict[str, Any], world_frame: str, namespace: str) -> None:
        """The whole rig's synchronised sets (core.detection.rig_sets) and, with the onnx backend,
        their detection (core.detection.image_sets: its crops planned from skeletons/live)."""
        if self._backend == 'onnx':
            self._images = ImageSetDetector(self._detector, [c.camera for c in self._cameras],
                                            self._settings.person_detector_every)
            if self._images.tracking:
                self.create_subscription(PointCloud2, in_namespace(namespace, SKELETONS_LIVE), self._on_skeletons,
                                         DATA_QOS)
        # a set none of whose cameras reaches the association: its stamp goes here, as association
        # and bp_solver announce theirs, so that a subscriber waiting for every frame stops waiting
        self._dropped_sets = self.create_publisher(Header, SKELETONS_DROPPED, DATA_QOS)
        self._world_frame = world_frame
        self._frame_rate = p['frame_rate']
        self._rate_said = False  # whether the cameras' rate off frame_rate is logged (it is on /diagnostics)
        self._intrinsics_in = threading.Condition()  # notified when a camera's first CameraInfo is taken
        settings = SetSettings(p['frame_rate'], p['sync_timeout'], p['max_skew'], p['min_cameras'], p['waiting_sets'])
        callbacks = SetCallbacks(self._detect_set, self._not_synchronised, self._announce_dropped, self._delivered,
                                 lambda text: self.get_logger().error(text))
        try:
            self._sets = RigSets(settings, [self._inputs[c.index] for c in self._cameras], self._monitor, self._log,
                                 callbacks)
        except ValueError as exc:
            raise StartupError(str(exc)) from None
        self.create_timer(min(0.05, p['sync_timeout'] / 2), lambda: self._sets.expire(time.monotonic()))
        names = ', '.join(c.rig.name for c in self._cameras)
        self.get_logger().info(f'whole rig: {len(self._cameras)} cameras ({names}), max_skew '
                               f'{1e3 * p["max_skew"]:.1f} ms, sync_timeout {p["sync_timeout"]} s; while detecting, '
                               f'the newest {p["waiting_sets"]} set(s) wait')

    def _subscribe(self, cam: DetectorCamera) -> None:
        callback = partial(self._on_set_input if self._whole_rig else self._on_input, cam)
        if self._backend == 'openpose':  # recorded data, not a camera: reliable, but bounded
            cam.subscription = self.create_subscription(PointCloud2, cam.input_topic,
                                                        partial(self._on_openpose_cdr, cam, callback),
                                                        RECORDED_INPUT_QOS, raw=True)
            return
        cam.subscription = camera_subscription(self, cam.image.kind, cam.input_topic, callback, self._depth)

    def _resubscribe(self, index: int) -> None:
        """Camera `index`'s image topic has another type than subscribed (ImageTypes)."""
        cam = next(c for c in self._cameras if c.index == index)
        self.destroy_subscription(cam.subscription)
        self._subscribe(cam)

    # --- CameraInfo ---------------------------------------------------------------------------

    def _on_info_cdr(self, cam: DetectorCamera, cdr: bytes) -> None:
        """A CameraInfo as bytes, taken in only when more than its stamp differs (DetectorCamera.info)."""
        try:
            msg = cam.info(cdr)
        except ValueError as exc:
            self._log.log((cam.rig.name, 'camera_info unreadable'),
                          f'{cam.rig.name}: camera_info of {len(cdr)} bytes unreadable: {short_cause(str(exc))}',
                          'error')
            return
        if msg is not None:
            self._on_info(cam, msg)

    def _on_info(self, cam: DetectorCamera, msg: CameraInfo) -> None:
        said = cam.take_info(msg)  # after info(): its content is taken in
        if said is None:
            return
        level, text = said
        if level == 'error':  # rclpy ties a severity to the line that logs
            self.get_logger().error(text)
            return
        self.get_logger().info(text)
        if self._whole_rig:
            with self._intrinsics_in:
                self._intrinsics_in.notify_all()

    # --- detection ----------------------------------------------------------------------------

    def _on_input(self, cam: DetectorCamera, msg: Any) -> None:
        """One-camera mode: detect in the callback (a slower detector drops frames in the
        keep-last subscription, never queues them)."""
        t0 = time.perf_counter()
        arrival = time.monotonic()
        stamp = stamp_ns(msg.header.stamp)
        self._inputs[cam.index].received(arrival, stamp)
        try:
            if self._backend == 'openpose':
                people = detect_people(msg_to_openpose(msg), self._settings.openpose)
            else:
                image = cam.admit(msg, queued=False)
                size = (cam.camera.width, cam.camera.height)
                bgr = cam.decode(image, self._detector.reduced_decoding(*size))
                (people,) = self._detector.detect_set([bgr], sizes=[size], turns=[cam.turns])
        except ValueError as exc:
            self._drop(cam, stamp, str(exc))
            return
        cam.output.publish(people_to_msg(people, msg.header))
        self._refusals.used(cam.rig.name)
        self._delivered([stamp], arrival, time.perf_counter() - t0)

    def _on_set_input(self, cam: DetectorCamera, msg: Any) -> None:
        """Whole-rig mode: an input checked, then into the synchroniser (junk takes no real image's place)."""
        stamp = stamp_ns(msg.header.stamp)
        now = time.monotonic()
        self._inputs[cam.index].received(now, stamp)
        try:
            item = msg if self._backend == 'openpose' else cam.admit(msg, queued=True)  # openpose: _on_openpose_cdr
        except ValueError as exc:
            self._drop(cam, stamp, str(exc))
            return
        self._sets.add(cam.index, stamp, item, now)  # every rig camera: sync index

    def _detect_set(self, synced: SyncedSet) -> int:
        """Detect every input of the set, then publish them together (the set reaches the
        association at once, not spread over the detection time); the cameras published."""
        # a camera's first images come with its first CameraInfo, which may be taken just after
        # them: wait for it as long as a set waits for a camera, rather than lose the first sets
        unknown = [cam for cam, item in zip(self._cameras, synced.items) if item is not None and cam.camera is None]
        if unknown:
            with self._intrinsics_in:
                self._intrinsics_in.wait_for(lambda: all(cam.camera is not None for cam in unknown),
                                             timeout=self._sets.sync.timeout)
        msgs = [item.msg if isinstance(item, CheckedImage) else item for item in synced.items]  # openpose: the msg
        if self._backend == 'onnx':
            found, errors = self._images.detect(synced.stamp_ns, synced.items, [c.camera for c in self._cameras],
                                                [c.turns for c in self._cameras],
                                                lambda c, image, reduce: self._cameras[c].decode(image, reduce))
            for c, exc in errors:
                self._drop(self._cameras[c], stamp_ns(msgs[c].header.stamp), str(exc))
        else:
            found = [None if msg is None else detect_people(msg_to_openpose(msg), self._settings.openpose)
                     for msg in msgs]
        sent = 0
        for cam, msg, people in zip(self._cameras, msgs, found):
            if people is not None:
                cam.output.publish(people_to_msg(people, msg.header))
                self._refusals.used(cam.rig.name)
                sent += 1
        self.get_logger().debug(f'set {synced.index} stamp {synced.stamp_ns} ns: {sent} of {len(self._cameras)} '
                                f'cameras, skew {synced.skew_ns / 1e6:.1f} ms')
        return sent

    def _on_skeletons(self, msg: PointCloud2) -> None:
        try:
            skeletons = msg_to_skeletons(msg)
        except ValueError as exc:
            self._log.log(('skeletons', 'malformed'), f'skeletons/live stamp {stamp_ns(msg.header.stamp)} ns: {exc}; '
                          f'not used to plan the next regions', 'error')
            return
        self._images.track(stamp_ns(msg.header.stamp), skeletons.joints, skeletons.ids)

    def _what(self) -> str:
        return 'openpose' if self._backend == 'openpose' else 'image'

    def _on_openpose_cdr(self, cam: DetectorCamera, callback: Any, cdr: bytes) -> None:
        """An OpenPose input as serialised bytes, deserialised for `callback` once it passes its one
        check (DetectorCamera.openpose)."""
        try:
            msg = cam.openpose(cdr)
        except ValueError as exc:
            stamp = cam.stamp_of(cdr)
            self._inputs[cam.index].received(time.monotonic(), stamp)
            self._drop(cam, stamp, str(exc))
            return
        callback(msg)

    def _drop(self, cam: DetectorCamera, stamp: int | None, cause: str, refused: bool = True) -> None:
        """An input that could not be used: counted for diagnostics, logged throttled per camera and
        cause. refused: for what it is (not for when it came: synchronisation), so that a camera
        every input of which is refused so is said to be unusable (core.health.refusals)."""
        cause = short_cause(cause)
        now = time.monotonic()
        self._inputs[cam.index].dropped(now, cause.split(':')[0])
        if refused:
            self._refusals.refused(cam.rig.name, cause, now)
        what = 'with no readable stamp' if stamp is None else f'stamp {stamp} ns'
        self._log.log((cam.rig.name, cause), f'{cam.rig.name}: {self._what()} {what} dropped: {cause}', 'error')

    def _delivered(self, stamps: list[int], started: float, seconds: float) -> None:
        """Diagnostics of one detection (a message, or a set): its time, latency since `started`
        (monotonic) and from the capture stamps."""
        now = time.monotonic()
        self._monitor.processed(now, {'detection': seconds})
        clock = self.get_clock().now().nanoseconds
        self._monitor.delivered(now, now - started, (clock - min(stamps)) / 1e9 if stamps else None)

    def _not_synchronised(self, camera: int, stamp: int, cause: str) -> None:
        """An input the synchroniser left out of every set: dropped for when it came, not refused."""
        self._drop(self._cameras[camera], stamp, cause, refused=False)

    def _announce_dropped(self, stamp: int) -> None:
        """Publish the stamp (ns) of a set that will get no skeletons on skeletons/dropped."""
        self._dropped_sets.publish(Header(stamp=stamp_of_ns(stamp), frame_id=self._world_frame))

    def _check(self, changes: dict[str, Any]) -> str | None:
        try:
            self._settings.retuned({k: v for k, v in changes.items() if k in SPECS})
            if self._whole_rig:
                self._sets.sync_settings(changes)
        except ValueError as exc:
            return str(exc)
        return None

    def _retune(self, changes: dict[str, Any]) -> None:
        self._settings = self._settings.retuned({k: v for k, v in changes.items() if k in SPECS})
        if self._backend == 'onnx':
            self._detector.config = self._settings.onnx
        if self._whole_rig:
            self._sets.retune(changes)

    def _statuses(self, now: float, t: HealthThresholds) -> list[Status]:
        node = self._health.prefix()
        waiting = self._sets.pending if self._whole_rig else 0
        extra = self._sets.statistics() if self._whole_rig else {}
        statuses = [*input_statuses(node, [i.stats(now, t.window) for i in self._inputs.values()], t),
                    *self._refused_statuses(node, now),
                    node_status(node, self._monitor.stats(now, t.window), waiting, t, extra)]
        if self._whole_rig:
            camera_hz = stamp_rate([i.stamps(now, t.window) for i in self._inputs.values()])
            rate = frame_rate_status(node, camera_hz, self._frame_rate)
            if rate.level != Level.OK and not self._rate_said:
                self.get_logger().warning(rate.message)
            if camera_hz is not None:  # a window too short to tell says nothing either way
                self._rate_said = rate.level != Level.OK
            statuses.append(rate)
        return statuses

    def _refused_statuses(self, node: str, now: float) -> list[Status]:
        """The refusals per camera (core.health.refusals); a camera found unusable is also logged, once."""
        statuses = self._refusals.statuses(node, now)
        for status in statuses:
            if status.level == Level.ERROR and status.hardware_id not in self._unusable:
                self._unusable.add(status.hardware_id)
                self.get_logger().error(f'{status.hardware_id}: {status.message}')
        return statuses

    def destroy_node(self) -> None:
        """Stop the worker (whole-rig mode) and log the totals, then destroy the node."""
        # the context may be shut down already (Ctrl-C): a logger without a rosout publisher
        logger = rclpy.logging.get_logger(f'{self.get_logger().name}.totals')
        if hasattr(self, '_sets'):
            logger.info(self._sets.close())
            if hasattr(self, '_images'):
                self._images.close()
        if hasattr(self, '_log') and self._log.counts:
            logger.info(f'problems: {self._log.summary()}')
        super().destroy_node()


def _settings(p: dict[str, Any]) -> DetectorConfig:
    """The detector's configuration from the parameter values; a bad value is a StartupError."""
    try:
        model_dir = data_root(p['data_root'] or None) / 'models' if p['backend'] == 'onnx' else Path()
        return DetectorConfig.from_params(p, model_dir)
    except (FileNotFoundError, ValueError) as exc:
        raise StartupError(f'parameters: {" ".join(str(exc).split())}') from None


def _onnx_detector(settings: DetectorConfig) -> OnnxPoseDetector:
    """The ONNX sessions, created once; a bad model file is a StartupError."""
    # the one entry to the onnx backend: an openpose node never loads onnxruntime
    from mvpose_ros.core.detection.onnx_detector import OnnxPoseDetector
    try:
        return OnnxPoseDetector(settings.onnx)
    except (FileNotFoundError, ValueError) as exc:  # ModelError is a ValueError
        raise StartupError(f'backend onnx: {" ".join(str(exc).split())}') from None


def main(args: list[str] | None = None) -> None:
    """Entry point of `ros2 run mvpose_ros heatmap_detector`."""
    run(HeatmapDetectorNode, args)


if __name__ == '__main__':
    main()
