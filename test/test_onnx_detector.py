"""The ONNX backend with the real models on a real Shelf image (heatmaps from EfficientPose, from
MultiPose's keypoints, or fused), the rendering of keypoints as maps, and the clear errors for a
missing model, another model's file, a file that is not ONNX, and bad settings."""
from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import cv2
import numpy as np
import pytest

from mvpose_ros.core.datasets.shelf_campus import dataset_dir, load_actors_gt_2d
from mvpose_ros.core.defaults import data_root
from mvpose_ros.core.detection.onnx_detector import (OnnxDetectorConfig, OnnxPoseDetector, crowd_tiles,
                                                     keypoint_people, region_input_side, without_duplicates)
from mvpose_ros.core.detection.onnx_models import EFFICIENTPOSE, MULTIPOSE, ModelError
from mvpose_ros.core.geometry.body import L_EAR, NECK, NUM_INFERENCE_JOINTS, R_EAR
from mvpose_ros.core.heatmap import PersonHeatmap
from mvpose_ros.core.types import Person2D

MODELS = data_root() / 'models'
FRAME, CAMERA = 572, 4


@pytest.fixture(scope='module')
def detector() -> OnnxPoseDetector:
    return OnnxPoseDetector(OnnxDetectorConfig(model_dir=MODELS, heatmaps='efficientpose'))


@pytest.fixture(scope='module')
def shelf_image() -> np.ndarray:
    return cv2.imread(str(dataset_dir('shelf') / 'frames' / f'cam{CAMERA}_{FRAME:06d}.png'))


def test_real_models_find_the_people_of_a_shelf_image(detector, shelf_image):
    people = detector.detect(shelf_image)
    h, w = shelf_image.shape[:2]
    assert 3 <= len(people) <= 5  # four people are in view; actors 1, 3 and 4 are annotated
    for person in people:
        kp = person.keypoints
        assert kp.shape == (NUM_INFERENCE_JOINTS, 3)
        seen = kp[:, 2] > 0
        assert seen[:12].sum() >= 10 and seen[[R_EAR, L_EAR]].any()  # limbs from EfficientPose, ears from MultiPose
        assert np.all((kp[seen, :2] >= 0) & (kp[seen, :2] < [w, h]))
        maps = person.heatmap.maps
        assert maps.shape[0] == NUM_INFERENCE_JOINTS and maps.min() >= 0 and maps.max() <= 1
        assert np.all(maps[~seen] == 0)
        # each detected joint's heatmap peaks where its keypoint is (the keypoint is sub-pixel)
        peak = person.heatmap.peak()
        assert np.all(np.linalg.norm(peak[seen, :2] - kp[seen, :2], axis=1) <= 2 * person.heatmap.stride)
    # every annotated actor has a detection whose joints are near the annotation: median joint
    # error (14 joints) measured 12-24 px on this image, 1032x776; 40 px would be a real regression
    _near_annotations(people, 40.0)
    t = detector.timing
    assert t.people == len(people) and 0 < t.multipose < t.total and 0 < t.efficientpose < t.total


def _near_annotations(people, errors_px: float) -> None:
    """Every annotated actor of the image has a detection whose median joint error (14 joints) is
    below errors_px."""
    gt = load_actors_gt_2d(dataset_dir('shelf') / 'actorsGT.mat', [FRAME])[0, :, CAMERA]  # (A, 14, 2)
    annotated = np.isfinite(gt).all(axis=(1, 2))
    assert annotated.sum() == 3
    for truth in gt[annotated]:
        errors = [np.nanmedian(np.linalg.norm(p.keypoints[:14, :2] - truth, axis=1)) for p in people]
        assert min(errors) < errors_px


