"""Encodings B (2D people of one camera) and C (per-person view bundles): round trips with
heatmaps of different sizes, real detector output, and rejection of malformed messages."""
from __future__ import annotations

import numpy as np
import pytest
from rclpy.serialization import deserialize_message, serialize_message
from sensor_msgs.msg import PointCloud2
from std_msgs.msg import Header

from msg_adapters.people_msg import (BUNDLE_KEYS, bundles_to_msg, msg_to_bundles, msg_to_people,
                                     people_dtype, people_to_msg)
from msg_adapters.records import from_cloud, to_cloud
from mvpose_ros.core.evaluation.datasets import dataset_dir
from mvpose_ros.core.heatmap import PersonHeatmap
from mvpose_ros.core.detection.openpose import read_body25
from mvpose_ros.core.detection.openpose_detector import OpenPoseDetectorConfig, detect_people
from mvpose_ros.core.types import Person2D

TOL = 0.5 / 255 + 1e-7  # quantisation to 1/255 steps, plus float32 rounding


def _person(seed: int, h: int, w: int) -> Person2D:
    rng = np.random.default_rng(seed)
    kp = np.column_stack([rng.uniform(0, 1000, (16, 2)), rng.uniform(0.05, 1, 16)])
    kp[rng.random(16) < 0.3] = (np.nan, np.nan, 0.0)
    maps = rng.uniform(-0.2, 1.2, (16, h, w)).astype(np.float32)  # out of [0, 1]: clipped
    return Person2D(kp, PersonHeatmap(maps, rng.uniform(-50, 900, (16, 2)), float(rng.uniform(2, 8))))


def _assert_person(person: Person2D, back: Person2D, grid: tuple[int, int]):
    assert back.track_id == -1
    assert back.keypoints.shape == (16, 3)
    np.testing.assert_array_equal(back.keypoints, person.keypoints.astype(np.float32))
    np.testing.assert_array_equal(back.heatmap.origin, person.heatmap.origin.astype(np.float32))
    assert back.heatmap.stride == np.float32(person.heatmap.stride)
    maps = back.heatmap.maps
    assert maps.dtype == np.float32 and maps.shape == (16, *grid)
    _, h, w = person.heatmap.maps.shape
    assert np.abs(maps[:, :h, :w] - np.clip(person.heatmap.maps, 0, 1)).max() <= TOL
    assert not maps[:, h:].any() and not maps[:, :, w:].any()  # zero padding


def _header(frame_id: str = 'cam1') -> Header:
    return Header(frame_id=frame_id)


PEOPLE = [_person(0, 30, 20), _person(1, 12, 41), _person(2, 5, 5)]


@pytest.mark.parametrize('n', [0, 1, 3])
def test_people_round_trip(n):
    people = PEOPLE[:n]
    msg = people_to_msg(people, _header())
    grid = (30, 41) if n > 1 else (30, 20) if n else (0, 0)
    assert msg.width == n and msg.header.frame_id == 'cam1'
    assert [f.name for f in msg.fields] == ['keypoints', 'origin', 'stride', 'grid', 'heatmap']
    assert [f.count for f in msg.fields] == [48, 32, 1, 2, 16 * grid[0] * grid[1]]
    assert msg.point_step == 4 * 48 + 4 * 32 + 4 + 4 + 16 * grid[0] * grid[1]
    back = msg_to_people(deserialize_message(serialize_message(msg), PointCloud2))
    assert len(back) == n
    for person, b in zip(people, back):
        _assert_person(person, b, grid)


def test_quantisation_rounds_to_nearest_step():
    person = _person(3, 2, 2)
    person.heatmap.maps[:] = 0.5 / 255 + 1e-4  # just above half a step: rounds up
    person.heatmap.maps[0, 0, 0] = 1.0
    maps = msg_to_people(people_to_msg([person], _header()))[0].heatmap.maps
    assert maps[0, 0, 0] == 1.0 and maps[0, 0, 1] == np.float32(1 / 255)


def test_real_detections_round_trip():
    frame = read_body25(dataset_dir('shelf') / 'openpose_body25' / '0.txt')[0]
    people = detect_people(frame, OpenPoseDetectorConfig())
    assert len(people) >= 2
    msg = people_to_msg(people, _header('cam0'))
    grid = tuple(np.max([p.heatmap.maps.shape[1:] for p in people], axis=0))
    for person, back in zip(people, msg_to_people(msg)):
        _assert_person(person, back, grid)
        # the padded map still peaks where the original did
        np.testing.assert_allclose(back.heatmap.peak()[:, :2], person.heatmap.peak()[:, :2],
                                   atol=1e-3)


def test_bundles_round_trip():
    bundles = [(7, {3: PEOPLE[0], 0: PEOPLE[1]}), (2, {4: PEOPLE[2]}), (4_000_000_000, {1: PEOPLE[1]})]
    msg = bundles_to_msg(bundles, _header('world'))
    assert msg.width == 4
    assert [f.name for f in msg.fields[:3]] == ['person', 'camera', 'keypoints']
    records = from_cloud(msg, people_dtype(16 * 30 * 41, BUNDLE_KEYS))
    assert records['person'].tolist() == [2, 7, 7, 4_000_000_000]
    assert records['camera'].tolist() == [4, 0, 3, 1]
    for m in (msg, deserialize_message(serialize_message(msg), PointCloud2)):
        back = msg_to_bundles(m)
        assert [pid for pid, _ in back] == [2, 7, 4_000_000_000]
        assert [sorted(views) for _, views in back] == [[4], [0, 3], [1]]
        for pid, views in back:
            for camera, person in views.items():
                _assert_person(dict(bundles)[pid][camera], person, (30, 41))
    # records in any order decode the same
    shuffled = to_cloud(records[::-1], _header('world'))
    assert [(pid, sorted(v)) for pid, v in msg_to_bundles(shuffled)] == [(2, [4]), (7, [0, 3]),
                                                                         (4_000_000_000, [1])]


