"""The skeleton recorder: the node that keeps the graph's output, for the runner and on its own.

`SkeletonRecorder` keeps the first skeletons message of every stamp, counts duplicates, keeps the
stamps the graph dropped, and records when (middleware receipt time, ns of the system clock) each
stamp's first camera_info and its skeletons arrived: the graph's latency. `mvpose-graph` runs one
inside its own process; `python -m mvpose_ros.graph.recorder` runs it alone (the compute host of a
split graph), creating a ready file once every link of the graph is matched and exiting once
every input stamp has its output. Options, exit codes and the stats file:
docs/cli.md#the-recorder-on-its-own."""
from __future__ import annotations

import argparse
import json
import sys
import time
from collections import Counter
from pathlib import Path
from typing import AbstractSet, Any, Callable, Mapping, Sequence, TextIO

import rclpy
from diagnostic_msgs.msg import DiagnosticArray
from rclpy.context import Context
from rclpy.event_handler import PublisherEventCallbacks, SubscriptionEventCallbacks
from rclpy.executors import ExternalShutdownException, SingleThreadedExecutor
from rclpy.node import Node
from rclpy.publisher import Publisher
from rclpy.qos import QoSProfile
from rclpy.serialization import deserialize_message
from sensor_msgs.msg import CameraInfo, CompressedImage, PointCloud2
from std_msgs.msg import Empty, Header
from visualization_msgs.msg import MarkerArray

from msg_adapters.cdr_header import header_stamp_ns
from msg_adapters.diagnostics_msg import msg_to_statuses
from msg_adapters.skeleton_msg import Skeletons, msg_to_skeletons
from msg_adapters.stamp import frame_of_stamp, stamp_ns
from mvpose_ros.bags.io import read_bag
from mvpose_ros.core.defaults import FRAME_RATE
from mvpose_ros.core.evaluation.predictions import frame_line
from mvpose_ros.core.health.links import unmatched_links
from mvpose_ros.core.health.refusals import refusals_of
from mvpose_ros.core.health.status import Level, Status
from mvpose_ros.core.inference.window import FrameResult
from mvpose_ros.graph.config import expected_connections
from mvpose_ros.nodes.bag_player import START_QOS
from mvpose_ros.nodes.health import DIAGNOSTICS_QOS
from mvpose_ros.nodes.runtime import DATA_QOS, VIEWER_QOS
from mvpose_ros.topics import (BUNDLES, CAMERA_INFO, DIAGNOSTICS, MARKERS, OPENPOSE, PEOPLE2D, SKELETONS,
                               SKELETONS_DROPPED, SKELETONS_LIVE, camera_topic)

TIMING_TOPIC = camera_topic(0, CAMERA_INFO)  # a frame's latency is timed from its arrival here
OUTPUT_TOPIC = SKELETONS
START_TOPIC = 'bag_player/start'  # the player's start signal (its parameter start_topic)
SPIN_S = 0.05
# Readers and writers without rclpy's default QoS event handlers (a warning on an incompatible QoS
# or type), but for the skeletons reader: each handler is a waitable that the Python executor
# sets up at every wait: with them the runner's camera_info readers, at the cameras' rate, cost
# CPU the nodes need (the figure: docs/benchmarks.md#figures-behind-choices-in-the-code).
NO_EVENTS = SubscriptionEventCallbacks(use_default_callbacks=False)


def graph_topics(cameras: int) -> dict[str, Any]:
    """Every topic the nodes publish -> its message class. Not the player's: a subscriber of
    cam*/openpose other than the detectors would let the player start before they listen."""
    topics: dict[str, Any] = {camera_topic(c, PEOPLE2D): PointCloud2 for c in range(cameras)}
    return topics | {BUNDLES: PointCloud2, OUTPUT_TOPIC: PointCloud2, MARKERS: MarkerArray}


