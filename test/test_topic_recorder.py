"""The rosbag2 MCAP recorder: every message of the graph's output topics written as it came, with
definitions an independent reader (mcap + mcap-ros2-support) decodes; latched frusta included;
mvpose-record's command line."""
from __future__ import annotations

import re
import signal

import numpy as np
import pytest
import yaml
from sensor_msgs.msg import CompressedImage
from std_msgs.msg import Header

from msg_adapters.diagnostics_msg import statuses_to_msg
from msg_adapters.markers import camera_markers
from msg_adapters.skeleton_msg import Skeletons, skeletons_to_msg
from mvpose_ros.core.health.status import Level, Status
from mvpose_ros.graph import topic_recorder
from mvpose_ros.graph.topic_recorder import TopicRecorder, recorded_inputs, recorded_outputs
from mvpose_ros.nodes.health import DIAGNOSTICS_QOS
from mvpose_ros.nodes.runtime import DATA_QOS, LATCHED_QOS
from mcap_check import decoded_messages, decoded_skeletons, same_people
from ros_harness import probe, spin_until


def _header(k: int) -> Header:
    header = Header(frame_id='world')
    header.stamp.sec, header.stamp.nanosec = 12, k * 40_000_000
    return header


def test_output_topics_name_every_output_and_the_overlays_only_when_asked():
    assert set(recorded_outputs(['cam0', 'cam1'])) == {
        'skeletons', 'skeletons/live', 'skeletons/dropped', 'skeletons/markers', 'cameras/markers', '/diagnostics'}
    with_overlays = recorded_outputs(['cam0', 'cam1'], overlays=True)
    assert {'cam0/overlay/compressed', 'cam1/overlay/compressed'} <= set(with_overlays)
    assert with_overlays['cam0/overlay/compressed'].msg_class is CompressedImage
    # the frusta are published once, transient local: read so, or a late recorder misses them
    assert with_overlays['cameras/markers'].qos is LATCHED_QOS
    # a run waits for the volatile outputs' readers, not for those sent again or latched
    assert {t for t, r in with_overlays.items() if not r.wait} == {'cameras/markers', '/diagnostics'}


def test_every_message_is_written_and_decodes_to_what_was_sent(domain, tmp_path, shelf_rig):
    folder = tmp_path / 'rec'
    topics = recorded_outputs(['cam0'], overlays=True)
    with probe(domain, 'sender') as (node, executor):
        # the frusta go out before the recorder exists: it gets them as a late subscriber would
        frusta = camera_markers(shelf_rig, [f'cam{c}' for c in range(len(shelf_rig))], _header(0))
        node.create_publisher(topics['cameras/markers'].msg_class, 'cameras/markers', LATCHED_QOS).publish(frusta)
        recorder = TopicRecorder(folder, topics, context=node.context)
        executor.add_node(recorder)
        skeletons = node.create_publisher(topics['skeletons'].msg_class, 'skeletons', DATA_QOS)
        diagnostics = node.create_publisher(topics['/diagnostics'].msg_class, '/diagnostics', DIAGNOSTICS_QOS)
        overlay = node.create_publisher(CompressedImage, 'cam0/overlay/compressed', DATA_QOS)
        assert spin_until(executor, lambda: not recorder.unmatched(['skeletons', '/diagnostics',
                                                                    'cam0/overlay/compressed', 'cameras/markers']))
        assert recorder.unmatched(['skeletons/live']) == []  # nobody publishes it: nothing to wait for
        rng = np.random.default_rng(0)
        sent = []
        for k in range(5):
            people = Skeletons(np.array([3, 8]), rng.uniform(-2, 2, (2, 14, 3)), rng.uniform(0, 1, (2, 14)))
            skeletons.publish(skeletons_to_msg(people.ids, people.joints, _header(k), confidence=people.confidence))
            sent.append(people)
        status = Status('/bp_solver: latency', Level.WARN, 'median 1.2 s', {'p50 ms': '1200'})
        diagnostics.publish(statuses_to_msg([status], _header(0).stamp))
        jpeg = CompressedImage(header=_header(1), format='jpeg', data=b'\xff\xd8fake')
        overlay.publish(jpeg)
        assert spin_until(executor, lambda: recorder.counts['skeletons'] == 5 and recorder.counts['/diagnostics']
                          and recorder.counts['cam0/overlay/compressed'] and recorder.counts['cameras/markers'])
        recorder.close()
        executor.remove_node(recorder)
        recorder.destroy_node()
    messages = decoded_messages(folder)
    by_topic: dict[str, list] = {}
    for topic, schema, cdr, decoded in messages:
        by_topic.setdefault(topic, []).append((schema, cdr, decoded))
    assert [s for s, _, _ in by_topic['/skeletons']] == ['sensor_msgs/msg/PointCloud2'] * 5
    got = [decoded_skeletons(d) for _, _, d in by_topic['/skeletons']]
    assert [stamp for stamp, _ in got] == [12_000_000_000 + k * 40_000_000 for k in range(5)]
    assert all(same_people(a, b) for (_, a), b in zip(got, sent))
    (schema, _, markers), = by_topic['/cameras/markers']
    assert schema == 'visualization_msgs/msg/MarkerArray'
    assert [(m.ns, m.id, m.text, [(p.x, p.y, p.z) for p in m.points]) for m in markers.markers] == [
        (m.ns, m.id, m.text, [(p.x, p.y, p.z) for p in m.points]) for m in frusta.markers]
    (_, _, diag), = [m for m in by_topic['/diagnostics'] if m[2].status[0].name == '/bp_solver: latency']
    assert diag.status[0].message == 'median 1.2 s' and diag.status[0].values[0].value == '1200'
    (_, _, image), = by_topic['/cam0/overlay/compressed']
    assert image.format == 'jpeg' and bytes(image.data) == b'\xff\xd8fake'
    # ros2 bag's metadata: every topic with its type and count, the storage mcap
    meta = yaml.safe_load((folder / 'metadata.yaml').read_text())['rosbag2_bagfile_information']
    assert meta['storage_identifier'] == 'mcap'
    counts = {t['topic_metadata']['name']: (t['topic_metadata']['type'], t['message_count'])
              for t in meta['topics_with_message_count']}
    assert counts['/skeletons'] == ('sensor_msgs/msg/PointCloud2', 5)
    assert counts['/skeletons/live'] == ('sensor_msgs/msg/PointCloud2', 0)


