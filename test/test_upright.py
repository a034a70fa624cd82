"""Upright detection: the quarter turns that stand a camera's people up, from its rotation and the
world's up; and, through the real models, the frame-572 images of cameras mounted on their side or
upside down give back the people the upright images give."""
from __future__ import annotations


import cv2
import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from mvpose_ros.core.datasets.shelf_campus import dataset_dir
from mvpose_ros.core.defaults import data_root
from mvpose_ros.core.detection.onnx_detector import OnnxDetectorConfig, OnnxPoseDetector
from mvpose_ros.core.detection.upright import MIN_UP_IN_IMAGE, upright_turns
from mvpose_ros.core.geometry.camera import load_rig

UP = np.array([0.0, 0.0, 1.0])
# a camera looking along the world's +x, level: optical x right (world -y), y down (world -z)
LEVEL = np.array([[0.0, -1.0, 0.0], [0.0, 0.0, -1.0], [1.0, 0.0, 0.0]])


def _roll(degrees: float) -> np.ndarray:
    """Rotation of the optical frame about its z axis (the camera turned on its mount)."""
    return Rotation.from_euler('z', degrees, degrees=True).as_matrix()


def _up_in_image_after(R: np.ndarray, up: np.ndarray, turns: int) -> np.ndarray:
    """The image direction (dx, dy) of the world's up at the image centre, after `turns` quarter
    turns of the image as np.rot90 makes them (a direction (dx, dy) becomes (dy, -dx))."""
    d = (R @ up)[:2]
    for _ in range(turns):
        d = np.array([d[1], -d[0]])
    return d / np.linalg.norm(d)


@pytest.mark.parametrize('roll, turns', [(0, 0), (90, 1), (180, 2), (270, 3), (-90, 3), (30, 0), (60, 1),
                                         (200, 2)])
def test_a_rolled_camera_is_turned_back_to_the_nearest_quarter(roll, turns):
    R = _roll(roll) @ LEVEL
    assert upright_turns(R, UP) == turns
    # after the turns, up points up within 45 degrees
    assert _up_in_image_after(R, UP, turns)[1] <= -np.cos(np.radians(45)) + 1e-12


def test_any_camera_and_up_end_within_45_degrees_of_upright():
    rng = np.random.default_rng(0)
    for R, up in zip(Rotation.random(200, random_state=1).as_matrix(), rng.normal(size=(200, 3))):
        turns = upright_turns(R, 2.5 * up)  # up need not be a unit vector
        d = R @ (up / np.linalg.norm(up))
        if np.hypot(d[0], d[1]) < MIN_UP_IN_IMAGE:
            assert turns == 0
        else:
            assert _up_in_image_after(R, up, turns)[1] <= -np.cos(np.radians(45)) + 1e-9


def test_a_camera_looking_straight_down_or_up_is_not_turned():
    down = Rotation.from_euler('x', 180, degrees=True).as_matrix()  # optical z = world -z
    for R in (down, _roll(90) @ down, Rotation.from_euler('x', 10, degrees=True).as_matrix()):
        assert upright_turns(R, UP) == 0


def test_the_shelf_cameras_are_upright():
    cameras = load_rig(dataset_dir('shelf') / 'calibration' / 'calibration_shelf.json', 1032, 776)
    assert [upright_turns(cam.R, UP) for cam in cameras] == [0] * 5


@pytest.fixture(scope='module')
def detector() -> OnnxPoseDetector:
    return OnnxPoseDetector(OnnxDetectorConfig(model_dir=data_root() / 'models', heatmaps='multipose', threads=1))


def _back(uv: np.ndarray, turned: int, width: int, height: int) -> np.ndarray:
    """Pixels (..., 2) of an image that cv2.rotate turned `turned` quarter turns clockwise, in the
    image before (width x height)."""
    u, v = uv[..., 0], uv[..., 1]
    return np.stack({1: (v, height - 1 - u), 2: (width - 1 - u, height - 1 - v), 3: (width - 1 - v, u)}[turned], -1)


@pytest.mark.parametrize('image_turn, turned', [(cv2.ROTATE_90_CLOCKWISE, 1), (cv2.ROTATE_180, 2),
                                                (cv2.ROTATE_90_COUNTERCLOCKWISE, 3)])
def test_a_camera_on_its_side_or_upside_down_finds_the_upright_people(detector, image_turn, turned):
    """Camera 4's frame-572 image as a camera mounted turned would take it: MultiPose on it as it
    comes finds fewer people; turned back by the detector (as many quarter turns counterclockwise as
    the camera is turned clockwise) it finds the four people of the upright image, their keypoints
    within two input pixels of those, in the turned camera's own pixels."""
    image = cv2.imread(str(dataset_dir('shelf') / 'frames' / 'cam4_000572.png'))
    h, w = image.shape[:2]
    (upright,) = detector.detect_set([image])
    taken = cv2.rotate(image, image_turn)
    (as_it_comes,), (turned_back,) = detector.detect_set([taken]), detector.detect_set([taken], turns=[turned])
    assert len(upright) == len(turned_back) == 4 and len(as_it_comes) < 4
    input_pixel = max(w, h) / detector.config.input_size
    for person in turned_back:
        kp = person.keypoints
        seen = kp[:, 2] > 0.3
        assert np.all((kp[seen, :2] >= -0.5) & (kp[seen, :2] <= np.array(taken.shape[1::-1]) - 0.5))
        # the person's maps are in the turned camera's pixels too: each peaks at its keypoint
        peak = person.heatmap.peak()
        assert np.all(np.linalg.norm(peak[seen, :2] - kp[seen, :2], axis=1) <= 2 * person.heatmap.stride)
        back = _back(kp[:, :2], turned, w, h)
        shifts = [np.median(np.linalg.norm(back[seen & (p.keypoints[:, 2] > 0.3)]
                                           - p.keypoints[seen & (p.keypoints[:, 2] > 0.3), :2], axis=1))
                  for p in upright]
        assert min(shifts) < 2 * input_pixel
