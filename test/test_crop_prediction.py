"""The crops-on-real-motion benchmark's scoring: which annotated person-views a set's crops hold,
and that the crops planned from the set before follow a person who walks on."""
from __future__ import annotations

import numpy as np

from mvpose_ros.bench.crop_prediction import Coverage, coverage, frame_coverage
from mvpose_ros.core.detection.tracked_crops import grown_boxes
from mvpose_ros.core.geometry.camera import Camera
from mvpose_ros.core.types import FrameResult

NAN = np.nan


def _camera() -> Camera:
    """640 x 480, looking along world +y from the origin (x right, z up)."""
    R = np.array([[1.0, 0, 0], [0, 0, -1.0], [0, 1.0, 0]])
    K = np.array([[500.0, 0, 320], [0, 500.0, 240], [0, 0, 1]])
    return Camera('c', K, R, np.zeros(3), np.zeros(5), 640, 480)


def test_a_view_is_covered_when_one_crop_holds_every_annotated_joint_inside_the_image():
    boxes = np.array([[100.0, 100, 200, 300], [300, 100, 400, 200]])
    uv = np.array([
        [[120, 120], [180, 280], [NAN, NAN]],  # in the first crop; box 60 x 160
        [[310, 110], [390, 210], [350, 150]],  # one joint below the second crop
        [[-50, 10], [-10, 20], [-30, 30]],  # out of the image: not counted
        [[150, 150], [150, 150], [700, 100]],  # a point (its box at least a pixel a side), one joint out of view
    ])
    got = coverage(boxes, uv, (640, 480))
    np.testing.assert_array_equal(got.covered, [True, False, True])
    np.testing.assert_allclose(got.area_ratio, [100 * 200 / (60 * 160), NAN, 100 * 200])
    assert got.line() == ("crops cover 2 of 3 annotated person-views (66.67%); mean crop area 10001.04 x the "
                          "annotation's box")


def test_no_crop_covers_nobody():
    got = coverage(np.zeros((0, 4)), np.array([[[10.0, 10.0]]]), (640, 480))
    np.testing.assert_array_equal(got.covered, [False])
    assert Coverage(np.zeros(0, bool), np.zeros(0)).line().startswith('crops cover 0 of 0')


def test_grown_moves_each_side_out_by_the_margin_times_the_size():
    np.testing.assert_allclose(grown_boxes(np.array([[10.0, 20, 30, 60]]), 0.1), [[8, 16, 32, 64]])


def test_crops_from_the_set_before_follow_a_walker_only_with_his_motion():
    cam = _camera()
    body = np.array([[0.0, 4.0, 0.8], [0.3, 4.0, 0.0], [-0.3, 4.0, 0.0], [0.0, 4.0, -0.8]])  # (J, 3)
    step = np.array([0.25, 0.0, 0.0])  # metres a set: the annotation is two steps on from `earlier`
    earlier = FrameResult(0, [7], body[None])
    before = FrameResult(1, [7], (body + step)[None])
    annotated = cam.project(body + 2 * step)[None, None]  # (A, C, J, 2)
    assert frame_coverage([cam], before, earlier, annotated, margin=0.0).covered.all()
    assert not frame_coverage([cam], before, None, annotated, margin=0.0).covered.any()
