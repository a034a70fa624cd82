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

The work is done in mvpose_ros.graph: `runner` (processes, waits, play, collect), `recorder` (the
recorder node) and `report` (what is printed).
"""
from __future__ import annotations

import argparse
import os
import signal
import sys
from dataclasses import replace
from pathlib import Path
from typing import Sequence, TextIO

import rclpy
from rclpy.context import Context
from rclpy.executors import SingleThreadedExecutor
from rclpy.signals import SignalHandlerOptions

from mvpose_ros.core.evaluation.datasets import data_root
from mvpose_ros.graph.config import detector_backend, graph_nodes, graph_settings, load_params, unknown_nodes
from mvpose_ros.graph.recorder import START_TOPIC, SkeletonRecorder
from mvpose_ros.graph.report import OUTPUT_NAME, frame_of, report, score
from mvpose_ros.graph.runner import input_stamps, run_graph, save_predictions
from mvpose_ros.nodes.heatmap_detector import INPUT_TOPICS
from mvpose_ros.topics import camera_topic

PROG = 'mvpose-graph'
RECORDER_NAME = 'mvpose_graph'
# Fast DDS settings beside the parameter file (config/fastdds.xml: a shared-memory segment large
# enough for the heatmap messages), used by this process and every node unless already chosen.
DDS_PROFILE = 'fastdds.xml'
DDS_PROFILE_ENV = 'FASTRTPS_DEFAULT_PROFILES_FILE'


def build_parser() -> argparse.ArgumentParser:
    """The command line."""
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


def run(args: argparse.Namespace, out: TextIO | None = None, err: TextIO | None = None) -> int:
    """Run the graph as `args` say; returns the exit code."""
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
    stamps = input_stamps(bag, '/' + camera_topic(0, input_topic), args.loops)
    per_loop = len(stamps) // args.loops
    nodes = graph_nodes(settings.cameras, str(bag), settings.rate, root, args.loops, start_topic=START_TOPIC)
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
        node = SkeletonRecorder(RECORDER_NAME, context=context, frame_rate=settings.frame_rate)
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
    problems = report(outcome.stamps, node, settings, out)
    n = save_predictions(outcome.stamps, node, settings.frame_rate, predictions)
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
        score(predictions, [frame_of(s, settings.frame_rate) for s in stamps[:per_loop]], root, out, args.loops)
    if outcome.stalled:
        problems.insert(0, f'stopped: no {OUTPUT_NAME} for {settings.timeout:g} s')
    if problems:
        print(f'{PROG}: error: {"; ".join(problems)}', file=err)
        return 1
    return 0


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point of `mvpose-graph`."""
    args = build_parser().parse_args(argv)
    try:
        return run(args)
    except (FileNotFoundError, ValueError) as exc:
        print(f'{PROG}: error: {exc}', file=sys.stderr)
        return 2


if __name__ == '__main__':
    sys.exit(main())
