"""The 14-joint body, the 16 inference joints, the mapping of 2D formats onto them and the 3D head
models."""
from __future__ import annotations

import numpy as np
import pytest

from mvpose_ros.core.datasets.shelf_campus import SHELF_TEST_FRAMES, load_actors_gt
from mvpose_ros.core.defaults import data_root
from mvpose_ros.core.geometry import body


def _side_swapped(name: str) -> str:
    return {'r': 'l', 'l': 'r'}[name[0]] + name[1:]


def test_inference_joints_extend_the_limbs():
    assert body.NUM_INFERENCE_JOINTS == 16 == len(body.INFERENCE_NAMES)
    assert body.INFERENCE_NAMES[:12] == body.JOINT_NAMES[:12]
    assert [body.INFERENCE_NAMES[j] for j in (body.NECK, body.HEAD, body.R_EAR, body.L_EAR)] \
        == ['neck', 'head', 'r_ear', 'l_ear']


@pytest.mark.parametrize('fmt', ['body25', 'coco17', 'mpii16'])
def test_source_index_names_the_same_limb_joints(fmt):
    names = body.FORMAT_NAMES[fmt]
    index = body.SOURCE_INDEX[fmt]
    assert index.shape == (16,)
    used = index[index >= 0]
    assert len(set(used.tolist())) == len(used)  # injective: no source joint used twice
    assert [names[i] for i in index[:12]] == list(body.JOINT_NAMES[:12])


def test_format_sizes_and_known_indices():
    assert len(body.BODY25_NAMES) == 25 and len(body.COCO17_NAMES) == 17
    assert len(body.MPII16_NAMES) == 16
    # spot checks against the published orders (shared/README.md, COCO keypoints)
    assert body.SOURCE_INDEX['body25'].tolist() == [11, 10, 9, 12, 13, 14, 4, 3, 2, 5, 6, 7,
                                                    1, 0, 17, 18]
    assert body.SOURCE_INDEX['coco17'].tolist() == [16, 14, 12, 11, 13, 15, 10, 8, 6, 5, 7, 9,
                                                    -1, 0, 4, 3]
    assert body.SOURCE_INDEX['mpii16'].tolist() == [12, 11, 10, 13, 14, 15, 4, 3, 2, 6, 7, 8,
                                                    1, 0, -1, -1]
    np.testing.assert_array_equal(body.BODY25_INFERENCE_JOINTS, body.SOURCE_INDEX['body25'])


def test_mirror_and_symmetric_pairs():
    assert len(body.SYMMETRIC_PAIRS) == 6
    for r, l in body.SYMMETRIC_PAIRS:
        assert body.JOINT_NAMES[r].startswith('r_')
        assert body.JOINT_NAMES[l] == _side_swapped(body.JOINT_NAMES[r])
    assert np.array_equal(body.MIRROR[body.MIRROR], np.arange(14))
    assert body.MIRROR[12] == 12 and body.MIRROR[13] == 13
    for j in range(12):
        assert body.JOINT_NAMES[body.MIRROR[j]] == _side_swapped(body.JOINT_NAMES[j])


def test_inference_mirror():
    mirror = body.INFERENCE_MIRROR
    assert mirror.shape == (16,)
    assert np.array_equal(mirror[mirror], np.arange(16))
    np.testing.assert_array_equal(mirror[:14], body.MIRROR)  # same limbs; neck, head fixed
    assert mirror[body.R_EAR] == body.L_EAR and mirror[body.L_EAR] == body.R_EAR


def test_bones_form_one_tree_plus_torso_loops():
    bones = np.array(body.BONES)
    assert bones.shape == (15, 2) and bones.min() == 0 and bones.max() == 13
    assert len({tuple(sorted(b)) for b in body.BONES}) == 15
    # connected: a flood fill from joint 0 reaches every joint
    reached = {0}
    for _ in range(14):
        reached |= {b for a, b in body.BONES if a in reached} | {a for a, b in body.BONES
                                                                 if b in reached}
    assert reached == set(range(14))


