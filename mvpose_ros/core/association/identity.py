"""Stable 3D person ids across frames.

A person keeps its id while the per-camera tracks that make it up continue: each shared
(camera, track) pair votes for the id it has long been part of. An id reaches only as far as a
person can move (`max_jump` metres plus `max_speed` m/s times the frames' own time), so a stray
cluster cannot take an id from across the room; when all the tracks changed, the id is recovered
from the 3D position alone. A person found twice in one camera keeps one id; a person one camera
alone still sees keeps his (`continue_alone`) for `memory` seconds. The state that outlives a
restart (`state` / `restore`) is the next id and where each recent person was: a restored keeper
never hands out an id again. The rules and why: docs/method.md#stable-ids."""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, Collection, Mapping, Sequence

import numpy as np
from scipy.optimize import linear_sum_assignment


MAX_VOTES = 25  # frames a (camera, track) pair's vote for its id counts at most


@dataclass
class _Known:
    members: dict[tuple[int, int], int]  # (camera, track) -> frames it has been part of this id
    centre: np.ndarray
    last_time: float | None  # None: restored, seen at the next frame's time


@dataclass
class IdentityKeeper:
    """Assigns ids to each frame's multi-view clusters. max_jump (m) and max_speed (m/s): how far
    from where it was last seen an id may be taken, max_jump + max_speed x the seconds since it was
    seen (by its tracks) or since the frame before (by position alone); memory (s): how long the
    frames may go without an id before it is forgotten. Their defaults are the association's
    (associator.AssociationConfig)."""

    max_jump: float
    max_speed: float
    memory: float
    _known: dict[int, _Known] = field(default_factory=dict)
    _next_id: int = 0
    _last_time: float | None = None  # of the frame before

    def assign(self, time_s: float, members: Sequence[set[tuple[int, int]]], centres: np.ndarray) -> list[int]:
        """Ids for the people of the frame taken at time_s seconds (non-decreasing from call to call).

        members: per person the (camera, track id) pairs it was built from; centres: (P, 3)
        rough 3D centres in metres. Returns one id per person; people sharing an id are one
        person seen twice (docs/method.md#stable-ids).
        """
        for known in self._known.values():
            known.last_time = time_s if known.last_time is None else known.last_time
        # Absence is what the frames show: a stream that stalls (no frame at all for a while, an
        # overloaded graph dropping sets) is no sign that anyone left.
        before = time_s if self._last_time is None else self._last_time
        self._known = {k: v for k, v in self._known.items() if before - v.last_time <= self.memory}
        known_ids = list(self._known)
        ids = [-1] * len(members)
        twice: set[int] = set()  # the people that are another one seen twice
        if members and known_ids:
            # per (camera, track) the known ids it was part of: a look-up per track, not per pair of people
            votes: dict[tuple[int, int], list[tuple[int, int]]] = {}
            for col, k in enumerate(known_ids):
                for t, frames in self._known[k].members.items():
                    votes.setdefault(t, []).append((col, frames))
            shared = np.zeros((len(members), len(known_ids)), dtype=int)
            for row, m in enumerate(members):
                for t in m:
                    for col, frames in votes.get(t, ()):
                        shared[row, col] += frames
            jump = np.linalg.norm(centres[:, None] - np.array([self._known[k].centre for k in known_ids])[None],
                                  axis=-1)
            elapsed = np.maximum(time_s - np.array([self._known[k].last_time for k in known_ids]), 0.0)
            gap = max(time_s - self._last_time, 0.0) if self._last_time is not None else 0.0
            by_tracks = self.max_jump + self.max_speed * elapsed  # (K,) m
            by_position = self.max_jump + self.max_speed * gap
            # by position alone only a person none of whose tracks has a history (docs/method.md#stable-ids)
            new_tracks = (shared == 0).all(axis=1, keepdims=True)
            allowed = np.where(shared > 0, jump <= by_tracks[None], new_tracks & (jump <= by_position))
            # Shared track history dominates; distance breaks ties and decides when no track survives.
            # A new id costs more than any allowed match, and a forbidden one is never taken, so a
            # person nobody matches takes a new id instead of pushing another person off its own.
            new_id = max(by_tracks.max(), by_position) + 1.0  # above any allowed jump
            cost = np.hstack([np.where(allowed, -100.0 * shared + jump, np.inf), np.full((len(members),) * 2, new_id)])
            rows, cols = linear_sum_assignment(cost)
            for r, c in zip(rows.tolist(), cols.tolist()):
                if c < len(known_ids) and allowed[r, c]:
                    ids[r] = known_ids[c]
            twice = self._join_duplicates(ids, shared, known_ids, centres)
        tracks_of: dict[int, set[tuple[int, int]]] = {}
        centre_of: dict[int, np.ndarray] = {}
        for i, tracks in enumerate(members):
            if ids[i] < 0:
                ids[i] = self._next_id
                self._next_id += 1
            tracks_of.setdefault(ids[i], set()).update(tracks)
            if i not in twice:
                centre_of[ids[i]] = centres[i]
        for pid, tracks in tracks_of.items():
            before = self._known[pid].members if pid in self._known else {}
            self._known[pid] = _Known({t: min(before.get(t, 0) + 1, MAX_VOTES) for t in tracks}, centre_of[pid],
                                      time_s)
        self._last_time = time_s
        return ids

    def continue_alone(self, tracks: Sequence[tuple[int, int]], taken: Collection[int]) -> list[int]:
        """Ids for views no other camera's matched this frame, after `assign`: each (camera, track
        id) gets the id its track has been part of for the most frames, unless that id is in
        `taken` (the frame's people's: the view is then a duplicate of one of them), each id once,
        or -1. A person who walks out of all but one camera's view so keeps his id (docs/method.md#stable-ids); the
        keeper's state is left as it was, so he keeps it until the frames have gone `memory` seconds
        without two cameras seeing him."""
        votes = [max(((known.members.get(t, 0), k) for k, known in self._known.items()), default=(0, -1))
                 for t in tracks]
        votes = [(0, -1) if pid in taken else (frames, pid) for frames, pid in votes]
        ids = [-1] * len(tracks)
        for row in sorted(range(len(tracks)), key=lambda r: -votes[r][0]):  # the longest history first
            frames, pid = votes[row]
            if frames > 0 and pid not in ids:
                ids[row] = pid
        return ids

    def _join_duplicates(self, ids: list[int], shared: np.ndarray, known_ids: list[int],
                         centres: np.ndarray) -> set[int]:
        """Give each person left without an id (-1 in ids) the id its tracks vote for most among
        those another person of the frame took within max_jump of it (docs/method.md#stable-ids); returns the
        people given one so."""
        host = {pid: row for row, pid in enumerate(ids) if pid >= 0}
        twice = set()
        for row in [r for r, pid in enumerate(ids) if pid < 0]:
            for col in np.argsort(-shared[row], kind='stable'):
                if shared[row, col] <= 0:
                    break
                other = host.get(known_ids[col])
                if other is not None and np.linalg.norm(centres[row] - centres[other]) <= self.max_jump:
                    ids[row] = known_ids[col]
                    twice.add(row)
                    break
        return twice

    def state(self) -> dict[str, Any]:
        """JSON-able: {'next_id': int, 'people': [{'id': int, 'centre': [x, y, z]}, ...]} (metres)."""
        return {'next_id': self._next_id,
                'people': [{'id': k, 'centre': [float(x) for x in v.centre]} for k, v in sorted(self._known.items())]}

    def restore(self, state: Mapping[str, Any]) -> None:
        """Take over a `state` (of a keeper that stopped) as if its people had been seen at the time
        of the next frame; ValueError naming what is malformed."""
        try:
            next_id = state['next_id']
            people = [(p['id'], np.asarray(p['centre'], dtype=float)) for p in state['people']]
        except (KeyError, TypeError, ValueError) as exc:
            raise ValueError(f'identity state: missing or malformed {exc}') from None
        if type(next_id) is not int or next_id < 0:
            raise ValueError(f'identity state: next_id must be an integer >= 0, got {next_id!r}')
        for pid, centre in people:
            if type(pid) is not int or not 0 <= pid < next_id:
                raise ValueError(f'identity state: person id {pid!r} is not in 0..next_id-1 ({next_id - 1})')
            if centre.shape != (3,) or not np.all(np.isfinite(centre)):
                raise ValueError(f'identity state: person {pid}: centre must be 3 finite numbers')
        self._next_id = max(self._next_id, next_id)
        for pid, centre in people:
            self._known[pid] = _Known({}, centre, None)