def test_keypoint_people_render_each_joint_as_a_score_weighted_gaussian():
    keypoints = np.full((2, NUM_INFERENCE_JOINTS, 3), np.nan)
    keypoints[..., 2] = 0.0
    keypoints[0, :3] = [[101.3, 200.7, 0.9], [150.0, 260.2, 0.4], [170.0, 300.0, 0.0]]
    keypoints[0, 2, :2] = (170.0, 300.0)  # a joint of score 0 where a point is given: still no evidence
    keypoints[0, NECK] = [130.0, 120.0, 1.0]
    sigma = 12.0
    people = keypoint_people(keypoints, np.array([sigma, 5.0]), 4.0)
    assert len(people) == 1  # the second person has no joint
    heatmap = people[0].heatmap
    np.testing.assert_array_equal(people[0].keypoints[:2], keypoints[0, :2])
    peak = heatmap.peak()
    seen = [0, 1, NECK]
    # each map peaks in the cell holding its keypoint, at about its score (the cell centre is at
    # most half a cell's diagonal away)
    assert np.all(np.abs(peak[seen, :2] - keypoints[0, seen, :2]) <= 2.0)
    np.testing.assert_allclose(peak[seen, 2], keypoints[0, seen, 2], rtol=0.02)
    uv = keypoints[0, :, None, :2] + np.array([[0.0, 0.0], [sigma, 0.0], [0.0, -2 * sigma]])  # (16, 3, 2)
    values = heatmap.lookup(np.nan_to_num(uv))
    # score-weighted Gaussians of std sigma: exp(-1/2) of the peak one sigma off, exp(-2) two sigmas off
    np.testing.assert_allclose(values[seen, 1] / values[seen, 0], np.exp(-0.5), rtol=0.03)
    np.testing.assert_allclose(values[seen, 2] / values[seen, 0], np.exp(-2.0), rtol=0.1)
    empty = np.setdiff1d(np.arange(NUM_INFERENCE_JOINTS), seen)
    assert not heatmap.maps[empty].any() and np.all(peak[empty, 2] == 0)


@pytest.fixture(scope='module')
def multipose_detector() -> OnnxPoseDetector:
    return OnnxPoseDetector(OnnxDetectorConfig(model_dir=MODELS, heatmaps='multipose'))


def test_heatmaps_from_multipose_keypoints_without_efficientpose(multipose_detector, shelf_image, tmp_path):
    people = multipose_detector.detect(shelf_image)
    assert 3 <= len(people) <= 5
    for person in people:
        seen = person.keypoints[:, 2] > 0
        assert seen[:12].sum() >= 8 and seen[NECK]
        peak = person.heatmap.peak()
        assert np.all(np.linalg.norm(peak[seen, :2] - person.keypoints[seen, :2], axis=1) <= person.heatmap.stride)
        np.testing.assert_allclose(peak[seen, 2], np.minimum(person.keypoints[seen, 2], 1.0), rtol=0.05)
        assert not person.heatmap.maps[~seen].any()
    # measured 15, 31, 24 px on this image (EfficientPose: 12, 23, 21 px)
    _near_annotations(people, 40.0)
    t = multipose_detector.timing
    assert t.people == len(people) and 0 < t.multipose < t.total and t.efficientpose < 0.1 * t.multipose
    # EfficientPose is not even loaded: a model folder without it will do
    folder = _folder(tmp_path, **{MULTIPOSE.file: MODELS / MULTIPOSE.file})
    assert len(OnnxPoseDetector(OnnxDetectorConfig(model_dir=folder, heatmaps='multipose')).detect(shelf_image)) \
        == len(people)