def _skeleton(fmt: str) -> np.ndarray:
    """A frontal hand-made 2D skeleton (K, 3): every joint score 0.9 except named overrides."""
    names = body.FORMAT_NAMES[fmt]
    pos = {'nose': (100, 140), 'neck': (100, 200), 'r_eye': (95, 135), 'l_eye': (105, 135),
           'r_ear': (90, 150), 'l_ear': (110, 150), 'r_shoulder': (80, 200),
           'l_shoulder': (120, 200), 'head_top': (100, 100), 'upper_neck': (100, 190)}
    kp = np.zeros((len(names), 3))
    for k, name in enumerate(names):
        kp[k] = (*pos.get(name, (50 + k, 300 + k)), 0.9)
    return kp


def test_body25_to_inference():
    kp = _skeleton('body25')
    kp[body.BODY25_NAMES.index('l_ear'), 2] = 0.4
    out = body.to_inference(kp, 'body25')
    assert out.shape == (16, 3)
    np.testing.assert_allclose(out[:12], kp[body.SOURCE_INDEX['body25'][:12]])
    np.testing.assert_allclose(out[body.NECK], [100, 200, 0.9])
    np.testing.assert_allclose(out[body.HEAD], [100, 140, 0.9])  # the nose
    np.testing.assert_allclose(out[body.R_EAR], [90, 150, 0.9])
    np.testing.assert_allclose(out[body.L_EAR], [110, 150, 0.4])


def test_coco_neck_is_shoulder_midpoint():
    kp = _skeleton('coco17')
    kp[body.COCO17_NAMES.index('r_shoulder')] = (80, 210, 0.7)
    out = body.to_inference(kp, 'coco17')
    np.testing.assert_allclose(out[body.NECK], [100, 205, 0.7])  # the weaker shoulder's score
    np.testing.assert_allclose(out[body.HEAD], [100, 140, 0.9])
    np.testing.assert_allclose(out[body.R_EAR], [90, 150, 0.9])
    np.testing.assert_allclose(out[body.L_EAR], [110, 150, 0.9])
    kp[body.COCO17_NAMES.index('l_shoulder'), 2] = 0.0  # one shoulder missing: no neck
    out = body.to_inference(kp, 'coco17')
    assert out[body.NECK, 2] == 0 and np.all(np.isnan(out[body.NECK, :2]))


def test_mpii_head_is_head_top_and_ears_are_missing():
    kp = _skeleton('mpii16')
    out = body.to_inference(kp, 'mpii16')
    np.testing.assert_allclose(out[body.NECK], [100, 190, 0.9])  # upper_neck
    np.testing.assert_allclose(out[body.HEAD], [100, 100, 0.9])  # head_top
    assert np.all(out[[body.R_EAR, body.L_EAR], 2] == 0)
    assert np.all(np.isnan(out[[body.R_EAR, body.L_EAR], :2]))


def test_batched_and_missing_convention():
    kp = np.stack([_skeleton('body25')] * 6).reshape(2, 3, 25, 3)
    kp[1, 2, body.BODY25_NAMES.index('r_wrist'), 2] = 0.0
    kp[0, 1, body.BODY25_NAMES.index('nose'), 2] = np.nan
    out = body.to_inference(kp, 'body25')
    assert out.shape == (2, 3, 16, 3)
    assert np.all(np.isnan(out[1, 2, 6, :2])) and out[1, 2, 6, 2] == 0
    assert np.all(np.isnan(out[0, 1, body.HEAD, :2])) and out[0, 1, body.HEAD, 2] == 0
    np.testing.assert_allclose(out[0, 0], out[1, 1])
    with pytest.raises(ValueError):
        body.to_inference(kp, 'coco17')  # 25 keypoints are not COCO
    with pytest.raises(ValueError):
        body.to_inference(kp, 'openpose')


def _skeleton_3d() -> np.ndarray:
    """A hand-made standing person (16, 3) in metres, z up: random limbs, a known head."""
    joints = np.random.default_rng(3).normal(scale=0.3, size=(16, 3)) + (0.0, 0.0, 1.0)
    joints[body.NECK] = (0.0, 0.0, 1.50)
    joints[body.HEAD] = (0.0, 0.10, 1.62)  # nose, a little forward
    joints[body.R_EAR] = (-0.08, 0.02, 1.64)
    joints[body.L_EAR] = (0.08, 0.04, 1.66)
    return joints


