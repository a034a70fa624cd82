"""OpenPose's greedy bottom-up grouping: joint candidates are linked into people limb by limb
with their part-affinity scores."""
from __future__ import annotations

import numpy as np

from mvpose_ros.core.compiled import kernel, kernel_array
from mvpose_ros.core.detection.openpose import BODY25_NUM_JOINTS, BODY25_PAF_PAIRS, OpenPoseFrame


# Shoulder-ear limbs (2, 17) and (5, 18) close loops over the kinematic tree the other 24 limbs
# span. The file lists them before the eye-ear limbs, so taken in file order they would claim
# ears before the head chain reaches them and a wrong shoulder-ear link would then block the
# right ear. They go last instead (as in OpenPose's own order): by then they can only add an
# ear the head chain missed or join a head fragment to its body, and they never start a person.
BODY25_REDUNDANT_LIMBS = frozenset(BODY25_PAF_PAIRS.index(p) for p in ((2, 17), (5, 18)))
_LIMB_ORDER = ([k for k in range(len(BODY25_PAF_PAIRS)) if k not in BODY25_REDUNDANT_LIMBS]
               + sorted(BODY25_REDUNDANT_LIMBS))


def group_body25(frame: OpenPoseFrame, paf_power: float = 0.2, min_paf: float = 0.05,
                 min_joints: int = 4, min_mean_score: float = 0.3) -> np.ndarray:
    """Group one frame's BODY25 candidates into people; returns (P, 25) int candidate index per
    joint (-1 where the person has none), best-scoring person first.

    Limbs are taken in the file's order (torso first, so people grow from the neck), the two
    redundant shoulder-ear limbs last. Per limb, candidate pairs are accepted greedily by
    sharpened score, each candidate at most once; an accepted pair starts a person (neither end
    owned), extends one (its person lacks that joint) or merges two people (no joint in common);
    anything else is a conflict and the pair is ignored.

    paf_power: sharpening exponent applied to the raw PAF scores (the file's producer used 0.2).
    min_paf: a pair is a connection only if its sharpened score is > min_paf. The files hold
        raw 0 for pairs OpenPose rejected and >= 0.05 otherwise, so the default keeps every
        pair OpenPose accepted and rejects only the zeros (0.05 ** 0.2 = 0.55 would do the same).
    min_joints, min_mean_score: people with fewer joints, or whose (sum of candidate scores + sum
        of sharpened PAF scores of their connections) / joint count is lower, are dropped
        (OpenPose's subset filter).
    """
    # the greedy walk is compiled (_group): in Python it was a few hundred steps per frame
    pafs = [frame.pafs[k] for k in _LIMB_ORDER]
    score = np.asarray(np.power(np.concatenate(pafs, axis=None), paf_power), dtype=np.float64)
    n_b = np.array([p.shape[1] for p in pafs])
    n_cand = np.array([len(c) for c in frame.candidates])
    cand = kernel_array(np.concatenate(frame.candidates), np.float64)
    return _group(score, n_b, cand, n_cand, float(min_paf), int(min_joints), float(min_mean_score))


# joints a, b of each limb in _LIMB_ORDER; the limbs from _TREE_LIMBS on (the redundant ones)
# never start a person
_LIMB_A = np.array([BODY25_PAF_PAIRS[k][0] for k in _LIMB_ORDER])
_LIMB_B = np.array([BODY25_PAF_PAIRS[k][1] for k in _LIMB_ORDER])
_TREE_LIMBS = len(_LIMB_ORDER) - len(BODY25_REDUNDANT_LIMBS)


@kernel('int64[:, ::1](float64[::1], int64[::1], float64[:, ::1], int64[::1], float64, int64, float64)')
def _group(score, n_b, cand, n_cand, min_paf, min_joints, min_mean_score):
    """group_body25 on flat arrays: score (S,) the sharpened PAF entries of every limb in
    _LIMB_ORDER, each limb's (n_a, n_b) matrix row-major; cand (C, 3) every candidate, joint
    after joint, n_cand (25,) of them per joint."""
    cand_first = np.zeros(BODY25_NUM_JOINTS + 1, dtype=np.int64)
    cand_first[1:] = np.cumsum(n_cand)
    n_max = len(cand) // 2 + 1  # a person starts with two free candidates
    owner = np.full(len(cand), -1)  # person per candidate
    used = np.full(len(cand), -1)  # the last limb that paired a candidate
    people = np.full((n_max, BODY25_NUM_JOINTS), -1)
    total = np.zeros(n_max)  # candidate scores + PAF scores of each person
    alive = np.ones(n_max, dtype=np.bool_)
    n_people = 0
    pairs = np.empty(len(score), dtype=np.int64)
    start = 0
    for r in range(len(n_b)):
        a, b = _LIMB_A[r], _LIMB_B[r]
        size = (cand_first[a + 1] - cand_first[a]) * n_b[r]
        # the limb's pairs above min_paf, best first, ties in index order (stable insertion sort)
        n = 0
        for k in range(start, start + size):
            if score[k] > min_paf:
                i = n
                while i > 0 and score[pairs[i - 1]] < score[k]:
                    pairs[i] = pairs[i - 1]
                    i -= 1
                pairs[i] = k
                n += 1
        for i in range(n):
            k = pairs[i]
            ga = cand_first[a] + (k - start) // n_b[r]
            gb = cand_first[b] + (k - start) % n_b[r]
            if used[ga] == r or used[gb] == r:
                continue
            used[ga] = used[gb] = r
            paf = score[k]
            pa, pb = owner[ga], owner[gb]
            if pa < 0 and pb < 0:
                if r >= _TREE_LIMBS:
                    continue
                people[n_people, a], people[n_people, b] = ga - cand_first[a], gb - cand_first[b]
                owner[ga] = owner[gb] = n_people
                total[n_people] = cand[ga, 2] + cand[gb, 2] + paf
                n_people += 1
            elif pa < 0 or pb < 0:
                # attach the free end unless its person already has that joint
                p, j, g = (pb, a, ga) if pa < 0 else (pa, b, gb)
                if people[p, j] < 0:
                    people[p, j] = g - cand_first[j]
                    owner[g] = p
                    total[p] += cand[g, 2] + paf
            elif pa != pb:
                if np.any((people[pa] >= 0) & (people[pb] >= 0)):
                    continue  # the two fragments disagree on some joint
                for j in range(BODY25_NUM_JOINTS):
                    c = people[pb, j]
                    if c >= 0:
                        people[pa, j] = c
                        owner[cand_first[j] + c] = pa
                total[pa] += total[pb] + paf
                alive[pb] = False
        start += size

    n_joints = (people[:n_people] >= 0).sum(axis=1)
    kept = np.flatnonzero(alive[:n_people] & (n_joints >= min_joints)
                          & (total[:n_people] / np.maximum(n_joints, 1) >= min_mean_score))
    kept = kept[np.argsort(-total[kept], kind='mergesort')]  # best first, ties in creation order
    out = np.empty((len(kept), BODY25_NUM_JOINTS), dtype=np.int64)
    for i in range(len(kept)):
        out[i] = people[kept[i]]
    return out
