"""The predictions file: JSON lines, one line per frame.

`{"frame": <actorsGT frame index>, "people": [{"id": <int>, "joints": [[x, y, z], ...]}]}` with
14 rows per person in the Shelf joint order, metres, world frame. Both the offline evaluator
and the ROS graph runner write it; `mvpose-eval --predictions` and tests read it back.
"""
from __future__ import annotations

import json
from pathlib import Path
from typing import IO, Iterable

import numpy as np

from mvpose_ros.core.geometry.body import NUM_JOINTS
from mvpose_ros.core.types import FrameResult


def frame_line(result: FrameResult) -> str:
    """One JSON line (no newline) for a decoded frame; millimetre precision is plenty."""
    people = [{'id': int(pid), 'joints': np.round(j, 4).tolist()} for pid, j in zip(result.person_ids, result.joints)]
    return json.dumps({'frame': int(result.frame), 'people': people}, separators=(',', ':'))


def write_predictions(results: Iterable[FrameResult], stream: IO[str]) -> int:
    """Write frames in order; returns how many were written."""
    n = 0
    for r in results:
        stream.write(frame_line(r) + '\n')
        n += 1
    stream.flush()
    return n


def read_predictions(path: str | Path) -> dict[int, np.ndarray]:
    """Frame index -> (P, 14, 3) joints. Raises ValueError naming the file and line when invalid."""
    out: dict[int, np.ndarray] = {}
    with open(path, encoding='utf-8') as f:
        for n, line in enumerate(f, 1):
            if not line.strip():
                continue
            try:
                rec = json.loads(line)
                joints = np.array([p['joints'] for p in rec['people']], dtype=float).reshape(-1, NUM_JOINTS, 3)
                frame = int(rec['frame'])
            except (ValueError, KeyError, TypeError) as exc:
                raise ValueError(f'{path}:{n}: not a predictions line ({exc})') from None
            if not np.all(np.isfinite(joints)) or frame in out:
                reason = 'non-finite joint' if frame not in out else f'frame {frame} repeated'
                raise ValueError(f'{path}:{n}: {reason}')
            out[frame] = joints
    return out