class SkeletonRecorder(Node):
    """Skeletons per stamp, their receipt times, camera 0's camera_info receipt times and the
    stamps the graph dropped.

    stream: a text file every skeletons message goes to as a predictions line (None: kept only);
    measure_cameras: > 0 also records the size of every message the nodes of a graph with that
    many cameras publish (`sizes`, by fully qualified topic name).
    """

    def __init__(self, name: str = 'skeleton_recorder', context: Context | None = None,
                 frame_rate: float = FRAME_RATE, stream: TextIO | None = None, measure_cameras: int = 0,
                 timing_topics: Sequence[str] = (TIMING_TOPIC,), timing_qos: QoSProfile = DATA_QOS,
                 people_topics: Sequence[str] = (), watch_topics: Sequence[str] = (),
                 overlay_files: Mapping[str, Path] | None = None,
                 also_unmatched: Callable[[bool], list[str]] | None = None) -> None:
        """timing_topics: camera_info topics a stamp's latency is timed from (read with timing_qos:
        best effort for a player or driver publishing so); people_topics: people2d topics whose
        stamps are kept in `people_stamps` (by the topic as given), with when each stamp's last
        people2d and each set's bundles came (`people_at`, `bundles_at`); watch_topics: topics (as given,
        PointCloud2: the nodes' outputs) that `arm` can watch, each read from its first `arm` on
        (reading every node's output all along would cost the runner CPU at every frame);
        overlay_files: overlay topic (CompressedImage, the overlay node's) -> folder each of its
        images is written to as <stamp ns>.jpg (their stamps in `overlay_stamps`, None without
        overlay_files; the monotonic s of the last in `last_overlay`); the run waits for these
        readers to match as for the skeletons'; also_unmatched(inputs): readers of another node
        in this process (a TopicRecorder's) not yet matched, that the run waits for as for this
        node's own: its output readers (False) with the skeletons', its input readers (True) with
        the camera_info ones."""
        super().__init__(name, context=context, start_parameter_services=False)
        self.frame_rate = frame_rate
        self.stream = stream
        self.info_at: dict[int, int] = {}
        self.outputs: dict[int, Skeletons] = {}
        self.output_at: dict[int, int] = {}
        self.live_at: dict[int, int] = {}  # stamp -> receipt (ns) of its skeletons/live
        self.dropped: set[int] = set()  # stamps the graph dropped (skeletons/dropped)
        # accounted()'s last no: the stamps asked about, and how many outputs and drops there were
        self._not_accounted: tuple[AbstractSet[int], tuple[int, int]] | None = None
        self.received: Counter[int] = Counter()
        self.bad: list[str] = []
        self.last_activity = 0.0  # monotonic s of the last message, for stall timeouts
        self.last_output = 0.0  # monotonic s of the last skeletons message
        self.sizes: dict[str, list[tuple[int, int]]] = {}  # fully qualified topic -> (stamp ns, bytes)
        self._gate: Publisher | None = None
        self._also_unmatched = also_unmatched or (lambda inputs: [])
        self._infos = [self.create_subscription(CameraInfo, t, self._on_info, timing_qos, raw=True,
                                                event_callbacks=NO_EVENTS) for t in timing_topics]
        self.people_stamps: dict[str, list[int]] = {t: [] for t in people_topics}
        self.people_at: dict[int, int] = {}  # a people2d stamp -> receipt (ns) of its last one
        self.bundles_at: dict[int, int] = {}  # a set's stamp -> receipt (ns) of its bundles (with people_topics)
        for topic in people_topics:
            self.create_subscription(PointCloud2, topic, lambda cdr, info, t=topic: self._on_people(t, cdr, info),
                                     DATA_QOS, raw=True, event_callbacks=NO_EVENTS)
        if people_topics:
            self.create_subscription(PointCloud2, BUNDLES, self._on_bundles, DATA_QOS, raw=True,
                                     event_callbacks=NO_EVENTS)
        self._outputs = [self.create_subscription(PointCloud2, OUTPUT_TOPIC, self._on_skeletons, DATA_QOS,
                                                  raw=True)]
        self.overlays = 0
        self.overlay_stamps: set[int] | None = set() if overlay_files else None
        self.last_overlay = 0.0
        for topic, folder in (overlay_files or {}).items():
            self._outputs.append(self.create_subscription(
                CompressedImage, topic, lambda msg, d=Path(folder): self._on_overlay(d, msg), VIEWER_QOS,
                event_callbacks=NO_EVENTS))
        # timed when there, not waited for: only bp_solver publishes it
        self.create_subscription(PointCloud2, SKELETONS_LIVE, self._on_live, DATA_QOS, raw=True,
                                 event_callbacks=NO_EVENTS)
        self.create_subscription(Header, SKELETONS_DROPPED, self._on_dropped, DATA_QOS, event_callbacks=NO_EVENTS)
        # (topic, since ns) -> receipt ns of the topic's first message after `since`, once heard
        self.first_after: dict[tuple[str, int], int] = {}
        self._armed: set[tuple[str, int]] = set()
        self._watchable = set(watch_topics) - {OUTPUT_TOPIC}
        self._watched: set[str] = set()
        for topic, msg_type in (graph_topics(measure_cameras) if measure_cameras > 0 else {}).items():
            name = self.resolve_topic_name(topic)
            self.sizes[name] = []
            if topic != OUTPUT_TOPIC:
                self._outputs.append(self.create_subscription(
                    msg_type, topic, lambda cdr, t=name, m=msg_type: self._measure(t, m, cdr), DATA_QOS, raw=True,
                    event_callbacks=NO_EVENTS))
        self._output_name = self.resolve_topic_name(OUTPUT_TOPIC)
        self._statuses: dict[str, Status] = {}  # name -> the latest status of that name on /diagnostics
        # the detectors' refusals statuses (core.health.refusals) by name: the latest, and when it came
        self._refusals: dict[str, tuple[Status, float]] = {}
        self.unusable: list[str] = []  # '<camera>: every image refused: <cause>' of each unusable camera, sorted
        self.create_subscription(DiagnosticArray, DIAGNOSTICS, self._on_diagnostics, DIAGNOSTICS_QOS,
                                 event_callbacks=NO_EVENTS)

    def _on_info(self, cdr: bytes, info: Any) -> None:
        self.last_activity = time.monotonic()
        self.info_at.setdefault(header_stamp_ns(cdr), info['received_timestamp'])

    def _on_diagnostics(self, msg: DiagnosticArray) -> None:
        try:
            statuses = msg_to_statuses(msg)
        except ValueError:  # not a status of ours (a level no node here sends)
            return
        now = time.monotonic()
        for status in statuses:
            self._statuses[status.name] = status
            if refusals_of(status) is not None:
                self._refusals[status.name] = status, now
        self.unusable = sorted(f'{s.hardware_id}: {s.message}' for s, _ in self._refusals.values()
                               if s.level == Level.ERROR)

    def refusals_since(self, since: float) -> bool:
        """Whether every refusals status heard was heard again after `since` (monotonic s): the
        counts then include every input before it."""
        return all(at > since for _, at in self._refusals.values())

    def refusals(self) -> dict[str, Counter]:
        """Camera -> its inputs refused since the start by cause, as the detectors last reported."""
        out: dict[str, Counter] = {}
        for status, _ in self._refusals.values():
            camera, causes = refusals_of(status)
            out[camera] = out.get(camera, Counter()) + causes
        return out

    def _on_people(self, topic: str, cdr: bytes, info: Any) -> None:
        stamp = header_stamp_ns(cdr)
        self.people_stamps[topic].append(stamp)
        self.people_at[stamp] = max(self.people_at.get(stamp, 0), info['received_timestamp'])

    def _on_bundles(self, cdr: bytes, info: Any) -> None:
        self.bundles_at.setdefault(header_stamp_ns(cdr), info['received_timestamp'])

    def _measure(self, topic: str, msg_type: Any, cdr: bytes) -> None:
        if msg_type is MarkerArray:  # no header of its own: the stamp of its first marker
            markers = deserialize_message(cdr, MarkerArray).markers
            stamp = stamp_ns(markers[0].header.stamp) if markers else -1
        else:
            stamp = header_stamp_ns(cdr)
        self.sizes[topic].append((stamp, len(cdr)))

    def _on_overlay(self, folder: Path, msg: CompressedImage) -> None:
        folder.mkdir(parents=True, exist_ok=True)
        stamp = stamp_ns(msg.header.stamp)
        (folder / f'{stamp}.jpg').write_bytes(bytes(msg.data))
        self.overlays += 1
        self.overlay_stamps.add(stamp)
        self.last_overlay = time.monotonic()

    def _on_live(self, cdr: bytes, info: Any) -> None:
        self.live_at.setdefault(header_stamp_ns(cdr), info['received_timestamp'])

    def _on_dropped(self, msg: Header) -> None:
        self.last_activity = time.monotonic()
        self.dropped.add(stamp_ns(msg.stamp))

    def arm(self, topic: str, since_ns: int) -> None:
        """Record in first_after[(topic, since_ns)] when the first message on `topic` (skeletons or
        a watch topic) published after since_ns (system clock) was published: its source time, as
        a restarted node's first messages may come before this reader has matched its writer. A
        watch topic is read from its first arm on: a node is armed for when it has died, so its
        restarted writer is new to every reader alike."""
        self._armed.add((topic, since_ns))
        if topic in self._watchable and topic not in self._watched:
            self._watched.add(topic)
            self.create_subscription(PointCloud2, topic, lambda cdr, info, t=topic: self._heard(t, info), DATA_QOS,
                                     raw=True, event_callbacks=NO_EVENTS)

    def _heard(self, topic: str, info: Any) -> None:
        at = info['source_timestamp']
        for key in [k for k in self._armed if k[0] == topic and at > k[1]]:
            self._armed.discard(key)
            self.first_after[key] = at

    def _on_skeletons(self, cdr: bytes, info: Any) -> None:
        self.last_activity = self.last_output = time.monotonic()
        if self._armed:
            self._heard(OUTPUT_TOPIC, info)
        msg = deserialize_message(cdr, PointCloud2)
        stamp = stamp_ns(msg.header.stamp)
        if self._output_name in self.sizes:
            self.sizes[self._output_name].append((stamp, len(cdr)))
        self.received[stamp] += 1
        try:
            decoded = msg_to_skeletons(msg)
        except ValueError as exc:
            self.bad.append(f'{stamp} ns: {exc}')
            return
        if stamp not in self.outputs:
            self.outputs[stamp] = decoded
            self.output_at[stamp] = info['received_timestamp']
        if self.stream is not None:
            result = FrameResult(frame_of_stamp(msg.header.stamp, self.frame_rate), [int(i) for i in decoded.ids],
                                 decoded.joints, decoded.confidence)
            self.stream.write(frame_line(result, stamp=stamp) + '\n')
            self.stream.flush()

    def accounted(self, wanted: AbstractSet[int]) -> bool:
        """Whether every stamp of `wanted` has its output or was dropped. Callers ask at every spin,
        with tens of thousands of stamps in a long run: the answer is worked out again only once an
        output or a dropped stamp has come since it was last no (both only grow)."""
        seen = (len(self.outputs), len(self.dropped))
        if self._not_accounted is not None and self._not_accounted[0] is wanted and self._not_accounted[1] == seen:
            return False
        done = wanted <= self.outputs.keys() or (bool(self.dropped) and wanted - self.dropped <= self.outputs.keys())
        self._not_accounted = None if done else (wanted, seen)
        return done

    def missing_links(self, expected: Mapping[str, Sequence[str]]) -> list[str]:
        """Expected endpoints not yet in the ROS graph, e.g. 'subscriber of /cam3/openpose'."""
        count = {'pub': self.count_publishers, 'sub': self.count_subscribers}
        word = {'pub': 'publisher', 'sub': 'subscriber'}
        return [f'{word[end]} of {self.resolve_topic_name(topic)}' for topic, ends in expected.items()
                for end in ends if count[end](topic) == 0]

    def not_connected(self, expected: Mapping[str, Sequence[str]]) -> list[str]:
        """What keeps the graph from playing without loss, in words (empty once connected): an
        expected endpoint not yet visible, a reader of this node not yet matched, a link between
        two of the graph's nodes (a topic of `expected` with both ends) whose writer has not yet
        matched every reader, or a reader every writer, by the nodes' links on /diagnostics."""
        missing = [f'no {m}' for m in self.missing_links(expected)]
        missing += [f'no matched writer of {t}' for t in self.unmatched_outputs()]
        if missing:
            return missing
        links = [self.resolve_topic_name(t) for t, ends in expected.items() if {'pub', 'sub'} <= set(ends)]
        seen = {t: (self.count_publishers(t), self.count_subscribers(t)) for t in links}
        return unmatched_links(self._statuses.values(), seen)

    def unmatched_outputs(self) -> list[str]:
        """This node's readers of skeletons (and of every measured topic) that have not matched a
        writer yet (bp_solver's, ...), by fully qualified name: once matched, a reader drops
        nothing that writer sends."""
        return [sub.topic_name for sub in self._outputs if sub.get_publisher_count() == 0] + self._also_unmatched(False)

    def timing_matched(self) -> bool:
        """Whether every camera_info reader of this node has matched a writer (the player's)."""
        return all(sub.get_publisher_count() > 0 for sub in self._infos) and not self._also_unmatched(True)

    def open_gate(self, topic: str = START_TOPIC) -> None:
        """Let a player waiting on `topic` (its start_topic) play: one latched message."""
        if self._gate is None:
            self._gate = self.create_publisher(Empty, topic, START_QOS,
                                               event_callbacks=PublisherEventCallbacks(use_default_callbacks=False))
            self._gate.publish(Empty())


