"""The data that passes between the stages of the 3D pipeline, defined once.

Detection produces `Person2D`s per camera (a `Sequence2D` over a recording); association groups
them into people with stable ids; inference turns each person of a frame into a `PersonFrame`
(hypotheses and data term) and decodes `FrameResult`s. Every array is in pixels (2D) or metres
(3D), world frame.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import Protocol

import numpy as np

from mvpose_ros.core.geometry.camera import Camera
from mvpose_ros.core.heatmap import PersonHeatmap, render_heatmap


class Keypoints2D(Protocol):
    """What association needs of a 2D person: keypoints (16, 3) u, v pixels, score (as Person2D's)
    and a per-camera track_id it sets. A Person2D is one; the association node passes people whose
    heatmaps stay in the messages they came in, as association never looks at them."""

    keypoints: np.ndarray
    track_id: int


@dataclass
class Person2D:
    """A person detected in one camera image.

    keypoints: (16, 3) u, v pixels, score of the inference joints (body.INFERENCE_NAMES); a joint
    with score 0 was not detected (its u, v are NaN when it comes from body.to_inference).
    heatmap: the 16 joint maps the 3D stage samples. track_id: per-camera identity set by the
    tracker (-1 = none yet).
    """

    keypoints: np.ndarray
    heatmap: PersonHeatmap
    track_id: int = -1

    def bbox(self) -> np.ndarray:
        """(4,) u_min, v_min, u_max, v_max over the detected keypoints; NaN when none is."""
        detected = self.keypoints[self.keypoints[:, 2] > 0, :2]
        if len(detected) == 0:
            return np.full(4, np.nan)
        return np.concatenate([detected.min(axis=0), detected.max(axis=0)])

    @classmethod
    def from_keypoints(cls, keypoints: np.ndarray, stride: float, sigma: float) -> Person2D:
        """A person whose heatmaps are one Gaussian (std sigma px, peak = score) per detected
        keypoint (16, 3): for detectors that give keypoints but no maps, and for projected ground
        truth."""
        keypoints = np.asarray(keypoints, dtype=np.float64)
        seen = keypoints[:, 2] > 0
        if not seen.any():
            raise ValueError('a person needs at least one detected keypoint')
        centres = [keypoints[j][None] if seen[j] else np.zeros((0, 3)) for j in range(len(keypoints))]
        return cls(keypoints, render_heatmap(centres, stride, sigma))


# A person of one frame as association hands it on: (3D id, camera index -> 2D person).
Bundle = tuple[int, dict[int, Person2D]]


@dataclass
class Sequence2D:
    """Per frame, per camera, the 2D people of a recording (None where a camera has no data).

    seconds: time spent producing them, per named step.
    """

    cameras: list[Camera]
    frames: list[int]
    people: list[list[list[Person2D] | None]]
    seconds: dict[str, float] = field(default_factory=dict)


@dataclass
class PersonFrame:
    """One person's hypotheses (J, M, 3) metres, normalised data term (J, M) and 2D support (J,)
    in [0, 1] (inference.confidence.joint_support) at one frame."""

    person_id: int
    hypotheses: np.ndarray
    data: np.ndarray
    support: np.ndarray


@dataclass
class FrameResult:
    """Decoded people of one frame: ids (P,), joints (P, J, 3) metres and their confidence (P, J)
    in [0, 1] (inference.confidence; None where the source has none, e.g. an older predictions
    file)."""

    frame: int
    person_ids: list[int]
    joints: np.ndarray
    confidence: np.ndarray | None = None
