"""A run of the whole graph on a bag, as `mvpose-graph` asks for it: the Shelf-style graph (one
detector per camera) or a recorded rig (one whole-rig detector), each node its own process, a
recorder in this process, then the report, the predictions file and the exit code. The command
line is in cli.graph; processes, waits and playing in graph.runner; what is printed in
graph.report.
"""
from __future__ import annotations

import argparse
import os
import shutil
import signal
import sys
import threading
import time
from dataclasses import dataclass, field, replace
from functools import partial
from pathlib import Path
from contextlib import contextmanager
from concurrent.futures import Future
from typing import Any, Callable, Iterator, Mapping, Sequence, TextIO, TypeVar

import rclpy
from rclpy.context import Context
from rclpy.executors import SingleThreadedExecutor
from rclpy.signals import SignalHandlerOptions

from rclpy.qos import qos_profile_sensor_data

from msg_adapters.cdr_header import STAMP_END
from msg_adapters.definitions import message_class
from mvpose_ros.bags.io import bag_summary, has_header, read_bag
from mvpose_ros.bags.replay import SyncSet, group_sets, loop_offset_ns
from mvpose_ros.core.association.approximate_sync import rate_differs, stamp_rate
from mvpose_ros.core.defaults import FRAME_RATE, data_root
from mvpose_ros.core.geometry.rig import Rig, load_rig_file
from mvpose_ros.graph.config import (RIG_RUNNER_KEYS, RIG_TEMPLATE, RUNNER_SECTION, GraphSettings, NodeSpec, RigRun,
                                     detector_backend, graph_nodes, graph_settings, load_params, output_topics,
                                     rig_connections, rig_frame_rate, rig_graph_nodes, rig_played_connections, rig_sync,
                                     runner_section, sets_frame_rate, unknown_nodes, write_overrides)
from mvpose_ros.graph.recorder import START_TOPIC, SkeletonRecorder
from mvpose_ros.graph.report import (OUTPUT_NAME, count_under_sets, frame_of, frame_rate_note, print_first_second,
                                     print_periods, print_refusals, print_restarts, report, restart_effects,
                                     rig_prediction_lines, rig_report, score, score_sets)
from mvpose_ros.graph.respawn import RESPAWN_DELAY_S, RESPAWN_LIMIT, Respawner
from mvpose_ros.graph.runner import PLAYER, Outcome, Supervision, input_stamps, run_graph, save_predictions
from mvpose_ros.graph.startup import process_start_ns, startup_line
from mvpose_ros.graph.topic_recorder import Recorded, TopicRecorder, recorded_inputs, recorded_outputs
from mvpose_ros.nodes.heatmap_detector import INPUT_TOPICS
from mvpose_ros.package_files import package_path
from mvpose_ros.topics import CAMERA_INFO, OVERLAY, PEOPLE2D, camera_namespace, camera_topic

PROG = 'mvpose-graph'
RECORDER_NAME = 'mvpose_graph'
VIEW_NODE = 'foxglove_view'
# Fast DDS settings beside the parameter file (config/fastdds.xml: a shared-memory segment large
# enough for the heatmap messages), used by this process and every node unless already chosen.
DDS_PROFILE = 'fastdds.xml'
DDS_PROFILE_ENV = 'FASTRTPS_DEFAULT_PROFILES_FILE'
# rmw_fastrtps takes the history memory policy and publication mode from the profile only with this
DDS_QOS_FROM_XML_ENV = 'RMW_FASTRTPS_USE_QOS_FROM_XML'
RATE_QUIET_S = 5.0  # a rig run is over this long after the player's end without output
HEAD_S = 10.0  # s of a rig bag read before the graph starts, for its cameras' rate
T = TypeVar('T')
RECORD_QUIET_S = 0.2  # --record: the recording is complete once nothing came for this long after the run
RECORD_DRAIN_S = 2.0  # at most this long


