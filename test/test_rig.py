"""Rig files: a quaternion rig reproduces the Shelf calibration's projection, the Shelf and Campus
rig files load the calibration, CameraInfo completes extrinsics-only cameras, and every error is
one line naming the file, the camera and the field."""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import yaml
from scipy.spatial.transform import Rotation

from mvpose_ros.core.datasets.shelf_campus import dataset_dir
from mvpose_ros.core.defaults import data_root
from mvpose_ros.core.geometry.camera import load_rig
from mvpose_ros.core.geometry.rig import (RigCamera, load_rig_file, matrix_to_quaternion,
                                          quaternion_to_matrix)

CONFIG = Path(__file__).resolve().parents[1] / 'config' / 'rigs'
SHELF_JSON = dataset_dir('shelf') / 'calibration' / 'calibration_shelf.json'

IMAGE_SIZES = {'shelf': (1032, 776), 'campus': (360, 288)}  # (width, height) as the datasets publish them


@pytest.fixture(scope='module')
def shelf():
    return load_rig(SHELF_JSON, *IMAGE_SIZES['shelf'])


def _points(rng: np.random.Generator, n: int = 400) -> np.ndarray:
    """(n, 3) points in the Shelf capture volume, metres."""
    return rng.uniform([-2.0, -2.0, 0.0], [2.0, 2.0, 2.0], (n, 3))


def _quaternion_entry(cam, with_intrinsics: bool = True) -> dict:
    """A rig-file camera entry of cam: position and orientation world <- camera (scipy's x y z w)."""
    entry = {'name': f'cam{cam.name}', 'image': f'/rig/cam{cam.name}/image_raw/compressed',
             'camera_info': f'/rig/cam{cam.name}/camera_info', 'frame_id': f'cam{cam.name}_optical',
             'position': cam.centre.tolist(), 'orientation': Rotation.from_matrix(cam.R.T).as_quat().tolist()}
    if with_intrinsics:
        entry.update(width=cam.width, height=cam.height, K=cam.K.tolist(), distortion_model='plumb_bob',
                     D=cam.dist.tolist())
    return entry


def _max_px(a: np.ndarray, b: np.ndarray) -> float:
    """Largest pixel difference of two projections, which must be behind the camera (NaN) alike."""
    assert np.array_equal(np.isnan(a), np.isnan(b)) and np.isfinite(a).any()
    return float(np.nanmax(np.abs(a - b)))


def _write(tmp_path: Path, doc) -> Path:
    path = tmp_path / 'rig.yaml'
    path.write_text(doc if isinstance(doc, str) else yaml.safe_dump(doc))
    return path


def test_quaternion_rig_reproduces_the_shelf_projection(tmp_path, shelf):
    path = _write(tmp_path, {'world_frame': 'map', 'up': [0, 0, 2.0],
                             'cameras': [_quaternion_entry(cam) for cam in shelf]})
    rig = load_rig_file(path)
    assert rig.world_frame == 'map' and rig.up.tolist() == [0.0, 0.0, 1.0] and rig.calibrated
    assert rig.names == ['cam0', 'cam1', 'cam2', 'cam3', 'cam4']
    X = _points(np.random.default_rng(0))
    for cam, rc, ours in zip(shelf, rig.cameras, rig.calibrated_cameras()):
        assert (rc.frame_id, rc.image) == (f'cam{cam.name}_optical', f'/rig/cam{cam.name}/image_raw/compressed')
        assert _max_px(ours.project(X), cam.project(X)) < 1e-6  # pixels
        np.testing.assert_allclose(rc.position, cam.centre, atol=1e-12)


