"""The crowd at the level of OpenPose output (core.scenarios.crowd_openpose), which the shelf_crowd bag
carries: copies group into people of their own, where the copied 3D people would be seen."""
import numpy as np
import pytest

from mvpose_ros.bags.recipes import make_recipe
from mvpose_ros.core.association.associator import AssociationConfig, Associator
from mvpose_ros.core.defaults import FRAME_RATE
from mvpose_ros.core.detection.openpose import BODY25_NUM_JOINTS, BODY25_PAF_PAIRS
from mvpose_ros.core.detection.openpose_detector import OpenPoseDetectorConfig, detect_grouped, detect_people
from mvpose_ros.core.evaluation.offline import shelf_openpose_raw
from mvpose_ros.core.geometry.body import BODY25_NAMES, INFERENCE_NAMES
from mvpose_ros.core.scenarios.crowd_openpose import (ANCHORS, candidate_displacements, copy_candidates, crowd_openpose,
                                                      with_copies)

DETECTOR = OpenPoseDetectorConfig()


@pytest.fixture(scope='module')
def shelf_raw():
    """Shelf cameras and, per frame, every camera's OpenPose output (the first 20 test frames)."""
    cameras, raw = shelf_openpose_raw(None)
    return cameras, [list(per_frame) for per_frame in zip(*raw)][:20]


def test_every_body25_joint_moves_with_its_own_or_its_nearest_inference_joint():
    names = {BODY25_NAMES[b]: {INFERENCE_NAMES[i] for i in ANCHORS[b]} for b in range(BODY25_NUM_JOINTS)}
    assert names['r_wrist'] == {'r_wrist'} and names['nose'] == {'head'} and names['l_ear'] == {'l_ear'}
    assert names['mid_hip'] == {'r_hip', 'l_hip'} and names['l_eye'] == {'head'} and names['r_heel'] == {'r_ankle'}


def test_displacements_are_the_moved_projections(shelf_raw):
    cameras, _ = shelf_raw
    cam = cameras[0]
    joints = np.full((len(INFERENCE_NAMES), 3), np.nan)
    joints[INFERENCE_NAMES.index('r_hip')] = (0.1, 0.2, 0.9)
    joints[INFERENCE_NAMES.index('l_hip')] = (0.1, 0.4, 0.9)
    offset = np.array([1.0, -0.5, 0.0])
    shift = candidate_displacements(cam, joints, offset)
    r = cam.project(joints[2] + offset) - cam.project(joints[2])
    left = cam.project(joints[3] + offset) - cam.project(joints[3])
    np.testing.assert_allclose(shift[BODY25_NAMES.index('r_hip')], r)
    np.testing.assert_allclose(shift[BODY25_NAMES.index('mid_hip')], 0.5 * (r + left))
    assert np.isnan(shift[BODY25_NAMES.index('r_wrist')]).all()  # not triangulated: no copy of it
    np.testing.assert_allclose(candidate_displacements(cam, joints, np.zeros(3))[[8, 9, 12]], 0.0)


def test_a_copy_groups_as_a_person_of_its_own_at_the_shifted_place(shelf_raw):
    cameras, frames = shelf_raw
    frame, cam = frames[0][1], cameras[1]
    groups, people = detect_grouped(frame, DETECTOR)
    assert len(people) >= 2
    shift = np.tile([60.0, -20.0], (BODY25_NUM_JOINTS, 1))
    rows = copy_candidates(frame, cam, groups[0], shift)
    crowd = with_copies(frame, [(rows, groups[0])])
    for b, cand in enumerate(frame.candidates):  # the frame's own candidates and affinities stay first
        np.testing.assert_array_equal(crowd.candidates[b][:len(cand)], cand)
    for k, paf in enumerate(frame.pafs):
        np.testing.assert_array_equal(crowd.pafs[k][:paf.shape[0], :paf.shape[1]], paf)
    found = detect_people(crowd, DETECTOR)
    assert len(found) == len(people) + 1
    expected = people[0].keypoints.copy()
    seen = expected[:, 2] > 0
    expected[seen, :2] += (60.0, -20.0)
    copy = [p for p in found if np.allclose(p.keypoints[seen, :2], expected[seen, :2])]
    assert len(copy) == 1 and np.array_equal(copy[0].keypoints[:, 2] > 0, seen)


def test_a_copy_links_only_its_own_candidates(shelf_raw):
    cameras, frames = shelf_raw
    frame = frames[0][0]
    groups, _ = detect_grouped(frame, DETECTOR)
    shift = np.zeros((BODY25_NUM_JOINTS, 2))
    rows = copy_candidates(frame, cameras[0], groups[0], shift)
    crowd = with_copies(frame, [(rows, groups[0])])
    for k, (a, b) in enumerate(BODY25_PAF_PAIRS):
        old = frame.pafs[k]
        new = crowd.pafs[k]
        # the copy's rows and columns are zero but for its own pair, which has the original's affinity
        assert not new[old.shape[0]:, :old.shape[1]].any() and not new[:old.shape[0], old.shape[1]:].any()
        if groups[0][a] >= 0 and groups[0][b] >= 0:
            assert new[-1, -1] == old[groups[0][a], groups[0][b]]


def test_a_copy_mostly_outside_the_image_is_not_made(shelf_raw):
    cameras, frames = shelf_raw
    frame, cam = frames[0][0], cameras[0]
    groups, _ = detect_grouped(frame, DETECTOR)
    far = np.tile([cam.width * 2.0, 0.0], (BODY25_NUM_JOINTS, 1))
    assert copy_candidates(frame, cam, groups[0], far) is None


def test_the_crowd_brings_the_scene_near_the_target_and_keeps_the_originals(shelf_raw):
    cameras, frames = shelf_raw
    crowd = crowd_openpose(cameras, frames, 8)
    assert len(crowd.offsets) > 1 and crowd.original < 5
    for original, copied in zip(frames, crowd.frames):
        for f, g in zip(original, copied):
            for a, b in zip(f.candidates, g.candidates):
                np.testing.assert_array_equal(b[:len(a)], a)
    associator = Associator(cameras, AssociationConfig())
    found = [len(associator.update(t / FRAME_RATE, [detect_people(f, DETECTOR) for f in per_camera]))
             for t, per_camera in enumerate(crowd.frames)]
    assert abs(np.mean(found) - crowd.expected) <= 0.2 * crowd.expected
    assert np.mean(found) >= 2 * crowd.original


@pytest.mark.slow
def test_shelf_crowd_recipe_has_every_frame_with_the_crowd():
    recipe = make_recipe('shelf_crowd')
    assert recipe.variant == 'people 20'
    first = []
    for topic, msg, ns in recipe.items():
        if topic == '/cam0/openpose':
            first.append(ns)
            if len(first) == 1:
                assert msg.header.frame_id == 'cam0' and msg.width > 0
    assert len(first) == 301 and first == sorted(first)
