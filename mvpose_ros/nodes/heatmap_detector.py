"""The heatmap_detector node: the rig's cameras' 2D people with their joint heatmaps.

Backends: 'openpose' turns each camera's raw OpenPose output (`<camera>/openpose`, PointCloud2
encoding A, reliable keep-last as the recorded data it is) into people; 'onnx' detects them in the
camera image (MoveNet MultiPose, and EfficientPose when `heatmaps` is efficientpose or fused, on
onnxruntime, core.detection.onnx_detector). People go out on `<camera>/people2d` (PointCloud2
encoding B) with the input's stamp and frame_id, one message per used input, empty when nobody is
seen.

Modes, by the parameter `camera`:

- one camera: its name in the rig file ('cam2', 'left') or its index in the rig (2 or '2'). Run
  one node per camera; each input is detected in its callback.
- the whole rig: '' or 'all'. One node takes every camera. Inputs are grouped into synchronised
  sets (core.association.approximate_sync: stamps within `max_skew`, a missing camera waited for at most
  `sync_timeout`); a worker thread detects one set at a time and publishes every camera's people of the set
  together, each with that camera's own stamp and frame_id. While it is busy only the newest
  released set waits: an older waiting set is dropped whole and counted (a throttled warning, and
  the totals when the node stops), so latency stays bounded by about two sets' detection time and
  no queue grows (camera subscriptions keep the last `queue_depth` messages; the synchroniser
  keeps at most a sync_timeout's worth of frames per camera). The stamp of a set that reaches
  the association from no camera (dropped whole, short of `min_cameras`, or none of its images
  usable) goes out on `skeletons/dropped` (std_msgs/Header, the rig's world frame), as association
  and bp_solver announce the frames they drop. With the onnx backend and `person_detector_every`
  K > 1, MultiPose searches the whole images of every K-th set only; in the sets between, where the
  newest skeletons on `skeletons/live` (of the rig's namespace) project: MultiPose searches only
  that region (heatmaps multipose, core.detection.tracked_crops.people_region) or EfficientPose takes those
  crops.

Names: the rig file gives each camera's topics (absolute, or relative to the rig's namespace)
and, optionally, frame_id; without it, the frame_id of the camera's first CameraInfo or input is
the camera's from then on (core.geometry.frame_id). The rig's namespace is the node's own, except
that a one-camera node whose namespace ends with the camera's name (the Shelf graph's `/cam1`, or
`/rig/cam1`) is in the camera's namespace: the rig's is then its parent. Outputs are `<camera name>/people2d` there.

Image type: sensor_msgs/Image or CompressedImage (jpeg, png), its publishers' when one is known at
start-up (get_publishers_info_by_topic), else by image_transport's naming: a topic ending in
'/compressed' is CompressedImage, any other an Image. A topic decided by its name is looked up
again every image_topics.TYPE_RECHECK_S s until a publisher shows; if that has the other type,
the subscription is re-made (logged; nodes.image_topics.ImageTypes). A JPEG is decoded shrunk by
as much as the detector allows (OnnxPoseDetector.reduced_decoding: with heatmaps 'multipose', down
to MultiPose's input side), its people mapped back to the camera's pixels.

QoS: images and CameraInfo are camera inputs (runtime.camera_subscription): best effort, keep
last `queue_depth`, so best-effort (sensor data) and reliable publishers both connect; the
parameter file can override them (qos_overrides.<topic>.subscription.*).

Intrinsics: from the rig file, else from the camera's first usable CameraInfo (images wait
for it: dropped, with the reason). A CameraInfo contradicting the intrinsics in use (of rectified
images, their R too) is logged once per camera and problem and never acted on; one that differs
from the last by its stamp alone is not even deserialised.

Bounded input: every input is checked before it is queued or worked on (_admit, no decoding):
the camera's frame_id; an image against its camera's size (the data at most what such an image
takes, encoded_image.max_image_bytes; the Image fields or the JPEG/PNG header declaring exactly that
size), OpenPose output against openpose_msg.max_openpose_bytes. OpenPose output is taken as
serialised bytes, its frame_id and size read there (msg_adapters.cdr_header), and deserialised only
when they pass: a flood of junk costs a check per message, not its message objects. What the
middleware keeps is bounded by the keep-last depth of the subscriptions.

An input that cannot be used (another frame_id, too large, an encoding or size that does not decode,
no intrinsics yet, out of sync) is logged once per camera and cause, with its stamp, and counted
after that (a throttled summary, and the totals when the node stops); the node goes on. That
camera is left out of that stamp: nothing is published for it, so the synchronisation downstream
leaves it out of its set. An empty people2d would instead claim the camera saw nobody.
A cause that repeats is logged at most every few seconds with a count (core.throttled_log).

Diagnostics (nodes.health, on /diagnostics): per camera the input rate, drops by cause, sync
offset (whole rig) and silence, and its inputs refused since the start by cause: ERROR, and logged
once, when every one of a camera's first inputs was refused for one cause (core.health.refusals:
a wrong rig file or topic, which `mvpose-graph` stops on); the node's ms per detection, waiting
sets and latency. Live
parameters: secondary_radius, box_margin, min_person_score, min_joint_score, heatmap_floor,
sync_timeout, max_skew and the diagnostics thresholds; the others are read-only.
"""
from __future__ import annotations

