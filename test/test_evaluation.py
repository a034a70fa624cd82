"""PCP and MPJPE scoring, on the real Shelf ground truth and hand-made cases."""
from __future__ import annotations

import numpy as np
import pytest

from mvpose_ros.core.datasets.shelf_campus import (SHELF_ACTORS, SHELF_TEST_FRAMES, GroundTruth, dataset_dir,
                                                   load_actors_gt)
from mvpose_ros.core.evaluation.pcp import (FORMS, GROUPS, LIMBS, PAPER_SHELF_PCP, evaluate,
                                            format_table)


@pytest.fixture(scope='module')
def gt() -> GroundTruth:
    return load_actors_gt(dataset_dir('shelf') / 'actorsGT.mat', SHELF_TEST_FRAMES)


def _as_predictions(poses: np.ndarray, present: np.ndarray, frames: np.ndarray) -> dict:
    """{frame: (P, 14, 3)} of the present actors' poses."""
    return {int(f): poses[i][present[i]] for i, f in enumerate(frames)}


def _limb_lengths(poses: np.ndarray) -> np.ndarray:
    """(..., 10) limb lengths, torso from the hip centre."""
    ext = np.concatenate([poses, poses[..., 2:4, :].mean(-2, keepdims=True)], axis=-2)
    return np.linalg.norm(ext[..., LIMBS[:, 0], :] - ext[..., LIMBS[:, 1], :], axis=-1)


def test_gt_against_itself_is_perfect(gt):
    ev = evaluate(_as_predictions(gt.poses, gt.present, gt.frames), gt, SHELF_ACTORS)
    for form in FORMS:
        for actor in SHELF_ACTORS:
            for group in GROUPS:
                assert ev.pcp(form, actor, group) == 100.0
        assert ev.actor_average(form) == ev.frame_weighted(form) == 100.0
    np.testing.assert_array_equal(ev.frames, [279, 37, 161])
    np.testing.assert_array_equal(ev.missed, 0)
    np.testing.assert_array_equal(ev.mpjpe, 0.0)
    assert ev.mpjpe_all == 0.0
    # 10 limbs per actor-frame: 2 per paired group, 1 for head and torso.
    np.testing.assert_array_equal(ev.total[0], 279 * np.array([1, 1, 2, 2, 2, 2, 10]))


def test_shift_beyond_longest_limb_is_all_wrong(gt):
    shift = 1.5 * np.nanmax(_limb_lengths(gt.poses))
    shifted = gt.poses + np.array([shift, 0.0, 0.0])
    # One actor at a time, so the only candidate is that actor's own shifted skeleton (shifted
    # neighbours can land on an actor and be rightly scored correct).
    for actor in SHELF_ACTORS:
        here = gt.present[:, actor]
        preds = {int(f): shifted[i, [actor]] for i, f in enumerate(gt.frames) if here[i]}
        ev = evaluate(preds, gt, [actor])
        assert ev.total[0, -1] == 10 * here.sum() > 0
        np.testing.assert_array_equal(ev.correct, 0)
        assert ev.frame_weighted('lenient') == 0.0
        assert ev.mpjpe[0] == pytest.approx(1000 * shift)


def _single_frame(gt: GroundTruth) -> tuple[GroundTruth, float]:
    pose = gt.poses[0, 0]
    return GroundTruth(frames=np.array([7]), poses=pose[None, None].copy()), _limb_lengths(pose)[8]


@pytest.mark.parametrize('head_top, neck, strict, lenient', [
    (0.6, 0.1, False, True),    # one endpoint too far, mean within
    (0.45, 0.45, True, True),
    (0.7, 0.4, False, False),   # mean 0.55 L
])
def test_strict_and_lenient_on_the_head(gt, head_top, neck, strict, lenient):
    truth, head_len = _single_frame(gt)
    pred = truth.poses[0].copy()
    pred[0, 13] += head_len * head_top * np.array([0.6, 0.0, 0.8])
    pred[0, 12] += head_len * neck * np.array([0.0, 1.0, 0.0])
    ev = evaluate({7: pred}, truth, [0])
    assert ev.pcp('strict', 0, 'Head') == (100.0 if strict else 0.0)
    assert ev.pcp('lenient', 0, 'Head') == (100.0 if lenient else 0.0)
    for group in GROUPS[1:-1]:  # the neck moves less than half of the torso's length
        assert ev.pcp('strict', 0, group) == 100.0
    assert ev.pcp('strict', 0) == (100.0 if strict else 90.0)


