"""CameraInfo from the real Shelf rig, Image conversion and the frame <-> stamp timeline."""
from __future__ import annotations

import dataclasses

import numpy as np
import pytest
from builtin_interfaces.msg import Time
from rclpy.serialization import deserialize_message, serialize_message
from sensor_msgs.msg import CameraInfo, Image
from std_msgs.msg import Header

from msg_adapters.camera_info_msg import camera_to_info, check_info, info_camera, info_to_intrinsics
from msg_adapters.image_msg import image_to_msg, msg_to_image
from msg_adapters.stamp import frame_of_stamp, stamp_ns, stamp_of_frame, stamp_of_ns
from mvpose_ros.core.geometry.rig import RigCamera


@pytest.fixture(scope='module')
def rig(shelf_rig):
    return shelf_rig


def test_camera_info_round_trip(rig):
    for c, cam in enumerate(rig):
        msg = camera_to_info(cam, Header(frame_id=f'cam{c}', stamp=stamp_of_frame(300)))
        assert (msg.width, msg.height) == (1032, 776)
        assert msg.distortion_model == 'plumb_bob' and len(msg.d) == 5
        np.testing.assert_array_equal(np.reshape(msg.r, (3, 3)), np.eye(3))
        np.testing.assert_array_equal(np.reshape(msg.p, (3, 4)), np.column_stack([cam.K, np.zeros(3)]))
        back = deserialize_message(serialize_message(msg), CameraInfo)
        K, dist, width, height, model = info_to_intrinsics(back)
        assert model == 'plumb_bob'
        np.testing.assert_array_equal(K, cam.K)
        np.testing.assert_array_equal(dist, cam.dist)
        assert (width, height) == (cam.width, cam.height)
        check_info(back, cam)


def test_check_info_detects_changes(rig):
    cam = rig[1]
    msg = camera_to_info(cam, Header())
    msg.k[0] += 0.4  # within 0.5 px
    check_info(msg, cam)
    msg.k[0] += 1.0
    with pytest.raises(ValueError, match='CameraInfo fx'):
        check_info(msg, cam)
    msg = camera_to_info(cam, Header())
    msg.width = 1030
    with pytest.raises(ValueError, match='CameraInfo size: 1030x776'):
        check_info(msg, cam)
    msg = camera_to_info(cam, Header())
    msg.k[5] -= 2
    with pytest.raises(ValueError, match='CameraInfo cy'):
        check_info(msg, cam)
    msg = camera_to_info(dataclasses.replace(cam, dist=np.array([0.05, 0, 0, 0, 0])), Header())
    with pytest.raises(ValueError, match='CameraInfo distortion'):
        check_info(msg, cam)
    msg = camera_to_info(dataclasses.replace(cam, dist=np.array([1e-7, 0, 0, 0, 0])), Header())
    check_info(msg, cam)  # far below a pixel at the corners


def test_info_to_intrinsics_rejects(rig):
    msg = camera_to_info(rig[0], Header())
    msg.distortion_model = 'kannala_brandt'
    with pytest.raises(ValueError, match="distortion_model: 'kannala_brandt' is not supported"):
        info_to_intrinsics(msg)
    msg = camera_to_info(rig[0], Header())
    msg.d = [0.0] * 4
    with pytest.raises(ValueError, match='CameraInfo d: expected 5 values for plumb_bob'):
        info_to_intrinsics(msg)
    msg = camera_to_info(rig[0], Header())
    msg.k[8] = 0
    with pytest.raises(ValueError, match='CameraInfo k'):
        info_to_intrinsics(msg)


@pytest.mark.parametrize('change, problem', [
    (dict(distortion_model='fisheye', d=[0.0] * 4),
     "CameraInfo distortion_model: 'fisheye' is not supported (supported: plumb_bob (k1 k2 p1 p2 k3), "
     "rational_polynomial (k1 k2 p1 p2 k3 k4 k5 k6), equidistant (k1 k2 k3 k4))"),
    (dict(distortion_model='rational_polynomial', d=[0.0] * 5),
     'CameraInfo d: expected 8 or 14 values for rational_polynomial (k1 k2 p1 p2 k3 k4 k5 k6) (or none), got 5'),
    (dict(distortion_model='equidistant', d=[0.0] * 5), 'CameraInfo d: expected 4 values for equidistant'),
    (dict(distortion_model='rational_polynomial', d=[0.0] * 13 + [0.01]),
     'CameraInfo d: thin prism and tilt terms (s1-s4, tau_x, tau_y) are not supported'),
    (dict(k=[0.0] * 9), 'fx, fy > 0 and K[2, 2] = 1, got [0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0] (all zeros: '
                        'the camera is not calibrated)'),
    (dict(k=[float('nan')] + [0.0] * 7 + [1.0]), 'CameraInfo k: expected a finite'),
    (dict(k=[-500.0, 0, 320, 0, 500, 240, 0, 0, 1]), 'CameraInfo k: expected a finite upper-triangular K with fx'),
    (dict(width=0), 'CameraInfo size: expected width, height >= 1, got 0x776'),
    (dict(height=0), 'CameraInfo size: expected width, height >= 1, got 1032x0'),
    (dict(d=[0.0, float('inf'), 0, 0, 0]), 'CameraInfo d: expected finite values'),
])
def test_info_to_intrinsics_errors_are_one_line(rig, change, problem):
    msg = camera_to_info(rig[0], Header())
    for field, value in change.items():
        setattr(msg, field, value)
    with pytest.raises(ValueError) as err:
        info_to_intrinsics(msg)
    assert str(err.value).startswith('CameraInfo ') and problem in str(err.value) and '\n' not in str(err.value)


