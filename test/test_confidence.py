"""Per-joint confidence: its measure (inference.confidence), its way through the sliding window
and the head model, and the report that checks it against error (evaluation.confidence)."""
from __future__ import annotations

import numpy as np
import pytest
import scipy.stats

from mvpose_ros.core.datasets.shelf_campus import GroundTruth
from mvpose_ros.core.evaluation.confidence import confidence_samples, format_confidence_report, plot_confidence_report
from mvpose_ros.core.geometry.body import (L_EAR, LIMB_BONES, LIMB_LENGTHS, NECK, NUM_INFERENCE_JOINTS, R_EAR,
                                           SYMMETRIC_PAIRS, finalize_confidence)
from mvpose_ros.core.inference.confidence import SPREAD_SCALE_M, joint_confidence, joint_support
from mvpose_ros.core.inference.window import InferenceConfig, SlidingWindow
from mvpose_ros.core.types import FrameResult, PersonFrame

J, M = NUM_INFERENCE_JOINTS, 8


def test_confidence_is_in_the_unit_interval_whatever_the_input():
    rng = np.random.default_rng(0)
    for _ in range(50):
        marginals = rng.exponential(size=(3, J, M)) * (rng.random((3, J, 1)) < 0.9)  # some rows all zero
        hyp = rng.normal(scale=rng.uniform(0.001, 5), size=(3, J, M, 3))
        c = joint_confidence(marginals, hyp, marginals.argmax(-1), rng.random((3, J)))
        assert c.shape == (3, J) and ((c >= 0) & (c <= 1)).all()


@pytest.mark.parametrize('shape', [(3, J, M), (J, 16), (0, J, M), (2, 1), (4, 5, 1)])
def test_confidence_is_numpys_to_the_bit(shape):
    """The kernel against the numpy formulation it replaces (rows all zero, no joints, one hypothesis)."""
    rng = np.random.default_rng(1)
    marginals = rng.exponential(size=shape) * (rng.random(shape[:-1] + (1,)) < 0.8)
    hyp = rng.normal(scale=0.3, size=shape + (3,))
    best = marginals.argmax(-1)
    support = rng.random(shape[:-1])
    p = marginals / np.maximum(marginals.sum(axis=-1, keepdims=True), np.finfo(float).tiny)
    decoded = np.take_along_axis(hyp, best[..., None, None], axis=-2)
    spread = (p * np.linalg.norm(hyp - decoded, axis=-1)).sum(axis=-1)
    expected = np.clip(support * np.exp(-spread / SPREAD_SCALE_M), 0.0, 1.0)
    np.testing.assert_array_equal(joint_confidence(marginals, hyp, best, support), expected)


def test_concentrated_beats_spread_and_seen_beats_hidden():
    hyp = np.zeros((1, M, 3))
    hyp[0, :, 0] = np.linspace(0, 1.4, M)  # hypotheses 20 cm apart along x
    sure = np.eye(M)[:1]  # all belief on hypothesis 0
    split = np.full((1, M), 1.0 / M)
    best = np.zeros(1, dtype=int)
    full = np.ones(1)
    assert joint_confidence(sure, hyp, best, full)[0] == pytest.approx(1.0)
    spread = joint_confidence(split, hyp, best, full)[0]
    assert spread == pytest.approx(np.exp(-hyp[0, :, 0].mean() / SPREAD_SCALE_M))
    assert joint_confidence(sure, hyp, best, np.array([0.4]))[0] == pytest.approx(0.4)
    # near-duplicates sharing the belief do not make a joint uncertain (its max belief would)
    twins = np.zeros((1, M, 3))
    twins[0, :, 0] = np.linspace(0, 0.007, M)
    assert joint_confidence(split, twins, best, full)[0] > 0.95


def test_support_is_the_share_of_the_rig_seeing_the_joint():
    scores = np.array([[1.0, 0.5, 0.0], [2.0, np.nan, 0.0]])  # 2 views, 3 joints; scores above 1 count as 1
    np.testing.assert_allclose(joint_support(scores, 4), [0.5, 0.125, 0.0])
    np.testing.assert_allclose(joint_support(scores, 1), [1.0, 0.5, 0.0])


def test_head_joints_are_as_sure_as_what_they_are_made_of():
    c = np.linspace(0.05, 0.8, J)
    out = finalize_confidence(c, 'anatomical')
    assert out.shape == (14,) and (out[:12] == c[:12]).all()
    assert out[12] == out[13] == min(c[NECK], c[R_EAR], c[L_EAR])
    np.testing.assert_array_equal(finalize_confidence(c, 'paper'), c[:14])


