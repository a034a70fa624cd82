"""Running the node graph on a bag: start the node processes, wait until the graph is connected
and the recorder's readers have matched, play, collect every output, stop everything.

The order makes start-up lossless: a volatile message sent before its writer and reader have
matched each other is lost, so the player starts only once every link between the nodes reports
matched at both ends (core.health.links) and the recorder has signalled that its readers matched
the player's writers. With a Respawner, a node that dies (not the player) is started again
instead of ending the run. The whole order: docs/cli.md#mvpose-graph (Start order)."""
from __future__ import annotations

import os
import subprocess
import sys
import time
from concurrent.futures import Future
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable, Mapping, Sequence

from rclpy.executors import SingleThreadedExecutor

from mvpose_ros.bags.io import read_bag
from mvpose_ros.bags.replay import loop_offset_ns
from mvpose_ros.core.evaluation.predictions import frame_line
from mvpose_ros.core.health.thresholds import HealthThresholds
from mvpose_ros.core.inference.window import FrameResult
from mvpose_ros.core.kernel_cache import caches_fresh, import_root
from mvpose_ros.graph.config import (GraphSettings, NodeSpec, composed_command, expected_connections, node_command,
                                     played_connections, processes)
from mvpose_ros.graph.cpu import CpuLog
from mvpose_ros.graph.memory import MemoryLog
from mvpose_ros.graph.processes import Interrupted, ProcessGroup
from mvpose_ros.graph.recorder import OUTPUT_TOPIC, TIMING_TOPIC, SkeletonRecorder
from mvpose_ros.graph.report import frame_of
from mvpose_ros.graph.respawn import Restart, Respawner

PLAYER = 'bag_player'
SPIN_S = 0.05
DRAIN_S = 0.25  # at most this long for camera infos and live estimates still queued once every output has come
# at most this long for the detectors' next diagnostics after the end, which hold their refusals
REFUSALS_DRAIN_S = HealthThresholds().period + 0.5
# once a camera cannot work, the others that cannot (a camera that started later) are waited for this long
UNUSABLE_GRACE_S = REFUSALS_DRAIN_S
OVERLAY_DRAIN_S = 1.0  # at most this long for the overlays of the last set (drawn after its live estimate)
OVERLAY_QUIET_S = 0.2  # the last set's overlays are all in once none came for this long after its first
# Node start-up (imports, calibration, models, DDS discovery, the player's wait for readers).
STARTUP_TIMEOUT_S = 60.0
LOG_TAIL = 15
SAMPLE_PERIOD_S = 1.0


Stamps = Sequence[int] | Future  # the input stamps (ns), or a future of them: see run_graph


def _known(stamps: Stamps) -> Sequence[int]:
    """The stamps (a future's result: waited for, an exception raised)."""
    return stamps.result() if isinstance(stamps, Future) else stamps


class GraphFailure(Exception):
    """The graph cannot finish: `node` (a process name, or '' for the graph as a whole) and why."""

    def __init__(self, node: str, reason: str) -> None:
        super().__init__(reason)
        self.node = node


@dataclass
class Outcome:
    """How the run ended: why it stopped early if it did (a failure, a stall, or the signal that
    interrupted it), the end of the failed node's log, the nodes' memory and CPU, and every restart
    of a node (with a Respawner)."""

    memory: MemoryLog = field(default_factory=lambda: MemoryLog(0))
    cpu: CpuLog = field(default_factory=CpuLog)
    failure: GraphFailure | None = None
    log_tail: str = ''
    stalled: bool = False
    interrupted: int | None = None
    restarts: list[Restart] = field(default_factory=list)


@dataclass
class Supervision:
    """What watches the node processes while the graph runs: without a respawner the first exit is
    a GraphFailure; with one, a dead node is restarted and the recorder armed on its output topic
    (outputs: process name -> the topic it publishes, relative)."""

    respawner: Respawner | None = None
    outputs: Mapping[str, str] = field(default_factory=dict)


def input_stamps(bag: Path, topic: str, loops: int = 1) -> list[int]:
    """Header stamps (ns) of the frames the player sends: the log times of the bag's messages on
    topic (camera 0's detector input, as named in the bag), moved on for each later loop as the
    player does."""
    stamps = [stamp for _, _, stamp, _ in read_bag(bag, [topic])]
    if not stamps:
        raise ValueError(f'{bag}: no {topic} messages')
    return [s + loop_offset_ns(k, stamps[0], stamps[-1]) for k in range(loops) for s in stamps]


def _check_crashes(group: ProcessGroup, finished_ok: Sequence[str], watch: Supervision | None,
                   node: SkeletonRecorder) -> None:
    """GraphFailure for the first process that has exited, unless it is in `finished_ok` with code 0
    or `watch` respawns it (then it is restarted once its delay has passed, and `node` armed)."""
    respawner = watch.respawner if watch else None
    for name, code in group.poll().items():
        if (name in finished_ok and code == 0) or (respawner is not None and respawner.pending(name)):
            continue
        if respawner is None or name == PLAYER:
            raise GraphFailure(name, f'node {name} exited with code {code} (log: {group.log_path(name)})')
        why = respawner.exited(name, code, group.log_tail(name, LOG_TAIL))
        if why is not None:
            raise GraphFailure(name, f'node {name} {why} (log: {group.log_path(name)})')
        died = respawner.restarts[-1].died_ns
        node.arm(watch.outputs.get(name, OUTPUT_TOPIC), died)
        node.arm(OUTPUT_TOPIC, died)
    for restart in respawner.due() if respawner else ():
        group.restart(restart.node, f'restart {restart.count}, {restart.cause}')
        respawner.restarted(restart.node)


