"""PointCloud2 record tables: PointField layout of structured dtypes, the strict decoder, and the
layout checks every encoding's decoder inherits."""
from __future__ import annotations

import numpy as np
import pytest
from sensor_msgs.msg import PointField
from std_msgs.msg import Header

from msg_adapters.openpose_msg import msg_to_openpose, openpose_to_msg
from msg_adapters.people_msg import bundles_to_msg, msg_to_bundles, msg_to_people, people_to_msg
from msg_adapters.records import fields_of, from_cloud, to_cloud
from msg_adapters.skeleton_msg import msg_to_skeletons, skeletons_to_msg
from mvpose_ros.core.detection.openpose import BODY25_PAF_PAIRS, OpenPoseFrame
from mvpose_ros.core.types import Person2D

DTYPE = np.dtype([('kind', 'u1'), ('xyz', '<f4', (3,)), ('id', '<u4'), ('grid', '<u2', (2, 2)),
                  ('w', '<f8'), ('s', '<i2')])


def _records(n: int = 5) -> np.ndarray:
    rng = np.random.default_rng(0)
    r = np.zeros(n, DTYPE)
    r['kind'] = np.arange(n)
    r['xyz'] = rng.normal(size=(n, 3))
    r['id'] = np.arange(n) * 1000003
    r['grid'] = rng.integers(0, 65535, size=(n, 2, 2))
    r['w'] = rng.normal(size=n)
    r['s'] = -np.arange(n)
    return r


def test_fields_of_packed_layout():
    fields = fields_of(DTYPE)
    assert [f.name for f in fields] == ['kind', 'xyz', 'id', 'grid', 'w', 's']
    assert [f.offset for f in fields] == [0, 1, 13, 17, 25, 33]
    assert [f.count for f in fields] == [1, 3, 1, 4, 1, 1]
    assert [f.datatype for f in fields] == [PointField.UINT8, PointField.FLOAT32, PointField.UINT32,
                                            PointField.UINT16, PointField.FLOAT64, PointField.INT16]


@pytest.mark.parametrize('dtype, match', [
    (np.dtype([('a', 'u1'), ('b', '<f4')], align=True), 'offset'),
    (np.dtype([('a', '>f4')]), 'little-endian'),
    (np.dtype([('a', '?')]), 'datatype'),
    (np.dtype('<f4'), 'structured'),
])
def test_fields_of_rejects(dtype, match):
    with pytest.raises(ValueError, match=match):
        fields_of(dtype)


@pytest.mark.parametrize('n', [0, 1, 5])
def test_round_trip_and_layout(n):
    records = _records(n)
    msg = to_cloud(records, Header(frame_id='world'))
    assert (msg.height, msg.width, msg.point_step, msg.row_step) == (1, n, 35, 35 * n)
    assert msg.is_dense and not msg.is_bigendian
    assert len(msg.data) == 35 * n
    back = from_cloud(msg, DTYPE)
    assert back.dtype == DTYPE and back.tobytes() == records.tobytes()
    back['id'] += 1  # a copy: the message stays as it was
    assert from_cloud(msg, DTYPE).tobytes() == records.tobytes()


def _broken(change) -> object:
    msg = to_cloud(_records(), Header())
    change(msg)
    return msg


def _set_field(i, **kw):
    def change(msg):
        for k, v in kw.items():
            setattr(msg.fields[i], k, v)
    return change


@pytest.mark.parametrize('change, match', [
    (_set_field(1, name='xy'), "field 1 name: expected 'xyz', got 'xy'"),
    (_set_field(2, datatype=PointField.INT32), "'id' datatype: expected UINT32 .*got INT32"),
    (_set_field(1, count=2), "'xyz' count: expected 3, got 2"),
    (_set_field(4, offset=24), "'w' offset: expected 25, got 24"),
    (lambda m: m.fields.pop(), 'fields: expected 6'),
    (lambda m: setattr(m, 'point_step', 36), 'point_step: expected 35'),
    (lambda m: setattr(m, 'row_step', 35 * 4), 'row_step'),
    (lambda m: setattr(m, 'data', m.data[:-1]), 'data: expected row_step = 175 bytes, got 174'),
    (lambda m: setattr(m, 'is_bigendian', True), 'is_bigendian'),
    (lambda m: setattr(m, 'height', 2), 'height'),
])
def test_from_cloud_names_the_mismatch(change, match):
    with pytest.raises(ValueError, match=match):
        from_cloud(_broken(change), DTYPE)


def test_to_cloud_rejects_2d_records():
    with pytest.raises(ValueError, match='one-dimensional'):
        to_cloud(_records(4).reshape(2, 2), Header())


def _encoded() -> list[tuple[object, object]]:
    """(message, decoder) of each encoding A-D, each with a few records."""
    candidates = [np.array([[10.0 + j, 20.0, 0.5]] * (1 + j % 2)) for j in range(25)]
    frame = OpenPoseFrame(candidates, [np.full((1 + a % 2, 1 + b % 2), 0.25)
                                       for a, b in BODY25_PAF_PAIRS])
    kp = np.column_stack([np.arange(16.0), np.arange(16.0), np.full(16, 0.9)])
    person = Person2D.from_keypoints(kp, stride=4.0, sigma=3.0)
    return [
        (openpose_to_msg(frame, Header()), msg_to_openpose),
        (people_to_msg([person, person], Header()), msg_to_people),
        (bundles_to_msg([(1, {0: person, 3: person})], Header()), msg_to_bundles),
        (skeletons_to_msg([1, 2], np.zeros((2, 14, 3)), Header(), confidence=np.ones((2, 14))), msg_to_skeletons),
    ]


@pytest.mark.parametrize('which', range(4))
@pytest.mark.parametrize('change, match', [
    (_set_field(0, name='bogus'), 'field 0 name'),
    (_set_field(1, datatype=PointField.FLOAT64), 'datatype'),
    (_set_field(2, count=7), 'count'),
    (lambda m: setattr(m, 'data', m.data[:-3]), 'data: expected'),
    (lambda m: setattr(m, 'row_step', m.row_step + 1), 'row_step'),
    (lambda m: setattr(m, 'is_bigendian', True), 'is_bigendian'),
])
def test_every_decoder_checks_the_layout(which, change, match):
    msg, decode = _encoded()[which]
    decode(msg)  # intact: decodes
    change(msg)
    with pytest.raises(ValueError, match=match):
        decode(msg)