def test_a_recording_never_overwrites_a_folder(domain, tmp_path):
    (tmp_path / 'rec').mkdir()
    with probe(domain, 'sender') as (node, _):
        with pytest.raises(FileExistsError, match='already exists'):
            TopicRecorder(tmp_path / 'rec', recorded_outputs([]), context=node.context)


def test_mvpose_record_topics_of_a_rig_and_of_numbered_cameras(tmp_path, capsys):
    rig = tmp_path / 'rig.yaml'
    rig.write_text(yaml.safe_dump({'cameras': [
        {'name': 'left', 'image': '/rig/left/image_raw/compressed', 'camera_info': '/rig/left/camera_info',
         'position': [0.0, 0.0, 2.0], 'orientation': [0.0, 0.0, 0.0, 1.0]}]}))
    args = topic_recorder.build_parser().parse_args([str(tmp_path / 'rec'), '--rig', str(rig), '--inputs',
                                                     '--overlays'])
    topics = topic_recorder._topics(args)
    assert topics['/rig/left/image_raw/compressed'].msg_class is CompressedImage
    assert {'/rig/left/camera_info', 'left/overlay/compressed', 'skeletons'} <= set(topics)
    numbered = topic_recorder._topics(topic_recorder.build_parser().parse_args(['x', '--cameras', '2']))
    assert set(numbered) == set(recorded_outputs(['cam0', 'cam1']))
    assert topic_recorder.main([str(tmp_path / 'r'), '--cameras', '0']) == 2
    assert '--cameras must be >= 1' in capsys.readouterr().err
    assert set(recorded_inputs({'cam0/camera_info': object})) == {'cam0/camera_info'}


def test_mvpose_record_runs_for_its_duration_and_prints_the_counts(domain, tmp_path, monkeypatch, capsys):
    monkeypatch.setenv('ROS_DOMAIN_ID', str(domain))
    monkeypatch.setenv('ROS_AUTOMATIC_DISCOVERY_RANGE', 'LOCALHOST')
    handler = signal.getsignal(signal.SIGINT)
    assert topic_recorder.main([str(tmp_path / 'rec'), '--cameras', '1', '--duration', '0.3']) == 0
    assert signal.getsignal(signal.SIGINT) is handler  # Ctrl-C handling given back
    out = capsys.readouterr().out
    assert 'recording 6 topics' in out and re.search(r'\s0\s+/skeletons\n', out)
    meta = yaml.safe_load((tmp_path / 'rec' / 'metadata.yaml').read_text())['rosbag2_bagfile_information']
    assert meta['storage_identifier'] == 'mcap' and meta['message_count'] == 0
