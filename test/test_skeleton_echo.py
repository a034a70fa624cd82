"""skeleton_echo, the example consumer: it prints what a publisher of skeletons sent, joint names
and confidence included, and survives a malformed message."""
from __future__ import annotations

import numpy as np
from sensor_msgs.msg import PointCloud2
from std_msgs.msg import Header

from msg_adapters.records import to_cloud
from msg_adapters.skeleton_msg import SKELETON_DTYPE, Skeletons, skeletons_to_msg
from mvpose_ros.core.geometry.body import JOINT_NAMES
from mvpose_ros.nodes.skeleton_echo import SKELETON_QOS, format_skeletons
from ros_harness import probe, spin_until, start_node, stop


def test_format_names_every_joint_with_its_confidence():
    joints = np.arange(2 * 14 * 3, dtype=float).reshape(2, 14, 3) / 10
    confidence = np.linspace(0, 1, 28).reshape(2, 14)
    text = format_skeletons(1.5, 'world', Skeletons(np.array([3, 8]), joints, confidence))
    lines = text.splitlines()
    assert lines[0] == "stamp 1.500000000 s, frame 'world', 2 people" and lines[1] == '  person 3'
    assert lines[16] == '  person 8' and len(lines) == 1 + 2 * 15
    assert lines[2].split() == ['r_ankle', 'x', '0.000', 'y', '0.100', 'z', '0.200', 'm', 'confidence', '0.00']
    assert [line.split()[0] for line in lines[17:]] == list(JOINT_NAMES)
    assert lines[-1].endswith('confidence 1.00')


def test_echo_prints_what_was_published(domain, tmp_path):
    log = tmp_path / 'echo.log'
    with probe(domain, 'echo_probe') as (node, executor):
        pub = node.create_publisher(PointCloud2, 'skeletons', SKELETON_QOS)
        proc = start_node('skeleton_echo', domain, log)
        try:
            assert spin_until(executor, lambda: pub.get_subscription_count() > 0), log.read_text()
            header = Header(frame_id='world')
            header.stamp.sec, header.stamp.nanosec = 12, 40_000_000
            bad = np.zeros(3, SKELETON_DTYPE)  # 3 records of person 0: not a skeleton
            pub.publish(to_cloud(bad, header))
            joints = np.full((1, 14, 3), 0.25)
            pub.publish(skeletons_to_msg(np.array([5]), joints, header, confidence=np.full((1, 14), 0.75)))
            assert spin_until(executor, lambda: 'l_wrist' in log.read_text()), log.read_text()
        finally:
            stop(proc)
    text = log.read_text()
    assert 'person 0 has 3 joint records, expected 14' in text  # logged, and it went on
    assert "stamp 12.040000000 s, frame 'world', 1 person" in text and '  person 5' in text
    assert '    top_head      x   0.250  y   0.250  z   0.250 m  confidence 0.75' in text
