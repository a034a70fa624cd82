"""Which 2D skeletons in different cameras show the same person, by ray-to-ray distance.

Two skeletons match when the rays through their shared joints pass close to each other on
average (paper: 2 cm; on the real Shelf calibration and OpenPose noise the right value is
larger, see MatchingConfig). Views are then clustered greedily, closest pairs first, with at
most one skeleton per camera in a person.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Sequence

import numpy as np

from mvpose_ros.core.geometry.camera import Camera, ray_ray_distance
from mvpose_ros.core.types import Person2D


TIE_M = 1e-9  # metres: two mean ray distances closer than this are taken as equal


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
    # closest first; distances within TIE_M of each other are rounding noise (views of one point
    # projected exactly, as in a synthetic scene), so they keep index order whatever the arithmetic
    order = np.argsort(np.round(dist[a, b] / TIE_M), kind='stable')
    edges = [(dist[a[e], b[e]], view[a[e]], view[b[e]]) for e in order]
    owner: dict[tuple[int, int], int] = {}
    clusters: list[dict[int, int]] = []
    for _, u, v in edges:
        cu, cv = owner.get(u), owner.get(v)
        if cu is None and cv is None:
            owner[u] = owner[v] = len(clusters)
            clusters.append({u[0]: u[1], v[0]: v[1]})
        elif cu is not None and cv is not None:
            if cu != cv and not clusters[cu].keys() & clusters[cv].keys():
                for cam, idx in clusters[cv].items():
                    owner[(cam, idx)] = cu
                clusters[cu].update(clusters[cv])
                clusters[cv] = {}
        else:
            keep, new = (cu, v) if cu is not None else (cv, u)
            if new[0] not in clusters[keep]:
                clusters[keep][new[0]] = new[1]
                owner[new] = keep
    return [c for c in clusters if len(c) >= 2]