def test_frames_without_predictions_count_as_wrong(gt):
    preds = _as_predictions(gt.poses, gt.present, gt.frames)
    empty, absent = gt.frames[gt.present[:, 0]][:2]  # two frames where actor 0 is present
    preds[int(empty)] = np.empty((0, 14, 3))
    del preds[int(absent)]
    ev = evaluate(preds, gt, SHELF_ACTORS)
    lost = gt.present[np.isin(gt.frames, [empty, absent])][:, list(SHELF_ACTORS)].sum(axis=0)
    np.testing.assert_array_equal(ev.missed, lost)
    np.testing.assert_array_equal(ev.total[:, -1] - ev.correct[0, :, -1], 10 * lost)
    np.testing.assert_array_equal(ev.correct[0], ev.correct[1])
    np.testing.assert_array_equal(ev.mpjpe, 0.0)  # missed frames are left out of MPJPE
    assert ev.pcp('strict', 0) == pytest.approx(100.0 * (279 - 2) / 279)


def test_nearest_person_assignment(gt):
    rng = np.random.default_rng(0)
    noise = rng.normal(scale=0.005, size=gt.poses.shape)
    preds = {}
    for i, f in enumerate(gt.frames):
        people = gt.poses[i][gt.present[i]] + noise[i][gt.present[i]]
        decoys = people + rng.uniform(1.0, 3.0, (len(people), 1, 3))  # whole people elsewhere
        preds[int(f)] = rng.permutation(np.concatenate([decoys, people, decoys[:, ::-1]]))
    ev = evaluate(preds, gt, SHELF_ACTORS)
    for actor in SHELF_ACTORS:
        assert ev.pcp('strict', actor) == 100.0
    # Mean of |N(0, 5 mm I3)| is 5 * sqrt(8 / pi) ~ 8.0 mm; a wrong match would be metres.
    assert ev.mpjpe_all == pytest.approx(8.0, abs=0.3)
    np.testing.assert_array_less(ev.mpjpe, 9.0)


def test_nan_joints_make_limbs_wrong(gt):
    poses = gt.poses.copy()
    poses[:, :, 6] = np.nan  # right wrist never estimated
    ev = evaluate(_as_predictions(poses, gt.present, gt.frames), gt, SHELF_ACTORS)
    for form in FORMS:
        assert ev.pcp(form, 0, 'Forearm') == 50.0
        assert ev.pcp(form, 0, 'Upper arm') == 100.0
        assert ev.pcp(form, 0) == 90.0
    np.testing.assert_array_equal(ev.mpjpe, 0.0)


def test_actor_average_vs_frame_weighted(gt):
    # Actor 1 (index 1, 37 frames) is predicted nowhere near; actors 0 and 2 exactly.
    far = gt.poses.copy()
    far[:, 1] += np.array([50.0, 0.0, 0.0])
    ev = evaluate(_as_predictions(far, gt.present, gt.frames), gt, SHELF_ACTORS)
    assert ev.pcp('strict', 1) == 0.0
    assert ev.actor_average('strict') == pytest.approx((100 + 0 + 100) / 3)
    assert ev.frame_weighted('strict') == pytest.approx(100 * (279 + 161) / (279 + 37 + 161))
    assert ev.frame_weighted('strict') > ev.actor_average('strict')


def test_format_table(gt):
    ev = evaluate(_as_predictions(gt.poses, gt.present, gt.frames), gt, SHELF_ACTORS)
    table = format_table(ev, PAPER_SHELF_PCP)
    lines = table.splitlines()
    assert lines[0].split() == ['PCP', '(%),', 'alpha=0.5', 'Head', 'Torso', 'Upper-arm', 'Forearm',
                                'Thigh', 'Shin', 'All', 'MPJPE', 'mm', 'frames', 'missed']
    row = {line[:24].strip(): line[24:].split() for line in lines[1:]}
    assert row['Actor 1 reference'] == ['32.14', '99.64', '95.18', '82.50', '99.64', '99.64',
                                        '88.34']
    assert row['Actor 2 strict'][:7] == ['100.00'] * 7
    assert row['Actor 3 strict'][-2:] == ['161', '0']
    assert row['Average reference'] == ['-'] * 6 + ['88.92']
    assert 'Actor mean lenient' in row
    assert 'reference' not in format_table(ev)
