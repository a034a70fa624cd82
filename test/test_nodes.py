"""Each processing node as its own process, fed real Shelf data by an in-test probe node over
DDS: one output per good input frame, the same numbers as the ROS-free core, and bad input
logged with a reason while the node keeps going."""
from __future__ import annotations

import dataclasses

import numpy as np
import pytest
from sensor_msgs.msg import CameraInfo, PointCloud2, PointField
from std_msgs.msg import Header
from visualization_msgs.msg import MarkerArray

from msg_adapters.camera_info_msg import camera_to_info
from msg_adapters.openpose_msg import openpose_to_msg
from msg_adapters.people_msg import bundles_to_msg, msg_to_bundles, msg_to_people, people_to_msg
from msg_adapters.skeleton_msg import msg_to_skeletons
from msg_adapters.stamp import frame_of_stamp, stamp_of_frame
from mvpose_ros.core.association.associator import AssociationConfig, Associator
from mvpose_ros.core.detection.openpose_detector import OpenPoseDetectorConfig, detect_people
from mvpose_ros.core.inference.solver import Inference3D
from mvpose_ros.core.stage import StageConfig
from mvpose_ros.nodes.runtime import DATA_QOS
from ros_harness import probe, spin_until, start_node, stop

FIRST = 300  # first frame of the OpenPose files


@pytest.fixture(scope='module')
def shelf(shelf_openpose):
    cameras, raw = shelf_openpose
    return cameras, [frames[:16] for frames in raw]


def _header(frame: int, frame_id: str) -> Header:
    return Header(stamp=stamp_of_frame(frame), frame_id=frame_id)


def _collect(node, topic: str, msg_type, into: dict) -> None:
    node.create_subscription(msg_type, topic, lambda m: into.setdefault(frame_of_stamp(m.header.stamp)
                                                                        if hasattr(m, 'header') else
                                                                        frame_of_stamp(m.markers[0].header.stamp),
                                                                        []).append(m), DATA_QOS)


def test_heatmap_detector_turns_raw_openpose_into_people_and_logs_bad_frames(domain, shelf, tmp_path):
    cameras, raw = shelf
    log = tmp_path / 'detector.log'
    with probe(domain, 'detector_probe') as (node, executor):
        out: dict[int, list] = {}
        _collect(node, '/cam1/people2d', PointCloud2, out)
        pub = node.create_publisher(PointCloud2, '/cam1/openpose', DATA_QOS)
        info = node.create_publisher(CameraInfo, '/cam1/camera_info', DATA_QOS)
        proc = start_node('heatmap_detector', domain, log, '-r', '__ns:=/cam1', '-p', 'camera:=1')
        try:
            assert spin_until(executor, lambda: pub.get_subscription_count() > 0), log.read_text()
            assert spin_until(executor, lambda: info.get_subscription_count() > 0), log.read_text()
            info.publish(camera_to_info(cameras[1], _header(300, 'cam1')))  # agrees: nothing said
            wrong = camera_to_info(dataclasses.replace(cameras[1], K=cameras[1].K * [[1.1], [1], [1]]),
                                   _header(301, 'cam1'))
            info.publish(wrong)
            info.publish(wrong)  # the same problem again: said once
            for f in (300, 301, 302):
                pub.publish(openpose_to_msg(raw[1][f - FIRST], _header(f, 'cam1')))
            pub.publish(openpose_to_msg(raw[1][303 - FIRST], _header(303, 'cam7')))  # not this camera
            pub.publish(PointCloud2(header=_header(304, 'cam1'), fields=[PointField(name='x', datatype=7, count=1)]))
            pub.publish(openpose_to_msg(raw[1][305 - FIRST], _header(305, 'cam1')))
            assert spin_until(executor, lambda: 305 in out), log.read_text()
            spin_until(executor, lambda: False, 0.5)
        finally:
            stop(proc)
    assert sorted(out) == [300, 301, 302, 305] and all(len(v) == 1 for v in out.values())
    for f, [msg] in out.items():
        assert msg.header.frame_id == 'cam1'
        expected = detect_people(raw[1][f - FIRST], OpenPoseDetectorConfig())
        got = msg_to_people(msg)
        assert len(got) == len(expected) > 0
        for a, b in zip(got, expected):
            np.testing.assert_allclose(a.keypoints, b.keypoints, rtol=1e-6, atol=1e-4)
    text = log.read_text()
    assert "stamp 12120000000 ns dropped: frame_id 'cam7' is not this camera" in text
    assert 'stamp 12160000000 ns dropped' in text
    # the CameraInfo that contradicts the calibration parameter: named, once; the node goes on
    assert text.count('contradicts the calibration parameter: CameraInfo fx') == 1, text
    assert 'camera_info stamp 12040000000 ns' in text and 'camera_info stamp 12000000000' not in text