def test_given_boxes_make_multipose_search_only_the_region_around_them(multipose_detector, shelf_image):
    """heatmaps 'multipose' with the boxes where people are expected (tracked_crops): MultiPose runs
    on the region around them, at least at the whole image's input pixels per image pixel, so on
    a smaller input. The same people, keypoints within a few pixels (medians per person measured
    on the five frame-572 images: 1.9-5.3 px; one input pixel of the whole image is 2.7 px);
    nobody outside the region (the letterbox's padding gives no keypoints); no boxes: the whole
    image."""
    (whole,) = multipose_detector.detect_set([shelf_image])
    keypoints = np.array([p.keypoints for p in whole])
    seen = keypoints[..., 2] > 0
    boxes = np.concatenate([np.where(seen[..., None], keypoints[..., :2], np.inf).min(axis=1),
                            np.where(seen[..., None], keypoints[..., :2], -np.inf).max(axis=1)], axis=1)
    (region,) = multipose_detector.detect_set([shelf_image], [boxes])
    assert multipose_detector.timing.multipose_runs == 1 and len(region) == len(whole) >= 3
    input_pixel = max(shelf_image.shape[:2]) / multipose_detector.config.input_size
    for a in whole:
        shifts = []
        for b in region:
            both = (a.keypoints[:, 2] > 0.3) & (b.keypoints[:, 2] > 0.3)
            shifts.append(np.median(np.linalg.norm(a.keypoints[both, :2] - b.keypoints[both, :2], axis=1)))
        assert min(shifts) < 3 * input_pixel
    _near_annotations(region, 40.0)
    # a region of shelves holding nobody: no one, and no keypoint from the letterbox's padding
    (corner,) = multipose_detector.detect_set([shelf_image], [np.array([[900.0, 20.0, 1000.0, 150.0]])])
    assert corner == []
    (again,) = multipose_detector.detect_set([shelf_image], [np.zeros((0, 4))])
    assert len(again) == len(whole) and all(np.array_equal(a.keypoints, b.keypoints) for a, b in zip(again, whole))


def test_a_regions_input_keeps_the_whole_images_scale_in_multiples_of_32():
    assert region_input_side(np.array([784.0, 776.0]), (1032, 776), 384) == 320  # 291.7 px, rounded up
    assert region_input_side(np.array([400.0, 600.0]), (1032, 776), 384) == 224  # 223.3 px
    assert region_input_side(np.array([2000.0, 10.0]), (1032, 776), 384) == 384  # never above the whole image's
    assert region_input_side(np.array([5.0, 5.0]), (1032, 776), 384) == 32


def test_multipose_workers_find_the_same_people_in_each_image_of_a_set(shelf_image):
    """MultiPose on two images at once: each camera's people as one after the other (threads 1:
    onnxruntime's sums depend on the thread split)."""
    config = OnnxDetectorConfig(model_dir=MODELS, heatmaps='multipose', threads=1)
    images = [shelf_image, None, shelf_image[:, ::-1].copy(), np.zeros_like(shelf_image), shelf_image[::-1].copy()]
    one = OnnxPoseDetector(config).detect_set(images)
    pool = OnnxPoseDetector(replace(config, multipose_workers=2))
    two = pool.detect_set(images)
    assert pool.timing.multipose_runs == 4 and two[1] is None and two[3] == []
    assert [len(p) for p in one if p] == [len(p) for p in two if p] and len(two[0]) >= 3
    for a, b in zip(sum([p for p in one if p], []), sum([p for p in two if p], [])):
        np.testing.assert_array_equal(a.keypoints, b.keypoints)
        np.testing.assert_array_equal(a.heatmap.maps, b.heatmap.maps)


@pytest.mark.slow
def test_sets_started_while_the_one_before_finishes_find_what_each_set_alone_finds(shelf_image):
    """start_set / finish with a second set started before the first is finished (as the whole-rig
    detector and mvpose-images --sets run a sequence): every set's people are those detect_set
    gives it alone, in order, and the sets' MultiPose runs all end."""
    config = OnnxDetectorConfig(model_dir=MODELS, heatmaps='multipose', threads=1)
    sets = [[shelf_image, shelf_image[:, ::-1].copy(), None], [shelf_image[::-1].copy(), shelf_image, shelf_image],
            [np.zeros_like(shelf_image), shelf_image, shelf_image[:, ::-1].copy()]]
    alone = OnnxPoseDetector(config)
    expected = [alone.detect_set(images) for images in sets]
    pool = OnnxPoseDetector(replace(config, multipose_workers=2))
    pending = [pool.start_set(sets[0]), pool.start_set(sets[1])]
    got = [pool.finish(pending[0])]
    pending.append(pool.start_set(sets[2]))
    got += [pool.finish(pending[1]), pool.finish(pending[2])]
    assert all(f.done() for p in pending for f in p.finds) and [len(p.finds) for p in pending] == [2, 3, 3]
    assert pool.timing.multipose_runs == 3 and pool.timing.total >= pool.timing.multipose > 0
    for one, two in zip(expected, got):
        assert [p is None for p in one] == [p is None for p in two]
        assert [len(p) for p in one if p is not None] == [len(p) for p in two if p is not None]
        for a, b in zip(sum([p for p in one if p], []), sum([p for p in two if p], [])):
            np.testing.assert_array_equal(a.keypoints, b.keypoints)
            np.testing.assert_array_equal(a.heatmap.maps, b.heatmap.maps)
    assert sum(len(p) for p in got[1]) >= 6


