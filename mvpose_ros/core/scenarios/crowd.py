"""More people for a benchmark or a bag: copies of a recorded scene's 2D detections, shifted in space.

Each frame's original 2D people are associated (core.association.Associator) into 3D people,
whose joints are triangulated from their keypoints (rays.closest_point_to_rays). Copy k of the
scene moves every 3D person by a fixed offset d_k in the floor plane and re-renders each of its
views geometrically: keypoint j of a view becomes project(X_j + d_k) (its score kept), and map j
of the view's heatmap is translated by that joint's pixel displacement
project(X_j + d_k) - project(X_j) (origin moved, cells unchanged). A joint without a 3D estimate
is dropped from the copy (score 0, NaN pixel, empty map), and so is a joint whose shifted
projection leaves the image; a view stays only where enough of its joints remain inside the
image (people leaving the view), and a copy is only ever seen by cameras that saw the original.

Offsets are chosen once per sequence on a grid in the floor plane: the ones whose copies most
cameras still see come first, and an offset is taken only if, in every frame, every copied
person stays at least `clearance` metres (horizontally) from every person of the scene and of
the copies already taken, so copies never overlap nor merge in association. Copies are added
until the expected number of 3D people per frame (seen by >= 2 cameras) is closest to the
target.
"""
from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass
from typing import Sequence

import numpy as np

from mvpose_ros.core.association.associator import AssociationConfig, Associator
from mvpose_ros.core.defaults import FRAME_RATE
from mvpose_ros.core.geometry.camera import Camera
from mvpose_ros.core.geometry.rays import closest_point_to_rays
from mvpose_ros.core.heatmap import PersonHeatmap
from mvpose_ros.core.types import Person2D

Frame2D = Sequence[Sequence[Person2D] | None]  # per camera, its 2D people (None: camera missing)


@dataclass
class ScenePerson:
    """One associated person of one frame: its views (camera index -> 2D person) and its
    triangulated joints (J, 3) metres, NaN where fewer than two views see the joint."""

    views: dict[int, Person2D]
    joints: np.ndarray

    @property
    def centre(self) -> np.ndarray:
        """(3,) mean of the triangulated joints."""
        return np.nanmean(self.joints, axis=0)


@dataclass
class MultipliedScene:
    """The scene with its copies: people[f][c] per frame and camera (originals first);
    offsets (K, 3) metres, row 0 = the original (zeros); expected: estimated 3D people per
    frame (people seen by >= 2 cameras, all copies included); original: 3D people per frame of
    the scene itself."""

    people: list[list[list[Person2D] | None]]
    offsets: np.ndarray
    expected: float
    original: float


def triangulate(cameras: Sequence[Camera], views: Sequence[dict[int, Person2D]], min_score: float) -> np.ndarray:
    """(P, J, 3): per person (camera index -> 2D person), each joint triangulated from the rays
    of its keypoints scoring above min_score in every view; NaN where fewer than two views do."""
    if not views:
        return np.zeros((0, 0, 3))
    width = max(len(v) for v in views)
    n_j = len(next(iter(views[0].values())).keypoints)
    origins = np.zeros((len(views), n_j, width, 3))
    dirs = np.zeros((len(views), n_j, width, 3))
    seen = np.zeros((len(views), n_j, width), dtype=bool)
    for p, person in enumerate(views):
        for k, (c, view) in enumerate(sorted(person.items())):
            kp = view.keypoints
            ok = (kp[:, 2] > min_score) & np.isfinite(kp[:, :2]).all(axis=1)
            origins[p, :, k] = cameras[c].centre
            dirs[p, ok, k] = cameras[c].directions(kp[ok, :2])
            seen[p, :, k] = ok
    points = closest_point_to_rays(origins, dirs, seen)
    points[seen.sum(axis=-1) < 2] = np.nan
    return points


def _triangulated(config: AssociationConfig | None) -> AssociationConfig:
    """config (or the default) counting only the people two cameras see: a scene's people are
    copied from their triangulated joints."""
    return dataclasses.replace(config or AssociationConfig(), single_view_people=False)


def scene_people(cameras: Sequence[Camera], frames: Sequence[int], people: Sequence[Frame2D],
                 config: AssociationConfig | None = None) -> list[list[ScenePerson]]:
    """Per frame, the associated 3D people of the scene with their triangulated joints (people
    two cameras see: not single_view_people). The association runs on copies of the 2D people, so
    their track ids are left as they were."""
    config = _triangulated(config)
    associator = Associator(cameras, config)
    out = []
    for frame, per_camera in zip(frames, people):
        own = [None if ps is None else [dataclasses.replace(p) for p in ps] for ps in per_camera]
        observations = associator.update(frame / FRAME_RATE, own)
        # map the associated copies back to the caller's Person2D objects
        back = {id(c): o for ps_c, ps_o in zip(own, per_camera) if ps_c is not None for c, o in zip(ps_c, ps_o)}
        views = [{c: back[id(p)] for c, p in obs.views.items()} for obs in observations]
        joints = triangulate(cameras, views, config.matching.min_score)
        out.append([ScenePerson(v, x) for v, x in zip(views, joints)])
    return out


