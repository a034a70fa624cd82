"""The predictions file: JSON lines, one line per frame.

`{"frame": <actorsGT frame index>, "people": [{"id": <int>, "joints": [[x, y, z], ...],
"confidence": [c, ...]}]}` with 14 rows per person in the Shelf joint order, metres, world frame,
and each joint's confidence in [0, 1] (left out where unknown; a file has it for every person or
for none). A line may carry more keys (the graph's "stamp", ns). Both the offline evaluator and
the ROS graph runner write it; `mvpose-eval --predictions` and tests read it back.
"""
from __future__ import annotations

import json
from pathlib import Path
from typing import IO, Iterable

import numpy as np

from mvpose_ros.core.geometry.body import NUM_JOINTS
from mvpose_ros.core.types import FrameResult


def frame_line(result: FrameResult, **extra: int) -> str:
    """One JSON line (no newline) for a decoded frame, with `extra` keys after "frame" (e.g.
    stamp=<ns>); millimetre precision is plenty, and a thousandth of confidence."""
    people = [{'id': int(pid), 'joints': np.round(j, 4).tolist()} for pid, j in zip(result.person_ids, result.joints)]
    if result.confidence is not None:
        for person, c in zip(people, result.confidence):
            person['confidence'] = np.round(c, 3).tolist()
    return json.dumps({'frame': int(result.frame), **extra, 'people': people}, separators=(',', ':'))


def write_predictions(results: Iterable[FrameResult], stream: IO[str]) -> int:
    """Write frames in order; returns how many were written."""
    n = 0
    for r in results:
        stream.write(frame_line(r) + '\n')
        n += 1
    stream.flush()
    return n


def read_results(path: str | Path) -> list[tuple[FrameResult, dict]]:
    """Every line as (its frame's result, the line's other keys, e.g. {"stamp": ns}), in file
    order; confidence None when the file has none. Raises ValueError naming the file and line
    when invalid."""
    out: list[tuple[FrameResult, dict]] = []
    seen: set[int] = set()
    with open(path, encoding='utf-8') as f:
        for n, line in enumerate(f, 1):
            if not line.strip():
                continue
            try:
                rec = json.loads(line)
                people = rec.pop('people')
                joints = np.array([p['joints'] for p in people], dtype=float).reshape(-1, NUM_JOINTS, 3)
                has = [('confidence' in p) for p in people]
                confidence = (np.array([p['confidence'] for p in people], dtype=float).reshape(-1, NUM_JOINTS)
                              if people and all(has) else None)
                if any(has) and not all(has):
                    raise ValueError('confidence given for some people only')
                frame = int(rec.pop('frame'))
                ids = [int(p['id']) for p in people]
            except (ValueError, KeyError, TypeError, AttributeError) as exc:
                raise ValueError(f'{path}:{n}: not a predictions line ({exc})') from None
            if not np.all(np.isfinite(joints)) or frame in seen:
                reason = 'non-finite joint' if frame not in seen else f'frame {frame} repeated'
                raise ValueError(f'{path}:{n}: {reason}')
            if confidence is not None and not ((confidence >= 0) & (confidence <= 1)).all():
                raise ValueError(f'{path}:{n}: confidence outside [0, 1]')
            seen.add(frame)
            out.append((FrameResult(frame, ids, joints, confidence), rec))
    return out


def read_predictions(path: str | Path) -> dict[int, np.ndarray]:
    """Frame index -> (P, 14, 3) joints. Raises ValueError naming the file and line when invalid."""
    return {r.frame: r.joints for r, _ in read_results(path)}
