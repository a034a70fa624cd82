"""Crops from projected skeletons instead of the person detector: the boxes, the carried ears, the
schedule of MultiPose runs, and a real crop from a projected Shelf skeleton; batched EfficientPose
runs give what one crop at a time gives."""
from __future__ import annotations

from dataclasses import replace

import cv2
import numpy as np
import pytest

from mvpose_ros.core.datasets.shelf_campus import calibration_file, dataset_dir, load_actors_gt, load_actors_gt_2d
from mvpose_ros.core.defaults import data_root
from mvpose_ros.core.detection.onnx_detector import OnnxDetectorConfig, OnnxPoseDetector
from mvpose_ros.core.detection.tracked_crops import (CropPlanner, carried_ears, people_region, predicted_joints,
                                                     projected_boxes, unexplained)
from mvpose_ros.core.geometry.body import L_EAR, NECK, NUM_INFERENCE_JOINTS, R_EAR
from mvpose_ros.core.geometry.camera import Camera, load_rig
from mvpose_ros.core.types import Person2D

FRAME, CAMERA = 572, 4


def _camera() -> Camera:
    """640 x 480, looking along world +y from the origin (x right, z up)."""
    R = np.array([[1.0, 0, 0], [0, 0, -1.0], [0, 1.0, 0]])
    K = np.array([[500.0, 0, 320], [0, 500.0, 240], [0, 0, 1]])
    return Camera('c', K, R, np.zeros(3), np.zeros(5), 640, 480)


def test_a_box_around_the_projected_joints_grown_by_the_margin_and_cut_to_the_image():
    cam = _camera()
    near = np.array([[0.0, 4.0, 0.5], [0.4, 4.0, -0.5], [-0.4, 4.0, 0.0], [0.0, 4.0, np.nan]])  # one joint missing
    uv = cam.project(near[:3])
    (box,) = projected_boxes(near[None], cam, margin=0.1, min_joints=3)
    size = uv.max(axis=0) - uv.min(axis=0)
    np.testing.assert_allclose(box, np.concatenate([uv.min(axis=0) - 0.1 * size, uv.max(axis=0) + 0.1 * size]))
    # a person at the right edge: the box stops at the image's last pixel edge
    edge = near + [2.2, 0.0, 0.0]  # u 545, 645 (out of view), 595
    (cut,) = projected_boxes(edge[None], cam, margin=0.1, min_joints=2)
    np.testing.assert_allclose(cut[[0, 2]], [545.0 - 10.0, 639.5])
    # behind the camera, out of view, or too few joints in view: no box, the others keep their order
    behind = near * [1, -1, 1]
    out_of_view = near + [5.0, 0.0, 0.0]
    boxes = projected_boxes(np.stack([behind, near, out_of_view, edge]), cam, margin=0.1, min_joints=2)
    np.testing.assert_allclose(boxes, [box, cut])
    assert len(projected_boxes(edge[None], cam, min_joints=3)) == 0  # two of its joints in view
    assert projected_boxes(np.zeros((0, 14, 3)), cam).shape == (0, 4)


def test_ears_follow_the_nearest_previous_neck():
    previous = np.zeros((2, NUM_INFERENCE_JOINTS, 3))
    previous[0, NECK] = (100.0, 100.0, 0.9)
    previous[0, [R_EAR, L_EAR]] = [(90.0, 80.0, 0.7), (110.0, 80.0, 0.6)]
    previous[1, NECK] = (300.0, 100.0, 0.9)
    previous[1, R_EAR] = (290.0, 80.0, 0.8)  # its left ear unseen (score 0)
    ears = carried_ears(np.array([105.0, 98.0, 0.8]), previous, size=200.0)
    np.testing.assert_allclose(ears, [[95.0, 78.0, 0.7], [115.0, 78.0, 0.6]])
    ears = carried_ears(np.array([310.0, 100.0, 0.8]), previous, size=200.0)
    np.testing.assert_allclose(ears[0], [300.0, 80.0, 0.8])
    assert ears[1, 2] == 0 and np.isnan(ears[1, :2]).all()
    # beyond the gate (0.25 * 200 px), an undetected neck, or nobody before: no ears
    for neck, before in (([200.0, 100.0, 0.8], previous), ([105.0, 98.0, 0.0], previous),
                         ([105.0, 98.0, 0.8], previous[:0])):
        assert (carried_ears(np.array(neck), before, size=200.0)[:, 2] == 0).all()