def run(args: argparse.Namespace, out: TextIO | None = None, err: TextIO | None = None) -> int:
    """Run the graph as the command line's `args` say (checked); returns the exit code."""
    out, err = out or sys.stdout, err or sys.stderr
    started_ns = process_start_ns()
    if args.rig is not None:
        return run_rig(args, out, err, started_ns)
    settings = graph_settings(args.config)
    settings = replace(settings, bag=args.bag or settings.bag, predictions=args.predictions or settings.predictions,
                       rate=settings.rate if args.rate is None else args.rate)
    root = None if args.data_root is None else str(data_root(args.data_root).resolve())
    config = args.config.resolve()
    overrides = _override_files(args.overrides)
    bag = Path(settings.bag).resolve()
    predictions = Path(settings.predictions)
    log_dir = args.log_dir or predictions.with_name(predictions.stem + '_logs')
    params = load_params(args.config)
    try:
        backend = detector_backend(_merged([params] + [load_params(f) for f in overrides]))
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
    nodes = _with_view(nodes, args.foxglove_port)
    _warn_unknown([args.config, *overrides], nodes, err)

    watch = _supervision(args, nodes, err)
    nodes = _keeping_ids(nodes, log_dir) if args.respawn else nodes
    _environment(config.parent, args.domain_id)
    cameras = [camera_namespace(c) for c in range(settings.cameras)]
    record = _record_plan(args, cameras, bag, [camera_topic(c, t) for c in cameras for t in (input_topic, CAMERA_INFO)])
    with _recording(record, frame_rate=settings.frame_rate, watch_topics=_watched(watch)) as (node, executor):
        print(f'{PROG}: {len(stamps)} frames from {bag}, rate {settings.rate:g}, logs in {log_dir}', file=out)
        outcome = run_graph(settings, [config, *overrides], nodes, stamps, log_dir, node, executor, input_topic,
                            per_loop, watch=watch, compose=args.compose)
    _print_recording(record, out)
    if outcome.failure is not None:
        return _failed(outcome, err)
    effects = restart_effects(stamps, node, outcome.restarts, watch.outputs, settings.frame_rate)
    problems = report(stamps, node, settings, out, effects)
    print_refusals(node.refusals(), out)
    _print_footprint(outcome, node, started_ns, out)
    print_restarts(effects, _start_ns(node, outcome), watch.outputs, settings.frame_rate, out)
    if args.report_every:
        print_periods(stamps, node, outcome.memory, args.report_every, out)
    n = save_predictions(stamps, node, settings.frame_rate, predictions)
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
    return _verdict(outcome, problems, settings.timeout, err)


def _with_view(nodes: Sequence[NodeSpec], port: int | None) -> list[NodeSpec]:
    """With a port, the nodes and the live view (nodes.foxglove_view on that port) before the player."""
    if port is None:
        return list(nodes)
    view = NodeSpec(VIEW_NODE, '', {'port': port})
    return [n for n in nodes if n.executable != PLAYER] + [view] + [n for n in nodes if n.executable == PLAYER]


def _supervision(args: argparse.Namespace, nodes: Sequence[NodeSpec], err: TextIO,
                 detector_output: str = '') -> Supervision:
    """How the run handles a node that dies: with --respawn, restarted (logged to err)."""
    if not args.respawn:
        return Supervision()
    delay = RESPAWN_DELAY_S if args.respawn_delay is None else args.respawn_delay
    limit = RESPAWN_LIMIT if args.respawn_limit is None else args.respawn_limit
    respawner = Respawner(delay, limit, lambda text: print(f'{PROG}: {text}', file=err, flush=True))
    return Supervision(respawner, output_topics(nodes, detector_output))


def _keeping_ids(nodes: Sequence[NodeSpec], log_dir: Path) -> list[NodeSpec]:
    """The nodes with association keeping its ids' state in <log_dir>/state (emptied: a run starts
    with ids from 0), so that a restarted association keeps the ids."""
    state = log_dir / 'state'
    shutil.rmtree(state, ignore_errors=True)
    return [replace(spec, parameters={**spec.parameters, 'state_dir': str(state.resolve())})
            if spec.executable == 'association' else spec for spec in nodes]


def _watched(watch: Supervision) -> list[str]:
    """The topics the recorder watches for restarted nodes (none without respawn)."""
    return sorted(set(watch.outputs.values())) if watch.respawner else []


def _start_ns(node: SkeletonRecorder, outcome: Outcome) -> int:
    """The run's start on the system clock: the first camera_info's arrival (else the first death)."""
    return min(node.info_at.values(), default=min((r.died_ns for r in outcome.restarts), default=0))