def test_heatmap_detector_with_a_bad_parameter_exits_2_with_one_line(domain, tmp_path):
    log = tmp_path / 'bad.log'
    proc = start_node('heatmap_detector', domain, log, '-p', 'camera:=9')
    assert proc.wait(30) == 2
    assert 'parameter camera: 9 is not in 0..4' in log.read_text()
    assert 'Traceback' not in log.read_text()


def test_association_bundles_every_stamp_and_goes_on_without_a_missing_camera(domain, shelf, tmp_path):
    cameras, raw = shelf
    frames = range(300, 306)
    people = {f: [detect_people(raw[c][f - FIRST], OpenPoseDetectorConfig()) for c in range(5)] for f in frames}
    log = tmp_path / 'association.log'
    with probe(domain, 'association_probe') as (node, executor):
        out: dict[int, list] = {}
        _collect(node, '/people/bundles', PointCloud2, out)
        pubs = [node.create_publisher(PointCloud2, f'/cam{c}/people2d', DATA_QOS) for c in range(5)]
        proc = start_node('association', domain, log, '-p', 'sync_timeout:=5.0')  # cam3 moving on releases 302
        try:
            assert spin_until(executor, lambda: all(p.get_subscription_count() for p in pubs)), log.read_text()
            for f in frames:
                for c in range(5):
                    if (f, c) != (302, 3):  # camera 3 loses frame 302
                        pubs[c].publish(people_to_msg(people[f][c], _header(f, f'cam{c}')))
            assert spin_until(executor, lambda: len(out) == len(frames)), log.read_text()
            spin_until(executor, lambda: False, 0.5)
        finally:
            stop(proc)
    assert sorted(out) == list(frames) and all(len(v) == 1 for v in out.values())
    # the same association as the core given the same (quantised) people
    associator = Associator(cameras, AssociationConfig())
    for f in frames:
        decoded = [msg_to_people(people_to_msg(people[f][c], _header(f, f'cam{c}'))) for c in range(5)]
        if f == 302:
            decoded[3] = None
        expected = sorted((o.person_id, sorted(o.views)) for o in associator.update(f, decoded))
        got = [(pid, sorted(views)) for pid, views in msg_to_bundles(out[f][0])]
        assert got == expected and len(got) >= 2
        assert out[f][0].header.frame_id == 'world'
    assert all(3 not in views for _, views in msg_to_bundles(out[302][0]))
    assert 'stamp 12080000000 ns (frame 302): no data from cam3; going on without' in log.read_text()


def test_bp_solver_publishes_one_skeleton_message_per_frame_equal_to_the_core(domain, shelf, tmp_path):
    cameras, raw = shelf
    frames = range(300, 312)
    associator = Associator(cameras, AssociationConfig())
    wire = {}
    for f in frames:
        people = [detect_people(raw[c][f - FIRST], OpenPoseDetectorConfig()) for c in range(5)]
        bundles = [(o.person_id, o.views) for o in associator.update(f, people)]
        wire[f] = bundles_to_msg(bundles, _header(f, 'world'))
    core = Inference3D(cameras, StageConfig.from_params({'window': 6, 'lag': 2}).solver)
    expected = {r.frame: r for f in frames for r in core.push(f, msg_to_bundles(wire[f]))}
    expected.update({r.frame: r for r in core.flush()})

    log = tmp_path / 'bp.log'
    with probe(domain, 'bp_probe') as (node, executor):
        skeletons: dict[int, list] = {}
        markers: dict[int, list] = {}
        _collect(node, '/skeletons', PointCloud2, skeletons)
        _collect(node, '/skeletons/markers', MarkerArray, markers)
        pub = node.create_publisher(PointCloud2, '/people/bundles', DATA_QOS)
        proc = start_node('bp_solver', domain, log, '-p', 'window:=6', '-p', 'lag:=2', '-p', 'idle_flush:=0.3')
        try:
            assert spin_until(executor, lambda: pub.get_subscription_count() > 0), log.read_text()
            for f in frames:
                pub.publish(wire[f])
            pub.publish(PointCloud2(header=_header(312, 'world')))  # no fields at all
            assert spin_until(executor, lambda: len(skeletons) == 13), log.read_text()
            spin_until(executor, lambda: False, 0.5)
        finally:
            stop(proc)
    assert sorted(skeletons) == [*frames, 312] and all(len(v) == 1 for v in skeletons.values())
    for f in frames:
        ids, joints = msg_to_skeletons(skeletons[f][0])
        assert ids.tolist() == expected[f].person_ids and len(ids) >= 2
        np.testing.assert_allclose(joints, expected[f].joints, atol=1e-5)
        assert skeletons[f][0].header.frame_id == 'world'
        assert len(markers[f]) == 1
    assert msg_to_skeletons(skeletons[312][0])[0].size == 0
    assert 'frame 312' in log.read_text() and 'published with no people' in log.read_text()
