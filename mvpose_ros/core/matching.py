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

from mvpose_ros.core.camera import Camera, ray_ray_distance
from mvpose_ros.core.person2d import Person2D


@dataclass(frozen=True)
class MatchingConfig:
    """max_distance: metres of mean ray distance; min_shared: joints both views must see."""

    max_distance: float = 0.15
    min_shared: int = 4
    min_score: float = 0.1


def view_distance(cam_a: Camera, people_a: Sequence[Person2D], cam_b: Camera, people_b: Sequence[Person2D],
                  config: MatchingConfig) -> np.ndarray:
    """Mean ray-to-ray distance (Na, Nb) between every skeleton pair; inf when too few shared joints."""
    if not people_a or not people_b:
        return np.full((len(people_a), len(people_b)), np.inf)
    kp_a = np.stack([p.keypoints for p in people_a])  # (Na, J, 3)
    kp_b = np.stack([p.keypoints for p in people_b])
    o_a, d_a = cam_a.rays(kp_a[..., :2])
    o_b, d_b = cam_b.rays(kp_b[..., :2])
    dist = ray_ray_distance(o_a[:, None], d_a[:, None], o_b[None], d_b[None])  # (Na, Nb, J)
    shared = (kp_a[:, None, :, 2] > config.min_score) & (kp_b[None, :, :, 2] > config.min_score)
    n = shared.sum(-1)
    mean = np.where(shared, dist, 0.0).sum(-1) / np.maximum(n, 1)
    return np.where(n >= config.min_shared, mean, np.inf)


def cluster_views(cameras: Sequence[Camera], people: Sequence[Sequence[Person2D]],
                  config: MatchingConfig) -> list[dict[int, int]]:
    """Group skeletons across cameras into people seen by at least two cameras.

    people[c] are camera c's skeletons. Returns one {camera index: skeleton index} per person.
    """
    edges = []
    for a in range(len(cameras)):
        for b in range(a + 1, len(cameras)):
            dist = view_distance(cameras[a], people[a], cameras[b], people[b], config)
            for i, k in zip(*np.nonzero(dist <= config.max_distance)):
                edges.append((dist[i, k], (a, int(i)), (b, int(k))))
    edges.sort(key=lambda e: e[0])
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
