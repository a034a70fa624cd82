"""What a clip's remaining errors rest on: for every endpoint that makes a limb wrong (strict PCP),
whether the cameras' 2D detections back the estimate or the annotation; and where the annotated
heads sit against the estimated ones.

A camera *backs* a 3D point for a joint when a person detected in its image has a keypoint of that
joint within `radius` (a fraction of the annotated person's projected box diagonal, so any image
size reads alike) of the point's projection. An endpoint that more cameras back where it was
estimated than where it is annotated is wrong with the detections, not against them: a 3D stage fed
these detections would put it at the annotation only by overruling them. Head ends and the hip
centre are derived, with no keypoint of their own, and left out: the head table covers the heads.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Sequence

import numpy as np

from mvpose_ros.core.evaluation.pcp import ALPHA, LIMBS, Matches, endpoint_errors
from mvpose_ros.core.geometry.body import BOTTOM_HEAD, JOINT_NAMES, TOP_HEAD, UP
from mvpose_ros.core.types import Sequence2D

SUPPORT_RADIUS = 0.05  # of the annotated person's projected box diagonal (21-35 px on Shelf)
VERDICTS = ('estimate', 'annotation', 'neither')
_DETECTED = len(JOINT_NAMES) - 2  # joints 0-11 have keypoints of their own; the head's two do not


@dataclass(frozen=True)
class WrongEndpoint:
    """One endpoint beyond its limb's tolerance in a strictly wrong limb.

    actor: actorsGT index; frame: dataset frame; joint: JOINT_NAMES index; error_m: metres from the
    annotation; cameras backing the estimate and the annotation (a camera may back both).
    """

    actor: int
    frame: int
    joint: int
    error_m: float
    backing_estimate: int
    backing_annotation: int

    @property
    def verdict(self) -> str:
        """'estimate' or 'annotation' (more cameras back it), else 'neither'."""
        if self.backing_estimate > self.backing_annotation:
            return 'estimate'
        if self.backing_annotation > self.backing_estimate:
            return 'annotation'
        return 'neither'


def wrong_endpoints(matches: Matches, actors: Sequence[int], seq: Sequence2D, frames: Sequence[int],
                    radius: float = SUPPORT_RADIUS, alpha: float = ALPHA) -> list[WrongEndpoint]:
    """The wrong endpoints (of detected joints) of every matched actor-frame, with their backing.
    matches: of the frames `frames` (dataset numbers) and the actorsGT `actors`, in that order;
    seq: the clip's 2D people (frames not in it back nothing)."""
    end_err, tolerance = endpoint_errors(matches.truth, matches.chosen, alpha)  # (F, A, 10, 2), (F, A, 10)
    beyond = (end_err > tolerance[..., None]) & matches.matched[..., None, None]  # such an end makes a limb wrong
    index = {int(f): k for k, f in enumerate(seq.frames)}
    out = []
    for i, a in zip(*np.nonzero(beyond.any(axis=(-2, -1)))):
        joints = sorted({int(LIMBS[limb, end]) for limb, end in zip(*np.nonzero(beyond[i, a]))
                         if LIMBS[limb, end] < _DETECTED})
        people = seq.people[index[int(frames[i])]] if int(frames[i]) in index else []
        truth, chosen = matches.truth[i, a], matches.chosen[i, a]
        for j in joints:
            on_truth, on_estimate = _backing(seq.cameras, people, truth, j, chosen[j], radius)
            out.append(WrongEndpoint(int(actors[a]), int(frames[i]), j, float(matches.joint_err[i, a, j]),
                                     on_estimate, on_truth))
    return out


def _backing(cameras, people, truth: np.ndarray, joint: int, estimate: np.ndarray, radius: float) -> tuple[int, int]:
    """How many cameras back the annotated joint truth[joint] and the estimate (3,): truth (14, 3)."""
    on_truth = on_estimate = 0
    for camera, seen in zip(cameras, people):
        if not seen:
            continue
        body = camera.project(truth)  # (14, 2)
        if np.isnan(body).any():
            continue
        reach = radius * float(np.linalg.norm(body.max(axis=0) - body.min(axis=0)))
        keypoints = np.stack([p.keypoints[joint] for p in seen])  # (P, 3)
        found = keypoints[keypoints[:, 2] > 0, :2]
        if not len(found):
            continue
        truth_near, estimate_near = (bool(np.isfinite(p).all() and np.linalg.norm(found - p, axis=1).min() <= reach)
                                     for p in (body[joint], camera.project(estimate)))
        on_truth += truth_near
        on_estimate += estimate_near
    return on_truth, on_estimate


