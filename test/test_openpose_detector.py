"""People with keypoints and heatmaps from the real Shelf OpenPose output (frame 572)."""
from __future__ import annotations

import time

import numpy as np
import pytest

from mvpose_ros.core.defaults import data_root
from mvpose_ros.core.detection.grouping import group_body25
from mvpose_ros.core.detection.openpose import read_body25
from mvpose_ros.core.detection.openpose_detector import (OpenPoseDetectorConfig, detect_grouped, detect_people,
                                                         grouped_keypoints)
from mvpose_ros.core.geometry.body import (BODY25_INFERENCE_JOINTS, HEAD, INFERENCE_MIRROR, L_EAR, NECK,
                                           NUM_INFERENCE_JOINTS, R_EAR)
from mvpose_ros.core.heatmap import render_heatmaps

LINE = 272  # actorsGT frame 572


@pytest.fixture(scope='module')
def frames():
    root = data_root() / 'data' / 'shelf' / 'openpose_body25'
    return [read_body25(root / f'{c}.txt')[LINE] for c in range(5)]


def test_people_per_camera(frames):
    for frame in frames:
        people = detect_people(frame, OpenPoseDetectorConfig())
        assert 3 <= len(people) <= 5
        assert sum((p.keypoints[:, 2] > 0).sum() >= 10 for p in people) >= 3
        for p in people:
            assert p.keypoints.shape == (NUM_INFERENCE_JOINTS, 3) and p.track_id == -1
            assert p.heatmap.maps.shape[0] == NUM_INFERENCE_JOINTS
            assert 0 <= p.heatmap.maps.min() and p.heatmap.maps.max() <= 1
            box = p.bbox()
            assert np.all(box[:2] <= box[2:])


def test_keypoints_match_grouping(frames):
    frame = frames[0]
    people = detect_people(frame, OpenPoseDetectorConfig())
    groups = group_body25(frame)
    kp25 = grouped_keypoints(frame, groups)
    assert len(people) == len(groups)
    for person, kp in zip(people, kp25):
        np.testing.assert_array_equal(person.keypoints, kp[BODY25_INFERENCE_JOINTS])
        np.testing.assert_array_equal(person.keypoints[NECK], kp[1])
        np.testing.assert_array_equal(person.keypoints[HEAD], kp[0])  # the nose
        np.testing.assert_array_equal(person.keypoints[[R_EAR, L_EAR]], kp[[17, 18]])


def _own_peak_errors(people) -> tuple[np.ndarray, np.ndarray]:
    """(N,) pixel distances keypoint -> map peak and (N,) joint ids over detected joints."""
    dist, joint = [], []
    for p in people:
        peak = p.heatmap.peak()
        ok = p.keypoints[:, 2] > 0
        dist.append(np.linalg.norm(peak[ok, :2] - p.keypoints[ok, :2], axis=1))
        joint.append(np.flatnonzero(ok))
    return np.concatenate(dist), np.concatenate(joint)


def test_single_gaussian_maps_peak_at_the_keypoints(frames):
    config = OpenPoseDetectorConfig(secondary_radius=0.0, mirror_weight=0.0)
    for frame in frames:
        dist, _ = _own_peak_errors(detect_people(frame, config))
        assert len(dist) > 30
        assert np.all(dist <= config.stride)


def test_default_maps_peak_at_lone_candidates(frames):
    """With secondary and mirror evidence, a joint with no other candidate of its BODY25 type
    within the secondary radius still peaks at its keypoint unless the mirrored candidate
    outweighs it (neck and head have no mirror: they are their own counterpart)."""
    config = OpenPoseDetectorConfig()
    checked, joints = 0, set()
    for frame in frames:
        for p in detect_people(frame, config):
            peak = p.heatmap.peak()
            box = p.bbox()
            radius = config.secondary_radius * np.hypot(*(box[2:] - box[:2]))
            for j in range(NUM_INFERENCE_JOINTS):
                own, mirror = p.keypoints[j], p.keypoints[INFERENCE_MIRROR[j]]
                cand = frame.candidates[BODY25_INFERENCE_JOINTS[j]]
                lone = np.sum(np.linalg.norm(cand[:, :2] - own[:2], axis=1) <= radius) == 1
                if own[2] > 0 and lone and own[2] > config.mirror_weight * mirror[2]:
                    assert np.linalg.norm(peak[j, :2] - own[:2]) <= config.stride
                    checked += 1
                    joints.add(j)
    assert checked >= 150 and joints == set(range(NUM_INFERENCE_JOINTS))


