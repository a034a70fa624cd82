"""The bag_player node as a process, observed by an in-test rclpy node: every frame once, in
stamp order, at no more than the recorded speed; nothing before its readers have matched and the
start signal has come; rate 0 held back by acknowledgements; loops with increasing stamps;
relative topics under a namespace; bad bags and parameters fail with one line and exit code 2;
sensor (best-effort) QoS; lockstep by synchronised sets of a rig bag with offset stamps."""
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
from rclpy.qos import qos_profile_sensor_data
from sensor_msgs.msg import CameraInfo, CompressedImage, PointCloud2
from std_msgs.msg import Header

from msg_adapters.stamp import stamp_ns, stamp_of_frame
from mvpose_ros.bags.io import write_bag
from mvpose_ros.nodes.runtime import DATA_QOS
from ros_harness import matched, open_start_gate, ros_domain, ros_env, stop

START = 'bag_player/start'
REPO = Path(__file__).resolve().parents[1]
S = 1_000_000_000
# The player ends by waiting until subscribers confirm receipt; with Fast DDS's default 3 s
# writer heartbeat that alone takes ~3 s per run. A faster heartbeat keeps this file short
# without changing what is tested.
FAST_HEARTBEAT = """<?xml version="1.0" encoding="UTF-8"?>
<dds xmlns="http://www.eprosima.com/XMLSchemas/fastRTPS_Profiles"><profiles>
  <data_writer profile_name="test_writer" is_default_profile="true"><times>
    <heartbeatPeriod><sec>0</sec><nanosec>50000000</nanosec></heartbeatPeriod>
  </times><historyMemoryPolicy>DYNAMIC</historyMemoryPolicy>
  <qos><publishMode><kind>SYNCHRONOUS</kind></publishMode></qos></data_writer>
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
def domain(monkeypatch):
    """A ROS domain of this test's own, set in this process's environment."""
    with ros_domain(monkeypatch, profile=None) as domain_id:
        yield domain_id


@pytest.fixture
def probe(domain):
    """An rclpy node on this test's domain and its executor."""
    context = Context()
    rclpy.init(context=context, domain_id=domain)
    node = Node('bag_player_probe', context=context)
    executor = SingleThreadedExecutor(context=context)
    executor.add_node(node)
    yield node, executor
    executor.shutdown()
    node.destroy_node()
    context.try_shutdown()


def _listen(node: Node, topic: str, msg_type, received: list):
    """Append (topic, stamp ns, message, monotonic receipt time) for every message on topic;
    returns the subscription."""
    def on_message(msg):
        stamp = msg.clock if msg_type is Clock else msg.header.stamp
        received.append((topic, stamp_ns(stamp), msg, time.monotonic()))
    return node.create_subscription(msg_type, topic, on_message, DATA_QOS)


def _player(tmp_path: Path, *params: str, ros_args: tuple[str, ...] = ()) -> tuple[subprocess.Popen, Path]:
    profile = tmp_path / 'fastdds.xml'
    profile.write_text(FAST_HEARTBEAT)
    env = ros_env(int(os.environ['ROS_DOMAIN_ID']), profile)
    log = tmp_path / f'player{len(list(tmp_path.glob("player*.log")))}.log'
    args = [x for p in params for x in ('-p', p)]
    with open(log, 'w') as err:
        proc = subprocess.Popen([sys.executable, '-m', 'mvpose_ros.nodes.bag_player', '--ros-args', *ros_args, *args],
                                env=env, stdout=subprocess.DEVNULL, stderr=err, cwd=tmp_path)
    return proc, log


def _spin_until(executor, done, timeout: float = 15.0) -> bool:
    deadline = time.monotonic() + timeout
    while not done() and time.monotonic() < deadline:
        executor.spin_once(timeout_sec=0.02)
    return done()


def _start_when_matched(node, executor, proc: subprocess.Popen, log: Path, subscriptions) -> None:
    """Once every reader of the probe has matched the player's writer, give the start signal."""
    assert _spin_until(executor, lambda: matched(subscriptions) or proc.poll() is not None), log.read_text()
    open_start_gate(node, START)


