"""The heatmap detector's input handling without processes: every image encoding and both
compressed formats decoded with the node's checks (DetectorCamera.admit, once, on arrival: the
calibrated size, a compressed header checked before decoding; then decode, nothing checked
again), an image checked once however it goes, the image type from the graph or by
image_transport's naming, rig topics resolved in the rig's namespace, the `camera` parameter, unusable inputs logged
once per camera and cause, and a driver's CameraInfo read once per content."""
from __future__ import annotations

import dataclasses
import struct
from types import SimpleNamespace

import cv2
import numpy as np
import pytest
from builtin_interfaces.msg import Time
from rclpy.parameter import Parameter
from rclpy.qos import HistoryPolicy, ReliabilityPolicy
from rclpy.serialization import serialize_message
from sensor_msgs.msg import CompressedImage, Image
from std_msgs.msg import Header

from msg_adapters.camera_info_msg import camera_to_info
from msg_adapters.cdr_header import deserialise
from msg_adapters.image_msg import ENCODINGS, check_camera_image, image_to_compressed_msg, image_to_msg
from mvpose_ros.core.detection.detector_settings import PARAMETERS, SPECS
from mvpose_ros.core.datasets.shelf_campus import dataset_dir, shelf_cameras
from mvpose_ros.core.defaults import data_root
from mvpose_ros.core.detection.encoded_image import max_image_bytes
from mvpose_ros.core.geometry.rig import load_rig_file
from mvpose_ros.nodes import detector_cameras
from mvpose_ros.nodes.detector_cameras import DetectorCamera, camera_indices, in_namespace, rig_namespace
from mvpose_ros.nodes.heatmap_detector import HeatmapDetectorNode
from mvpose_ros.nodes.image_topics import TYPE_RECHECK_S, ImageTypes, image_type, image_type_by_name
from mvpose_ros.nodes.runtime import StartupError, camera_qos
from mvpose_ros.package_files import package_path
from ros_harness import node_in_process

HEADER = Header(frame_id='cam1')


def decode_image(msg, camera):
    """An image through a one-camera node's input path: admitted (checked once), then decoded."""
    rig_camera = load_rig_file(package_path('config/rigs/shelf.yaml'), data_root=data_root()).cameras[1]
    cam = DetectorCamera(1, rig_camera, '/cam1/image_raw', '/cam1/camera_info', camera)
    return cam.decode(cam.admit(msg, queued=False))


@pytest.fixture(scope='module')
def shelf_image():
    """Shelf camera 1, frame 572, and its Camera (1032 x 776)."""
    bgr = cv2.imread(str(dataset_dir('shelf') / 'frames' / 'cam1_000572.png'))
    return bgr, shelf_cameras()[1]


@pytest.mark.parametrize('encoding', ENCODINGS)
def test_every_image_encoding_decodes_through_the_node_checks(shelf_image, encoding):
    bgr, camera = shelf_image
    got = decode_image(image_to_msg(bgr, HEADER, encoding, padding=3), camera)
    assert got.shape == bgr.shape and got.dtype == np.uint8
    if encoding.startswith('mono'):
        want = np.repeat(cv2.cvtColor(bgr, cv2.COLOR_BGR2GRAY)[..., None], 3, axis=2)
        np.testing.assert_array_equal(got, want)
    elif encoding in ('yuv422', 'uyvy', 'yuv422_yuy2', 'yuyv'):  # chroma shared by pixel pairs
        assert np.abs(got.astype(int) - bgr).mean() < 6
    elif encoding.startswith('bayer_'):  # two colours of each pixel interpolated
        assert np.abs(got.astype(int) - bgr).mean() < 6
    else:
        np.testing.assert_array_equal(got, bgr)


@pytest.mark.parametrize('fmt', ['jpeg', 'png'])
def test_compressed_images_decode_through_the_node_checks(shelf_image, fmt):
    bgr, camera = shelf_image
    got = decode_image(image_to_compressed_msg(bgr, HEADER, fmt), camera)
    assert got.shape == bgr.shape
    if fmt == 'png':
        np.testing.assert_array_equal(got, bgr)
    else:
        assert np.abs(got.astype(int) - bgr).mean() < 3