def _environment(config_dir: Path, domain_id: int | None) -> None:
    """Set before the first rclpy context: it and every child read them."""
    os.environ.setdefault('ROS_AUTOMATIC_DISCOVERY_RANGE', 'LOCALHOST')
    if (config_dir / DDS_PROFILE).is_file():
        os.environ.setdefault(DDS_PROFILE_ENV, str(config_dir / DDS_PROFILE))
        os.environ.setdefault(DDS_QOS_FROM_XML_ENV, '1')
    if domain_id is not None:
        os.environ['ROS_DOMAIN_ID'] = str(domain_id)


def rig_run_plan(args: argparse.Namespace) -> tuple[Rig, RigRun, GraphSettings, list[Path], Future[list[SyncSet]]]:
    """What a --rig run will do: the rig, the run, the runner settings, the parameter files (the
    template, then --config) and the bag's synchronised sets, every pass's. Only the bag's first
    HEAD_S s are read for the cameras' rate: the sets are grouped in a thread (a long recording
    starts at once). ValueError naming what is wrong (a damaged bag: from the future's result)."""
    rig_path = args.rig.resolve()
    if not rig_path.is_file():
        raise FileNotFoundError(f'--rig: no such file: {args.rig}')
    rig = load_rig_file(rig_path, data_root=partial(data_root, args.data_root))
    files = ([package_path(RIG_TEMPLATE)] + ([args.config.resolve()] if args.config else [])
             + _override_files(args.overrides))
    params_list = [load_params(f) for f in files]
    section = {k: v for k, v in runner_section(params_list).items() if k in RIG_RUNNER_KEYS}
    missing = [k for k in RIG_RUNNER_KEYS if k not in section]
    if missing:
        raise ValueError(f'{files[0]}: {RUNNER_SECTION}.{missing[0]}: missing')
    max_skew, sync_timeout = rig_sync(params_list)
    bag = Path(args.bag).resolve()
    summary = bag_summary(bag)
    topics = summary.topics
    images = [c.image for c in rig.cameras]
    missing = [t for t in images if t not in topics]
    if missing:
        raise ValueError(f'{bag}: no topic {", ".join(missing)} of the rig {args.rig} (the bag has '
                         f'{", ".join(topics)})')
    head = _image_stamps(bag, images, summary.first_ns + round(HEAD_S * 1e9))
    if not head:
        raise ValueError(f'{bag}: no image messages on the rig\'s topics')
    bag_rate = stamp_rate([[s.members[c.image] for s in _sets(head, images, max_skew, sync_timeout)
                            if c.image in s.members] for c in rig.cameras])
    frame_rate = rig_frame_rate(params_list)
    # --rig alone is enough: without a frame_rate of the user's, the bag's cameras give it
    from_bag = not sets_frame_rate(params_list[1:]) and rate_differs(bag_rate, frame_rate)
    if from_bag:
        frame_rate = round(bag_rate, 2)
        max_skew, sync_timeout = rig_sync(params_list, frame_rate)
    rate = 0.0 if args.lockstep else float(section['rate'] if args.rate is None else args.rate)
    if not (rate > 0 or args.lockstep):
        raise ValueError(f'--rate must be > 0 (or use --lockstep), got {rate:g}')
    sets = _in_background(partial(_every_set, bag, images, max_skew, sync_timeout, args.loops,
                                  None if args.lockstep else (summary.first_ns, summary.last_ns)))
    run = RigRun(str(rig_path), str(bag), args.lockstep, rate, args.qos or str(section['qos']), max_skew,
                 sync_timeout, float(section['ack_timeout']), args.loops, frame_rate, bag_rate, from_bag)
    settings = GraphSettings('rig', len(rig.cameras), str(bag), args.predictions or str(section['predictions']),
                             FRAME_RATE, rate, float(section['timeout']))
    return rig, run, settings, files, sets


def _image_stamps(bag: Path, images: Sequence[str], until_ns: int | None = None) -> list[tuple[str, str, int, bytes]]:
    """The bag's messages on the rig's image topics (logged up to until_ns; None: all), each cut to
    the bytes of its header stamp (all the grouping reads of an image): no image is held."""
    out = []
    for topic, msgtype, log_ns, cdr in read_bag(bag, images):
        if until_ns is not None and log_ns > until_ns:
            break
        out.append((topic, msgtype, log_ns, cdr[:STAMP_END]))
    return out


