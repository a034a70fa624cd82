"""skeleton_echo: the example consumer of the skeletons topic. It prints each message's people,
one line per joint with its name, position and confidence.

Everything it does with a message is `msg_to_skeletons` (msg_adapters.skeleton_msg: ids, joints
(P, 14, 3) metres, confidence (P, 14)) and the names of body.JOINT_NAMES: copy it to start a
consumer of your own. A message it cannot decode is logged with the reason, and it goes on.
Its output, and how to run it: docs/messages.md#python."""
from __future__ import annotations

from rclpy.node import Node
from rclpy.qos import HistoryPolicy, QoSProfile, ReliabilityPolicy
from sensor_msgs.msg import PointCloud2

from msg_adapters.skeleton_msg import Skeletons, msg_to_skeletons
from msg_adapters.stamp import stamp_ns
from mvpose_ros import topics
from mvpose_ros.core.geometry.body import JOINT_NAMES
from mvpose_ros.nodes.runtime import run

# What a consumer needs: reliable (bp_solver publishes reliably; best effort would connect too but
# may lose frames), volatile, a few messages of queue.
SKELETON_QOS = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=10, reliability=ReliabilityPolicy.RELIABLE)


def format_skeletons(stamp_s: float, frame_id: str, skeletons: Skeletons) -> str:
    """The text skeleton_echo prints for one message."""
    ids, joints, confidence = skeletons
    lines = [f'stamp {stamp_s:.9f} s, frame {frame_id!r}, {len(ids)} {"person" if len(ids) == 1 else "people"}']
    for pid, xyz, conf in zip(ids.tolist(), joints, confidence):
        lines.append(f'  person {pid}')
        lines += [f'    {name:12s}  x {x:7.3f}  y {y:7.3f}  z {z:7.3f} m  confidence {c:.2f}'
                  for name, (x, y, z), c in zip(JOINT_NAMES, xyz.tolist(), conf.tolist())]
    return '\n'.join(lines)


class SkeletonEcho(Node):
    """skeletons in, text on stdout."""

    def __init__(self) -> None:
        super().__init__('skeleton_echo')
        self.create_subscription(PointCloud2, topics.SKELETONS, self._on_skeletons, SKELETON_QOS)

    def _on_skeletons(self, msg: PointCloud2) -> None:
        stamp = stamp_ns(msg.header.stamp)
        try:
            skeletons = msg_to_skeletons(msg)
        except ValueError as exc:
            self.get_logger().error(f'skeletons stamp {stamp} ns: {exc}')
            return
        print(format_skeletons(stamp / 1e9, msg.header.frame_id, skeletons), flush=True)


def main(args: list[str] | None = None) -> None:
    run(SkeletonEcho, args)


if __name__ == '__main__':
    main()
