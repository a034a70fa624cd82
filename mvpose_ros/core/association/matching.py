"""Which 2D skeletons in different cameras show the same person, by ray-to-ray distance.

Two skeletons match when the rays through their shared joints pass close to each other on
average (paper: 2 cm; on the real Shelf calibration and OpenPose noise the right value is
larger, see MatchingConfig). Views are then clustered greedily, closest pairs first, with at
most one skeleton per camera in a person, and a view joins a person (or two persons merge) only
when it matches that person's views on average: one close pair must not chain two people
standing near each other into one (single linkage did, at Shelf frame 590).

Every distance of a frame comes from one compiled pass over all pairs of skeletons' rays
(Pluecker coordinates), and the greedy clustering is compiled too, so matching all pairs stays a
small share of association even for crowds of a hundred skeletons.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Sequence

import numpy as np

from mvpose_ros.core.compiled import kernel, kernel_array, pairwise_sum
from mvpose_ros.core.geometry.camera import Camera
from mvpose_ros.core.geometry.rays import line_distance
from mvpose_ros.core.types import Keypoints2D


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
    def of(cls, cameras: Sequence[Camera], people: Sequence[Sequence[Keypoints2D]]) -> ViewRays:
        """The rays of people[c], camera c's skeletons (one back-projection per camera)."""
        counts = [len(p) for p in people]
        owner = np.repeat(np.arange(len(cameras)), counts)
        if len(owner) == 0:
            return cls(np.zeros((0, 0, 3)), owner, np.zeros((0, 3)), np.zeros((0, 0, 3)))
        kp = np.stack([p.keypoints for ps in people for p in ps])  # (N, J, 3)
        dirs = np.empty(kp.shape)
        origins = np.empty((len(kp), 3))
        end = 0
        for cam, count in zip(cameras, counts):  # each camera's skeletons are one block of rows
            start, end = end, end + count
            if count:
                dirs[start:end] = cam.directions(kp[start:end, :, :2])
                origins[start:end] = cam.centre
        return cls(kp, owner, origins, dirs)


# Below this sine of the angle between two rays, their distance is taken from the parallel-safe
# formula (rays.line_distance) instead of the one that divides by the sine.
_NEAR_PARALLEL = 1e-6


@kernel('float64[:, ::1](float64[:, ::1], float64[:, :, ::1], boolean[:, ::1], int64[::1], int64)')
def _mean_line_distances(origins, dirs, seen, owner, min_shared):
    """all_view_distances of the rays: origins (N, 3), unit dirs (N, J, 3), seen (N, J) keypoints
    that count, owner (N,) camera. Two lines with moments m = o x d are |d_a . m_b + d_b . m_a| /
    |d_a x d_b| apart; the mean is over the joints both see."""
    n, n_joints = seen.shape
    # component-major copies (x, y, z; skeleton; joint): a pair's joints then sit side by side and
    # its loop, without branches, runs on vectors
    d = np.empty((3, n, n_joints))
    m = np.empty((3, n, n_joints))
    for a in range(n):
        ox, oy, oz = origins[a]
        for j in range(n_joints):
            dx, dy, dz = dirs[a, j]
            d[0, a, j], d[1, a, j], d[2, a, j] = dx, dy, dz
            m[0, a, j], m[1, a, j], m[2, a, j] = oy * dz - oz * dy, oz * dx - ox * dz, ox * dy - oy * dx
    out = np.full((n, n), np.inf)
    per_joint = np.empty(n_joints)
    for a in range(n):
        for b in range(a + 1, n):
            if owner[a] == owner[b]:
                continue
            shared = 0
            for j in range(n_joints):
                shared += seen[a, j] & seen[b, j]
            if shared < min_shared:
                continue
            near = False
            for j in range(n_joints):
                recip = ((d[0, a, j] * m[0, b, j] + d[1, a, j] * m[1, b, j] + d[2, a, j] * m[2, b, j])
                         + (d[0, b, j] * m[0, a, j] + d[1, b, j] * m[1, a, j] + d[2, b, j] * m[2, a, j]))
                cos = d[0, a, j] * d[0, b, j] + d[1, a, j] * d[1, b, j] + d[2, a, j] * d[2, b, j]
                sin = np.sqrt(max(1.0 - cos * cos, 0.0))
                both = seen[a, j] & seen[b, j]  # & not and: no branch
                near |= both & (sin < _NEAR_PARALLEL)
                per_joint[j] = abs(recip) / sin if both else 0.0
            if near:  # rare: those joints again, by the formula that does not divide by the sine
                for j in range(n_joints):
                    cos = d[0, a, j] * d[0, b, j] + d[1, a, j] * d[1, b, j] + d[2, a, j] * d[2, b, j]
                    if seen[a, j] and seen[b, j] and np.sqrt(max(1.0 - cos * cos, 0.0)) < _NEAR_PARALLEL:
                        per_joint[j] = line_distance(origins[a], dirs[a, j], origins[b], dirs[b, j])
            out[a, b] = out[b, a] = pairwise_sum(per_joint) / shared
    return out


