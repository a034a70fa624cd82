"""One synchronised set of a rig's camera images detected together by the ONNX detector (the
heatmap_detector node's whole-rig mode, without ROS): the images decoded side by side, then one
detect_set, so that EfficientPose takes the crops of every camera in one run; with
person_detector_every > 1, the cameras' crops or regions planned from the newest skeletons
(core.detection.tracked_crops.CropPlanner)."""
from __future__ import annotations

from concurrent.futures import ThreadPoolExecutor
from typing import TYPE_CHECKING, Any, Callable, Sequence

import numpy as np

from mvpose_ros.core.detection.tracked_crops import CropPlanner
from mvpose_ros.core.geometry.body import NUM_JOINTS
from mvpose_ros.core.geometry.camera import Camera
from mvpose_ros.core.types import Person2D

if TYPE_CHECKING:  # a node of the openpose backend imports this module and never loads onnxruntime
    from mvpose_ros.core.detection.onnx_detector import OnnxPoseDetector

# Skeletons older than this, against a set's stamp, place no one (the whole image is searched):
# a few sets at the onnx backend's 2-5 sets per second, a walk of about a metre.
TRACK_MAX_AGE_S = 1.0


class ImageSetDetector:
    """detect() a set; track() the newest skeletons, which plan the sets between MultiPose's
    whole-image runs (every `every`-th set); close() ends the decoding threads."""

    def __init__(self, detector: OnnxPoseDetector, cameras: Sequence[Camera | None], every: int = 1) -> None:
        self.detector = detector
        self._planner = CropPlanner(cameras, every) if every > 1 else None
        # (stamp ns, joints (P, 14, 3), ids (P,)) of the newest skeletons
        self._tracked: tuple[int, np.ndarray, np.ndarray] | None = None
        # a set's images decode side by side (OpenCV lets go of the GIL), as many at once as
        # MultiPose runs
        self._decoders = ThreadPoolExecutor(max(1, detector.config.multipose_workers), thread_name_prefix='decode')

    @property
    def tracking(self) -> bool:
        """Whether sets between MultiPose's whole-image runs are planned from skeletons."""
        return self._planner is not None

    def track(self, stamp_ns: int, joints: np.ndarray, ids: np.ndarray) -> None:
        """The newest skeletons (P, 14, 3) world metres with their ids (P,), stamped stamp_ns."""
        self._tracked = (stamp_ns, joints, ids)

    def detect(self, stamp_ns: int, items: Sequence[Any], cameras: Sequence[Camera | None], turns: Sequence[int],
               decode: Callable[[int, Any, int], np.ndarray]) -> tuple[list[list[Person2D] | None],
                                                                       list[tuple[int, ValueError]]]:
        """The people of each camera of the set stamped stamp_ns (None: no item, or one that could
        not be decoded) and the cameras whose item could not be, with why. items: per camera, its
        input or None; cameras: their intrinsics (None: not known yet); turns: their quarter turns
        (upright); decode(camera, item, reduce): its (H, W, 3) uint8 BGR image, shrunk by `reduce`
        where the detector allows (OnnxPoseDetector.reduced_decoding), ValueError when unusable
        (a camera whose intrinsics are not known included)."""
        sizes = [None if cam is None else (cam.width, cam.height) for cam in cameras]
        plan = self._plan(stamp_ns, cameras)

        def decoded(c: int) -> np.ndarray | ValueError | None:
            if items[c] is None:
                return None
            try:
                return decode(c, items[c], 1 if sizes[c] is None else
                              self.detector.reduced_decoding(*sizes[c], None if plan is None else plan[c]))
            except ValueError as exc:  # for the caller to report: a decoding thread only decodes
                return exc

        images = list(self._decoders.map(decoded, range(len(items))))
        errors = [(c, image) for c, image in enumerate(images) if isinstance(image, ValueError)]
        images = [None if isinstance(image, ValueError) else image for image in images]
        found = self.detector.detect_set(images, plan, None if plan is None else self._planner.previous, sizes,
                                         list(turns))
        if plan is not None:
            self._planner.update(plan, found)
        return found, errors

    def close(self) -> None:
        """End the decoding threads."""
        self._decoders.shutdown(wait=False)

    def _plan(self, stamp: int, cameras: Sequence[Camera | None]) -> list[np.ndarray | None] | None:
        """With person_detector_every > 1, per camera None (MultiPose on the whole image) or where
        the newest skeletons, if at most TRACK_MAX_AGE_S older than this set, put its people
        (CropPlanner); None without."""
        if self._planner is None:
            return None
        tracked = self._tracked
        fresh = tracked is not None and (stamp - tracked[0]) / 1e9 <= TRACK_MAX_AGE_S
        self._planner.cameras = list(cameras)
        self._planner.skeletons(*(tracked[1:] if fresh else (np.zeros((0, NUM_JOINTS, 3)), None)))
        return self._planner.plan()
