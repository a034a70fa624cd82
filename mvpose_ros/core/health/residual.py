"""Per-camera reprojection residual of the decoded 3D skeletons: the pixel distance between each
camera's 2D keypoints of a person and that person's 3D joints projected into the camera. A camera
knocked out of its calibrated pose (bumped, moved) sees every person displaced from where the
calibration puts them, so its residual rises well above the other cameras'; a camera with
ordinary detection noise stays with them."""
from __future__ import annotations

import warnings
from collections import deque
from typing import Sequence

import numpy as np

from mvpose_ros.core.geometry.camera import Camera
from mvpose_ros.core.health.status import Level
from mvpose_ros.core.types import Bundle

LIMB_JOINTS = 12  # joints 0..11 are the same in the dataset (3D) and inference (2D) orders


def frame_residuals(cameras: Sequence[Camera | None], person_ids: Sequence[int], joints: np.ndarray,
                    bundles: Sequence[Bundle], min_score: float) -> np.ndarray:
    """(C,) median pixel distance per camera over every limb joint of every output person seen in
    that camera's view of it (the bundle of the same person id, seen by two or more cameras) with a
    keypoint scoring >= min_score; NaN for a camera with no such joint. joints: (P, 14, 3) metres,
    in person_ids order."""
    out = np.full(len(cameras), np.nan)
    row = {int(pid): p for p, pid in enumerate(person_ids)}
    pairs: dict[int, tuple[list, list]] = {}
    for pid, views in bundles:
        if pid not in row or len(views) < 2:  # one view places a person where that camera sees him
            continue
        for c, person in views.items():
            kp = np.asarray(person.keypoints)[:LIMB_JOINTS]
            seen = kp[:, 2] >= min_score
            points, pixels = pairs.setdefault(c, ([], []))
            points.append(joints[row[pid], :LIMB_JOINTS][seen])
            pixels.append(kp[seen, :2])
    for c, (points, pixels) in pairs.items():
        if cameras[c] is None:
            continue
        uv = cameras[c].project(np.concatenate(points))
        d = np.linalg.norm(uv - np.concatenate(pixels), axis=-1)
        d = d[np.isfinite(d)]
        if len(d):
            out[c] = np.median(d)
    return out


class ResidualMonitor:
    """The last `frames` output frames' per-camera residuals (frame_residuals)."""

    def __init__(self, n_cameras: int, frames: int) -> None:
        self.n_cameras = n_cameras
        self._frames: deque[np.ndarray] = deque(maxlen=frames)
        self.newest_stamp: int | None = None

    def add(self, residuals: np.ndarray, stamp_ns: int | None = None) -> None:
        """One output frame's (C,) residuals (NaN: no data from that camera), and its stamp."""
        self._frames.append(np.asarray(residuals, dtype=float))
        if stamp_ns is not None:
            self.newest_stamp = stamp_ns

    def medians(self) -> tuple[np.ndarray, np.ndarray]:
        """(C,) median residual of each camera over the recent frames (NaN: none), (C,) frames with data."""
        if not self._frames:
            return np.full(self.n_cameras, np.nan), np.zeros(self.n_cameras, dtype=int)
        stack = np.array(self._frames)
        counts = np.isfinite(stack).sum(axis=0)
        with warnings.catch_warnings():
            warnings.simplefilter('ignore', RuntimeWarning)  # an all-NaN column (no data) gives NaN
            return np.nanmedian(stack, axis=0), counts


def residual_levels(medians: np.ndarray, ratio: float, floor: float) -> list[tuple[Level, str]]:
    """Per camera: WARN when its median residual is above `floor` px and above `ratio` x the median
    of the other cameras' medians (cameras with data only), else OK, each with its reason."""
    out = []
    for c, value in enumerate(medians):
        others = np.delete(medians, c)
        others = others[np.isfinite(others)]
        if not np.isfinite(value) or len(others) == 0:
            out.append((Level.OK, 'no residual yet' if not np.isfinite(value) else f'{value:.1f} px (no other camera)'))
            continue
        reference = float(np.median(others))
        if value > floor and value > ratio * reference:
            out.append((Level.WARN, f'reprojection residual {value:.1f} px, over {ratio:g} x the other cameras\' '
                                    f'{reference:.1f} px: moved out of its calibration?'))
        else:
            out.append((Level.OK, f'{value:.1f} px (others {reference:.1f} px)'))
    return out
