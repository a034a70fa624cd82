"""rosbag2 bags: write/read round trip, the Shelf and Campus recipes against the real data,
damaged bags, the foreign-rig bags (shelf_rig, shelf_rig_raw) and the `mvpose-make-bag` command."""
from __future__ import annotations

import json
import random
import shutil
import sys
from pathlib import Path

import cv2
import numpy as np
import pytest
import scipy.io
from rclpy.serialization import deserialize_message
from sensor_msgs.msg import CameraInfo, Image, PointCloud2
from std_msgs.msg import Header

from msg_adapters.camera_info_msg import check_info
from msg_adapters.image_msg import msg_to_image
from msg_adapters.openpose_msg import msg_to_openpose
from msg_adapters.skeleton_msg import msg_to_skeletons
from mvpose_ros.bags import recipes
from mvpose_ros.bags.io import bag_size, bag_summary, has_header, read_bag, typestore, write_bag
from mvpose_ros.bags.recipes import campus_image, campus_recipe, shelf_recipe
from mvpose_ros.cli.make_bag import main as make_bag
from mvpose_ros.core.datasets.shelf_campus import (CAMPUS_TEST_FRAMES, SHELF_TEST_FRAMES, calibration_file,
                                                   dataset_cameras, dataset_dir, shelf_cameras)
from mvpose_ros.core.detection.openpose import read_body25

S = 1_000_000_000
FRAME_NS = 40_000_000
SHELF = dataset_dir('shelf')
TYPES = {'/cam0/camera_info': CameraInfo, '/cam0/openpose': PointCloud2, '/cam1/image_raw': Image}


def _sample_items(n_frames: int = 20):
    """Messages of three topics over n_frames, written in shuffled order."""
    rng = random.Random(3)
    items = []
    for f in range(n_frames):
        header = Header(frame_id='cam0')
        header.stamp.sec, header.stamp.nanosec = divmod(f * FRAME_NS, S)
        items.append(('/cam0/camera_info', CameraInfo(header=header, width=f + 1, d=[0.1 * f] * 5), f * FRAME_NS))
        cloud = PointCloud2(header=header, width=f, data=rng.randbytes(16 * f))
        items.append(('/cam0/openpose', cloud, f * FRAME_NS))
        if f % 5 == 0:
            items.append(('/cam1/image_raw', Image(header=header, height=2, width=3, encoding='bgr8', step=9,
                                                   data=rng.randbytes(18)), f * FRAME_NS))
    shuffled = items[:]
    rng.shuffle(shuffled)
    return items, shuffled


@pytest.mark.parametrize('storage', ['mcap', 'sqlite3'])
def test_write_read_round_trip(tmp_path, storage):
    items, shuffled = _sample_items()
    path = tmp_path / 'bag'
    write_bag(path, shuffled, storage=storage, custom_data={'k': 'v'})
    suffix = 'mcap' if storage == 'mcap' else 'db3'
    assert sorted(p.name for p in path.iterdir()) == [f'bag.{suffix}', 'metadata.yaml']
    assert not list(tmp_path.glob('.*partial*'))

    read = list(read_bag(path))
    assert [stamp for _, _, stamp, _ in read] == sorted(stamp for _, _, stamp in items)
    expected = {(topic, stamp): msg for topic, msg, stamp in items}
    assert len(read) == len(expected)
    for topic, msgtype, stamp, cdr in read:
        assert msgtype == f'sensor_msgs/msg/{TYPES[topic].__name__}'
        assert deserialize_message(cdr, TYPES[topic]) == expected[topic, stamp]

    only = list(read_bag(path, ['/cam1/image_raw']))
    assert [(t, s) for t, _, s, _ in only] == [('/cam1/image_raw', f * FRAME_NS) for f in range(0, 20, 5)]

    summary = bag_summary(path)
    assert summary.topics == {'/cam0/camera_info': ('sensor_msgs/msg/CameraInfo', 20),
                              '/cam0/openpose': ('sensor_msgs/msg/PointCloud2', 20),
                              '/cam1/image_raw': ('sensor_msgs/msg/Image', 4)}
    assert (summary.message_count, summary.first_ns, summary.last_ns) == (44, 0, 19 * FRAME_NS)
    assert summary.custom_data == {'k': 'v'}


