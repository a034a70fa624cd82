"""What `mvpose-graph` prints after a run: frames in and out, missing, duplicate and unexpected
stamps, end-to-end latency (p50, p95, by quarter of the run) and the PCP table of the predictions."""
from __future__ import annotations

from pathlib import Path
from typing import Mapping, Protocol, Sequence, TextIO

import numpy as np

from mvpose_ros.core.evaluation.datasets import SHELF_ACTORS, SHELF_TEST_FRAMES, dataset_dir, load_actors_gt
from mvpose_ros.core.evaluation.pcp import PAPER_SHELF_PCP, evaluate, format_table
from mvpose_ros.core.evaluation.predictions import read_predictions
from mvpose_ros.graph.config import GraphSettings
from mvpose_ros.graph.recorder import OUTPUT_TOPIC, TIMING_TOPIC

# As printed: the graph runs in the root namespace.
TIMING_NAME = '/' + TIMING_TOPIC
OUTPUT_NAME = '/' + OUTPUT_TOPIC


class Recorded(Protocol):
    """What the report reads of a recorder (graph.recorder.SkeletonRecorder)."""

    info_at: Mapping[int, int]
    outputs: Mapping[int, object]
    output_at: Mapping[int, int]
    received: Mapping[int, int]
    bad: Sequence[str]


def frame_of(stamp: int, frame_rate: float) -> int:
    """The dataset frame of a stamp (ns): frame f has stamp f / frame_rate s."""
    return round(stamp * frame_rate / 1e9)


def frame_ranges(frames: Sequence[int]) -> str:
    """'300-305, 410' for [300, 301, 302, 303, 304, 305, 410]."""
    f = np.unique(np.asarray(frames, dtype=int))
    if f.size == 0:
        return 'none'
    breaks = np.flatnonzero(np.diff(f) != 1)
    starts, ends = f[np.r_[0, breaks + 1]], f[np.r_[breaks, f.size - 1]]
    return ', '.join(f'{a}' if a == b else f'{a}-{b}' for a, b in zip(starts, ends))


def latency_ms(info_at: Mapping[int, int], output_at: Mapping[int, int]) -> np.ndarray:
    """(N,) ms from a stamp's camera_info receipt to its skeletons receipt (ns; stamps with both)."""
    common = sorted(info_at.keys() & output_at.keys())
    return 1e-6 * (np.array([output_at[s] for s in common], dtype=np.int64)
                   - np.array([info_at[s] for s in common], dtype=np.int64))


def report(stamps: Sequence[int], node: Recorded, settings: GraphSettings, out: TextIO) -> list[str]:
    """Print counts and latency of the input `stamps` (ns, bag order); returns the problems
    (missing, duplicate, unexpected, bad outputs)."""
    wanted = set(stamps)
    missing = [s for s in stamps if s not in node.outputs]
    duplicate = [s for s, n in node.received.items() if n > 1]
    unexpected = [s for s in node.received if s not in wanted]
    fr = settings.frame_rate
    print(f'frames in {len(stamps)} (seen on {TIMING_NAME}: {len(node.info_at.keys() & wanted)}), '
          f'frames out {len(wanted & node.outputs.keys())}', file=out)
    print(f'missing {len(missing)}: {frame_ranges([frame_of(s, fr) for s in missing])}; '
          f'duplicate {len(duplicate)}: {frame_ranges([frame_of(s, fr) for s in duplicate])}; '
          f'unexpected {len(unexpected)}: {frame_ranges([frame_of(s, fr) for s in unexpected])}', file=out)
    lat = latency_ms(node.info_at, {s: t for s, t in node.output_at.items() if s in wanted})
    if lat.size:
        p50, p95 = np.percentile(lat, [50, 95])
        print(f'latency {TIMING_NAME} -> {OUTPUT_NAME}: p50 {p50:.1f} ms, p95 {p95:.1f} ms, '
              f'max {lat.max():.1f} ms ({lat.size} frames)', file=out)
        # a graph that falls behind real time shows latency growing through the run
        quarters = [f'{np.median(q):.0f}' for q in np.array_split(lat, 4) if q.size]
        print(f'latency p50 by quarter of the run: {", ".join(quarters)} ms', file=out)
    problems = [f'{len(missing)} of {len(stamps)} input stamps got no {OUTPUT_NAME}'] if missing else []
    problems += [f'{len(duplicate)} stamps got more than one {OUTPUT_NAME}'] if duplicate else []
    problems += [f'{len(unexpected)} {OUTPUT_NAME} stamps are not in the bag'] if unexpected else []
    problems += [f'{len(node.bad)} undecodable {OUTPUT_NAME} messages, first: {node.bad[0]}'] if node.bad else []
    return problems


def score(predictions: Path | str, frames: Sequence[int], root: str | None, out: TextIO, loops: int = 1) -> None:
    """Print the PCP table and summary of the predictions over Shelf frames `frames` (one pass of
    the bag; actors 1-3), with the paper's rows when they are the whole test clip; with loops > 1
    a summary line per loop (loop k's frames are moved on by k times the span of `frames`)."""
    gt = load_actors_gt(dataset_dir('shelf', root) / 'actorsGT.mat', frames)
    predicted = read_predictions(predictions)
    span = max(frames) - min(frames) + 1
    whole = sorted(frames) == list(SHELF_TEST_FRAMES)
    print(f'{predictions}: Shelf frames {frame_ranges(frames)}' + (f', {loops} loops' if loops > 1 else ''), file=out)
    for k in range(loops):
        ev = evaluate({f: predicted[f + k * span] for f in frames if f + k * span in predicted}, gt, SHELF_ACTORS)
        if k == 0:
            print(format_table(ev, PAPER_SHELF_PCP if whole else None), file=out)
        print((f'loop {k + 1:2d}: ' if loops > 1 else '')
              + f'strict {ev.frame_weighted("strict"):6.2f} frame-weighted / {ev.actor_average("strict"):6.2f} '
              f'actor-average | lenient {ev.frame_weighted("lenient"):6.2f} / {ev.actor_average("lenient"):6.2f}'
              f' | MPJPE {ev.mpjpe_all:5.1f} mm', file=out)