def _every_set(bag: Path, images: Sequence[str], max_skew: float, sync_timeout: float, loops: int,
               span: tuple[int, int] | None) -> list[SyncSet]:
    """The bag's synchronised sets, then each later pass's, their stamps moved on as the player
    moves them: by the bag's log span (span: first, last log ns), or in lockstep (span None) by its
    sets' span."""
    sets = _sets(_image_stamps(bag, images), images, max_skew, sync_timeout)
    first, last = span or (sets[0].stamp_ns, sets[-1].stamp_ns)
    n = len(sets)
    return sets + [s.moved(loop_offset_ns(k, first, last), k * n + s.index) for k in range(1, loops) for s in sets]


def _stamps_of(sets: Future[list[SyncSet]]) -> Future[list[int]]:
    """The stamps (ns) of the future's sets, once they are known."""
    stamps: Future[list[int]] = Future()
    sets.add_done_callback(lambda done: stamps.set_exception(done.exception()) if done.exception()
                           else stamps.set_result([s.stamp_ns for s in done.result()]))
    return stamps


def _in_background(work: Callable[[], T]) -> Future[T]:
    """work() in a daemon thread (an interrupted run does not wait for it), as a future."""
    future: Future[T] = Future()

    def run() -> None:
        try:
            future.set_result(work())
        except BaseException as exc:  # handed to whoever asks for the result
            future.set_exception(exc)

    threading.Thread(target=run, name='rig_sets', daemon=True).start()
    return future


def _sets(messages: Sequence[tuple[str, str, int, bytes]], images: Sequence[str], max_skew: float,
          sync_timeout: float) -> list[SyncSet]:
    """The synchronised sets of the rig's image messages (_image_stamps), stamps only."""
    return [_stamps_only(s) for s in group_sets(messages, images, max_skew, sync_timeout, has_header)]


def _override_files(paths: Sequence[Path]) -> list[Path]:
    """--overrides files, resolved; ValueError when one holds the runner's own section (its
    settings come from --config alone)."""
    for path in paths:
        if RUNNER_SECTION in load_params(path):
            raise ValueError(f'{path}: --overrides takes node sections only, not {RUNNER_SECTION}')
    return [p.resolve() for p in paths]


def _merged(params_list: Sequence[Mapping[str, Mapping[str, object]]]) -> dict[str, dict[str, object]]:
    """Parameter files' sections merged node by node, a later file's values winning."""
    out: dict[str, dict[str, object]] = {}
    for params in params_list:
        for node, section in params.items():
            out[node] = {**out.get(node, {}), **section}
    return out


def _warn_unknown(paths: Sequence[Path], nodes: Sequence[NodeSpec], err: TextIO) -> None:
    for path in paths:
        for section in unknown_nodes(load_params(path), nodes):
            print(f'{PROG}: warning: {path}: section {section} matches no node of the graph', file=err)


def _stamps_only(s: SyncSet) -> SyncSet:
    """The set without its message bytes (the runner keeps only stamps)."""
    s.messages = []
    return s