def _ambiguous_clip(seed: int, n_frames: int = 12):
    """One person standing still at random joints; per joint M hypotheses: the truth and a rival
    40 cm off (both plus a few mm, every frame), near copies of each and others scattered 30..60 cm
    off. Half of the joints have a data term that clearly favours the truth; for the other half
    the rival is about as strong (for the whole clip stronger or weaker, so the solver gets some
    of them wrong), and they are seen by fewer cameras. Returns the frames and the truth (J, 3)."""
    rng = np.random.default_rng(seed)
    truth = rng.uniform(-1, 1, (J, 3))
    rival = rng.normal(size=(J, 3))
    rival = truth + 0.4 * rival / np.linalg.norm(rival, axis=-1, keepdims=True)
    ambiguous = rng.random(J) < 0.5
    rival_weight = 1.0 + rng.uniform(-0.4, 0.4, J)
    frames = []
    for _ in range(n_frames):
        hyp = truth[:, None] + rng.normal(scale=0.005, size=(J, M, 3))
        far = rng.normal(size=(J, M // 2, 3))
        hyp[:, M // 2:] += far * rng.uniform(0.3, 0.6, (J, M // 2, 1)) / np.linalg.norm(far, axis=-1, keepdims=True)
        hyp[:, M // 2] = rival + rng.normal(scale=0.005, size=(J, 3))
        data = np.full((J, M), 0.02)
        data[:, 0] = 1.0
        data[ambiguous, M // 2] = rival_weight[ambiguous] + rng.normal(scale=0.02, size=ambiguous.sum())
        data /= data.sum(-1, keepdims=True)
        frames.append([PersonFrame(1, hyp, data, np.where(ambiguous, 0.4, 1.0))])
    return frames, truth


@pytest.mark.parametrize('window', [None, 6])
def test_sure_joints_are_nearer_the_truth_through_the_window(window):
    """Synthetic: joints the solver is less sure of are those it gets wrong more often, in both
    schedules (the whole clip, the warm-started sliding window)."""
    confidence, error = [], []
    for seed in range(6):
        frames, truth = _ambiguous_clip(seed)
        config = InferenceConfig(terms=('data', 'temp'), window=window, lag=3 if window else 7)
        win = SlidingWindow(config, np.array(SYMMETRIC_PAIRS), LIMB_BONES, LIMB_LENGTHS)
        results = []
        for f, people in enumerate(frames):
            results += win.push(f, people)
        results += win.flush()
        assert len(results) == len(frames)
        for r in results:
            assert r.confidence.shape == (1, J) and ((r.confidence >= 0) & (r.confidence <= 1)).all()
            confidence.append(r.confidence[0])
            error.append(np.linalg.norm(r.joints[0] - truth, axis=-1))
    confidence, error = np.concatenate(confidence), np.concatenate(error)
    assert (error > 0.2).sum() > 20  # some ambiguous joints did go wrong
    # ambiguous joints decoded right are unsure yet near: the rank correlation is moderate,
    # but every wrong joint is among the unsure ones
    assert scipy.stats.spearmanr(confidence, error)[0] < -0.25
    wrong = error > 0.2
    assert confidence[wrong].max() < confidence[~wrong].mean()
    low, high = confidence < np.quantile(confidence, 0.25), confidence > np.quantile(confidence, 0.75)
    assert error[low].mean() > 3 * error[high].mean()


def _gt_and_results(rng, n_frames: int = 40):
    """Two actors; each predicted joint off by an error that falls as its confidence rises."""
    poses = rng.uniform(-2, 2, (n_frames, 2, 14, 3))
    poses[:, 1] += 10  # far apart: matching is unambiguous
    confidence = rng.uniform(0, 1, (n_frames, 2, 14))
    direction = rng.normal(size=(n_frames, 2, 14, 3))
    direction /= np.linalg.norm(direction, axis=-1, keepdims=True)
    predicted = poses + direction * (0.3 * (1 - confidence) ** 2)[..., None]
    gt = GroundTruth(np.arange(n_frames), poses)
    # people in reverse order in each frame: the report must follow the matching, not the order
    results = [FrameResult(f, [4, 3], predicted[f, ::-1], confidence[f, ::-1]) for f in range(n_frames)]
    return gt, results


def test_report_bins_tables_and_plots(tmp_path):
    gt, results = _gt_and_results(np.random.default_rng(1))
    samples = confidence_samples(results, gt, (0, 1))
    assert len(samples.joint_confidence) == 40 * 2 * 14 and len(samples.limb_confidence) == 40 * 2 * 10
    assert samples.spearman() < -0.9
    bins = samples.joint_bins()
    assert len(bins) == 10 and sum(b['n'] for b in bins) == 40 * 2 * 14
    means = [b['mean mm'] for b in bins]
    assert means == sorted(means, reverse=True)
    limbs = samples.limb_bins()
    assert limbs[0]['strict %'] < limbs[-1]['strict %'] == 100.0
    trade = samples.tradeoff()
    dropped = [r['wrong dropped %'] for r in trade]
    kept = [r['right kept %'] for r in trade]
    assert dropped[0] == 0 and kept[0] == 100 and dropped == sorted(dropped) and kept == sorted(kept, reverse=True)
    text = format_confidence_report(samples)
    assert f'{samples.spearman():+.3f}' in text and 'wrong dropped' in text
    paths = plot_confidence_report(samples, tmp_path)
    assert [p.name for p in paths] == ['confidence_joints.png', 'confidence_limbs.png']
    assert all(p.stat().st_size > 5000 for p in paths)


def test_report_refuses_results_without_confidence():
    gt, results = _gt_and_results(np.random.default_rng(2), 3)
    results[1] = FrameResult(results[1].frame, results[1].person_ids, results[1].joints)
    with pytest.raises(ValueError, match='frame 1: no confidence'):
        confidence_samples(results, gt, (0, 1))
