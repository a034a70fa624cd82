"""The bag_player node as a process, observed by an in-test rclpy node: every frame once, in
stamp order, at no more than the recorded speed; rate 0 held back by acknowledgements; loops
with increasing stamps; bad bags and parameters fail with one line and exit code 2."""
from __future__ import annotations

import os
import subprocess
import sys
import time
from pathlib import Path

import pytest
import rclpy
from rclpy.context import Context
from rclpy.executors import SingleThreadedExecutor
from rclpy.node import Node
from rosgraph_msgs.msg import Clock
from sensor_msgs.msg import CameraInfo, PointCloud2
from std_msgs.msg import Header

from msg_adapters.stamp import stamp_ns, stamp_of_frame
from mvpose_ros.bags.io import write_bag
from mvpose_ros.nodes.runtime import DATA_QOS

DOMAIN_ID = 142
REPO = Path(__file__).resolve().parents[1]
S = 1_000_000_000
# The player ends by waiting until subscribers confirm receipt; with Fast DDS's default 3 s
# writer heartbeat that alone takes ~3 s per run. A faster heartbeat keeps this file short
# without changing what is tested.
FAST_HEARTBEAT = """<?xml version="1.0" encoding="UTF-8"?>
<dds xmlns="http://www.eprosima.com/XMLSchemas/fastRTPS_Profiles"><profiles>
  <data_writer profile_name="test_writer" is_default_profile="true"><times>
    <heartbeatPeriod><sec>0</sec><nanosec>50000000</nanosec></heartbeatPeriod>
  </times></data_writer>
</profiles></dds>
"""


def _make_bag(path: Path, frames: range, cameras: int = 2, camera_info: bool = True) -> Path:
    """Per frame: /cam{c}/openpose clouds whose data names (frame, camera), and /cam0/camera_info."""
    items = []
    for f in frames:
        stamp = stamp_of_frame(f)
        if camera_info:
            items.append(('/cam0/camera_info', CameraInfo(header=Header(stamp=stamp, frame_id='cam0'),
                                                          width=1032, height=776, d=[0.5, 0.0, 0.0, 0.0, 0.0]),
                          stamp_ns(stamp)))
        for c in range(cameras):
            cloud = PointCloud2(header=Header(stamp=stamp, frame_id=f'cam{c}'), data=f'{f}/{c}'.encode())
            items.append((f'/cam{c}/openpose', cloud, stamp_ns(stamp)))
    write_bag(path, items)
    return path


@pytest.fixture
def probe(monkeypatch):
    """An rclpy node on this test's domain, its executor, and what it received."""
    monkeypatch.setenv('ROS_AUTOMATIC_DISCOVERY_RANGE', 'LOCALHOST')
    monkeypatch.setenv('ROS_DOMAIN_ID', str(DOMAIN_ID))
    context = Context()
    rclpy.init(context=context, domain_id=DOMAIN_ID)
    node = Node('bag_player_probe', context=context)
    executor = SingleThreadedExecutor(context=context)
    executor.add_node(node)
    yield node, executor
    executor.shutdown()
    node.destroy_node()
    context.try_shutdown()


def _listen(node: Node, topic: str, msg_type, received: list) -> None:
    """Append (topic, stamp ns, message, monotonic receipt time) for every message on topic."""
    def on_message(msg):
        stamp = msg.clock if msg_type is Clock else msg.header.stamp
        received.append((topic, stamp_ns(stamp), msg, time.monotonic()))
    node.create_subscription(msg_type, topic, on_message, DATA_QOS)


def _player(tmp_path: Path, *params: str) -> tuple[subprocess.Popen, Path]:
    profile = tmp_path / 'fastdds.xml'
    profile.write_text(FAST_HEARTBEAT)
    env = dict(os.environ, PYTHONPATH=str(REPO), ROS_AUTOMATIC_DISCOVERY_RANGE='LOCALHOST',
               ROS_DOMAIN_ID=str(DOMAIN_ID), FASTRTPS_DEFAULT_PROFILES_FILE=str(profile))
    log = tmp_path / f'player{len(list(tmp_path.glob("player*.log")))}.log'
    args = [x for p in params for x in ('-p', p)]
    with open(log, 'w') as err:
        proc = subprocess.Popen([sys.executable, '-m', 'mvpose_ros.nodes.bag_player', '--ros-args', *args],
                                env=env, stdout=subprocess.DEVNULL, stderr=err, cwd=tmp_path)
    return proc, log


def _spin_until(executor, done, timeout: float = 15.0) -> None:
    deadline = time.monotonic() + timeout
    while not done() and time.monotonic() < deadline:
        executor.spin_once(timeout_sec=0.02)


def _run_to_end(executor, proc: subprocess.Popen, timeout: float = 15.0) -> int:
    """Spin until the player exits, then a little longer for callbacks already queued."""
    _spin_until(executor, lambda: proc.poll() is not None, timeout)
    if proc.poll() is None:
        proc.kill()
        pytest.fail('bag_player did not finish')
    _spin_until(executor, lambda: False, 0.3)
    return proc.returncode


def _by_topic(received: list) -> dict[str, list]:
    out = {}
    for topic, stamp, msg, t in received:
        out.setdefault(topic, []).append((stamp, msg, t))
    return out


