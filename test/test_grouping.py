"""OpenPose's greedy PAF grouping on synthetic frames and on real Shelf detections."""
from __future__ import annotations

import numpy as np
import pytest
from scipy.optimize import linear_sum_assignment

from mvpose_ros.core.datasets.shelf_campus import load_actors_gt_2d
from mvpose_ros.core.defaults import data_root
from mvpose_ros.core.detection.grouping import BODY25_REDUNDANT_LIMBS, group_body25
from mvpose_ros.core.detection.openpose import BODY25_PAF_PAIRS, OpenPoseFrame, read_body25

SHELF = data_root() / 'data' / 'shelf'
FRAME, LINE = 572, 272  # actorsGT frame and its index in the detection files
MID_HIP, R_HIP, L_HIP = 8, 2, 3  # BODY25 mid-hip; body-14 hips


def test_redundant_limbs_are_the_shoulder_ear_pairs():
    assert {BODY25_PAF_PAIRS[k] for k in BODY25_REDUNDANT_LIMBS} == {(2, 17), (5, 18)}
    # the other 24 limbs are a spanning tree of the 25 joints (no cycle, all joints reached)
    root = list(range(25))

    def find(x: int) -> int:
        while root[x] != x:
            x = root[x]
        return x

    for k, (a, b) in enumerate(BODY25_PAF_PAIRS):
        if k not in BODY25_REDUNDANT_LIMBS:
            assert find(a) != find(b)
            root[find(b)] = find(a)
    assert len({find(j) for j in range(25)}) == 1


def _two_people(rng: np.random.Generator, right: float = 0.9, wrong: float = 0.5):
    """Two full BODY25 people side by side; candidate order alternates per joint so that a
    candidate index says nothing about the person. Every cross-person pair has a non-zero
    (wrong) affinity below the right one; returns the frame and the expected (2, 25) groups."""
    order = [(0, 1) if j % 2 else (1, 0) for j in range(25)]
    candidates = []
    for j, (first, second) in enumerate(order):
        pos = [(100 + 300 * p + 4 * j, 20 + 15 * j, 0.8) for p in (first, second)]
        candidates.append(np.array(pos))
    pafs = []
    for a, b in BODY25_PAF_PAIRS:
        paf = np.empty((2, 2))
        for ia in range(2):
            for ib in range(2):
                same = order[a][ia] == order[b][ib]
                paf[ia, ib] = (right if same else wrong) + 0.05 * rng.random()
        pafs.append(paf)
    expected = np.array([[order[j].index(p) for j in range(25)] for p in (0, 1)])
    return OpenPoseFrame(candidates, pafs), expected


def _as_set(groups: np.ndarray) -> set[tuple[int, ...]]:
    return {tuple(g) for g in groups.tolist()}


@pytest.mark.parametrize('seed', range(5))
def test_two_people_with_crossing_affinities(seed):
    frame, expected = _two_people(np.random.default_rng(seed))
    assert _as_set(group_body25(frame)) == _as_set(expected)


def test_wrong_affinities_stronger_than_right_ones_break_grouping():
    # guards the test above: the synthetic frame does exercise the PAF scores
    frame, expected = _two_people(np.random.default_rng(0), right=0.3, wrong=0.9)
    assert _as_set(group_body25(frame)) != _as_set(expected)


def test_redundant_limb_adds_a_missing_ear_but_creates_no_conflict():
    frame, expected = _two_people(np.random.default_rng(1))
    k_eye_ear = BODY25_PAF_PAIRS.index((15, 17))
    k_shoulder_ear = BODY25_PAF_PAIRS.index((5, 18))
    frame.pafs[k_eye_ear][:] = 0.0  # r_ear reachable only through shoulder-ear (2, 17)
    # l_shoulder of one person fits the other's l_ear best: must not steal or merge
    a, b = expected[0, 5], expected[1, 18]
    frame.pafs[k_shoulder_ear][a, b] = 1.0
    assert _as_set(group_body25(frame)) == _as_set(expected)


def test_fragments_merge_and_small_people_are_dropped():
    frame, expected = _two_people(np.random.default_rng(2))
    # cut person 0 at the neck-mid-hip limb: the limbs below (listed in file order before
    # their link to the mid-hip) grow as fragments that must still merge into one lower body
    k = BODY25_PAF_PAIRS.index((1, 8))
    frame.pafs[k][expected[0, 1], expected[0, 8]] = 0.0
    frame.pafs[k][expected[0, 1], expected[1, 8]] = 0.0
    groups = group_body25(frame)
    assert len(groups) == 3
    lower = {8, 9, 10, 11, 12, 13, 14, 19, 20, 21, 22, 23, 24}
    person0 = [g for g in groups if g[1] == expected[0, 1] or g[8] == expected[0, 8]]
    assert len(person0) == 2
    for g in person0:
        joints = set(np.flatnonzero(g >= 0).tolist())
        assert joints == lower or joints == set(range(25)) - lower
        np.testing.assert_array_equal(g[g >= 0], expected[0][g >= 0])
    assert len(group_body25(frame, min_joints=13)) == 2  # the 12-joint upper body goes
    assert len(group_body25(frame, min_mean_score=5.0)) == 0


def _hip_midpoints(frame: OpenPoseFrame, groups: np.ndarray) -> np.ndarray:
    mids = np.full((len(groups), 2), np.nan)
    has = groups[:, MID_HIP] >= 0
    mids[has] = frame.candidates[MID_HIP][groups[has, MID_HIP], :2]
    return mids


@pytest.fixture(scope='module')
def shelf_572():
    frames = [read_body25(SHELF / 'openpose_body25' / f'{c}.txt')[LINE] for c in range(5)]
    gt = load_actors_gt_2d(SHELF / 'actorsGT.mat', [FRAME])[0]  # (A, C, 14, 2)
    return frames, gt