def test_writer_refuses_bad_input(tmp_path):
    items, _ = _sample_items(2)
    write_bag(tmp_path / 'bag', items)
    with pytest.raises(FileExistsError):
        write_bag(tmp_path / 'bag', items)
    with pytest.raises(ValueError, match='storage'):
        write_bag(tmp_path / 'other', items, storage='rosbag1')
    mixed = [('/x', CameraInfo(), 0), ('/x', PointCloud2(), 1)]
    with pytest.raises(ValueError, match='/x'):
        write_bag(tmp_path / 'mixed', mixed)
    # a failed write leaves nothing behind
    assert sorted(p.name for p in tmp_path.iterdir()) == ['bag']
    with pytest.raises(ValueError, match='no topic /nope'):
        list(read_bag(tmp_path / 'bag', ['/nope']))


def test_types_carry_the_definitions_ros2_bag_needs():
    """The hash stored per topic is the one the installed message packages declare, so real
    `ros2 bag play` matches the types; Header-first types are the ones whose stamp is rewritten."""
    for msgtype in ('sensor_msgs/msg/PointCloud2', 'sensor_msgs/msg/CameraInfo', 'sensor_msgs/msg/Image'):
        package, _, name = msgtype.split('/')
        description = Path(sys.prefix) / 'share' / package / 'msg' / f'{name}.json'
        hashes = {h['type_name']: h['hash_string'] for h in json.loads(description.read_text())['type_hashes']}
        assert typestore().hash_rihs01(msgtype) == hashes[msgtype]
        assert typestore().generate_msgdef(msgtype, ros_version=2)[0].startswith('std_msgs/Header header')
        assert has_header(msgtype)
    assert not has_header('rosgraph_msgs/msg/Clock')
    assert not has_header('visualization_msgs/msg/MarkerArray')


@pytest.fixture(scope='module')
def shelf_bag(tmp_path_factory):
    path = tmp_path_factory.mktemp('shelf') / 'shelf'
    write_bag(path, shelf_recipe(SHELF).items())
    return path


@pytest.fixture(scope='module')
def shelf_messages(shelf_bag):
    by_topic = {}
    for topic, msgtype, stamp, cdr in read_bag(shelf_bag):
        by_topic.setdefault(topic, []).append((msgtype, stamp, cdr))
    return by_topic


def test_shelf_bag_has_every_test_frame_of_every_camera(shelf_bag, shelf_messages):
    stamps = [f * FRAME_NS for f in SHELF_TEST_FRAMES]
    assert stamps[0] == 12 * S and len(stamps) == 301
    summary = bag_summary(shelf_bag)
    assert (summary.first_ns, summary.last_ns) == (12 * S, 24 * S)
    for c in range(5):
        for kind in ('openpose', 'camera_info'):
            assert [s for _, s, _ in shelf_messages[f'/cam{c}/{kind}']] == stamps
        assert [s for _, s, _ in shelf_messages[f'/cam{c}/image_raw']] == [572 * FRAME_NS]
    assert len(shelf_messages) == 15


def test_shelf_openpose_messages_are_the_real_detections(shelf_messages):
    rig = shelf_cameras()
    for c, cam in enumerate(rig):
        frames = read_body25(SHELF / 'openpose_body25' / f'{c}.txt', cam.width, cam.height)
        messages = shelf_messages[f'/cam{c}/openpose']
        assert len(messages) == len(frames) == 301
        for (msgtype, stamp, cdr), expected, f in zip(messages, frames, SHELF_TEST_FRAMES):
            assert msgtype == 'sensor_msgs/msg/PointCloud2'
            msg = deserialize_message(cdr, PointCloud2)
            assert msg.header.frame_id == f'cam{c}'
            assert msg.header.stamp.sec * S + msg.header.stamp.nanosec == stamp == f * FRAME_NS
            got = msg_to_openpose(msg)
            # encoding A stores float32: the decoded frame is read_body25's, rounded to float32
            assert len(got.candidates) == 25 and len(got.pafs) == 26
            for g, e in zip(got.candidates + got.pafs, expected.candidates + expected.pafs):
                assert g.shape == e.shape
                assert np.array_equal(np.asarray(g, np.float32), e.astype(np.float32))


def test_shelf_camera_info_and_images(shelf_messages):
    rig = shelf_cameras()
    for c, cam in enumerate(rig):
        for _, stamp, cdr in shelf_messages[f'/cam{c}/camera_info'][::50]:
            info = deserialize_message(cdr, CameraInfo)
            check_info(info, cam, tol_px=1e-9)
            assert np.array_equal(np.reshape(info.k, (3, 3)), cam.K) and np.array_equal(info.d, cam.dist)
            assert (info.width, info.height, info.header.frame_id) == (1032, 776, f'cam{c}')
        [(_, stamp, cdr)] = shelf_messages[f'/cam{c}/image_raw']
        image = deserialize_message(cdr, Image)
        assert (image.encoding, image.header.frame_id) == ('bgr8', f'cam{c}')
        expected = cv2.imread(str(SHELF / 'frames' / f'cam{c}_000572.png'))
        assert np.array_equal(msg_to_image(image), expected)


