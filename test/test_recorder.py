"""The skeleton recorder as a program of its own (`python -m mvpose_ros.graph.recorder`), on the
fake graph of test_processes: ready once the graph is visible, its output reader matched and the
nodes report their links matched on /diagnostics (without those reports it never is), the player
let go once its camera_info reader matched, every frame exactly once, sizes measured."""
from __future__ import annotations

import json
import sys
import time

from sensor_msgs.msg import PointCloud2

from mvpose_ros.bags.io import write_bag
from mvpose_ros.graph.processes import ProcessGroup
from mvpose_ros.graph.recorder import START_TOPIC
from ros_harness import ros_domain, ros_env
from test_processes import FAKE_NODE

CAMERAS = 2
FRAMES = range(300, 320)


def test_recorder_process_records_every_frame_of_a_gated_player(tmp_path, monkeypatch):
    bag = tmp_path / 'bag'
    write_bag(bag, [('/cam0/openpose', PointCloud2(), f * 1_000_000_000 // 25) for f in FRAMES])
    script = tmp_path / 'fake_node.py'
    script.write_text(FAKE_NODE)
    (tmp_path / 'pids').mkdir()
    ready, predictions, stats = tmp_path / 'ready', tmp_path / 'p.jsonl', tmp_path / 'stats.json'
    with ros_domain(monkeypatch, profile=None) as domain:
        env = ros_env(domain, profile=None, FAKE_CAMERAS=str(CAMERAS), FAKE_FRAMES=f'{FRAMES.start}:{FRAMES.stop}',
                      FAKE_PIDS=str(tmp_path / 'pids'))
        with ProcessGroup(tmp_path / 'logs', env) as group:
            group.start('recorder', [sys.executable, '-m', 'mvpose_ros.graph.recorder', '--bag', str(bag),
                                     '--predictions', str(predictions), '--ready', str(ready), '--stats', str(stats),
                                     '--cameras', str(CAMERAS), '--timeout', '60', '--drain', '0.2', '--measure',
                                     '--start-topic', START_TOPIC])
            for role, ns in [*(('heatmap_detector', f'cam{c}') for c in range(CAMERAS)), ('association', ''),
                             ('bp_solver', ''), ('bag_player', '')]:
                group.start(f'{ns}/{role}' if ns else role,
                            [sys.executable, str(script), role, START_TOPIC, '--ros-args',
                             *(['-r', f'__ns:=/{ns}'] if ns else [])])
            deadline = time.monotonic() + 90  # a bound for a failure only: the recorder's exit is the event
            while 'recorder' not in group.poll() and time.monotonic() < deadline:
                time.sleep(0.05)
            code = group.poll().get('recorder')
            log = group.log_tail('recorder', 20)
    assert code == 0, log
    assert ready.exists()
    lines = [json.loads(line) for line in predictions.read_text().splitlines()]
    assert [r['frame'] for r in lines] == list(FRAMES)  # each once, in order
    assert all(r['people'][0]['id'] == 7 for r in lines)
    summary = json.loads(stats.read_text())
    assert summary['complete'] and summary['bad'] == []
    assert len(summary['topics']['/skeletons']) == len(FRAMES)
    assert [len(summary['topics'][f'/cam{c}/people2d']) for c in range(CAMERAS)] == [len(FRAMES)] * CAMERAS


def test_accounted_follows_the_outputs_and_drops_that_come(monkeypatch):
    """Whether every wanted stamp has an output or was dropped: worked out again only once either
    has grown, and right after every change."""
    import rclpy

    from mvpose_ros.graph.recorder import SkeletonRecorder
    with ros_domain(monkeypatch, profile=None):
        context = rclpy.Context()
        rclpy.init(context=context)
        try:
            node = SkeletonRecorder(context=context)
            wanted = {1, 2, 3}
            assert not node.accounted(wanted) and not node.accounted(wanted)
            node.outputs.update({1: None, 2: None})
            assert not node.accounted(wanted)
            node.dropped.add(3)
            assert node.accounted(wanted)
            assert not node.accounted({1, 2, 3, 4})  # another set of stamps: not the answer kept
            node.outputs[4] = None
            assert node.accounted({1, 2, 3, 4}) and node.accounted({1, 2})
            node.destroy_node()
        finally:
            rclpy.shutdown(context=context)


def test_overlay_images_are_written_per_camera_and_their_readers_count_as_outputs(tmp_path, monkeypatch):
    """overlay_files: each overlay topic's images go to its folder as <stamp ns>.jpg, byte for byte;
    until the overlay node's writers have matched, those readers keep the run from playing."""
    import numpy as np
    import rclpy
    from rclpy.executors import SingleThreadedExecutor
    from sensor_msgs.msg import CompressedImage
    from std_msgs.msg import Header

    from msg_adapters.image_msg import image_to_compressed_msg
    from msg_adapters.stamp import stamp_of_ns
    from mvpose_ros.graph.recorder import SkeletonRecorder
    from mvpose_ros.nodes.runtime import VIEWER_QOS
    from ros_harness import spin_until
    with ros_domain(monkeypatch, profile=None):
        context = rclpy.Context()
        rclpy.init(context=context)
        try:
            node = SkeletonRecorder(context=context, overlay_files={'left/overlay/compressed': tmp_path / 'left'})
            assert '/left/overlay/compressed' in node.unmatched_outputs() and node.overlay_stamps == set()
            writer = rclpy.create_node('overlay_writer', context=context)
            pub = writer.create_publisher(CompressedImage, 'left/overlay/compressed', VIEWER_QOS)
            executor = SingleThreadedExecutor(context=context)
            executor.add_node(node)
            executor.add_node(writer)
            assert spin_until(executor, lambda: node.unmatched_outputs() == ['/skeletons']
                              and pub.get_subscription_count() > 0)
            msg = image_to_compressed_msg(np.full((8, 8, 3), 200, np.uint8), Header(stamp=stamp_of_ns(1_500_000_000)))
            assert spin_until(executor, lambda: pub.publish(msg) or node.overlays > 0)
            assert (tmp_path / 'left' / '1500000000.jpg').read_bytes() == bytes(msg.data)
            assert node.overlay_stamps == {1_500_000_000} and node.last_overlay > 0
            assert SkeletonRecorder(context=context, name='plain').overlay_stamps is None
            writer.destroy_node()
            node.destroy_node()
        finally:
            rclpy.shutdown(context=context)