def test_a_shrunk_copy_finds_the_same_people_in_the_cameras_pixels(shelf_image):
    """The image decoded at 1/2 (a JPEG's DCT scaling), with the camera's size: the same people,
    their keypoints within one pixel of MultiPose's input of those found on the whole image
    (measured on the five frame-572 images: medians 0.3-1.0 px at 1032 x 776 shrunk by 2, 0.2-0.7
    px at 1548 x 1164 shrunk by 2, 0.9-3.2 px shrunk by 4). The node shrinks a camera only while
    two pixels per input pixel remain."""
    detector = OnnxPoseDetector(OnnxDetectorConfig(model_dir=MODELS, heatmaps='multipose', threads=1))
    h, w = shelf_image.shape[:2]
    assert [detector.reduced_decoding(*size) for size in ((w, h), (1548, 1164), (1920, 1080), (3840, 2160))] == \
        [1, 2, 2, 4]
    small = cv2.imdecode(cv2.imencode('.jpg', shelf_image, [cv2.IMWRITE_JPEG_QUALITY, 95])[1],
                         cv2.IMREAD_REDUCED_COLOR_2)
    (whole,), (shrunk,) = detector.detect_set([shelf_image]), detector.detect_set([small], sizes=[(w, h)])
    assert len(shrunk) == len(whole) >= 3
    input_pixel = max(w, h) / detector.config.input_size
    for a in whole:
        shifts = []
        for b in shrunk:
            seen = (a.keypoints[:, 2] > 0.3) & (b.keypoints[:, 2] > 0.3)
            shifts.append(np.median(np.linalg.norm(a.keypoints[seen, :2] - b.keypoints[seen, :2], axis=1)))
        assert min(shifts) < input_pixel


def test_crops_cut_from_a_shrunk_copy_give_the_people_of_the_whole_image(shelf_image):
    """A crop model shrinks a camera only as far as its smallest crop keeps the model's input
    pixels (none while MultiPose's people, of any size, become its crops); on the frame-572
    image decoded at 1/2, crops given MultiPose's boxes find the same joints as on the image
    itself (measured on the five frame-572 images: medians 0.4-1.8 px, people 330-720 px tall)."""
    detector = OnnxPoseDetector(OnnxDetectorConfig(model_dir=MODELS, heatmaps='efficientpose', model='lightning',
                                                   threads=1))
    h, w = shelf_image.shape[:2]
    (people,) = detector.detect_set([shelf_image])
    boxes = np.array([[*p.keypoints[p.keypoints[:, 2] > 0, :2].min(axis=0), *p.keypoints[p.keypoints[:, 2] > 0, :2].max(
        axis=0)] for p in people])
    assert detector.reduced_decoding(w, h) == 1 and detector.reduced_decoding(w, h, np.zeros((0, 4))) == 8
    tall = boxes[(boxes[:, 2:] - boxes[:, :2]).max(axis=1) * (1 + 2 * detector.config.box_margin) >= 2 * 192]
    assert len(tall) >= 2 and detector.reduced_decoding(w, h, tall) == 2
    assert detector.reduced_decoding(w, h, np.array([[0.0, 0.0, 100.0, 150.0]])) == 1  # a small person: every pixel
    small = cv2.imdecode(cv2.imencode('.jpg', shelf_image, [cv2.IMWRITE_JPEG_QUALITY, 95])[1],
                         cv2.IMREAD_REDUCED_COLOR_2)
    (whole,) = detector.detect_set([shelf_image], [tall])
    (shrunk,) = detector.detect_set([small], [tall], sizes=[(w, h)])
    assert len(whole) == len(shrunk) == len(tall)
    for a, b in zip(whole, shrunk):
        seen = (a.keypoints[:, 2] > 0.3) & (b.keypoints[:, 2] > 0.3)
        assert seen.sum() >= 8
        assert np.median(np.linalg.norm(a.keypoints[seen, :2] - b.keypoints[seen, :2], axis=1)) < 3.0