def test_extrinsics_only_camera_is_completed_from_camera_info(tmp_path, shelf):
    path = _write(tmp_path, {'cameras': [_quaternion_entry(cam, with_intrinsics=False) for cam in shelf]})
    rig = load_rig_file(path)
    assert not rig.calibrated and all(rc.camera is None for rc in rig.cameras)
    with pytest.raises(ValueError, match='cameras cam0, cam1, cam2, cam3, cam4: no intrinsics'):
        rig.calibrated_cameras()
    X = _points(np.random.default_rng(1))
    for cam, rc in zip(shelf, rig.cameras):
        ours = rc.with_info(cam.K, cam.dist, cam.width, cam.height, 'plumb_bob')
        assert (ours.width, ours.height) == (1032, 776)
        assert _max_px(ours.project(X), cam.project(X)) < 1e-6
    with pytest.raises(ValueError, match=r"camera 'cam0': distortion_model: 'fisheye' is not supported"):
        rig.cameras[0].with_info(shelf[0].K, np.zeros(4), 1032, 776, 'fisheye')
    with pytest.raises(ValueError, match=r"camera 'cam0': width: expected a whole number of pixels >= 1, got 0"):
        rig.cameras[0].with_info(shelf[0].K, np.zeros(5), 0, 776)


def test_defaults_and_intrinsics_forms(tmp_path, shelf):
    cam = shelf[0]
    fx, fy, cx, cy = (float(v) for v in (cam.K[0, 0], cam.K[1, 1], cam.K[0, 2], cam.K[1, 2]))
    entry = {'name': 'left', 'position': [0, 0, 1], 'orientation': [0, 0, 0, 1],
             'width': 640, 'height': 480, 'K': [fx, fy, cx, cy]}
    rig = load_rig_file(_write(tmp_path, {'cameras': [entry]}))
    rc = rig.cameras[0]
    # no frame_id: the one its messages carry (core.geometry.frame_id), not its name
    assert (rc.name, rc.image, rc.camera_info, rc.frame_id) == ('left', 'left/image_raw', 'left/camera_info', None)
    assert rig.world_frame == 'world' and rig.up.tolist() == [0.0, 0.0, 1.0]
    np.testing.assert_array_equal(rc.camera.K, [[fx, 0, cx], [0, fy, cy], [0, 0, 1]])
    np.testing.assert_array_equal(rc.camera.dist, np.zeros(5))
    # identity orientation: the optical axis is the world's +z, from the centre (0, 0, 1)
    np.testing.assert_allclose(rc.camera.project(np.array([0.0, 0.0, 3.0])), [cx, cy])
    np.testing.assert_allclose(rc.orientation, [0, 0, 0, 1])


def test_quaternion_conversions_agree_with_scipy():
    for q in Rotation.random(50, random_state=2).as_quat():
        np.testing.assert_allclose(quaternion_to_matrix(q), Rotation.from_quat(q).as_matrix(), atol=1e-12)
        back = matrix_to_quaternion(quaternion_to_matrix(q))
        np.testing.assert_allclose(back, q if q[3] >= 0 else -q, atol=1e-12)


@pytest.mark.parametrize('dataset, cameras', [('shelf', 5), ('campus', 3)])
def test_shelf_and_campus_rig_files(dataset, cameras):
    rig = load_rig_file(CONFIG / f'{dataset}.yaml', data_root=data_root())
    reference = load_rig(dataset_dir(dataset) / 'calibration' / f'calibration_{dataset}.json',
                         *IMAGE_SIZES[dataset])
    assert rig.names == [f'cam{c}' for c in range(cameras)] and rig.world_frame == 'world'
    assert [(rc.image, rc.camera_info, rc.frame_id) for rc in rig.cameras] == [
        (f'cam{c}/image_raw', f'cam{c}/camera_info', f'cam{c}') for c in range(cameras)]
    for ours, ref in zip(rig.calibrated_cameras(), reference):
        assert (ours.name, ours.width, ours.height) == (ref.name, *IMAGE_SIZES[dataset])
        for field in ('K', 'R', 't', 'dist'):
            np.testing.assert_array_equal(getattr(ours, field), getattr(ref, field))
    with pytest.raises(ValueError, match=r"calibration: '\{data_root\}/data/.*' needs a data root"):
        load_rig_file(CONFIG / f'{dataset}.yaml')