def test_zero_bundles():
    msg = bundles_to_msg([], _header('world'))
    assert msg.width == 0 and len(msg.fields) == 7 and msg.fields[-1].count == 0
    assert msg_to_bundles(msg) == []


def _people_records(people) -> np.ndarray:
    msg = people_to_msg(people, _header())
    return from_cloud(msg, people_dtype(msg.fields[-1].count))


def _set(records, field, index, value):
    records[field][index] = value
    return records


@pytest.mark.parametrize('change, match', [
    (lambda r: _set(r, 'grid', 1, (29, 41)), r'grid mismatch: record 1 has \(29, 41\)'),
    (lambda r: _set(r, 'keypoints', (0, 2), np.nan), 'record 0 joint 0: keypoint score is not finite'),
    (lambda r: _set(r, 'keypoints', (1, 3), np.inf), 'record 1 joint 1: keypoint u, v infinite'),
    (lambda r: _set(r, 'stride', 2, 0.0), 'record 2 heatmap stride'),
    (lambda r: _set(r, 'origin', (0, 1), np.nan), 'record 0 heatmap origin'),
])
def test_people_decoder_rejects(change, match):
    records = change(_people_records(PEOPLE))
    with pytest.raises(ValueError, match=match):
        msg_to_people(to_cloud(records, _header()))


def test_people_decoder_rejects_nan_uv_with_score():
    records = _people_records(PEOPLE)
    kp = records['keypoints'].reshape(3, 16, 3)
    j = int(np.argmax(kp[1, :, 2] > 0))
    kp[1, j, 0] = np.nan
    records['keypoints'] = kp.reshape(3, 48)
    with pytest.raises(ValueError, match=f'record 1 joint {j}: keypoint u, v NaN with score != 0'):
        msg_to_people(to_cloud(records, _header()))


def test_people_decoder_rejects_grid_count_mismatch():
    records = _people_records(PEOPLE[:1])
    records['grid'] = (20, 30)  # same cell count, but 30 x 20 was declared by the field count
    msg_to_people(to_cloud(records, _header()))  # 16 * 20 * 30 cells: consistent, decodes
    records['grid'] = (20, 31)
    with pytest.raises(ValueError, match=r'grid \(20, 31\): needs .* heatmap count'):
        msg_to_people(to_cloud(records, _header()))
    empty = people_to_msg([], _header())
    empty.fields[-1].count = 16
    with pytest.raises(ValueError, match='heatmap count 16: more than the 0 data bytes'):
        msg_to_people(empty)


def test_bundles_decoder_rejects_repeated_view():
    msg = bundles_to_msg([(1, {0: PEOPLE[0], 2: PEOPLE[1]})], _header('world'))
    records = from_cloud(msg, people_dtype(msg.fields[-1].count, BUNDLE_KEYS))
    records['camera'][1] = 0
    with pytest.raises(ValueError, match='person 1 camera 0 given twice'):
        msg_to_bundles(to_cloud(records, _header('world')))


def test_encoders_reject():
    bad_kp = Person2D(np.zeros((15, 3)), PEOPLE[0].heatmap)
    with pytest.raises(ValueError, match=r'person 1 keypoints: expected \(16, 3\)'):
        people_to_msg([PEOPLE[0], bad_kp], _header())
    bad_maps = Person2D(PEOPLE[0].keypoints, PersonHeatmap(np.zeros((15, 4, 4)), np.zeros(2), 4.0))
    with pytest.raises(ValueError, match='person 0 heatmap maps'):
        people_to_msg([bad_maps], _header())
    nan_maps = Person2D(PEOPLE[0].keypoints, PersonHeatmap(np.full((16, 4, 4), np.nan), np.zeros(2), 4.0))
    with pytest.raises(ValueError, match='person 0 heatmap maps: non-finite'):
        people_to_msg([nan_maps], _header())
    # maps are checked a grid size at a time: the error still names the first bad person
    heat = PEOPLE[1].heatmap
    inf_cell = Person2D(PEOPLE[1].keypoints, PersonHeatmap(heat.maps.copy(), heat.origin, heat.stride))
    inf_cell.heatmap.maps[3, 2, 7] = np.inf
    with pytest.raises(ValueError, match='person 2 heatmap maps: non-finite'):
        people_to_msg([PEOPLE[0], PEOPLE[2], inf_cell, nan_maps], _header())
    with pytest.raises(ValueError, match='person 3: no views'):
        bundles_to_msg([(3, {})], _header())
    with pytest.raises(ValueError, match='person id 3: given twice'):
        bundles_to_msg([(3, {0: PEOPLE[0]}), (3, {1: PEOPLE[1]})], _header())
    with pytest.raises(ValueError, match='camera 70000'):
        bundles_to_msg([(3, {70000: PEOPLE[0]})], _header())
    with pytest.raises(ValueError, match='person id -1'):
        bundles_to_msg([(-1, {0: PEOPLE[0]})], _header())