import math
import threading
import time
import traceback
from collections import Counter
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field, replace
from functools import partial
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
import rclpy.logging
from rcl_interfaces.msg import ParameterDescriptor
from rclpy.exceptions import ParameterException
from rclpy.node import Node
from rclpy.subscription import Subscription
from sensor_msgs.msg import CameraInfo, CompressedImage, Image, PointCloud2
from std_msgs.msg import Header

from msg_adapters.camera_info_msg import check_info, info_camera
from msg_adapters.cdr_header import (CLOUD_OVERHEAD, after_stamp, deserialise, deserialise_cloud,
                                     header_frame_id, header_stamp_ns)
from msg_adapters.image_msg import check_camera_image, to_bgr
from msg_adapters.openpose_msg import max_openpose_bytes, msg_to_openpose
from msg_adapters.people_msg import people_to_msg
from msg_adapters.skeleton_msg import msg_to_skeletons
from msg_adapters.stamp import stamp_ns, stamp_of_ns
from mvpose_ros.core.association.approximate_sync import ApproximateSync, SyncedSet, stamp_rate
from mvpose_ros.core.defaults import FRAME_RATE, SYNC_TIMEOUT_S, data_root, default_max_skew
from mvpose_ros.core.detection.newest_queue import NewestQueue
from mvpose_ros.core.detection.onnx_config import HEATMAP_SOURCES, MODELS, OnnxDetectorConfig
from mvpose_ros.core.detection.openpose_detector import OpenPoseDetectorConfig, detect_people
from mvpose_ros.core.detection.tracked_crops import CropPlanner
from mvpose_ros.core.detection.upright import UPRIGHT, upright_turns
from mvpose_ros.core.geometry.body import NUM_JOINTS
from mvpose_ros.core.geometry.camera import Camera
from mvpose_ros.core.geometry.frame_id import CameraFrameId
from mvpose_ros.core.geometry.rig import Rig, RigCamera
from mvpose_ros.core.health.monitor import (InputMonitor, NodeMonitor, frame_rate_status, input_statuses,
                                            node_status)
from mvpose_ros.core.health.refusals import Refusals
from mvpose_ros.core.health.status import Level, Status
from mvpose_ros.core.health.thresholds import HealthThresholds
from mvpose_ros.core.parameters import Param
from mvpose_ros.core.throttled_log import ThrottledLog, short_cause
from mvpose_ros.nodes.health import NodeHealth
from mvpose_ros.nodes.image_topics import ImageInput, ImageTypes
from mvpose_ros.nodes.runtime import (CAMERA_QUEUE_DEPTH, DATA_QOS, RECORDED_INPUT_QOS, RESTART,
                                      StartupError, camera_subscription, declare, live_parameters, load_rig_parameter,
                                      rig_parameters, run)
from mvpose_ros.topics import OPENPOSE, PEOPLE2D, SKELETONS_DROPPED, SKELETONS_LIVE, camera_topic

if TYPE_CHECKING:
    from mvpose_ros.core.detection.onnx_detector import OnnxPoseDetector

# backend -> its input topic in a Shelf-style rig (onnx: the rig camera's `image` topic)
INPUT_TOPICS = {'openpose': OPENPOSE, 'onnx': 'image_raw'}
BACKENDS = tuple(INPUT_TOPICS)
WHOLE_RIG = ('', 'all')  # values of `camera` meaning one node for every camera
# Skeletons older than this, against a set's stamp, place no one (the whole image is searched):
# a few sets at the onnx backend's 2-5 sets per second, a walk of about a metre.
TRACK_MAX_AGE_S = 1.0
# parameter -> the detector configuration field it sets, applied live
LIVE_DETECTOR = {'openpose': ('secondary_radius',),
                 'onnx': ('box_margin', 'min_person_score', 'min_joint_score', 'heatmap_floor')}


def rig_namespace(node_namespace: str, camera: str | None) -> str:
    """The rig's namespace of a node in node_namespace: the same, or for a one-camera node (camera:
    its name) whose last namespace component is that name, the parent."""
    parts = [p for p in node_namespace.split('/') if p]
    if camera is not None and parts and parts[-1] == camera:
        parts.pop()
    return '/' + '/'.join(parts)


def in_namespace(namespace: str, topic: str) -> str:
    """A rig topic (absolute, or relative to the rig's namespace) as an absolute name."""
    if topic.startswith('/'):
        return topic
    return f'{namespace.rstrip("/")}/{topic}'


def decode_image(msg: Image | CompressedImage, camera: Camera, reduce: int = 1) -> Any:
    """(H, W, 3) uint8 BGR of a camera image of the calibrated size camera.width x camera.height
    (to_bgr: an Image's fields, a CompressedImage's jpeg/png header checked before decoding, the
    data's size against what such an image takes first; a jpeg at 1/reduce of that size).
    ValueError of one line otherwise."""
    return to_bgr(msg, (camera.width, camera.height), reduce)


def _size(camera: Camera) -> tuple[int, int]:
    return camera.width, camera.height


