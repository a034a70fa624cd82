"""The offline evaluator's clips: ground truth cut to the frames a drop leaves, and the datasets it knows."""
from __future__ import annotations

import numpy as np
import pytest

from mvpose_ros.core.datasets.shelf_campus import GroundTruth
from mvpose_ros.core.detection.openpose_detector import OpenPoseDetectorConfig
from mvpose_ros.core.evaluation.clips import Clip, load_clip, restricted, thinned
from mvpose_ros.core.scenarios.frame_drops import FrameDrop
from mvpose_ros.core.types import Sequence2D


def _gt(frames) -> GroundTruth:
    frames = np.asarray(frames)
    return GroundTruth(frames, np.arange(frames.size, dtype=float)[:, None, None, None] * np.ones((1, 2, 14, 3)))


def test_restricted_keeps_the_rows_of_the_frames_asked_for():
    gt = restricted(_gt([10, 11, 12, 13]), [11, 13])
    assert gt.frames.tolist() == [11, 13] and gt.poses[:, 0, 0, 0].tolist() == [1.0, 3.0]
    with pytest.raises(ValueError, match='not all in the ground truth'):
        restricted(_gt([10, 12]), [11])


def test_a_thinned_clip_scores_only_the_frames_left():
    frames = list(range(100, 110))
    clip = Clip(Sequence2D([], frames, [[] for _ in frames]), _gt(frames), (0, 1))
    thin = thinned(clip, FrameDrop(every=2))
    assert thin.seq.frames == thin.gt.frames.tolist() and len(thin.seq.frames) == 5
    assert thin.actors == clip.actors


def test_an_unknown_dataset_is_refused():
    with pytest.raises(ValueError, match='shelf, campus, ring'):
        load_clip('panoptic', None, OpenPoseDetectorConfig())
