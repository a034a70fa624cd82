"""Lens models besides plumb_bob (core.geometry.lens): rational_polynomial and equidistant
against OpenCV, on the real Shelf camera 1 given the lenses of other drivers, and their way
through the rig file and CameraInfo; a calibration whose lens folds back inside its image is refused."""
from __future__ import annotations

import dataclasses

import cv2
import numpy as np
import pytest
import yaml
from rclpy.serialization import deserialize_message, serialize_message
from sensor_msgs.msg import CameraInfo
from std_msgs.msg import Header

from msg_adapters.camera_info_msg import camera_to_info, check_info, info_to_intrinsics
from msg_adapters.markers import frustum
from mvpose_ros.core.geometry import lens
from mvpose_ros.core.geometry.camera import Camera
from mvpose_ros.core.geometry.projection import rig_directions, rig_project
from mvpose_ros.core.geometry.rig import load_rig_file, matrix_to_quaternion

# the magnitudes of an Azure Kinect colour camera's rational_polynomial and a wide fisheye's equidistant
RATIONAL = np.array([0.5, -2.5, 0.001, -0.0005, 1.4, 0.4, -2.3, 1.3])
FISHEYE = np.array([0.1, -0.05, 0.01, -0.002])
UNTIL = 1e-12  # relative convergence of OpenCV's undistortion


@pytest.fixture(scope='module')
def camera(shelf_rig) -> Camera:
    return shelf_rig[1]


def _with(camera: Camera, model: str, dist: np.ndarray) -> Camera:
    return dataclasses.replace(camera, dist=dist, distortion_model=model)


def _points(camera: Camera, n: int, max_degrees: float, seed: int) -> np.ndarray:
    """(n, 3) world points within max_degrees of the camera's optical axis, 1-6 m in front."""
    rng = np.random.default_rng(seed)
    theta, phi = np.radians(rng.uniform(0, max_degrees, n)), rng.uniform(0, 2 * np.pi, n)
    d = np.stack([np.sin(theta) * np.cos(phi), np.sin(theta) * np.sin(phi), np.cos(theta)], axis=-1)
    return (d * rng.uniform(1, 6, (n, 1)) - camera.t) @ camera.R


def _rays_through(camera: Camera, X: np.ndarray) -> float:
    """The largest distance (m) of the points X (N, 3) from the rays of their own pixels."""
    o, d = camera.rays(camera.project(X))
    return float(np.linalg.norm(np.cross(X - o, d), axis=-1).max())


def test_rational_polynomial_matches_opencv(camera):
    cam = _with(camera, 'rational_polynomial', RATIONAL)
    X = _points(cam, 500, 35, 0)
    ours = cam.project(X)
    ref, _ = cv2.projectPoints(X, cv2.Rodrigues(cam.R)[0], cam.t, cam.K, RATIONAL)
    np.testing.assert_allclose(ours, ref[:, 0], atol=1e-6)
    assert np.abs(_with(camera, 'plumb_bob', RATIONAL[:5]).project(X) - ours).max() > 10.0  # k4-k6 matter
    assert _rays_through(cam, X) < 1e-9
    d = cam.directions(ours) @ cam.R.T
    ref = cv2.undistortPoints(ours[:, None], cam.K, RATIONAL, None, None, None,
                              (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 100, UNTIL))
    np.testing.assert_allclose(d[:, :2] / d[:, 2:], ref[:, 0], atol=1e-6)


def test_plumb_bob_is_rational_polynomial_without_k4_to_k6_to_the_bit(camera, shelf_rig):
    five = np.array([0.1, -0.05, 0.001, -0.002, 0.01])
    plumb = _with(camera, 'plumb_bob', five)
    rational = _with(camera, 'rational_polynomial', np.pad(five, (0, 3)))
    X = _points(camera, 300, 35, 1)
    np.testing.assert_array_equal(rational.project(X), plumb.project(X))
    uv = plumb.project(X)
    np.testing.assert_array_equal(rational.directions(uv), plumb.directions(uv))
    # in a rig of cameras with and without lenses, each camera's own (the undistorted one: test_camera)
    rig = [shelf_rig[0], rational, _with(camera, 'equidistant', FISHEYE)]
    which = np.arange(3).repeat(100)
    uv = rig_project(rig, which, X[:, None]).reshape(-1, 2)
    d = rig_directions(rig, which, uv)
    for c, cam in enumerate(rig):
        np.testing.assert_array_equal(uv[which == c], cam.project(X[which == c]))
        if c:
            np.testing.assert_array_equal(d[which == c], cam.directions(uv[which == c]))