def test_each_camera_searches_every_kth_set_in_turn_and_all_while_no_skeleton_is_known():
    cam = _camera()
    planner = CropPlanner([cam, cam, cam], every=3)
    skeleton = np.array([[[0.0, 4.0, 0.5], [0.4, 4.0, -0.5], [-0.4, 4.0, 0.0], [0.1, 4.0, -0.9]]])
    searched = []
    for n in range(8):
        plan = planner.plan()
        searched.append(''.join('W' if p is None else '.' for p in plan))
        assert all(p.shape == (1, 4) for p in plan if p is not None)
        planner.update(plan, [[], [], []])
        planner.skeletons(skeleton if n != 4 else skeleton[:0])  # set 4 saw nobody
    # set 0: no skeleton yet; then camera c at the sets n with (n + c) % 3 == 0; set 5 after nobody
    assert searched == ['WWW', '..W', '.W.', 'W..', '..W', 'WWW', 'W..', '..W']
    # every camera searches within any 3 sets in a row, and one camera a set in the steady state
    two = CropPlanner([cam, cam], every=4)
    two.update([None, None], [[], []])
    two.skeletons(skeleton)
    searches = []
    for _ in range(8):
        plan = two.plan()
        assert two.plan() is not plan and [p is None for p in two.plan()] == [p is None for p in plan]  # no side effect
        searches.append(sum(p is None for p in plan))
        two.update(plan, [[], []])
    assert searches == [0, 1, 0, 1, 0, 1, 0, 1]
    with pytest.raises(ValueError, match='person_detector_every 0 must be >= 1'):
        CropPlanner([cam], every=0)
    # a camera whose intrinsics are not known yet runs MultiPose on its whole image
    planner = CropPlanner([None, cam], every=3)
    planner.update([None, None], [[], []])
    planner.skeletons(skeleton)
    plan = planner.plan()
    assert plan[0] is None and plan[1].shape == (1, 4)


def test_the_region_multipose_searches_holds_every_box_grown_by_the_margin_cut_to_the_image():
    boxes = np.array([[100.0, 50.0, 200.0, 250.0], [400.0, 300.0, 440.0, 380.0]])
    # first box grows by 25 / 50 px, the second by 10 / 20 px
    np.testing.assert_allclose(people_region(boxes, (640, 480), 0.25), [75.0, 0.0, 450.0, 400.0])
    np.testing.assert_allclose(people_region(boxes, (640, 480), 0.0), [100.0, 50.0, 440.0, 380.0])
    np.testing.assert_allclose(people_region(boxes, (420, 390), 0.25), [75.0, 0.0, 419.5, 389.5])  # cut


@pytest.fixture(scope='module')
def shelf() -> tuple[OnnxPoseDetector, np.ndarray, Camera]:
    detector = OnnxPoseDetector(OnnxDetectorConfig(model_dir=data_root() / 'models', heatmaps='efficientpose'))
    image = cv2.imread(str(dataset_dir('shelf') / 'frames' / f'cam{CAMERA}_{FRAME:06d}.png'))
    camera = load_rig(calibration_file('shelf'), image.shape[1], image.shape[0])[CAMERA]
    return detector, image, camera


def test_crops_from_projected_skeletons_find_the_people_without_multipose(shelf):
    """Shelf's annotated 3D skeletons of frame 572 projected into camera 4: EfficientPose on those
    crops alone (MultiPose does not run) puts every actor's joints near its 2D annotation."""
    detector, image, camera = shelf
    joints = load_actors_gt(dataset_dir('shelf') / 'actorsGT.mat', [FRAME]).poses[0]  # (A, 14, 3)
    annotated = np.isfinite(joints).all(axis=(1, 2))
    boxes = projected_boxes(joints[annotated], camera)
    assert len(boxes) == annotated.sum() == 3
    (people,) = detector.detect_set([image], [boxes])
    assert detector.timing.multipose_runs == 0 and detector.timing.multipose < detector.timing.efficientpose
    assert len(people) == 3
    truth = load_actors_gt_2d(dataset_dir('shelf') / 'actorsGT.mat', [FRAME])[0, annotated, CAMERA]  # (3, 14, 2)
    for person, gt in zip(people, truth):  # crops in the skeletons' order
        # 12-24 px with MultiPose's boxes on this image (test_onnx_detector); 40 px is a real regression
        assert np.nanmedian(np.linalg.norm(person.keypoints[:14, :2] - gt, axis=1)) < 40.0
        assert person.keypoints[[R_EAR, L_EAR], 2].max() == 0  # no MultiPose and no previous people: no ears
    # with the camera's people of the previous set (here: MultiPose's), each gets its ears back
    before = detector.detect(image)
    previous = np.array([p.keypoints for p in before])
    (carried,) = detector.detect_set([image], [boxes], [previous])
    assert all(p.keypoints[[R_EAR, L_EAR], 2].max() > 0 for p in carried)


