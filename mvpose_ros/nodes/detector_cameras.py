"""The cameras a heatmap_detector node detects: which ones (its `camera` parameter), their topics in
the rig's namespace, each one's state (intrinsics once known, input type, frame_id, output), and
its inputs checked once, on arrival, before they are queued or decoded: an image's frame_id and
size (msg_adapters.image_msg.check_camera_image), OpenPose output's frame_id and size read in its
serialised bytes (msg_adapters.cdr_header), a CameraInfo read only when more than its stamp changed."""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, Sequence

import numpy as np
from rclpy.subscription import Subscription
from sensor_msgs.msg import CameraInfo, CompressedImage, Image, PointCloud2

from msg_adapters.camera_info_msg import check_info, info_camera
from msg_adapters.cdr_header import (CLOUD_OVERHEAD, after_stamp, deserialise, deserialise_cloud, header_frame_id,
                                     header_stamp_ns)
from msg_adapters.image_msg import CheckedImage, check_camera_image
from msg_adapters.openpose_msg import max_openpose_bytes
from msg_adapters.stamp import stamp_ns
from mvpose_ros.core.geometry.camera import Camera
from mvpose_ros.core.geometry.frame_id import CameraFrameId
from mvpose_ros.core.detection.upright import upright_turns
from mvpose_ros.core.geometry.rig import Rig, RigCamera
from mvpose_ros.nodes.image_topics import ImageInput
from mvpose_ros.nodes.runtime import StartupError
from mvpose_ros.topics import OPENPOSE, camera_topic

WHOLE_RIG = ('', 'all')  # values of `camera` meaning one node for every camera


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


@dataclass
class DetectorCamera:
    """One camera a node detects: its rig entry, topics, intrinsics once known, output."""

    index: int
    rig: RigCamera
    input_topic: str  # absolute
    info_topic: str  # absolute
    camera: Camera | None = None
    source: str = 'the rig file'  # where the intrinsics came from
    output: Any = None  # Publisher of its people2d
    image: ImageInput | None = None  # onnx: its image topic's type (openpose: PointCloud2)
    subscription: Subscription | None = None
    info_problems: set[str] = field(default_factory=set)
    info_content: bytes | None = None  # cdr_header.after_stamp of the last CameraInfo taken in
    turns: int = 0  # onnx: quarter turns that stand its image up (upright.upright_turns)
    frame_id: CameraFrameId = field(init=False)

    def __post_init__(self) -> None:
        self.frame_id = CameraFrameId(self.rig.name, self.rig.frame_id)

    def admit(self, msg: Image | CompressedImage, queued: bool) -> CheckedImage:
        """The one check of an image, on arrival, before it is queued or decoded: its frame_id, and
        every check short of decoding against the camera's size (check_camera_image). queued: it
        goes into a set, where a camera's first images may wait for its first CameraInfo (sent
        with them): checked against the largest size until then, against the camera's in decode.
        ValueError (one line) when it cannot be used."""
        self.frame_id.check(msg.header.frame_id, 'image')
        if self.camera is None and not queued:
            raise ValueError(self._no_intrinsics())
        return check_camera_image(msg, None if self.camera is None else (self.camera.width, self.camera.height))

    def decode(self, image: CheckedImage, reduce: int = 1) -> np.ndarray:
        """(H, W, 3) uint8 BGR of an admitted image, not checked again (but against the camera's
        size where it was admitted without: CheckedImage.fits), a JPEG at 1/reduce. ValueError."""
        if self.camera is None:
            raise ValueError(self._no_intrinsics())
        if image.expected is None:
            image = image.fits((self.camera.width, self.camera.height))
        return image.decode(reduce)

    def openpose(self, cdr: bytes) -> PointCloud2:
        """The OpenPose output of serialised bytes, deserialised only once the frame_id and size
        read in them pass (a flood of junk costs a check per message, not its message objects);
        ValueError (one line) otherwise."""
        self.frame_id.check(header_frame_id(cdr), 'openpose')
        if len(cdr) > max_openpose_bytes() + CLOUD_OVERHEAD:
            raise ValueError(f'OpenPose output of {len(cdr)} serialised bytes, more than one image can have '
                             f'({max_openpose_bytes()} data bytes)')
        return deserialise_cloud(cdr)

    @staticmethod
    def stamp_of(cdr: bytes) -> int | None:
        """The header stamp (ns) of serialised bytes, None where it cannot be read."""
        try:
            return header_stamp_ns(cdr)
        except ValueError:
            return None

    def info(self, cdr: bytes) -> CameraInfo | None:
        """The CameraInfo of serialised bytes, None when only its stamp differs from the last one
        taken in: a driver sends the same CameraInfo with every image, and deserialising each
        one would cost CPU for nothing. ValueError when unreadable."""
        content = after_stamp(cdr)
        if content == self.info_content:
            return None
        msg = deserialise(cdr, CameraInfo)
        self.info_content = content
        return msg

    def _no_intrinsics(self) -> str:
        return f'no intrinsics yet (the rig file has none: waiting for a CameraInfo on {self.info_topic})'

    def take_info(self, msg: CameraInfo) -> tuple[str, str] | None:
        """A CameraInfo of this camera: the intrinsics from the first usable one, ('info', what to
        log); one contradicting the intrinsics in use (of rectified images, their R too), ('error',
        what to log) once per problem, never acted on (a wrong file or a re-calibrated camera);
        else None."""
        try:
            self.frame_id.check(msg.header.frame_id, 'CameraInfo')
            if self.camera is None:
                self.camera = info_camera(self.rig, msg)
                self.source = f'the CameraInfo of stamp {stamp_ns(msg.header.stamp)} ns'
                size = f'{self.camera.width}x{self.camera.height}'
                return 'info', f'{self.rig.name}: intrinsics from {self.info_topic} ({size})'
            check_info(msg, self.camera, rectified=self.rig.rectified, raw_R=self.rig.R)
        except ValueError as exc:
            problem = ' '.join(str(exc).split())
            if problem not in self.info_problems:
                self.info_problems.add(problem)
                what = 'the calibration parameter' if self.source == 'the rig file' else self.source
                return 'error', (f'{self.rig.name}: camera_info stamp {stamp_ns(msg.header.stamp)} ns contradicts '
                                 f'{what}: {problem}; the intrinsics are kept (said once per problem)')
        return None


def camera_indices(camera: Any, rig: Rig) -> list[int]:
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


def detector_cameras(rig: Rig, indices: Sequence[int], namespace: str, backend: str,
                     upright: bool) -> list[DetectorCamera]:
    """The rig's cameras `indices` as a detector of `backend` in the rig's `namespace` takes them:
    input topics (onnx: the rig's image topic; openpose: <camera>/openpose), intrinsics if the rig
    file gives them, and (onnx, upright) the quarter turns that stand their people up."""
    cameras = []
    for index in indices:
        rc = rig.cameras[index]
        topic = rc.image if backend == 'onnx' else camera_topic(rc.name, OPENPOSE)
        turns = upright_turns(rc.R, rig.up) if backend == 'onnx' and upright else 0
        source = 'the rig file' if rc.camera is not None else ''
        info = in_namespace(namespace, rc.camera_info)
        cameras.append(DetectorCamera(index, rc, in_namespace(namespace, topic), info, rc.camera, source, turns=turns))
    return cameras
