"""Stable 3D person ids across frames.

A person keeps its id while the per-camera tracks that make it up continue: each shared
(camera, track) pair votes for the old id with the number of frames it has been part of that id
(up to MAX_VOTES), so a person split for a few frames into two clusters (a duplicate detection in
one camera) goes back to the id its tracks have long made up rather than to the newcomer's.
An id goes only as far as a person can move: `max_jump` metres (how far rough centres of one
person differ) plus `max_speed` m/s times a time. A person's tracks carry its id within the reach
of the time since it was seen, so a stray two-view cluster holding one of a person's tracks
cannot take that person's id from across the room. When the tracks all changed (a new box in
every camera after an occlusion, or people crossing a view between two sets of a slow detector),
the id is recovered from the 3D position alone within the reach of the time since the frame
before: the motion of one step of the stream, not of the person's whole absence, so a newcomer
does not take the id of someone lost a second ago a metre or two away. Only a person none of
whose tracks has a history is placed so: one whose tracks vote for an id is that id's (or, below,
its duplicate), not whoever was last seen nearby. Times are the frames' own (seconds): sets
0.4 s apart keep walking people's ids as frames 40 ms apart do. An id is forgotten once the
frames have gone more than `memory` seconds without it; a stream that stalls (no frame at all for a
while: an overloaded graph, a paused bag) shows no one leaving, and the people of the frame after
it keep their ids, found within the reach of the stall.

A person the detector found twice in a camera splits into two clusters, each with one of that
camera's two views. The part that gets no id of its own, but whose tracks vote for the id the
other part took and which lies within `max_jump` of it, is that person seen twice: it gets the
same id (its tracks count for it), and the associator merges the two. Without this the second
part took a new id, which, where tracks restart often (frames dropped upstream), could then take
over the person's (Shelf thinned 15 ways: 26 id changes, none with it and the pace limit).
Telling a duplicate from someone close by is what the tracks are for: ray distances alone cannot
(two people near each other, one seen by two cameras only, match on average as well).

A person whose views all but one camera's lost (he walks out of the covered volume) is no longer
matched, but that view's track still votes: it keeps his id (`continue_alone`), for at most
`memory` seconds of frames after two cameras last saw him, as the solver places him from where he was.

The keeper's state that outlives a restart is small: the next id and where each recent person
was (`state` / `restore`). A restored keeper never hands out an id it handed out before, and a
person found within reach of where it was last seen gets its old id back (its camera tracks
are new after a restart, so only the position can match).
"""
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
        person seen twice (module doc).
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
            # by position alone only a person none of whose tracks has a history (module doc)
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
        or -1. A person who walks out of all but one camera's view so keeps his id (module doc); the
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
        those another person of the frame took within max_jump of it (module doc); returns the
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
