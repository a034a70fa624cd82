"""What `mvpose-graph` prints after a run: frames in and out, missing, duplicate and unexpected
stamps, end-to-end latency (p50, p95, by quarter of the run) and the PCP table of the predictions;
with restarted nodes, per restart the time until output resumed, the frames lost and the person
ids before and after; by period of the run, frames, latency and memory; for a rig run, sets in /
processed / dropped, the synchronisation skew, the latency, the predictions lines by set, and a
one-scene bag scored set by set against a Shelf frame."""
from __future__ import annotations

import json
from collections import Counter
from dataclasses import dataclass
from pathlib import Path
from typing import AbstractSet, Mapping, MutableMapping, Protocol, Sequence, TextIO

import numpy as np

from msg_adapters.skeleton_msg import Skeletons
from mvpose_ros.core.association.approximate_sync import FRAME_RATE_EFFECT, rate_differs
from mvpose_ros.core.datasets.shelf_campus import SHELF_ACTORS, SHELF_TEST_FRAMES, dataset_dir, load_actors_gt
from mvpose_ros.core.evaluation.identities import identity_report
from mvpose_ros.core.evaluation.pcp import PAPER_SHELF_PCP, evaluate, format_table
from mvpose_ros.core.evaluation.predictions import frame_line, read_predictions, read_results
from mvpose_ros.core.inference.window import FrameResult
from mvpose_ros.graph.config import GraphSettings
from mvpose_ros.graph.memory import MemoryLog
from mvpose_ros.graph.recorder import OUTPUT_TOPIC, TIMING_TOPIC
from mvpose_ros.graph.respawn import Restart
from mvpose_ros.topics import SKELETONS_LIVE

# As printed: the graph runs in the root namespace.
TIMING_NAME = '/' + TIMING_TOPIC
OUTPUT_NAME = '/' + OUTPUT_TOPIC
LIVE_NAME = '/' + SKELETONS_LIVE


class Recorded(Protocol):
    """What the report reads of a recorder (graph.recorder.SkeletonRecorder)."""

    info_at: Mapping[int, int]
    outputs: Mapping[int, object]
    output_at: Mapping[int, int]
    live_at: Mapping[int, int]
    dropped: AbstractSet[int]
    received: Mapping[int, int]
    bad: Sequence[str]
    first_after: Mapping[tuple[str, int], int]


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


def frame_rate_note(bag_hz: float | None, frame_rate: float) -> str | None:
    """What to say of a bag whose cameras run at another rate than the frame_rate a parameter file
    of the user's sets (None when rate_differs is False): max_skew's default, half a period of
    frame_rate, may then be too short for the rig's offsets or longer than its period."""
    if not rate_differs(bag_hz, frame_rate):
        return None
    return (f"the bag's cameras run at {bag_hz:.1f} Hz, the parameters' frame_rate is {frame_rate:g} Hz: "
            f'{FRAME_RATE_EFFECT}; set it to {bag_hz:.1f} in your parameter file, or leave it out there to take the '
            f"bag's (docs/own_cameras.md, step 2)")


def latency_ms(info_at: Mapping[int, int], output_at: Mapping[int, int]) -> np.ndarray:
    """(N,) ms from a stamp's camera_info receipt to its skeletons receipt (ns; stamps with both)."""
    common = sorted(info_at.keys() & output_at.keys())
    return 1e-6 * (np.array([output_at[s] for s in common], dtype=np.int64)
                   - np.array([info_at[s] for s in common], dtype=np.int64))


def print_latency(lat: np.ndarray, start: str, unit: str, out: TextIO, output: str = OUTPUT_NAME) -> None:
    """Print latency (N,) ms from `start` to `output`: p50, p95, max, and p50 / p95 by quarter of
    the run (a graph that falls behind real time shows them growing)."""
    if not lat.size:
        return
    p50, p95 = np.percentile(lat, [50, 95])
    print(f'latency {start} -> {output}: p50 {p50:.1f} ms, p95 {p95:.1f} ms, max {lat.max():.1f} ms '
          f'({lat.size} {unit})', file=out)
    quarters = [q for q in np.array_split(lat, 4) if q.size]
    print(f'latency p50 by quarter of the run: {", ".join(f"{np.median(q):.0f}" for q in quarters)} ms', file=out)
    print(f'latency p95 by quarter of the run: {", ".join(f"{np.percentile(q, 95):.0f}" for q in quarters)} ms',
          file=out)


