"""`mvpose-graph`: run the whole ROS graph on a bag, each node its own process, and score it.

    mvpose-graph --config config/shelf.yaml [--data-root DIR] [--bag DIR] [--rate R] [--loops N]
                 [--predictions FILE] [--domain-id N] [--log-dir DIR]

Starts the detectors, association and bp_solver (with the Fast DDS profile `fastdds.xml` beside
the parameter file, when there is one), waits until the graph is connected, then plays
the bag; a recorder node inside this process keeps every /skeletons message and times it from
the arrival of the same stamp's /cam0/camera_info. The input frames are the bag's messages on
the detectors' input topic, which follows their backend (/cam0/openpose for openpose,
/cam0/image_raw for onnx). It stops when every input stamp has its output (or nothing came for
`timeout` s), stops every process, writes the predictions file and prints counts, latency and
the PCP table of those frames against Shelf's ground truth (actors 1-3, as `mvpose-eval shelf
--score` for the whole test clip). Exit code 1 with a one-line reason when a node crashes, the
graph never connects, or outputs are missing. With --loops N (a soak run) the bag is replayed N
times with its stamps moved on every loop; it then also prints each node's resident memory after
the first loop and at the end, and one PCP line per loop. Ctrl-C stops every node and still
writes the frames received so far (exit code 130).
"""
from __future__ import annotations

import argparse
import os
import signal
import sys
import time
from collections import Counter
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Mapping, Sequence, TextIO

import numpy as np
import rclpy
from rclpy.context import Context
from rclpy.executors import SingleThreadedExecutor
from rclpy.node import Node
from rclpy.qos import HistoryPolicy, QoSProfile, ReliabilityPolicy
from rclpy.signals import SignalHandlerOptions
from sensor_msgs.msg import CameraInfo, PointCloud2

from msg_adapters.skeleton_msg import msg_to_skeletons
from msg_adapters.stamp import stamp_ns
from mvpose_ros.bags.io import read_bag
from mvpose_ros.bags.replay import loop_offset_ns
from mvpose_ros.core.evaluation.datasets import SHELF_ACTORS, SHELF_TEST_FRAMES, data_root, dataset_dir, load_actors_gt
from mvpose_ros.core.evaluation.pcp import PAPER_SHELF_PCP, evaluate, format_table
from mvpose_ros.core.evaluation.predictions import read_predictions, write_predictions
from mvpose_ros.core.inference.window import FrameResult
from mvpose_ros.graph.config import (GraphSettings, NodeSpec, detector_backend, expected_connections, graph_nodes,
                                     graph_settings, load_params, node_command, unknown_nodes)
from mvpose_ros.graph.memory import MemoryLog
from mvpose_ros.graph.processes import Interrupted, ProcessGroup
from mvpose_ros.nodes.heatmap_detector import INPUT_TOPICS

PROG = 'mvpose-graph'
TIMING_TOPIC = '/cam0/camera_info'
OUTPUT_TOPIC = '/skeletons'
PLAYER = 'bag_player'
# Fast DDS settings beside the parameter file (config/fastdds.xml: a shared-memory segment large
# enough for the heatmap messages), used by this process and every node unless already chosen.
DDS_PROFILE = 'fastdds.xml'
DDS_PROFILE_ENV = 'FASTRTPS_DEFAULT_PROFILES_FILE'
QOS = QoSProfile(reliability=ReliabilityPolicy.RELIABLE, history=HistoryPolicy.KEEP_LAST, depth=100)
_SPIN_S = 0.05
_DRAIN_S = 0.25
# Node start-up (imports, calibration, models, DDS discovery, the player's wait for subscribers).
STARTUP_TIMEOUT_S = 60.0
_LOG_TAIL = 15
MEMORY_PERIOD_S = 1.0


class GraphFailure(Exception):
    """The graph cannot finish: `node` (a process name, or '' for the graph as a whole) and why."""

    def __init__(self, node: str, reason: str) -> None:
        super().__init__(reason)
        self.node = node


