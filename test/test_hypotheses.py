"""3D joint hypotheses sampled from sharp heatmaps rendered at the real Shelf cameras' projections
of a ground-truth pose, and the data term that scores them."""
from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from mvpose_ros.core.datasets.shelf_campus import dataset_dir, load_actors_gt
from mvpose_ros.core.drawing.video import look_at
from mvpose_ros.core.geometry.body import (HANGING, INFERENCE_MIRROR, INFERENCE_NAMES, INFERENCE_PARENT,
                                           PRIOR_BONE_LENGTH, UNSEEN_FROM, UNSEEN_FROM_SEEN, UNSEEN_RISE, UP)
from mvpose_ros.core.geometry.projection import rig_directions
from mvpose_ros.core.geometry.rays import line_terms, solve_line_terms
from mvpose_ros.core.heatmap import MARGIN_SIGMAS, HeatmapStack, PersonHeatmap, render_heatmap
from mvpose_ros.core.inference.factors import data_terms
from mvpose_ros.core.inference.hypotheses import (SamplingConfig, _anchors, _depth, _plan, bone_scales,
                                                  camera_subsets, own_bone_lengths, sample_people, split_draws,
                                                  subset_count)

SIGMA, STRIDE = 1.5, 1.0
# a sample lies in the 3-sigma cut square around the true pixel, jittered within its cell
SAMPLE_RADIUS_PX = np.sqrt(2) * (MARGIN_SIGMAS * SIGMA + STRIDE)


def data_term(hypotheses, views):
    """(J, M) data term of one person (data_terms of one)."""
    return data_terms([hypotheses], [views], HeatmapStack.of([hm for _, hm in views]))[0]


def sample_hypotheses(views, rng, config):
    """Hypotheses (J, M, 3) of one person (sample_people of one), or None when no joint is seen twice."""
    return sample_people([views], HeatmapStack.of([hm for _, hm in views]), [rng], config)[0]


@pytest.fixture(scope='module')
def rig(shelf_rig):
    return shelf_rig


@pytest.fixture(scope='module')
def truth() -> np.ndarray:
    """(16, 3) inference joints of actor 2 at frame 300 (seen whole by all five cameras): GT
    joints 0..13, then two 'ears' 8 cm either side of the head top, each on its shoulder's side."""
    gt = load_actors_gt(dataset_dir('shelf') / 'actorsGT.mat', [300]).poses[0, 2]
    assert np.isfinite(gt).all()
    right = (gt[8] - gt[9]) / np.linalg.norm(gt[8] - gt[9])  # towards the right shoulder
    return np.concatenate([gt, gt[13] + 0.08 * np.stack([right, -right])])


def _render(rig, points: np.ndarray, sigma: float = SIGMA, stride: float = STRIDE) -> list:
    """One (camera, heatmap) view per camera: a Gaussian at each joint's projection."""
    views = []
    for cam in rig:
        uv = cam.project(points)
        assert np.all((uv >= 0) & (uv < (cam.width, cam.height)))
        views.append((cam, render_heatmap([np.array([[u, v, 1.0]]) for u, v in uv], stride, sigma)))
    return views


@pytest.fixture(scope='module')
def views(rig, truth):
    return _render(rig, truth)


def _without(views, joints, cams) -> list:
    """views with the maps of `joints` emptied in cameras `cams`."""
    out = []
    for c, (cam, hm) in enumerate(views):
        maps = hm.maps.copy()
        if c in cams:
            maps[joints] = 0.0
        out.append((cam, PersonHeatmap(maps=maps, origin=hm.origin, stride=hm.stride)))
    return out


def test_camera_subsets():
    subsets = camera_subsets(range(5))
    assert len(subsets) == 26  # 2^5 - 5 singletons - the empty set
    assert len(set(subsets)) == 26
    sizes = [len(s) for s in subsets]
    assert sizes == sorted(sizes, reverse=True) and min(sizes) == 2 and sizes[0] == 5
    assert all(list(s) == sorted(s) and set(s) <= set(range(5)) for s in subsets)
    assert len(camera_subsets(range(5), min_size=3)) == 16
    assert camera_subsets([2, 7]) == [(2, 7)]
    assert camera_subsets([3]) == []


def test_camera_subsets_up_to_a_limit_are_the_first_of_all():
    every = camera_subsets(range(9))
    assert [subset_count(n) for n in range(1, 10)] == [len(camera_subsets(range(n))) for n in range(1, 10)]
    assert camera_subsets(range(9), limit=40) == every[:40] and camera_subsets(range(9), limit=600) == every
    # a studio of 40 cameras has 2^40 subsets: only those asked for are listed
    largest = camera_subsets(range(40), limit=42)
    assert largest[0] == tuple(range(40)) and all(len(s) == 39 for s in largest[1:41]) and len(largest[41]) == 38
    assert subset_count(40) == 2 ** 40 - 41