def test_a_data_root_is_looked_for_only_when_the_rig_file_names_it(tmp_path, shelf):
    """load_rig_file's data_root may be a function finding it (the nodes' default, which fails on a
    host without the shared data): a rig file with its own cameras never calls it."""
    calls = []

    def missing() -> Path:
        calls.append('missing')
        raise FileNotFoundError('mvpose data root not found')

    explicit = _write(tmp_path, {'cameras': [_quaternion_entry(cam) for cam in shelf]})
    assert load_rig_file(explicit, data_root=missing).names == [f'cam{c}' for c in range(5)] and not calls
    with pytest.raises(FileNotFoundError, match='data root not found'):
        load_rig_file(CONFIG / 'shelf.yaml', data_root=missing)
    assert calls == ['missing']
    found = load_rig_file(CONFIG / 'shelf.yaml', data_root=lambda: data_root())
    assert [cam.name for cam in found.calibrated_cameras()] == [cam.name for cam in shelf]


def test_calibration_json_with_explicit_size(tmp_path, shelf):
    rig = load_rig_file(SHELF_JSON, 1032, 776)
    assert rig.names == ['cam0', 'cam1', 'cam2', 'cam3', 'cam4']
    assert [c.name for c in rig.calibrated_cameras()] == ['0', '1', '2', '3', '4']
    with pytest.raises(ValueError, match='image size unknown'):
        load_rig_file(SHELF_JSON)
    # a calibration path relative to the rig file, size from the caller, default topics
    rig = load_rig_file(_write(tmp_path, {'calibration': str(SHELF_JSON)}), 1032, 776)
    assert rig.cameras[3].image == 'cam3/image_raw' and rig.cameras[3].camera.width == 1032


def _explicit(tmp_path, shelf, change) -> Path:
    entries = [_quaternion_entry(cam) for cam in shelf[:2]]
    doc = {'world_frame': 'world', 'cameras': entries}
    change(doc, entries[1])
    return _write(tmp_path, doc)


