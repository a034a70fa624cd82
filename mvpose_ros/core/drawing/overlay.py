"""Overlay images: 3D skeletons reprojected into a camera image, each person in its own colour,
over that camera's 2D detections drawn thinly, and where a dataset annotates the frame its
ground truth in one fixed colour, so an annotation and an estimate that disagree can be told apart
at a glance."""
from __future__ import annotations

from typing import Sequence

import cv2
import numpy as np

from mvpose_ros.core.geometry.body import BONES, NUM_JOINTS, TOP_HEAD
from mvpose_ros.core.geometry.camera import Camera
from mvpose_ros.core.types import Person2D

DETECTION_BGR = (255, 255, 255)
GROUND_TRUTH_BGR = (0, 255, 255)  # yellow, and drawn thinner than the estimates and with open joints
_SHIFT = 4  # cv2 sub-pixel drawing: coordinates in 1/16 px
_BONES = np.array(BONES)  # (B, 2) joints of each bone, the 14 dataset joints


def _segments(uv: np.ndarray) -> np.ndarray:
    """(S, 2, 2) fixed-point endpoints of the bones whose two joints are finite (uv: (14, 2))."""
    ends = uv[_BONES]  # (B, 2, 2)
    ok = np.isfinite(ends).all(axis=(1, 2))
    return np.round(ends[ok] * (1 << _SHIFT)).astype(np.int32)


def draw_detections(bgr: np.ndarray, people: Sequence[Person2D], scale: float = 1.0) -> None:
    """Thin lines over each 2D person's detected bones (the first 14 inference joints are the
    dataset's joints with neck and head for the two head joints), in place; scale: image pixels
    per camera pixel (an image decoded shrunk)."""
    for person in people:
        kp = person.keypoints[:NUM_JOINTS]
        uv = scale * np.where((kp[:, 2] > 0)[:, None], kp[:, :2], np.nan)
        cv2.polylines(bgr, list(_segments(uv)), False, DETECTION_BGR, 1, cv2.LINE_AA, _SHIFT)


def draw_skeletons(bgr: np.ndarray, camera: Camera, joints: np.ndarray,
                   colours: Sequence[tuple[float, float, float]], scale: float = 1.0,
                   labels: Sequence[str] = ()) -> None:
    """Each person's 3D joints (P, 14, 3) metres reprojected through camera, bones and joints in
    its colour (r, g, b in [0, 1]) and, when given, its label at the top of its head, in place;
    scale: image pixels per camera pixel; line width follows the image size."""
    width = max(2, round(bgr.shape[1] / 300))
    for p, (xyz, (r, g, b)) in enumerate(zip(np.asarray(joints, dtype=np.float64), colours)):
        colour = (int(255 * b), int(255 * g), int(255 * r))
        uv = scale * camera.project(xyz)
        cv2.polylines(bgr, list(_segments(uv)), False, colour, width, cv2.LINE_AA, _SHIFT)
        for point in np.round(uv[np.isfinite(uv).all(axis=1)] * (1 << _SHIFT)).astype(np.int32):
            cv2.circle(bgr, tuple(point.tolist()), (width + 2) << _SHIFT, colour, -1, cv2.LINE_AA, _SHIFT)
        if p < len(labels) and np.isfinite(uv[TOP_HEAD]).all():
            corner = (int(uv[TOP_HEAD, 0]) + 4 * width, int(uv[TOP_HEAD, 1]) - 4 * width)
            cv2.putText(bgr, labels[p], corner, cv2.FONT_HERSHEY_SIMPLEX, bgr.shape[1] / 1500, colour, width,
                        cv2.LINE_AA)


def draw_caption(bgr: np.ndarray, text: str) -> None:
    """One line of white text on a dark band at the image's top left, in place."""
    scale = max(0.4, bgr.shape[1] / 1600)
    thickness = max(1, round(scale * 1.5))
    (w, h), base = cv2.getTextSize(text, cv2.FONT_HERSHEY_SIMPLEX, scale, thickness)
    pad = max(2, h // 3)
    bgr[:h + base + 2 * pad, :w + 2 * pad] //= 3
    cv2.putText(bgr, text, (pad, pad + h), cv2.FONT_HERSHEY_SIMPLEX, scale, (255, 255, 255), thickness, cv2.LINE_AA)


def draw_ground_truth(bgr: np.ndarray, camera: Camera, truth: np.ndarray, actors: Sequence[int]) -> None:
    """Each annotated pose (A, 14, 3) metres reprojected through camera, bones in GROUND_TRUTH_BGR
    at half the skeletons' width, joints as open circles and `GT <actor>` (actors (A,): the
    dataset's 0-based actor indices, printed from 1 as everywhere) at the top of its head, in place."""
    width = max(1, round(bgr.shape[1] / 600))
    scale = bgr.shape[1] / 1500
    for xyz, actor in zip(np.asarray(truth, dtype=np.float64), actors):
        uv = camera.project(xyz)
        cv2.polylines(bgr, list(_segments(uv)), False, GROUND_TRUTH_BGR, width, cv2.LINE_AA, _SHIFT)
        for point in np.round(uv[np.isfinite(uv).all(axis=1)] * (1 << _SHIFT)).astype(np.int32):
            cv2.circle(bgr, tuple(point.tolist()), (width + 3) << _SHIFT, GROUND_TRUTH_BGR, width, cv2.LINE_AA, _SHIFT)
        if np.isfinite(uv[TOP_HEAD]).all():
            corner = (int(uv[TOP_HEAD, 0]) + 4 * width, int(uv[TOP_HEAD, 1]) - 4 * width)
            cv2.putText(bgr, f'GT {int(actor) + 1}', corner, cv2.FONT_HERSHEY_SIMPLEX, scale, GROUND_TRUTH_BGR,
                        width, cv2.LINE_AA)


def overlay(bgr: np.ndarray, camera: Camera, people: Sequence[Person2D], joints: np.ndarray,
            colours: Sequence[tuple[float, float, float]], truth: np.ndarray | None = None,
            truth_actors: Sequence[int] = (), *, scale: float = 1.0, labels: Sequence[str] = ()) -> np.ndarray:
    """A copy of bgr with the 2D detections (thin, white), the reprojected 3D skeletons (labelled
    when labels are given) and, when given, the annotated poses truth (A, 14, 3) of truth_actors
    (draw_ground_truth, at full scale); scale: image pixels per camera pixel."""
    out = np.array(bgr, copy=True)
    draw_detections(out, people, scale)
    draw_skeletons(out, camera, joints, colours, scale, labels)
    if truth is not None:
        draw_ground_truth(out, camera, truth, truth_actors)
    return out
