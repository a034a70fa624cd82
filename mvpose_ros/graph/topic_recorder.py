"""Recording a run as rosbag2 MCAP: the node that writes every message of the graph's output
topics (and, when asked, its inputs) as it arrives, message definitions included, so that
`ros2 bag info/play` and Foxglove open the folder as it is.

`mvpose-graph --record DIR` runs one inside its own process; `mvpose-record DIR [--rig FILE]`
records a live rig, as `ros2 bag record` would. Each message is written as the middleware
delivered it (CDR), its receipt time the log time. Outputs are read reliable, overlays and inputs
best effort, so the recorder never holds up a camera. Topics and sizes: docs/visualize.md#record-a-run."""
from __future__ import annotations

import argparse
import signal
import sys
import time
from dataclasses import dataclass
from functools import partial
from pathlib import Path
from typing import Any, Mapping, Sequence

import rclpy
from diagnostic_msgs.msg import DiagnosticArray
from rclpy.context import Context
from rclpy.event_handler import SubscriptionEventCallbacks
from rclpy.executors import ExternalShutdownException, SingleThreadedExecutor
from rclpy.node import Node
from rclpy.qos import HistoryPolicy, QoSProfile, ReliabilityPolicy
from rclpy.signals import SignalHandlerOptions
from rclpy.subscription import Subscription
from rosbags.rosbag2 import StoragePlugin, Writer
from sensor_msgs.msg import CameraInfo, CompressedImage, PointCloud2
from std_msgs.msg import Header
from visualization_msgs.msg import MarkerArray

from msg_adapters.definitions import type_name, typestore
from mvpose_ros.core.defaults import data_root
from mvpose_ros.core.geometry.rig import load_rig_file
from mvpose_ros.nodes.health import DIAGNOSTICS_QOS
from mvpose_ros.nodes.image_topics import image_type_by_name
from mvpose_ros.nodes.runtime import DATA_QOS, LATCHED_QOS, VIEWER_QOS
from mvpose_ros.topics import (CAMERA_INFO, CAMERA_MARKERS, DIAGNOSTICS, IMAGE, MARKERS, OPENPOSE, OVERLAY, SKELETONS,
                               SKELETONS_DROPPED, SKELETONS_LIVE, camera_namespace, camera_topic)

BAG_VERSION = 9  # rosbag2's metadata version of Jazzy
# Inputs: best effort (a camera driver's or the player's writer never waits for the recorder),
# deep enough for a second of a rig's images queued while the recorder writes.
INPUT_QOS = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=100, reliability=ReliabilityPolicy.BEST_EFFORT)
NO_EVENTS = SubscriptionEventCallbacks(use_default_callbacks=False)
SPIN_S = 0.1


@dataclass(frozen=True)
class Recorded:
    """One recorded topic: its message class, the QoS it is read with, and whether a run waits
    for its reader to have matched the topic's writers before playing (a volatile topic whose
    first messages would be lost otherwise; not the latched frusta nor /diagnostics, sent again)."""

    msg_class: type
    qos: QoSProfile
    wait: bool = True


def recorded_outputs(cameras: Sequence[str], overlays: bool = False) -> dict[str, Recorded]:
    """The graph's outputs (relative names; /diagnostics absolute): skeletons, their live
    estimate and dropped stamps, the skeleton markers, the camera frusta, the diagnostics and,
    with `overlays`, each camera's overlay image (cameras: their namespaces, e.g. 'cam0')."""
    topics = {SKELETONS: Recorded(PointCloud2, DATA_QOS), SKELETONS_LIVE: Recorded(PointCloud2, DATA_QOS),
              SKELETONS_DROPPED: Recorded(Header, DATA_QOS), MARKERS: Recorded(MarkerArray, DATA_QOS),
              CAMERA_MARKERS: Recorded(MarkerArray, LATCHED_QOS, wait=False),
              DIAGNOSTICS: Recorded(DiagnosticArray, DIAGNOSTICS_QOS, wait=False)}
    if overlays:
        topics |= {camera_topic(c, OVERLAY): Recorded(CompressedImage, VIEWER_QOS) for c in cameras}
    return topics


def recorded_inputs(inputs: Mapping[str, type]) -> dict[str, Recorded]:
    """Input topics (name -> message class: the detectors' inputs, camera_info) read best effort."""
    return {topic: Recorded(kind, INPUT_QOS) for topic, kind in inputs.items()}


