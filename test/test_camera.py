"""Camera model, rig loading and ray geometry, checked on the real Shelf and Campus calibration."""
from __future__ import annotations

import dataclasses
import json

import cv2
import numpy as np
import pytest
import scipy.optimize

from mvpose_ros.core.datasets.shelf_campus import SHELF_TEST_FRAMES, dataset_dir, load_actors_gt, load_actors_gt_2d
from mvpose_ros.core.geometry.camera import Camera, load_rig
from mvpose_ros.core.geometry.projection import rig_directions, rig_project
from mvpose_ros.core.geometry.rays import (closest_point_to_rays, closest_points_of_ray_sets, line_terms,
                                           ray_ray_distance, solve_line_terms)

SHELF_FRAMES = list(SHELF_TEST_FRAMES)[::10]

IMAGE_SIZES = {'shelf': (1032, 776), 'campus': (360, 288)}  # (width, height) as the datasets publish them


def _calibration(dataset: str):
    return dataset_dir(dataset) / 'calibration'


def _gt(dataset: str):
    """3D (F, A, 14, 3) and 2D (F, A, C, 14, 2) ground truth."""
    if dataset == 'shelf':
        mat, frames = dataset_dir('shelf') / 'actorsGT.mat', SHELF_FRAMES
    else:
        mat, frames = dataset_dir('campus') / 'mmpose_subset' / 'actorsGT.mat', None
    return load_actors_gt(mat, frames).poses, load_actors_gt_2d(mat, frames)


def _load(path, dataset: str = 'shelf') -> list[Camera]:
    """load_rig at the dataset's image size (the calibration files do not record it)."""
    return load_rig(path, *IMAGE_SIZES[dataset])


def _rigs(dataset: str) -> dict[str, list[Camera]]:
    calib = _calibration(dataset)
    p_form = [_load(f, dataset)[0] for f in sorted(calib.glob('P*.txt'))]
    return {'json': _load(calib / f'calibration_{dataset}.json', dataset), 'P': p_form}


@pytest.fixture(scope='module', params=['shelf', 'campus'])
def dataset(request):
    return request.param


def test_load_rig_shapes_and_sizes():
    shelf, campus = _load(_calibration('shelf'), 'shelf'), _load(_calibration('campus'), 'campus')
    assert [c.name for c in shelf] == ['0', '1', '2', '3', '4']
    assert {(c.width, c.height) for c in shelf} == {(1032, 776)}
    assert [c.name for c in campus] == ['0', '1', '2']
    assert {(c.width, c.height) for c in campus} == {(360, 288)}
    assert load_rig(_calibration('shelf'), width=640, height=480)[0].width == 640
    for cam in shelf + campus:
        assert cam.P.shape == (3, 4)
        np.testing.assert_allclose(cam.R @ cam.R.T, np.eye(3), atol=1e-5)
        # The rigs look at people near the world origin from 2..13 m away.
        assert 2.0 < np.linalg.norm(cam.centre[:2]) < 15.0


def test_json_matches_projection_files(dataset):
    rigs = _rigs(dataset)
    for cj, cp in zip(rigs['json'], rigs['P']):
        assert cj.name == cp.name
        assert (cj.width, cj.height) == (cp.width, cp.height)
        np.testing.assert_allclose(cj.R, cp.R, atol=1e-5)
        np.testing.assert_allclose(cj.centre, cp.centre, atol=1e-3)  # 1 mm
        np.testing.assert_allclose(cj.K, cp.K, atol=0.1)
        # The json rebuilds P*.txt (5 significant digits) up to scale.
        P = np.loadtxt(_calibration(dataset) / f'P{cj.name}.txt',
                       delimiter=',' if dataset == 'shelf' else None)
        np.testing.assert_allclose(cj.P / cj.P[2, 3] * P[2, 3], P,
                                   rtol=2e-4, atol=1e-3 * np.abs(P).max())


def test_projection_reproduces_actor2d(dataset):
    X, uv = _gt(dataset)
    for form, rig in _rigs(dataset).items():
        err = np.stack([np.abs(cam.project(X) - uv[:, :, c]) for c, cam in enumerate(rig)], axis=2)
        present = np.isfinite(uv).all(axis=(2, 3, 4))
        assert present.sum() >= 3
        err = err[present]  # (N, C, 14, 2)
        if dataset == 'shelf':
            assert err.max() < 0.1, form
        else:
            # Campus: camera 2 is an exact reprojection of the 3D ground truth; cameras 0 and 1
            # hold integer hand annotations the 3D was fitted to (errors up to ~2.7 px).
            assert err[:, 2].max() < 0.1, form
            assert err[:, :2].max() < 3.0, form
            assert np.all(uv[present][:, :2] == np.round(uv[present][:, :2]))


