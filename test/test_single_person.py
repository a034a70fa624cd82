"""The single-person models (MoveNet Lightning / Thunder, BlazePose Full / Heavy) on real person
crops of Shelf frame 572: their I/O contract, their keypoints near the annotation, the heatmap
read-out against each model's own decoded keypoints, and crops on parallel workers equal to one
crop at a time."""
from __future__ import annotations

import cv2
import numpy as np
import pytest

from mvpose_ros.core.datasets.shelf_campus import dataset_dir, load_actors_gt_2d
from mvpose_ros.core.defaults import data_root
from mvpose_ros.core.detection.letterbox import letterbox
from mvpose_ros.core.detection.onnx_models import ModelError
from mvpose_ros.core.detection.single_person import COCO_KEYPOINTS, SINGLE_POSE, SinglePoseModel
from mvpose_ros.core.geometry.body import SOURCE_INDEX

MODELS = data_root() / 'models'
FRAME, CAMERA = 572, 4
# the 12 limb joints: COCO-17 index of Shelf's joints 0..11 (r_ankle .. l_wrist)
_SHELF_LIMBS_IN_COCO = SOURCE_INDEX['coco17'][:12]


@pytest.fixture(scope='module')
def crops() -> list[tuple[np.ndarray, np.ndarray]]:
    """Per annotated actor of camera 4: the crop's box (4,) around the annotated joints grown by a
    fifth of its size, and the annotation (14, 2)."""
    image = cv2.imread(str(dataset_dir('shelf') / 'frames' / f'cam{CAMERA}_{FRAME:06d}.png'))
    gt = load_actors_gt_2d(dataset_dir('shelf') / 'actorsGT.mat', [FRAME])[0, :, CAMERA]
    out = []
    for truth in gt[np.isfinite(gt).all(axis=(1, 2))]:
        lo, hi = truth.min(axis=0), truth.max(axis=0)
        out.append((image, np.concatenate([lo - 0.2 * (hi - lo), hi + 0.2 * (hi - lo)]), truth))
    assert len(out) == 3
    return out


@pytest.mark.parametrize('name', list(SINGLE_POSE))
def test_each_model_reads_a_real_crop_and_its_heatmap_agrees_with_its_keypoints(name, crops):
    model = SinglePoseModel(MODELS, name, threads=1)
    side = model.side
    errors = []
    for image, box, truth in crops:
        lb = letterbox(image.shape[1], image.shape[0], box, side)
        rgb = lb.apply(image)[..., ::-1]
        out = model.run(rgb[None])
        assert out.keypoints.shape == (1, COCO_KEYPOINTS, 3)
        channels = 17 if model.model.movenet else 39
        assert out.heatmap.shape == (1, side // 4, side // 4, channels)
        assert (out.offsets is not None) == model.model.movenet
        kp = out.keypoints[0]
        assert np.isfinite(kp).all() and np.all((kp[:, 2] >= 0) & (kp[:, 2] <= 1))
        uv = lb.to_image(kp[:, :2])
        errors.append(np.median(np.linalg.norm(uv[_SHELF_LIMBS_IN_COCO] - truth[:12], axis=1)))
        # the read-out of the model's own maps lands where its decoding puts the joints: MoveNet to
        # sub-pixel for most joints (its keypoints are the heatmap's argmax plus offsets, the argmax
        # weighted by the distance from the person's centre); BlazePose within two of its 4 px cells
        read = model.heatmap_keypoints(out.heatmap[0], None if out.offsets is None else out.offsets[0])
        gap = np.linalg.norm(read[:, :2] - kp[:, :2], axis=1)
        assert np.median(gap) < (1.0 if model.model.movenet else 8.0), (name, np.round(gap, 1))
    # box crops of these people: 10-25 px median limb error; 45 px would be another model or mapping
    assert np.median(errors) < 45.0, (name, errors)


def test_crops_on_parallel_workers_equal_one_crop_at_a_time(crops):
    one = SinglePoseModel(MODELS, 'lightning', threads=1)
    two = SinglePoseModel(MODELS, 'lightning', threads=1, workers=2)
    rgb = np.stack([letterbox(im.shape[1], im.shape[0], box, one.side).apply(im)[..., ::-1] for im, box, _ in crops])
    a, b = one.run(rgb), two.run(rgb)
    np.testing.assert_array_equal(a.keypoints, b.keypoints)
    np.testing.assert_array_equal(a.heatmap, b.heatmap)
    # and each crop alone gives its row of the set's run (the order is kept)
    for k in range(len(rgb)):
        np.testing.assert_array_equal(one.run(rgb[k:k + 1]).keypoints[0], b.keypoints[k])


def test_bad_crops_and_another_models_file_are_clear_errors(tmp_path):
    model = SinglePoseModel(MODELS, 'lightning', threads=1)
    with pytest.raises(ValueError, match=r'expected crops \(N, 192, 192, 3\) uint8 RGB'):
        model.run(np.zeros((1, 256, 256, 3), dtype=np.uint8))
    assert model.run(np.zeros((0, 192, 192, 3), dtype=np.uint8)).keypoints.shape == (0, COCO_KEYPOINTS, 3)
    (tmp_path / 'movenet_thunder.onnx').write_bytes((MODELS / 'movenet_lightning.onnx').read_bytes())
    with pytest.raises(ModelError, match='not the MoveNet SinglePose Thunder model'):
        SinglePoseModel(tmp_path, 'thunder')
    with pytest.raises(ValueError, match="model 'xl' is not one of lightning, thunder"):
        SinglePoseModel(MODELS, 'xl')