class RecorderNode(Node):
    """Keeps the first /skeletons message of every stamp, and when (middleware receipt time, ns of
    the system clock, so queueing in this process's executor does not count) each stamp's
    /cam0/camera_info and /skeletons arrived."""

    def __init__(self, context: Context) -> None:
        super().__init__('mvpose_graph', context=context)
        self.info_at: dict[int, int] = {}
        self.outputs: dict[int, tuple[np.ndarray, np.ndarray]] = {}
        self.output_at: dict[int, int] = {}
        self.received: Counter[int] = Counter()
        self.bad: list[str] = []
        self.last_activity = 0.0  # monotonic s of the last message, for the stall timeout
        self.create_subscription(CameraInfo, TIMING_TOPIC, self._on_info, QOS)
        self.create_subscription(PointCloud2, OUTPUT_TOPIC, self._on_skeletons, QOS)

    def _on_info(self, msg: CameraInfo, info: dict) -> None:
        self.last_activity = time.monotonic()
        self.info_at.setdefault(stamp_ns(msg.header.stamp), info['received_timestamp'])

    def _on_skeletons(self, msg: PointCloud2, info: dict) -> None:
        self.last_activity = time.monotonic()
        stamp = stamp_ns(msg.header.stamp)
        self.received[stamp] += 1
        try:
            decoded = msg_to_skeletons(msg)
        except ValueError as exc:
            self.bad.append(f'{stamp} ns: {exc}')
            return
        if stamp not in self.outputs:
            self.outputs[stamp] = decoded
            self.output_at[stamp] = info['received_timestamp']

    def missing_links(self, expected: Mapping[str, Sequence[str]]) -> list[str]:
        """Expected endpoints not yet in the ROS graph, e.g. 'subscriber of /cam3/openpose'."""
        count = {'pub': self.count_publishers, 'sub': self.count_subscribers}
        word = {'pub': 'publisher', 'sub': 'subscriber'}
        return [f'{word[end]} of {topic}' for topic, ends in expected.items() for end in ends
                if count[end](topic) == 0]


@dataclass
class Outcome:
    """How the run ended: the input stamps (ns, bag order), why it stopped early if it did (a
    failure, a stall, or the signal that interrupted it), the end of the failed node's log, and
    the nodes' memory."""

    stamps: list[int]
    memory: MemoryLog = field(default_factory=lambda: MemoryLog(0))
    failure: GraphFailure | None = None
    log_tail: str = ''
    stalled: bool = False
    interrupted: int | None = None


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog=PROG, description=__doc__.split('\n')[0])
    p.add_argument('--config', required=True, type=Path,
                   help='ROS 2 parameter file with every node and the mvpose_graph section')
    p.add_argument('--data-root', help='folder holding data/ and models/ (default: $MVPOSE_DATA_ROOT or ../shared)')
    p.add_argument('--bag', help='bag to play (default: mvpose_graph.bag)')
    p.add_argument('--rate', type=float,
                   help='playback speed, 0 = as fast as the graph keeps up (default: mvpose_graph.rate)')
    p.add_argument('--loops', type=int, default=1,
                   help='replay the bag this many times, stamps moved on every loop (a soak run; default 1)')
    p.add_argument('--predictions', help='predictions file to write (default: mvpose_graph.predictions)')
    p.add_argument('--domain-id', type=int, help='ROS_DOMAIN_ID for the graph (default: inherited)')
    p.add_argument('--log-dir', type=Path, help='per-node logs (default: beside the predictions, <name>_logs)')
    return p


def input_stamps(bag: Path, topic: str, loops: int = 1) -> list[int]:
    """Header stamps (ns) of the frames the player sends: the log times of the bag's messages on
    topic (camera 0's detector input), moved on for each later loop as the player does."""
    stamps = [stamp for _, _, stamp, _ in read_bag(bag, [topic])]
    if not stamps:
        raise ValueError(f'{bag}: no {topic} messages')
    return [s + loop_offset_ns(k, stamps[0], stamps[-1]) for k in range(loops) for s in stamps]