def test_equidistant_matches_opencv_fisheye_to_85_degrees(camera):
    cam = _with(camera, 'equidistant', FISHEYE)
    X = _points(cam, 500, 85, 2)
    ours = cam.project(X)
    ref, _ = cv2.fisheye.projectPoints(X[:, None], cv2.Rodrigues(cam.R)[0], cam.t, cam.K, FISHEYE)
    np.testing.assert_allclose(ours, ref[:, 0], atol=1e-6)
    assert _rays_through(cam, X) < 1e-9
    d = cam.directions(ours) @ cam.R.T
    ref = cv2.fisheye.undistortPoints(ours[:, None], cam.K, FISHEYE,
                                      criteria=(cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 100, UNTIL))
    np.testing.assert_allclose(d[:, :2] / d[:, 2:], ref[:, 0], atol=1e-6)
    # the principal point is the optical axis
    np.testing.assert_allclose(cam.directions(cam.K[:2, 2]), cam.R[2], atol=1e-15)


def test_an_equidistant_lens_without_coefficients_still_maps_angles(camera):
    cam = _with(camera, 'equidistant', np.zeros(4))
    assert cam.has_distortion and not _with(camera, 'rational_polynomial', np.zeros(8)).has_distortion
    X = _points(cam, 200, 60, 3)
    x = (X @ cam.R.T + cam.t)
    r = np.hypot(x[:, 0], x[:, 1]) / x[:, 2]
    radius = np.hypot(*((cam.project(X) - cam.K[:2, 2]) / np.diag(cam.K)[:2]).T)  # normalised
    np.testing.assert_allclose(radius, np.arctan(r), atol=1e-12)


def test_kernel_and_numpy_distortion_agree(camera):
    for model, dist in (('rational_polynomial', RATIONAL), ('equidistant', FISHEYE)):
        cam = _with(camera, model, dist)
        x = _points(cam, 200, 60, 4) @ cam.R.T + cam.t
        xy = lens.distort(model, dist, x[:, :2] / x[:, 2:])
        np.testing.assert_allclose(cam.project(x @ cam.R - cam.t @ cam.R), xy @ cam.K[:2, :2].T + cam.K[:2, 2],
                                   rtol=0, atol=1e-9)
        np.testing.assert_allclose(lens.undistort(model, dist, xy), x[:, :2] / x[:, 2:], atol=1e-12)


def test_coefficients_pad_and_refuse_in_one_line():
    np.testing.assert_array_equal(lens.coefficients('equidistant', [0.1]), [0.1, 0, 0, 0])
    np.testing.assert_array_equal(lens.coefficients('rational_polynomial', np.r_[RATIONAL, np.zeros(6)]), RATIONAL)
    for model, values, problem in (
            ('plumb_bob', np.zeros(8), 'X: plumb_bob has at most 5 coefficients (k1 k2 p1 p2 k3), got 8'),
            ('rational_polynomial', np.r_[RATIONAL, [0, 0, 0, 0, 0.01, 0]],
             'X: thin prism and tilt terms (s1-s4, tau_x, tau_y) are not supported, '
             'got [0.0, 0.0, 0.0, 0.0, 0.01, 0.0]'),
            ('equidistant', np.zeros(8), 'X: equidistant has at most 4 coefficients (k1 k2 k3 k4), got 8')):
        with pytest.raises(ValueError) as err:
            lens.coefficients(model, values, 'X')
        assert str(err.value) == problem
    assert lens.unsupported('fisheye').startswith("distortion_model: 'fisheye' is not supported (supported: plumb_bob")
    with pytest.raises(ValueError, match="distortion_model 'fisheye' is not one of plumb_bob"):
        _with(Camera('c', np.eye(3), np.eye(3), np.zeros(3), np.zeros(5), 8, 8), 'fisheye', np.zeros(4))


def test_rig_file_and_camera_info_carry_the_model(tmp_path, camera):
    """A rig file's lens, and a driver's CameraInfo with it, give the camera back; a CameraInfo
    with another model is told apart by check_info."""
    X = _points(camera, 300, 35, 5)
    for model, dist in (('rational_polynomial', RATIONAL), ('equidistant', FISHEYE)):
        cam = _with(camera, model, dist)
        entry = {'name': 'wide', 'position': cam.centre.tolist(), 'orientation': matrix_to_quaternion(cam.R.T).tolist(),
                 'width': cam.width, 'height': cam.height, 'K': cam.K.tolist(), 'distortion_model': model,
                 'D': dist.tolist()}
        path = tmp_path / f'{model}.yaml'
        path.write_text(yaml.safe_dump({'cameras': [entry]}))
        ours = load_rig_file(path).cameras[0]
        assert ours.camera.distortion_model == model
        np.testing.assert_allclose(ours.camera.project(X), cam.project(X), atol=1e-6)
        msg = deserialize_message(serialize_message(camera_to_info(cam, Header(frame_id='wide'))), CameraInfo)
        assert msg.distortion_model == model and list(msg.d) == dist.tolist()
        from_info = ours.with_info(*info_to_intrinsics(msg))
        np.testing.assert_allclose(from_info.project(X), cam.project(X), atol=1e-6)
        check_info(msg, cam)
        with pytest.raises(ValueError, match=f'CameraInfo distortion: plumb_bob .* px from camera 1 {model}'):
            check_info(camera_to_info(camera, Header()), cam)
    # OpenCV's 14 coefficients, as some drivers send them, are the 8 while the rest are 0
    msg = camera_to_info(_with(camera, 'rational_polynomial', RATIONAL), Header())
    msg.d = [*RATIONAL, *[0.0] * 6]
    np.testing.assert_array_equal(info_to_intrinsics(msg)[1], RATIONAL)