def test_every_frame_once_in_order_at_no_more_than_the_recorded_speed(probe, tmp_path):
    node, executor = probe
    frames = range(300, 326)  # 25 frame periods: 1.0 s recorded
    bag = _make_bag(tmp_path / 'bag', frames)
    received = []
    for topic, msg_type in (('/cam0/camera_info', CameraInfo), ('/cam0/openpose', PointCloud2),
                            ('/cam1/openpose', PointCloud2)):
        _listen(node, topic, msg_type, received)
    proc, log = _player(tmp_path, f'bag:={bag}', 'rate:=1.0', 'wait_subscribers:=10.0')
    assert _run_to_end(executor, proc) == 0, log.read_text()

    expected = [f * S // 25 for f in frames]
    by_topic = _by_topic(received)
    assert sorted(by_topic) == ['/cam0/camera_info', '/cam0/openpose', '/cam1/openpose']
    for c in range(2):
        got = by_topic[f'/cam{c}/openpose']
        assert [stamp for stamp, _, _ in got] == expected  # once each, in stamp order
        assert [bytes(msg.data).decode() for _, msg, _ in got] == [f'{f}/{c}' for f in frames]
        assert {msg.header.frame_id for _, msg, _ in got} == {f'cam{c}'}
    infos = by_topic['/cam0/camera_info']
    assert [stamp for stamp, _, _ in infos] == expected
    assert all(list(msg.d) == [0.5, 0, 0, 0, 0] and msg.width == 1032 for _, msg, _ in infos)
    # paced: the last frame cannot arrive sooner than the recorded span after the first
    got = by_topic['/cam0/openpose']
    assert got[-1][2] - got[0][2] >= 0.9 * (expected[-1] - expected[0]) / S
    assert 'done: 26 frames, 78 messages' in log.read_text()


def test_loops_shift_stamps_on_and_clock_follows(probe, tmp_path):
    node, executor = probe
    frames = range(300, 306)
    bag = _make_bag(tmp_path / 'bag', frames, cameras=1)
    received = []
    _listen(node, '/cam0/openpose', PointCloud2, received)
    _listen(node, '/cam0/camera_info', CameraInfo, received)
    _listen(node, '/clock', Clock, received)
    proc, log = _player(tmp_path, f'bag:={bag}', 'rate:=4.0', 'loops:=2', 'clock:=true')
    assert _run_to_end(executor, proc) == 0, log.read_text()

    # loop 1 continues one frame period after loop 0's last frame: frames 306..311
    expected = [f * S // 25 for f in range(300, 312)]
    by_topic = _by_topic(received)
    for topic in ('/cam0/openpose', '/cam0/camera_info'):
        assert [stamp for stamp, _, _ in by_topic[topic]] == expected
    # only the stamp changes in later loops
    assert [bytes(msg.data).decode() for _, msg, _ in by_topic['/cam0/openpose']] == [f'{f}/0' for f in frames] * 2
    assert all(list(msg.d) == [0.5, 0, 0, 0, 0] for _, msg, _ in by_topic['/cam0/camera_info'])
    assert [stamp for stamp, _, _ in by_topic['/clock']] == expected


def test_rate_zero_runs_at_most_max_in_flight_frames_ahead_of_acks(probe, tmp_path):
    node, executor = probe
    frames = range(300, 310)
    bag = _make_bag(tmp_path / 'bag', frames, cameras=1, camera_info=False)
    received = []
    _listen(node, '/cam0/openpose', PointCloud2, received)
    ack = node.create_publisher(PointCloud2, '/test_ack', DATA_QOS)
    proc, log = _player(tmp_path, f'bag:={bag}', 'rate:=0.0', 'max_in_flight:=3', 'ack_topic:=/test_ack')

    def acknowledge(frame: int) -> None:
        ack.publish(PointCloud2(header=Header(stamp=stamp_of_frame(frame), frame_id='world')))

    _spin_until(executor, lambda: len(received) >= 3 and ack.get_subscription_count() > 0)
    _spin_until(executor, lambda: False, 0.5)
    assert len(received) == 3  # no acknowledgement yet: held at max_in_flight
    acknowledge(301)  # frames 300 and 301 are done downstream
    _spin_until(executor, lambda: len(received) >= 5)
    _spin_until(executor, lambda: False, 0.5)
    assert len(received) == 5
    deadline = time.monotonic() + 15
    while proc.poll() is None and time.monotonic() < deadline:
        acknowledge(round(received[-1][1] * 25 / S))
        _spin_until(executor, lambda: False, 0.05)
    assert _run_to_end(executor, proc) == 0, log.read_text()
    assert [stamp for _, stamp, _, _ in received] == [f * S // 25 for f in frames]


def test_bad_bag_or_parameter_is_one_line_and_exit_2(tmp_path):
    damaged = _make_bag(tmp_path / 'damaged', range(300, 302))
    for mcap in damaged.glob('*.mcap'):
        mcap.write_bytes(b'junk' * 100)
    cases = [(f'bag:={tmp_path / "missing"}', 'missing'), (f'bag:={damaged}', 'damaged'),
             ('rate:=-1.0', 'rate')]
    procs = [(_player(tmp_path, param), needle) for param, needle in cases]
    for (proc, log), needle in procs:
        assert proc.wait(timeout=20) == 2
        lines = [line for line in log.read_text().splitlines() if line.strip()]
        assert len(lines) == 1 and needle in lines[0] and 'FATAL' in lines[0], lines