@dataclass
class _Camera:
    """One camera this node detects: its rig entry, topics, intrinsics once known, output."""

    index: int
    rig: RigCamera
    input_topic: str  # absolute
    info_topic: str  # absolute
    output: Any  # Publisher
    camera: Camera | None = None
    source: str = 'the rig file'  # where the intrinsics came from
    image: ImageInput | None = None  # onnx: its image topic's type (openpose: PointCloud2)
    subscription: Subscription | None = None
    info_problems: set[str] = field(default_factory=set)
    info_content: bytes | None = None  # cdr_header.after_stamp of the last CameraInfo taken in
    turns: int = 0  # onnx: quarter turns that stand its image up (upright.upright_turns)
    frame_id: CameraFrameId = field(init=False)

    def __post_init__(self) -> None:
        self.frame_id = CameraFrameId(self.rig.name, self.rig.frame_id)


class HeatmapDetectorNode(Node):
    """Raw detections or images of one camera, or of every rig camera, in; 2D people out."""

    def __init__(self, **options: Any) -> None:
        """options: rclpy Node's (cli_args: this node's own --ros-args, as in a composed process)."""
        super().__init__('heatmap_detector', **options)
        defaults = OpenPoseDetectorConfig()
        onnx = OnnxDetectorConfig(model_dir=Path())  # its defaults
        try:
            self.declare_parameter('camera', 0, ParameterDescriptor(
                dynamic_typing=True, read_only=True, additional_constraints=RESTART,
                description="this node's camera: its name in the rig, or its index there (an integer, or a string "
                            f"of digits); {' or '.join(repr(w) for w in WHOLE_RIG)}: every camera of the rig, "
                            'detected in synchronised sets'))
        except ParameterException as exc:
            raise StartupError(f'parameter camera: {exc}') from None
        p = declare(self, [
            Param('backend', 'openpose', f'2D detector: one of {", ".join(BACKENDS)} (input: openpose: '
                  "<camera>/openpose; onnx: the rig camera's image topic)"),
            Param('stride', defaults.stride, 'heatmap cell size, pixels', 0.5, 256.0),
            Param('sigma', defaults.sigma, 'std of the Gaussian rendered at each candidate (onnx: at each COCO ear), '
                  'pixels', 0.1, 1000.0),
            Param('secondary_radius', defaults.secondary_radius,
                  "openpose: other candidates within this fraction of the person's box diagonal also enter its map",
                  0.0, 10.0, live=True),
            Param('heatmaps', onnx.heatmaps, f'onnx: heatmap source, {" or ".join(HEATMAP_SOURCES)}: EfficientPose on '
                  "each person's crop, MultiPose's own keypoints as Gaussians (EfficientPose not loaded), or both "
                  'fused per limb joint'),
            Param('keypoint_sigma', onnx.keypoint_sigma, "onnx, heatmaps multipose or fused: std of the Gaussians of "
                  "MultiPose's keypoints, as a fraction of the person's box diagonal", 0.001, 1.0),
            Param('model', onnx.model, f'onnx: the model on each person crop, {" or ".join(MODELS)}: EfficientPose '
                  '(rt, i: heatmaps) or a single-person keypoint model (MoveNet, BlazePose; docs/crop_models.md)'),
            Param('crop_workers', onnx.crop_workers, 'onnx, single-person keypoint models: crops run at once, each '
                  'with `threads` intra-op threads', 1, 64),
            Param('providers', list(onnx.providers), 'onnx: onnxruntime execution providers, in order of preference'),
            Param('threads', onnx.threads, 'onnx: intra-op threads per model (0 = one per core)', 0, 1024),
            Param('max_batch', onnx.max_batch, 'onnx: EfficientPose crops per run (0 = all crops of a set in one run, '
                  'for a GPU)', 0, 4096),
            Param('multipose_workers', onnx.multipose_workers, 'onnx, whole rig: images of a set MultiPose runs on at '
                  'once, each with `threads` intra-op threads (two cores: 2 with threads 1 was faster)', 1, 64),
            Param('input_size', onnx.input_size, 'onnx: MultiPose square input side, pixels, a multiple of 32',
                  32, 4096),
            Param('person_detector_every', 1, 'onnx, whole rig: MultiPose searches the whole image of every K-th '
                  'set only; between, where the newest skeletons on skeletons/live project: MultiPose on that region '
                  '(heatmaps multipose) or EfficientPose on those crops (MultiPose does not run)', 1, 1000),
            Param('region_margin', onnx.region_margin, "onnx, person_detector_every > 1, heatmaps multipose: each "
                  "person's projected box grows by this fraction of its size into the region MultiPose searches",
                  0.0, 10.0),
            Param('box_margin', onnx.box_margin,
                  "onnx: each side of a person's box grows by this fraction of its size before the EfficientPose "
                  'crop', 0.0, 10.0, live=True),
            Param('min_person_score', onnx.min_person_score, 'onnx: MultiPose people scoring less are dropped',
                  0.0, 1.0, live=True),
            Param('min_joint_score', onnx.min_joint_score,
                  'onnx: a joint whose heatmap peak is lower is not detected (empty map)', 0.0, 1.0, live=True),
            Param('heatmap_floor', onnx.heatmap_floor, "onnx: heatmap cells below this fraction of their map's peak "
                  'are 0', 0.0, 0.999, live=True),
            Param('ears', onnx.ears, "onnx: fill the ear joints from MultiPose's COCO ears (the anatomical head model "
                  'needs them)'),
            Param('tile_levels', onnx.tile_levels, 'onnx: a MultiPose run that comes back full (6 people) is '
                  'repeated on two overlapping halves of what it searched, at most this many levels deep (crowds; '
                  '0: never)', 0, 4),
            Param('upright', UPRIGHT, 'onnx: turn the image of a camera mounted on its side or upside down by quarter '
                  "turns (from its orientation and the rig's up) so that the networks see people standing"),
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
        p['camera'] = self.get_parameter('camera').value
        p |= declare(self, [Param('max_skew', default_max_skew(p['frame_rate']),
                                  'whole rig: s between the oldest and newest stamp of a set (default: half a frame '
                                  'period)', 0.0, 3600.0, live=True)])
        if p['backend'] not in BACKENDS:
            raise StartupError(f'parameter backend: {p["backend"]!r} is not one of {", ".join(BACKENDS)}')
        rig = load_rig_parameter(p)
        indices = _camera_indices(p['camera'], rig)
        self._whole_rig = len(indices) != 1 or p['camera'] in WHOLE_RIG
        self._backend = p['backend']
        self._depth = p['queue_depth']
        self._config = OpenPoseDetectorConfig(stride=p['stride'], sigma=p['sigma'],
                                              secondary_radius=p['secondary_radius'])
        if self._backend == 'onnx':
            self._detector = self._onnx_detector(p)  # before subscribing: the graph connects when it is ready
        self._log = ThrottledLog(self.get_logger())
        self._monitor = NodeMonitor()
        self._released: dict[int, float] = {}  # whole rig: set index -> when released (monotonic)
        namespace = rig_namespace(self.get_namespace(), None if self._whole_rig else rig.cameras[indices[0]].name)
        self._image_types = ImageTypes(self, self._resubscribe)
        self._cameras: list[_Camera] = []
        for index in indices:
            rc = rig.cameras[index]
            output = self.create_publisher(PointCloud2, in_namespace(namespace, camera_topic(rc.name, PEOPLE2D)),
                                           DATA_QOS)
            cam = _Camera(index, rc, '', in_namespace(namespace, rc.camera_info), output, rc.camera,
                          'the rig file' if rc.camera is not None else '')
            if self._backend == 'onnx':
                cam.input_topic = in_namespace(namespace, rc.image)
                cam.image = self._image_types.add(index, rc.name, cam.input_topic)
                cam.turns = upright_turns(rc.R, rig.up) if p['upright'] else 0
            else:
                cam.input_topic = in_namespace(namespace, camera_topic(rc.name, OPENPOSE))
            self._cameras.append(cam)
        if self._whole_rig:
            self._planner: CropPlanner | None = None
            # (stamp ns, joints (P, 14, 3), ids (P,)) of the newest skeletons
            self._tracked: tuple[int, np.ndarray, np.ndarray] | None = None
            if self._backend == 'onnx' and p['person_detector_every'] > 1:
                self._planner = CropPlanner([c.camera for c in self._cameras], p['person_detector_every'])
                self.create_subscription(PointCloud2, in_namespace(namespace, SKELETONS_LIVE), self._on_skeletons,
                                         DATA_QOS)
            self._start_sets(p, rig.world_frame)
        for cam in self._cameras:
            self._subscribe(cam)
            camera_subscription(self, CameraInfo, cam.info_topic, partial(self._on_info_cdr, cam), self._depth,
                                raw=True)
            typed = f'{cam.image.kind.__name__}, by {cam.image.typed_by}' if cam.image else 'PointCloud2'
            turned = f', turned {90 * cam.turns} degrees counterclockwise to stand people up' if cam.turns else ''
            self.get_logger().info(f'{cam.rig.name}: backend {self._backend}, {cam.input_topic} ({typed}{turned}) -> '
                                   f'{self.resolve_topic_name(cam.output.topic_name)}')
        now = time.monotonic()
        self._inputs = {cam.index: InputMonitor(cam.rig.name, now) for cam in self._cameras}
        self._refusals = Refusals([cam.rig.name for cam in self._cameras], 'image' if self._backend == 'onnx'
                                  else 'openpose input')
        self._unusable: set[str] = set()  # cameras said to be unusable (logged once)
        self._health = NodeHealth(self, self._statuses)
        live_parameters(self, [*LIVE_DETECTOR[self._backend], 'sync_timeout', 'max_skew'], self._check, self._retune)

    # --- set-up -------------------------------------------------------------------------------

    def _start_sets(self, p: dict[str, Any], world_frame: str) -> None:
        if not (p['sync_timeout'] > 0 and p['max_skew'] >= 0 and 1 <= p['min_cameras'] <= len(self._cameras)
                and p['waiting_sets'] >= 1):
            raise StartupError(f'parameters sync_timeout, max_skew, min_cameras, waiting_sets: need sync_timeout > 0, '
                               f'max_skew >= 0, 1 <= min_cameras <= {len(self._cameras)} and waiting_sets >= 1, got '
                               f'{p["sync_timeout"]}, {p["max_skew"]}, {p["min_cameras"]}, {p["waiting_sets"]}')
        # pending messages per camera: a sync_timeout's worth of frames, twice (more only from a
        # camera stamping far ahead of the others: its oldest are dropped as 'overflow', counted)
        queue = math.ceil(2 * p['sync_timeout'] * p['frame_rate']) + 2
        # a camera that has sent nothing yet (one starting late) holds a set back one frame period at most
        self._sync = ApproximateSync(len(self._cameras), p['sync_timeout'], p['max_skew'], p['min_cameras'], queue,
                                     first_wait=1.0 / p['frame_rate'])
        self._waiting: NewestQueue[SyncedSet] = NewestQueue(p['waiting_sets'])
        # a set none of whose cameras reaches the association: its stamp goes here, as association
        # and bp_solver announce theirs, so that a subscriber waiting for every frame stops waiting
        self._dropped_sets = self.create_publisher(Header, SKELETONS_DROPPED, DATA_QOS)
        self._world_frame = world_frame
        self._frame_rate = p['frame_rate']
        self._rate_said = False  # whether the cameras' rate off frame_rate is logged (it is on /diagnostics)
        self._intrinsics_in = threading.Condition()  # notified when a camera's first CameraInfo is taken
        self._stopping = False
        self._processed = 0
        self._expire_timer = self.create_timer(min(0.05, p['sync_timeout'] / 2), self._expire)
        # a set's images decode side by side (OpenCV lets go of the GIL), as many at once as
        # MultiPose runs (5 JPEGs of 1548 x 1164: 46 ms one after another, 29 ms two at a time)
        self._decoders = ThreadPoolExecutor(max(1, p['multipose_workers']), thread_name_prefix='decode')
        self._worker = threading.Thread(target=self._work, name='heatmap_detector_sets', daemon=True)
        self._worker.start()
        names = ', '.join(c.rig.name for c in self._cameras)
        self.get_logger().info(f'whole rig: {len(self._cameras)} cameras ({names}), max_skew '
                               f'{1e3 * p["max_skew"]:.1f} ms, sync_timeout {p["sync_timeout"]} s; while detecting, '
                               f'the newest {p["waiting_sets"]} set(s) wait')

    def _subscribe(self, cam: _Camera) -> None:
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

    @staticmethod
    def _onnx_detector(p: dict[str, Any]) -> OnnxPoseDetector:
        """The ONNX sessions, created once; a bad value or model file is a StartupError."""
        # the one entry to the onnx backend: an openpose node never loads onnxruntime
        from mvpose_ros.core.detection.onnx_detector import OnnxPoseDetector
        try:
            config = OnnxDetectorConfig(
                model_dir=data_root(p['data_root'] or None) / 'models', model=p['model'],
                providers=tuple(p['providers']), threads=p['threads'], input_size=p['input_size'],
                box_margin=p['box_margin'], min_person_score=p['min_person_score'],
                min_joint_score=p['min_joint_score'], heatmap_floor=p['heatmap_floor'], stride=p['stride'],
                ears=p['ears'], sigma=p['sigma'], max_batch=p['max_batch'], heatmaps=p['heatmaps'],
                keypoint_sigma=p['keypoint_sigma'], multipose_workers=p['multipose_workers'],
                crop_workers=p['crop_workers'],
                region_margin=p['region_margin'], tile_levels=p['tile_levels'])
            return OnnxPoseDetector(config)
        except (FileNotFoundError, ValueError) as exc:  # ModelError is a ValueError
            raise StartupError(f'backend onnx: {" ".join(str(exc).split())}') from None

    # --- CameraInfo ---------------------------------------------------------------------------

    def _on_info_cdr(self, cam: _Camera, cdr: bytes) -> None:
        """A CameraInfo as bytes, taken in (_on_info) only when more than its stamp differs from the
        last one taken in: a driver sends the same CameraInfo with every image, and each one taken
        in as a message cost about 0.2 ms of CPU (a bare node's 0.62 against 0.44 ms a frame)."""
        try:
            content = after_stamp(cdr)
            if content == cam.info_content:
                return
            msg = deserialise(cdr, CameraInfo)
        except ValueError as exc:
            self._log.log((cam.rig.name, 'camera_info unreadable'),
                          f'{cam.rig.name}: camera_info of {len(cdr)} bytes unreadable: {short_cause(str(exc))}',
                          'error')
            return
        self._on_info(cam, msg)
        cam.info_content = content

    def _on_info(self, cam: _Camera, msg: CameraInfo) -> None:
        try:
            cam.frame_id.check(msg.header.frame_id, 'CameraInfo')
            if cam.camera is None:
                cam.camera = info_camera(cam.rig, msg)
                cam.source = f'the CameraInfo of stamp {stamp_ns(msg.header.stamp)} ns'
                self.get_logger().info(f'{cam.rig.name}: intrinsics from {cam.info_topic} '
                                       f'({cam.camera.width}x{cam.camera.height})')
                if self._whole_rig:
                    with self._intrinsics_in:
                        self._intrinsics_in.notify_all()
                return
            check_info(msg, cam.camera, rectified=cam.rig.rectified, raw_R=cam.rig.R)
        except ValueError as exc:
            # A CameraInfo that disagrees means a wrong file or a re-calibrated camera: said once
            # per camera and problem, never acted on.
            problem = ' '.join(str(exc).split())
            if problem not in cam.info_problems:
                cam.info_problems.add(problem)
                what = 'the calibration parameter' if cam.source == 'the rig file' else cam.source
                self.get_logger().error(f'{cam.rig.name}: camera_info stamp {stamp_ns(msg.header.stamp)} ns '
                                        f'contradicts {what}: {problem}; the intrinsics are kept (said once per '
                                        f'problem)')

    # --- detection ----------------------------------------------------------------------------

    def _admit(self, cam: _Camera, msg: Any, queued: bool = False) -> None:
        """The checks of an input before it is queued or worked on, none of them decoding (see the
        module's "Bounded input"); ValueError (one line) when it cannot be used. queued: it goes
        into the synchroniser, where a camera's first images may wait for its first CameraInfo
        (sent with them): checked against the largest size until then, against the camera's
        when worked on."""
        cam.frame_id.check(msg.header.frame_id, self._what())
        if self._backend == 'openpose':
            if len(msg.data) > max_openpose_bytes():
                raise ValueError(f'OpenPose output of {len(msg.data)} bytes, more than one image can have '
                                 f'({max_openpose_bytes()})')
            return
        if cam.camera is None and not queued:
            raise ValueError(f'no intrinsics yet (the rig file has none: waiting for a CameraInfo on '
                             f'{cam.info_topic})')
        check_camera_image(msg, None if cam.camera is None else (cam.camera.width, cam.camera.height))

    def _people(self, cam: _Camera, msg: Any) -> PointCloud2:
        """The people2d message of one input; ValueError (one line) when it cannot be used."""
        if self._backend == 'openpose':
            self._admit(cam, msg)
            return people_to_msg(detect_people(msg_to_openpose(msg), self._config), msg.header)
        (people,) = self._detector.detect_set([self._image(cam, msg)], sizes=[_size(cam.camera)], turns=[cam.turns])
        return people_to_msg(people, msg.header)

    def _image(self, cam: _Camera, msg: Any) -> Any:
        """The admitted, decoded BGR image of one camera input, a JPEG shrunk as the detector
        allows (OnnxPoseDetector.reduced_decoding); ValueError (one line) otherwise."""
        self._admit(cam, msg)
        return decode_image(msg, cam.camera, self._detector.reduced_decoding(*_size(cam.camera)))

    def _decoded(self, cam: _Camera, msg: Any) -> Any:
        """_image of one camera of a set (None without a message), or the ValueError it raised,
        for the worker to log: a decoding thread only decodes."""
        if msg is None:
            return None
        try:
            return self._image(cam, msg)
        except ValueError as exc:
            return exc

    def _what(self) -> str:
        return 'openpose' if self._backend == 'openpose' else 'image'

    def _on_openpose_cdr(self, cam: _Camera, callback: Any, cdr: bytes) -> None:
        """An OpenPose input as serialised bytes: deserialised for `callback` only once its header
        and size pass (see the module's "Bounded input")."""
        stamp = None
        try:
            stamp = header_stamp_ns(cdr)
            cam.frame_id.check(header_frame_id(cdr), self._what())
            if len(cdr) > max_openpose_bytes() + CLOUD_OVERHEAD:
                raise ValueError(f'OpenPose output of {len(cdr)} serialised bytes, more than one image can have '
                                 f'({max_openpose_bytes()} data bytes)')
            msg = deserialise_cloud(cdr)
        except ValueError as exc:
            self._inputs[cam.index].received(time.monotonic(), stamp)
            self._drop(cam, stamp, str(exc))
            return
        callback(msg)

    def _drop(self, cam: _Camera, stamp: int | None, cause: str, refused: bool = True) -> None:
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

    def _check(self, changes: dict[str, Any]) -> str | None:
        try:
            self._retuned(changes)
            if {'sync_timeout', 'max_skew'} & changes.keys() and self._whole_rig:
                ApproximateSync(1, changes.get('sync_timeout', self._sync.timeout),
                                changes.get('max_skew', self._sync.max_skew_ns / 1e9))
        except ValueError as exc:
            return str(exc)
        return None

    def _retune(self, changes: dict[str, Any]) -> None:
        if self._backend == 'onnx':
            self._detector.config = self._retuned(changes)
        else:
            self._config = self._retuned(changes)
        if self._whole_rig and {'sync_timeout', 'max_skew'} & changes.keys():
            self._sync.retune(changes.get('sync_timeout', self._sync.timeout),
                              changes.get('max_skew', self._sync.max_skew_ns / 1e9))

    def _retuned(self, changes: dict[str, Any]) -> Any:
        """The detector configuration with the live changes (ValueError when invalid)."""
        config = self._detector.config if self._backend == 'onnx' else self._config
        return replace(config, **{k: v for k, v in changes.items() if k in LIVE_DETECTOR[self._backend]})

    def _statuses(self, now: float, t: HealthThresholds) -> list[Status]:
        node = self._health.prefix()
        waiting = (len(self._waiting) + self._sync.pending) if self._whole_rig else 0
        extra = ({'sets released': str(self._waiting.put_count), 'sets detected': str(self._processed),
                  'sets dropped whole while detecting': str(self._waiting.dropped)} if self._whole_rig else {})
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

    def _on_input(self, cam: _Camera, msg: Any) -> None:
        """One-camera mode: detect in the callback (a slower detector drops frames in the
        keep-last subscription, never queues them)."""
        t0 = time.perf_counter()
        arrival = time.monotonic()
        self._inputs[cam.index].received(arrival, stamp_ns(msg.header.stamp))
        try:
            out = self._people(cam, msg)
        except ValueError as exc:
            self._drop(cam, stamp_ns(msg.header.stamp), str(exc))
            return
        cam.output.publish(out)
        self._refusals.used(cam.rig.name)
        self._delivered([stamp_ns(msg.header.stamp)], arrival, time.perf_counter() - t0)
        if self._backend == 'onnx':
            t = self._detector.timing
            self.get_logger().debug(f'{cam.rig.name}: image stamp {stamp_ns(msg.header.stamp)} ns: {t.people} '
                                    f'people, MultiPose {1e3 * t.multipose:.0f} ms, EfficientPose '
                                    f'{1e3 * t.efficientpose:.0f} ms, in-to-out '
                                    f'{1e3 * (time.perf_counter() - t0):.0f} ms')

    # --- whole rig: synchronised sets ----------------------------------------------------------

    def _on_set_input(self, cam: _Camera, msg: Any) -> None:
        stamp = stamp_ns(msg.header.stamp)
        self._inputs[cam.index].received(time.monotonic(), stamp)
        try:
            self._admit(cam, msg, queued=True)  # before the synchroniser holds it: junk takes no real image's place
        except ValueError as exc:
            self._drop(cam, stamp, str(exc))
            return
        before = Counter(self._sync.dropped)
        try:
            released = self._sync.add(stamp, cam.index, msg, time.monotonic())  # every rig camera: sync index
        except ValueError as exc:
            reason = next(iter(self._sync.dropped - before), 'rejected')
            self._drop(cam, stamp, f'not synchronised ({reason}): {_without_numbers(str(exc))}', refused=False)
            return
        self._offer(released)

    def _expire(self) -> None:
        self._offer(self._sync.expire(time.monotonic()))

    def _offer(self, released: list[SyncedSet]) -> None:
        for drop in self._sync.take_drops():
            cam = self._cameras[drop.camera]
            cause = {'unmatched': 'its set had fewer than min_cameras cameras',
                     'overflow': 'too many frames pending synchronisation (a camera stamping far ahead?)'}
            self._drop(cam, drop.stamp_ns, f'not synchronised ({drop.reason}): {cause.get(drop.reason, drop.reason)}',
                       refused=False)
        for stamp in self._sync.take_lost():
            self._announce_dropped(stamp)
        now = time.monotonic()
        for synced in released:
            for c, s in enumerate(synced.stamps):
                if s is not None:
                    self._inputs[c].synchronised(now, (s - synced.stamp_ns) / 1e9)
            self._monitor.set_skew(now, synced.skew_ns / 1e9)
            self._released[synced.index] = now
            for old in self._waiting.put(synced):
                self._released.pop(old.index, None)
                self._announce_dropped(old.stamp_ns)
                self._log.log(('sets', 'dropped whole while detecting'),
                              f'detection is slower than the cameras: {self._waiting.dropped} of '
                              f'{self._waiting.put_count} sets dropped whole so far (the newest wait)')

    def _announce_dropped(self, stamp: int) -> None:
        """Publish the stamp (ns) of a set that will get no skeletons on skeletons/dropped."""
        self._dropped_sets.publish(Header(stamp=stamp_of_ns(stamp), frame_id=self._world_frame))

    def _work(self) -> None:
        while (synced := self._waiting.take()) is not None:
            try:
                self._detect_set(synced)
            except Exception:  # the worker must survive a bug in one set; a shutdown ends it quietly
                if self._stopping:
                    return
                self.get_logger().error(f'set {synced.index}: {traceback.format_exc(limit=3)}')

    def _detect_set(self, synced: SyncedSet) -> None:
        """Detect every image of the set, then publish them together (the set reaches the
        association at once, not spread over the detection time)."""
        t0 = time.perf_counter()
        # a camera's first images come with its first CameraInfo, which may be taken just after
        # them: wait for it as long as a set waits for a camera, rather than lose the first sets
        unknown = [cam for cam, msg in zip(self._cameras, synced.items) if msg is not None and cam.camera is None]
        if unknown:
            with self._intrinsics_in:
                self._intrinsics_in.wait_for(lambda: all(cam.camera is not None for cam in unknown),
                                             timeout=self._sync.timeout)
        outputs = []
        if self._backend == 'onnx':
            # every image decoded, then one detect_set: EfficientPose takes the crops of all cameras
            images = list(self._decoders.map(self._decoded, self._cameras, synced.items))
            for cam, msg, image in zip(self._cameras, synced.items, images):
                if isinstance(image, ValueError):
                    self._drop(cam, stamp_ns(msg.header.stamp), str(image))
            images = [None if isinstance(image, ValueError) else image for image in images]
            sizes = [None if cam.camera is None else _size(cam.camera) for cam in self._cameras]
            plan = self._plan(synced.stamp_ns)
            found = self._detector.detect_set(images, plan, None if plan is None else self._planner.previous, sizes,
                                              [cam.turns for cam in self._cameras])
            if plan is not None:
                self._planner.update(plan, found)
            for cam, msg, people in zip(self._cameras, synced.items, found):
                if people is not None:
                    outputs.append((cam, people_to_msg(people, msg.header)))
        else:
            for cam, msg in zip(self._cameras, synced.items):
                if msg is None:
                    continue
                try:
                    outputs.append((cam, self._people(cam, msg)))
                except ValueError as exc:
                    self._drop(cam, stamp_ns(msg.header.stamp), str(exc))
        for cam, out in outputs:
            cam.output.publish(out)
            self._refusals.used(cam.rig.name)
        if not outputs:
            self._announce_dropped(synced.stamp_ns)
        self._delivered([s for s in synced.stamps if s is not None], self._released.pop(synced.index, time.monotonic()),
                        time.perf_counter() - t0)
        self._processed += 1
        dropped = self._waiting.dropped
        self.get_logger().debug(f'set {synced.index} stamp {synced.stamp_ns} ns: {len(outputs)} of '
                                f'{len(self._cameras)} cameras, skew {synced.skew_ns / 1e6:.1f} ms, detected in '
                                f'{1e3 * (time.perf_counter() - t0):.0f} ms; {dropped} sets dropped whole so far')

    def _on_skeletons(self, msg: PointCloud2) -> None:
        try:
            skeletons = msg_to_skeletons(msg)
        except ValueError as exc:
            self._log.log(('skeletons', 'malformed'), f'skeletons/live stamp {stamp_ns(msg.header.stamp)} ns: {exc}; '
                          f'not used to plan the next regions', 'error')
            return
        self._tracked = (stamp_ns(msg.header.stamp), skeletons.joints, skeletons.ids)

    def _plan(self, stamp: int) -> list[np.ndarray | None] | None:
        """With person_detector_every > 1, per camera None (MultiPose on the whole image) or where
        the newest skeletons, if at most TRACK_MAX_AGE_S older than this set, put its people
        (CropPlanner); None without."""
        if self._planner is None:
            return None
        tracked = self._tracked
        fresh = tracked is not None and (stamp - tracked[0]) / 1e9 <= TRACK_MAX_AGE_S
        self._planner.cameras = [cam.camera for cam in self._cameras]
        self._planner.skeletons(*(tracked[1:] if fresh else (np.zeros((0, NUM_JOINTS, 3)), None)))
        return self._planner.plan()

    def destroy_node(self) -> None:
        """Stop the worker (whole-rig mode) and log the totals, then destroy the node."""
        # the context may be shut down already (Ctrl-C): a logger without a rosout publisher
        logger = rclpy.logging.get_logger(f'{self.get_logger().name}.totals')
        if getattr(self, '_whole_rig', False) and hasattr(self, '_worker'):
            self._stopping = True
            self._waiting.close()
            self._worker.join(10.0)
            self._decoders.shutdown(wait=False)
            logger.info(f'sets: {self._waiting.put_count} released, {self._processed} detected, '
                        f'{self._waiting.dropped} dropped whole while detecting; sync drops '
                        f'{dict(self._sync.dropped) or "none"}')
        if hasattr(self, '_log') and self._log.counts:
            logger.info(f'problems: {self._log.summary()}')
        super().destroy_node()


def _without_numbers(text: str) -> str:
    """A cause without the stamps and counts in it (so that it names the cause, not the message)."""
    return ' '.join('<n>' if word.strip('(),:;').isdigit() else word for word in text.split())


def _camera_indices(camera: Any, rig: Rig) -> list[int]:
    """The rig indices a `camera` parameter value names: every camera for '' or 'all', else one
    (a name in the rig, or an index as an integer or a string of digits)."""
    n = len(rig.cameras)
    if isinstance(camera, str) and camera.strip() in WHOLE_RIG:
        return list(range(n))
    if isinstance(camera, str) and camera in rig.names:
        return [rig.names.index(camera)]
    if isinstance(camera, str) and camera.strip().isdigit():
        camera = int(camera)
    if isinstance(camera, int) and not isinstance(camera, bool):
        if not 0 <= camera < n:
            raise StartupError(f'parameter camera: {camera} is not in 0..{n - 1} ({rig.path or "the rig"} has '
                               f'{n} cameras: {", ".join(rig.names)})')
        return [camera]
    raise StartupError(f'parameter camera: {camera!r} is not a camera of {rig.path or "the rig"} (expected one of '
                       f'{", ".join(rig.names)}, an index 0..{n - 1}, or {" or ".join(map(repr, WHOLE_RIG))})')


def main(args: list[str] | None = None) -> None:
    run(HeatmapDetectorNode, args)


if __name__ == '__main__':
    main()
