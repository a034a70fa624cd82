"""The solver half of the 3D stage: from associated people (an id and its views) to decoded
3D skeletons: hypothesis sampling with the data term, sliding-window BP and the head model, with
the time each step takes. The bp_solver node runs it (through core.stage); the offline evaluator
calls the same person_frames and window (core.evaluation.offline).
"""
from __future__ import annotations

import time
from dataclasses import dataclass, field
from typing import Mapping, Sequence

import numpy as np

from mvpose_ros.core.geometry.body import (HEAD_MODELS, LIMB_BONES, LIMB_LENGTHS, SYMMETRIC_PAIRS, UP,
                                           finalize_confidence, finalize_head)
from mvpose_ros.core.geometry.camera import Camera
from mvpose_ros.core.inference.confidence import joint_support
from mvpose_ros.core.inference.factors import data_terms
from mvpose_ros.core.heatmap import HeatmapStack
from mvpose_ros.core.inference.hypotheses import SamplingConfig, sample_people
from mvpose_ros.core.types import Bundle, FrameResult, PersonFrame
from mvpose_ros.core.timing import StageTimer
from mvpose_ros.core.inference.window import InferenceConfig, SlidingWindow


@dataclass(frozen=True)
class SolverConfig:
    """Everything the solver needs; head_model must match the one the 2D side used."""

    sampling: SamplingConfig = field(default_factory=SamplingConfig)
    inference: InferenceConfig = field(default_factory=InferenceConfig)
    head_model: str = 'anatomical'
    seed: int = 0

    def __post_init__(self) -> None:
        if self.head_model not in HEAD_MODELS:
            raise ValueError(f'head_model {self.head_model!r} is not one of {", ".join(HEAD_MODELS)}')


def person_frames(cameras: Sequence[Camera], people: Sequence[Bundle], frame: int,
                  config: SolverConfig, timer: StageTimer | None = None, up: np.ndarray = UP,
                  before: Mapping[int, np.ndarray] | None = None) -> list[PersonFrame]:
    """Hypotheses and data term of each person of a frame (person id, camera index -> 2D
    person), all people batched; a person none of whose joints is seen twice is placed from his
    centre in the frame before (before: person id -> (3,) metres, frame_centres of that frame's
    person frames), and left out when he was not in it. up: (3,) the world's up (sampling's
    hanging legs).

    Each person's generator is seeded by (seed, frame, person id), so the same frame gives the
    same hypotheses whatever the window, the order of processing, the other people or the
    process doing it.
    """
    t0 = time.perf_counter()
    views = [[(cameras[c], p.heatmap) for c, p in sorted(v.items())] for _, v in people]
    stack = HeatmapStack.of([hm for person in views for _, hm in person])
    rngs = [np.random.default_rng([config.seed, frame, pid]) for pid, _ in people]
    centres = np.array([before[pid] if before and pid in before else np.full(3, np.nan) for pid, _ in people])
    hyps = sample_people(views, stack, rngs, config.sampling, up, centres.reshape(-1, 3))
    if timer:
        t0 = timer.add('sampling', t0)
    kept = [p for p, h in enumerate(hyps) if h is not None]
    data = data_terms([hyps[p] for p in kept], [views[p] for p in kept],
                      HeatmapStack.of([hm for p in kept for _, hm in views[p]]) if len(kept) < len(people) else stack)
    if timer:
        timer.add('data term', t0)
    support = [joint_support([v.keypoints[:, 2] for v in people[p][1].values()], len(cameras)) for p in kept]
    return [PersonFrame(people[p][0], hyps[p], d, s) for p, d, s in zip(kept, data, support)]


def frame_centres(frames: Sequence[PersonFrame]) -> dict[int, np.ndarray]:
    """Person id -> (3,) the mean of his hypotheses, metres: where person_frames places him in the
    next frame if one camera alone sees him there."""
    return {f.person_id: f.hypotheses.reshape(-1, 3).mean(axis=0) for f in frames}


class Inference3D:
    """From associated people (id and views) of each frame to decoded 3D skeletons: sampling,
    data term, sliding-window BP and the head model. The bp_solver node runs this."""

    def __init__(self, cameras: Sequence[Camera], config: SolverConfig, up: np.ndarray = UP) -> None:
        """up (3,): the world's up, a unit vector (the rig's; the head model's and the hanging legs'
        gravity)."""
        self.cameras = list(cameras)
        self.config = config
        self.up = np.asarray(up, dtype=np.float64)
        self.timer = StageTimer()
        self.window = SlidingWindow(config.inference, np.array(SYMMETRIC_PAIRS), LIMB_BONES, LIMB_LENGTHS, self.timer)
        self._centres: dict[int, np.ndarray] = {}  # of the frame before (person_frames)

    def push(self, frame: int, people: Sequence[Bundle], time_s: float | None = None) -> list[FrameResult]:
        """people: (person id, camera index -> 2D person) of this frame, taken at time_s seconds
        (None: frame / the nominal frame rate; see window.SlidingWindow.push); returns the frames due."""
        frames = person_frames(self.cameras, people, frame, self.config, self.timer, self.up, self._centres)
        self._centres = frame_centres(frames)
        return [self._finish(r) for r in self.window.push(frame, frames, time_s)]

    def live(self) -> FrameResult | None:
        """The newest frame pushed, decoded from it and the frames before it only (no lag; see
        window.SlidingWindow.live)."""
        result = self.window.live()
        return None if result is None else self._finish(result)

    def flush(self) -> list[FrameResult]:
        """Every frame not yet output (end of stream)."""
        return [self._finish(r) for r in self.window.flush()]

    def _finish(self, result: FrameResult) -> FrameResult:
        t0 = time.perf_counter()
        head = self.config.head_model
        out = FrameResult(result.frame, result.person_ids, finalize_head(result.joints, head, self.up),
                          finalize_confidence(result.confidence, head))
        self.timer.add('decoding', t0)
        return out