def test_shelf_images_recipe_is_frame_572_only(tmp_path):
    path = tmp_path / 'shelf_images'
    write_bag(path, shelf_recipe(SHELF, images_only=True).items())
    summary = bag_summary(path)
    assert summary.topics == {**{f'/cam{c}/camera_info': ('sensor_msgs/msg/CameraInfo', 1) for c in range(5)},
                              **{f'/cam{c}/image_raw': ('sensor_msgs/msg/Image', 1) for c in range(5)}}
    assert summary.first_ns == summary.last_ns == 572 * FRAME_NS


# Campus: (frame, cameras with an image) and the actors annotated in that frame.
CAMPUS_IMAGES = {350: (0, 1, 2), 351: (0, 1, 2), 470: (0, 2), 700: (1,)}
CAMPUS_ACTORS = {350: (0,), 351: (0, 2), 470: (), 700: (1,)}


def _cell_column(n_frames: int, empty) -> np.ndarray:
    column = np.empty((n_frames, 1), dtype=object)
    for f in range(n_frames):
        column[f, 0] = empty()
    return column


@pytest.fixture(scope='module')
def campus_dir(tmp_path_factory):
    """A CampusSeq1-layout folder: Camera{c}/ PNGs, actorsGT.mat (MATLAB cells), calibration."""
    root = tmp_path_factory.mktemp('CampusSeq1')
    rng = np.random.default_rng(0)
    for f, cams in CAMPUS_IMAGES.items():
        for c in cams:
            path = campus_image(root, c, f)
            path.parent.mkdir(exist_ok=True)
            cv2.imwrite(str(path), rng.integers(0, 256, (288, 360, 3), dtype=np.uint8))
    (root / 'Camera0' / 'campus4-c0-00100.png').write_bytes(b'')  # not a test frame: ignored
    n_frames, n_actors = 760, 3
    actor3d, actor2d = np.empty((1, n_actors), dtype=object), np.empty((1, n_actors), dtype=object)
    for a in range(n_actors):
        actor3d[0, a] = _cell_column(n_frames, lambda: np.zeros((1, 0)))

        def no_views():
            views = np.empty((1, 3), dtype=object)
            for c in range(3):
                views[0, c] = np.zeros((1, 0))
            return views
        actor2d[0, a] = _cell_column(n_frames, no_views)
    poses = {}
    for f, actors in CAMPUS_ACTORS.items():
        for a in actors:
            poses[f, a] = rng.uniform(-2, 2, (14, 3))
            actor3d[0, a][f, 0] = poses[f, a]
    scipy.io.savemat(root / 'actorsGT.mat', {'actor3D': actor3d, 'actor2D': actor2d})
    calibration = calibration_file('campus')
    shutil.copy(calibration, root / 'calibration_campus.json')
    return root, poses


def test_campus_recipe_gives_images_camera_info_and_ground_truth(campus_dir, tmp_path):
    root, poses = campus_dir
    path = tmp_path / 'campus'
    write_bag(path, campus_recipe(root).items())
    summary = bag_summary(path)
    frames = sorted(CAMPUS_IMAGES)
    assert all(f in CAMPUS_TEST_FRAMES for f in frames)
    assert summary.topics == {
        **{f'/cam{c}/camera_info': ('sensor_msgs/msg/CameraInfo', 4) for c in range(3)},
        **{f'/cam{c}/image_raw': ('sensor_msgs/msg/Image', sum(c in cams for cams in CAMPUS_IMAGES.values()))
           for c in range(3)},
        '/ground_truth/skeletons': ('sensor_msgs/msg/PointCloud2', 4)}
    rig = dataset_cameras('campus', calibration=root / 'calibration_campus.json')
    gt = [(stamp, deserialize_message(cdr, PointCloud2))
          for _, _, stamp, cdr in read_bag(path, ['/ground_truth/skeletons'])]
    assert [stamp for stamp, _ in gt] == [f * FRAME_NS for f in frames]
    for (_, msg), f in zip(gt, frames):
        ids, joints, confidence = msg_to_skeletons(msg)
        assert (confidence == 1).all()  # the truth
        assert msg.header.frame_id == 'world'
        assert ids.tolist() == list(CAMPUS_ACTORS[f])
        for a, pose in zip(ids, joints):
            np.testing.assert_array_equal(pose, poses[f, a].astype(np.float32))
    for topic, _, stamp, cdr in read_bag(path, [f'/cam{c}/image_raw' for c in range(3)]):
        c, f = int(topic[4]), stamp // FRAME_NS
        image = msg_to_image(deserialize_message(cdr, Image))
        assert np.array_equal(image, cv2.imread(str(campus_image(root, c, f))))
    for topic, _, _, cdr in read_bag(path, ['/cam2/camera_info']):
        check_info(deserialize_message(cdr, CameraInfo), rig[2], tol_px=1e-9)