class TopicRecorder(Node):
    """Writes every message of `topics` (name -> Recorded) to a new rosbag2 MCAP folder `path`
    (which must not exist yet); `close()` finishes the file. `counts`: messages written per
    topic as given."""

    def __init__(self, path: Path, topics: Mapping[str, Recorded], name: str = 'topic_recorder',
                 context: Context | None = None) -> None:
        super().__init__(name, context=context, start_parameter_services=False)
        if Path(path).exists():
            raise FileExistsError(f'recording folder already exists: {path}')
        self.path = Path(path)
        self._writer = Writer(self.path, version=BAG_VERSION, storage_plugin=StoragePlugin.MCAP)
        self._writer.open()
        self.counts: dict[str, int] = {topic: 0 for topic in topics}
        self._readers: dict[str, Subscription] = {}
        store = typestore()
        for topic, rec in topics.items():
            connection = self._writer.add_connection(self.resolve_topic_name(topic), type_name(rec.msg_class),
                                                     typestore=store)
            self._readers[topic] = self.create_subscription(
                rec.msg_class, topic, lambda cdr, info, t=topic, c=connection: self._write(t, c, cdr, info),
                rec.qos, raw=True, event_callbacks=NO_EVENTS)

    def _write(self, topic: str, connection: Any, cdr: bytes, info: Any) -> None:
        self._writer.write(connection, info['received_timestamp'], cdr)
        self.counts[topic] += 1

    def unmatched(self, topics: Sequence[str]) -> list[str]:
        """Those of `topics` (as given) whose reader has not yet matched every writer the ROS graph
        shows (fully qualified): what such a writer sends now is lost to the recording. A topic
        nobody publishes is not waited for (a graph without that output)."""
        return [reader.topic_name for t in topics if (reader := self._readers.get(t)) is not None
                and reader.get_publisher_count() < self.count_publishers(reader.topic_name)]

    def close(self) -> None:
        """Finish the recording (its index and metadata.yaml); no message is written after."""
        for reader in self._readers.values():
            self.destroy_subscription(reader)
        self._readers.clear()
        self._writer.close()


def build_parser() -> argparse.ArgumentParser:
    """The command line of `mvpose-record`."""
    p = argparse.ArgumentParser(prog='mvpose-record', description=__doc__.split('\n')[0])
    p.add_argument('folder', type=Path, help='the recording to write (a new folder)')
    cams = p.add_mutually_exclusive_group()
    cams.add_argument('--rig', type=Path, help='rig file: its cameras (names, image and camera_info topics)')
    cams.add_argument('--cameras', type=int, default=5, help='cameras cam0..cam<N-1> (default 5)')
    p.add_argument('--overlays', action='store_true', help="also each camera's overlay image")
    p.add_argument('--inputs', action='store_true', help="also each camera's image (or openpose) and camera_info")
    p.add_argument('--openpose', action='store_true',
                   help='--inputs: the cameras carry OpenPose output (cam<c>/openpose), not images')
    p.add_argument('--duration', type=float, default=0.0, help='stop after this many s (default: at Ctrl-C)')
    return p


def _topics(args: argparse.Namespace) -> dict[str, Recorded]:
    if args.rig is not None:
        rig = load_rig_file(args.rig, data_root=partial(data_root, None))
        names = rig.names
        inputs = {c.image: image_type_by_name(c.image) for c in rig.cameras} | {
            c.camera_info: CameraInfo for c in rig.cameras}
    else:
        if args.cameras < 1:
            raise ValueError(f'--cameras must be >= 1, got {args.cameras}')
        names = [camera_namespace(c) for c in range(args.cameras)]
        kind = (OPENPOSE, PointCloud2) if args.openpose else (IMAGE, image_type_by_name(IMAGE))
        inputs = {camera_topic(n, kind[0]): kind[1] for n in names} | {
            camera_topic(n, CAMERA_INFO): CameraInfo for n in names}
    return recorded_outputs(names, args.overlays) | (recorded_inputs(inputs) if args.inputs else {})


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point of `mvpose-record`: record until Ctrl-C (or --duration), then print the counts."""
    args = build_parser().parse_args(argv)
    try:
        topics = _topics(args)
        if args.duration < 0:
            raise ValueError(f'--duration must be >= 0 s, got {args.duration:g}')
        rclpy.init(signal_handler_options=SignalHandlerOptions.NO)
        node = TopicRecorder(args.folder, topics)
    except (FileNotFoundError, FileExistsError, ValueError) as exc:
        print(f'mvpose-record: error: {exc}', file=sys.stderr)
        rclpy.try_shutdown()
        return 2
    stop: list[int] = []
    previous = {s: signal.signal(s, lambda *_: stop.append(1)) for s in (signal.SIGINT, signal.SIGTERM)}
    executor = SingleThreadedExecutor()
    executor.add_node(node)
    end = time.monotonic() + args.duration if args.duration > 0 else float('inf')
    print(f'mvpose-record: recording {len(topics)} topics to {args.folder} (Ctrl-C to stop)', flush=True)
    try:
        while not stop and time.monotonic() < end:
            executor.spin_once(timeout_sec=SPIN_S)
    except ExternalShutdownException:
        pass
    finally:
        node.close()
        for topic, n in node.counts.items():
            print(f'  {n:7d}  {node.resolve_topic_name(topic)}')
        executor.shutdown()
        node.destroy_node()
        rclpy.try_shutdown()
        for signum, handler in previous.items():
            signal.signal(signum, handler)
    return 0


if __name__ == '__main__':
    sys.exit(main())