def test_from_projection_recovers_camera():
    rng = np.random.default_rng(0)
    R = cv2.Rodrigues(rng.normal(size=3))[0]
    K = np.array([[800.0, 0.5, 320.0], [0.0, 780.0, 240.0], [0.0, 0.0, 1.0]])
    t = np.array([0.1, -0.2, 4.0])
    P = K @ np.column_stack([R, t])
    for scale in (1.0, -3.7):  # P is defined up to any scale, sign included
        cam = Camera.from_projection('c', scale * P, 640, 480)
        np.testing.assert_allclose(cam.K, K, atol=1e-9)
        np.testing.assert_allclose(cam.R, R, atol=1e-12)
        np.testing.assert_allclose(cam.t, t, atol=1e-12)
        assert np.linalg.det(cam.R) == pytest.approx(1.0)


def _points_in_front(cam: Camera, rng: np.random.Generator, n: int) -> np.ndarray:
    """(n, 3) world points 0.5..10 m in front of cam, inside a wide cone."""
    x_cam = np.column_stack([rng.uniform(-1, 1, (n, 2)), np.ones(n)]) * rng.uniform(0.5, 10, (n, 1))
    return (x_cam - cam.t) @ cam.R


def test_ray_round_trip_real_cameras(dataset):
    rng = np.random.default_rng(1)
    for cam in _load(_calibration(dataset), dataset):
        X = _points_in_front(cam, rng, 500)
        o, d = cam.rays(cam.project(X))
        np.testing.assert_allclose(np.linalg.norm(d, axis=-1), 1.0)
        np.testing.assert_allclose(o, np.broadcast_to(cam.centre, o.shape))
        dist = np.linalg.norm(np.cross(X - o, d), axis=-1)
        assert dist.max() < 1e-6


def test_behind_camera_is_nan():
    cam = _load(_calibration('shelf'))[0]
    rng = np.random.default_rng(2)
    X = _points_in_front(cam, rng, 10)
    behind = 2 * cam.centre - X  # mirrored through the optical centre
    uv = cam.project(np.stack([X, behind, np.broadcast_to(cam.centre, X.shape)]))
    assert uv.shape == (3, 10, 2)
    assert np.isfinite(uv[0]).all()
    assert np.isnan(uv[1:]).all()


DIST = np.array([-0.28, 0.09, 0.0012, -0.0017, -0.015])


def _distorted_camera() -> Camera:
    cam = _load(_calibration('shelf'))[1]
    return dataclasses.replace(cam, dist=DIST)


def test_distortion_matches_opencv():
    cam = _distorted_camera()
    X = _points_in_front(cam, np.random.default_rng(3), 300)
    ours = cam.project(X)
    ref, _ = cv2.projectPoints(X, cv2.Rodrigues(cam.R)[0], cam.t, cam.K, cam.dist)
    np.testing.assert_allclose(ours, ref[:, 0], atol=1e-6)
    # Distortion actually moves points, so the comparison above is not vacuous.
    plain = dataclasses.replace(cam, dist=np.zeros(5)).project(X)
    assert np.abs(plain - ours).max() > 10.0


def test_distortion_round_trip():
    cam = _distorted_camera()
    rng = np.random.default_rng(4)
    # Pixels over the whole image (this lens stays monotone there) -> rays -> project back.
    uv = rng.uniform([0, 0], [cam.width, cam.height], (1000, 2))
    o, d = cam.rays(uv)
    np.testing.assert_allclose(cam.project(o + 3.0 * d), uv, atol=1e-6)
    # And world points -> pixels -> rays pass through the points.
    X = o + rng.uniform(0.5, 10.0, (1000, 1)) * d
    o2, d2 = cam.rays(cam.project(X))
    assert np.linalg.norm(np.cross(X - o2, d2), axis=-1).max() < 1e-6
    # Agrees with OpenCV's undistortion run to convergence.
    ref = cv2.undistortPoints(uv[:, None], cam.K, cam.dist, None, None, None,
                              (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 100, 1e-12))
    d_cam = d @ cam.R.T
    np.testing.assert_allclose(d_cam[:, :2] / d_cam[:, 2:], ref[:, 0], atol=1e-6)