def test_campus_recipe_errors(campus_dir, tmp_path):
    with pytest.raises(FileNotFoundError, match='not found'):
        campus_recipe(tmp_path / 'nowhere')
    (tmp_path / 'empty').mkdir()
    with pytest.raises(FileNotFoundError, match='actorsGT.mat'):
        campus_recipe(tmp_path / 'empty')
    root, _ = campus_dir
    bad = tmp_path / 'bad'
    shutil.copytree(root, bad)
    cv2.imwrite(str(campus_image(bad, 1, 700)), np.zeros((100, 100, 3), np.uint8))
    with pytest.raises(ValueError, match='image size: the png header declares 100x100'):
        write_bag(tmp_path / 'bag', campus_recipe(bad).items())
    assert not (tmp_path / 'bag').exists()


def _damage(bag: Path, tmp_path: Path, how) -> Path:
    copy = tmp_path / f'damaged_{how.__name__}'
    shutil.copytree(bag, copy)
    [data_file] = copy.glob('*.mcap')
    data_file.write_bytes(how(data_file.read_bytes()))
    return copy


def truncated(data: bytes) -> bytes:
    return data[:len(data) // 2]


def garbage(data: bytes) -> bytes:
    return b'not a bag at all ' * 100


def scrambled_chunk(data: bytes) -> bytes:
    # inside the compressed OpenPose chunks before frame 572's images (a stored, incompressible
    # block could be damaged silently: rosbags writes no chunk CRC)
    out = bytearray(data)
    start = len(out) // 20
    out[start:start + 4096] = bytes(b ^ 0x5A for b in out[start:start + 4096])
    return bytes(out)


def test_bag_size_is_the_bytes_of_its_files(shelf_bag, tmp_path):
    files = [f for f in shelf_bag.iterdir() if f.is_file()]
    assert bag_size(shelf_bag) == sum(f.stat().st_size for f in files) > 0
    assert {f.suffix for f in files} >= {'.yaml', '.mcap'}
    with pytest.raises(FileNotFoundError, match='bag not found'):
        bag_size(tmp_path / 'missing')


@pytest.mark.parametrize('how', [truncated, garbage, scrambled_chunk])
def test_damaged_bags_are_clear_one_line_errors(shelf_bag, tmp_path, how):
    damaged = _damage(shelf_bag, tmp_path, how)
    with pytest.raises(ValueError) as err:
        bag_summary(damaged)
        list(read_bag(damaged))
    assert str(damaged) in str(err.value) and '\n' not in str(err.value)


def test_missing_and_incomplete_bags(tmp_path):
    with pytest.raises(FileNotFoundError, match='bag not found'):
        bag_summary(tmp_path / 'nope')
    with pytest.raises(FileNotFoundError, match='bag not found'):
        list(read_bag(tmp_path / 'nope'))
    (tmp_path / 'half').mkdir()
    with pytest.raises(ValueError, match='no metadata.yaml'):
        bag_summary(tmp_path / 'half')


def test_make_bag_exit_codes(tmp_path, capsys, campus_dir, monkeypatch):
    out = tmp_path / 'images'
    assert make_bag(['shelf_images', '--output', str(out)]) == 0
    assert '10 messages on 10 topics' in capsys.readouterr().out
    made = (out / 'images.mcap').stat().st_mtime_ns
    assert make_bag(['shelf_images', '--output', str(out)]) == 0
    assert 'already made' in capsys.readouterr().out
    assert (out / 'images.mcap').stat().st_mtime_ns == made

    # another recipe's bag, or an out-of-date one, needs --force
    assert make_bag(['shelf', '--output', str(out)]) == 2
    assert "holds recipe 'shelf_images'" in capsys.readouterr().err
    monkeypatch.setattr(recipes, 'RECIPE_VERSION', recipes.RECIPE_VERSION + 1)
    assert make_bag(['shelf_images', '--output', str(out)]) == 2
    err = capsys.readouterr().err
    assert 'out of date' in err and '--force' in err and len(err.strip().splitlines()) == 1
    assert make_bag(['shelf_images', '--output', str(out), '--force']) == 0
    assert 'made in' in capsys.readouterr().out
    assert make_bag(['shelf_images', '--output', str(out)]) == 0

    # a damaged bag is not "made"
    [data_file] = out.glob('*.mcap')
    data_file.write_bytes(data_file.read_bytes()[:1000])
    assert make_bag(['shelf_images', '--output', str(out)]) == 2
    assert 'not a complete bag' in capsys.readouterr().err

    # --force deletes bag folders only
    other = tmp_path / 'notes'
    other.mkdir()
    (other / 'thesis.tex').write_text('precious')
    assert make_bag(['shelf_images', '--output', str(other), '--force']) == 2
    assert 'non-bag files' in capsys.readouterr().err and (other / 'thesis.tex').exists()

    assert make_bag(['campus', '--output', str(tmp_path / 'c')]) == 2
    assert '--campus-dir' in capsys.readouterr().err
    assert make_bag(['campus', '--campus-dir', str(campus_dir[0]), '--output', str(tmp_path / 'c')]) == 0
    assert '7 topics' in capsys.readouterr().out
    assert make_bag(['shelf', '--data-root', str(tmp_path / 'nowhere'), '--output', str(tmp_path / 's')]) == 2
    err = capsys.readouterr().err
    assert 'nowhere' in err and 'Traceback' not in err
    assert not (tmp_path / 's').exists()


def test_shelf_rig_bag_is_a_foreign_driver_recording_with_its_rig_file(tmp_path, capsys):
    """mvpose-make-bag shelf_rig: driver topics and frame ids, CompressedImage (jpeg) + CameraInfo
    per capture, images upscaled x1.5 with K to match, stamps within +-9 ms of the 25 Hz grid, a
    late camera and a camera dropping 3 frames, MCAP read back; its rig.yaml has the Shelf
    extrinsics and no intrinsics, which CameraInfo completes into the scaled Shelf cameras."""
    from msg_adapters.camera_info_msg import info_to_intrinsics
    from msg_adapters.image_msg import compressed_to_image
    from mvpose_ros.bags.recipes import ForeignRig, RIG_FILE
    from mvpose_ros.core.geometry.rig import load_rig_file
    from sensor_msgs.msg import CompressedImage
    out = tmp_path / 'shelf_rig'
    assert make_bag(['shelf_rig', '--output', str(out)]) == 0
    assert 'rig.yaml' in capsys.readouterr().out
    assert [f.suffix for f in out.glob('*.mcap')] == ['.mcap']
    summary = bag_summary(out)
    names = ForeignRig.NAMES
    expected_counts = {'back': 37, 'door': 37}
    assert summary.topics == {
        **{f'/rig/{n}/camera_info': ('sensor_msgs/msg/CameraInfo', expected_counts.get(n, 40)) for n in names},
        **{f'/rig/{n}/image_raw/compressed': ('sensor_msgs/msg/CompressedImage', expected_counts.get(n, 40))
           for n in names}}
    shelf = shelf_cameras()
    per_camera: dict[str, list[int]] = {n: [] for n in names}
    decoded = set()
    for topic, msgtype, log_ns, cdr in read_bag(out):
        name = topic.split('/')[2]
        msg = deserialize_message(cdr, CompressedImage if msgtype.endswith('CompressedImage') else CameraInfo)
        stamp = msg.header.stamp.sec * S + msg.header.stamp.nanosec
        assert msg.header.frame_id == f'{name}_optical_frame' and log_ns == stamp
        c = names.index(name)
        if isinstance(msg, CameraInfo):
            per_camera[name].append(stamp)
            K, D, width, height, model = info_to_intrinsics(msg)
            assert model == 'plumb_bob'
            assert (width, height) == (1548, 1164)
            assert np.allclose(K[:2, :2], 1.5 * shelf[c].K[:2, :2])
            assert np.allclose(K[:2, 2], 1.5 * (shelf[c].K[:2, 2] + 0.5) - 0.5)
        elif name not in decoded:
            decoded.add(name)
            assert 'jpeg' in msg.format
            assert compressed_to_image(msg).shape == (1164, 1548, 3)
    start = ForeignRig.START_NS
    for name, stamps in per_camera.items():
        sets = [round((s - start) / FRAME_NS) for s in stamps]
        offsets = np.array([s - start - k * FRAME_NS for s, k in zip(stamps, sets)])
        assert np.abs(offsets).max() <= 9_000_000, name
        missing = sorted(set(range(40)) - set(sets))
        assert missing == {'back': [0, 1, 2], 'door': [11, 22, 33]}.get(name, []), name
    assert len({tuple(np.array(v[3:30]) - np.array(per_camera['left'][3:30])) for v in per_camera.values()}) == 5

    rig = load_rig_file(out / RIG_FILE)
    assert rig.names == list(names) and not rig.calibrated
    assert [c.image for c in rig.cameras] == [f'/rig/{n}/image_raw/compressed' for n in names]
    point = np.array([0.3, -0.2, 1.1])
    for c, rig_camera in enumerate(rig.cameras):
        first = next(read_bag(out, [f'/rig/{names[c]}/camera_info']))
        info = deserialize_message(first[3], CameraInfo)
        camera = rig_camera.with_info(*info_to_intrinsics(info))
        assert np.allclose(camera.project(point[None]), 1.5 * (shelf[c].project(point[None]) + 0.5) - 0.5, atol=1e-4)


def test_shelf_rig_raw_recipe_gives_rgb8_images_on_the_raw_topics():
    from mvpose_ros.bags.recipes import shelf_rig_recipe
    recipe = shelf_rig_recipe(SHELF, compressed=False)
    assert recipe.name == 'shelf_rig_raw'
    items = recipe.items()
    (t1, _, s1), (t2, image, s2) = next(items), next(items)
    assert t1.endswith('/camera_info') and t2 == t1.replace('camera_info', 'image_raw') and s1 == s2
    assert isinstance(image, Image) and image.encoding == 'rgb8' and (image.width, image.height) == (1548, 1164)
    assert msg_to_image(image).shape == (1164, 1548, 3)
    assert '/image_raw/compressed' not in recipe.rig_text() and "image: /rig/left/image_raw\n" in recipe.rig_text()


def _rot90_pixels(uv: np.ndarray, turns: int, width: int, height: int) -> np.ndarray:
    """Where pixels (N, 2) of a width x height image land in np.rot90(image, turns)."""
    for _ in range(turns % 4):
        uv = np.stack([uv[:, 1], width - 1 - uv[:, 0]], -1)
        width, height = height, width
    return uv


@pytest.mark.parametrize('turns', [1, 2, 3, 4])
def test_a_turned_camera_sees_the_turned_image(turns):
    """recipes.turned_camera: the camera turned on its mount projects every point where np.rot90
    moves the camera's pixel, with skew and tangential distortion too, its size swapped by odd turns."""
    from mvpose_ros.bags.recipes import turned_camera
    from mvpose_ros.core.geometry.camera import Camera
    cam = shelf_cameras()[1]
    K = cam.K.copy()
    K[0, 1] = 2.5
    cam = Camera('odd', K, cam.R, cam.t, [-0.2, 0.05, 0.004, -0.003, 0.01], cam.width, cam.height)
    turned = turned_camera(cam, turns)
    assert (turned.width, turned.height) == ((cam.height, cam.width) if turns % 2 else (cam.width, cam.height))
    X = np.random.default_rng(3).uniform([-2.0, -2.0, 0.0], [2.0, 2.0, 2.0], (300, 3))
    uv = cam.project(X)
    seen = np.isfinite(uv).all(axis=1)
    np.testing.assert_allclose(turned.project(X)[seen], _rot90_pixels(uv[seen], turns, cam.width, cam.height),
                               atol=1e-6)
    np.testing.assert_allclose(turned.centre, cam.centre, atol=1e-12)


def _first_messages(*recipes) -> dict[str, dict[str, object]]:
    """Per recipe name, the first message of each of its topics."""
    first = {}
    for recipe in recipes:
        items = {}
        for topic, msg, _ in recipe.items():
            items.setdefault(topic, msg)
        first[recipe.name] = items
    return first


def test_shelf_rig_turned_recipe_turns_images_cameras_and_rig_file_together(tmp_path):
    """shelf_rig_turned: each camera's image is np.rot90 of shelf_rig's by ForeignRig.TURNS, its
    CameraInfo and the rig file's orientation turned with it, so a world point lands where the
    turn moves shelf_rig's pixel; upright detection turns each camera back."""
    from msg_adapters.camera_info_msg import info_to_intrinsics
    from msg_adapters.image_msg import compressed_to_image
    from mvpose_ros.bags.recipes import ForeignRig, shelf_rig_recipe
    from mvpose_ros.core.detection.upright import upright_turns
    from mvpose_ros.core.geometry.rig import load_rig_file
    plain, turned = shelf_rig_recipe(SHELF), shelf_rig_recipe(SHELF, turned=True)
    assert turned.name == 'shelf_rig_turned' and turned.fingerprint() != plain.fingerprint()
    first = _first_messages(plain, turned)
    (tmp_path / 'turned.yaml').write_text(turned.rig_text())
    (tmp_path / 'plain.yaml').write_text(plain.rig_text())
    rig_file, plain_rig = load_rig_file(tmp_path / 'turned.yaml'), load_rig_file(tmp_path / 'plain.yaml')
    point = np.array([[0.3, -0.2, 1.1]])
    for name, k, rig_camera in zip(ForeignRig.NAMES, ForeignRig.TURNS, rig_file.cameras):
        image = compressed_to_image(first['shelf_rig_turned'][f'/rig/{name}/image_raw/compressed'])
        before = compressed_to_image(first['shelf_rig'][f'/rig/{name}/image_raw/compressed'])
        assert image.shape[:2] == np.rot90(before, k).shape[:2]
        assert np.abs(image.astype(int) - np.rot90(before, k).astype(int)).mean() < 2  # JPEG noise only
        info = first['shelf_rig_turned'][f'/rig/{name}/camera_info']
        camera = rig_camera.with_info(*info_to_intrinsics(info))
        upright = plain_rig.cameras[ForeignRig.NAMES.index(name)]
        unturned = upright.with_info(*info_to_intrinsics(first['shelf_rig'][f'/rig/{name}/camera_info']))
        np.testing.assert_allclose(camera.project(point), _rot90_pixels(unturned.project(point), k, unturned.width,
                                                                        unturned.height), atol=1e-4)
        assert upright_turns(rig_camera.R, rig_file.up) == (4 - k) % 4


def _seen_points(camera) -> np.ndarray:
    """(4, 3) world points 3 m out on the rays of four pixels towards the corners of the camera's
    image, where lenses move points most."""
    pixels = np.array([[0.15, 0.2], [0.85, 0.8], [0.2, 0.75], [0.8, 0.25]]) * [camera.width, camera.height]
    origins, dirs = camera.rays(pixels)
    return origins + 3.0 * dirs


@pytest.mark.slow
def test_through_lens_puts_a_point_where_the_lens_projects_it(shelf_rig):
    """A dot drawn where a pinhole camera sees a point lands where each of ForeignRig.LENSES,
    at the same pose, projects it."""
    from mvpose_ros.bags.recipes import ForeignRig, lensed_camera, through_lens
    cam = shelf_rig[2]
    for model, dist, focal in ForeignRig.LENSES:
        lensed = lensed_camera(cam, model, dist, focal)
        assert lensed.distortion_model == model and lensed.has_distortion
        for point in _seen_points(cam):
            u, v = np.round(cam.project(point)).astype(int)
            dot = np.zeros((cam.height, cam.width), np.float32)
            dot[v - 3:v + 4, u - 3:u + 4] = 1.0
            seen = through_lens(dot, cam, lensed)
            centre = np.argwhere(seen > 0.5).mean(axis=0)[::-1]  # (u, v)
            assert np.abs(centre - lensed.project(point)).max() < 1.0, (model, point)


@pytest.mark.slow
def test_shelf_rig_lenses_recipe_gives_each_camera_its_lens(tmp_path):
    """shelf_rig_lenses: each CameraInfo carries its camera's lens of ForeignRig.LENSES, the rig
    file is shelf_rig's extrinsics, and a world point's pixel in the lensed image shows what its
    pixel in shelf_rig's image shows."""
    from msg_adapters.camera_info_msg import info_to_intrinsics
    from msg_adapters.image_msg import compressed_to_image
    from mvpose_ros.bags.recipes import ForeignRig, shelf_rig_recipe
    from mvpose_ros.core.geometry.rig import load_rig_file
    plain, lensed = shelf_rig_recipe(SHELF), shelf_rig_recipe(SHELF, lenses=True)
    assert lensed.name == 'shelf_rig_lenses' and lensed.fingerprint() != plain.fingerprint()
    first = _first_messages(plain, lensed)
    (tmp_path / 'rig.yaml').write_text(lensed.rig_text())
    rig = load_rig_file(tmp_path / 'rig.yaml')
    for name, (model, dist, _), rig_camera in zip(ForeignRig.NAMES, ForeignRig.LENSES, rig.cameras):
        info = first['shelf_rig_lenses'][f'/rig/{name}/camera_info']
        assert info.distortion_model == model and list(info.d) == list(dist)
        camera = rig_camera.with_info(*info_to_intrinsics(info))
        pinhole = rig_camera.with_info(*info_to_intrinsics(first['shelf_rig'][f'/rig/{name}/camera_info']))
        image = compressed_to_image(first['shelf_rig_lenses'][f'/rig/{name}/image_raw/compressed']).astype(int)
        before = compressed_to_image(first['shelf_rig'][f'/rig/{name}/image_raw/compressed']).astype(int)
        X = _seen_points(pinhole)
        for (u, v), (u0, v0) in zip(np.round(camera.project(X)).astype(int), np.round(pinhole.project(X)).astype(int)):
            # a 5 x 5 patch's mean colour: the remap's interpolation and JPEG noise only (at most 4.3
            # here, where the patch at the pinhole pixel (u0, v0) of the lensed image is up to 166 off)
            assert np.abs(image[v - 2:v + 3, u - 2:u + 3].mean(axis=(0, 1))
                          - before[v0 - 2:v0 + 3, u0 - 2:u0 + 3].mean(axis=(0, 1))).max() < 8, name


@pytest.mark.slow
def test_shelf_bag_with_a_bumped_or_an_unplugged_camera():
    """--rotate-camera: camera 2's candidates move (about fx tan 2 degrees) from frame 450 on, the
    others and earlier frames are the real ones; --unplug-camera: camera 3 sends nothing from then."""
    shelf = dataset_dir('shelf', None)
    first = 450 * 40_000_000

    def openpose(fault):
        out = {}
        for topic, msg, stamp in shelf_recipe(shelf, fault=fault).items():
            if topic.endswith('/openpose'):
                out[topic, stamp] = np.concatenate([c[:, :2] for c in msg_to_openpose(msg).candidates if len(c)])
        return out

    real = openpose(None)
    turned = openpose(recipes.CameraFault(2, 450, 2.0))
    fx = shelf_cameras(None)[2].K[0, 0]
    for (topic, stamp), uv in real.items():
        shift = np.abs(turned[topic, stamp] - uv).max(axis=0)
        if topic == '/cam2/openpose' and stamp >= first:
            assert 0.8 * fx * np.tan(np.radians(2)) < shift[0] < 1.3 * fx * np.tan(np.radians(2))
        else:
            assert shift.max() == 0
    unplugged = openpose(recipes.CameraFault(3, 450))
    assert set(unplugged) == {k for k in real if not (k[0] == '/cam3/openpose' and k[1] >= first)}
    with pytest.raises(ValueError, match='camera 7'):
        shelf_recipe(shelf, fault=recipes.CameraFault(7, 450))


@pytest.mark.slow
def test_shelf_rig_hd_recipe_is_a_30_hz_1920_by_1080_rig_showing_the_same_scene(tmp_path):
    """shelf_rig_hd: 1920 x 1080 images at 30 Hz (60 sets, shelf_rig's offsets and gaps), each
    Shelf image scaled to the frame's height between black bars, its CameraInfo moved with it: a
    world point's patch in the HD image shows what its patch in shelf_rig's image shows."""
    from msg_adapters.camera_info_msg import info_to_intrinsics
    from msg_adapters.image_msg import compressed_to_image
    from mvpose_ros.bags.recipes import ForeignRig, HdRig, shelf_rig_recipe, shelf_rig_stamps
    from mvpose_ros.core.geometry.rig import load_rig_file
    plain, hd = shelf_rig_recipe(SHELF), shelf_rig_recipe(SHELF, hd=True)
    assert hd.name == 'shelf_rig_hd' and hd.fingerprint() != plain.fingerprint()
    stamps = shelf_rig_stamps(HdRig)
    left = [s for s in stamps['left'] if s is not None]
    assert len(left) == 60 and np.allclose(np.diff(left), 1e9 / 30, atol=2.5e6)
    assert sum(s is None for s in stamps[ForeignRig.DROP_CAMERA]) == len(ForeignRig.DROPPED_SETS)
    first = _first_messages(plain, hd)
    (tmp_path / 'rig.yaml').write_text(hd.rig_text())
    rig = load_rig_file(tmp_path / 'rig.yaml')
    for name, rig_camera in zip(ForeignRig.NAMES, rig.cameras):
        camera = rig_camera.with_info(*info_to_intrinsics(first['shelf_rig_hd'][f'/rig/{name}/camera_info']))
        before = rig_camera.with_info(*info_to_intrinsics(first['shelf_rig'][f'/rig/{name}/camera_info']))
        assert (camera.width, camera.height) == (1920, 1080)
        image = compressed_to_image(first['shelf_rig_hd'][f'/rig/{name}/image_raw/compressed']).astype(int)
        plain_image = compressed_to_image(first['shelf_rig'][f'/rig/{name}/image_raw/compressed']).astype(int)
        assert image.shape == (1080, 1920, 3) and image[:, :200].max() < 10  # a black bar on the left
        for (u, v), (u0, v0) in zip(np.round(camera.project(_seen_points(before))).astype(int),
                                    np.round(before.project(_seen_points(before))).astype(int)):
            assert np.abs(image[v - 2:v + 3, u - 2:u + 3].mean(axis=(0, 1))
                          - plain_image[v0 - 2:v0 + 3, u0 - 2:u0 + 3].mean(axis=(0, 1))).max() < 12, name
