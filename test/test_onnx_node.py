"""heatmap_detector with backend onnx as its own process, fed real Shelf images over DDS by an
in-test probe: one people2d message per usable image, the same people as the ROS-free detector,
and every unusable image logged with its stamp and the reason; a missing model stops the node at
start-up with one line and exit code 2; config/shelf_images.yaml as the runner and the node read it."""
from __future__ import annotations

import cv2
import numpy as np
import pytest
import rclpy
from rclpy.signals import SignalHandlerOptions
from sensor_msgs.msg import Image, PointCloud2
from std_msgs.msg import Header

from msg_adapters.image_msg import image_to_msg
from msg_adapters.people_msg import msg_to_people
from msg_adapters.stamp import frame_of_stamp, stamp_of_frame
from mvpose_ros.core.datasets.shelf_campus import calibration_file, dataset_dir
from mvpose_ros.core.defaults import data_root
from mvpose_ros.core.detection.onnx_detector import OnnxDetectorConfig, OnnxPoseDetector
from mvpose_ros.core.detection.onnx_models import MULTIPOSE
from mvpose_ros.graph.config import (NodeSpec, detector_backend, expected_connections, graph_settings, load_params,
                                     node_command)
from mvpose_ros.nodes.heatmap_detector import INPUT_TOPICS, HeatmapDetectorNode
from mvpose_ros.nodes.runtime import DATA_QOS
from ros_harness import REPO, probe, spin_until, start_node, stop

CALIBRATION = calibration_file('shelf')


def _header(frame: int, frame_id: str) -> Header:
    return Header(stamp=stamp_of_frame(frame), frame_id=frame_id)


def test_onnx_detector_node_turns_images_into_people_and_logs_bad_frames(domain, tmp_path):
    bgr = cv2.imread(str(dataset_dir('shelf') / 'frames' / 'cam1_000572.png'))
    log = tmp_path / 'detector.log'
    with probe(domain, 'onnx_detector_probe') as (node, executor):
        out: dict[int, list[PointCloud2]] = {}
        node.create_subscription(PointCloud2, '/cam1/people2d',
                                 lambda m: out.setdefault(frame_of_stamp(m.header.stamp), []).append(m), DATA_QOS)
        pub = node.create_publisher(Image, '/cam1/image_raw', DATA_QOS)
        # every image counts here: the camera subscription made reliable and deep enough by QoS
        # overrides (its default, best effort keep-last 2, drops what a slow detector cannot take)
        overrides = 'qos_overrides./cam1/image_raw.subscription'
        proc = start_node('heatmap_detector', domain, log, '-r', '__ns:=/cam1', '-p', 'camera:=1',
                          '-p', 'backend:=onnx', '-p', 'threads:=1', '-p', f'{overrides}.reliability:=reliable',
                          '-p', f'{overrides}.depth:=10')
        try:
            assert spin_until(executor, lambda: pub.get_subscription_count() > 0, 30.0), log.read_text()
            pub.publish(image_to_msg(bgr, _header(572, 'cam1')))
            pub.publish(image_to_msg(bgr, _header(573, 'cam7')))  # not this camera
            pub.publish(image_to_msg(bgr[:240, :320], _header(574, 'cam1')))  # not the calibrated size
            unknown = Image(header=_header(575, 'cam1'), height=2, width=2, encoding='xyz', step=2, data=bytes(4))
            pub.publish(unknown)
            pub.publish(image_to_msg(np.zeros_like(bgr), _header(576, 'cam1')))  # nobody: an empty message
            pub.publish(image_to_msg(bgr, _header(577, 'cam1')))
            pub.publish(image_to_msg(bgr, _header(578, 'cam1'), 'bayer_rggb8'))  # a machine-vision camera's
            assert spin_until(executor, lambda: 578 in out, 30.0), log.read_text()
            spin_until(executor, lambda: False, 0.5)
        finally:
            stop(proc)
    assert sorted(out) == [572, 576, 577, 578] and all(len(v) == 1 for v in out.values())
    assert msg_to_people(out[576][0]) == []
    rng = np.random.default_rng(0)
    # the node's settings (threads 1 as there: onnxruntime's sums depend on the thread split)
    expected = OnnxPoseDetector(OnnxDetectorConfig(model_dir=data_root() / 'models', threads=1)).detect(bgr)
    for f in (572, 577):
        msg = out[f][0]
        assert msg.header.frame_id == 'cam1'
        got = msg_to_people(msg)
        assert len(got) == len(expected) >= 3
        for a, b in zip(got, expected):
            np.testing.assert_allclose(a.keypoints, b.keypoints, atol=0.05)
            # the same maps (uint8 on the wire, zero-padded to the message's common grid), looked up
            # between the cell centres of the detector's own grid
            origin = np.broadcast_to(b.heatmap.origin, (16, 2))[:, None]
            last_cell = np.array(b.heatmap.maps.shape[:0:-1]) - 1
            uv = origin + b.heatmap.stride * rng.uniform(0, 1, (16, 200, 2)) * last_cell
            np.testing.assert_allclose(a.heatmap.lookup(uv), b.heatmap.lookup(uv), atol=1 / 255 + 1e-3)
    # demosaiced, the same people within a few pixels (3.6 px at most here; read as another pattern,
    # red and blue swapped, MultiPose orders them otherwise)
    mosaic = msg_to_people(out[578][0])
    assert len(mosaic) == len(expected)
    for a, b in zip(mosaic, expected):
        np.testing.assert_allclose(a.keypoints[:, :2], b.keypoints[:, :2], atol=5.0)
    text = log.read_text()
    assert "stamp 22920000000 ns dropped: frame_id 'cam7' is not 'cam1'; set frame_id: cam7 in the rig file" in text
    assert 'stamp 22960000000 ns dropped: Image size: 320x240, expected 1032x776' in text
    assert "stamp 23000000000 ns dropped: Image encoding: expected one of" in text and "got 'xyz'" in text