def test_batched_crops_equal_one_crop_at_a_time(shelf):
    """All the crops of a set in one EfficientPose run (max_batch 0, for a GPU) give the people and
    heatmaps that runs of one crop give, to float rounding."""
    detector, image, _ = shelf
    single = OnnxPoseDetector(replace(detector.config, max_batch=1))
    batched = OnnxPoseDetector(replace(detector.config, max_batch=0))
    images = [image, image[:, ::-1].copy()]  # two cameras' worth of crops in one run
    one, many = single.detect_set(images), batched.detect_set(images)
    assert [len(p) for p in one] == [len(p) for p in many] and len(one[0]) >= 3
    for a, b in zip(sum(one, []), sum(many, [])):
        np.testing.assert_allclose(a.keypoints, b.keypoints, atol=1e-2, equal_nan=True)
        assert a.heatmap.maps.shape == b.heatmap.maps.shape
        np.testing.assert_allclose(a.heatmap.maps, b.heatmap.maps, atol=1e-4)


def test_a_skeletons_motion_carries_him_on_one_set_and_his_crop_holds_both_places():
    joints = np.array([[[0.0, 4.0, 0.5], [0.4, 4.0, -0.5], [np.nan] * 3, [0.1, 4.0, -0.9], [-0.3, 4.0, 0.2]]])
    before = joints - [0.1, 0.0, 0.0]
    before[0, 3] = np.nan  # a joint not seen before stays where it is
    moved = predicted_joints(joints, np.array([7]), before, np.array([7]))
    np.testing.assert_allclose(moved[0, [0, 1]], joints[0, [0, 1]] + [0.1, 0.0, 0.0])
    np.testing.assert_array_equal(moved[0, 3], joints[0, 3])
    assert np.isnan(moved[0, 2]).all()
    # another id: no motion
    np.testing.assert_array_equal(predicted_joints(joints, np.array([8]), before, np.array([7])), joints)
    cam = _camera()
    planner = CropPlanner([cam], every=5)
    planner.update([None], [[]])
    planner.skeletons(before, np.array([7]))
    planner.skeletons(joints, np.array([7]))
    planner.skeletons(joints, np.array([7]))  # the same skeletons again (no new set solved): motion kept
    (box,) = planner.plan()[0]
    both = np.concatenate([joints, moved], axis=1)
    np.testing.assert_allclose(box, projected_boxes(both, cam)[0])
    assert box[2] > projected_boxes(joints, cam)[0, 2] + 5  # moving right: the crop reaches further right
    with pytest.raises(ValueError, match='2 ids for 1 people'):
        planner.skeletons(joints, np.array([1, 2]))