def test_rays_vectorised_shapes():
    cam = _load(_calibration('shelf'))[0]
    o, d = cam.rays(np.zeros((4, 7, 2)))
    assert o.shape == d.shape == (4, 7, 3)


def _numpy_project(cam: Camera, X: np.ndarray) -> np.ndarray:
    """Camera.project as numpy on whole arrays (the formulation the kernel replaced)."""
    x, y, z = np.moveaxis(X, -1, 0)
    R, t, K = cam.R, cam.t, cam.K
    depth = R[2, 0] * x + R[2, 1] * y + R[2, 2] * z + t[2]
    with np.errstate(divide='ignore'):
        inv = np.where(depth > 0, 1.0 / depth, np.nan)
    xn = (R[0, 0] * x + R[0, 1] * y + R[0, 2] * z + t[0]) * inv
    yn = (R[1, 0] * x + R[1, 1] * y + R[1, 2] * z + t[1]) * inv
    if cam.has_distortion:
        k1, k2, p1, p2, k3 = cam.dist
        r2 = xn * xn + yn * yn
        radial = 1 + r2 * (k1 + r2 * (k2 + r2 * k3))
        xn, yn = (xn * radial + 2 * p1 * xn * yn + p2 * (r2 + 2 * xn * xn),
                  yn * radial + p1 * (r2 + 2 * yn * yn) + 2 * p2 * xn * yn)
    return np.stack([K[0, 0] * xn + K[0, 1] * yn + K[0, 2], K[1, 0] * xn + K[1, 1] * yn + K[1, 2]], axis=-1)


def test_projection_is_numpys_arithmetic():
    rig = _load(_calibration('shelf'))[:3] + [_distorted_camera()]
    rng = np.random.default_rng(5)
    X = rng.uniform(-3, 3, (6, 50, 3))
    X[0, :5] = rig[0].centre  # at the camera: NaN
    for cam in rig:
        np.testing.assert_array_equal(cam.project(X), _numpy_project(cam, X))
        np.testing.assert_array_equal(cam.project(X[0, 0]), _numpy_project(cam, X[0, 0]))
        assert cam.project(np.zeros((0, 3))).shape == (0, 2)
    # read-only points (a camera's centre) and broadcasts are taken as any other
    np.testing.assert_array_equal(rig[0].project(rig[1].centre), _numpy_project(rig[0], rig[1].centre))
    np.testing.assert_array_equal(rig[0].project(np.broadcast_to(X[1, 0], (2, 3))),
                                  _numpy_project(rig[0], X[1, :1])[[0, 0]])
    which, of = np.array([3, 0, 0, 2]), np.array([1, 1, 5, 0])
    uv = rig_project(rig, which, X, of)
    for n in range(4):
        np.testing.assert_array_equal(uv[n], _numpy_project(rig[which[n]], X[of[n]]))
    assert rig_project(rig, np.zeros(0, int), X[:0]).shape == (0, 50, 2)


def test_rig_directions_are_each_cameras():
    rig = _load(_calibration('shelf'))[:3] + [_distorted_camera()]
    rng = np.random.default_rng(6)
    which = rng.integers(0, len(rig), 200)
    uv = rng.uniform(0, 700, (200, 2))
    d = rig_directions(rig, which, uv)
    for i, cam in enumerate(rig):
        mine = which == i
        if cam.has_distortion:
            np.testing.assert_array_equal(d[mine], cam.directions(uv[mine]))
        else:  # numpy's arithmetic on whole arrays, the same bits
            to_ray = cam._pixel_to_ray
            ray = to_ray[:, 0] * uv[mine, :1] + to_ray[:, 1] * uv[mine, 1:] + to_ray[:, 2]
            np.testing.assert_array_equal(d[mine], ray / np.sqrt(np.einsum('ni,ni->n', ray, ray))[:, None])
    assert rig_directions(rig[:1], np.zeros(0, int), np.zeros((0, 2))).shape == (0, 3)