@pytest.mark.parametrize('mirror_weight', [0.0, 0.5])
def test_mirror_evidence(frames, mirror_weight):
    config = OpenPoseDetectorConfig(secondary_radius=0.0, mirror_weight=mirror_weight)
    checked, joints = 0, set()
    for frame in frames:
        for p in detect_people(frame, config):
            kp = p.keypoints
            for j in range(NUM_INFERENCE_JOINTS):
                own, mirror = kp[j], kp[INFERENCE_MIRROR[j]]
                # far apart, so the own Gaussian contributes nothing at the mirror
                if own[2] > 0 and mirror[2] > 0 and np.linalg.norm(own[:2] - mirror[:2]) > 60:
                    uv = np.zeros((NUM_INFERENCE_JOINTS, 1, 2))
                    uv[j, 0] = mirror[:2]
                    value = p.heatmap.lookup(uv)[j, 0]
                    if mirror_weight == 0:
                        assert value == 0
                    else:
                        assert value == pytest.approx(mirror_weight * mirror[2], rel=0.15)
                    checked += 1
                    joints.add(j)
    assert checked >= 100 and {R_EAR, L_EAR} <= joints


def test_secondary_candidates_enter_the_map(frames):
    base = OpenPoseDetectorConfig(mirror_weight=0.0, secondary_radius=0.0)
    wide = OpenPoseDetectorConfig(mirror_weight=0.0, secondary_radius=10.0,
                                  secondary_weight=0.5)
    frame = frames[0]
    for p0, p1 in zip(detect_people(frame, base), detect_people(frame, wide)):
        for j in range(NUM_INFERENCE_JOINTS):
            others = frame.candidates[BODY25_INFERENCE_JOINTS[j]]
            far = np.linalg.norm(others[:, :2] - p0.keypoints[j, :2], axis=1) > 60
            if p0.keypoints[j, 2] <= 0 or not far.any():
                continue
            uv = np.zeros((NUM_INFERENCE_JOINTS, far.sum(), 2))
            uv[j] = others[far, :2]
            np.testing.assert_array_equal(p0.heatmap.lookup(uv)[j], 0.0)
            np.testing.assert_allclose(p1.heatmap.lookup(uv)[j], 0.5 * others[far, 2],
                                       rtol=0.15)


def _reference_maps(frame, groups, keypoints, config):
    """The maps of detect_grouped's people (groups (P, 25), keypoints (P, 16, 3)) from each
    joint's centre rows listed one by one: own candidate, secondary ones, counterpart."""
    rows = []
    for g, kp in zip(groups, keypoints):
        seen = kp[kp[:, 2] > 0, :2]
        radius = config.secondary_radius * np.hypot(*(seen.max(axis=0) - seen.min(axis=0)))
        person = []
        for j, b in enumerate(BODY25_INFERENCE_JOINTS):
            joint = []
            if g[b] >= 0:
                own = frame.candidates[b][g[b]]
                joint.append(own)
                joint += [c * (1, 1, config.secondary_weight) for i, c in enumerate(frame.candidates[b])
                          if i != g[b] and np.linalg.norm(c[:2] - own[:2]) <= radius]
            m = BODY25_INFERENCE_JOINTS[INFERENCE_MIRROR[j]]
            if config.mirror_weight > 0 and m != b and g[m] >= 0:  # also where joint j is missing
                joint.append(frame.candidates[m][g[m]] * (1, 1, config.mirror_weight))
            person.append(joint)
        rows.append(person)
    n = max([len(joint) for person in rows for joint in person] + [1])
    centres = np.zeros((len(rows), NUM_INFERENCE_JOINTS, n, 3))
    for p, person in enumerate(rows):
        for j, joint in enumerate(person):
            centres[p, j, :len(joint)] = np.reshape(joint, (-1, 3))
    return [hm.maps for hm in render_heatmaps(centres, config.stride, config.sigma)]


@pytest.mark.parametrize('config', [
    OpenPoseDetectorConfig(),
    OpenPoseDetectorConfig(secondary_radius=0.6, secondary_weight=0.5, mirror_weight=0.3),
    OpenPoseDetectorConfig(secondary_radius=0.0, mirror_weight=1.0)])
def test_maps_match_the_joint_by_joint_centres(config):
    root = data_root() / 'data' / 'shelf' / 'openpose_body25'
    for c in range(5):
        for frame in read_body25(root / f'{c}.txt')[LINE - 40:LINE + 40:8]:
            groups, people = detect_grouped(frame, config)
            keypoints = np.array([p.keypoints for p in people]).reshape(-1, NUM_INFERENCE_JOINTS, 3)
            expected = _reference_maps(frame, groups, keypoints, config)
            assert len(expected) == len(people)
            for person, maps in zip(people, expected):
                np.testing.assert_array_equal(person.heatmap.maps, maps)


def test_fast_enough(frames):
    config = OpenPoseDetectorConfig()
    detect_people(frames[0], config)
    times = []
    for _ in range(5):
        for frame in frames:
            start = time.perf_counter()
            detect_people(frame, config)
            times.append(time.perf_counter() - start)
    assert np.median(times) < 0.02  # ~3 ms measured; generous for loaded CI machines