@dataclass(frozen=True)
class HeadOffsets:
    """How an actor's annotated head sits against the estimated one, medians over matched frames.

    length_true / length_estimate: bottom-to-top, metres. top / bottom (3,): the annotated end
    minus the estimate's head centre (mid-point of its bottom and top), in the body's frame
    (forward, left, up) metres, forward being horizontal and square to the estimate's shoulder line.
    """

    actor: int
    frames: int
    length_true: float
    length_estimate: float
    top: np.ndarray
    bottom: np.ndarray


def head_offsets(matches: Matches, actors: Sequence[int], up: np.ndarray = UP) -> list[HeadOffsets]:
    """One HeadOffsets per actor matched in at least one frame."""
    up = np.asarray(up, dtype=float) / np.linalg.norm(up)
    out = []
    for a, actor in enumerate(actors):
        rows = np.flatnonzero(matches.matched[:, a] & np.isfinite(matches.chosen[:, a]).all(axis=(-2, -1)))
        if not len(rows):
            continue
        truth, chosen = matches.truth[rows, a], matches.chosen[rows, a]  # (N, 14, 3)
        left = chosen[:, 9] - chosen[:, 8]  # right shoulder -> left shoulder
        left -= (left @ up)[:, None] * up
        left /= np.linalg.norm(left, axis=-1, keepdims=True)
        forward = np.cross(left, up)
        frame = np.stack([forward, left, np.broadcast_to(up, forward.shape)], axis=1)  # (N, 3, 3)
        centre = 0.5 * (chosen[:, BOTTOM_HEAD] + chosen[:, TOP_HEAD])

        def local(points: np.ndarray) -> np.ndarray:
            return np.median(np.einsum('nij,nj->ni', frame, points - centre), axis=0)

        out.append(HeadOffsets(int(actor), len(rows),
                               float(np.median(np.linalg.norm(truth[:, TOP_HEAD] - truth[:, BOTTOM_HEAD], axis=-1))),
                               float(np.median(np.linalg.norm(chosen[:, TOP_HEAD] - chosen[:, BOTTOM_HEAD], axis=-1))),
                               local(truth[:, TOP_HEAD]), local(truth[:, BOTTOM_HEAD])))
    return out


def format_error_sources(endpoints: Sequence[WrongEndpoint], heads: Sequence[HeadOffsets],
                         actors: Sequence[int], radius: float = SUPPORT_RADIUS) -> str:
    """The report: per actor, the wrong endpoints by joint and verdict, then the head table."""
    lines = [f'Wrong endpoints of strictly wrong limbs, by what the 2D detections back (a keypoint of the joint '
             f'within {radius:g} of the annotated person\'s box diagonal of its projection):']
    for actor in actors:
        mine = [e for e in endpoints if e.actor == actor]
        counts = {v: sum(e.verdict == v for e in mine) for v in VERDICTS}
        joints = []
        for j in sorted({e.joint for e in mine}):
            of_joint = [e for e in mine if e.joint == j]
            backed = '/'.join(str(sum(e.verdict == v for e in of_joint)) for v in VERDICTS)
            joints.append(f'{JOINT_NAMES[j]} {len(of_joint)} ({backed})')
        lines.append(f'  Actor {actor + 1}: {len(mine)}, backing the estimate {counts["estimate"]}, the annotation '
                     f'{counts["annotation"]}, neither {counts["neither"]}'
                     + (f'; by joint (estimate/annotation/neither) {", ".join(joints)}' if joints else ''))
    for e in endpoints:
        if e.verdict == 'annotation':
            lines.append(f'    against the detections: actor {e.actor + 1} frame {e.frame} {JOINT_NAMES[e.joint]} '
                         f'{1000 * e.error_m:.0f} mm off (cameras backing the annotation {e.backing_annotation}, '
                         f'the estimate {e.backing_estimate})')
    lines.append('Heads, medians: annotated and estimated length, and the annotated top and bottom from the '
                 'estimate\'s head centre (forward, left, up), m:')
    for h in heads:
        lines.append(f'  Actor {h.actor + 1} ({h.frames} frames): length {h.length_true:.3f} / '
                     f'{h.length_estimate:.3f}; top {_triple(h.top)}, bottom {_triple(h.bottom)}')
    return '\n'.join(lines)


def _triple(v: np.ndarray) -> str:
    return '(' + ', '.join(f'{x:+.3f}' for x in v) + ')'
