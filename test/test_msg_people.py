"""Encodings B (2D people of one camera) and C (per-person view bundles): round trips with
heatmaps of different sizes, real detector output, and rejection of malformed messages; bundles
forwarded from the records that came (the association node's way) against bundles encoded again."""
from __future__ import annotations

import numpy as np
import pytest
from rclpy.serialization import deserialize_message, serialize_message
from sensor_msgs.msg import PointCloud2
from std_msgs.msg import Header

from msg_adapters.people_msg import (BUNDLE_KEYS, bundles_to_msg, msg_to_bundles, msg_to_people,
                                     msg_to_wire_people, people_dtype, people_to_msg, wire_bundles_to_msg)
from msg_adapters.records import from_cloud, to_cloud
from mvpose_ros.core.association.associator import Associator
from mvpose_ros.core.datasets.shelf_campus import SHELF_TEST_FRAMES, dataset_dir
from mvpose_ros.core.defaults import FRAME_RATE
from mvpose_ros.core.detection.openpose import read_body25
from mvpose_ros.core.detection.openpose_detector import OpenPoseDetectorConfig, detect_people
from mvpose_ros.core.evaluation.offline import detect_sequence
from mvpose_ros.core.heatmap import PersonHeatmap
from mvpose_ros.core.inference.solver import Inference3D
from mvpose_ros.core.stage import StageConfig
from mvpose_ros.core.types import Person2D

TOL = 0.5 / 255 + 1e-7  # quantisation to 1/255 steps, plus float32 rounding


def _person(seed: int, h: int, w: int) -> Person2D:
    rng = np.random.default_rng(seed)
    kp = np.column_stack([rng.uniform(0, 1000, (16, 2)), rng.uniform(0.05, 1, 16)])
    kp[rng.random(16) < 0.3] = (np.nan, np.nan, 0.0)
    maps = rng.uniform(-0.2, 1.2, (16, h, w)).astype(np.float32)  # out of [0, 1]: clipped
    return Person2D(kp, PersonHeatmap(maps, rng.uniform(-50, 900, (16, 2)), float(rng.uniform(2, 8))))


def _assert_person(person: Person2D, back: Person2D):
    """back, decoded, holds person's maps quantised, each cut to its non-zero cells (and a zero
    ring where the map has one) at the matching origin."""
    assert back.track_id == -1
    assert back.keypoints.shape == (16, 3)
    np.testing.assert_array_equal(back.keypoints, person.keypoints.astype(np.float32))
    heat, got = person.heatmap, back.heatmap
    assert got.stride == np.float32(heat.stride) and got.cells.dtype == np.float32
    offset = np.rint((got.origin - heat.origin) / heat.stride).astype(int)  # (J, 2) columns, rows
    np.testing.assert_allclose(got.origin, (heat.origin + heat.stride * offset).astype(np.float32))
    maps = heat.maps
    for j in range(16):
        (c0, r0), (h, w) = offset[j], got.shape[j]
        assert r0 >= 0 and c0 >= 0 and r0 + h <= maps.shape[1] and c0 + w <= maps.shape[2]
        cut = np.zeros(maps.shape[1:], dtype=bool)
        cut[r0:r0 + h, c0:c0 + w] = True
        mine = got.cells[_map_start(got, j):_map_start(got, j) + h * w].reshape(h, w)
        assert np.abs(mine - np.clip(maps[j, r0:r0 + h, c0:c0 + w], 0, 1)).max() <= TOL
        assert not maps[j][~cut].any()  # only zeros were cut away


def _map_start(heat: PersonHeatmap, j: int) -> int:
    return int((heat.shape[:j, 0] * heat.shape[:j, 1]).sum())


def _header(frame_id: str = 'cam1') -> Header:
    return Header(frame_id=frame_id)


PEOPLE = [_person(0, 30, 20), _person(1, 12, 41), _person(2, 5, 5)]