def test_a_person_found_twice_in_one_camera_is_kept_once():
    """Of two people whose keypoints nearly coincide the one with more score stays, in its place;
    neighbours whose boxes overlap, and people sharing fewer than two joints, all stay."""
    rng = np.random.default_rng(0)
    body = np.column_stack([rng.uniform(100, 200, 16), rng.uniform(100, 400, 16), np.full(16, 0.8)])
    twin = body + np.array([3.0, -2.0, -0.1])  # 3.6 px off on a ~320 px person
    neighbour = body + np.array([60.0, 0.0, 0.0])  # overlapping box, every joint 60 px away
    few = np.column_stack([body[:, :2], np.r_[0.9, np.zeros(15)]])
    people = [Person2D(k, PersonHeatmap(np.zeros((16, 1, 1), np.float32), np.zeros(2), 4.0))
              for k in (twin, neighbour, body, few)]
    kept = without_duplicates(people)
    assert [p.keypoints[0, 0] for p in kept] == [neighbour[0, 0], body[0, 0], few[0, 0]]
    assert without_duplicates(people[:2]) == people[:2] and without_duplicates([]) == []


def test_fused_heatmaps_hold_the_efficientpose_evidence_and_multipose_keypoints(detector, shelf_image):
    fused = OnnxPoseDetector(OnnxDetectorConfig(model_dir=MODELS, heatmaps='fused')).detect(shelf_image)
    alone = detector.detect(shelf_image)
    assert len(fused) == len(alone)  # the same crops
    raised = 0
    for f, e in zip(fused, alone):
        seen = e.keypoints[:12, 2] > 0
        at = np.nan_to_num(e.keypoints[:12, None, :2])
        # at EfficientPose's keypoints the fused maps are the pointwise max: never below its own
        assert np.all(f.heatmap.lookup(np.pad(at, ((0, 4), (0, 0), (0, 0))))[:12, 0][seen]
                      >= e.heatmap.lookup(np.pad(at, ((0, 4), (0, 0), (0, 0))))[:12, 0][seen] - 1e-6)
        assert np.all(f.keypoints[:12, 2] >= e.keypoints[:12, 2])  # the better-scoring source's keypoint
        raised += int((f.keypoints[:12, 2] > e.keypoints[:12, 2]).sum())
        np.testing.assert_array_equal(f.keypoints[12:], e.keypoints[12:])  # neck, head, ears: not fused
    assert raised > 0  # MultiPose's keypoint scores higher somewhere
    _near_annotations(fused, 40.0)


def test_no_people_in_a_black_image_and_bad_images(detector):
    assert detector.detect(np.zeros((240, 320, 3), np.uint8)) == []
    assert detector.timing.people == 0
    with pytest.raises(ValueError, match=r'expected \(H, W, 3\) uint8 BGR, got float32'):
        detector.detect(np.zeros((240, 320, 3), np.float32))


def _folder(tmp_path: Path, **files: Path | str) -> Path:
    """A model folder: name -> a link to a real model file, or text."""
    for name, source in files.items():
        target = tmp_path / name
        if isinstance(source, Path):
            target.symlink_to(source)
        else:
            target.write_text(source)
    return tmp_path


def test_a_missing_model_names_the_file(tmp_path):
    folder = _folder(tmp_path, **{MULTIPOSE.file: MODELS / MULTIPOSE.file})
    with pytest.raises(ModelError, match=rf'^{tmp_path}/efficientpose_rt.onnx: EfficientPose RT model file not found$'):
        OnnxPoseDetector(OnnxDetectorConfig(model_dir=folder, heatmaps='efficientpose'))


