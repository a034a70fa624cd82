"""`mvpose-graph`: run the whole ROS graph on a bag and score it.

    mvpose-graph --config config/shelf.yaml [--bag DIR] [--loops N] [--respawn] [--compose MODE] ...
    mvpose-graph --rig FILE --bag DIR [--lockstep | --rate R] [--ground-truth shelf --frame N] ...

A Shelf-style run (--config) plays the Shelf bag through the detectors, association and bp_solver
and prints counts, latency, memory and the PCP against Shelf's ground truth; a recorded rig
(--rig) runs one whole-rig detector on any bag and prints sets in / processed / dropped. Either
way the player starts only once the graph is connected, so the first frame reaches every node.
Argument parsing only: the work is in mvpose_ros.graph (session, runner, recorder, report).
What each option does, the exit codes and the start order: docs/cli.md#mvpose-graph."""
from __future__ import annotations

import argparse
import sys
from pathlib import Path
from typing import Sequence

from mvpose_ros.graph.config import COMPOSED, DEFAULT_COMPOSE
from mvpose_ros.graph.respawn import RESPAWN_DELAY_S, RESPAWN_LIMIT, RESPAWN_WINDOW_S
from mvpose_ros.graph.session import PROG, run

MAX_DOMAIN_ID = 232  # the highest domain id whose DDS ports are valid (Fast DDS refuses higher ones)


def build_parser() -> argparse.ArgumentParser:
    """The command line."""
    p = argparse.ArgumentParser(prog=PROG, description=__doc__.split('\n')[0])
    p.add_argument('--config', type=Path,
                   help='ROS 2 parameter file with every node and the mvpose_graph section (with --rig: '
                        'overrides config/rig_template.yaml)')
    p.add_argument('--overrides', type=Path, action='append', default=[], metavar='FILE',
                   help='a parameter file of node sections only, applied after --config (and the rig '
                        'template); repeatable, a later file wins: e.g. config/crowd.yaml')
    p.add_argument('--rig', type=Path, help='rig file: run the graph on a recording of this rig (needs --bag)')
    p.add_argument('--lockstep', action='store_true',
                   help='--rig: publish the next synchronised set once the previous one is through (every set '
                        'processed)')
    p.add_argument('--qos', choices=('sensor', 'reliable'),
                   help='--rig: how the player publishes (default sensor: best effort, as a camera driver)')
    p.add_argument('--ground-truth', choices=('shelf',),
                   help="--rig: score every set against this dataset's actorsGT frame --frame")
    p.add_argument('--frame', type=int, help='--ground-truth: the actorsGT frame every set of the bag shows')
    p.add_argument('--overlay', type=Path, metavar='DIR',
                   help='--rig: also run the overlay node and write its images, DIR/<camera>/<stamp ns>.jpg (with '
                        '--lockstep every set, else at most its max_rate per camera)')
    p.add_argument('--data-root', help='folder holding data/ and models/ (default: $MVPOSE_DATA_ROOT or ../shared)')
    p.add_argument('--bag', help='bag to play (default: mvpose_graph.bag)')
    p.add_argument('--rate', type=float,
                   help='playback speed, 0 = as fast as the graph keeps up (default: mvpose_graph.rate)')
    p.add_argument('--loops', type=int, default=1,
                   help='replay the bag this many times, stamps moved on every loop (a soak run; default 1)')
    p.add_argument('--predictions', help='predictions file to write (default: mvpose_graph.predictions)')
    p.add_argument('--domain-id', type=int,
                   help=f'ROS_DOMAIN_ID for the graph, 0-{MAX_DOMAIN_ID} (default: inherited)')
    p.add_argument('--log-dir', type=Path, help='per-node logs (default: beside the predictions, <name>_logs)')
    p.add_argument('--respawn', action='store_true',
                   help='restart a node that dies (not the player) instead of stopping the run; the frames lost '
                        'are reported per restart')
    p.add_argument('--respawn-delay', type=float,
                   help=f'--respawn: s between a death and the restart (default {RESPAWN_DELAY_S:g})')
    p.add_argument('--respawn-limit', type=int,
                   help=f'--respawn: restarts of one node within {RESPAWN_WINDOW_S:g} s before the run ends '
                        f'(default {RESPAWN_LIMIT})')
    p.add_argument('--record', type=Path, metavar='DIR',
                   help='also write the run\'s outputs (skeletons, skeletons/live, markers, camera frusta, '
                        'diagnostics; the overlays with --overlay) to DIR, a new rosbag2 MCAP recording')
    p.add_argument('--record-inputs', action='store_true',
                   help='--record: also the inputs played (each camera\'s detector input and camera_info)')
    p.add_argument('--foxglove-port', type=int, metavar='PORT',
                   help='also run the live view: the skeletons, frusta, overlays and diagnostics over Foxglove\'s '
                        'WebSocket protocol on ws://127.0.0.1:PORT (docs/visualize.md)')
    p.add_argument('--compose', choices=list(COMPOSED),
                   help='which nodes share a process (ROS composition): none, a process per node; detectors, '
                        'every heatmap_detector; detectors+association, those and association; all, every node but '
                        f'the player (default: {DEFAULT_COMPOSE}, none with --respawn; docs/footprint.md)')
    p.add_argument('--report-every', type=float, metavar='SECONDS',
                   help='also print frames in / out, latency and memory per node by this many s of the run')
    return p