def run_rig(args: argparse.Namespace, out: TextIO, err: TextIO, started_ns: int) -> int:
    """mvpose-graph --rig: the graph on a recorded rig; returns the exit code. started_ns: the
    command's start (system clock ns), for the start-up time."""
    rig, run, settings, files, sets = rig_run_plan(args)
    root = None if args.data_root is None else str(data_root(args.data_root).resolve())
    nodes = rig_graph_nodes(run, root, start_topic=START_TOPIC, overlay=args.overlay is not None)
    nodes = _with_view(nodes, args.foxglove_port)
    _warn_unknown(files[1:], nodes, err)
    rate_note = frame_rate_note(run.bag_rate, run.frame_rate)
    if rate_note:
        print(f'{PROG}: warning: {rate_note}', file=err)
    predictions = Path(settings.predictions)
    log_dir = args.log_dir or predictions.with_name(predictions.stem + '_logs')
    people = [camera_topic(c.name, PEOPLE2D) for c in rig.cameras]
    watch = _supervision(args, nodes, err, people[0])
    nodes = _keeping_ids(nodes, log_dir) if args.respawn else nodes
    files = [*files, write_overrides(nodes, log_dir / 'runner_overrides.yaml')]
    _environment(files[0].parent, args.domain_id)
    overlays = {camera_topic(c.name, OVERLAY): args.overlay / c.name for c in rig.cameras} if args.overlay else {}
    record = _record_plan(args, rig.names, Path(run.bag), [t for c in rig.cameras for t in (c.image, c.camera_info)])
    with _recording(record, timing_topics=[c.camera_info for c in rig.cameras], timing_qos=qos_profile_sensor_data,
                    people_topics=people, watch_topics=_watched(watch), overlay_files=overlays) as (node, executor):
        mode = 'lockstep' if run.lockstep else f'rate {run.rate:g}'
        rate = (f", frame_rate {run.frame_rate:g} Hz from the bag's cameras (no parameter file of yours sets it)"
                if run.rate_from_bag else '')
        print(f'{PROG}: {len(rig.cameras)} cameras ({", ".join(rig.names)}) from {run.bag}, {mode}, qos '
              f'{run.qos}, max_skew {1e3 * run.max_skew:g} ms{rate}, logs in {log_dir}', file=out)
        # per_loop 0: a rig run prints no memory baseline, only its periods (--report-every)
        outcome = run_graph(settings, files, nodes, _stamps_of(sets), log_dir, node, executor, '', 0,
                            expected=rig_connections(rig), played=rig_played_connections(rig, run.lockstep),
                            quiet=RATE_QUIET_S, watch=watch, compose=args.compose)
    _print_recording(record, out)
    if outcome.failure is not None:
        return _failed(outcome, err)
    if outcome.interrupted is not None and not sets.done():  # no wait for the rest of a long bag's sets
        print(f'{PROG}: interrupted by {signal.Signals(outcome.interrupted).name}; every node stopped', file=err)
        return 128 + outcome.interrupted
    sets = sets.result()
    stamps = [s.stamp_ns for s in sets]
    moved = count_under_sets(node, {m: s.stamp_ns for s in sets for m in s.members.values()})
    if moved:
        print(f'{moved} sets came out under a later member\'s stamp (their earliest image never reached the '
              f'graph): counted as those sets', file=out)
    problems = rig_report(stamps, [s.skew_ns for s in sets], node, node.people_stamps,
                          round(run.max_skew * 1e9), run.lockstep, out)
    print_first_second(stamps, [list(s.members.values()) for s in sets], node, node.people_at, node.bundles_at, out)
    print_refusals(node.refusals(), out)
    _print_footprint(outcome, node, started_ns, out)
    print_restarts(restart_effects(stamps, node, outcome.restarts, watch.outputs, settings.frame_rate),
                   _start_ns(node, outcome), watch.outputs, settings.frame_rate, out)
    if args.report_every:
        print_periods(stamps, node, outcome.memory, args.report_every, out)
    lines = rig_prediction_lines(stamps, node.outputs)
    predictions.parent.mkdir(parents=True, exist_ok=True)
    partial = predictions.with_name(predictions.name + '.partial')
    partial.write_text(''.join(line + '\n' for line in lines), encoding='utf-8')
    os.replace(partial, predictions)
    print(f'wrote {len(lines)} sets to {predictions}', file=out)
    if overlays:
        print(f'wrote {node.overlays} overlay images to {args.overlay}', file=out)
    if outcome.interrupted is not None:
        print(f'{PROG}: interrupted by {signal.Signals(outcome.interrupted).name}; every node stopped', file=err)
        return 128 + outcome.interrupted
    if args.ground_truth == 'shelf' and lines:
        names = {c.image: c.name for c in rig.cameras}
        score_sets(predictions, args.frame, root, out,
                   {s.index: [n for t, n in names.items() if t not in s.members] for s in sets})
    return _verdict(outcome, problems, settings.timeout, err)


@dataclass
class RecordPlan:
    """--record: the folder, the topics to write, those among them the run waits for before
    playing (outputs: with the skeletons reader; inputs: with the camera_info readers), and once
    recorded, the messages written per topic."""

    folder: Path
    topics: dict[str, Recorded]
    outputs: list[str]
    inputs: list[str]
    counts: dict[str, int] = field(default_factory=dict)