def test_line_terms_and_their_solve_are_numpys_arithmetic():
    rng = np.random.default_rng(7)
    o = rng.normal(size=(4, 3, 3))
    d = rng.normal(size=(4, 3, 3))
    d /= np.linalg.norm(d, axis=-1, keepdims=True)
    terms = line_terms(o, d)
    dx, dy, dz = np.moveaxis(d, -1, 0)
    along = dx * o[..., 0] + dy * o[..., 1] + dz * o[..., 2]
    expected = np.stack([1 - dx * dx, -dx * dy, -dx * dz, 1 - dy * dy, -dy * dz, 1 - dz * dz,
                         o[..., 0] - dx * along, o[..., 1] - dy * along, o[..., 2] - dz * along])
    np.testing.assert_array_equal(terms, expected)
    np.testing.assert_array_equal(line_terms(o[:, :1], d), line_terms(np.broadcast_to(o[:, :1], d.shape), d))
    d.flags.writeable = False
    np.testing.assert_array_equal(line_terms(o, d), terms)
    out = np.zeros((9, 4, 3, 2))
    line_terms(o, d, out=out[..., 0])
    np.testing.assert_array_equal(out[..., 0], terms)
    # Cramer's rule against a linear solve; one line alone and non-finite sums are NaN
    summed = terms.sum(axis=-1)
    summed[:, 1] = terms[:, 1, 0]
    summed[6, 2] = np.inf
    x = solve_line_terms(summed, 3)
    a = summed[[0, 1, 2, 1, 3, 4, 2, 4, 5]].T.reshape(-1, 3, 3)
    np.testing.assert_allclose(x[[0, 3]], np.linalg.solve(a[[0, 3]], summed[6:, [0, 3]].T[..., None])[..., 0],
                               rtol=1e-9)
    assert np.isnan(x[[1, 2]]).all()
    assert solve_line_terms(np.zeros((9, 0)), 2).shape == (0, 3)


def test_closest_points_of_ray_sets_are_line_terms_summed_and_solved():
    rng = np.random.default_rng(8)
    centres = rng.normal(size=(4, 3))
    of = rng.integers(0, 4, 30)
    dirs = rng.normal(size=(30, 3))
    dirs /= np.linalg.norm(dirs, axis=1, keepdims=True)
    sets = rng.integers(0, 30, (12, 4))
    sets[:4, 3] = -1  # sets of three
    sets[4, 1:] = -1  # one ray alone: NaN
    sets[5, 1] = sets[5, 0]  # the same ray twice, and two more
    sets[6] = -1  # no ray at all, after a set that had some: NaN, nothing left over from it
    # numpy: every ray's terms, a zero column for padding, summed slot after slot, solved
    terms = np.concatenate([line_terms(centres[of], dirs), np.zeros((9, 1))], axis=1)
    summed = terms[:, sets[:, 0]]
    for k in range(1, 4):
        summed += terms[:, sets[:, k]]
    expected = solve_line_terms(summed, 4)
    points = closest_points_of_ray_sets(centres, of, dirs, sets)
    np.testing.assert_array_equal(points, expected)
    assert np.isnan(points[[4, 6]]).all() and np.isfinite(points[~np.isin(np.arange(12), [4, 6])]).all()
    assert closest_points_of_ray_sets(centres, of, dirs, np.zeros((0, 2), int)).shape == (0, 3)


def test_closest_point_exact_without_noise():
    rng = np.random.default_rng(5)
    X = rng.normal(size=(50, 3))
    o = rng.normal(scale=5.0, size=(50, 4, 3))
    d = (X[:, None] - o) * rng.uniform(0.1, 3.0, (50, 4, 1))  # non-unit, either length
    np.testing.assert_allclose(closest_point_to_rays(o, d), X, atol=1e-10)
    np.testing.assert_allclose(closest_point_to_rays(o[:, :2], d[:, :2]), X, atol=1e-10)


def test_closest_point_is_least_squares_under_noise():
    rng = np.random.default_rng(6)
    o = rng.normal(scale=4.0, size=(20, 3, 3))
    d = rng.normal(size=(20, 3, 3))  # unrelated lines: a large residual
    ours = closest_point_to_rays(o, d)
    for i in range(len(o)):
        u = d[i] / np.linalg.norm(d[i], axis=-1, keepdims=True)

        def residual(x, i=i, u=u):
            return np.cross(x - o[i], u).ravel()  # |(x - o) x u| = distance to the line

        ref = scipy.optimize.least_squares(residual, np.zeros(3), xtol=1e-14, ftol=1e-14).x
        np.testing.assert_allclose(ours[i], ref, atol=1e-6)
        cost = np.sum(residual(ours[i]) ** 2)
        assert cost > 0.1  # genuinely noisy: the lines do not meet
        assert cost <= np.sum(residual(ref) ** 2) + 1e-12