def _spin_until(node: SkeletonRecorder, executor: SingleThreadedExecutor, group: ProcessGroup,
                done: Callable[[], bool], why_not: Callable[[], str], watch: Supervision | None = None) -> None:
    """Spin until done(); GraphFailure on a crash, or after STARTUP_TIMEOUT_S with why_not()."""
    deadline = time.monotonic() + STARTUP_TIMEOUT_S
    while not done():
        _check_crashes(group, (), watch, node)
        if time.monotonic() > deadline:
            raise GraphFailure('', why_not())
        executor.spin_once(timeout_sec=SPIN_S)


def _wait_connected(node: SkeletonRecorder, executor: SingleThreadedExecutor, group: ProcessGroup,
                    expected: Mapping[str, Sequence[str]], watch: Supervision) -> None:
    """Until every expected endpoint exists, the recorder's skeletons reader has matched, and the
    nodes report every link between them matched (SkeletonRecorder.not_connected)."""
    _spin_until(node, executor, group, lambda: not node.not_connected(expected),
                lambda: f'graph not connected after {STARTUP_TIMEOUT_S:g} s: {"; ".join(node.not_connected(expected))}',
                watch)


def _start_player(node: SkeletonRecorder, executor: SingleThreadedExecutor, group: ProcessGroup,
                  spec: NodeSpec, config: Path | Sequence[Path], played: Mapping[str, Sequence[str]],
                  watch: Supervision) -> None:
    """Start the player; with a start_topic, let it play once the recorder's camera_info readers
    have matched its writers and the nodes report every link of `played` (the player's topics the
    nodes read) matched: a volatile message sent before its reader matched is lost (bp_solver
    without a camera's first CameraInfo answered the first set of a rig bag with no people)."""
    start_topic = str(spec.parameters.get('start_topic', ''))
    group.start(spec.name, node_command(spec, config))
    if start_topic:
        _spin_until(node, executor, group, node.timing_matched,
                    lambda: f'the player did not publish /{TIMING_TOPIC} within {STARTUP_TIMEOUT_S:g} s', watch)
        _spin_until(node, executor, group, lambda: not node.not_connected(played),
                    lambda: f'the player not connected after {STARTUP_TIMEOUT_S:g} s: '
                            f'{"; ".join(node.not_connected(played))}', watch)
        node.open_gate(start_topic)


def _play(node: SkeletonRecorder, executor: SingleThreadedExecutor, group: ProcessGroup, settings: GraphSettings,
          stamps: Stamps, outcome: Outcome, quiet: float = 0.0, watch: Supervision | None = None) -> bool:
    """Spin until every stamp has an output or was dropped (skeletons/dropped: a set short of
    min_cameras, or bp_solver behind the input); True when it stopped because nothing happened for
    `timeout` s since the last input or output seen or the player's exit (STARTUP_TIMEOUT_S
    after the player's start while neither happened yet). quiet > 0 (a paced rig run, whose
    graph drops sets): also done, not stalled, once the player has exited and nothing came for
    `quiet` s. A run in which a node was restarted is done once the player has exited and the
    last frame's output is in: the graph keeps the frames' order, so every frame still to come
    has come, and those lost in the restart never will. GraphFailure, a line per camera with its
    cause, once a detector says a camera cannot work (core.health.refusals) and UNUSABLE_GRACE_S
    more have passed for the others that cannot either."""
    wanted: set[int] | None = None  # known once the stamps are (a future's: grouped meanwhile)
    started = time.monotonic()
    player_done: float | None = None
    unusable_since: float | None = None  # when a detector first said a camera cannot work
    sampled = 0.0
    while wanted is None or not node.accounted(wanted):
        if wanted is None and (not isinstance(stamps, Future) or stamps.done()):
            wanted = set(_known(stamps))
        executor.spin_once(timeout_sec=SPIN_S)
        if time.monotonic() - sampled > SAMPLE_PERIOD_S:
            sampled = time.monotonic()
            pids = {name: p.pid for name, p in group.procs.items() if p.poll() is None}
            outcome.memory.sample(pids, len(node.outputs))
            outcome.cpu.sample(pids)
        _check_crashes(group, (PLAYER,), watch, node)
        if unusable_since is None and node.unusable:
            unusable_since = time.monotonic()
        if unusable_since is not None and time.monotonic() - unusable_since > UNUSABLE_GRACE_S:
            raise GraphFailure('', '\n'.join(node.unusable))
        if player_done is None and PLAYER in group.poll():
            player_done = time.monotonic()
        limit = settings.timeout if node.last_activity or player_done else STARTUP_TIMEOUT_S
        idle = time.monotonic() - max(started, player_done or 0.0, node.last_activity)
        restarted = bool(watch and watch.respawner and watch.respawner.restarts)
        if restarted and player_done is not None and wanted and max(wanted) in node.outputs:
            break
        if quiet > 0 and player_done is not None and idle > quiet:
            return False
        if idle > limit:
            return True
    # The detectors' refusal counts as of the end: their next diagnostics.
    end = time.monotonic()
    deadline = end + REFUSALS_DRAIN_S
    while not node.refusals_since(end) and time.monotonic() < deadline:
        executor.spin_once(timeout_sec=SPIN_S)
    # Camera infos and live estimates of the last frames may still be queued behind their outputs.
    deadline = time.monotonic() + DRAIN_S
    wanted = set(_known(stamps))
    solved = wanted - node.dropped
    while not (wanted <= node.info_at.keys() and solved <= node.live_at.keys()) and time.monotonic() < deadline:
        executor.spin_once(timeout_sec=SPIN_S)
    # A set's earliest image has the set's stamp: the last set's overlays come from when that one
    # does until they stop.
    deadline = time.monotonic() + OVERLAY_DRAIN_S
    while node.overlay_stamps is not None and solved and time.monotonic() < deadline and (
            max(solved) not in node.overlay_stamps or time.monotonic() - node.last_overlay < OVERLAY_QUIET_S):
        executor.spin_once(timeout_sec=SPIN_S)
    return False


