"""The multi-host test's recorder: a process of its own (so that it can run inside a network
namespace, `ip netns exec <ns> python test/skeleton_recorder.py ...`) that records /skeletons.

It waits until every endpoint the graph needs before playback is visible (graph.config
expected_connections), then creates the --ready file. Every /skeletons message is appended to
--predictions as it arrives, as a predictions line (mvpose_ros.core.evaluation.predictions), duplicates
included. With --measure it also records the serialized size of every message the nodes
publish. It exits 0 once every input stamp of --bag has its output and --drain s have
passed (to catch duplicates), 1 after --timeout s without a new output; --stats is written either
way:

    {"complete": bool, "bad": ["<stamp> ns: <why>", ...],
     "topics": {"/cam0/people2d": [[<stamp ns>, <bytes>], ...], ...}}
"""
from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path
from typing import Any, Sequence

import rclpy
from rclpy.executors import ExternalShutdownException, SingleThreadedExecutor
from rclpy.node import Node
from rclpy.serialization import deserialize_message
from sensor_msgs.msg import PointCloud2
from visualization_msgs.msg import MarkerArray

from msg_adapters.skeleton_msg import msg_to_skeletons
from msg_adapters.stamp import frame_of_stamp, stamp_ns
from mvpose_ros.bags.io import read_bag
from mvpose_ros.bags.replay import header_stamp_ns
from mvpose_ros.core.evaluation.predictions import frame_line
from mvpose_ros.core.inference.window import FrameResult
from mvpose_ros.graph.config import expected_connections
from mvpose_ros.nodes.runtime import DATA_QOS

OUTPUT = '/skeletons'
_SPIN_S = 0.05


def graph_topics(cameras: int) -> dict[str, Any]:
    """Every topic the nodes publish -> its message class. Not the player's: a subscriber of
    /cam*/openpose other than the detectors would let the player start before they listen."""
    topics: dict[str, Any] = {f'/cam{c}/people2d': PointCloud2 for c in range(cameras)}
    return topics | {'/people/bundles': PointCloud2, OUTPUT: PointCloud2, '/skeletons/markers': MarkerArray}


class Recorder(Node):
    """/skeletons to a predictions file as they come; optionally the size of every message."""

    def __init__(self, predictions: Path, cameras: int, frame_rate: float, measure: bool) -> None:
        super().__init__('multihost_recorder')
        self.frame_rate = frame_rate
        self.out = open(predictions, 'w', encoding='utf-8')
        self.outputs: dict[int, int] = {}  # stamp ns -> messages received
        self.last_output = 0.0
        self.bad: list[str] = []
        topics = graph_topics(cameras) if measure else {OUTPUT: PointCloud2}
        self.sizes: dict[str, list[tuple[int, int]]] = {topic: [] for topic in topics}  # (stamp ns, bytes)
        for topic, msg_type in topics.items():
            self.create_subscription(msg_type, topic, lambda cdr, t=topic, m=msg_type: self._on_message(t, m, cdr),
                                     DATA_QOS, raw=True)

    def _on_message(self, topic: str, msg_type: Any, cdr: bytes) -> None:
        if msg_type is MarkerArray:  # no header of its own: the stamp of its first marker
            markers = deserialize_message(cdr, MarkerArray).markers
            stamp = stamp_ns(markers[0].header.stamp) if markers else -1
        else:
            stamp = header_stamp_ns(cdr)
        self.sizes[topic].append((stamp, len(cdr)))
        if topic == OUTPUT:
            self._on_skeletons(cdr)

    def _on_skeletons(self, cdr: bytes) -> None:
        self.last_output = time.monotonic()
        msg = deserialize_message(cdr, PointCloud2)
        stamp = stamp_ns(msg.header.stamp)
        self.outputs[stamp] = self.outputs.get(stamp, 0) + 1
        try:
            ids, joints = msg_to_skeletons(msg)
        except ValueError as exc:
            self.bad.append(f'{stamp} ns: {exc}')
            return
        result = FrameResult(frame_of_stamp(msg.header.stamp, self.frame_rate), [int(i) for i in ids], joints)
        self.out.write(frame_line(result) + '\n')
        self.out.flush()

    def missing(self, expected: dict[str, Sequence[str]]) -> list[str]:
        """Endpoints of `expected` not yet in the ROS graph."""
        count = {'pub': self.count_publishers, 'sub': self.count_subscribers}
        return [f'{end} {topic}' for topic, ends in expected.items() for end in ends if count[end](topic) == 0]


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(description=__doc__.split('\n')[0])
    p.add_argument('--bag', required=True, type=Path,
                   help='the bag to be played: its /cam0/openpose stamps are the input')
    p.add_argument('--predictions', required=True, type=Path)
    p.add_argument('--ready', required=True, type=Path, help='created once every endpoint of the graph is visible')
    p.add_argument('--stats', required=True, type=Path)
    p.add_argument('--cameras', type=int, default=5)
    p.add_argument('--frame-rate', type=float, default=25.0)
    p.add_argument('--timeout', type=float, default=60.0,
                   help='s without a new output (or before the graph is visible) before giving up')
    p.add_argument('--drain', type=float, default=1.0, help='s to keep listening once every stamp has its output')
    p.add_argument('--measure', action='store_true',
                   help='also record the size of every message the nodes publish')
    return p


def record(args: argparse.Namespace) -> bool:
    """Record until complete (True) or timed out (False)."""
    wanted = {stamp for _, _, stamp, _ in read_bag(args.bag, ['/cam0/openpose'])}
    expected = expected_connections(args.cameras)
    rclpy.init()
    node = Recorder(args.predictions, args.cameras, args.frame_rate, args.measure)
    executor = SingleThreadedExecutor()
    executor.add_node(node)
    complete = False
    try:
        deadline = time.monotonic() + args.timeout
        while node.missing(expected):
            if time.monotonic() > deadline:
                print(f'graph not all visible after {args.timeout:g} s: no {", no ".join(node.missing(expected))}',
                      file=sys.stderr)
                return False
            executor.spin_once(timeout_sec=_SPIN_S)
        args.ready.touch()
        node.last_output = time.monotonic()
        while not wanted <= node.outputs.keys():
            if time.monotonic() - node.last_output > args.timeout:
                print(f'no {OUTPUT} for {args.timeout:g} s; {len(wanted - node.outputs.keys())} of {len(wanted)} '
                      f'stamps missing', file=sys.stderr)
                return False
            executor.spin_once(timeout_sec=_SPIN_S)
        complete = True
        drain_until = time.monotonic() + args.drain
        while time.monotonic() < drain_until:
            executor.spin_once(timeout_sec=_SPIN_S)
        return True
    except (KeyboardInterrupt, ExternalShutdownException):
        return False
    finally:
        node.out.close()
        args.stats.write_text(json.dumps({'complete': complete, 'bad': node.bad, 'topics': node.sizes}))
        executor.shutdown()
        node.destroy_node()
        rclpy.try_shutdown()


def main(argv: Sequence[str] | None = None) -> int:
    return 0 if record(build_parser().parse_args(argv)) else 1


if __name__ == '__main__':
    sys.exit(main())