def test_closest_point_degenerate_is_nan():
    o = np.array([[[0.0, 0, 0], [1, 0, 0]], [[0, 0, 0], [1, 0, 0]]])
    d = np.array([[[0.0, 0, 1], [0, 0, 2]], [[0, 0, 1], [np.nan, 0, 1]]])
    assert np.isnan(closest_point_to_rays(o, d)).all()
    good = closest_point_to_rays(np.array([[0.0, 0, 0], [1, 0, 0]]),
                                 np.array([[0.0, 0, 1], [-1, 0, 1]]))
    np.testing.assert_allclose(good, [0, 0, 1], atol=1e-12)


def test_ray_ray_distance_vs_brute_force():
    rng = np.random.default_rng(7)
    o1, d1, o2, d2 = rng.normal(size=(4, 30, 3))
    ours = ray_ray_distance(o1, d1, o2, d2)
    for i in range(30):
        ref = scipy.optimize.minimize(
            lambda st, i=i: np.sum((o1[i] + st[0] * d1[i] - o2[i] - st[1] * d2[i]) ** 2),
            np.zeros(2), method='BFGS', options={'gtol': 1e-12}).fun
        assert ours[i] == pytest.approx(np.sqrt(ref), abs=1e-6)
    # Intersecting lines are at distance 0.
    assert ray_ray_distance(o1, d1, o1 + 2.0 * d1, d2) == pytest.approx(np.zeros(30), abs=1e-12)


def test_ray_ray_distance_parallel():
    o1 = np.array([[0.0, 0, 0], [1, 2, 3]])
    d = np.array([[0.0, 0, 1], [1, 1, 0]])
    # Perpendicular parts of the offsets: (3, 4, 0) and all of (0.5, -0.5, 2).
    offset = np.array([[3.0, 4, 7], [0.5, -0.5, 2]])
    dist = ray_ray_distance(o1, d, o1 + offset, -2.5 * d)
    np.testing.assert_allclose(dist, [5.0, np.sqrt(0.5 + 4)], atol=1e-12)


def _broken_calibration(tmp_path, change) -> str:
    entries = json.loads((_calibration('shelf') / 'calibration_shelf.json').read_text())
    change(entries['1'])
    path = tmp_path / 'calibration_shelf.json'
    path.write_text(json.dumps(entries))
    return str(path)


@pytest.mark.parametrize('change, problem', [
    (lambda e: e.pop('fx'), "camera '1': missing fx"),
    (lambda e: e.update(R=[[0.0] * 3] * 3), "camera '1': R is not a rotation (determinant 0)"),
    (lambda e: e.update(R=[[-1.0, 0, 0], [0, 1, 0], [0, 0, 1]]), 'R is not a rotation (determinant -1)'),
    (lambda e: e.update(fx=0.0), 'focal lengths fx, fy must be > 0 (a singular K)'),
    (lambda e: e.update(T=[1.0, 'a', 2.0]), 'must be numbers'),
    (lambda e: e.update(cy=float('nan')), 'non-finite values'),
])
def test_bad_calibration_is_a_clear_error_naming_file_camera_and_field(tmp_path, change, problem):
    path = _broken_calibration(tmp_path, change)
    with pytest.raises(ValueError) as err:
        _load(path)
    assert str(err.value).startswith(path) and problem in str(err.value) and '\n' not in str(err.value)


def test_calibration_that_is_not_json(tmp_path):
    path = tmp_path / 'calibration_x.json'
    path.write_text('{"0": {"R": [1, 2')
    with pytest.raises(ValueError, match=r'calibration_x.json: not valid JSON'):
        _load(path)


@pytest.mark.parametrize('size', [(None, None), (1032, None), (None, 776)])
def test_image_size_is_never_guessed(size):
    """Calibration files do not record the image size: without one, a clear error naming the
    file, not a size guessed from the file name ("shelf") or from 2 cx, 2 cy."""
    for path in (_calibration('shelf') / 'calibration_shelf.json', _calibration('shelf') / 'P0.txt',
                 _calibration('campus')):
        with pytest.raises(ValueError, match=r'image size unknown: .* give width and height') as err:
            load_rig(path, *size)
        assert str(err.value).startswith(str(path)) and '\n' not in str(err.value)


def test_image_size_must_be_positive():
    with pytest.raises(ValueError, match='image size must be at least 1x1 pixels, got 0x776'):
        load_rig(_calibration('shelf'), 0, 776)
