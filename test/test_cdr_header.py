"""The header of serialised messages, read and rewritten in the bytes: stamp, frame_id; and a
PointCloud2 deserialised with a one-line error."""
from __future__ import annotations

import pytest
from rclpy.serialization import deserialize_message, serialize_message
from sensor_msgs.msg import CameraInfo, Image, PointCloud2

from msg_adapters.cdr_header import (CLOUD_OVERHEAD, after_stamp, deserialise, deserialise_cloud, header_frame_id,
                                     header_stamp_ns, with_header_stamp)

S = 1_000_000_000


@pytest.mark.parametrize('msg', [CameraInfo(d=[0.1, 0.2, 0.0, 0.0, 0.3], width=1032, height=776),
                                 PointCloud2(width=3, point_step=4, row_step=12, data=bytes(range(12)))])
def test_header_stamp_rewritten_in_the_cdr_bytes(msg):
    msg.header.stamp.sec, msg.header.stamp.nanosec, msg.header.frame_id = 12, 40_000_000, 'cam3'
    cdr = serialize_message(msg)
    assert header_stamp_ns(cdr) == 12 * S + 40_000_000
    new_stamp = 36 * S + 80_000_000
    moved = with_header_stamp(cdr, new_stamp)
    assert len(moved) == len(cdr) and header_stamp_ns(moved) == new_stamp
    back = deserialize_message(moved, type(msg))
    assert (back.header.stamp.sec, back.header.stamp.nanosec) == (36, 80_000_000)
    back.header.stamp = msg.header.stamp
    assert back == msg  # nothing but the stamp changed


def test_header_stamp_needs_cdr_bytes():
    with pytest.raises(ValueError, match='CDR'):
        header_stamp_ns(b'\x01\x02\x00\x00' + bytes(8))
    with pytest.raises(ValueError, match='CDR'):
        with_header_stamp(b'\x00\x01\x00\x00', 0)
    cdr = serialize_message(PointCloud2())
    with pytest.raises(ValueError, match='Time'):
        with_header_stamp(cdr, 2 ** 31 * S)


@pytest.mark.parametrize('frame_id', ['cam3', '', 'a' * 4, 'kamera_überall'])
def test_header_frame_id_read_from_the_cdr_bytes(frame_id):
    msg = Image(height=2, width=3, encoding='mono8', step=3, data=bytes(6))
    msg.header.frame_id = frame_id
    assert header_frame_id(serialize_message(msg)) == frame_id


@pytest.mark.parametrize('cdr', [b'\x00\x01\x00\x00' + bytes(8),  # no room for the string length
                                 b'\x00\x01\x00\x00' + bytes(8) + (100).to_bytes(4, 'little') + b'ab\x00',
                                 b'\x00\x01\x00\x00' + bytes(8) + (0).to_bytes(4, 'little'),
                                 b'\x00\x01\x00\x00' + bytes(8) + (3).to_bytes(4, 'little') + b'abc',  # no NUL
                                 b'\x00\x01\x00\x00' + bytes(8) + (3).to_bytes(4, 'little') + b'\xff\xfe\x00'])
def test_header_frame_id_of_bytes_that_cannot_hold_one_is_a_value_error(cdr):
    with pytest.raises(ValueError, match='frame_id'):
        header_frame_id(cdr)


def test_a_cloud_deserialises_or_is_a_one_line_value_error():
    cloud = PointCloud2(width=3, point_step=4, row_step=12, data=bytes(range(12)))
    cloud.header.frame_id = 'cam1'
    cdr = serialize_message(cloud)
    assert deserialise_cloud(cdr) == cloud
    assert len(cdr) - len(cloud.data) < CLOUD_OVERHEAD  # the bound the nodes add to a data bound
    half = len(cdr) // 2
    with pytest.raises(ValueError, match=rf'^failed to deserialize .* \({half} bytes as a PointCloud2\)$') as err:
        deserialise_cloud(cdr[:half])
    assert '\n' not in str(err.value)


def test_after_stamp_tells_messages_apart_by_all_but_their_stamps():
    """A driver's CameraInfo comes with every image, the same but for its stamp: equal bytes after
    the stamp; any field the checks read, or the frame_id, changes them."""
    def info(sec: int, **fields) -> bytes:
        msg = CameraInfo(width=1032, height=776, distortion_model='plumb_bob', d=[0.1, -0.2, 0.0, 0.0, 0.03],
                         k=[1000.0, 0, 516, 0, 1000.0, 388, 0, 0, 1])
        msg.header.stamp.sec, msg.header.frame_id = sec, 'cam1'
        for name, value in fields.items():
            target = msg.header if name == 'frame_id' else msg
            setattr(target, name, value)
        return serialize_message(msg)

    assert after_stamp(info(12)) == after_stamp(info(13)) != after_stamp(info(12, width=1030))
    for change in ({'height': 770}, {'d': [0.1, -0.2, 0.0, 0.0, 0.031]}, {'distortion_model': 'equidistant'},
                   {'k': [1000.5, 0, 516, 0, 1000.0, 388, 0, 0, 1]}, {'frame_id': 'cam2'}, {'binning_x': 2}):
        assert after_stamp(info(12, **change)) != after_stamp(info(12)), change
    with pytest.raises(ValueError, match='CDR'):
        after_stamp(b'\x07\x07' + info(12)[2:])


def test_deserialise_names_the_type_it_wanted_in_one_line():
    cdr = serialize_message(CameraInfo(width=3))
    assert deserialise(cdr, CameraInfo).width == 3
    with pytest.raises(ValueError, match=r'^failed to deserialize .* \(20 bytes as a CameraInfo\)$'):
        deserialise(cdr[:20], CameraInfo)
