"""Which 2D skeletons in different cameras show the same person, by ray-to-ray distance.

Two skeletons match when the rays through their shared joints pass close to each other on
average (paper: 2 cm; on the real Shelf calibration and OpenPose noise the right value is
larger, see MatchingConfig). Views are then clustered greedily, closest pairs first, with at
most one skeleton per camera in a person, and a view joins a person (or two persons merge) only
when it matches that person's views on average: one close pair must not chain two people
standing near each other into one (single linkage did, at Shelf frame 590).
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Sequence

import numpy as np

from mvpose_ros.core.geometry.camera import Camera, ray_ray_distance
from mvpose_ros.core.types import Person2D


@dataclass(frozen=True)
class MatchingConfig:
    """max_distance: metres of mean ray distance; min_shared: joints both views must see."""

    max_distance: float = 0.15
    min_shared: int = 4
    min_score: float = 0.1

    def __post_init__(self) -> None:
        if not self.max_distance > 0:
            raise ValueError(f'match_distance must be > 0, got {self.max_distance}')
        if self.min_shared < 1:
            raise ValueError(f'min_shared must be >= 1, got {self.min_shared}')


def all_view_distances(cameras: Sequence[Camera], people: Sequence[Sequence[Person2D]],
                       config: MatchingConfig) -> np.ndarray:
    """Mean ray-to-ray distance between every two skeletons of all cameras at once (N, N), N = all
    skeletons in camera order; inf within a camera and where too few joints are shared."""
    owner = np.repeat(np.arange(len(cameras)), [len(p) for p in people])
    if len(owner) == 0:
        return np.zeros((0, 0))
    kp = np.stack([p.keypoints for ps in people for p in ps])  # (N, J, 3)
    dirs = np.empty(kp.shape)
    origins = np.empty((len(kp), 3))
    for c, cam in enumerate(cameras):
        if people[c]:
            dirs[owner == c] = cam.directions(kp[owner == c, :, :2])
            origins[owner == c] = cam.centre
    dist = ray_ray_distance(origins[:, None, None], dirs[:, None], origins[None, :, None], dirs[None])  # (N, N, J)
    seen = kp[..., 2] > config.min_score
    shared = seen[:, None] & seen[None]
    n = shared.sum(-1)
    mean = np.where(shared, dist, 0.0).sum(-1) / np.maximum(n, 1)
    return np.where((n >= config.min_shared) & (owner[:, None] != owner[None]), mean, np.inf)


def cluster_views(cameras: Sequence[Camera], people: Sequence[Sequence[Person2D]],
                  config: MatchingConfig) -> list[dict[int, int]]:
    """Group skeletons across cameras into people seen by at least two cameras.

    people[c] are camera c's skeletons. Returns one {camera index: skeleton index} per person.
    """
    dist = all_view_distances(cameras, people, config)
    view = [(c, i) for c, ps in enumerate(people) for i in range(len(ps))]
    a, b = np.nonzero(np.triu(dist <= config.max_distance, 1))
    order = np.argsort(dist[a, b], kind='stable')
    owner: dict[int, int] = {}  # view (row of dist) -> its cluster
    clusters: list[list[int]] = []

    def linked(x: list[int], y: list[int]) -> bool:
        """The two groups of views are one person: other cameras, and close on average."""
        if {view[u][0] for u in x} & {view[v][0] for v in y}:
            return False
        cross = dist[np.ix_(x, y)]
        return bool(np.mean(cross[np.isfinite(cross)]) <= config.max_distance)

    for e in order:
        u, v = int(a[e]), int(b[e])
        cu, cv = owner.get(u), owner.get(v)
        if cu is not None and cu == cv:
            continue
        x = clusters[cu] if cu is not None else [u]
        y = clusters[cv] if cv is not None else [v]
        if not linked(x, y):
            continue
        merged = x + y
        target = cu if cu is not None else cv if cv is not None else len(clusters)
        if target == len(clusters):
            clusters.append(merged)
        else:
            clusters[target] = merged
        if cu is not None and cv is not None:
            clusters[cv] = []
        for w in merged:
            owner[w] = target
    return [{view[w][0]: view[w][1] for w in c} for c in clusters if len(c) >= 2]