def build_parser() -> argparse.ArgumentParser:
    """The command line of `python -m mvpose_ros.graph.recorder`."""
    p = argparse.ArgumentParser(prog='python -m mvpose_ros.graph.recorder', description=__doc__.split('\n')[0])
    p.add_argument('--bag', required=True, type=Path,
                   help='the bag to be played: its camera 0 openpose stamps are the input')
    p.add_argument('--predictions', required=True, type=Path, help='predictions file, written as outputs come')
    p.add_argument('--ready', required=True, type=Path,
                   help='created once the graph is connected: every endpoint visible, every link matched')
    p.add_argument('--stats', required=True, type=Path, help='JSON summary written at the end')
    p.add_argument('--cameras', type=int, default=5)
    p.add_argument('--frame-rate', type=float, default=FRAME_RATE)
    p.add_argument('--timeout', type=float, default=60.0,
                   help='s without a new output (or before the graph is visible) before giving up')
    p.add_argument('--drain', type=float, default=1.0, help='s to keep listening once every stamp has its output')
    p.add_argument('--measure', action='store_true',
                   help='also record the size of every message the nodes publish')
    p.add_argument('--start-topic', default='',
                   help="once ready, let a player with this start_topic play (e.g. 'bag_player/start')")
    return p


def _spin_until(executor: SingleThreadedExecutor, done, timeout: float) -> bool:
    deadline = time.monotonic() + timeout
    while not done():
        if time.monotonic() > deadline:
            return False
        executor.spin_once(timeout_sec=SPIN_S)
    return True