def test_another_models_file_is_a_clear_error(tmp_path):
    # EfficientPose given as MultiPose: its input is float 224x224, not int32 of any size
    folder = _folder(tmp_path, **{MULTIPOSE.file: MODELS / EFFICIENTPOSE['rt'].file})
    with pytest.raises(ModelError) as err:
        OnnxPoseDetector(OnnxDetectorConfig(model_dir=folder))
    text = str(err.value)
    assert text.startswith(f'{tmp_path}/movenet_multipose.onnx: not the MoveNet MultiPose model: expected input '
                           'input tensor(int32) [1, None, None, 3]')
    assert 'the file has input input_res1:0 tensor(float)' in text and '\n' not in text


def test_efficientpose_of_the_wrong_size_is_a_clear_error(tmp_path):
    folder = _folder(tmp_path, **{MULTIPOSE.file: MODELS / MULTIPOSE.file,
                                  EFFICIENTPOSE['rt'].file: MODELS / EFFICIENTPOSE['i'].file})
    with pytest.raises(ModelError, match=r'efficientpose_rt.onnx: not the EfficientPose RT model: expected input '
                                         r'input_res1:0 tensor\(float\) \[None, 224, 224, 3\].*\[.*, 256, 256, 3\]'):
        OnnxPoseDetector(OnnxDetectorConfig(model_dir=folder, heatmaps='efficientpose'))


def test_a_file_that_is_not_onnx_is_a_clear_error(tmp_path):
    folder = _folder(tmp_path, **{MULTIPOSE.file: 'not a model\n'})
    with pytest.raises(ModelError, match=rf'^{tmp_path}/movenet_multipose.onnx: not a loadable ONNX model \(.*\)$'):
        OnnxPoseDetector(OnnxDetectorConfig(model_dir=folder))
    assert issubclass(ModelError, ValueError)  # what the node and the command line report in one line


@pytest.mark.parametrize('changes, message', [
    ({'model': 'xl'}, "model 'xl' is not one of rt, i, lightning, thunder, blazepose_full, blazepose_heavy"),
    ({'input_size': 100}, 'input_size 100 is not a positive multiple of 32'),
    ({'stride': 0.0}, 'stride 0.0 and sigma 6.0 must be > 0'),
    ({'heatmap_floor': 1.0}, r'heatmap_floor 1.0 in \[0, 1\)'),
    ({'heatmaps': 'openpose'}, "heatmaps 'openpose' is not one of efficientpose, multipose, fused"),
    ({'keypoint_sigma': 0.0}, 'keypoint_sigma 0.0 must be > 0'),
    ({'multipose_workers': 0}, 'multipose_workers 0 must be >= 1'),
    ({'crop_workers': 0}, 'crop_workers 0 must be >= 1'),
    ({'heatmaps': 'fused', 'model': 'thunder'},
     r"heatmaps 'fused' needs an EfficientPose model \(rt, i\), not 'thunder'"),
    ({'region_margin': -0.1}, 'box_margin 0.1 and region_margin -0.1 must be >= 0'),
    ({'tile_levels': 5}, 'tile_levels 5 must lie in 0..4'),
])
def test_bad_settings(changes, message):
    with pytest.raises(ValueError, match=message):
        replace(OnnxDetectorConfig(model_dir=MODELS), **changes)


def test_an_unavailable_execution_provider_is_an_error_not_a_silent_fallback():
    with pytest.raises(ValueError, match=r"execution providers \['NoSuchExecutionProvider'\]: "
                                         r"\['NoSuchExecutionProvider'\] not available \(this onnxruntime has .*CPU"):
        OnnxPoseDetector(OnnxDetectorConfig(model_dir=MODELS, providers=('NoSuchExecutionProvider',)))


