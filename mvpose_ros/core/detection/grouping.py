"""OpenPose's greedy bottom-up grouping: joint candidates are linked into people limb by limb
with their part-affinity scores."""
from __future__ import annotations

import numpy as np

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
    # Every limb's candidate pairs in one array, ordered by limb (in _LIMB_ORDER), then by
    # sharpened score, best first, ties in index order (lexsort is stable): the greedy matching
    # below then walks them once, in plain Python (a few dozen pairs: numpy scalars are slow).
    pafs = [frame.pafs[k] for k in _LIMB_ORDER]
    sizes = np.array([p.size for p in pafs])
    score = np.power(np.concatenate([p.ravel() for p in pafs] + [np.zeros(0)]), paf_power)
    limb = np.repeat(np.arange(len(pafs)), sizes)
    pick = np.flatnonzero(score > min_paf)
    pick = pick[np.lexsort((-score[pick], limb[pick]))]
    n_b = np.array([p.shape[1] if p.size else 1 for p in pafs])
    ia, ib = np.divmod(pick - (np.cumsum(sizes) - sizes)[limb[pick]], n_b[limb[pick]])
    cand_first = np.cumsum([0] + [len(c) for c in frame.candidates]).tolist()
    cand_score = np.concatenate([c[:, 2] for c in frame.candidates] + [np.zeros(0)]).tolist()

    owner = [[-1] * len(c) for c in frame.candidates]  # person index per candidate
    people: list[list[int] | None] = []
    scores: list[float] = []
    current = -1
    for r, ca, cb, paf in zip(limb[pick].tolist(), ia.tolist(), ib.tolist(), score[pick].tolist()):
        if r != current:  # each candidate of a limb takes at most one pair
            current = r
            used_a: set[int] = set()
            used_b: set[int] = set()
            a, b = BODY25_PAF_PAIRS[_LIMB_ORDER[r]]
            redundant = _LIMB_ORDER[r] in BODY25_REDUNDANT_LIMBS
        if ca in used_a or cb in used_b:
            continue
        used_a.add(ca)
        used_b.add(cb)
        pa, pb = owner[a][ca], owner[b][cb]
        if pa < 0 and pb < 0:
            if redundant:
                continue
            person = [-1] * BODY25_NUM_JOINTS
            person[a], person[b] = ca, cb
            owner[a][ca] = owner[b][cb] = len(people)
            people.append(person)
            scores.append(cand_score[cand_first[a] + ca] + cand_score[cand_first[b] + cb] + paf)
        elif pa < 0 or pb < 0:
            # attach the free end unless its person already has that joint
            p, j, c = (pb, a, ca) if pa < 0 else (pa, b, cb)
            if people[p][j] < 0:
                people[p][j] = c
                owner[j][c] = p
                scores[p] += cand_score[cand_first[j] + c] + paf
        elif pa != pb:
            first, second = people[pa], people[pb]
            if any(x >= 0 and y >= 0 for x, y in zip(first, second)):
                continue  # the two fragments disagree on some joint
            for j, c in enumerate(second):
                if c >= 0:
                    first[j] = c
                    owner[j][c] = pa
            scores[pa] += scores[pb] + paf
            people[pb] = None

    kept = []
    for person, score in zip(people, scores):
        if person is None:
            continue
        n = sum(c >= 0 for c in person)
        if n >= min_joints and score / n >= min_mean_score:
            kept.append((score, person))
    kept.sort(key=lambda x: -x[0])
    return np.array([p for _, p in kept], dtype=np.int64).reshape(-1, BODY25_NUM_JOINTS)