@dataclass
class RestartEffect:
    """What a node's restart did to the output: the frames (stamps, ns) lost, s from the death until
    the node published on its own output topic again (as heard) and until the skeletons of a frame
    input after the death came (None: never), and the person ids in the second of output before the death and
    after output resumed."""

    restart: Restart
    lost: list[int]
    node_back_s: float | None
    graph_back_s: float | None
    ids_before: list[int]
    ids_after: list[int]


def restart_effects(stamps: Sequence[int], node: Recorded, restarts: Sequence[Restart], outputs: Mapping[str, str],
                    frame_rate: float) -> list[RestartEffect]:
    """Per restart (in order), its effect on the run of input `stamps` (ns, bag order; the graph
    keeps their order). The frames lost to it are those without output between the last frame
    output before the death and the first frame input after it that has its output (a frame
    claimed by an earlier restart is not counted again). outputs: process name -> its output
    topic (relative; a node without one: the skeletons)."""
    done = np.array(sorted(set(stamps) & node.outputs.keys()), dtype=np.int64)
    out_at = np.array([node.output_at[s] for s in done], dtype=np.int64)
    in_at = np.array([node.info_at.get(s, -1) for s in done], dtype=np.int64)
    missing = [s for s in stamps if s not in node.outputs]
    claimed: set[int] = set()
    window = max(1, round(frame_rate))  # frames: a second of output
    effects = []
    for r in restarts:
        before = np.flatnonzero(out_at < r.died_ns)
        last = done[before.max()] if before.size else None  # stamps increase along `done`
        after = np.flatnonzero(in_at > r.died_ns)
        first = done[after.min()] if after.size else None
        lost = [s for s in missing if (last is None or s > last) and (first is None or s < first) and s not in claimed]
        claimed.update(lost)
        heard = node.first_after.get((outputs.get(r.node, OUTPUT_TOPIC), r.died_ns))
        i_last = -1 if last is None else int(np.searchsorted(done, last))
        i_first = None if first is None else int(np.searchsorted(done, first))
        effects.append(RestartEffect(
            r, lost, None if heard is None else 1e-9 * (heard - r.died_ns),
            None if first is None else 1e-9 * (int(out_at[i_first]) - r.died_ns),
            _ids(node, done[max(0, i_last + 1 - window):i_last + 1]),
            [] if i_first is None else _ids(node, done[i_first:i_first + window])))
    return effects


def _ids(node: Recorded, stamps: np.ndarray) -> list[int]:
    return sorted({int(i) for s in stamps for i in node.outputs[int(s)][0]})


def print_restarts(effects: Sequence[RestartEffect], start_ns: int, outputs: Mapping[str, str], frame_rate: float,
                   out: TextIO) -> None:
    """One line per restart: the node, why it died and when (s from start_ns), its restart delay,
    when its output and the graph's came back, the frames lost, the ids before and after."""
    if not effects:
        return
    lost = sum(len(e.lost) for e in effects)
    print(f'restarts {len(effects)}, frames lost in them {lost}:', file=out)
    for e in effects:
        r = e.restart
        delay = '' if r.restarted_ns is None else f', started again {1e-9 * (r.restarted_ns - r.died_ns):.1f} s later'
        topic = '/' + outputs.get(r.node, OUTPUT_TOPIC)
        back = 'never' if e.node_back_s is None else f'{e.node_back_s:.1f} s'
        graph = 'never' if e.graph_back_s is None else f'{e.graph_back_s:.1f} s'
        frames = f' (frames {frame_ranges([frame_of(s, frame_rate) for s in e.lost])})' if e.lost else ''
        print(f'  {r.node} {r.cause} (restart {r.count}) at {1e-9 * (r.died_ns - start_ns):.1f} s{delay}; '
              f'{topic} back after {back}, {OUTPUT_NAME} of new frames after {graph}; lost {len(e.lost)}{frames}; '
              f'ids {e.ids_before} before, {e.ids_after} after', file=out)


