"""A synthetic rig of any number of cameras around Shelf's annotated actors, for the 3D stage.

The shared data has rigs of 5 (Shelf) and 3 (Campus) cameras only; a user's studio may have a
dozen or thirty. `ring_sequence` puts n cameras on a circle around the actors of Shelf's test
frames, alternately at two heights, each looking at their centre, and gives them the annotated
joints projected with Gaussian pixel noise, and in a share of the views one joint thrown off (a
detector's wrong keypoint). Like Campus without its folder this is an oracle: it checks how
sampling, inference and scoring scale with the cameras, not detection. An actor exists only where
Shelf annotates him, so he leaves the scene in its gaps (actor 3 for 72 and 67 frames, actor 2 for
37) and comes back as a new person: the id switches reported there are the oracle's.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from mvpose_ros.core.datasets.shelf_campus import SHELF_TEST_FRAMES, GroundTruth, dataset_dir, load_actors_gt
from mvpose_ros.core.defaults import FRAME_RATE
from mvpose_ros.core.drawing.video import look_at
from mvpose_ros.core.geometry.body import NUM_INFERENCE_JOINTS, NUM_JOINTS, UP
from mvpose_ros.core.geometry.camera import Camera
from mvpose_ros.core.types import Person2D, Sequence2D

HEAD_MODEL = 'direct'  # the projected joints 12 and 13 are the annotated bottom and top of the head
STRIDE, SIGMA = 4.0, 6.0  # px: heatmap cells and the Gaussian of each keypoint
WALK_RADIUS = 1.0  # m: the circle a walking scene goes round, well inside the default ring's views


@dataclass(frozen=True)
class RingConfig:
    """cameras: how many; radius: metres from the actors' centre, horizontally; heights: metres
    above it, camera after camera in turn; width, height, fov_deg: every camera's image and
    horizontal field of view; noise_px: std of every keypoint's pixel noise; outlier_share: the
    share of views in which one joint, picked at random, is moved by outlier_px (std, per axis);
    miss_share: the share of keypoints a view misses, each on its own (a detector's misses, so that
    with few cameras some joints are seen by one camera or none); walk_speed: m/s at which the
    whole scene walks round a horizontal circle of WALK_RADIUS (its annotation with it), so that
    people cross the views faster than Shelf's actors; seed: of the noise."""

    cameras: int = 8
    radius: float = 5.0
    heights: tuple[float, ...] = (1.0, 1.5)
    width: int = 1032
    height: int = 776
    fov_deg: float = 60.0
    noise_px: float = 3.0
    outlier_share: float = 0.2
    outlier_px: float = 60.0
    miss_share: float = 0.0
    walk_speed: float = 0.0
    seed: int = 0

    def __post_init__(self) -> None:
        if self.cameras < 2:
            raise ValueError(f'a ring needs at least 2 cameras, got {self.cameras}')
        if not (self.radius > 0 and self.heights and self.noise_px >= 0 and 0 <= self.outlier_share <= 1
                and 0 <= self.miss_share < 1 and self.walk_speed >= 0):
            raise ValueError('radius must be > 0, heights not empty, noise_px >= 0, outlier_share in [0, 1], '
                             'miss_share in [0, 1) and walk_speed >= 0')


def ring_cameras(centre: np.ndarray, config: RingConfig) -> list[Camera]:
    """config.cameras cameras evenly spaced on the circle around centre (3,), looking at it."""
    cameras = []
    for c in range(config.cameras):
        angle = 2 * np.pi * c / config.cameras
        eye = centre + [config.radius * np.cos(angle), config.radius * np.sin(angle),
                        config.heights[c % len(config.heights)]]
        cameras.append(look_at(eye, centre, UP, config.width, config.height, config.fov_deg, name=f'ring{c}'))
    return cameras


def ring_sequence(root: str | None, config: RingConfig) -> tuple[Sequence2D, GroundTruth, str]:
    """The Shelf test frames seen by the ring: the sequence, its ground truth (Shelf's) and the
    head model its keypoints need."""
    gt = load_actors_gt(dataset_dir('shelf', root) / 'actorsGT.mat', SHELF_TEST_FRAMES)
    centre = np.nanmean(gt.poses.reshape(-1, 3), axis=0)
    if config.walk_speed:
        gt = GroundTruth(gt.frames, gt.poses + walked(gt.frames, config.walk_speed)[:, None, None])
    cameras = ring_cameras(centre, config)
    rng = np.random.default_rng(config.seed)
    people = [[_seen(camera, poses, config, rng) for camera in cameras] for poses in gt.poses]
    return Sequence2D(cameras, [int(f) for f in gt.frames], people), gt, HEAD_MODEL


def walked(frames: np.ndarray, speed: float) -> np.ndarray:
    """(F, 3) metres: where a scene walking round a horizontal circle of WALK_RADIUS at `speed` m/s
    has gone at each frame (Shelf's FRAME_RATE), from where it was at the first."""
    angle = speed / WALK_RADIUS * (np.asarray(frames) - frames[0]) / FRAME_RATE
    return WALK_RADIUS * np.stack([np.cos(angle) - 1.0, np.sin(angle), np.zeros_like(angle)], axis=-1)


def _seen(camera: Camera, poses: np.ndarray, config: RingConfig, rng: np.random.Generator) -> list[Person2D]:
    """The present actors of poses (A, 14, 3) as camera's 2D people: projected, noisy, in view."""
    people = []
    for pose in poses[np.isfinite(poses).all(axis=(1, 2))]:
        uv = camera.project(pose) + rng.normal(0.0, config.noise_px, (NUM_JOINTS, 2))
        if rng.random() < config.outlier_share:
            uv[rng.integers(NUM_JOINTS)] += rng.normal(0.0, config.outlier_px, 2)
        inside = (uv >= 0).all(axis=1) & (uv[:, 0] < camera.width) & (uv[:, 1] < camera.height)
        if config.miss_share:
            inside &= rng.random(NUM_JOINTS) >= config.miss_share
        if inside.sum() < 4:
            continue
        keypoints = np.zeros((NUM_INFERENCE_JOINTS, 3))
        keypoints[:NUM_JOINTS, :2] = uv
        keypoints[:NUM_JOINTS, 2] = inside
        people.append(Person2D.from_keypoints(keypoints, STRIDE, SIGMA))
    return people