def test_camera_info_completes_a_rig_camera(rig):
    """A rig camera with extrinsics only, completed from CameraInfo, is the calibrated camera; an
    empty d (a driver without distortion) is no distortion."""
    X = np.random.default_rng(0).uniform([-2, -2, 0], [2, 2, 2], (200, 3))
    for cam in rig:
        rc = RigCamera(f'cam{cam.name}', 'image_raw', 'camera_info', f'cam{cam.name}', cam.R, cam.t)
        msg = deserialize_message(serialize_message(camera_to_info(cam, Header())), CameraInfo)
        ours = rc.with_info(*info_to_intrinsics(msg))
        assert (ours.width, ours.height) == (1032, 776)
        np.testing.assert_allclose(ours.project(X), cam.project(X), atol=1e-9)
    msg = camera_to_info(rig[0], Header())
    msg.d = []
    K, dist, width, height, model = info_to_intrinsics(msg)
    assert dist.tolist() == [0.0] * 5 and (width, height) == (1032, 776) and model == 'plumb_bob'


def test_binning_and_a_region_of_interest_give_the_sent_images_intrinsics(rig):
    """A driver that bins and cuts a region sends the whole sensor's calibration with binning and
    roi: the camera is that of the image it sends (image_geometry's convention, full-sensor pixel
    u is (u - x_offset) / binning_x)."""
    cam = rig[1]
    rc = RigCamera('c1', 'image_raw', 'camera_info', 'c1', cam.R, cam.t)
    X = np.random.default_rng(1).uniform([-2, -2, 0], [2, 2, 2], (100, 3))
    full = cam.project(X)
    for binning, (x0, y0, w, h), size, offset in (((2, 2), (0, 0, 0, 0), (516, 388), (0, 0)),
                                                  ((0, 0), (100, 50, 600, 400), (600, 400), (100, 50)),
                                                  ((2, 4), (100, 50, 601, 400), (300, 100), (100, 50))):
        msg = camera_to_info(cam, Header())
        msg.binning_x, msg.binning_y = binning
        msg.roi.x_offset, msg.roi.y_offset, msg.roi.width, msg.roi.height = x0, y0, w, h
        sent = rc.with_info(*info_to_intrinsics(msg))
        assert (sent.width, sent.height) == size
        np.testing.assert_allclose(sent.project(X), (full - offset) / np.maximum(binning, 1), atol=1e-9)
    msg = camera_to_info(cam, Header())
    msg.roi.x_offset, msg.roi.width, msg.roi.height = 500, 600, 400
    with pytest.raises(ValueError) as err:
        info_to_intrinsics(msg)
    assert str(err.value) == 'CameraInfo roi: 600x400 at (500, 0) reaches outside the 1032x776 sensor'
    msg = camera_to_info(cam, Header())
    msg.binning_x = 2000
    with pytest.raises(ValueError, match='CameraInfo binning: 2000x1 leaves no pixel of the 1032x776 sensor'):
        info_to_intrinsics(msg)