@pytest.mark.parametrize('n', [0, 1, 3])
def test_people_round_trip(n):
    people = PEOPLE[:n]
    msg = people_to_msg(people, _header())
    cells = 16 * 30 * 20 if n else 0  # the largest record's, each record on its own grids
    assert msg.width == n and msg.header.frame_id == 'cam1'
    assert [f.name for f in msg.fields] == ['keypoints', 'origin', 'stride', 'grid', 'heatmap']
    assert [f.count for f in msg.fields] == [48, 32, 1, 32, cells]
    assert msg.point_step == 4 * 48 + 4 * 32 + 4 + 2 * 32 + cells
    back = msg_to_people(deserialize_message(serialize_message(msg), PointCloud2))
    assert len(back) == n
    for person, b in zip(people, back):
        _assert_person(person, b)
        assert (b.heatmap.shape == person.heatmap.shape).all()  # maps of random values: nothing to cut


def test_maps_travel_cut_to_their_evidence():
    """Zeros around a map's evidence stay home, bar one ring: look-ups, peaks and draws of the
    decoded maps are those of the sent maps, quantised."""
    rng = np.random.default_rng(5)
    maps = np.zeros((16, 40, 50), np.float32)
    maps[3, 10:13, 20:24] = rng.uniform(0.1, 1, (3, 4))  # inside: a ring of zeros kept
    maps[4, 0:2, 45:50] = rng.uniform(0.1, 1, (2, 5))  # at the grid's top right: no ring there
    maps[5, 39, 0] = 0.5
    person = Person2D(PEOPLE[0].keypoints, PersonHeatmap(maps, np.array([100.0, 60.0]), 8.0))
    msg = people_to_msg([person], _header())
    assert msg.fields[-1].count == 5 * 6 + 3 * 6 + 2 * 2 + 13 * 1  # 13 empty maps: one cell each
    back = msg_to_people(msg)[0]
    _assert_person(person, back)
    assert back.heatmap.shape[3].tolist() == [5, 6] and back.heatmap.origin[3].tolist() == [100 + 8 * 19, 60 + 8 * 9]
    uv = rng.uniform([80, 40], [520, 400], (16, 2000, 2))
    uv[3] = rng.uniform([100 + 8 * 18, 60 + 8 * 8], [100 + 8 * 26, 60 + 8 * 15], (2000, 2))  # about the edges
    quantised = PersonHeatmap(np.rint(maps * 255) / np.float32(255), np.array([100.0, 60.0]), 8.0)
    np.testing.assert_allclose(back.heatmap.lookup(uv), quantised.lookup(uv), atol=1e-6)
    np.testing.assert_array_equal(back.heatmap.peak(), quantised.peak())
    draws = [h.sample(np.random.default_rng(1), 50) for h in (back.heatmap, quantised)]
    np.testing.assert_allclose(*draws, atol=1e-9)


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
    assert msg.fields[-1].count < 16 * np.prod(people[0].heatmap.maps.shape[1:])  # the padding stays home
    for person, back in zip(people, msg_to_people(msg)):
        _assert_person(person, back)
        np.testing.assert_allclose(back.heatmap.peak()[:, :2], person.heatmap.peak()[:, :2],
                                   atol=1e-3)