def test_paper_head_is_neck_and_nose_shifted_up():
    joints = np.stack([_skeleton_3d(), _skeleton_3d() + 1.0])  # (2, 16, 3)
    before = joints.copy()
    out = body.finalize_head(joints, 'paper')
    np.testing.assert_array_equal(joints, before)  # input untouched
    assert out.shape == (2, 14, 3)
    expected = joints[:, :14].copy()
    expected[:, [12, 13], 2] += body.HEAD_SHIFT_M
    np.testing.assert_allclose(out, expected, atol=1e-12)
    assert body.HEAD_SHIFT_M == pytest.approx(0.10)
    np.testing.assert_array_equal(body.UP, [0, 0, 1])
    # a rig whose world has y up: the shift goes along y
    sideways = body.finalize_head(joints, 'paper', up=np.array([0.0, 1.0, 0.0]))
    expected = joints[:, :14].copy()
    expected[:, [12, 13], 1] += body.HEAD_SHIFT_M
    np.testing.assert_allclose(sideways, expected, atol=1e-12)


def test_anatomical_head_from_3d_ears_and_neck():
    joints = _skeleton_3d()
    out = body.finalize_head(joints, 'anatomical')
    assert out.shape == (14, 3)
    np.testing.assert_array_equal(out[:12], joints[:12])
    # ear midpoint (0, 0.03, 1.65); bottom = (neck + mid) / 2; top = 2 mid - bottom
    np.testing.assert_allclose(out[12], [0.0, 0.015, 1.575], atol=1e-12)
    np.testing.assert_allclose(out[13], [0.0, 0.045, 1.725], atol=1e-12)
    # batched the same as one at a time
    batch = np.stack([joints, joints + (1.0, -2.0, 0.0)])
    out2 = body.finalize_head(batch, 'anatomical')
    np.testing.assert_allclose(out2[0], out)
    np.testing.assert_allclose(out2[1], out + (1.0, -2.0, 0.0))


def test_facing_head_puts_the_top_forward_and_up_from_the_anatomical_bottom():
    joints = _skeleton_3d()
    joints[[2, 3]] = (0.1, 0.0, 1.0), (-0.1, 0.0, 1.0)  # hips: right at +x
    joints[[8, 9]] = (0.2, 0.0, 1.45), (-0.2, 0.0, 1.45)  # shoulders: facing +y (z up, right at +x)
    anatomical = body.finalize_head(joints, 'anatomical')
    out = body.finalize_head(joints, 'facing')
    np.testing.assert_array_equal(out[:13], anatomical[:13])
    forward, rise = body.FACING_TOP_M
    np.testing.assert_allclose(out[13], anatomical[12] + (0.0, forward, rise), atol=1e-12)
    # the rise goes along the world's up; the confidence of the top is that of every joint it uses
    np.testing.assert_allclose(body.finalize_head(joints, 'facing', up=np.array([0.0, 0.0, -1.0]))[13],
                               anatomical[12] + (0.0, forward, -rise), atol=1e-12)
    confidence = np.linspace(0.2, 0.9, 16)
    confidence[3] = 0.05
    head = body.finalize_confidence(confidence, 'facing')[[12, 13]]
    np.testing.assert_allclose(head, [confidence[[12, 14, 15]].min(), 0.05])


def test_direct_head_keeps_neck_and_head():
    joints = _skeleton_3d()
    out = body.finalize_head(joints, 'direct')
    np.testing.assert_array_equal(out, joints[:14])


def test_head_model_is_validated():
    with pytest.raises(ValueError):
        body.finalize_head(_skeleton_3d(), 'nose')


def test_shelf_world_is_z_up():
    root = data_root() / 'data' / 'shelf'
    gt = load_actors_gt(root / 'actorsGT.mat', SHELF_TEST_FRAMES)
    present = np.isfinite(gt.poses).all(axis=(-2, -1))
    poses = gt.poses[present]  # (N, 14, 3)
    assert len(poses) > 300
    z = poses[..., 2]
    ankles = z[:, [0, 5]].max(axis=1)
    assert np.all(z[:, 13] > ankles + 1.0)  # top of the head > 1 m above both ankles
    assert np.all(z[:, 13] > z[:, 12])
    assert np.all(z[:, 12] > z[:, [2, 3]].max(axis=1))
    assert abs(np.median(ankles)) < 0.2  # the floor is z = 0
    # the 'paper' shift goes along the head axis: body.UP is the world's up
    axis = poses[:, 13] - poses[:, 12]
    cos = axis @ body.UP / np.linalg.norm(axis, axis=1)
    assert np.median(cos) > 0.9