@kernel('Tuple((int64[::1], int64[::1]))(float64[:, ::1], int64[::1], float64)')
def _greedy_clusters(dist, owner, max_distance):
    """cluster_views' clustering of the views seen by cameras owner (N,) at mean distances dist
    (N, N): the views of every cluster in order, clusters in order of creation, and each
    cluster's size."""
    n = len(owner)
    a_edge, b_edge = [], []
    for a in range(n):
        for b in range(a + 1, n):
            if dist[a, b] <= max_distance:
                a_edge.append(a)
                b_edge.append(b)
    # closest first; distances within TIE_M of each other are rounding noise (views of one point
    # projected exactly, as in a synthetic scene), so they keep index order whatever the arithmetic
    key = np.empty(len(a_edge))
    for e in range(len(a_edge)):
        key[e] = dist[a_edge[e], b_edge[e]] / TIE_M
    order = np.argsort(np.round(key), kind='mergesort')
    cluster = np.full(n, -1)
    head = np.full(n, -1)  # per cluster, its first view; then each view's next in nxt (-1: last)
    tail = np.full(n, -1)
    nxt = np.full(n, -1)
    size = np.zeros(n, dtype=np.int64)
    n_cameras = owner.max() + 1 if n else 0
    cameras = np.zeros((n, n_cameras), dtype=np.bool_)  # per cluster, its cameras
    n_clusters = 0
    cross = np.empty(n * n)
    for e in order:
        u, v = a_edge[e], b_edge[e]
        cu, cv = cluster[u], cluster[v]
        if cu >= 0 and cu == cv:
            continue
        if cu >= 0 and cv >= 0:
            clash = np.any(cameras[cu] & cameras[cv])
        elif cu >= 0:
            clash = cameras[cu, owner[v]]
        elif cv >= 0:
            clash = cameras[cv, owner[u]]
        else:
            clash = owner[u] == owner[v]
        if clash:  # a camera sees each view of a person once
            continue
        if cu >= 0 or cv >= 0:  # linked: close on average (two single views are, being an edge)
            count = 0
            x = head[cu] if cu >= 0 else u  # a view in no cluster has no next
            while x >= 0:
                y = head[cv] if cv >= 0 else v
                while y >= 0:
                    if np.isfinite(dist[x, y]):
                        cross[count] = dist[x, y]
                        count += 1
                    y = nxt[y]
                x = nxt[x]
            if not pairwise_sum(cross[:count]) / count <= max_distance:
                continue
        if cu < 0 and cv < 0:
            target = n_clusters
            n_clusters += 1
            head[target], nxt[u], tail[target] = u, v, v
            size[target] = 2
            cameras[target, owner[u]] = cameras[target, owner[v]] = True
        elif cu < 0:  # u joins v's cluster, in front
            target = cv
            nxt[u], head[target] = head[target], u
            size[target] += 1
            cameras[target, owner[u]] = True
        else:  # v or v's cluster joins u's, behind
            target = cu
            first, last = (head[cv], tail[cv]) if cv >= 0 else (v, v)
            nxt[tail[target]], tail[target] = first, last
            if cv >= 0:
                size[target] += size[cv]
                cameras[target] |= cameras[cv]
                size[cv], head[cv], tail[cv] = 0, -1, -1
                cameras[cv] = False
            else:
                size[target] += 1
                cameras[target, owner[v]] = True
        w = head[target]
        while w >= 0:
            cluster[w] = target
            w = nxt[w]
    members = np.empty(n, dtype=np.int64)
    sizes = np.empty(n_clusters, dtype=np.int64)
    count = kept = 0
    for c in range(n_clusters):
        if size[c]:
            w = head[c]
            while w >= 0:
                members[count] = w
                count += 1
                w = nxt[w]
            sizes[kept] = size[c]
            kept += 1
    return members[:count], sizes[:kept]


def all_view_distances(cameras: Sequence[Camera], people: Sequence[Sequence[Keypoints2D]],
                       config: MatchingConfig, rays: ViewRays | None = None) -> np.ndarray:
    """Mean ray-to-ray distance between every two skeletons of all cameras at once (N, N), N = all
    skeletons in camera order; inf within a camera and where too few joints are shared. rays: the
    skeletons' ViewRays, when already made."""
    rays = rays or ViewRays.of(cameras, people)
    if len(rays.owner) == 0:
        return np.zeros((0, 0))
    seen = np.ascontiguousarray(rays.keypoints[..., 2] > config.min_score)
    return _mean_line_distances(kernel_array(rays.origins, np.float64),
                                kernel_array(rays.dirs, np.float64), seen,
                                rays.owner.astype(np.int64), config.min_shared)


def cluster_views(cameras: Sequence[Camera], people: Sequence[Sequence[Keypoints2D]],
                  config: MatchingConfig, rays: ViewRays | None = None,
                  dist: np.ndarray | None = None) -> list[dict[int, int]]:
    """Group skeletons across cameras into people seen by at least two cameras.

    people[c] are camera c's skeletons (rays: their ViewRays, dist: their all_view_distances, when
    already made). Returns one {camera index: skeleton index} per person.
    """
    dist = all_view_distances(cameras, people, config, rays) if dist is None else dist
    view = [(c, i) for c, ps in enumerate(people) for i in range(len(ps))]
    owner = np.array([c for c, _ in view], dtype=np.int64)
    members, sizes = _greedy_clusters(dist, owner, float(config.max_distance))
    ends = np.cumsum(sizes).tolist()
    members = members.tolist()
    return [{view[w][0]: view[w][1] for w in members[end - size:end]} for size, end in zip(sizes.tolist(), ends)]