def _mosaic() -> tuple[np.ndarray, dict[int, tuple[int, int]]]:
    """Frame 572's cameras 0, 1, 2 and 4 two by two (16 people, 4 in each) and each image's offset."""
    images = {c: cv2.imread(str(dataset_dir('shelf') / 'frames' / f'cam{c}_{FRAME:06d}.png')) for c in (0, 1, 2, 4)}
    h, w = images[0].shape[:2]
    offsets = {0: (0, 0), 1: (w, 0), 2: (0, h), 4: (w, h)}
    mosaic = np.zeros((2 * h, 2 * w, 3), dtype=np.uint8)
    for c, (u, v) in offsets.items():
        mosaic[v:v + h, u:u + w] = images[c]
    return mosaic, offsets


def test_a_crowd_beyond_multiposes_six_is_found_in_tiles(multipose_detector):
    """MultiPose returns at most 6 people a run. On a mosaic of four frame-572 images (16 people)
    one run finds 6; with crowd tiles (tile_levels 2, the default) every person each image alone
    gives is found once, where that image lies in the mosaic: keypoints at a median distance under 5%
    of the person's size (measured 3-11 px for people of 250-600 px)."""
    mosaic, offsets = _mosaic()
    none = OnnxPoseDetector(replace(multipose_detector.config, tile_levels=0))
    assert len(none.detect(mosaic)) == 6 and none.timing.crowd_tiles == 0
    found = multipose_detector.detect(mosaic)
    assert multipose_detector.timing.crowd_tiles == 6  # two halves, then the halves of both
    expected = 0
    for c, (u, v) in offsets.items():
        image = mosaic[v:v + mosaic.shape[0] // 2, u:u + mosaic.shape[1] // 2]
        for person in multipose_detector.detect(image):
            expected += 1
            seen = person.keypoints[:, 2] > 0.3
            size = np.hypot(*np.ptp(person.keypoints[seen, :2], axis=0))
            gaps = []
            for other in found:
                both = seen & (other.keypoints[:, 2] > 0.3)
                shifted = other.keypoints[both, :2] - (u, v)
                gaps.append(np.median(np.hypot(*(person.keypoints[both, :2] - shifted).T)) if both.sum() >= 3
                            else np.inf)
            assert sorted(gaps)[0] < 0.05 * size and sorted(gaps)[1] > 0.1 * size, (c, sorted(gaps)[:2], size)
    assert len(found) == expected == 16


def test_crowd_tiles_halve_the_long_side_with_a_quarter_overlap():
    wide, tall = crowd_tiles(np.array([-0.5, -0.5, 1999.5, 799.5])), crowd_tiles(np.array([100.0, 0.0, 500.0, 1000.0]))
    np.testing.assert_allclose(wide, [[-0.5, -0.5, 1249.5, 799.5], [749.5, -0.5, 1999.5, 799.5]])
    np.testing.assert_allclose(tall, [[100.0, 0.0, 500.0, 625.0], [100.0, 375.0, 500.0, 1000.0]])


def test_runs_are_merged_one_to_one():
    """Two people of one run stay two even where their keypoints nearly coincide (one hidden
    behind the other); a person found by two runs is kept once, as the finding with the higher
    score sum."""
    from mvpose_ros.core.detection.onnx_detector import _Found, _merged
    rng = np.random.default_rng(0)
    body = np.column_stack([rng.uniform(0, 100, 17), rng.uniform(0, 300, 17), np.full(17, 0.5)])
    near = body + [1.0, 1.0, 0.0]  # within 1% of the size: a duplicate if it came from another run
    other = body + [400.0, 0.0, 0.0]
    boxes = np.array([[0.0, 0.0, 100.0, 300.0]])
    first = _Found(np.stack([body, near]), np.repeat(boxes, 2, axis=0), np.zeros(4), 1.0)
    better = near + [0.0, 0.0, 0.2]
    second = _Found(np.stack([better, other]), np.concatenate([boxes, boxes + 400]), np.zeros(4), 2.0)
    merged = _merged([first, second], np.array([0.0, 0.0, 1000.0, 400.0]))
    assert len(merged.keypoints) == 3 and merged.runs == 2 and merged.done == 2.0
    # `better` replaced the run-one person nearest it (near, not body), `other` was added
    np.testing.assert_array_equal(merged.keypoints, np.stack([body, better, other]))