def test_images_of_another_size_or_undecodable_are_refused_with_their_cause(shelf_image):
    bgr, camera = shelf_image
    with pytest.raises(ValueError, match=r'^Image size: 320x240, expected 1032x776$'):
        decode_image(image_to_msg(bgr[:240, :320], HEADER), camera)
    with pytest.raises(ValueError, match=r'^CompressedImage size: the jpeg header declares 320x240, expected '
                                         r'1032x776$'):
        decode_image(image_to_compressed_msg(bgr[:240, :320], HEADER), camera)  # smaller: refused undecoded too
    big = image_to_compressed_msg(cv2.resize(bgr, (1040, 776)), HEADER)
    with pytest.raises(ValueError, match='declares 1040x776, expected 1032x776'):
        decode_image(big, camera)
    jpeg = image_to_compressed_msg(bgr, HEADER)
    data = bytes(jpeg.data)
    with pytest.raises(ValueError, match=r'no end marker \(truncated\)'):
        decode_image(CompressedImage(header=HEADER, format=jpeg.format, data=data[:len(data) // 2]), camera)
    # a header declaring a huge image: refused from the header, nothing decoded
    sof = data.index(b'\xff\xc0')
    bomb = data[:sof + 5] + struct.pack('>HH', 60000, 60000) + data[sof + 9:]
    with pytest.raises(ValueError, match='declares 60000x60000, expected 1032x776'):
        decode_image(CompressedImage(header=HEADER, format=jpeg.format, data=bomb), camera)
    with pytest.raises(ValueError, match='not a JPEG or PNG'):
        decode_image(CompressedImage(header=HEADER, format='jpeg', data=b'\x00' * 64), camera)
    with pytest.raises(ValueError, match="expected one of .* got '16UC1'"):  # a depth camera's topic
        decode_image(Image(header=HEADER, height=776, width=1032, encoding='16UC1', step=2064,
                           data=bytes(2064 * 776)), camera)


def test_the_image_type_comes_from_the_publishers_else_from_the_topic_name():
    assert image_type_by_name('/rig/left/image_raw/compressed') is CompressedImage
    assert image_type_by_name('/rig/left/image_raw') is Image
    assert image_type_by_name('/rig/left/compressed_image') is Image
    compressed, raw = 'sensor_msgs/msg/CompressedImage', 'sensor_msgs/msg/Image'
    assert image_type('/rig/right/frames', [compressed, compressed]) == (CompressedImage, 'graph')
    assert image_type('/rig/odd/compressed', [raw]) == (Image, 'graph')  # the publishers win over the name
    assert image_type('/rig/both', [raw, compressed]) == (Image, 'name')  # ambiguous: by the name
    assert image_type('/rig/absent/compressed', []) == (CompressedImage, 'name')


class _GraphNode:
    """What ImageTypes uses of a node: publishers that can come, a timer, a logger."""

    def __init__(self, publishers):
        self.publishers, self.timers, self.warnings = publishers, [], []

    def get_publishers_info_by_topic(self, topic):
        return [SimpleNamespace(topic_type=kind) for name, kind in self.publishers if name == topic]

    def create_timer(self, period, callback):
        timer = SimpleNamespace(period=period, callback=callback, cancelled=False)
        timer.cancel = lambda: setattr(timer, 'cancelled', True)
        self.timers.append(timer)
        return timer

    def get_logger(self):
        return SimpleNamespace(warning=self.warnings.append)


def test_image_types_follow_a_camera_that_comes_up_after_the_node():
    """A topic no publisher shows yet is typed by its name and looked up again until one does;
    publishers of the other type make the node subscribe again, once."""
    node = _GraphNode([('/rig/left/image_raw', 'sensor_msgs/msg/Image')])
    again = []
    types = ImageTypes(node, again.append)
    assert types.add(0, 'left', '/rig/left/image_raw').typed_by == 'graph' and not node.timers
    late = types.add(1, 'right', '/rig/right/frames')
    same = types.add(2, 'door', '/rig/door/image_raw/compressed')
    assert (late.kind, late.typed_by, same.kind) == (Image, 'name', CompressedImage)
    (timer,) = node.timers  # one for the node, however many topics wait
    assert timer.period == TYPE_RECHECK_S
    timer.callback()  # nobody publishes yet
    assert not again and late.typed_by == 'name' and not timer.cancelled
    node.publishers.append(('/rig/right/frames', 'sensor_msgs/msg/CompressedImage'))
    timer.callback()
    assert again == [1] and late.kind is CompressedImage and late.typed_by == 'graph'
    assert node.warnings == ['right: /rig/right/frames carries CompressedImage, not Image as its name suggests: '
                             'subscribing again'] and not timer.cancelled  # door still waits
    node.publishers.append(('/rig/door/image_raw/compressed', 'sensor_msgs/msg/CompressedImage'))
    timer.callback()
    assert again == [1] and same.typed_by == 'graph' and timer.cancelled  # as its name said


def test_rig_topics_resolve_in_the_rig_namespace():
    assert rig_namespace('/', None) == '/'
    assert rig_namespace('/cam1', 'cam1') == '/'  # the Shelf graph: a detector in its camera's namespace
    assert rig_namespace('/rig/cam1', 'cam1') == '/rig'
    assert rig_namespace('/rig', 'cam1') == '/rig'
    assert rig_namespace('/rig/cam1', None) == '/rig/cam1'  # the whole rig: the node's own
    assert in_namespace('/', 'cam1/image_raw') == '/cam1/image_raw'
    assert in_namespace('/rig', 'cam1/image_raw') == '/rig/cam1/image_raw'
    assert in_namespace('/rig', '/drivers/left/image_raw/compressed') == '/drivers/left/image_raw/compressed'


def test_the_camera_parameter_names_a_camera_an_index_or_the_whole_rig():
    rig = load_rig_file(package_path('config/rigs/shelf.yaml'), data_root=data_root())
    assert camera_indices(2, rig) == [2]
    assert camera_indices('2', rig) == [2]
    assert camera_indices('cam3', rig) == [3]
    assert camera_indices('', rig) == camera_indices('all', rig) == [0, 1, 2, 3, 4]
    with pytest.raises(StartupError, match=r'parameter camera: 9 is not in 0..4 .* cam0, cam1'):
        camera_indices(9, rig)
    with pytest.raises(StartupError, match=r"parameter camera: 'left' is not a camera of"):
        camera_indices('left', rig)
    with pytest.raises(StartupError, match='parameter camera'):
        camera_indices(True, rig)


def test_camera_inputs_are_best_effort_keep_last():
    qos = camera_qos(3)
    assert (qos.reliability, qos.history, qos.depth) == (ReliabilityPolicy.BEST_EFFORT, HistoryPolicy.KEEP_LAST, 3)
    assert camera_qos() is not camera_qos()  # fresh: the overriding options write into it


def test_admission_checks_every_input_before_it_is_queued_and_decodes_nothing(shelf_image):
    """The whole-rig mode admits an image into the synchroniser only after check_camera_image:
    data beyond the camera's byte bound, a header of another size, a truncated one are refused
    without decoding; a good image passes (and is then decodable)."""
    bgr, camera = shelf_image
    size = (camera.width, camera.height)
    jpeg = image_to_compressed_msg(bgr, HEADER)
    check_camera_image(jpeg, size)
    check_camera_image(image_to_msg(bgr, HEADER, 'rgb16'), size)  # 6 bytes a pixel: within the bound
    limit = max_image_bytes(*size)
    junk = Image(header=HEADER, height=776, width=1032, encoding='bgr8', step=limit // 776 + 1,
                 data=bytes((limit // 776 + 1) * 776))
    with pytest.raises(ValueError, match=f'^Image data: {len(junk.data)} bytes, more than a 1032x776 image takes'):
        check_camera_image(junk, size)
    padded = CompressedImage(header=HEADER, format=jpeg.format, data=bytes(jpeg.data) + bytes(limit))
    with pytest.raises(ValueError, match='^CompressedImage data: .* bytes, more than a 1032x776 image takes'):
        check_camera_image(padded, size)
    small = image_to_compressed_msg(bgr[:100, :100], HEADER, 'png')
    with pytest.raises(ValueError, match='declares 100x100, expected 1032x776'):
        check_camera_image(small, size)


def test_a_camera_info_is_read_once_per_content_and_what_is_wrong_said_once(monkeypatch, capfd):
    """A driver sends its CameraInfo with every image: the detector deserialises one only when
    more than its stamp differs from the last it read; one that contradicts the rig, or cannot be
    read, is still said (once)."""
    with node_in_process(monkeypatch, HeatmapDetectorNode, '-r', '__ns:=/cam1', '-p', 'camera:=1') as node:
        [cam] = node._cameras
        reads = []
        monkeypatch.setattr(detector_cameras, 'deserialise', lambda cdr, t: reads.append(cdr) or deserialise(cdr, t))

        def sent(sec: int, camera) -> bytes:
            return serialize_message(camera_to_info(camera, Header(stamp=Time(sec=sec), frame_id='cam1')))

        wrong = dataclasses.replace(cam.camera, K=cam.camera.K * [[1.1], [1], [1]])
        for sec, camera, total in ((12, cam.camera, 1), (13, cam.camera, 1), (14, cam.camera, 1),
                                   (15, wrong, 2), (16, wrong, 2), (17, cam.camera, 3)):
            node._on_info_cdr(cam, sent(sec, camera))
            assert len(reads) == total, sec
        junk = b'\x00\x01\x00\x00' + bytes(8) + b'\xff' * 8
        node._on_info_cdr(cam, junk)
        node._on_info_cdr(cam, junk)
    err = capfd.readouterr().err
    assert err.count('contradicts the calibration parameter: CameraInfo fx') == 1, err
    assert err.count(f'cam1: camera_info of {len(junk)} bytes unreadable') == 1, err


def test_an_image_is_checked_once_however_it_goes(shelf_image, monkeypatch):
    """One header read per image on every path: a one-camera node's (admitted, decoded), a whole
    rig's with the camera's size known and not yet known (fitted to it from what the check read),
    and to_bgr's; decoding reads it no more."""
    from msg_adapters.image_msg import to_bgr
    from mvpose_ros.core.detection import encoded_image
    bgr, camera = shelf_image
    reads = []
    declared_size = encoded_image.declared_size
    monkeypatch.setattr(encoded_image, 'declared_size', lambda data: reads.append(1) or declared_size(data))
    rig_camera = load_rig_file(package_path('config/rigs/shelf.yaml'), data_root=data_root()).cameras[1]
    jpeg = image_to_compressed_msg(bgr, HEADER)
    for queued, known in ((False, True), (True, True), (True, False)):
        cam = DetectorCamera(1, rig_camera, '/cam1/image_raw', '/cam1/camera_info', camera if known else None)
        image = cam.admit(jpeg, queued)
        cam.camera = camera
        assert cam.decode(image, 2).shape == (388, 516, 3) and len(reads) == 1, (queued, known)
        reads.clear()
    assert to_bgr(jpeg, (camera.width, camera.height)).shape == bgr.shape and len(reads) == 1
    small = image_to_compressed_msg(bgr[:100, :100], HEADER)
    cam = DetectorCamera(1, rig_camera, '/cam1/image_raw', '/cam1/camera_info')
    image = cam.admit(small, queued=True)  # any size until the camera's is known
    cam.camera = camera
    with pytest.raises(ValueError, match=r'^CompressedImage size: the jpeg header declares 100x100, expected '
                                         r'1032x776$'):
        cam.decode(image)


def test_the_node_declares_the_detectors_table_and_takes_live_changes_through_it(monkeypatch):
    """Every parameter of core.detection.detector_settings with its default, description and
    live or read-only; a live change reaches the detector's configuration, a read-only one is refused."""
    with node_in_process(monkeypatch, HeatmapDetectorNode, '-r', '__ns:=/cam1', '-p', 'camera:=1') as node:
        for p in PARAMETERS:
            assert node.get_parameter(p.name).value == p.default, p.name
            descriptor = node.describe_parameter(p.name)
            assert (descriptor.description, descriptor.read_only) == (p.description, not p.live), p.name
        live = {p.name for p in PARAMETERS if p.live}
        assert live == {'secondary_radius', 'box_margin', 'min_person_score', 'min_joint_score', 'heatmap_floor'}
        (result,) = node.set_parameters([Parameter('secondary_radius', value=0.5)])
        assert result.successful and node._settings.openpose.secondary_radius == 0.5
        (result,) = node.set_parameters([Parameter('stride', value=8.0)])
        assert not result.successful and node._settings.openpose.stride == SPECS['stride'].default
