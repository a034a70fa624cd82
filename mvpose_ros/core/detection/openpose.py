"""OpenPose BODY25 detections as stored in the 4D Association text format: per frame, joint
candidates (pixels, score) and the raw part-affinity score of every candidate pair of each limb."""
from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

# PAF limbs (joint a, joint b) in the file's order: torso first, so grouping grows from the neck
BODY25_PAF_PAIRS: tuple[tuple[int, int], ...] = (
    (1, 8), (9, 10), (10, 11), (8, 9), (8, 12), (12, 13), (13, 14), (1, 2), (2, 3), (3, 4),
    (2, 17), (1, 5), (5, 6), (6, 7), (5, 18), (1, 0), (0, 15), (0, 16), (15, 17), (16, 18),
    (14, 19), (19, 20), (14, 21), (11, 22), (22, 23), (11, 24),
)
BODY25_NUM_JOINTS = 25
BODY25_SKELETON_TYPE = 4  # the format's header code for BODY25


@dataclass
class OpenPoseFrame:
    """One camera's OpenPose output for one frame."""

    candidates: list[np.ndarray]  # 25 entries, each (n_k, 3): u, v pixels, score
    pafs: list[np.ndarray]  # 26 entries, each (n_a, n_b) raw PAF scores for BODY25_PAF_PAIRS


def _count(x: float) -> int | None:
    return int(x) if np.isfinite(x) and x >= 0 and x == int(x) else None


def parse_body25(tokens: np.ndarray, width: int = 1032, height: int = 776,
                 source: str = '<tokens>') -> tuple[list[OpenPoseFrame], int]:
    """Walk the numbers (T,) of a BODY25 detection file; returns the frames and the number of
    tokens consumed. Raises ValueError naming source, frame and joint/limb on bad input."""
    n_tok = len(tokens)
    if n_tok < 2:
        raise ValueError(f'{source}: missing header (expected "{BODY25_SKELETON_TYPE} <frames>")')
    if tokens[0] != BODY25_SKELETON_TYPE:
        raise ValueError(f'{source}: skeleton type {tokens[0]:g} is not BODY25 '
                         f'({BODY25_SKELETON_TYPE})')
    n_frames = _count(tokens[1])
    if n_frames is None:
        raise ValueError(f'{source}: bad frame count {tokens[1]:g}')
    scale = np.array([width - 1, height - 1, 1.0])
    frames = []
    i = 2
    for f in range(n_frames):
        candidates = []
        for j in range(BODY25_NUM_JOINTS):
            if i >= n_tok:
                raise ValueError(f'{source}: truncated at frame {f}, joint {j} (no count)')
            n = _count(tokens[i])
            if n is None:
                raise ValueError(f'{source}: frame {f}, joint {j}: bad candidate count '
                                 f'{tokens[i]:g}')
            end = i + 1 + 3 * n
            if end > n_tok:
                raise ValueError(f'{source}: truncated at frame {f}, joint {j} '
                                 f'({n} candidates announced)')
            # rows x, y, score; x, y normalised to [0, 1]
            candidates.append(tokens[i + 1:end].reshape(3, n).T * scale)
            i = end
        pafs = []
        for k, (a, b) in enumerate(BODY25_PAF_PAIRS):
            shape = (len(candidates[a]), len(candidates[b]))
            end = i + shape[0] * shape[1]
            if end > n_tok:
                raise ValueError(f'{source}: truncated at frame {f}, PAF {k} (joints {a}-{b})')
            pafs.append(tokens[i:end].reshape(shape))
            i = end
        frames.append(OpenPoseFrame(candidates, pafs))
    return frames, i


def read_body25(path: str | Path, width: int = 1032, height: int = 776,
                return_consumed: bool = False
                ) -> list[OpenPoseFrame] | tuple[list[OpenPoseFrame], int]:
    """Read a BODY25 detection file (header `4 <frames>`, then per frame 25 candidate blocks
    `n` + x, y, score rows and 26 PAF matrices n_a x n_b). width, height: the image size the
    normalised x, y scale to (pixel = x * (width - 1)). With return_consumed, also the number of
    tokens consumed (always all of them: trailing numbers are an error)."""
    path = Path(path)
    try:
        tokens = np.array(path.read_text().split(), dtype=np.float64)
    except ValueError as e:
        raise ValueError(f'{path}: non-numeric token ({e})') from None
    frames, consumed = parse_body25(tokens, width, height, source=str(path))
    if consumed != len(tokens):
        raise ValueError(f'{path}: {len(tokens) - consumed} trailing numbers after frame '
                         f'{len(frames) - 1}')
    return (frames, consumed) if return_consumed else frames