def test_a_rectified_image_is_described_by_p_without_distortion(rig):
    """image_proc's image_rect goes with the raw camera's CameraInfo: with `rectified` the camera is
    P's, without distortion, whatever d and its model say; a point lands where OpenCV's
    rectification (undistortPoints onto P) puts its raw pixel. A P that does not project and an R
    that is not a rotation are refused in one line."""
    import cv2
    raw = dataclasses.replace(rig[1], dist=np.array([-0.25, 0.08, 0.001, -0.002, 0.0]))
    new_K, _ = cv2.getOptimalNewCameraMatrix(raw.K, raw.dist, (raw.width, raw.height), 0.0)
    msg = camera_to_info(raw, Header())
    msg.p = np.column_stack([new_K, np.zeros(3)]).ravel()
    rc = RigCamera('c1', 'image_rect', 'camera_info', 'c1', raw.R, raw.t, rectified=True)
    K, dist, width, height, model = info_to_intrinsics(msg, rectified=True)
    np.testing.assert_array_equal(K, new_K)
    assert dist.tolist() == [0.0] * 5 and model == 'plumb_bob' and (width, height) == (raw.width, raw.height)
    X = np.random.default_rng(2).uniform([-1, -1, 0], [1, 1, 2], (100, 3))
    X = X[np.all((raw.project(X) > 0) & (raw.project(X) < [raw.width, raw.height]), axis=1)]
    rectified = cv2.undistortPoints(raw.project(X)[:, None], raw.K, raw.dist, None, None, new_K,
                                    (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 100, 1e-12))[:, 0]
    np.testing.assert_allclose(info_camera(rc, msg).project(X), rectified, atol=1e-6)
    assert np.abs(raw.project(X) - rectified).max() > 5  # the lens matters here
    check_info(msg, info_camera(rc, msg), rectified=True, raw_R=rc.R)
    # a later CameraInfo turning the rectified frame otherwise: reported as K would be, in pixels
    later = camera_to_info(raw, Header())
    later.p, tilt = msg.p, np.radians(0.5)
    later.r = np.array([[1.0, 0, 0], [0, np.cos(tilt), -np.sin(tilt)], [0, np.sin(tilt), np.cos(tilt)]]).ravel()
    with pytest.raises(ValueError, match=r'^CameraInfo r: turns the rectified frame 0\.5 degrees from the R in use '
                                         r'\(\d+\.?\d* px at its focal length; tolerance 0\.5 px\)$'):
        check_info(later, info_camera(rc, msg), rectified=True, raw_R=rc.R)
    check_info(later, info_camera(rc, later), rectified=True, raw_R=rc.R)  # the camera it gives itself
    msg.distortion_model, msg.d = 'kannala_brandt', [0.1] * 9  # the raw lens is not read
    np.testing.assert_array_equal(info_to_intrinsics(msg, True)[0], new_K)
    for field, value, problem in (
            ('p', np.column_stack([new_K, [-50.0, 0, 3.0]]).ravel(), 'CameraInfo p: expected a last column '
             '[Tx, Ty, 0] (a stereo baseline, or zeros), got [-50.0, 0.0, 3.0]'),
            ('r', np.array([[1.0, 0, 0], [0, 0.8, -0.6], [0, 0.6, 0.9]]).ravel(), 'CameraInfo r: [1.0, 0.0, 0.0, '
             '0.0, 0.8, -0.6, 0.0, 0.6, 0.9] is not a rotation'),
            ('r', np.diag([1.0, 1.0, -1.0]).ravel(), 'CameraInfo r: [1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, -1.0] '
             'is not a rotation'),
            ('p', np.zeros(12), 'CameraInfo p: expected a finite upper-triangular P with fx, fy > 0')):
        bad = camera_to_info(raw, Header())
        bad.p = np.column_stack([new_K, np.zeros(3)]).ravel()
        setattr(bad, field, value)
        with pytest.raises(ValueError) as err:
            info_camera(rc, bad)
        assert str(err.value).startswith(problem) and '\n' not in str(err.value)
        info_to_intrinsics(bad)  # the raw image's K and d are fine