def test_bundles_round_trip():
    bundles = [(7, {3: PEOPLE[0], 0: PEOPLE[1]}), (2, {4: PEOPLE[2]}), (4_000_000_000, {1: PEOPLE[1]})]
    msg = bundles_to_msg(bundles, _header('world'))
    assert msg.width == 4
    assert [f.name for f in msg.fields[:3]] == ['person', 'camera', 'keypoints']
    records = from_cloud(msg, people_dtype(16 * 30 * 20, BUNDLE_KEYS))
    assert records['person'].tolist() == [2, 7, 7, 4_000_000_000]
    assert records['camera'].tolist() == [4, 0, 3, 1]
    for m in (msg, deserialize_message(serialize_message(msg), PointCloud2)):
        back = msg_to_bundles(m)
        assert [pid for pid, _ in back] == [2, 7, 4_000_000_000]
        assert [sorted(views) for _, views in back] == [[4], [0, 3], [1]]
        for pid, views in back:
            for camera, person in views.items():
                _assert_person(dict(bundles)[pid][camera], person)
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
    (lambda r: _set(r, 'grid', (1, 7), 0), r'record 1 joint 3: grid \(12, 0\), needs h, w >= 1'),
    (lambda r: _set(r, 'grid', (2, 0), 2000),
     r'record 2: its grids hold 10375 cells, more than the heatmap count 9600'),
    (lambda r: _set(r, 'stride', 0, 3e37), r'record 0 joint 0: its map reaches pixel .*, beyond float32'),
    (lambda r: _set(r, 'keypoints', (0, 2), np.nan), 'record 0 joint 0: keypoint score is not finite'),
    (lambda r: _set(r, 'keypoints', (1, 3), np.inf), 'record 1 joint 1: keypoint u, v infinite'),
    (lambda r: _set(r, 'stride', 2, 0.0), 'record 2 heatmap stride'),
    (lambda r: _set(r, 'origin', (0, 1), np.nan), 'record 0 heatmap origin'),
])
@pytest.mark.parametrize('decode', [msg_to_people, msg_to_wire_people])
def test_people_decoder_rejects(change, match, decode):
    records = change(_people_records(PEOPLE))
    with pytest.raises(ValueError, match=match):
        decode(to_cloud(records, _header()))


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
    records['grid'] = (20, 30) * 16  # the same cells, read as maps of 20 x 30: consistent, decodes
    msg_to_people(to_cloud(records, _header()))
    records['grid'][0, 1] = 31
    with pytest.raises(ValueError, match=r'record 0: its grids hold 9620 cells, more than the heatmap count 9600'):
        msg_to_people(to_cloud(records, _header()))
    empty = people_to_msg([], _header())
    empty.fields[-1].count = 16
    with pytest.raises(ValueError, match='heatmap count 16: more than the 0 data bytes'):
        msg_to_people(empty)


def _same_maps(a: PersonHeatmap, b: PersonHeatmap) -> bool:
    """Whether two decoded heatmaps give the same look-ups and draws: equal once cut to their
    evidence."""
    a, b = a.trimmed(), b.trimmed()
    return (np.array_equal(a.cells, b.cells) and np.array_equal(a.shape, b.shape)
            and np.array_equal(a.origin, b.origin) and a.stride == b.stride)


def test_wire_bundles_carry_the_records_that_came():
    cams = [people_to_msg(PEOPLE, _header('cam0')), people_to_msg(PEOPLE[1:], _header('cam1'))]
    wire = [msg_to_wire_people(m) for m in cams]
    decoded = [msg_to_people(m) for m in cams]
    np.testing.assert_array_equal(wire[1][0].keypoints, decoded[1][0].keypoints)
    assert all(p.track_id == -1 for ps in wire for p in ps)
    views = [(9, {0: 0, 1: 1}), (3, {1: 0}), (5, {0: 2})]  # person id, {camera: index in that camera}
    forwarded = wire_bundles_to_msg([(pid, {c: wire[c][i] for c, i in v.items()}) for pid, v in views],
                                    _header('world'))
    encoded = bundles_to_msg([(pid, {c: decoded[c][i] for c, i in v.items()}) for pid, v in views],
                             _header('world'))
    assert forwarded.fields == encoded.fields and forwarded.width == encoded.width == 4
    back, again = msg_to_bundles(forwarded), msg_to_bundles(encoded)
    assert [(pid, sorted(v)) for pid, v in back] == [(3, [1]), (5, [0]), (9, [0, 1])]
    for (pid, views_back), (_, views_again) in zip(back, again):
        for c, person in views_back.items():
            np.testing.assert_array_equal(person.keypoints, views_again[c].keypoints)
            assert _same_maps(person.heatmap, views_again[c].heatmap)
    with pytest.raises(ValueError, match='person id 3: given twice'):
        wire_bundles_to_msg([(3, {0: wire[0][0]}), (3, {1: wire[1][0]})], _header())
    assert msg_to_bundles(wire_bundles_to_msg([], _header('world'))) == []