def record(args: argparse.Namespace) -> bool:
    """Record until complete (True) or timed out (False)."""
    wanted = {stamp for _, _, stamp, _ in read_bag(args.bag, ['/' + camera_topic(0, OPENPOSE)])}
    expected = expected_connections(args.cameras)
    rclpy.init()
    stream = open(args.predictions, 'w', encoding='utf-8')
    node = SkeletonRecorder(stream=stream, frame_rate=args.frame_rate,
                            measure_cameras=args.cameras if args.measure else 0)
    executor = SingleThreadedExecutor()
    executor.add_node(node)
    complete = False
    try:
        if not _spin_until(executor, lambda: not node.not_connected(expected), args.timeout):
            print(f'graph not connected after {args.timeout:g} s: {"; ".join(node.not_connected(expected))}',
                  file=sys.stderr)
            return False
        args.ready.touch()
        if args.start_topic:
            if not _spin_until(executor, node.timing_matched, args.timeout):
                print(f'no player on {node.resolve_topic_name(TIMING_TOPIC)} after {args.timeout:g} s', file=sys.stderr)
                return False
            node.open_gate(args.start_topic)
        node.last_output = time.monotonic()
        while not node.accounted(wanted):
            if time.monotonic() - node.last_output > args.timeout:
                print(f'no {OUTPUT_TOPIC} for {args.timeout:g} s; {len(wanted - node.outputs.keys() - node.dropped)} '
                      f'of {len(wanted)} stamps missing', file=sys.stderr)
                return False
            executor.spin_once(timeout_sec=SPIN_S)
        complete = wanted <= node.outputs.keys()
        drain_until = time.monotonic() + args.drain
        while time.monotonic() < drain_until:
            executor.spin_once(timeout_sec=SPIN_S)
        if not complete:
            print(f'{len(wanted - node.outputs.keys())} of {len(wanted)} stamps dropped by the graph '
                  f'(skeletons/dropped)', file=sys.stderr)
        return complete
    except (KeyboardInterrupt, ExternalShutdownException):
        return False
    finally:
        stream.close()
        args.stats.write_text(json.dumps({'complete': complete, 'bad': node.bad, 'dropped': sorted(node.dropped),
                                          'topics': node.sizes}))
        executor.shutdown()
        node.destroy_node()
        rclpy.try_shutdown()


def main(argv: Sequence[str] | None = None) -> int:
    """Run the recorder; exit code 0 when every input stamp got its output."""
    return 0 if record(build_parser().parse_args(argv)) else 1


if __name__ == '__main__':
    sys.exit(main())
