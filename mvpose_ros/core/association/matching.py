"""Which 2D skeletons in different cameras show the same person, by ray-to-ray distance.

Two skeletons match when the rays through their shared joints pass close to each other on
average (paper: 2 cm; on the real Shelf calibration and OpenPose noise the right value is
larger, see MatchingConfig). Views are then clustered greedily, closest pairs first, with at
most one skeleton per camera in a person, and a view joins a person (or two persons merge) only
when it matches that person's views on average: one close pair must not chain two people
standing near each other into one (single linkage did, at Shelf frame 590).

Every distance of a frame comes from two batched matrix products per joint over all skeletons'
rays (Pluecker coordinates), so matching all pairs stays a small share of association even for
crowds of a hundred skeletons.
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


@dataclass
class ViewRays:
    """The keypoint rays of every skeleton of a frame, skeletons in camera order: keypoints
    (N, J, 3), owner (N,) camera index, origins (N, 3) camera centres, dirs (N, J, 3) unit
    directions (NaN for undetected keypoints)."""

    keypoints: np.ndarray
    owner: np.ndarray
    origins: np.ndarray
    dirs: np.ndarray

    @classmethod
    def of(cls, cameras: Sequence[Camera], people: Sequence[Sequence[Person2D]]) -> ViewRays:
        """The rays of people[c], camera c's skeletons (one back-projection per camera)."""
        owner = np.repeat(np.arange(len(cameras)), [len(p) for p in people])
        if len(owner) == 0:
            return cls(np.zeros((0, 0, 3)), owner, np.zeros((0, 3)), np.zeros((0, 0, 3)))
        kp = np.stack([p.keypoints for ps in people for p in ps])  # (N, J, 3)
        dirs = np.empty(kp.shape)
        origins = np.empty((len(kp), 3))
        for c, cam in enumerate(cameras):
            if people[c]:
                dirs[owner == c] = cam.directions(kp[owner == c, :, :2])
                origins[owner == c] = cam.centre
        return cls(kp, owner, origins, dirs)


# Below this sine of the angle between two rays, their distance is taken from the parallel-safe
# formula (camera.ray_ray_distance) instead of the one that divides by the sine.
_NEAR_PARALLEL = 1e-6


def _line_distances(origins: np.ndarray, dirs: np.ndarray) -> np.ndarray:
    """(N, N, J) distance between the lines of every two skeletons' keypoints of the same joint:
    origins (N, 3), unit dirs (N, J, 3). With moments m = o x d, two lines are
    |d_a . m_b + d_b . m_a| / |d_a x d_b| apart, so all pairs take two matrix products per joint."""
    d = np.ascontiguousarray(dirs.transpose(1, 0, 2))  # (J, N, 3)
    m = np.cross(origins[None], d)  # (J, N, 3)
    with np.errstate(invalid='ignore'):
        recip = d @ m.transpose(0, 2, 1)  # (J, N, N) d_a . m_b
        cos = d @ d.transpose(0, 2, 1)
        sin = np.sqrt(np.maximum(1.0 - cos * cos, 0.0))
        dist = np.abs(recip + recip.transpose(0, 2, 1)) / np.where(sin < _NEAR_PARALLEL, 1.0, sin)
        near = np.argwhere(sin < _NEAR_PARALLEL)  # (K, 3) joint, a, b: rare
    if len(near):
        j, a, b = near.T
        dist[j, a, b] = ray_ray_distance(origins[a], dirs[a, j], origins[b], dirs[b, j])
    return np.ascontiguousarray(dist.transpose(1, 2, 0))


def all_view_distances(cameras: Sequence[Camera], people: Sequence[Sequence[Person2D]],
                       config: MatchingConfig, rays: ViewRays | None = None) -> np.ndarray:
    """Mean ray-to-ray distance between every two skeletons of all cameras at once (N, N), N = all
    skeletons in camera order; inf within a camera and where too few joints are shared. rays: the
    skeletons' ViewRays, when already made."""
    rays = rays or ViewRays.of(cameras, people)
    owner, kp = rays.owner, rays.keypoints
    if len(owner) == 0:
        return np.zeros((0, 0))
    dist = _line_distances(rays.origins, rays.dirs)
    seen = kp[..., 2] > config.min_score
    shared = seen[:, None] & seen[None]
    n = shared.sum(-1)
    mean = np.where(shared, dist, 0.0).sum(-1) / np.maximum(n, 1)
    return np.where((n >= config.min_shared) & (owner[:, None] != owner[None]), mean, np.inf)


def cluster_views(cameras: Sequence[Camera], people: Sequence[Sequence[Person2D]],
                  config: MatchingConfig, rays: ViewRays | None = None) -> list[dict[int, int]]:
    """Group skeletons across cameras into people seen by at least two cameras.

    people[c] are camera c's skeletons (rays: their ViewRays, when already made). Returns one
    {camera index: skeleton index} per person.
    """
    dist = all_view_distances(cameras, people, config, rays)
    view = [(c, i) for c, ps in enumerate(people) for i in range(len(ps))]
    a, b = np.nonzero(np.triu(dist <= config.max_distance, 1))
    # closest first; distances within TIE_M of each other are rounding noise (views of one point
    # projected exactly, as in a synthetic scene), so they keep index order whatever the arithmetic
    order = np.argsort(np.round(dist[a, b] / TIE_M), kind='stable')
    owner: dict[int, int] = {}  # view (row of dist) -> its cluster
    clusters: list[list[int]] = []
    camera_bits: list[int] = []  # per cluster, bit c set when it has a view of camera c

    def linked(x: list[int], y: list[int]) -> bool:
        """The two groups of views are one person: close on average (their cameras differ). Two
        single views are, being an edge (closer than max_distance) of different cameras."""
        if len(x) == 1 and len(y) == 1:
            return True
        cross = dist[np.ix_(x, y)]
        return bool(np.mean(cross[np.isfinite(cross)]) <= config.max_distance)

    for e in order:
        u, v = int(a[e]), int(b[e])
        cu, cv = owner.get(u), owner.get(v)
        if cu is not None and cu == cv:
            continue
        bits_u = camera_bits[cu] if cu is not None else 1 << view[u][0]
        bits_v = camera_bits[cv] if cv is not None else 1 << view[v][0]
        if bits_u & bits_v:  # a camera sees each view of a person once
            continue
        x = clusters[cu] if cu is not None else [u]
        y = clusters[cv] if cv is not None else [v]
        if not linked(x, y):
            continue
        merged = x + y
        target = cu if cu is not None else cv if cv is not None else len(clusters)
        if target == len(clusters):
            clusters.append(merged)
            camera_bits.append(bits_u | bits_v)
        else:
            clusters[target] = merged
            camera_bits[target] = bits_u | bits_v
        if cu is not None and cv is not None:
            clusters[cv] = []
            camera_bits[cv] = 0
        for w in merged:
            owner[w] = target
    return [{view[w][0]: view[w][1] for w in c} for c in clusters if len(c) >= 2]