def test_a_fisheye_frustum_stays_near_its_camera(camera):
    """Corners 90 degrees out (a fisheye's undistorted corners) are drawn near the camera, not at infinity."""
    cam = _with(dataclasses.replace(camera, K=np.diag([150.0, 150.0, 1.0]) + [[0, 0, 516], [0, 0, 388], [0, 0, 0]]),
                'equidistant', np.zeros(4))
    corners = frustum(cam, 0.5)
    assert np.degrees(np.arccos(cam.directions(np.array([[0.0, 0.0]])) @ cam.R[2])) > 85
    assert np.linalg.norm(corners[1:] - cam.centre, axis=-1).max() <= 1.0 + 1e-9


@pytest.mark.parametrize('model, dist, fold_at', [
    # r (1 + k1 r^2) stops growing at r = 1 / sqrt(-3 k1), where it is 2/3 of r
    ('plumb_bob', [-0.2, 0, 0, 0, 0], 2 / 3 / np.sqrt(0.6)),
    ('rational_polynomial', [-0.2, 0, 0, 0, 0, 0, 0, 0], 2 / 3 / np.sqrt(0.6)),
    # r / (1 + k4 r^2) at r = 1 / sqrt(k4), where it is r / 2
    ('rational_polynomial', [0, 0, 0, 0, 0, 0.5, 0, 0], 0.5 / np.sqrt(0.5)),
    # theta (1 + k1 theta^2) at theta = 1 / sqrt(-3 k1)
    ('equidistant', [-0.5, 0, 0, 0], 2 / 3 / np.sqrt(1.5)),
])
def test_a_lens_folds_where_its_radial_map_turns(model, dist, fold_at):
    dist = np.array(dist, dtype=float)
    assert lens.fold(model, dist, fold_at * 1.01) == pytest.approx(fold_at, rel=1e-4)
    assert lens.fold(model, dist, fold_at * 0.99) is None  # the image ends before it


def test_sound_lenses_do_not_fold_and_a_fisheye_may_see_beyond_its_corners():
    for model, dist in (('rational_polynomial', RATIONAL), ('equidistant', FISHEYE), ('plumb_bob', np.zeros(5))):
        assert lens.fold(model, dist, 3.0) is None  # about 70 degrees off axis
    # a circular fisheye: its image's corners lie beyond 90 degrees, outside its image circle
    assert lens.fold('equidistant', FISHEYE, 2.5) is None
    # a pinhole image cannot reach 90 degrees off axis: one reaching past what its lens maps there folds
    assert lens.fold('plumb_bob', np.array([-1e-7, 0, 0, 0, 0]), 1000.0) == pytest.approx(900.0, rel=1e-3)


def test_a_calibration_that_folds_inside_the_image_is_refused_in_one_line(tmp_path, camera):
    """From the rig file and from a CameraInfo: a wide camera whose k3 turns the map back 544 px out,
    with corners 734 px out, as a calibration without views near the corners can give."""
    wide = dataclasses.replace(camera, K=np.array([[600.0, 0, 640], [0, 600, 360], [0, 0, 1]]), width=1280,
                               height=720, dist=np.array([-0.3, 0.1, 0, 0, -0.02]))
    problem = (r"camera 'wide': D: the plumb_bob lens folds back about 544 px from the principal point, inside the "
               r"1280x720 image \(its corners reach 734 px\)")
    entry = {'name': 'wide', 'position': wide.centre.tolist(), 'orientation': matrix_to_quaternion(wide.R.T).tolist(),
             'width': wide.width, 'height': wide.height, 'K': wide.K.tolist(), 'D': wide.dist.tolist()}
    path = tmp_path / 'rig.yaml'
    path.write_text(yaml.safe_dump({'cameras': [entry]}))
    with pytest.raises(ValueError, match=problem) as err:
        load_rig_file(path)
    assert '\n' not in str(err.value)
    del entry['K'], entry['D'], entry['width'], entry['height']
    path.write_text(yaml.safe_dump({'cameras': [entry]}))
    from_info = load_rig_file(path).cameras[0]
    with pytest.raises(ValueError, match=problem):
        from_info.with_info(*info_to_intrinsics(camera_to_info(wide, Header())))
    k3 = dataclasses.replace(wide, dist=np.array([-0.3, 0.1, 0, 0, 0.0]))  # the same without k3: sound
    assert from_info.with_info(*info_to_intrinsics(camera_to_info(k3, Header()))).distortion_model == 'plumb_bob'