def _run_to_end(executor, proc: subprocess.Popen, done, timeout: float = 15.0) -> int:
    """Spin until the player exits and done() (every message expected has been taken)."""
    _spin_until(executor, lambda: proc.poll() is not None, timeout)
    if proc.poll() is None:
        stop(proc)
        pytest.fail('bag_player did not finish')
    _spin_until(executor, done, 5.0)
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
    subs = [_listen(node, topic, msg_type, received) for topic, msg_type in (
        ('/cam0/camera_info', CameraInfo), ('/cam0/openpose', PointCloud2), ('/cam1/openpose', PointCloud2))]
    proc, log = _player(tmp_path, f'bag:={bag}', 'rate:=1.0', 'wait_subscribers:=10.0', f'start_topic:={START}')
    _start_when_matched(node, executor, proc, log, subs)
    assert _run_to_end(executor, proc, lambda: len(received) >= 3 * len(frames)) == 0, log.read_text()

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
    subs = [_listen(node, '/cam0/openpose', PointCloud2, received),
            _listen(node, '/cam0/camera_info', CameraInfo, received), _listen(node, '/clock', Clock, received)]
    proc, log = _player(tmp_path, f'bag:={bag}', 'rate:=4.0', 'loops:=2', 'clock:=true', f'start_topic:={START}')
    _start_when_matched(node, executor, proc, log, subs)
    assert _run_to_end(executor, proc, lambda: len(received) >= 3 * 12) == 0, log.read_text()

    # loop 1 continues one frame period after loop 0's last frame: frames 306..311
    expected = [f * S // 25 for f in range(300, 312)]
    by_topic = _by_topic(received)
    for topic in ('/cam0/openpose', '/cam0/camera_info'):
        assert [stamp for stamp, _, _ in by_topic[topic]] == expected
    # only the stamp changes in later loops
    assert [bytes(msg.data).decode() for _, msg, _ in by_topic['/cam0/openpose']] == [f'{f}/0' for f in frames] * 2
    assert all(list(msg.d) == [0.5, 0, 0, 0, 0] for _, msg, _ in by_topic['/cam0/camera_info'])
    assert [stamp for stamp, _, _ in by_topic['/clock']] == expected


@pytest.mark.parametrize('preload_mib', [256.0, 0.0])
def test_a_bag_within_preload_mib_is_read_before_it_plays_and_loops_from_memory(probe, tmp_path, preload_mib):
    """The bag's files are deleted once the player is up: read into memory, it still plays both loops;
    read while playing (preload_mib 0), it cannot, and says so in one line (exit 2)."""
    node, executor = probe
    frames = range(300, 304)
    bag = _make_bag(tmp_path / 'bag', frames, cameras=1, camera_info=False)
    received = []
    subs = [_listen(node, '/cam0/openpose', PointCloud2, received)]
    proc, log = _player(tmp_path, f'bag:={bag}', 'rate:=4.0', 'loops:=2', f'start_topic:={START}',
                        f'preload_mib:={preload_mib}')
    assert _spin_until(executor, lambda: 'playing' in log.read_text() or proc.poll() is not None), log.read_text()
    for f in bag.iterdir():
        f.unlink()
    _start_when_matched(node, executor, proc, log, subs)
    if preload_mib:
        assert _run_to_end(executor, proc, lambda: len(received) >= 2 * len(frames)) == 0, log.read_text()
        assert [bytes(m.data).decode() for _, _, m, _ in received] == [f'{f}/0' for f in frames] * 2
    else:
        assert _run_to_end(executor, proc, lambda: True) == 2, log.read_text()
        fatal = [line for line in log.read_text().splitlines() if 'FATAL' in line]
        assert len(fatal) == 1 and str(bag) in fatal[0] and received == [], log.read_text()


def test_rate_zero_runs_at_most_max_in_flight_frames_ahead_of_acks(probe, tmp_path):
    node, executor = probe
    frames = range(300, 310)
    bag = _make_bag(tmp_path / 'bag', frames, cameras=1, camera_info=False)
    received = []
    sub = _listen(node, '/cam0/openpose', PointCloud2, received)
    ack = node.create_publisher(PointCloud2, '/test_ack', DATA_QOS)
    proc, log = _player(tmp_path, f'bag:={bag}', 'rate:=0.0', 'max_in_flight:=3', 'ack_topic:=/test_ack',
                        f'start_topic:={START}')
    _start_when_matched(node, executor, proc, log, [sub, ack])

    def acknowledge_until(frame: int, done) -> bool:
        """Acknowledge `frame` until done(): an ack sent before the player's reader matched the
        probe's writer is lost; acknowledging a frame again releases nothing more."""
        deadline = time.monotonic() + 15
        while not done() and time.monotonic() < deadline:
            ack.publish(PointCloud2(header=Header(stamp=stamp_of_frame(frame), frame_id='world')))
            _spin_until(executor, done, 0.1)
        return done()

    assert _spin_until(executor, lambda: len(received) >= 3), log.read_text()
    _spin_until(executor, lambda: len(received) > 3, 0.5)  # a window for a 4th frame to (wrongly) come
    assert len(received) == 3  # no acknowledgement yet: held at max_in_flight
    assert acknowledge_until(301, lambda: len(received) >= 5)  # frames 300 and 301 are done downstream
    _spin_until(executor, lambda: len(received) > 5, 0.5)
    assert len(received) == 5
    while len(received) < len(frames):  # acknowledging the last frame seen releases up to 3 more
        seen = len(received)
        assert acknowledge_until(round(received[-1][1] * 25 / S), lambda: len(received) > seen), log.read_text()
    # every frame out, the last ones in flight: the player ends only once they are acknowledged
    _spin_until(executor, lambda: proc.poll() is not None, 0.5)
    assert proc.poll() is None, log.read_text()
    assert acknowledge_until(frames[-1], lambda: proc.poll() is not None), log.read_text()
    assert _run_to_end(executor, proc, lambda: True) == 0, log.read_text()
    assert [stamp for _, stamp, _, _ in received] == [f * S // 25 for f in frames]


def test_bad_bag_or_parameter_is_one_line_and_exit_2(domain, tmp_path):
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


def test_waits_for_readers_and_the_start_signal_and_publishes_relative_topics(probe, tmp_path):
    """Under a namespace the bag's /cam0/openpose goes out as <ns>/cam0/openpose; nothing goes out
    before a reader has matched and the start signal has come."""
    node, executor = probe
    frames = range(300, 303)
    bag = _make_bag(tmp_path / 'bag', frames, cameras=1, camera_info=False)
    received = []
    proc, log = _player(tmp_path, f'bag:={bag}', 'rate:=0.0', 'ack_topic:=skeletons', f'start_topic:={START}',
                        'wait_subscribers:=60.0', ros_args=('-r', '__ns:=/rig1'))
    # no reader yet, then a reader but no start signal: the player has no reason to play yet;
    # its own endpoints (its start signal reader) show that it is up.
    assert _spin_until(executor, lambda: node.count_subscribers(f'/rig1/{START}') > 0), log.read_text()
    sub = _listen(node, '/rig1/cam0/openpose', PointCloud2, received)
    assert _spin_until(executor, lambda: matched([sub])), log.read_text()
    _spin_until(executor, lambda: bool(received), 0.5)  # a window for a frame to (wrongly) come
    assert received == [] and proc.poll() is None
    open_start_gate(node, f'/rig1/{START}')
    assert _spin_until(executor, lambda: len(received) >= 1), log.read_text()
    assert received[0][1] == stamp_ns(stamp_of_frame(300))
    stop(proc)


def _rig_bag(path: Path, sets: int = 6, offsets_ms=(0.0, 7.0, -6.0)) -> tuple[Path, list[list[int]]]:
    """A driver-style rig bag: per set and camera a CompressedImage and a CameraInfo of its own
    stamp (set k of camera c at 100 s + k / 25 s + offsets_ms[c] ms), logged at that stamp.
    Returns the bag and each set's member stamps."""
    members, items = [], []
    for k in range(sets):
        stamps = [100 * S + k * S // 25 + round(o * 1e6) for o in offsets_ms]
        members.append(stamps)
        for c, stamp in enumerate(stamps):
            header = Header(frame_id=f'cam_{c}_optical_frame')
            header.stamp.sec, header.stamp.nanosec = divmod(stamp, S)
            items.append((stamp, f'/rig/cam_{c}/camera_info', CameraInfo(header=header, width=64, height=48)))
            items.append((stamp, f'/rig/cam_{c}/image_raw/compressed',
                          CompressedImage(header=header, format='jpeg', data=f'{k}/{c}'.encode())))
    items.sort(key=lambda item: item[0])
    write_bag(path, [(topic, msg, stamp) for stamp, topic, msg in items])
    return path, members


def test_sensor_qos_reaches_best_effort_readers_and_reliable_reaches_both(probe, tmp_path):
    """qos sensor publishes best effort like a camera driver: a best-effort reader gets the images
    (best effort may lose some, never reorders them; DDS does not let a reliable reader match a
    best-effort writer: it stays unmatched); qos reliable reaches a reliable reader with every
    image, and best-effort readers too."""
    node, executor = probe
    bag, members = _rig_bag(tmp_path / 'bag', sets=4)
    topic = '/rig/cam_0/image_raw/compressed'
    for qos in ('sensor', 'reliable'):
        best_effort, reliable = [], []
        subs = [node.create_subscription(CompressedImage, topic, lambda m: best_effort.append(m),
                                         qos_profile_sensor_data),
                node.create_subscription(CompressedImage, topic, lambda m: reliable.append(m), DATA_QOS)]
        # the player waits for a reader on every camera's images: the other two cameras' readers
        others = [node.create_subscription(CompressedImage, f'/rig/cam_{c}/image_raw/compressed', lambda m: None,
                                           qos_profile_sensor_data) for c in (1, 2)]
        proc, log = _player(tmp_path, f'bag:={bag}', 'rate:=1.0', 'sets:=true', f'qos:={qos}',
                            'wait_subscribers:=60.0', f'start_topic:={START}')
        _start_when_matched(node, executor, proc, log, (subs if qos == 'reliable' else subs[:1]) + others)
        assert _run_to_end(executor, proc, lambda: len(best_effort) >= 4 and (qos == 'sensor' or len(reliable) >= 4)) \
            == 0, log.read_text()
        got = [stamp_ns(m.header.stamp) for m in best_effort]
        assert got and got == [m[0] for m in members if m[0] in got], 'in order, each once'
        if qos == 'sensor':
            assert reliable == [] and subs[1].get_publisher_count() == 0
        else:
            assert [stamp_ns(m.header.stamp) for m in reliable] == [m[0] for m in members]
        for sub in subs + others:
            node.destroy_subscription(sub)


def test_lockstep_publishes_the_next_set_once_the_previous_set_stamp_is_acknowledged(probe, tmp_path):
    """sets + rate 0 + max_in_flight 1: a set (every camera's image and CameraInfo, stamps up to
    13 ms apart) goes out whole, and the next only after an ack carrying the set's stamp, its
    earliest member stamp; a set never acknowledged is given up after ack_timeout, the last one
    too before the player ends."""
    node, executor = probe
    bag, members = _rig_bag(tmp_path / 'bag', sets=4)
    received = []
    subs = [node.create_subscription(CompressedImage, f'/rig/cam_{c}/image_raw/compressed',
                                     lambda m: received.append(m), DATA_QOS) for c in range(3)]
    ack = node.create_publisher(PointCloud2, '/test_ack', DATA_QOS)
    proc, log = _player(tmp_path, f'bag:={bag}', 'rate:=0.0', 'sets:=true', 'max_in_flight:=1', 'max_skew:=0.02',
                        'ack_topic:=/test_ack', 'ack_timeout:=3.0', f'start_topic:={START}')
    _start_when_matched(node, executor, proc, log, [*subs, ack])

    def stamps():
        return sorted(stamp_ns(m.header.stamp) for m in received)

    assert _spin_until(executor, lambda: len(received) >= 3), log.read_text()
    _spin_until(executor, lambda: len(received) > 3, 0.5)  # a window for the next set to (wrongly) come
    assert stamps() == sorted(members[0])
    set_stamp = min(members[0])  # the earliest member: camera 2, 6 ms before camera 0

    def acknowledge(stamp: int, count: int) -> bool:
        deadline = time.monotonic() + 15
        while len(received) < count and time.monotonic() < deadline:
            header = Header(frame_id='world')
            header.stamp.sec, header.stamp.nanosec = divmod(stamp, S)
            ack.publish(PointCloud2(header=header))
            _spin_until(executor, lambda: len(received) >= count, 0.1)
        return len(received) >= count

    # an ack older than the set's stamp releases nothing
    header = Header(frame_id='world')
    header.stamp.sec, header.stamp.nanosec = divmod(set_stamp - 1, S)
    ack.publish(PointCloud2(header=header))
    _spin_until(executor, lambda: len(received) > 3, 0.5)
    assert len(received) == 3
    assert acknowledge(set_stamp, 6), log.read_text()
    assert stamps() == sorted(members[0] + members[1])
    # set 1 is never acknowledged: after ack_timeout the player goes on with set 2
    assert _spin_until(executor, lambda: len(received) >= 9, 10.0), log.read_text()
    assert acknowledge(min(members[2]), 12)
    # the last set is never acknowledged either: the player waits ack_timeout for it, then ends
    _spin_until(executor, lambda: proc.poll() is not None, 1.0)
    assert proc.poll() is None, log.read_text()
    assert _run_to_end(executor, proc, lambda: True) == 0, log.read_text()
    assert stamps() == sorted(s for m in members for s in m)
    text = log.read_text()
    assert text.count('no ack of stamp') == 2, text
    assert 'done: 4 sets, 24 messages' in text and '2 never acknowledged' in text