def test_shelf_572_people_per_camera(shelf_572):
    frames, _ = shelf_572
    for frame in frames:
        groups = group_body25(frame)
        full = np.count_nonzero((groups >= 0).sum(axis=1) >= 10)
        # 4 people stand in the room (one, actor 1, is not annotated in this frame); camera 2
        # also sees a fifth, 8-joint fragment beside actor 3
        assert 3 <= full <= 4
        assert len(groups) <= 5


def test_shelf_572_groups_sit_on_annotated_actors(shelf_572):
    """Each annotated actor is matched one-to-one to a grouped person whose mid-hip is within
    50 px of the annotated hip midpoint in at least 4 of the 5 cameras. (Shelf's annotated hips
    sit 15-26 px below OpenPose's, so 30 px would test the annotation convention.)"""
    frames, gt = shelf_572
    actors = [a for a in range(gt.shape[0]) if np.isfinite(gt[a]).all()]
    assert actors == [0, 2, 3]
    hits = np.zeros(len(actors), int)
    for c, frame in enumerate(frames):
        mids = _hip_midpoints(frame, group_body25(frame))
        gt_mid = 0.5 * (gt[actors, c, R_HIP] + gt[actors, c, L_HIP])
        dist = np.linalg.norm(gt_mid[:, None] - mids[None], axis=-1)
        rows, cols = linear_sum_assignment(np.nan_to_num(dist, nan=1e6))
        hits[rows[dist[rows, cols] < 50]] += 1
    assert np.all(hits >= 4), hits


@pytest.mark.parametrize('cam', range(5))
def test_real_groups_are_valid_on_every_frame(cam):
    frames = read_body25(SHELF / 'openpose_body25' / f'{cam}.txt')
    n_people = []
    for frame in frames:
        groups = group_body25(frame)
        n_people.append(len(groups))
        for j, cand in enumerate(frame.candidates):
            used = groups[:, j][groups[:, j] >= 0]
            assert np.all(used < len(cand))
            assert len(np.unique(used)) == len(used)  # a candidate belongs to one person
        assert np.all((groups >= 0).sum(axis=1) >= 4)
    assert 2 <= np.median(n_people) <= 4


def _reference_grouping(frame: OpenPoseFrame, paf_power=0.2, min_paf=0.05, min_joints=4, min_mean_score=0.3):
    """group_body25 written out limb by limb, pair by pair."""
    people, scores = [], []
    owner = {}  # (joint, candidate) -> person
    order = [k for k in range(26) if k not in BODY25_REDUNDANT_LIMBS] + sorted(BODY25_REDUNDANT_LIMBS)
    for k in order:
        a, b = BODY25_PAF_PAIRS[k]
        paf = np.power(frame.pafs[k], paf_power)
        pairs = sorted(((-paf[i, j], i, j) for i in range(paf.shape[0]) for j in range(paf.shape[1])
                        if paf[i, j] > min_paf))
        used_a, used_b = set(), set()
        for s, ia, ib in pairs:
            if ia in used_a or ib in used_b:
                continue
            used_a.add(ia)
            used_b.add(ib)
            pa, pb = owner.get((a, ia), -1), owner.get((b, ib), -1)
            if pa < 0 and pb < 0:
                if k not in BODY25_REDUNDANT_LIMBS:
                    owner[a, ia] = owner[b, ib] = len(people)
                    people.append({a: ia, b: ib})
                    scores.append(frame.candidates[a][ia, 2] + frame.candidates[b][ib, 2] - s)
            elif pa < 0 or pb < 0:
                p, j, c = (pb, a, ia) if pa < 0 else (pa, b, ib)
                if j not in people[p]:
                    people[p][j] = c
                    owner[j, c] = p
                    scores[p] += frame.candidates[j][c, 2] - s
            elif pa != pb and not set(people[pa]) & set(people[pb]):
                for j, c in people[pb].items():
                    people[pa][j] = c
                    owner[j, c] = pa
                scores[pa] += scores[pb] - s
                people[pb] = None
    kept = sorted((-s, i) for i, (p, s) in enumerate(zip(people, scores))
                  if p is not None and len(p) >= min_joints and s / len(p) >= min_mean_score)
    out = np.full((len(kept), 25), -1)
    for row, (_, i) in enumerate(kept):
        for j, c in people[i].items():
            out[row, j] = c
    return out


@pytest.mark.parametrize('seed', range(20))
def test_matches_the_pair_by_pair_formulation(seed):
    """Random frames: 0-4 candidates per joint, PAF scores on a coarse grid (ties between pairs
    of a limb), a third of them 0 (rejected)."""
    rng = np.random.default_rng(seed)
    counts = rng.integers(0, 5, 25)
    candidates = [np.c_[rng.uniform(0, 500, (n, 2)), rng.integers(1, 10, n) / 10] for n in counts]
    pafs = [np.round(rng.uniform(0, 1, (counts[a], counts[b])), 1) * (rng.random((counts[a], counts[b])) > 0.3)
            for a, b in BODY25_PAF_PAIRS]
    frame = OpenPoseFrame(candidates, pafs)
    for min_joints in (1, 4):
        np.testing.assert_array_equal(group_body25(frame, min_joints=min_joints, min_mean_score=0.0),
                                      _reference_grouping(frame, min_joints=min_joints, min_mean_score=0.0))
        np.testing.assert_array_equal(group_body25(frame), _reference_grouping(frame))


def test_no_candidates():
    frame = OpenPoseFrame([np.zeros((0, 3))] * 25, [np.zeros((0, 0))] * 26)
    assert group_body25(frame).shape == (0, 25)
