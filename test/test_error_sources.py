"""error_sources: which wrong limb ends the 2D detections back, and the head offsets."""
import numpy as np
import pytest

from mvpose_ros.core.datasets.shelf_campus import GroundTruth
from mvpose_ros.core.drawing.video import look_at
from mvpose_ros.core.evaluation.error_sources import format_error_sources, head_offsets, wrong_endpoints
from mvpose_ros.core.evaluation.pcp import match_actors
from mvpose_ros.core.types import Person2D, Sequence2D

UP = np.array([0.0, 0.0, 1.0])
R_WRIST, L_WRIST = 6, 11
# a person at the origin facing +x (left is +y): ankles, knees, hips, wrists, elbows, shoulders, head
POSE = np.array([[0, -0.1, 0.05], [0, -0.1, 0.5], [0, -0.1, 0.95], [0, 0.1, 0.95], [0, 0.1, 0.5], [0, 0.1, 0.05],
                 [0.25, -0.25, 1.0], [0.05, -0.25, 1.2], [0, -0.2, 1.45], [0, 0.2, 1.45], [0.05, 0.25, 1.2],
                 [0.25, 0.25, 1.0], [0, 0, 1.55], [0, 0, 1.78]])


def _cameras():
    eyes = [np.array([4.0 * np.cos(a), 4.0 * np.sin(a), 1.5]) for a in np.radians([0, 70, -70])]
    return [look_at(eye, np.array([0.0, 0.0, 1.0]), UP, 800, 600, name=f'c{i}') for i, eye in enumerate(eyes)]


def _detected(cameras, pose):
    """Each camera's one person whose 12 limb keypoints are the projection of pose (14, 3)."""
    people = []
    for camera in cameras:
        keypoints = np.zeros((16, 3))
        keypoints[:12, :2] = camera.project(pose[:12])
        keypoints[:12, 2] = 0.9
        people.append([Person2D.from_keypoints(keypoints, 8.0, 6.0)])
    return people


def _case(estimate, detections):
    cameras = _cameras()
    gt = GroundTruth(frames=np.array([7]), poses=POSE[None, None])
    seq = Sequence2D(cameras, [7], [_detected(cameras, detections)])
    matches = match_actors({7: estimate[None]}, gt, [0])
    return matches, wrong_endpoints(matches, [0], seq, gt.frames)


def _moved(joint, offset):
    pose = POSE.copy()
    pose[joint] += offset
    return pose


def test_an_estimate_the_detections_back_is_wrong_with_them():
    estimate = _moved(R_WRIST, [0.0, -0.3, 0.1])
    _, endpoints = _case(estimate, estimate)
    assert [(e.joint, e.verdict, e.backing_estimate, e.backing_annotation) for e in endpoints] == \
        [(R_WRIST, 'estimate', 3, 0)]
    assert endpoints[0].error_m == pytest.approx(np.hypot(0.3, 0.1))


def test_an_estimate_against_the_detections_is_named():
    estimate = _moved(L_WRIST, [0.0, 0.0, 0.3])
    matches, endpoints = _case(estimate, POSE)
    assert [(e.joint, e.verdict, e.backing_estimate, e.backing_annotation) for e in endpoints] == \
        [(L_WRIST, 'annotation', 0, 3)]
    text = format_error_sources(endpoints, head_offsets(matches, [0]), [0])
    assert 'against the detections: actor 1 frame 7 l_wrist 300 mm off' in text


def test_a_small_error_within_the_tolerance_is_not_listed():
    _, endpoints = _case(_moved(R_WRIST, [0.0, 0.0, 0.05]), POSE)
    assert endpoints == []


def test_head_offsets_are_in_the_body_frame():
    estimate = POSE.copy()
    truth_top = np.array([0.05, 0.0, 0.1]) + 0.5 * (POSE[12] + POSE[13])
    truth = POSE.copy()
    truth[13] = truth_top
    turn = np.array([[0.0, -1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]])  # the scene turned 90 degrees about up
    for rotation in (np.eye(3), turn):
        gt = GroundTruth(frames=np.array([1]), poses=(truth @ rotation.T)[None, None])
        head, = head_offsets(match_actors({1: (estimate @ rotation.T)[None]}, gt, [0]), [0])
        assert head.top == pytest.approx([0.05, 0.0, 0.1], abs=1e-9)
        assert head.bottom == pytest.approx([0.0, 0.0, -0.115], abs=1e-9)
        assert head.length_estimate == pytest.approx(0.23)
        assert head.length_true == pytest.approx(np.linalg.norm(truth_top - POSE[12]))


def test_a_frame_or_camera_without_detections_backs_nothing():
    estimate = _moved(R_WRIST, [0.0, 0.0, 0.3])
    cameras = _cameras()
    gt = GroundTruth(frames=np.array([7]), poses=POSE[None, None])
    matches = match_actors({7: estimate[None]}, gt, [0])
    for seq in (Sequence2D(cameras, [8], [_detected(cameras, estimate)]),  # another frame
                Sequence2D(cameras, [7], [[None, [], None]])):  # no data, nobody, no data
        endpoints = wrong_endpoints(matches, [0], seq, gt.frames)
        assert [(e.joint, e.verdict, e.backing_estimate, e.backing_annotation) for e in endpoints] == \
            [(R_WRIST, 'neither', 0, 0)]
