"""Offline runs of the 3D stage over a recorded sequence, as the evaluator and benchmarks use it.

The expensive front half (2D people, association, hypotheses, data term) is computed once by
`prepare`; `infer` then runs BP over it with any set of terms, window and lag, so an ablation
costs only the BP part again.
"""
from __future__ import annotations

import time
from dataclasses import dataclass, field, replace
from typing import Sequence

import numpy as np

from mvpose_ros.core.geometry.body import BONES, SYMMETRIC_PAIRS, finalize_head
from mvpose_ros.core.geometry.camera import Camera, load_rig
from mvpose_ros.core.evaluation.datasets import SHELF_TEST_FRAMES, dataset_dir
from mvpose_ros.core.detection.openpose import read_body25
from mvpose_ros.core.detection.openpose_detector import OpenPoseDetectorConfig, detect_people
from mvpose_ros.core.person2d import Person2D
from mvpose_ros.core.inference.solver import StageConfig, person_frames
from mvpose_ros.core.timing import StageTimer
from mvpose_ros.core.association.associator import Associator
from mvpose_ros.core.inference.window import FrameResult, InferenceConfig, PersonFrame, SlidingWindow


@dataclass
class Sequence2D:
    """Per frame, per camera, the 2D people (None where a camera has no data)."""

    cameras: list[Camera]
    frames: list[int]
    people: list[list[list[Person2D] | None]]
    seconds: dict[str, float] = field(default_factory=dict)


@dataclass
class Prepared:
    """Association and hypotheses of every frame, ready for BP."""

    frames: list[int]
    person_frames: list[list[PersonFrame]]
    timer: StageTimer


def shelf_openpose(root: str | None, detector: OpenPoseDetectorConfig,
                   frames: Sequence[int] = SHELF_TEST_FRAMES) -> Sequence2D:
    """The Shelf test frames' 2D people from the shared OpenPose BODY25 output."""
    shelf = dataset_dir('shelf', root)
    cameras = load_rig(shelf / 'calibration' / 'calibration_shelf.json')
    raw = [read_body25(shelf / 'openpose_body25' / f'{c}.txt', cam.width, cam.height)
           for c, cam in enumerate(cameras)]
    first = SHELF_TEST_FRAMES.start
    t0 = time.perf_counter()
    people = [[detect_people(raw[c][f - first], detector) for c in range(len(cameras))] for f in frames]
    return Sequence2D(cameras, list(frames), people, {'grouping and heatmaps': time.perf_counter() - t0})


def prepare(seq: Sequence2D, config: StageConfig) -> Prepared:
    """Association, hypotheses and data term of every frame, in order."""
    associator = Associator(seq.cameras, config.association)
    timer = StageTimer()
    out = []
    for frame, people in zip(seq.frames, seq.people):
        t0 = time.perf_counter()
        observations = associator.update(frame, people)
        timer.add('association', t0)
        out.append(person_frames(seq.cameras, [(obs.person_id, obs.views) for obs in observations], frame,
                                 config, timer))
    return Prepared(list(seq.frames), out, timer)


def infer(prepared: Prepared, inference: InferenceConfig, head_model: str,
          timer: StageTimer | None = None) -> list[FrameResult]:
    """Decoded frames (one per prepared frame, in order); timer gets 'factors', 'bp' and 'decoding'."""
    timer = timer or StageTimer()
    window = SlidingWindow(inference, np.array(SYMMETRIC_PAIRS), np.array(BONES), timer)
    results = []
    for frame, people in zip(prepared.frames, prepared.person_frames):
        results += window.push(frame, people)
    results += window.flush()
    t0 = time.perf_counter()
    out = [replace(r, joints=finalize_head(r.joints, head_model)) for r in results]
    timer.add('decoding', t0)
    return out


def as_predictions(results: Sequence[FrameResult]) -> dict[int, np.ndarray]:
    """Frame -> (P, 14, 3), the form evaluation.evaluate takes."""
    return {r.frame: r.joints for r in results}