def test_a_stereo_pairs_rectified_images_are_each_at_their_cameras_pose(rig):
    """Two cameras 12 cm apart, rectified as a stereo pair by OpenCV (stereoRectify: R1, R2, P1, P2,
    P2 with the baseline), each given in the rig by its own raw pose: a world point lands in each
    rectified image where OpenCV's P projects it from the first camera's rectified frame, on the
    same row in both; without R it would not (the turn matters here)."""
    import cv2
    left = dataclasses.replace(rig[1], dist=np.array([-0.2, 0.05, 0.001, -0.001, 0.0]))
    turn = cv2.Rodrigues(np.array([0.02, -0.05, 0.01]))[0]  # right <- left
    shift = np.array([-0.12, 0.004, 0.006])  # the left centre in the right frame, metres
    right = dataclasses.replace(left, name='r', R=turn @ left.R, t=turn @ left.t + shift,
                                dist=np.array([-0.18, 0.04, -0.001, 0.0005, 0.0]))
    size = (left.width, left.height)
    R1, R2, P1, P2, *_ = cv2.stereoRectify(left.K, left.dist[None], right.K, right.dist[None], size, turn,
                                           shift[:, None], alpha=0)
    assert abs(P2[0, 3]) > 1.0 and np.abs(cv2.Rodrigues(R1)[0]).max() > 0.01  # a baseline and a turn
    X = np.random.default_rng(3).uniform([-1, -1, 0], [1, 1, 2], (200, 3))
    in_left = (left.R @ X.T).T + left.t  # left raw frame
    X = X[in_left[:, 2] > 1.0]
    in_left_rect = (R1 @ ((left.R @ X.T).T + left.t).T).T
    for cam, R, P in ((left, R1, P1), (right, R2, P2)):
        msg = camera_to_info(cam, Header())
        msg.r, msg.p = R.ravel(), P.ravel()
        rc = RigCamera(cam.name, 'image_rect', 'camera_info', cam.name, cam.R, cam.t, rectified=True)
        uvw = (P @ np.column_stack([in_left_rect, np.ones(len(X))]).T).T
        expected = uvw[:, :2] / uvw[:, 2:]
        np.testing.assert_allclose(info_camera(rc, msg).project(X), expected, atol=1e-6)
        msg.r = np.eye(3).ravel()
        assert np.abs(info_camera(rc, msg).project(X) - expected).max() > 5
    msgs = [camera_to_info(c, Header()) for c in (left, right)]
    for msg, R, P in zip(msgs, (R1, R2), (P1, P2)):
        msg.r, msg.p = R.ravel(), P.ravel()
    rows = [info_camera(RigCamera(c.name, 'i', 'c', c.name, c.R, c.t, rectified=True), m).project(X)[:, 1]
            for c, m in zip((left, right), msgs)]
    np.testing.assert_allclose(rows[0], rows[1], atol=1e-6)  # epipolar lines are rows


def _image(h: int = 6, w: int = 7) -> np.ndarray:
    return np.random.default_rng(0).integers(0, 256, (h, w, 3), dtype=np.uint8)


def test_image_round_trip():
    bgr = _image()
    msg = image_to_msg(bgr, Header(frame_id='cam2'))
    assert (msg.encoding, msg.height, msg.width, msg.step) == ('bgr8', 6, 7, 21)
    back = msg_to_image(deserialize_message(serialize_message(msg), Image))
    assert back.dtype == np.uint8 and np.array_equal(back, bgr)


def test_image_rgb8_and_padded_step():
    bgr = _image()
    rows = np.zeros((6, 25), np.uint8)  # 4 bytes of padding per row
    rows[:, :21] = bgr[..., ::-1].reshape(6, 21)
    msg = Image(height=6, width=7, encoding='rgb8', step=25, data=rows.tobytes())
    assert np.array_equal(msg_to_image(msg), bgr)
    msg.encoding = 'bgr8'
    assert np.array_equal(msg_to_image(msg), bgr[..., ::-1])


def test_image_rejects():
    msg = image_to_msg(_image(), Header())
    msg.encoding = 'bgr9'
    with pytest.raises(ValueError, match="encoding: expected one of .* got 'bgr9'"):
        msg_to_image(msg)
    msg = image_to_msg(_image(), Header())
    msg.height = 7
    with pytest.raises(ValueError, match='Image data: expected step'):
        msg_to_image(msg)
    msg = image_to_msg(_image(), Header())
    msg.step = 20
    with pytest.raises(ValueError, match='Image step'):
        msg_to_image(msg)
    with pytest.raises(ValueError, match=r'expected \(H, W, 3\) uint8'):
        image_to_msg(_image().astype(np.float32), Header())


def test_stamps():
    assert (stamp_of_frame(300).sec, stamp_of_frame(300).nanosec) == (12, 0)
    assert (stamp_of_frame(572).sec, stamp_of_frame(572).nanosec) == (22, 880_000_000)
    assert stamp_ns(stamp_of_frame(572)) == 22_880_000_000
    assert all(frame_of_stamp(stamp_of_frame(f)) == f for f in range(1001))
    assert all(stamp_ns(stamp_of_frame(f)) == 40_000_000 * f for f in range(1001))
    assert frame_of_stamp(Time(sec=12, nanosec=19_000_000)) == 300  # nearest frame
    assert frame_of_stamp(Time(sec=12, nanosec=21_000_000)) == 301
    assert frame_of_stamp(stamp_of_frame(90, rate=30.0), rate=30.0) == 90
    for ns in (0, 999_999_999, 1_700_000_000_123_456_789):
        t = stamp_of_ns(ns)
        assert stamp_ns(t) == ns and 0 <= t.nanosec < 1_000_000_000
    with pytest.raises(ValueError, match='frame'):
        stamp_of_frame(-1)
    with pytest.raises(ValueError, match='frame rate'):
        stamp_of_frame(3, rate=0.0)
