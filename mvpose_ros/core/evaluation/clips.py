"""The clips the offline evaluator scores, each with its ground truth: Shelf's test frames from
its OpenPose output, Campus (its detections, or its annotation projected: an oracle), and the
synthetic ring of cameras around Shelf's actors; and a clip with frames dropped upstream."""
from __future__ import annotations

from dataclasses import dataclass, replace
from pathlib import Path
from typing import Mapping, Sequence

import numpy as np

from mvpose_ros.core.datasets.campus import campus_sequence
from mvpose_ros.core.datasets.shelf_campus import (CAMPUS_ACTORS, SHELF_ACTORS, SHELF_TEST_FRAMES, GroundTruth,
                                                   dataset_dir, load_actors_gt)
from mvpose_ros.core.detection.openpose_detector import OpenPoseDetectorConfig
from mvpose_ros.core.evaluation.offline import drop_frames, shelf_openpose
from mvpose_ros.core.evaluation.pcp import PAPER_SHELF_PCP
from mvpose_ros.core.scenarios.frame_drops import FrameDrop
from mvpose_ros.core.scenarios.ring import RingConfig, ring_sequence
from mvpose_ros.core.types import Sequence2D

DATASETS = ('shelf', 'campus', 'ring')


@dataclass(frozen=True)
class Clip:
    """A clip to score. seq: its 2D people; gt: the ground truth of its frames; actors: those
    scored; reference: the paper's PCP table printed beside (None: none); head_model: the one its
    2D people need (None: the configured one); note: what the clip is when it is not real
    detections ('' for none)."""

    seq: Sequence2D
    gt: GroundTruth
    actors: Sequence[int]
    reference: Mapping[str, Mapping[str, float]] | None = None
    head_model: str | None = None
    note: str = ''


def shelf_ground_truth(root: str | None) -> GroundTruth:
    """Shelf's annotation of its test frames."""
    return load_actors_gt(dataset_dir('shelf', root) / 'actorsGT.mat', SHELF_TEST_FRAMES)


def load_clip(dataset: str, root: str | None, detector: OpenPoseDetectorConfig, campus_dir: Path | None = None,
              ring: RingConfig | None = None) -> Clip:
    """The clip of `dataset` (one of DATASETS): Shelf through `detector`, Campus from `campus_dir`
    (None: the oracle), the ring of `ring` (None: RingConfig's defaults)."""
    if dataset == 'shelf':
        return Clip(shelf_openpose(root, detector), shelf_ground_truth(root), SHELF_ACTORS, PAPER_SHELF_PCP)
    if dataset == 'campus':
        seq, gt, head_model = campus_sequence(root, campus_dir)
        note = ('' if campus_dir is not None else
                'campus: no CampusSeq1 folder given; 2D people are the 3 ground-truth frames projected into '
                'the cameras (an oracle: checks geometry, inference and scoring, not detection)')
        return Clip(seq, gt, CAMPUS_ACTORS, head_model=head_model, note=note)
    if dataset != 'ring':
        raise ValueError(f'dataset must be one of {", ".join(DATASETS)}, got {dataset!r}')
    ring = ring or RingConfig()
    seq, gt, head_model = ring_sequence(root, ring)
    heights = ', '.join(f'{h:g}' for h in ring.heights)
    note = (f'ring: {ring.cameras} synthetic cameras {ring.radius:g} m around the actors of the Shelf test frames '
            f'({heights} m above their centre, {ring.fov_deg:g} degrees), the annotated '
            f'joints projected with {ring.noise_px:g} px of noise and one of them {ring.outlier_px:g} px off in '
            f'{100 * ring.outlier_share:g} % of the views, {100 * ring.miss_share:g} % of the keypoints missed, '
            f'walking at {ring.walk_speed:g} m/s '
            f'(an oracle: checks how the 3D stage scales with cameras, not detection)')
    return Clip(seq, gt, SHELF_ACTORS, head_model=head_model, note=note)


def thinned(clip: Clip, drop: FrameDrop) -> Clip:
    """The clip without the frames `drop` leaves out, its ground truth with them."""
    seq = drop_frames(clip.seq, drop)
    return replace(clip, seq=seq, gt=restricted(clip.gt, seq.frames))


def restricted(gt: GroundTruth, frames: Sequence[int]) -> GroundTruth:
    """The ground truth of `frames` only (a subset of gt.frames)."""
    rows = np.searchsorted(gt.frames, frames)
    if not np.array_equal(gt.frames[rows], frames):
        raise ValueError('frames to score are not all in the ground truth')
    return replace(gt, frames=gt.frames[rows], poses=gt.poses[rows])