def test_a_camera_where_multipose_finds_someone_no_skeleton_explains_runs_it_until_explained():
    cam = _camera()
    rng = np.random.default_rng(0)
    skeleton = np.stack([rng.uniform(-0.3, 0.3, 14), np.full(14, 4.0), np.linspace(-0.9, 0.8, 14)], axis=1)[None]
    shift = np.array([250 * 4.0 / 500, 0.0, 0.0])  # 250 px to the right at 4 m (f 500 px)

    def person(joints: np.ndarray) -> Person2D:
        kp = np.full((NUM_INFERENCE_JOINTS, 3), np.nan)
        kp[:, 2] = 0.0
        kp[:12] = np.concatenate([cam.project(joints[:12]) + rng.normal(0, 3, (12, 2)), np.full((12, 1), 0.8)], axis=1)
        return Person2D(kp, None)

    one, two = person(skeleton[0]), person(skeleton[0] + shift)
    planner = CropPlanner([cam, cam], every=10)
    planner.update([None, None], [[one], [one, two]])  # camera 1 sees one more
    planner.skeletons(skeleton, np.array([1]))
    assert planner.unexplained == [False, True]
    plan = planner.plan()
    assert plan[0].shape == (1, 4) and plan[1] is None  # camera 1 keeps looking at its whole image
    planner.update(plan, [[one], [one, two]])
    planner.skeletons(skeleton, np.array([1]))
    assert planner.plan()[1] is None
    # the 3D stage took him up: explained, crops again
    planner.update(planner.plan(), [[one], [one, two]])
    planner.skeletons(np.concatenate([skeleton, skeleton + shift]), np.array([1, 2]))
    assert planner.unexplained == [False, False] and planner.plan()[1].shape == (2, 4)
    # a neighbour close to him is not explained by the skeleton he is matched to, and alone is
    near = person(skeleton[0] + shift / 5)
    np.testing.assert_array_equal(unexplained(np.stack([one.keypoints, near.keypoints]), cam.project(skeleton)),
                                  [False, True])
    assert not unexplained(near.keypoints[None], cam.project(skeleton)).any()
    # a stray detection of three joints flags nothing
    stray = person(skeleton[0] + shift)
    stray.keypoints[3:, 2] = 0.0
    assert not unexplained(stray.keypoints[None], np.zeros((0, 14, 2))).any()
    assert unexplained(two.keypoints[None], np.zeros((0, 14, 2))).all()


def test_a_person_who_enters_is_found_within_k_sets_and_kept_by_multipose_until_tracked():
    """Camera 4 of Shelf frame 572 with one annotated actor painted out of the first set, tracked
    crops through MoveNet Lightning and MultiPose every K = 3 sets, the skeletons the actors' own
    (annotated) 3D joints as the 3D stage would give them once it sees them: the actor who enters at
    set 1 is found at set 3 (the next whole-image run, within K sets of entering), his camera runs
    MultiPose again at set 4 while no skeleton explains him, and crops take him up once one does."""
    every = 3
    # the image's left 756 columns: the three annotated actors, without the fourth person (x > 738),
    # whom no annotated skeleton would explain
    image = cv2.imread(str(dataset_dir('shelf') / 'frames' / f'cam{CAMERA}_{FRAME:06d}.png'))
    image = np.ascontiguousarray(image[:, :756])
    camera = load_rig(calibration_file('shelf'), image.shape[1], image.shape[0])[CAMERA]
    actors = load_actors_gt(dataset_dir('shelf') / 'actorsGT.mat', [FRAME]).poses[0]  # (A, 14, 3)
    truth = load_actors_gt_2d(dataset_dir('shelf') / 'actorsGT.mat', [FRAME])[0, :, CAMERA]  # (A, 14, 2)
    annotated = np.flatnonzero(np.isfinite(truth).all(axis=(1, 2)))
    entering = annotated[-1]
    lo, hi = truth[entering].min(axis=0), truth[entering].max(axis=0)
    x0, y0 = np.maximum(0, lo - 0.15 * (hi - lo)).astype(int)
    x1, y1 = (hi + 0.15 * (hi - lo)).astype(int)
    empty = image.copy()
    empty[y0:y1, x0:x1] = np.median(image.reshape(-1, 3), axis=0).astype(np.uint8)
    detector = OnnxPoseDetector(OnnxDetectorConfig(model_dir=data_root() / 'models', heatmaps='efficientpose',
                                                   model='lightning', threads=1))
    planner = CropPlanner([camera], every)

    def near(people, actor: int) -> bool:
        return any(np.nanmedian(np.linalg.norm(p.keypoints[:12, :2] - truth[actor, :12], axis=1)) < 40.0
                   for p in people)

    tracked = [a for a in annotated if a != entering]
    whole, found = [], []
    for n in range(5):
        plan = planner.plan()
        whole.append(plan[0] is None)
        (people,) = detector.detect_set([empty if n == 0 else image], plan, planner.previous)
        found.append(near(people, entering))
        planner.update(plan, [people])
        if found[-1] and n > 3:
            tracked = list(annotated)  # the 3D stage took him up after a set that found him
        planner.skeletons(actors[tracked], np.array(tracked))
    assert whole == [True, False, False, True, True]
    assert found[:3] == [False, False, False] and found[3] and all(found[3:])
    assert len(planner.plan()[0]) == len(annotated)  # then crops for all, the one who entered too