def _check_crashes(group: ProcessGroup, finished_ok: Sequence[str] = ()) -> None:
    """GraphFailure for the first process that has exited, unless it is in `finished_ok` with code 0."""
    for name, code in group.poll().items():
        if not (name in finished_ok and code == 0):
            raise GraphFailure(name, f'node {name} exited with code {code} (log: {group.log_path(name)})')


def _wait_connected(node: RecorderNode, executor: SingleThreadedExecutor, group: ProcessGroup,
                    settings: GraphSettings, input_topic: str) -> None:
    """Spin until every expected endpoint exists; GraphFailure on a crash or after STARTUP_TIMEOUT_S."""
    expected = expected_connections(settings.cameras, input_topic)
    deadline = time.monotonic() + STARTUP_TIMEOUT_S
    while missing := node.missing_links(expected):
        _check_crashes(group)
        if time.monotonic() > deadline:
            raise GraphFailure('', f'graph not connected after {STARTUP_TIMEOUT_S:g} s: no {", no ".join(missing)}')
        executor.spin_once(timeout_sec=_SPIN_S)


def _play(node: RecorderNode, executor: SingleThreadedExecutor, group: ProcessGroup, settings: GraphSettings,
          stamps: Sequence[int], memory: MemoryLog) -> bool:
    """Spin until every stamp has an output; True when it stopped because nothing happened for
    `timeout` s since the last input or output seen or the player's exit (STARTUP_TIMEOUT_S
    after the player's start while neither happened yet)."""
    wanted = set(stamps)
    started = time.monotonic()
    player_done: float | None = None
    sampled = 0.0
    while not wanted <= node.outputs.keys():
        executor.spin_once(timeout_sec=_SPIN_S)
        if time.monotonic() - sampled > MEMORY_PERIOD_S:
            sampled = time.monotonic()
            memory.sample({name: p.pid for name, p in group.procs.items() if p.poll() is None}, len(node.outputs))
        _check_crashes(group, finished_ok=(PLAYER,))
        if player_done is None and PLAYER in group.poll():
            player_done = time.monotonic()
        limit = settings.timeout if node.last_activity or player_done else STARTUP_TIMEOUT_S
        if time.monotonic() - max(started, player_done or 0.0, node.last_activity) > limit:
            return True
    # Take what is still queued (camera infos of the last frames) before the nodes stop.
    deadline = time.monotonic() + _DRAIN_S
    while time.monotonic() < deadline:
        executor.spin_once(timeout_sec=_SPIN_S)
    return False


def run_graph(settings: GraphSettings, config: Path, nodes: Sequence[NodeSpec], stamps: list[int],
              log_dir: Path, node: RecorderNode, executor: SingleThreadedExecutor, input_topic: str,
              per_loop: int) -> Outcome:
    """Start the nodes, wait for the connections, play, collect; every process is stopped on return,
    also after Ctrl-C (outcome.interrupted). input_topic: what each detector reads in its camera
    namespace; per_loop: stamps in one pass of the bag (the memory baseline)."""
    outcome = Outcome(stamps, MemoryLog(per_loop))
    # one BLAS thread per node: a dozen numpy processes on a few cores only fight otherwise
    env = {'OMP_NUM_THREADS': '1', 'OPENBLAS_NUM_THREADS': '1', **os.environ, 'PYTHONUNBUFFERED': '1'}
    with ProcessGroup(log_dir, env) as group:
        try:
            for spec in nodes:
                if spec.executable == PLAYER:
                    _wait_connected(node, executor, group, settings, input_topic)
                group.start(spec.name, node_command(spec, config))
            outcome.stalled = _play(node, executor, group, settings, stamps, outcome.memory)
        except GraphFailure as failure:
            outcome.failure = failure
        except Interrupted as exc:
            outcome.interrupted = exc.signum
        group.stop()
        if outcome.failure is not None and outcome.failure.node:
            outcome.log_tail = group.log_tail(outcome.failure.node, _LOG_TAIL)
    return outcome