def test_wire_bundles_give_the_3d_stage_the_same_skeletons(shelf_openpose):
    """On real Shelf frames at the graph's settings, bp_solver's 3D stage gives the same ids and
    joints from the association's forwarded bundles as from bundles decoded and encoded again."""
    cameras, raw = shelf_openpose
    seq = detect_sequence(cameras, raw, list(SHELF_TEST_FRAMES[120:150]), OpenPoseDetectorConfig(stride=8.0))
    config = StageConfig.from_params({'window': 6, 'lag': 3})
    outputs = []
    for decode, encode in ((msg_to_people, bundles_to_msg), (msg_to_wire_people, wire_bundles_to_msg)):
        associator, solver = Associator(cameras, config.association), Inference3D(cameras, config.solver)
        results = []
        for frame, per_camera in zip(seq.frames, seq.people):
            people = [decode(people_to_msg(ps, _header(f'cam{c}'))) for c, ps in enumerate(per_camera)]
            bundles = [(o.person_id, o.views) for o in associator.update(frame / FRAME_RATE, people)]
            results += solver.push(frame, msg_to_bundles(encode(bundles, _header('world'))))
        outputs.append(results + solver.flush())
    before, after = outputs
    assert len(before) == len(seq.frames) and sum(len(r.person_ids) for r in before) > 60
    for a, b in zip(before, after, strict=True):
        assert a.frame == b.frame and list(a.person_ids) == list(b.person_ids)
        np.testing.assert_array_equal(a.joints, b.joints)
        np.testing.assert_array_equal(a.confidence, b.confidence)


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
    with pytest.raises(ValueError, match='person 0 heatmap grids: expected 16'):
        people_to_msg([bad_maps], _header())
    nan_maps = Person2D(PEOPLE[0].keypoints, PersonHeatmap(np.full((16, 4, 4), np.nan), np.zeros(2), 4.0))
    with pytest.raises(ValueError, match='person 0 heatmap maps: non-finite'):
        people_to_msg([nan_maps], _header())
    # maps are checked all at once: the error still names the first bad person
    heat = PEOPLE[1].heatmap
    inf_cell = Person2D(PEOPLE[1].keypoints, PersonHeatmap(heat.maps.copy(), heat.origin, heat.stride))
    inf_cell.heatmap.maps[3, 2, 7] = np.inf
    with pytest.raises(ValueError, match='person 2 heatmap maps: non-finite'):
        people_to_msg([PEOPLE[0], PEOPLE[2], inf_cell, nan_maps], _header())
    far = np.zeros((16, 1, 8), np.float32)
    far[:, 0, 7] = 0.5  # cut to columns 6 and 7: the origin moves 6 cells, past float32's largest
    edge = Person2D(PEOPLE[0].keypoints, PersonHeatmap(far, np.full(2, 3.0e38), 1e37))
    with pytest.raises(ValueError, match='person 0 heatmap origin: beyond float32 once its maps are cut'):
        people_to_msg([edge], _header())
    with pytest.raises(ValueError, match='person 3: no views'):
        bundles_to_msg([(3, {})], _header())
    with pytest.raises(ValueError, match='person id 3: given twice'):
        bundles_to_msg([(3, {0: PEOPLE[0]}), (3, {1: PEOPLE[1]})], _header())
    with pytest.raises(ValueError, match='camera 70000'):
        bundles_to_msg([(3, {70000: PEOPLE[0]})], _header())
    with pytest.raises(ValueError, match='person id -1'):
        bundles_to_msg([(-1, {0: PEOPLE[0]})], _header())


def test_a_map_is_cut_to_what_is_sent_so_encoding_a_decoded_person_again_gives_the_same_record():
    """Cells below half a quantisation step go out as 0: the map is cut by the quantised cells, so
    a decoded person encoded again (a bundle made from decoded people) has the same grid and origin
    as the record it came from, not one row fewer."""
    maps = np.zeros((16, 6, 5), np.float32)
    maps[:, 2:4, 1:4] = 0.5
    maps[:, 1, :] = 0.001  # non-zero, but 0 on the wire
    person = Person2D(np.ones((16, 3)), PersonHeatmap(maps, np.array([100.0, 200.0]), 8.0))
    once = from_cloud(people_to_msg([person], _header()), people_dtype(16 * 4 * 5))
    again_msg = people_to_msg(msg_to_people(people_to_msg([person], _header())), _header())
    again = from_cloud(again_msg, people_dtype(16 * 4 * 5))
    assert once['grid'][0, :2].tolist() == [4, 5]  # rows 1 (zeros on the wire) to 4, one zero ring
    for name in ('grid', 'origin', 'heatmap'):
        np.testing.assert_array_equal(once[name], again[name])