def run_graph(settings: GraphSettings, config: Path | Sequence[Path], nodes: Sequence[NodeSpec], stamps: Stamps,
              log_dir: Path, node: SkeletonRecorder, executor: SingleThreadedExecutor, input_topic: str,
              per_loop: int, expected: Mapping[str, Sequence[str]] | None = None,
              played: Mapping[str, Sequence[str]] | None = None, quiet: float = 0.0,
              watch: Supervision | None = None, compose: str | None = None) -> Outcome:
    """Start the nodes, wait for the connections, play, collect; every process is stopped on return,
    also after Ctrl-C (outcome.interrupted). config: the parameter file(s) every node gets, in
    order; stamps: the input stamps (ns, in play order), or a future of them (worked out while the
    graph runs); input_topic: what each detector reads in its camera namespace; per_loop: stamps in one
    pass of the bag (the memory baseline); expected: the endpoints to wait for before playing
    (default: the Shelf graph's, expected_connections); played: the player's links to wait for
    before it plays (default: the Shelf graph's, played_connections); quiet: see _play; watch: how
    node exits are handled (default: the first ends the run); compose: which nodes share a process
    (a key of config.COMPOSED; default none)."""
    if expected is None:
        expected = expected_connections(settings.cameras, input_topic)
    if played is None:
        played = played_connections(settings.cameras, input_topic)
    watch = watch or Supervision()
    outcome = Outcome(MemoryLog(per_loop), restarts=watch.respawner.restarts if watch.respawner else [])
    # one BLAS thread per node: a dozen numpy processes on a few cores only fight otherwise
    env = {'OMP_NUM_THREADS': '1', 'OPENBLAS_NUM_THREADS': '1', **os.environ, 'PYTHONUNBUFFERED': '1'}
    # nodes started together on a fresh install would each compile the same kernels at once. In a
    # process of their own, started as the nodes are: run from a checkout, `python -m` takes the
    # checkout's modules, whose cache is not the installed package's
    if not caches_fresh(import_root()):
        subprocess.run([sys.executable, '-m', 'mvpose_ros.core.compiled'], env=env, check=True)
    with ProcessGroup(log_dir, env) as group:
        try:
            for name, specs in processes(nodes, compose):
                if specs[0].executable == PLAYER:
                    _wait_connected(node, executor, group, expected, watch)
                    _start_player(node, executor, group, specs[0], config, played, watch)
                else:
                    group.start(name, node_command(specs[0], config) if len(specs) == 1
                                else composed_command(specs, config))
            outcome.stalled = _play(node, executor, group, settings, stamps, outcome, quiet, watch)
        except GraphFailure as failure:
            outcome.failure = failure
        except Interrupted as exc:
            outcome.interrupted = exc.signum
        group.stop()
        if outcome.failure is not None and outcome.failure.node:
            outcome.log_tail = group.log_tail(outcome.failure.node, LOG_TAIL)
    return outcome


def save_predictions(stamps: Sequence[int], node: SkeletonRecorder, frame_rate: float, path: Path) -> int:
    """Write the received frames of `stamps` in bag order; returns how many. Written beside and
    renamed into place, so that an interruption never leaves a half-written file."""
    lines = [frame_line(FrameResult(frame_of(s, frame_rate), [int(i) for i in node.outputs[s].ids],
                                    node.outputs[s].joints, node.outputs[s].confidence), stamp=int(s))
             for s in stamps if s in node.outputs]
    path.parent.mkdir(parents=True, exist_ok=True)
    partial = path.with_name(path.name + '.partial')
    with open(partial, 'w', encoding='utf-8') as f:
        f.write(''.join(line + '\n' for line in lines))
    n = len(lines)
    os.replace(partial, path)
    return n