def copy_view(camera: Camera, person: Person2D, joints: np.ndarray, offset: np.ndarray,
              min_inside: float = 0.5) -> Person2D | None:
    """The view `person` (seen by `camera`) of the 3D person `joints` (J, 3) moved by `offset`
    (3,) metres, or None when fewer than max(1, min_inside x its copyable joints) land inside the
    image. Copyable: detected in this view (score > 0) and triangulated."""
    joints = np.asarray(joints, dtype=np.float64)
    offset = np.asarray(offset, dtype=np.float64)
    kp = person.keypoints
    known = np.isfinite(joints).all(axis=1)
    old = camera.project(joints)
    new = camera.project(joints + offset)
    with np.errstate(invalid='ignore'):
        inside = (known & np.isfinite(new).all(axis=1) & np.isfinite(old).all(axis=1)
                  & (new[:, 0] >= 0) & (new[:, 0] < camera.width) & (new[:, 1] >= 0) & (new[:, 1] < camera.height))
    copyable = known & (kp[:, 2] > 0)
    keep = copyable & inside
    if keep.sum() < max(1, math.ceil(min_inside * copyable.sum())):
        return None
    keypoints = np.full_like(kp, np.nan)
    keypoints[:, 2] = 0.0
    keypoints[keep, :2] = new[keep]
    keypoints[keep, 2] = kp[keep, 2]
    hm = person.heatmap
    origin = np.array(hm.origin, dtype=np.float64)
    origin[inside] += new[inside] - old[inside]
    outside = np.repeat(~inside, hm.shape[:, 0] * hm.shape[:, 1])  # per cell
    cells = hm.cells
    if cells[outside].any():
        cells = np.where(outside, cells.dtype.type(0), cells)
    return Person2D(keypoints, PersonHeatmap.from_cells(cells, hm.shape, origin, hm.stride))


def copy_person(cameras: Sequence[Camera], person: ScenePerson, offset: np.ndarray,
                min_inside: float = 0.5) -> dict[int, Person2D]:
    """The views of a person's copy moved by `offset`: camera index -> 2D person, for the
    cameras that saw the original and still see enough of the copy."""
    out = {}
    for c, view in sorted(person.views.items()):
        moved = copy_view(cameras[c], view, person.joints, offset, min_inside)
        if moved is not None:
            out[c] = moved
    return out


def _pair_differences(scene: Sequence[Sequence[ScenePerson]]) -> np.ndarray:
    """(K, 2) every horizontal difference of two people's centres in the same frame (the zero
    vector included), deduplicated to 1 cm."""
    diffs = [np.zeros((1, 2))]
    for people in scene:
        if people:
            c = np.array([p.centre[:2] for p in people])
            c = c[np.isfinite(c).all(axis=1)]
            diffs.append((c[:, None] - c[None]).reshape(-1, 2))
    return np.unique(np.round(np.concatenate(diffs), 2), axis=0)


def _visible_counts(cameras: Sequence[Camera], scene: Sequence[Sequence[ScenePerson]], candidates: np.ndarray,
                    min_inside: float, min_joints: int) -> np.ndarray:
    """(N,) per candidate offset, the mean number of copied people per frame that >= 2 cameras
    still see with at least min_joints joints each (association needs a few shared joints to
    match two views), by copy_view's rule, all candidates and people at once."""
    people = [p for frame in scene for p in frame]
    if not people:
        return np.zeros(len(candidates))
    joints = np.stack([p.joints for p in people])  # (P, J, 3)
    n_views = np.zeros((len(candidates), len(people)), dtype=int)
    known = np.isfinite(joints).all(axis=-1)
    for c, cam in enumerate(cameras):
        has = np.array([c in p.views for p in people])
        if not has.any():
            continue
        score = np.stack([p.views[c].keypoints[:, 2] if c in p.views else np.zeros(joints.shape[1]) for p in people])
        copyable = known & (score > 0) & has[:, None]  # (P, J)
        old_ok = np.isfinite(cam.project(joints)).all(axis=-1)
        need = np.maximum(min_joints, np.ceil(min_inside * copyable.sum(axis=-1)))  # (P,)
        for lo in range(0, len(candidates), 64):  # (64, P, J, 2) pixels at a time
            new = cam.project(joints[None] + candidates[lo:lo + 64, None, None])
            with np.errstate(invalid='ignore'):
                inside = (np.isfinite(new).all(axis=-1) & (new[..., 0] >= 0) & (new[..., 0] < cam.width)
                          & (new[..., 1] >= 0) & (new[..., 1] < cam.height) & old_ok)
            n_views[lo:lo + 64] += has & ((inside & copyable).sum(axis=-1) >= need)
    return (n_views >= 2).sum(axis=1) / len(scene)


