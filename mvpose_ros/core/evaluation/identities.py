"""Identities over a clip, counted as for MOTA: which predicted id each annotated actor gets frame after
frame, the switches between them, the actors missed and the people who are no annotated actor.

Per frame, annotated actors and predicted people are paired one to one (Hungarian, on mean joint
distance) where they are within `max_distance`; an actor left without a partner is missed, a
person left without one is a false person (on Shelf this includes people present but not
annotated in that frame), and an actor whose partner's id differs from the id it last had is a
switch.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Sequence

import numpy as np
from scipy.optimize import linear_sum_assignment

from mvpose_ros.core.datasets.shelf_campus import GroundTruth
from mvpose_ros.core.types import FrameResult

MAX_DISTANCE = 0.5  # m of mean joint distance: beyond it a person is not that actor


@dataclass(frozen=True)
class IdentityReport:
    """actors: actorsGT indices reported on; ids[a]: the ids actor a had, in order of first use;
    switches[a]: the frames where its id changed; annotated, missed, false_people: actor-frames,
    actor-frames without a person, people without an actor (every annotated actor counts there)."""

    actors: tuple[int, ...]
    ids: tuple[tuple[int, ...], ...]
    switches: tuple[tuple[int, ...], ...]
    annotated: int
    missed: int
    false_people: int

    def lines(self) -> list[str]:
        """The report as printed by mvpose-eval."""
        out = [f'Actor {a + 1}: ids {list(ids)}, {len(sw)} switch{"es" if len(sw) != 1 else ""}'
               + (f' (frame{"s" if len(sw) > 1 else ""} {", ".join(str(f) for f in sw)})' if sw else '')
               for a, ids, sw in zip(self.actors, self.ids, self.switches)]
        out.append(f'clip: {self.annotated} annotated actor-frames, missed {self.missed}, switches '
                   f'{sum(len(s) for s in self.switches)}; {self.false_people} people matched to no annotated actor '
                   f'(people in view but not annotated count here)')
        return out


def identity_report(results: Sequence[FrameResult], gt: GroundTruth, actors: Sequence[int],
                    max_distance: float = MAX_DISTANCE) -> IdentityReport:
    """Identities of `actors` (actorsGT indices) over the ground truth's frames in `results`."""
    row_of = {int(f): k for k, f in enumerate(gt.frames)}
    ids: dict[int, list[int]] = {a: [] for a in actors}
    switches: dict[int, list[int]] = {a: [] for a in actors}
    last: dict[int, int] = {}
    annotated = missed = false_people = 0
    for result in sorted(results, key=lambda r: r.frame):
        k = row_of.get(result.frame)
        if k is None:
            continue
        present = np.flatnonzero(np.isfinite(gt.poses[k]).all(axis=(-2, -1)))  # every annotated actor
        pairs = _pairs(gt.poses[k, present], result.joints, max_distance)
        partner = {int(present[a]): int(result.person_ids[p]) for a, p in pairs}
        false_people += len(result.person_ids) - len(pairs)
        for actor in actors:
            if actor not in present:
                continue
            annotated += 1
            pid = partner.get(actor)
            if pid is None:
                missed += 1
                continue
            if actor in last and last[actor] != pid:
                switches[actor].append(result.frame)
            last[actor] = pid
            if pid not in ids[actor]:
                ids[actor].append(pid)
    return IdentityReport(tuple(actors), tuple(tuple(ids[a]) for a in actors),
                          tuple(tuple(switches[a]) for a in actors), annotated, missed, false_people)


def _pairs(truth: np.ndarray, joints: np.ndarray, max_distance: float) -> list[tuple[int, int]]:
    """(actor row, person row) pairs of truth (A, 14, 3) and joints (P, 14, 3): the assignment of
    least total mean joint distance, keeping pairs within max_distance."""
    if not len(truth) or not len(joints):
        return []
    dist = np.linalg.norm(truth[:, None] - joints[None], axis=-1)  # (A, P, 14)
    cost = np.nanmean(np.where(np.isfinite(dist), dist, np.nan), axis=-1)
    cost = np.where(np.isfinite(cost), cost, 1e6)
    rows, cols = linear_sum_assignment(cost)
    return [(int(r), int(c)) for r, c in zip(rows, cols) if cost[r, c] <= max_distance]
