"""A person detected in one camera image: the 16 inference keypoints (body.INFERENCE_NAMES) plus the heatmaps the 3D stage samples."""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from mvpose_ros.core.heatmap import PersonHeatmap, render_heatmap


@dataclass
class Person2D:
    """keypoints: (16, 3) u, v pixels, score; a joint with score 0 was not detected (its u, v
    are NaN when it comes from body.to_inference). heatmap: the 16 joint maps. track_id: per-camera
    identity set by the tracker (-1 = none yet)."""

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
