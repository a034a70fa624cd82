"""The ONNX backend with the real models on a real Shelf image, and the clear errors for a
missing model, another model's file, a file that is not ONNX, and bad settings."""
from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import cv2
import numpy as np
import pytest

from mvpose_ros.core.geometry.body import L_EAR, NUM_INFERENCE_JOINTS, R_EAR
from mvpose_ros.core.evaluation.datasets import data_root, dataset_dir, load_actors_gt_2d
from mvpose_ros.core.detection.onnx_detector import OnnxDetectorConfig, OnnxPoseDetector
from mvpose_ros.core.detection.onnx_models import EFFICIENTPOSE, MULTIPOSE, ModelError

MODELS = data_root() / 'models'
FRAME, CAMERA = 572, 4


@pytest.fixture(scope='module')
def detector() -> OnnxPoseDetector:
    return OnnxPoseDetector(OnnxDetectorConfig(model_dir=MODELS))


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
    gt = load_actors_gt_2d(dataset_dir('shelf') / 'actorsGT.mat', [FRAME])[0, :, CAMERA]  # (A, 14, 2)
    annotated = np.isfinite(gt).all(axis=(1, 2))
    assert annotated.sum() == 3
    for truth in gt[annotated]:
        errors = [np.nanmedian(np.linalg.norm(p.keypoints[:14, :2] - truth, axis=1)) for p in people]
        assert min(errors) < 40.0
    t = detector.timing
    assert t.people == len(people) and 0 < t.multipose < t.total and 0 < t.efficientpose < t.total


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
        OnnxPoseDetector(OnnxDetectorConfig(model_dir=folder))


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
        OnnxPoseDetector(OnnxDetectorConfig(model_dir=folder))


def test_a_file_that_is_not_onnx_is_a_clear_error(tmp_path):
    folder = _folder(tmp_path, **{MULTIPOSE.file: 'not a model\n'})
    with pytest.raises(ModelError, match=rf'^{tmp_path}/movenet_multipose.onnx: not a loadable ONNX model \(.*\)$'):
        OnnxPoseDetector(OnnxDetectorConfig(model_dir=folder))
    assert issubclass(ModelError, ValueError)  # what the node and the command line report in one line


@pytest.mark.parametrize('changes, message', [
    ({'model': 'xl'}, "model 'xl' is not one of rt, i"),
    ({'input_size': 100}, 'input_size 100 is not a positive multiple of 32'),
    ({'stride': 0.0}, 'stride 0.0 and sigma 6.0 must be > 0'),
    ({'heatmap_floor': 1.0}, r'heatmap_floor 1.0 in \[0, 1\)'),
])
def test_bad_settings(changes, message):
    with pytest.raises(ValueError, match=message):
        replace(OnnxDetectorConfig(model_dir=MODELS), **changes)


def test_an_unavailable_execution_provider_is_an_error_not_a_silent_fallback():
    with pytest.raises(ValueError, match=r"execution providers \['NoSuchExecutionProvider'\]: "
                                         r"\['NoSuchExecutionProvider'\] not available \(this onnxruntime has .*CPU"):
        OnnxPoseDetector(OnnxDetectorConfig(model_dir=MODELS, providers=('NoSuchExecutionProvider',)))
