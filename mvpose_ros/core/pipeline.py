"""The solver half of the 3D stage: from associated people (an id and its views) to decoded
3D skeletons: hypothesis sampling with the data term, sliding-window BP and the head model, with
the time each step takes. The bp_solver node runs it; the offline evaluator calls the same
person_frame and window (core.offline), after core.association.
"""
from __future__ import annotations

import time
from collections import defaultdict
from dataclasses import dataclass, field
from typing import Sequence

import numpy as np

from mvpose_ros.core.association import AssociationConfig
from mvpose_ros.core.body import BONES, SYMMETRIC_PAIRS, finalize_head
from mvpose_ros.core.camera import Camera
from mvpose_ros.core.factors import data_term
from mvpose_ros.core.hypotheses import SamplingConfig, sample_hypotheses
from mvpose_ros.core.person2d import Person2D
from mvpose_ros.core.window import FrameResult, InferenceConfig, PersonFrame, SlidingWindow


@dataclass(frozen=True)
class StageConfig:
    """Everything the 3D stage needs; head_model must match the one the 2D side used."""

    association: AssociationConfig = field(default_factory=AssociationConfig)
    sampling: SamplingConfig = field(default_factory=SamplingConfig)
    inference: InferenceConfig = field(default_factory=InferenceConfig)
    head_model: str = 'anatomical'
    seed: int = 0


class StageTimer:
    """Accumulated wall time per named step, in seconds."""

    def __init__(self) -> None:
        self.seconds: dict[str, float] = defaultdict(float)

    def add(self, name: str, since: float) -> float:
        now = time.perf_counter()
        self.seconds[name] += now - since
        return now


def person_frame(cameras: Sequence[Camera], person_id: int, views: dict[int, Person2D], frame: int,
                 config: StageConfig, timer: StageTimer | None = None) -> PersonFrame | None:
    """Hypotheses and data term of one person seen by `views` (camera index -> 2D person); None
    when no joint is seen twice.

    The generator is seeded by (seed, frame, person id), so the same frame gives the same
    hypotheses whatever the window, the order of processing or the process doing it.
    """
    t0 = time.perf_counter()
    pairs = [(cameras[c], p.heatmap) for c, p in sorted(views.items())]
    rng = np.random.default_rng([config.seed, frame, person_id])
    hyp = sample_hypotheses(pairs, rng, config.sampling)
    if timer:
        t0 = timer.add('sampling', t0)
    if hyp is None:
        return None
    data = data_term(hyp, pairs)
    if timer:
        timer.add('data term', t0)
    return PersonFrame(person_id, hyp, data)


class Inference3D:
    """From associated people (id and views) of each frame to decoded 3D skeletons: sampling,
    data term, sliding-window BP and the head model. The bp_solver node runs this."""

    def __init__(self, cameras: Sequence[Camera], config: StageConfig) -> None:
        self.cameras = list(cameras)
        self.config = config
        self.window = SlidingWindow(config.inference, np.array(SYMMETRIC_PAIRS), np.array(BONES))
        self.timer = StageTimer()

    def push(self, frame: int, people: Sequence[tuple[int, dict[int, Person2D]]]) -> list[FrameResult]:
        """people: (person id, camera index -> 2D person) of this frame; returns the frames due."""
        frames = [pf for pid, views in people
                  if (pf := person_frame(self.cameras, pid, views, frame, self.config, self.timer)) is not None]
        t0 = time.perf_counter()
        out = self.window.push(frame, frames)
        self.timer.add('bp', t0)
        return [self._finish(r) for r in out]

    def flush(self) -> list[FrameResult]:
        t0 = time.perf_counter()
        out = self.window.flush()
        self.timer.add('bp', t0)
        return [self._finish(r) for r in out]

    def _finish(self, result: FrameResult) -> FrameResult:
        return FrameResult(result.frame, result.person_ids, finalize_head(result.joints, self.config.head_model))