def _record_plan(args: argparse.Namespace, cameras: Sequence[str], bag: Path,
                 inputs: Sequence[str]) -> RecordPlan | None:
    """What --record writes: the graph's outputs (with --overlay the overlays) and, with
    --record-inputs, those of `inputs` (relative or absolute names) that the bag holds, typed as
    in the bag."""
    if args.record is None:
        return None
    if args.record.exists():
        raise ValueError(f'--record: {args.record} already exists (a recording goes to a new folder)')
    topics = recorded_outputs(cameras, overlays=getattr(args, 'overlay', None) is not None)
    outputs = [t for t, rec in topics.items() if rec.wait]
    played: list[str] = []
    if args.record_inputs:
        held = bag_summary(bag).topics
        played = [t for t in inputs if '/' + t.lstrip('/') in held]
        topics |= recorded_inputs({t: message_class(held['/' + t.lstrip('/')][0]) for t in played})
    return RecordPlan(args.record, topics, outputs, played)


def _print_recording(record: RecordPlan | None, out: TextIO) -> None:
    if record is not None:
        total = sum(record.counts.values())
        print(f'recorded {total} messages on {len(record.topics)} topics to {record.folder} (rosbag2, mcap)', file=out)


def _drain(executor: SingleThreadedExecutor, writer: TopicRecorder) -> None:
    """Write what the recorder's readers still hold (the last frames' messages, taken after the
    run's own readers had theirs): spin until nothing came for RECORD_QUIET_S, RECORD_DRAIN_S at most."""
    deadline = time.monotonic() + RECORD_DRAIN_S
    last, quiet_since = -1, time.monotonic()
    while time.monotonic() < deadline and time.monotonic() - quiet_since < RECORD_QUIET_S:
        executor.spin_once(timeout_sec=RECORD_QUIET_S / 4)
        total = sum(writer.counts.values())
        if total != last:
            last, quiet_since = total, time.monotonic()


@contextmanager
def _recording(record: RecordPlan | None = None,
               **options: Any) -> Iterator[tuple[SkeletonRecorder, SingleThreadedExecutor]]:
    """The recorder node (SkeletonRecorder options) in an rclpy context of its own, with its
    executor, and with `record` a TopicRecorder beside it whose readers the run waits for; nodes
    and context are destroyed on leaving (the recording closed), what it recorded stays readable."""
    context = Context()
    rclpy.init(context=context, signal_handler_options=SignalHandlerOptions.NO)
    node = writer = executor = None
    try:
        if record is not None:
            writer = TopicRecorder(record.folder, record.topics, context=context)
            options['also_unmatched'] = lambda inputs: writer.unmatched(record.inputs if inputs else record.outputs)
        node = SkeletonRecorder(RECORDER_NAME, context=context, **options)
        executor = SingleThreadedExecutor(context=context)
        executor.add_node(node)
        if writer is not None:
            executor.add_node(writer)
        yield node, executor
    finally:
        if writer is not None:
            if executor is not None:
                _drain(executor, writer)
            writer.close()
            record.counts = dict(writer.counts)
            writer.destroy_node()
        if node is not None:
            node.destroy_node()
        context.try_shutdown()


def _print_footprint(outcome: Outcome, node: SkeletonRecorder, started_ns: int, out: TextIO) -> None:
    """The start-up time to the first skeleton, the nodes' resident memory and their CPU."""
    line = startup_line(started_ns, node.info_at, node.output_at)
    if line:
        print(line, file=out)
    if outcome.memory.peak:
        print(outcome.memory.total_line(), file=out)
    if outcome.cpu.shares():
        print(outcome.cpu.total_line(), file=out)


def _verdict(outcome, problems: list[str], timeout: float, err: TextIO) -> int:
    """The exit code of a run that finished: 1 with every problem on one line, else 0."""
    if outcome.stalled:
        problems.insert(0, f'stopped: no {OUTPUT_NAME} for {timeout:g} s')
    if problems:
        print(f'{PROG}: error: {"; ".join(problems)}', file=err)
        return 1
    return 0


def _failed(outcome, err: TextIO) -> int:
    """Print why the graph could not run (a line each reason), with the end of the failing node's
    log; exit code 1."""
    for line in str(outcome.failure).splitlines():
        print(f'{PROG}: error: {line}', file=err)
    for line in outcome.log_tail.splitlines():
        print(f'  | {line}', file=err)
    return 1