def _check_arguments(args: argparse.Namespace) -> None:
    """ValueError naming the argument when the combination cannot run."""
    for name in ('respawn_delay', 'respawn_limit'):
        if getattr(args, name) is not None and not args.respawn:
            raise ValueError(f'--{name.replace("_", "-")} needs --respawn')
    if args.respawn and args.compose not in (None, 'none'):
        raise ValueError(f'--respawn restarts one node, not a process of composed nodes: not with --compose '
                         f'{args.compose}')
    if args.respawn_delay is not None and not args.respawn_delay >= 0:
        raise ValueError(f'--respawn-delay must be >= 0 s, got {args.respawn_delay:g}')
    if args.respawn_limit is not None and args.respawn_limit < 1:
        raise ValueError(f'--respawn-limit must be >= 1, got {args.respawn_limit}')
    if args.domain_id is not None and not 0 <= args.domain_id <= MAX_DOMAIN_ID:
        raise ValueError(f'--domain-id must be in 0-{MAX_DOMAIN_ID} (DDS has no port for a higher one), '
                         f'got {args.domain_id}')
    if args.report_every is not None and not args.report_every > 0:
        raise ValueError(f'--report-every must be > 0 s, got {args.report_every:g}')
    if args.foxglove_port is not None and not 0 <= args.foxglove_port <= 65535:
        raise ValueError(f'--foxglove-port must be in 0-65535, got {args.foxglove_port}')
    if args.record_inputs and args.record is None:
        raise ValueError('--record-inputs needs --record')
    if args.rig is None:
        if args.config is None:
            raise ValueError('one of --config (a graph parameter file) or --rig (a rig file) is required')
        for name in ('lockstep', 'qos', 'ground_truth', 'frame', 'overlay'):
            if getattr(args, name):
                raise ValueError(f'--{name.replace("_", "-")} needs --rig')
        return
    if not args.bag:
        raise ValueError('--rig needs --bag (the recording of the rig to play)')
    if args.lockstep and args.rate is not None:
        raise ValueError('--lockstep and --rate exclude each other (lockstep plays as fast as the graph goes)')
    if args.loops < 1:
        raise ValueError(f'--loops must be >= 1, got {args.loops}')
    if (args.ground_truth is None) != (args.frame is None):
        raise ValueError('--ground-truth and --frame go together')


def _compose(args: argparse.Namespace) -> str:
    """The run's --compose: the one given, else DEFAULT_COMPOSE, or 'none' with --respawn (a restart
    is of one node's process)."""
    if args.compose is not None:
        return args.compose
    return 'none' if args.respawn else DEFAULT_COMPOSE


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point of `mvpose-graph`."""
    args = build_parser().parse_args(argv)
    try:
        _check_arguments(args)
        args.compose = _compose(args)
        return run(args)
    except (FileNotFoundError, ValueError) as exc:
        print(f'{PROG}: error: {exc}', file=sys.stderr)
        return 2


if __name__ == '__main__':
    sys.exit(main())