def test_a_missing_model_stops_the_node_with_one_line(domain, tmp_path):
    log = tmp_path / 'bad.log'
    rig = tmp_path / 'rig.yaml'  # the calibration where it is, the models in an empty data root
    rig.write_text(f'calibration: {CALIBRATION}\nwidth: 1032\nheight: 776\n')
    proc = start_node('heatmap_detector', domain, log, '-p', 'backend:=onnx', '-p', f'data_root:={tmp_path}',
                      '-p', f'rig:={rig}')
    assert proc.wait(30) == 2
    text = log.read_text()
    assert f'backend onnx: {tmp_path}/models/movenet_multipose.onnx: MoveNet MultiPose model file not found' in text
    assert 'Traceback' not in text


def test_heatmaps_multipose_runs_without_efficientpose_and_a_bad_source_stops_the_node(domain, tmp_path):
    """heatmaps multipose: the node starts with a models folder holding only MultiPose and sends
    the ROS-free detector's people; an unknown source stops it at start-up with one line."""
    bgr = cv2.imread(str(dataset_dir('shelf') / 'frames' / 'cam1_000572.png'))
    (tmp_path / 'models').mkdir()
    (tmp_path / 'models' / MULTIPOSE.file).symlink_to(data_root() / 'models' / MULTIPOSE.file)
    rig = tmp_path / 'rig.yaml'
    rig.write_text(f'calibration: {CALIBRATION}\nwidth: 1032\nheight: 776\n')
    overrides = 'qos_overrides./cam1/image_raw.subscription'  # reliable: the one image must not be lost
    args = ['-r', '__ns:=/cam1', '-p', 'camera:=1', '-p', 'backend:=onnx', '-p', 'threads:=1',
            '-p', f'data_root:={tmp_path}', '-p', f'rig:={rig}', '-p', f'{overrides}.reliability:=reliable']
    log = tmp_path / 'detector.log'
    with probe(domain, 'onnx_multipose_probe') as (node, executor):
        out: list[PointCloud2] = []
        node.create_subscription(PointCloud2, '/cam1/people2d', out.append, DATA_QOS)
        pub = node.create_publisher(Image, '/cam1/image_raw', DATA_QOS)
        proc = start_node('heatmap_detector', domain, log, *args, '-p', 'heatmaps:=multipose',
                          '-p', 'keypoint_sigma:=0.03')
        try:
            assert spin_until(executor, lambda: pub.get_subscription_count() > 0, 30.0), log.read_text()
            pub.publish(image_to_msg(bgr, _header(572, 'cam1')))
            assert spin_until(executor, lambda: out, 30.0), log.read_text()
        finally:
            stop(proc)
    config = OnnxDetectorConfig(model_dir=tmp_path / 'models', threads=1, heatmaps='multipose', keypoint_sigma=0.03)
    expected = OnnxPoseDetector(config).detect(bgr)
    got = msg_to_people(out[0])
    assert len(got) == len(expected) >= 3
    for a, b in zip(got, expected):
        np.testing.assert_allclose(a.keypoints, b.keypoints, atol=0.05)
        np.testing.assert_allclose(a.heatmap.peak()[:, 2], b.heatmap.peak()[:, 2], atol=1 / 255 + 1e-3)

    bad = tmp_path / 'bad.log'
    assert start_node('heatmap_detector', domain, bad, *args, '-p', 'heatmaps:=mpii').wait(30) == 2
    text = bad.read_text()
    assert "parameters: heatmaps 'mpii' is not one of efficientpose, multipose, fused" in text
    assert 'Traceback' not in text


def test_the_shelf_images_graph_config_runs_onnx_detectors_on_image_raw(domain, monkeypatch):
    """config/shelf_images.yaml: the runner reads /cam<c>/image_raw, and a detector started with the
    file takes every value of its section with the file's type."""
    params = load_params(REPO / 'config' / 'shelf_images.yaml')
    assert detector_backend(params) == 'onnx'
    assert detector_backend(load_params(REPO / 'config' / 'shelf.yaml')) == 'openpose'
    assert INPUT_TOPICS[detector_backend(params)] == 'image_raw'
    assert 'cam4/image_raw' in expected_connections(5, 'image_raw')
    assert graph_settings(REPO / 'config' / 'shelf_images.yaml').bag == 'bags/shelf_images'
    with pytest.raises(ValueError, match=r"different backends \['onnx', 'openpose'\]"):
        detector_backend({'/**/heatmap_detector': {'backend': 'onnx'},
                          '/cam1/heatmap_detector': {'backend': 'openpose'}})

    monkeypatch.setenv('ROS_AUTOMATIC_DISCOVERY_RANGE', 'LOCALHOST')
    monkeypatch.setenv('ROS_DOMAIN_ID', str(domain))
    spec = NodeSpec('heatmap_detector', 'cam2', {'camera': 2})
    cmd = node_command(spec, REPO / 'config' / 'shelf_images.yaml', python='python')
    rclpy.init(args=['prog', *cmd[3:]], signal_handler_options=SignalHandlerOptions.NO)
    node = None
    try:
        node = HeatmapDetectorNode()
        section = params['/**/heatmap_detector']
        got = {name: node.get_parameter(name).value for name in section}
    finally:
        if node is not None:
            node.destroy_node()
        rclpy.try_shutdown()
    assert got == section and {k: type(v) for k, v in got.items()} == {k: type(v) for k, v in section.items()}