def frame_ranges(frames: Sequence[int]) -> str:
    """'300-305, 410' for [300, 301, 302, 303, 304, 305, 410]."""
    f = np.unique(np.asarray(frames, dtype=int))
    if f.size == 0:
        return 'none'
    breaks = np.flatnonzero(np.diff(f) != 1)
    starts, ends = f[np.r_[0, breaks + 1]], f[np.r_[breaks, f.size - 1]]
    return ', '.join(f'{a}' if a == b else f'{a}-{b}' for a, b in zip(starts, ends))


def latency_ms(info_at: Mapping[int, int], output_at: Mapping[int, int]) -> np.ndarray:
    """(N,) ms from a stamp's /cam0/camera_info receipt to its /skeletons receipt (ns; stamps with both)."""
    common = sorted(info_at.keys() & output_at.keys())
    return 1e-6 * (np.array([output_at[s] for s in common], dtype=np.int64)
                   - np.array([info_at[s] for s in common], dtype=np.int64))


def _frame(stamp: int, frame_rate: float) -> int:
    return round(stamp * frame_rate / 1e9)


def report(outcome: Outcome, node: RecorderNode, settings: GraphSettings, out: TextIO) -> list[str]:
    """Print counts and latency; returns the problems (missing, duplicate, unexpected, bad outputs)."""
    wanted = set(outcome.stamps)
    missing = [s for s in outcome.stamps if s not in node.outputs]
    duplicate = [s for s, n in node.received.items() if n > 1]
    unexpected = [s for s in node.received if s not in wanted]
    fr = settings.frame_rate
    print(f'frames in {len(outcome.stamps)} (seen on {TIMING_TOPIC}: {len(node.info_at.keys() & wanted)}), '
          f'frames out {len(wanted & node.outputs.keys())}', file=out)
    print(f'missing {len(missing)}: {frame_ranges([_frame(s, fr) for s in missing])}; '
          f'duplicate {len(duplicate)}: {frame_ranges([_frame(s, fr) for s in duplicate])}; '
          f'unexpected {len(unexpected)}: {frame_ranges([_frame(s, fr) for s in unexpected])}', file=out)
    lat = latency_ms(node.info_at, {s: t for s, t in node.output_at.items() if s in wanted})
    if lat.size:
        p50, p95 = np.percentile(lat, [50, 95])
        print(f'latency {TIMING_TOPIC} -> {OUTPUT_TOPIC}: p50 {p50:.1f} ms, p95 {p95:.1f} ms, '
              f'max {lat.max():.1f} ms ({lat.size} frames)', file=out)
        # a graph that falls behind real time shows latency growing through the run
        quarters = [f'{np.median(q):.0f}' for q in np.array_split(lat, 4) if q.size]
        print(f'latency p50 by quarter of the run: {", ".join(quarters)} ms', file=out)
    problems = [f'{len(missing)} of {len(outcome.stamps)} input stamps got no {OUTPUT_TOPIC}'] if missing else []
    problems += [f'{len(duplicate)} stamps got more than one {OUTPUT_TOPIC}'] if duplicate else []
    problems += [f'{len(unexpected)} {OUTPUT_TOPIC} stamps are not in the bag'] if unexpected else []
    problems += [f'{len(node.bad)} undecodable {OUTPUT_TOPIC} messages, first: {node.bad[0]}'] if node.bad else []
    return problems


def save_predictions(outcome: Outcome, node: RecorderNode, frame_rate: float, path: Path) -> int:
    """Write the received frames in bag order; returns how many. Written beside and renamed into
    place, so that an interruption never leaves a half-written file."""
    results = [FrameResult(_frame(s, frame_rate), [int(i) for i in node.outputs[s][0]], node.outputs[s][1])
               for s in outcome.stamps if s in node.outputs]
    path.parent.mkdir(parents=True, exist_ok=True)
    partial = path.with_name(path.name + '.partial')
    with open(partial, 'w', encoding='utf-8') as f:
        n = write_predictions(results, f)
    os.replace(partial, path)
    return n


def score(predictions: Path, frames: Sequence[int], root: str | None, out: TextIO, loops: int = 1) -> None:
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