def _associated_count(cameras: Sequence[Camera], frames: Sequence[Sequence[list[Person2D]]],
                      config: AssociationConfig) -> float:
    """Mean number of 3D people per frame that association finds in `frames` (per camera lists)."""
    associator = Associator(cameras, config)
    found = sum(len(associator.update(f / FRAME_RATE, [[dataclasses.replace(p) for p in ps] for ps in frame]))
                for f, frame in enumerate(frames))
    return found / max(len(frames), 1)


def choose_offsets(cameras: Sequence[Camera], scene: Sequence[Sequence[ScenePerson]], target: float,
                   config: AssociationConfig | None = None, *, step: float = 0.5, extent: float = 7.5,
                   clearance: float = 0.6, min_inside: float = 0.5, sample_every: int = 5,
                   min_seen: float = 0.05, min_joints: int = 4) -> tuple[np.ndarray, float]:
    """Offsets (K, 3) (row 0 = zeros, the scene itself) and the expected 3D people per frame.

    Candidates: a grid of `step` m over [-extent, extent]^2 in the floor plane (z = 0), ordered
    by how many copied people >= 2 cameras would still see with min_joints joints each, then by
    distance. A candidate is taken if every copied person keeps `clearance` m (horizontally,
    centre to centre: side by side in a crowd) from every person already placed, in every frame;
    the 3D people per frame are then measured by associating the scene with every copy taken so
    far on every `sample_every`-th frame (crowds confuse cross-view matching a little, so copies
    do not add exactly their own count), and candidates are added until that is closest to
    `target`.
    Candidates adding fewer than min_seen x the scene's people per frame are not used.
    """
    config = _triangulated(config)
    original = sum(len(f) for f in scene) / max(len(scene), 1)
    if target <= original or original == 0:
        return np.zeros((1, 3)), original
    offsets = [np.zeros(3)]
    axis = np.arange(-extent, extent + step / 2, step)
    grid = np.array([(x, y, 0.0) for x in axis for y in axis])
    grid = grid[np.linalg.norm(grid[:, :2], axis=1) >= clearance]
    sampled = scene[::sample_every]
    totals = [sum(len(f) for f in sampled) / len(sampled)]
    counts = _visible_counts(cameras, sampled, grid, min_inside, min_joints)
    order = np.lexsort((np.linalg.norm(grid, axis=1), -np.round(counts, 3)))
    diffs = _pair_differences(scene)
    # the sampled frames as association sees them: every person seen, then the copies taken
    views = [[[] for _ in cameras] for _ in sampled]
    for frame, persons in zip(views, sampled):
        for person in persons:
            for c, view in person.views.items():
                frame[c].append(view)
    for i in order:
        if counts[i] < min_seen * original:
            break
        d = grid[i]
        if any(np.min(np.linalg.norm(diffs - (d - e)[:2], axis=1)) < clearance for e in offsets):
            continue
        trial = [[list(ps) for ps in frame] for frame in views]
        for frame, persons in zip(trial, sampled):
            for person in persons:
                for c, view in copy_person(cameras, person, d, min_inside).items():
                    frame[c].append(view)
        found = _associated_count(cameras, trial, config)
        if found - totals[-1] < min_seen * original:
            continue
        offsets.append(d)
        totals.append(found)
        views = trial
        if found >= target:
            break
    if len(totals) > 1 and abs(totals[-2] - target) < abs(totals[-1] - target):
        offsets.pop()
        totals.pop()
    return np.array(offsets), totals[-1]


def multiply_scene(cameras: Sequence[Camera], frames: Sequence[int], people: Sequence[Frame2D], target: float, *,
                   config: AssociationConfig | None = None, offsets: np.ndarray | None = None,
                   min_inside: float = 0.5, **choose) -> MultipliedScene:
    """The scene with enough shifted copies for about `target` 3D people per frame (or with the
    given `offsets`, row 0 zeros). Originals are kept as they are (every detection, associated
    or not); copies are made of the associated people. choose: choose_offsets' keywords."""
    scene = scene_people(cameras, frames, people, config)
    original = sum(len(f) for f in scene) / max(len(scene), 1)
    if offsets is None:
        offsets, expected = choose_offsets(cameras, scene, target, config, min_inside=min_inside, **choose)
    else:
        offsets, expected = np.asarray(offsets, dtype=np.float64).reshape(-1, 3), float('nan')
    out = []
    for per_camera, persons in zip(people, scene):
        frame = [None if ps is None else list(ps) for ps in per_camera]
        for d in offsets:
            if not np.any(d):
                continue
            for person in persons:
                for c, view in copy_person(cameras, person, d, min_inside).items():
                    if frame[c] is not None:
                        frame[c].append(view)
        out.append(frame)
    return MultipliedScene(out, offsets, expected, original)