@pytest.mark.parametrize('change, problem', [
    (lambda d, e: e.pop('position'), "camera 'cam1': missing position"),
    (lambda d, e: e.pop('orientation'), "camera 'cam1': missing orientation"),
    (lambda d, e: e.pop('name'), 'camera 1: missing name'),
    (lambda d, e: e.update(position=[1.0, 'a', 2.0]), "camera 'cam1': position: 'a' is not a number"),
    (lambda d, e: e.update(position=[1.0, 2.0]), "camera 'cam1': position: expected 3 numbers, got 2"),
    (lambda d, e: e.update(position=[1.0, True, 2.0]), "camera 'cam1': position: True is not a number"),
    (lambda d, e: e.update(orientation=[0, 0, 0, 0.5]),
     "camera 'cam1': orientation: not a rotation (quaternion x y z w of norm 0.5"),
    (lambda d, e: e.update(orientation=[0, 0, 0, float('nan')]), "camera 'cam1': orientation: not finite"),
    (lambda d, e: e.update(distortion_model='kannala_brandt'),
     "camera 'cam1': distortion_model: 'kannala_brandt' is not supported (supported: plumb_bob (k1 k2 p1 p2 k3), "
     "rational_polynomial"),
    (lambda d, e: e.update(distortion_model=['plumb_bob']),
     "camera 'cam1': distortion_model: expected a non-empty string, got ['plumb_bob']"),
    (lambda d, e: e.update(D=[0.0] * 8), "camera 'cam1': D: plumb_bob has at most 5 coefficients"),
    (lambda d, e: e.update(rectified='yes'), "camera 'cam1': rectified: expected true or false, got 'yes'"),
    (lambda d, e: e.update(rectified=True), "camera 'cam1': rectified: only for intrinsics from CameraInfo"),
    (lambda d, e: e.update(distortion_model='equidistant', D=[0.0] * 5),
     "camera 'cam1': D: equidistant has at most 4 coefficients (k1 k2 k3 k4), got 5"),
    (lambda d, e: e.pop('K'), "camera 'cam1': missing K (intrinsics are all of width, height, K"),
    (lambda d, e: e.update(K=[0, 1, 2, 3]), "camera 'cam1': K: focal lengths fx, fy must be > 0"),
    (lambda d, e: e.update(width=10.5), "camera 'cam1': width: expected a whole number of pixels >= 1"),
    (lambda d, e: e.update(name='cam0'), "camera 'cam0': name: duplicate camera name"),
    (lambda d, e: e.update(image=d['cameras'][0]['image']),
     "camera 'cam1': image: '/rig/cam0/image_raw/compressed' is also the image topic of camera 'cam0'"),
    (lambda d, e: [c.pop(k) for c in d['cameras'] for k in ('width', 'height', 'K', 'distortion_model', 'D')]
     and e.update(camera_info=d['cameras'][0]['camera_info']),
     "camera 'cam1': camera_info: '/rig/cam0/camera_info' is also the camera_info topic of camera 'cam0', and "
     "intrinsics come from it"),
    (lambda d, e: e.update(name='1st'), "camera '1st': name: '1st' is not a valid name"),
    (lambda d, e: e.update(orientaton=[0, 0, 0, 1]), "camera 'cam1': unknown field 'orientaton'"),
    (lambda d, e: e.update(image=''), "camera 'cam1': image: expected a non-empty string"),
    (lambda d, e: d.update(up=[0, 0, 0]), 'up: must be a non-zero vector'),
    (lambda d, e: d.update(world_frame=3), 'world_frame: expected a non-empty string, got 3'),
    (lambda d, e: d.update(cameras=[]), 'cameras: expected a non-empty list'),
    (lambda d, e: d.pop('cameras'), 'missing cameras (or calibration)'),
    (lambda d, e: d.update(calibration='nowhere.json', width=10, height=10), 'calibration: calibration not found'),
    (lambda d, e: d.update(calibration=str(SHELF_JSON), width=1032), 'missing height (image size in pixels'),
    (lambda d, e: d.update(calibration=str(SHELF_JSON), width=1032, height=776),
     'cameras: expected a list of 5 entries (one per calibration camera)'),
])
def test_errors_are_one_line_naming_file_camera_and_field(tmp_path, shelf, change, problem):
    path = _explicit(tmp_path, shelf, change)
    with pytest.raises(ValueError) as err:
        load_rig_file(path)
    message = str(err.value)
    assert message.startswith(f'{path}: ') and problem in message and '\n' not in message, message


def test_cameras_with_their_intrinsics_in_the_rig_file_may_share_a_camera_info_topic(tmp_path, shelf):
    """Nothing reads it then."""
    path = _explicit(tmp_path, shelf, lambda d, e: e.update(camera_info=d['cameras'][0]['camera_info']))
    assert [c.camera_info for c in load_rig_file(path).cameras] == ['/rig/cam0/camera_info'] * 2


def test_calibration_errors_name_the_rig_file_and_the_calibration(tmp_path):
    broken = tmp_path / 'calibration_x.json'
    broken.write_text('{"0": {"R": [1, 2')
    path = _write(tmp_path, {'calibration': broken.name, 'width': 10, 'height': 10})
    with pytest.raises(ValueError) as err:
        load_rig_file(path)
    assert str(err.value).startswith(f'{path}: calibration: {broken}: not valid JSON') and '\n' not in str(err.value)


@pytest.mark.parametrize('text, problem', [
    ('cameras: [', 'not valid YAML'),
    ('- 1\n- 2\n', 'expected a mapping with cameras, got list'),
])
def test_not_a_rig_file(tmp_path, text, problem):
    path = _write(tmp_path, text)
    with pytest.raises(ValueError) as err:
        load_rig_file(path)
    assert str(err.value).startswith(f'{path}: {problem}') and '\n' not in str(err.value)


def test_rig_camera_is_frozen(shelf):
    rc = RigCamera('a', 'a/image_raw', 'a/camera_info', 'a', shelf[0].R, shelf[0].t)
    with pytest.raises(AttributeError):
        rc.name = 'b'
