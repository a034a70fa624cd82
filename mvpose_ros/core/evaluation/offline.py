"""Offline runs of the 3D stage over a recorded sequence, as the evaluator and benchmarks use it.

The expensive front half (2D people, association, hypotheses, data term) is computed once by
`prepare`; `infer` then runs BP over it with any set of terms, window and lag, so an ablation
costs only the BP part again. Frame f is taken at f / FRAME_RATE seconds (the datasets' own
timeline), so a sequence with frames left out (`drop_frames`, as a graph dropping sets under load
would) has uneven gaps that the temporal term bridges with the real times.
"""
from __future__ import annotations

import time
from dataclasses import dataclass, replace
from typing import Sequence

import numpy as np

from mvpose_ros.core.datasets.shelf_campus import SHELF_TEST_FRAMES, dataset_dir, shelf_cameras
from mvpose_ros.core.defaults import FRAME_RATE
from mvpose_ros.core.detection.openpose import OpenPoseFrame, read_body25
from mvpose_ros.core.detection.openpose_detector import OpenPoseDetectorConfig, detect_people
from mvpose_ros.core.geometry.body import LIMB_BONES, LIMB_LENGTHS, SYMMETRIC_PAIRS, finalize_confidence, finalize_head
from mvpose_ros.core.geometry.camera import Camera
from mvpose_ros.core.inference.solver import frame_centres, person_frames
from mvpose_ros.core.inference.window import InferenceConfig, SlidingWindow
from mvpose_ros.core.scenarios.frame_drops import FrameDrop
from mvpose_ros.core.stage import Stage3D, StageConfig
from mvpose_ros.core.timing import StageTimer
from mvpose_ros.core.types import FrameResult, PersonFrame, Sequence2D


@dataclass
class Prepared:
    """Association and hypotheses of every frame, ready for BP."""

    frames: list[int]
    person_frames: list[list[PersonFrame]]
    timer: StageTimer


GROUPING = 'grouping and heatmaps'  # the step that turns OpenPose output into 2D people


def shelf_openpose_raw(root: str | None,
                       n_cameras: int | None = None) -> tuple[list[Camera], list[list[OpenPoseFrame]]]:
    """The first n_cameras Shelf cameras (all when None) and, per camera, the OpenPose BODY25
    output of every test frame (SHELF_TEST_FRAMES order)."""
    cameras = shelf_cameras(root)[:n_cameras]
    openpose = dataset_dir('shelf', root) / 'openpose_body25'
    return cameras, [read_body25(openpose / f'{c}.txt', cam.width, cam.height) for c, cam in enumerate(cameras)]


def detect_sequence(cameras: Sequence[Camera], raw: Sequence[Sequence[OpenPoseFrame]], frames: Sequence[int],
                    detector: OpenPoseDetectorConfig) -> Sequence2D:
    """The 2D people of `frames` (Shelf test frame numbers) from raw[c], camera c's OpenPose
    output of every test frame; seconds[GROUPING] is the time of grouping alone."""
    first = SHELF_TEST_FRAMES.start
    t0 = time.perf_counter()
    people = [[detect_people(raw[c][f - first], detector) for c in range(len(cameras))] for f in frames]
    return Sequence2D(list(cameras), list(frames), people, {GROUPING: time.perf_counter() - t0})


def shelf_openpose(root: str | None, detector: OpenPoseDetectorConfig, frames: Sequence[int] = SHELF_TEST_FRAMES,
                   n_cameras: int | None = None) -> Sequence2D:
    """The Shelf test frames' 2D people from the shared OpenPose BODY25 output, of the first
    n_cameras cameras (all when None)."""
    cameras, raw = shelf_openpose_raw(root, n_cameras)
    return detect_sequence(cameras, raw, frames, detector)


def drop_frames(seq: Sequence2D, drop: FrameDrop) -> Sequence2D:
    """seq without the frames `drop` leaves out."""
    keep = drop.kept(len(seq.frames))
    return replace(seq, frames=[seq.frames[k] for k in keep], people=[seq.people[k] for k in keep])


def prepare(seq: Sequence2D, config: StageConfig) -> Prepared:
    """Association, hypotheses and data term of every frame, in order."""
    stage = Stage3D(seq.cameras, config)
    out: list[list[PersonFrame]] = []
    for frame, people in zip(seq.frames, seq.people):
        out.append(person_frames(seq.cameras, stage.associate(frame, people), frame, config.solver, stage.timer,
                                 stage.solver.up, frame_centres(out[-1]) if out else None))
    return Prepared(list(seq.frames), out, stage.timer)


def infer(prepared: Prepared, inference: InferenceConfig, head_model: str,
          timer: StageTimer | None = None, real_time: bool = True) -> list[FrameResult]:
    """Decoded frames (one per prepared frame, in order); timer gets 'factors', 'bp' and 'decoding'.
    Frame f is at f / FRAME_RATE s; real_time False takes the k-th prepared frame to be at
    k / FRAME_RATE s instead (evenly spaced whatever was dropped: what a solver blind to the real
    times would assume)."""
    timer = timer or StageTimer()
    window = SlidingWindow(inference, np.array(SYMMETRIC_PAIRS), LIMB_BONES, LIMB_LENGTHS, timer)
    results = []
    for k, (frame, people) in enumerate(zip(prepared.frames, prepared.person_frames)):
        results += window.push(frame, people, (frame if real_time else k) / FRAME_RATE)
    results += window.flush()
    t0 = time.perf_counter()
    out = [replace(r, joints=finalize_head(r.joints, head_model),
                   confidence=finalize_confidence(r.confidence, head_model)) for r in results]
    timer.add('decoding', t0)
    return out


def as_predictions(results: Sequence[FrameResult]) -> dict[int, np.ndarray]:
    """Frame -> (P, 14, 3), the form evaluation.evaluate takes."""
    return {r.frame: r.joints for r in results}