def run(args: argparse.Namespace, out: TextIO | None = None, err: TextIO | None = None) -> int:
    out, err = out or sys.stdout, err or sys.stderr
    settings = graph_settings(args.config)
    settings = replace(settings, bag=args.bag or settings.bag, predictions=args.predictions or settings.predictions,
                       rate=settings.rate if args.rate is None else args.rate)
    root = None if args.data_root is None else str(data_root(args.data_root).resolve())
    config = args.config.resolve()
    bag = Path(settings.bag).resolve()
    predictions = Path(settings.predictions)
    log_dir = args.log_dir or predictions.with_name(predictions.stem + '_logs')
    params = load_params(args.config)
    try:
        backend = detector_backend(params)
        if backend not in INPUT_TOPICS:
            raise ValueError(f'heatmap_detector backend {backend!r} is not one of {", ".join(INPUT_TOPICS)}')
    except ValueError as exc:
        raise ValueError(f'{args.config}: {exc}') from None
    input_topic = INPUT_TOPICS[backend]
    if args.loops < 1:
        raise ValueError(f'--loops must be >= 1, got {args.loops}')
    stamps = input_stamps(bag, f'/cam0/{input_topic}', args.loops)
    per_loop = len(stamps) // args.loops
    nodes = graph_nodes(settings.cameras, str(bag), settings.rate, root, args.loops)
    for section in unknown_nodes(params, nodes):
        print(f'{PROG}: warning: {args.config}: section {section} matches no node of the graph', file=err)

    # Set before the first rclpy context: it and every child read them.
    os.environ.setdefault('ROS_AUTOMATIC_DISCOVERY_RANGE', 'LOCALHOST')
    if (config.parent / DDS_PROFILE).is_file():
        os.environ.setdefault(DDS_PROFILE_ENV, str(config.parent / DDS_PROFILE))
    if args.domain_id is not None:
        os.environ['ROS_DOMAIN_ID'] = str(args.domain_id)
    context = Context()
    rclpy.init(context=context, signal_handler_options=SignalHandlerOptions.NO)
    node = None
    try:
        node = RecorderNode(context)
        executor = SingleThreadedExecutor(context=context)
        executor.add_node(node)
        print(f'{PROG}: {len(stamps)} frames from {bag}, rate {settings.rate:g}, logs in {log_dir}', file=out)
        outcome = run_graph(settings, config, nodes, stamps, log_dir, node, executor, input_topic, per_loop)
    finally:
        if node is not None:
            node.destroy_node()
        context.try_shutdown()
    if outcome.failure is not None:
        print(f'{PROG}: error: {outcome.failure}', file=err)
        for line in outcome.log_tail.splitlines():
            print(f'  | {line}', file=err)
        return 1
    problems = report(outcome, node, settings, out)
    n = save_predictions(outcome, node, settings.frame_rate, predictions)
    print(f'wrote {n} frames to {predictions}', file=out)
    if outcome.interrupted is not None:
        print(f'{PROG}: interrupted by {signal.Signals(outcome.interrupted).name}; every node stopped, '
              f'{n} of {len(stamps)} frames written', file=err)
        return 128 + outcome.interrupted
    if args.loops > 1:
        print('resident memory per process:', file=out)
        for line in outcome.memory.lines():
            print(f'  {line}', file=out)
    if settings.dataset == 'shelf' and n:
        score(predictions, [_frame(s, settings.frame_rate) for s in stamps[:per_loop]], root, out, args.loops)
    if outcome.stalled:
        problems.insert(0, f'stopped: no {OUTPUT_TOPIC} for {settings.timeout:g} s')
    if problems:
        print(f'{PROG}: error: {"; ".join(problems)}', file=err)
        return 1
    return 0


def main(argv: Sequence[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    try:
        return run(args)
    except (FileNotFoundError, ValueError) as exc:
        print(f'{PROG}: error: {exc}', file=sys.stderr)
        return 2


if __name__ == '__main__':
    sys.exit(main())