def print_periods(stamps: Sequence[int], node: Recorded, memory: MemoryLog, period_s: float, out: TextIO) -> None:
    """A table by `period_s` of the run (by the frames' camera_info arrival): frames in, out, latency
    p50 / p95 of those frames, and each process's largest resident size sampled in the period."""
    seen = [s for s in stamps if s in node.info_at]
    if not seen:
        return
    start = min(node.info_at[s] for s in seen)
    period_ns = round(period_s * 1e9)
    blocks: dict[int, list[int]] = {}
    for s in seen:
        blocks.setdefault((node.info_at[s] - start) // period_ns, []).append(s)
    rss: dict[int, dict[str, int]] = {}
    for at, sizes in memory.history:
        block = rss.setdefault((at - start) // period_ns, {})
        for name, size in sizes.items():
            block[name] = max(size, block.get(name, 0))
    names = sorted({name for _, sizes in memory.history for name in sizes})
    print(f'by {period_s:g} s of the run (frames by camera_info arrival; resident MiB: the most sampled in the '
          f'period):', file=out)
    print(' '.join([f'{"s":>11}', f'{"in":>6}', f'{"out":>6}', f'{"p50 ms":>7}', f'{"p95 ms":>7}',
                    *(f'{n:>{max(len(n), 6)}}' for n in names)]), file=out)
    for k in sorted(blocks):
        frames = blocks[k]
        done = [s for s in frames if s in node.outputs]
        lat = latency_ms(node.info_at, {s: node.output_at[s] for s in done})
        p50, p95 = np.percentile(lat, [50, 95]) if lat.size else (float('nan'),) * 2
        mib = [rss.get(k, {}).get(n) for n in names]
        span = f'{k * period_s:g}-{(k + 1) * period_s:g}'
        print(' '.join([f'{span:>11}', f'{len(frames):>6}', f'{len(done):>6}', f'{p50:>7.1f}', f'{p95:>7.1f}',
                        *(f'{"-" if m is None else f"{m / 2 ** 20:.1f}":>{max(len(n), 6)}}'
                          for n, m in zip(names, mib))]), file=out)


def report(stamps: Sequence[int], node: Recorded, settings: GraphSettings, out: TextIO,
           effects: Sequence[RestartEffect] = ()) -> list[str]:
    """Print counts and latency of the input `stamps` (ns, bag order); returns the problems
    (missing but for the frames lost in restarts (`effects`) and those the graph dropped
    (skeletons/dropped: a set short of min_cameras, or solved too late), which are counted apart:
    a graph behind its input by design, each logged; output never resumed
    after a restart, duplicate, unexpected, bad outputs)."""
    wanted = set(stamps)
    lost = {s for e in effects for s in e.lost}
    dropped = [s for s in stamps if s not in node.outputs and s in node.dropped]
    missing = [s for s in stamps if s not in node.outputs and s not in lost and s not in node.dropped]
    duplicate = [s for s, n in node.received.items() if n > 1]
    unexpected = [s for s in node.received if s not in wanted]
    fr = settings.frame_rate
    print(f'frames in {len(stamps)} (seen on {TIMING_NAME}: {len(node.info_at.keys() & wanted)}), '
          f'frames out {len(wanted & node.outputs.keys())}', file=out)
    print(f'missing {len(missing)}: {frame_ranges([frame_of(s, fr) for s in missing])}; '
          + (f'lost in restarts {len(lost)}; ' if effects else '')
          + (f'dropped (skeletons/dropped: too few cameras in a set, or behind the input) {len(dropped)}: '
             f'{frame_ranges([frame_of(s, fr) for s in dropped])}; ' if dropped else '')
          + f'duplicate {len(duplicate)}: {frame_ranges([frame_of(s, fr) for s in duplicate])}; '
          f'unexpected {len(unexpected)}: {frame_ranges([frame_of(s, fr) for s in unexpected])}', file=out)
    for output, at in ((OUTPUT_NAME, node.output_at), (LIVE_NAME, node.live_at)):
        print_latency(latency_ms(node.info_at, {s: t for s, t in at.items() if s in wanted}), TIMING_NAME, 'frames',
                      out, output)
    problems = [f'{len(missing)} of {len(stamps)} input stamps got no {OUTPUT_NAME}'] if missing else []
    problems += [f'no {OUTPUT_NAME} of a new frame after {e.restart.node} {e.restart.cause}' for e in effects
                 if e.graph_back_s is None]
    problems += [f'{len(duplicate)} stamps got more than one {OUTPUT_NAME}'] if duplicate else []
    problems += [f'{len(unexpected)} {OUTPUT_NAME} stamps are not in the bag'] if unexpected else []
    problems += [f'{len(node.bad)} undecodable {OUTPUT_NAME} messages, first: {node.bad[0]}'] if node.bad else []
    return problems


def score(predictions: Path | str, frames: Sequence[int], root: str | None, out: TextIO, loops: int = 1) -> None:
    """Print the PCP table and summary of the predictions over Shelf frames `frames` (one pass of
    the bag; actors 1-3), with the paper's rows when they are the whole test clip; with loops > 1
    a summary line per loop (loop k's frames are moved on by k times the span of `frames`); then
    the identities over the first pass."""
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
    first_loop = [r for r, _ in read_results(predictions) if r.frame in frames]
    print('\n'.join(identity_report(first_loop, gt, SHELF_ACTORS).lines()), file=out)


def set_skews_ms(set_stamps: Sequence[int], people_stamps: Mapping[str, Sequence[int]], max_skew_ns: int) -> np.ndarray:
    """(N,) ms: per set stamp, newest minus oldest of the cameras' people2d stamps within
    [stamp, stamp + max_skew] (the members the graph synchronised; sets seen by one camera: 0)."""
    per_camera = [np.sort(np.asarray(stamps, dtype=np.int64)) for stamps in people_stamps.values()]
    out = []
    for s in set_stamps:
        members = []
        for stamps in per_camera:
            i = np.searchsorted(stamps, s)
            if i < stamps.size and stamps[i] <= s + max_skew_ns:
                members.append(int(stamps[i]))
        if members:
            out.append(1e-6 * (max(members) - min(members)))
    return np.array(out)


class Rekeyable(Protocol):
    """What count_under_sets changes of a recorder (graph.recorder.SkeletonRecorder)."""

    outputs: MutableMapping[int, object]
    output_at: MutableMapping[int, int]
    live_at: MutableMapping[int, int]
    received: MutableMapping[int, int]


def count_under_sets(node: Rekeyable, set_of_member: Mapping[int, int]) -> int:
    """Re-key, in the recorder's own dicts, what came out under a stamp that is a member of a bag
    set but not the set's stamp: the graph stamps a set with its earliest member it received, so a
    set whose earliest image never reached it (lost on a best-effort link) comes out under a later
    member's. set_of_member: every member's stamp -> its set's stamp (ns). Returns how many stamps
    moved; a set that also came out under its own stamp keeps that output and counts twice."""
    set_stamps = set(set_of_member.values())
    moved = [s for s in node.received if s not in set_stamps and s in set_of_member]
    for member in moved:
        stamp = set_of_member[member]
        node.received[stamp] = node.received.get(stamp, 0) + node.received.pop(member)
        for kept in (node.outputs, node.output_at, node.live_at):
            if member in kept:
                kept.setdefault(stamp, kept.pop(member))
    return len(moved)


def rig_report(set_stamps: Sequence[int], bag_skews_ns: Sequence[int], node: Recorded,
               people_stamps: Mapping[str, Sequence[int]], max_skew_ns: int, lockstep: bool, out: TextIO) -> list[str]:
    """Print sets in / processed / dropped, the synchronisation skew and the latency of a rig run
    (set_stamps: every set of the bag, in order; bag_skews_ns: each set's skew in the bag);
    returns the problems (lockstep: any set without skeletons; any run: nothing processed,
    duplicate or unexpected stamps, undecodable outputs)."""
    wanted = set(set_stamps)
    processed = [s for s in set_stamps if s in node.outputs]
    duplicate = [s for s, n in node.received.items() if n > 1]
    unexpected = [s for s in node.received if s not in wanted]
    print(f'sets in {len(set_stamps)}, processed {len(processed)}, dropped {len(set_stamps) - len(processed)}'
          + (f' (set numbers {frame_ranges([i for i, s in enumerate(set_stamps) if s not in node.outputs])})'
             if len(processed) < len(set_stamps) else '')
          + f'; duplicate {len(duplicate)}, unexpected {len(unexpected)}', file=out)
    if not lockstep and len(set_stamps) > 1:
        # the bag's span, one set period included: played at --rate 1, the run's wall time
        span = (set_stamps[-1] - set_stamps[0]) * 1e-9 * len(set_stamps) / (len(set_stamps) - 1)
        print(f'sets processed per second of bag time: {len(processed) / span:.2f} of {len(set_stamps) / span:.2f} '
              'sent', file=out)
    bag = np.asarray(bag_skews_ns, dtype=float) * 1e-6
    graph = set_skews_ms(processed, people_stamps, max_skew_ns)
    if bag.size:
        print(f'sync skew (newest - oldest member stamp): bag sets p50 {np.median(bag):.1f} ms, max {bag.max():.1f} ms'
              + (f'; sets the graph processed (people2d stamps) p50 {np.median(graph):.1f} ms, max '
                 f'{graph.max():.1f} ms' if graph.size else ''), file=out)
    for output, at in ((OUTPUT_NAME, node.output_at), (LIVE_NAME, node.live_at)):
        print_latency(latency_ms(node.info_at, {s: t for s, t in at.items() if s in wanted}),
                      'first camera_info of a set', 'sets', out, output)
    problems = []
    if lockstep and len(processed) < len(set_stamps):
        problems.append(f'{len(set_stamps) - len(processed)} of {len(set_stamps)} sets got no {OUTPUT_NAME}')
    if not processed:
        problems.append(f'no set got {OUTPUT_NAME}')
    problems += [f'{len(duplicate)} stamps got more than one {OUTPUT_NAME}'] if duplicate else []
    problems += [f'{len(unexpected)} {OUTPUT_NAME} stamps are not set stamps of the bag'] if unexpected else []
    problems += [f'{len(node.bad)} undecodable {OUTPUT_NAME} messages, first: {node.bad[0]}'] if node.bad else []
    return problems


FIRST_SECOND_S = 1.0  # the start of a rig run whose sets' latency is shown stage by stage


def print_first_second(set_stamps: Sequence[int], members: Sequence[Sequence[int]], node: Recorded,
                       people_at: Mapping[int, int], bundles_at: Mapping[int, int], out: TextIO) -> None:
    """Where the latency of the sets of the run's first FIRST_SECOND_S (by stamp) goes: per set that
    reached detection, ms from its first camera_info to its last camera's people2d (sync and
    detection), its bundles (association) and its skeletons (the 3D stage); members: each set's
    member stamps (ns)."""
    if not set_stamps:
        return
    print(f'the first {FIRST_SECOND_S:g} s, ms from a set\'s first camera_info to: its last people2d '
          f'(synchronised and detected) / bundles (associated) / {OUTPUT_NAME}', file=out)
    for k, (stamp, stamps) in enumerate(zip(set_stamps, members)):
        if stamp - set_stamps[0] > FIRST_SECOND_S * 1e9:
            break
        start = node.info_at.get(stamp)
        people = [people_at[m] for m in stamps if m in people_at]
        stages = [max(people) if people else None, bundles_at.get(stamp), node.output_at.get(stamp)]
        if start is None or all(at is None for at in stages):
            continue  # dropped before detection (paced), or no camera_info timed
        shown = ' / '.join('-' if at is None else f'{(at - start) / 1e6:.0f}' for at in stages)
        print(f'  set {k:3d} ({len(stamps)} cameras): {shown}', file=out)


def print_refusals(refusals: Mapping[str, Counter], out: TextIO) -> None:
    """The inputs the detectors refused, by camera and cause (core.health.refusals), or that none were."""
    refused = {camera: causes for camera, causes in sorted(refusals.items()) if causes}
    if not refused:
        print('refused inputs: none', file=out)
        return
    print('refused inputs, by camera and cause:', file=out)
    for camera, causes in refused.items():
        for cause, n in causes.most_common():
            print(f'  {camera}: {n} x {cause}', file=out)


def rig_prediction_lines(set_stamps: Sequence[int], outputs: Mapping[int, Skeletons]) -> list[str]:
    """One predictions line per set with skeletons, in bag order: {"frame": <set index from 0>,
    "stamp": <ns>, "people": [{"id": ..., "joints": [[x, y, z] x 14], "confidence": [c x 14]}]}."""
    return [frame_line(FrameResult(index, [int(i) for i in outputs[stamp].ids], outputs[stamp].joints,
                                   outputs[stamp].confidence), stamp=int(stamp))
            for index, stamp in enumerate(set_stamps) if stamp in outputs]


def score_sets(predictions: Path | str, frame: int, root: str | None, out: TextIO,
               absent: Mapping[int, Sequence[str]] | None = None) -> None:
    """Every set of a rig predictions file scored against Shelf's actorsGT frame `frame` (a bag of
    that one scene repeated): per annotated actor, the sets it is found in, MPJPE (mean, min, max
    over those sets) and the ids it got (the same id throughout is the tracking working), after a
    line per set. absent: set index -> the cameras that set lacks in the bag (a late or dropped
    frame), named on its line; the summary then also gives the sets with every camera apart, the
    ones comparable with all the cameras' images."""
    gt = load_actors_gt(dataset_dir('shelf', root) / 'actorsGT.mat', [frame])
    actors = gt.annotated(0)[0].tolist()
    records = [json.loads(line) for line in Path(predictions).read_text(encoding='utf-8').splitlines() if line]
    absent = absent or {}
    errors: dict[int, list[float]] = {a: [] for a in actors}
    whole: dict[int, list[float]] = {a: [] for a in actors}  # sets with every camera
    ids: dict[int, set[int]] = {a: set() for a in actors}
    complete = 0
    for rec in records:
        lacking = absent.get(rec['frame'])
        people = rec['people']
        joints = np.array([p['joints'] for p in people], dtype=float).reshape(-1, 14, 3)
        ev = evaluate({frame: joints}, gt, actors)
        found, line = 0, []
        for a, actor in enumerate(ev.actors):
            if ev.missed[a] == 0:
                found += 1
                errors[actor].append(float(ev.mpjpe[a]))
                if not lacking:
                    whole[actor].append(float(ev.mpjpe[a]))
                truth = gt.poses[0, actor]
                nearest = int(np.argmin(np.linalg.norm(joints - truth, axis=-1).mean(axis=-1)))
                ids[actor].add(int(people[nearest]['id']))
                line.append(f'actor {actor + 1} {ev.mpjpe[a]:5.1f} mm (id {people[nearest]["id"]})')
            else:
                line.append(f'actor {actor + 1} not found')
        complete += found == len(actors)
        without = f' (without {", ".join(lacking)})' if lacking else ''
        print(f'set {rec["frame"]:3d}{without}: {", ".join(line)}', file=out)
    print(f'ground truth Shelf frame {frame} (actors {", ".join(str(a + 1) for a in actors)}): every annotated '
          f'actor found in {complete} of {len(records)} sets', file=out)
    for actor in actors:
        e = np.array(errors[actor])
        stats = f'MPJPE mean {e.mean():.1f} mm, min {e.min():.1f}, max {e.max():.1f}' if e.size else 'MPJPE -'
        w = np.array(whole[actor])
        if any(absent.values()):
            stats += (f'; in the {w.size} with every camera mean {w.mean():.1f}, max {w.max():.1f}' if w.size
                      else '; in none with every camera')
        print(f'Actor {actor + 1}: found in {e.size} sets, {stats}; ids {sorted(ids[actor])}', file=out)