@pytest.mark.parametrize('n_cams', [7, 9, 32])
def test_a_plan_with_more_subsets_than_hypotheses_keeps_the_largest_subsets_peaks(n_cams):
    """Past 6 cameras (M 64) the subsets' peaks do not all fit: the first half of M are the peak
    triangulations of the largest subsets, the all-camera one first, then a draw of each of them."""
    m = 64
    cam_of, draw, used = _plan(n_cams, m, True, n_cams)
    subsets = camera_subsets(range(n_cams), limit=m // 2)
    for i, subset in enumerate(subsets + subsets):
        k = len(subset)
        assert tuple(cam_of[i, :k]) == subset and np.all(draw[i, k:] == -1)
        if i < m // 2:
            assert np.all(draw[i, :k] == m)  # the peaks' ray
        else:
            assert np.all((draw[i, :k] >= 0) & (draw[i, :k] < m))
    # each camera's draws used once
    for c in range(n_cams):
        rows, cols = np.nonzero((cam_of == c) & (draw >= 0) & (draw < m))
        assert sorted(draw[rows, cols]) == list(range(used[c]))
    # no more subsets than hypotheses: every subset's peak
    _, draw5, _ = _plan(5, m, True, 5)
    assert np.count_nonzero((draw5 == m).any(axis=1)) == subset_count(5) == 26


@pytest.mark.parametrize('total, n', [(38, 26), (64, 26), (5, 26), (0, 3), (9, 3)])
def test_split_draws(total, n):
    counts = split_draws(total, n)
    assert counts.shape == (n,) and counts.sum() == total
    assert counts.max() - counts.min() <= 1
    assert np.all(np.diff(counts) <= 0)  # the remainder goes to the first subsets


def test_sampling_config_is_validated():
    with pytest.raises(ValueError):
        SamplingConfig(hypotheses=0)
    with pytest.raises(ValueError, match='single_view_depth'):
        SamplingConfig(single_view_depth='middle')


def test_hypotheses_land_on_the_joints(views, truth):
    hyp = sample_hypotheses(views, np.random.default_rng(0), SamplingConfig(hypotheses=64))
    assert hyp.shape == (16, 64, 3) and np.isfinite(hyp).all()
    err = np.linalg.norm(hyp - truth[:, None], axis=-1)  # (16, 64)
    assert np.median(err) < 0.01
    assert np.all(np.median(err, axis=1) < 0.01)
    assert np.percentile(err, 95) < 0.02
    assert np.all(err.min(axis=1) < 0.005)  # the peak triangulations are ~exact
    # Not every hypothesis is within 2 cm: Shelf cameras 0 and 4 face each other (rays ~170
    # degrees apart), so a pair's depth is ill-conditioned and a few-pixel sample offset moves
    # the point several cm along the rays. Each hypothesis still reprojects onto the sampled
    # support in at least two cameras.
    assert err.max() < 0.15
    reproj = np.stack([np.linalg.norm(cam.project(hyp) - cam.project(truth)[:, None], axis=-1)
                       for cam, _ in views])  # (C, 16, 64)
    assert np.all(np.sort(reproj, axis=0)[1] <= SAMPLE_RADIUS_PX)


def test_peak_hypotheses_alone(views, truth):
    """M = 26 = the number of camera subsets: every hypothesis is a peak triangulation, so the
    result does not depend on the seed and is within a pixel's worth of the truth."""
    config = SamplingConfig(hypotheses=26, peak_hypotheses=True)
    a = sample_hypotheses(views, np.random.default_rng(1), config)
    b = sample_hypotheses(views, np.random.default_rng(2), config)
    np.testing.assert_array_equal(a, b)
    assert np.linalg.norm(a - truth[:, None], axis=-1).max() < 0.015


@pytest.mark.parametrize('m', [1, 5, 26, 27, 64])
@pytest.mark.parametrize('peaks', [True, False])
def test_m_hypotheses_per_joint(views, truth, m, peaks):
    hyp = sample_hypotheses(views, np.random.default_rng(0), SamplingConfig(m, peaks))
    assert hyp.shape == (16, m, 3) and np.isfinite(hyp).all()
    assert np.linalg.norm(hyp - truth[:, None], axis=-1).max() < 0.15


def test_eight_cameras_anchor_on_the_peak_triangulation_of_all(truth):
    """A ring of eight cameras: more camera subsets (247) than hypotheses, yet each joint's first
    hypothesis is still the triangulation of every camera's peak (whatever the draws), which
    anchors the joints seen once."""
    centre = truth.mean(axis=0)
    rig = [look_at(centre + [5 * np.cos(a), 5 * np.sin(a), 1.0], centre, UP, 1000, 800, name=str(i))
           for i, a in enumerate(np.linspace(0, 2 * np.pi, 8, endpoint=False))]
    views = _render(rig, truth)
    config = SamplingConfig(hypotheses=64)
    a = sample_hypotheses(views, np.random.default_rng(1), config)
    b = sample_hypotheses(views, np.random.default_rng(2), config)
    assert a.shape == (16, 64, 3) and np.isfinite(a).all()
    np.testing.assert_array_equal(a[:, :32], b[:, :32])  # peaks, not draws
    assert not np.allclose(a[:, 32:], b[:, 32:])
    assert np.linalg.norm(a[:, 0] - truth, axis=-1).max() < 0.005
    np.testing.assert_array_equal(_anchors(a[None], config)[0], a[:, 0])


def test_a_leg_no_camera_sees_hangs_below_its_parent(views, truth):
    """Feet out of every picture: actor 2's right knee and ankle seen by no camera hang their
    bones' lengths (his own, from the left leg) straight down, the knee from each hip hypothesis
    and the ankle from the knee's; he walks upright, so they land within 0.25 m. With unseen_joints
    'centre' both take the person's centre, a metre off."""
    knee, ankle, hip = (INFERENCE_NAMES.index(n) for n in ('r_knee', 'r_ankle', 'r_hip'))
    sub = _without(views, [knee, ankle], set(range(5)))
    config = SamplingConfig(hypotheses=32)
    hyp = sample_hypotheses(sub, np.random.default_rng(0), config)
    lengths = own_bone_lengths(_anchors(hyp[None], config))[0]
    np.testing.assert_allclose(hyp[knee], hyp[hip] - lengths[knee] * UP, atol=1e-12)
    np.testing.assert_allclose(hyp[ankle], hyp[knee] - lengths[ankle] * UP, atol=1e-12)
    assert np.linalg.norm(hyp[[knee, ankle]] - truth[[knee, ankle], None], axis=-1).max() < 0.25  # 0.14, 0.21
    centred = sample_hypotheses(sub, np.random.default_rng(0), replace(config, unseen_joints='centre'))
    np.testing.assert_array_equal(centred[knee], centred[ankle])  # both the centre
    assert np.linalg.norm(centred[ankle] - truth[ankle], axis=-1).min() > 0.5


# joints no camera sees -> (joint, its two sources, metres along up times the person's scale, and
# how far from actor 2's true joint it may land; he stands upright, arms down)
UNSEEN_CASES = {
    'arm': [('r_elbow', 'r_shoulder', 'r_shoulder', -0.33, 0.15), ('r_wrist', 'r_elbow', 'r_elbow', -0.26, 0.25)],
    'head': [('head', 'neck', 'neck', 0.20, 0.10), ('r_ear', 'neck', 'r_shoulder', 0.20, 0.13)],
    'neck and head': [('neck', 'r_shoulder', 'l_shoulder', 0.0, 0.15), ('head', 'neck', 'neck', 0.20, 0.15)],
    'hip': [('l_hip', 'l_shoulder', 'l_shoulder', -0.50, 0.15)],
    'shoulder': [('r_shoulder', 'r_hip', 'r_hip', 0.50, 0.15), ('r_elbow', 'r_shoulder', 'r_shoulder', -0.33, 0.2)],
}


@pytest.mark.parametrize('case', sorted(UNSEEN_CASES))
def test_a_joint_no_camera_sees_is_put_on_the_body(views, truth, case):
    """unseen_joints 'body': an arm hangs from the shoulder, the head stands above the neck, the neck
    sits between the shoulders, a hip under its shoulder, a shoulder above its hip, each hypothesis
    from its sources' hypotheses of the same index (sources placed first), by a typical length
    times his scale; all land near his true joints, nearer than the person's centre."""
    joints = [INFERENCE_NAMES.index(j) for j, *_ in UNSEEN_CASES[case]]
    sub = _without(views, joints, set(range(5)))
    config = SamplingConfig(hypotheses=32)
    hyp = sample_hypotheses(sub, np.random.default_rng(0), config)
    anchors = _anchors(hyp[None], config)
    anchors[:, joints] = np.nan  # as the sampler saw them: not seen
    scale = bone_scales(anchors)[0]
    centred = sample_hypotheses(sub, np.random.default_rng(0), replace(config, unseen_joints='centre'))
    for name, a, b, rise, near in UNSEEN_CASES[case]:
        j, a, b = (INFERENCE_NAMES.index(n) for n in (name, a, b))
        assert UNSEEN_FROM[j].tolist() == [a, b] and UNSEEN_RISE[j] == rise
        np.testing.assert_allclose(hyp[j], 0.5 * (hyp[a] + hyp[b]) + rise * scale[j] * UP, atol=1e-12)
        assert np.linalg.norm(hyp[j] - truth[j], axis=-1).max() < near
    # (his right forearm is not straight down: its wrist alone is nearer the centre, 0.21 against 0.23 m)
    errors = [np.linalg.norm(h[joints] - truth[joints, None], axis=-1).mean() for h in (hyp, centred)]
    assert errors[0] < errors[1] - 0.05


def test_an_unseen_joint_hangs_from_an_unseen_source_at_the_centre(views):
    """A shoulder no camera sees whose hip no camera sees either has no place on the body (the hip
    would hang from it): it takes the person's centre, and its unseen elbow and hip hang from there
    (as a leg from a hip at the centre)."""
    shoulder, elbow, hip = (INFERENCE_NAMES.index(n) for n in ('r_shoulder', 'r_elbow', 'r_hip'))
    config = SamplingConfig(hypotheses=32)
    hidden = [shoulder, elbow, hip]
    hyp = sample_hypotheses(_without(views, hidden, set(range(5))), np.random.default_rng(0), config)
    centre = np.delete(hyp, hidden, axis=0).mean(axis=(0, 1))  # of the joints seen
    np.testing.assert_allclose(hyp[shoulder], np.broadcast_to(centre, (32, 3)), atol=1e-9)
    anchors = _anchors(hyp[None], config)
    anchors[:, hidden] = np.nan
    scale = bone_scales(anchors)[0]
    np.testing.assert_allclose(hyp[elbow], hyp[shoulder] - 0.33 * scale[elbow] * UP, atol=1e-12)
    np.testing.assert_allclose(hyp[hip], hyp[shoulder] - 0.50 * scale[hip] * UP, atol=1e-12)


def test_deterministic_for_a_seed(views):
    config = SamplingConfig(hypotheses=40, peak_hypotheses=False)
    a = sample_hypotheses(views, np.random.default_rng(7), config)
    b = sample_hypotheses(views, np.random.default_rng(7), config)
    c = sample_hypotheses(views, np.random.default_rng(8), config)
    np.testing.assert_array_equal(a, b)
    assert not np.allclose(a, c)


def test_joint_seen_by_one_camera_lies_on_its_rays(views, truth):
    single, unseen = 6, 11  # r_wrist seen by camera 2 only, l_wrist by none
    sub = _without(views, [single], {0, 1, 3, 4})
    sub = _without(sub, [unseen], set(range(5)))
    hyp = sample_hypotheses(sub, np.random.default_rng(0), SamplingConfig(hypotheses=32, single_view_depth='centre',
                                                                          unseen_joints='centre'))
    assert hyp.shape == (16, 32, 3) and np.isfinite(hyp).all()
    others = np.setdiff1d(np.arange(16), [single, unseen])
    centre = hyp[others].reshape(-1, 3).mean(axis=0)
    cam = sub[2][0]
    # on rays through sampled pixels of camera 2 ...
    uv = cam.project(hyp[single])
    assert np.all(np.linalg.norm(uv - cam.project(truth[single]), axis=1) <= SAMPLE_RADIUS_PX)
    # ... at the depth closest to the person's centre
    d = hyp[single] - cam.centre
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    np.testing.assert_allclose(np.einsum('md,md->m', hyp[single] - centre, d), 0.0, atol=1e-9)
    assert np.std(uv, axis=0).min() > 0.3  # the draws differ: rays, not one point
    # a joint no camera sees gets the centre itself
    np.testing.assert_allclose(hyp[unseen], np.broadcast_to(centre, (32, 3)), atol=1e-12)
    # the joints seen by the other four cameras are unaffected in quality
    err = np.linalg.norm(hyp[others] - truth[others, None], axis=-1)
    assert np.median(err) < 0.01


def test_joint_seen_by_one_camera_at_its_bone_length(views, truth):
    """single_view_depth 'limb': the l_wrist seen by camera 2 only lies on camera 2's rays where
    they meet the sphere of the forearm's prior length around the elbow's peak triangulation (or,
    a ray missing it, at its point nearest the elbow), and nearer the truth than at the centre's
    depth. With its elbow seen once too, each wrist hypothesis hangs from the elbow hypothesis of
    the same index (itself on camera 2's rays at the upper arm's length from the shoulder); with
    its elbow seen by none, at the centre's depth."""
    wrist, elbow = 11, 10  # this actor's left forearm is 27 cm long in the ground truth (the prior: 26)
    assert INFERENCE_PARENT[wrist] == elbow
    sub = _without(views, [wrist], {0, 1, 3, 4})
    limb = sample_hypotheses(sub, np.random.default_rng(0), SamplingConfig(hypotheses=32, single_view_depth='limb'))
    centre = sample_hypotheses(sub, np.random.default_rng(0), SamplingConfig(hypotheses=32, single_view_depth='centre'))
    cam = sub[2][0]
    uv = cam.project(limb[wrist])
    assert np.all(np.linalg.norm(uv - cam.project(truth[wrist]), axis=1) <= SAMPLE_RADIUS_PX)
    np.testing.assert_allclose(uv, cam.project(centre[wrist]), atol=1e-6)  # the same rays
    anchor = limb[elbow, 0]
    dist = np.linalg.norm(limb[wrist] - anchor, axis=1)
    ray = (limb[wrist] - cam.centre) / np.linalg.norm(limb[wrist] - cam.centre, axis=1, keepdims=True)
    on_sphere = np.isclose(dist, PRIOR_BONE_LENGTH[wrist], atol=1e-9)
    nearest = np.isclose(np.einsum('md,md->m', limb[wrist] - anchor, ray), 0.0, atol=1e-9)
    assert np.all(on_sphere | (nearest & (dist > PRIOR_BONE_LENGTH[wrist])))
    assert on_sphere.mean() > 0.5
    err_limb = np.linalg.norm(limb[wrist] - truth[wrist], axis=1)
    err_centre = np.linalg.norm(centre[wrist] - truth[wrist], axis=1)
    assert np.median(err_limb) < 0.05 < np.median(err_centre)
    others = np.setdiff1d(np.arange(16), [wrist])
    np.testing.assert_array_equal(limb[others], centre[others])

    config = SamplingConfig(hypotheses=32, single_view_depth='limb')
    arm_seen_once = _without(sub, [elbow], {0, 1, 3, 4})
    limb = sample_hypotheses(arm_seen_once, np.random.default_rng(0), config)
    dist = np.linalg.norm(limb[wrist] - limb[elbow], axis=1)
    assert np.isclose(dist, PRIOR_BONE_LENGTH[wrist], atol=1e-9).mean() > 0.5
    assert np.all(dist >= PRIOR_BONE_LENGTH[wrist] - 1e-9)  # on the sphere, or its ray's point nearest the elbow
    upper_arm = np.linalg.norm(limb[elbow] - limb[INFERENCE_PARENT[elbow], 0], axis=1)
    assert np.isclose(upper_arm, PRIOR_BONE_LENGTH[elbow], atol=1e-9).mean() > 0.5

    no_elbow = _without(sub, [elbow], set(range(5)))
    limb = sample_hypotheses(no_elbow, np.random.default_rng(0), config)
    centre = sample_hypotheses(no_elbow, np.random.default_rng(0), replace(config, single_view_depth='centre'))
    np.testing.assert_allclose(limb[wrist], centre[wrist], atol=1e-12)


def _bone(points, joint):
    return np.linalg.norm(points[joint] - points[INFERENCE_PARENT[joint]])


def test_own_bone_lengths(truth):
    """A joint's bone takes its counterpart's measured length, else the typical length times the
    median ratio of the person's measured bones (at least two), else the typical length; a
    measured bone beyond the plausible range counts for neither."""
    r_wrist, l_wrist, r_elbow, l_elbow, l_shoulder = 6, 11, 7, 10, 9
    child = truth[0] + 0.8 * (truth - truth[0])  # (16, 3) shrunk about the right ankle
    lengths = own_bone_lengths(child[None])
    assert lengths.shape == (1, 16)
    has_parent = INFERENCE_PARENT >= 0
    assert np.isnan(lengths[0, ~has_parent]).all()
    assert lengths[0, r_wrist] == pytest.approx(_bone(child, l_wrist), abs=1e-12)
    assert lengths[0, l_wrist] == pytest.approx(_bone(child, r_wrist), abs=1e-12)

    ratios = np.array([_bone(child, j) / PRIOR_BONE_LENGTH[j] for j in np.flatnonzero(has_parent) if j != l_wrist])
    no_left_wrist = child.copy()
    no_left_wrist[l_wrist] = np.nan
    lengths = own_bone_lengths(no_left_wrist[None])
    assert lengths[0, r_wrist] == pytest.approx(PRIOR_BONE_LENGTH[r_wrist] * np.median(ratios), abs=1e-12)

    # a left elbow anchored 2 m off: neither the right elbow's counterpart nor in the scale
    wrong = no_left_wrist.copy()
    wrong[l_elbow] += [2.0, 0.0, 0.0]
    lengths = own_bone_lengths(wrong[None])
    kept = [j for j in np.flatnonzero(has_parent) if j not in (l_wrist, l_elbow)]
    scale = np.median([_bone(child, j) / PRIOR_BONE_LENGTH[j] for j in kept])
    assert lengths[0, r_elbow] == pytest.approx(PRIOR_BONE_LENGTH[r_elbow] * scale, abs=1e-12)

    # one measured bone is no scale: the typical lengths
    one_bone = np.full_like(child, np.nan)
    one_bone[[l_elbow, l_shoulder]] = child[[l_elbow, l_shoulder]]
    np.testing.assert_array_equal(own_bone_lengths(one_bone[None])[0, r_wrist], PRIOR_BONE_LENGTH[r_wrist])
    assert own_bone_lengths(one_bone[None])[0, r_elbow] == pytest.approx(_bone(child, l_elbow), abs=1e-12)
    assert own_bone_lengths(np.zeros((0, 16, 3))).shape == (0, 16)


def test_own_bone_lengths_take_numpys_median():
    """The person's scale is np.nanmedian of the measured ratios for any number of anchored joints
    (own_bone_lengths sorts instead: a tenth of nanmedian's cost)."""
    rng = np.random.default_rng(0)
    has_parent = INFERENCE_PARENT >= 0
    only = np.flatnonzero(has_parent & (INFERENCE_MIRROR == np.arange(16)))
    assert len(only) == 0  # every limb joint has a counterpart: with both sides hidden, the scale shows
    for _ in range(300):
        anchors = rng.normal(0.0, 0.25, (4, 16, 3))
        anchors[rng.random((4, 16)) < rng.random()] = np.nan
        lengths = own_bone_lengths(anchors)
        for p in range(4):
            ratio = np.full(16, np.nan)
            ratio[has_parent] = [_bone(anchors[p], j) / PRIOR_BONE_LENGTH[j] for j in np.flatnonzero(has_parent)]
            ratio[(ratio < 0.45) | (ratio > 1.3)] = np.nan
            scale = np.nanmedian(ratio) if np.count_nonzero(~np.isnan(ratio)) >= 2 else 1.0
            for j in np.flatnonzero(has_parent & np.isnan(ratio[INFERENCE_MIRROR])):
                assert lengths[p, j] == pytest.approx(PRIOR_BONE_LENGTH[j] * scale, abs=1e-12)


def test_a_child_joint_seen_by_one_camera_at_his_own_bone_length(rig, truth):
    """A person of 0.6 an adult's size whose left wrist camera 2 alone sees, and his right wrist
    no camera: 'own_limb' puts the left wrist at the adult forearm's length times the median
    ratio of his measured bones from the elbow, near his own forearm's length; 'limb' at an
    adult's forearm, which misplaces it along camera 2's rays."""
    wrist, other = 11, 6
    child = truth[0] + 0.6 * (truth - truth[0])
    views = _without(_without(_render(rig, child), [wrist], {0, 1, 3, 4}), [other], set(range(5)))
    own = sample_hypotheses(views, np.random.default_rng(0), SamplingConfig(hypotheses=32))
    adult = sample_hypotheses(views, np.random.default_rng(0), SamplingConfig(hypotheses=32, single_view_depth='limb'))
    forearm = _bone(child, wrist)
    for hyp, off in ((own, (0.0, 0.03)), (adult, (0.06, 1.0))):
        dist = np.linalg.norm(hyp[wrist] - child[INFERENCE_PARENT[wrist]], axis=1)
        assert off[0] < np.median(np.abs(dist - forearm)) < off[1]
    err_own = np.median(np.linalg.norm(own[wrist] - child[wrist], axis=1))
    err_adult = np.median(np.linalg.norm(adult[wrist] - child[wrist], axis=1))
    assert err_own < 0.06 and err_adult > 0.1, (err_own, err_adult)


def test_a_leg_joint_seen_by_one_camera_hangs_below_its_parent(views, truth):
    """hanging_legs: the right ankle, seen by camera 2 alone, takes the crossing of camera 2's rays
    with the sphere around the knee that is lower along up, near the truth; the crossing nearer the
    person's centre is the one above the knee; with up reversed, the other crossing."""
    ankle = 0
    sub = _without(views, [ankle], {0, 1, 3, 4})
    config = SamplingConfig(hypotheses=32)
    hanging = sample_hypotheses(sub, np.random.default_rng(0), config)
    nearer_centre = sample_hypotheses(sub, np.random.default_rng(0), replace(config, hanging_legs=False))
    upside_down = sample_people([sub], HeatmapStack.of([hm for _, hm in sub]), [np.random.default_rng(0)], config,
                                up=-UP)[0]

    def error(hyp):
        return np.median(np.linalg.norm(hyp[ankle] - truth[ankle], axis=1))

    assert error(hanging) < 0.2 and error(nearer_centre) > 0.4, (error(hanging), error(nearer_centre))
    moved = np.linalg.norm(hanging[ankle] - upside_down[ankle], axis=1) > 1e-6
    assert moved.mean() > 0.5
    assert np.all(hanging[ankle][moved] @ UP < upside_down[ankle][moved] @ UP)
    others = np.setdiff1d(np.arange(16), [ankle])
    np.testing.assert_array_equal(hanging[others], nearer_centre[others])


def test_none_without_a_joint_seen_twice(views):
    config = SamplingConfig(hypotheses=16)
    assert sample_hypotheses(views[:1], np.random.default_rng(0), config) is None
    # camera 0 sees joints 0..7, camera 1 joints 8..15: no joint is seen twice
    split = _without(views[:2], list(range(8, 16)), {0})
    split = _without(split, list(range(8)), {1})
    assert sample_hypotheses(split, np.random.default_rng(0), config) is None


@pytest.mark.parametrize('sigma, stride', [(SIGMA, STRIDE), (30.0, 4.0)])
def test_data_term_prefers_the_true_point(rig, truth, sigma, stride):
    views = _render(rig, truth, sigma, stride)
    rng = np.random.default_rng(0)
    offset = rng.normal(size=(16, 3))
    offset *= 0.10 / np.linalg.norm(offset, axis=1, keepdims=True)
    far = truth + (0.0, 0.0, 20.0)  # high above: beyond every heatmap in every view
    hyp = np.stack([truth, truth + offset, far], axis=1)  # (16, 3, 3)
    score = data_term(hyp, views)
    assert score.shape == (16, 3)
    np.testing.assert_allclose(score.sum(axis=1), 1.0, rtol=1e-6)
    assert np.all(score[:, 0] > score[:, 1])
    assert np.all(score[:, 2] == 0)
    if sigma > 10:  # broad maps: the 10 cm point still has evidence, just less
        assert np.all(score[:, 1] > 0.05)
    # no evidence at all for any hypothesis of a joint: uniform row
    empty = data_term(np.stack([far, far + 1.0], axis=1), views)
    np.testing.assert_allclose(empty, 0.5)


def _numpy_sample_people(people, stack, rngs, config, before):
    """sample_people as numpy on whole arrays (the formulation the kernels replaced)."""
    m = config.hypotheses
    n_views, n_joints = stack.start.shape
    n_people, n_maps = len(people), n_views * n_joints
    counts = np.array([len(v) for v in people], dtype=np.intp)
    first_view = np.concatenate([[0], np.cumsum(counts)]).astype(np.intp)
    owner = np.repeat(np.arange(n_people), counts)
    draws = np.concatenate([rng.random((hi - lo, 3 * n_joints * m)) for rng, lo, hi in
                            zip(rngs, first_view[:-1], first_view[1:])])
    u = draws[:, :n_joints * m].reshape(n_maps, m)
    jitter = draws[:, n_joints * m:].reshape(n_maps, m, 2)
    peaks = stack.peak()
    sees = np.zeros((n_people, counts.max(), n_joints), dtype=bool)
    sees[owner, np.arange(n_views) - first_view[owner]] = peaks[..., 2] > 0
    n_seen = sees.sum(axis=1)
    seeing = first_view[:-1, None, None] + np.argsort(~sees, axis=1, kind='stable')
    width = int(n_seen.max())
    need = np.zeros((n_views, n_joints), dtype=np.intp)
    plans = []
    for n in range(2, width + 1):
        pp, pj = np.nonzero(n_seen == n)
        if len(pp):
            views = seeing[pp, :n, pj]
            plan = _plan(n, m, config.peak_hypotheses, width)
            need[views, pj[:, None]] = plan[2]
            plans.append((plan, pp, pj, views))
    single_p, single_j = np.nonzero(n_seen == 1)
    single_view = seeing[single_p, 0, single_j]
    need[single_view, single_j] = m
    first_draw = n_maps + np.concatenate([[0], np.cumsum(need.ravel())[:-1]]).reshape(n_views, n_joints)
    maps = np.repeat(np.arange(n_maps), need.ravel())
    k = np.arange(len(maps)) - (first_draw.ravel() - n_maps)[maps]
    pixels = np.concatenate([peaks[..., :2].reshape(-1, 2), stack.sample_at(maps, u[maps, k], jitter[maps, k])])
    view = np.concatenate([np.arange(n_maps), maps]) // n_joints
    cameras = [cam for views in people for cam, _ in views]
    rig = list({id(c): c for c in cameras}.values())
    camera_of_view = np.array([next(i for i, r in enumerate(rig) if r is c) for c in cameras])
    dirs = rig_directions(rig, camera_of_view[view], pixels)
    centres = np.stack([cam.centre for cam in rig])[camera_of_view]
    out = np.full((n_people, n_joints, m, 3), np.nan)
    if plans:
        terms = np.zeros((9, len(dirs) + 1))
        terms[:, :-1] = line_terms(centres[view], dirs)
        rays = []
        for (cam_of, draw, _), _, joints, views in plans:
            j = joints[:, None, None]
            views = views[:, cam_of]
            ray = np.where(draw == m, views * n_joints + j, first_draw[views, j] + draw)
            rays.append(np.where(draw < 0, -1, ray))
        ray = np.moveaxis(np.concatenate(rays), -1, 0)
        summed = terms[:, ray[0]]
        for slot in ray[1:]:
            summed += terms[:, slot]
        persons = np.concatenate([plan_persons for _, plan_persons, _, _ in plans])
        joints = np.concatenate([plan_joints for _, _, plan_joints, _ in plans])
        out[persons, joints] = solve_line_terms(summed, width)
    located = ~np.isnan(out).all(axis=(1, 2, 3))
    centre = np.full((n_people, 3), np.nan)
    centre[located] = np.nanmean(out[located].reshape(-1, n_joints * m, 3), axis=1)
    placed = ~located & ~np.isnan(before[:, 0])  # nothing seen twice: from where he was
    centre[placed], located = before[placed], located | placed
    keep = located[single_p]
    single_p, single_j, single_view = single_p[keep], single_j[keep], single_view[keep]
    origin = centres[single_view]
    direction = dirs[first_draw[single_view, single_j][:, None] + np.arange(m)]
    depth = np.einsum('smd,sd->sm', direction, centre[single_p] - origin)
    anchors = _anchors(out, config)
    scales = bone_scales(anchors) if config.single_view_depth == 'own_limb' else np.ones((n_people, n_joints))
    # without a parent to hang from: the depth nearest where the body puts the joint from its anchored sources
    body_rise = UNSEEN_RISE * scales if config.unseen_joints == 'body' else np.full_like(scales, np.nan)
    (a, b), rise = UNSEEN_FROM[single_j].T, body_rise[single_p, single_j]
    body = 0.5 * (anchors[single_p, a] + anchors[single_p, b]) + rise[:, None] * UP
    placed = (a >= 0) & ~np.isnan(body[:, 0])
    target = np.where(placed[:, None], body, centre[single_p])
    body_depth = np.einsum('smd,sd->sm', direction, target - origin)
    if config.single_view_depth == 'centre':
        out[single_p, single_j] = origin[:, None] + body_depth[..., None] * direction
    else:
        lengths = PRIOR_BONE_LENGTH * scales
        level = np.array([_depth(INFERENCE_PARENT[:, None], j) for j in single_j], dtype=int)
        for lv in np.unique(level):  # parents first: a parent seen once is the anchor of each hypothesis
            s = level == lv
            sp, sj = single_p[s], single_j[s]
            parent, length = INFERENCE_PARENT[sj], lengths[sp, sj]
            anchor = np.repeat(anchors[sp, np.maximum(parent, 0)][:, None], m, axis=1)  # (n, m, 3)
            chained = (parent >= 0) & np.isnan(anchor[:, 0, 0]) & (n_seen[sp, np.maximum(parent, 0)] == 1)
            anchor[chained] = out[sp[chained], parent[chained]]
            rel = anchor - origin[s][:, None]
            mid = np.einsum('nmd,nmd->nm', direction[s], rel)
            half = np.sqrt(np.maximum(mid ** 2 - np.einsum('nmd,nmd->nm', rel, rel) + length[:, None] ** 2, 0.0))
            near, far = mid - half, mid + half
            limb = np.where(np.abs(near - depth[s]) <= np.abs(far - depth[s]), near, far)
            rise = np.einsum('nmd,d->nm', direction[s], UP)
            lower = np.where(rise * (near - far) <= 0.0, near, far)
            limb = np.where((HANGING[sj] & config.hanging_legs)[:, None], lower, limb)
            on_limb = (parent >= 0) & ~np.isnan(anchor[:, 0, 0]) & ~np.isnan(length)
            out[sp, sj] = origin[s][:, None] + np.where(on_limb[:, None], limb, body_depth[s])[..., None] * direction[s]
    unseen_p, unseen_j = np.nonzero((n_seen == 0) & located[:, None])
    out[unseen_p, unseen_j] = centre[unseen_p, None]
    if config.unseen_joints == 'body':
        waits_for = np.where(UNSEEN_FROM_SEEN[:, None], -1, UNSEEN_FROM)  # seen sources are never placed
        for j in sorted(range(n_joints), key=lambda k: _depth(waits_for, k)):  # sources first
            (a, b), rise = UNSEEN_FROM[j], UNSEEN_RISE[j] * scales[:, j]
            put = located & (n_seen[:, j] == 0) & (a >= 0) & ~np.isnan(rise)
            if UNSEEN_FROM_SEEN[j]:
                put &= (n_seen[:, a] > 0) & (n_seen[:, b] > 0)
            out[put, j] = 0.5 * (out[put, a] + out[put, b]) + rise[put, None, None] * UP
    return [out[p] if located[p] else None for p in range(n_people)]


@pytest.mark.parametrize('config', [SamplingConfig(), SamplingConfig(27, False, 'centre'), SamplingConfig(5),
                                    SamplingConfig(40, False, 'limb'), SamplingConfig(40, False, 'own_limb', False),
                                    SamplingConfig(unseen_joints='centre')])
def test_sampling_is_numpys_arithmetic(views, truth, config):
    """Several people at once, as the kernels take them: one seen by all five cameras, one with a
    wrist seen once (its elbow twice) and a wrist seen by none, one seen once only, one whose
    joints no two of its cameras share (None), one with an elbow and its wrist seen once, one with
    both ankles seen once, one with a shoulder seen by none (its hip seen) and the other shoulder and
    its hip seen by none, one with an ear and a hip seen once (their places on the body anchored),
    one seen once only but placed from where he was."""
    wrist_seen_once = _without(_without(views, [6], {0, 1, 3, 4}), [11], set(range(5)))
    split = _without(_without(views[:2], list(range(8, 16)), {0}), list(range(8)), {1})
    limb_seen_once = _without(views[1:4], [10, 11], {1, 2})
    ankles_seen_once = _without(views, [0, 5], {1, 2, 3, 4})
    shoulders_unseen = _without(views, [8, 9, 3], set(range(5)))
    ear_and_hip_seen_once = _without(views, [14, 3], {1, 2, 3, 4})
    people = [views, wrist_seen_once, views[2:3], split, limb_seen_once, ankles_seen_once, shoulders_unseen,
              ear_and_hip_seen_once, views[4:5]]
    stack = HeatmapStack.of([hm for person in people for _, hm in person])
    before = np.full((len(people), 3), np.nan)
    before[[0, 8]] = [[0.0, 0.0, 0.0], truth.mean(axis=0) + 0.1]  # where they were (the first is seen twice)
    out = sample_people(people, stack, [np.random.default_rng(i) for i in range(9)], config, UP, before)
    expected = _numpy_sample_people(people, stack, [np.random.default_rng(i) for i in range(9)], config, before)
    assert [h is None for h in out] == [False, False, True, True, False, False, False, False, False]
    for got, want in zip(out, expected):
        if want is not None:
            np.testing.assert_array_equal(got, want)
    assert sample_people([], HeatmapStack.of([]), [], config) == []


def test_a_joint_seen_once_without_a_parent_takes_its_depth_from_the_body(views, truth):
    """A hip, the head and an ear seen by one camera have no parent to hang from: each hypothesis
    lies on its ray at the depth nearest where unseen_joints 'body' would put the joint from its
    anchored sources (the hip under its shoulder, the head above the neck, the ear beside it), nearer the
    truth than at the depth nearest the person's centre ('centre')."""
    names = ('l_hip', 'head', 'r_ear')
    joints = [INFERENCE_NAMES.index(n) for n in names]
    sub = _without(views, joints, {1, 2, 3, 4})
    config = SamplingConfig(hypotheses=32)
    hyp = sample_hypotheses(sub, np.random.default_rng(0), config)
    centred = sample_hypotheses(sub, np.random.default_rng(0), replace(config, unseen_joints='centre'))
    anchors = _anchors(hyp[None], config)
    anchors[:, joints] = np.nan  # as the sampler saw them: not seen twice
    scale, anchors = bone_scales(anchors)[0], anchors[0]
    origin = views[0][0].centre
    for j in joints:
        (a, b), rise = UNSEEN_FROM[j], UNSEEN_RISE[j] * scale[j]
        body = 0.5 * (anchors[a] + anchors[b]) + rise * UP
        rays = (hyp[j] - origin) / np.linalg.norm(hyp[j] - origin, axis=-1, keepdims=True)
        np.testing.assert_allclose(np.einsum('md,md->m', rays, hyp[j] - origin), rays @ (body - origin), atol=1e-9)
        errors = [np.linalg.norm(h[j] - truth[j], axis=-1).mean() for h in (hyp, centred)]
        assert errors[0] < errors[1] - 0.015


def test_a_person_one_camera_alone_sees_is_placed_from_where_he_was(views, truth):
    """Nothing seen twice: without a centre from the frame before he is left out (None); with one
    (0.1 m off his own), each joint lies on its camera's rays near his true joint, roots at the
    given centre's depth and limbs hanging from them."""
    alone = views[1:2]
    config = SamplingConfig(hypotheses=32)
    stack = HeatmapStack.of([hm for _, hm in alone])
    assert sample_people([alone], stack, [np.random.default_rng(0)], config)[0] is None
    before = truth.mean(axis=0) + [0.1, 0.0, 0.0]
    hyp = sample_people([alone], stack, [np.random.default_rng(0)], config, UP, before[None])[0]
    errors = np.linalg.norm(hyp - truth[:, None], axis=-1).mean(axis=1)  # (J,)
    assert np.median(errors) < 0.15 and errors.max() < 0.45  # limbs along a ray: either crossing of a bone
    assert np.linalg.norm(hyp.mean(axis=(0, 1)) - truth.mean(axis=0)) < 0.15
