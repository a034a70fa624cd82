"""Encoding D (3D skeletons, one record per person joint) and the RViz markers built from it."""
from __future__ import annotations

import itertools

import numpy as np
import pytest
from geometry_msgs.msg import Point
from rclpy.serialization import deserialize_message, serialize_message
from sensor_msgs.msg import PointCloud2
from std_msgs.msg import Header
from visualization_msgs.msg import Marker, MarkerArray

from msg_adapters.markers import camera_markers, frustum, person_colour, skeleton_markers
from msg_adapters.records import from_cloud, to_cloud
from msg_adapters.skeleton_msg import SKELETON_DTYPE, msg_to_skeletons, skeletons_to_msg
from mvpose_ros.core.drawing.colours import MIN_ALPHA
from mvpose_ros.core.geometry.body import BONES

WORLD = Header(frame_id='world')


def _joints(p: int, seed: int = 0) -> np.ndarray:
    return np.random.default_rng(seed).uniform(-3, 3, (p, 14, 3))


def _conf(p: int, seed: int = 0) -> np.ndarray:
    return np.random.default_rng(seed + 1).uniform(0, 1, (p, 14))


@pytest.mark.parametrize('ids', [[], [4], [9, 0, 3]])
def test_round_trip(ids):
    joints, confidence = _joints(len(ids)), _conf(len(ids))
    msg = skeletons_to_msg(np.array(ids, dtype=int), joints, WORLD, confidence=confidence)
    assert msg.width == 14 * len(ids) and msg.point_step == 21 and msg.header.frame_id == 'world'
    # the older layout's fields where they were, confidence appended
    assert [(f.name, f.offset) for f in msg.fields] == [('x', 0), ('y', 4), ('z', 8),
                                                        ('person', 12), ('joint', 16), ('confidence', 17)]
    order = np.argsort(ids)
    for m in (msg, deserialize_message(serialize_message(msg), PointCloud2)):
        back_ids, back, back_conf = msg_to_skeletons(m)
        assert back_ids.tolist() == sorted(ids) and back.shape == (len(ids), 14, 3)
        np.testing.assert_array_equal(back, joints[order].astype(np.float32))
        np.testing.assert_array_equal(back_conf, confidence[order].astype(np.float32))


def test_a_reader_of_named_fields_reads_the_older_fields():
    """A reader that looks x, y, z, person and joint up by name (as PointCloud2 iterators do) and
    ignores the rest gets what it got before confidence was appended."""
    msg = skeletons_to_msg(np.array([3]), _joints(1), WORLD, confidence=_conf(1))
    data = bytes(msg.data)
    offsets = {f.name: f.offset for f in msg.fields}
    joint = np.frombuffer(data, np.uint8)[offsets['joint']::msg.point_step]
    person = [int.from_bytes(data[k + offsets['person']:k + offsets['person'] + 4], 'little')
              for k in range(0, len(data), msg.point_step)]
    assert joint.tolist() == list(range(14)) and person == [3] * 14


def _records(p: int = 2) -> np.ndarray:
    return from_cloud(skeletons_to_msg(np.arange(p) * 5, _joints(p), WORLD, confidence=_conf(p)), SKELETON_DTYPE)


def _decode(records):
    return msg_to_skeletons(to_cloud(records, WORLD))


def test_decoder_rejects_incomplete_person():
    with pytest.raises(ValueError, match='person 5 has 13 joint records, expected 14'):
        _decode(np.delete(_records(), 20))


def test_decoder_rejects_joint_order():
    records = _records()
    records['joint'][[14, 15]] = records['joint'][[15, 14]]
    with pytest.raises(ValueError, match='joints of person 5 are .* expected 0..13 in order'):
        _decode(records)


def test_decoder_rejects_unsorted_people():
    records = _records()
    with pytest.raises(ValueError, match='not grouped by person in increasing id'):
        _decode(np.concatenate([records[14:], records[:14]]))
    with pytest.raises(ValueError, match='not grouped by person'):
        _decode(records[np.r_[0:7, 14:21, 7:14, 21:28]])


def test_decoder_rejects_non_finite():
    records = _records()
    records['z'][17] = np.nan
    with pytest.raises(ValueError, match='person 5: joint 3 not finite'):
        _decode(records)


def test_decoder_rejects_confidence_outside_unit_interval():
    for bad in (np.nan, -0.01, 1.01):
        records = _records()
        records['confidence'][16] = bad
        with pytest.raises(ValueError, match='person 5: joint 2 confidence .* not in'):
            _decode(records)


def test_encoder_rejects():
    c = _conf(2)
    with pytest.raises(ValueError, match=r'expected \(2, 14, 3\)'):
        skeletons_to_msg([1, 2], _joints(2)[:, :13], WORLD, confidence=c)
    with pytest.raises(ValueError, match='person 1 given twice'):
        skeletons_to_msg([1, 1], _joints(2), WORLD, confidence=c)
    with pytest.raises(ValueError, match='integers'):
        skeletons_to_msg([1.5, 2], _joints(2), WORLD, confidence=c)
    joints = _joints(2)
    joints[1, 12, 0] = np.inf
    with pytest.raises(ValueError, match='person 2: joint 12 not finite'):
        skeletons_to_msg([1, 2], joints, WORLD, confidence=c)
    with pytest.raises(ValueError, match=r'confidence: expected \(2, 14\)'):
        skeletons_to_msg([1, 2], _joints(2), WORLD, confidence=c[:, :13])
    c[0, 4] = 1.5
    with pytest.raises(ValueError, match='person 1: joint 4 confidence 1.5 not in'):
        skeletons_to_msg([1, 2], _joints(2), WORLD, confidence=c)


def test_markers():
    ids = np.array([7, 2, 3])
    joints, confidence = _joints(3), _conf(3)
    confidence[0, 0] = 0.0  # person 7's joint 0: the faintest
    array = skeleton_markers(ids, joints, WORLD, confidence=confidence, lifetime_s=0.5)
    markers = array.markers
    assert len(markers) == 1 + 2 * 3
    assert markers[0].action == Marker.DELETEALL
    assert all(m.header.frame_id == 'world' for m in markers)
    body = markers[1:]
    assert [(m.ns, m.id, m.type) for m in body] == [
        (ns, i, t) for i in (2, 3, 7)
        for ns, t in (('joints', Marker.SPHERE_LIST), ('bones', Marker.LINE_LIST))]
    by_id = dict(zip(ids.tolist(), joints))
    conf_of = dict(zip(ids.tolist(), confidence))
    for m in body:
        assert m.action == Marker.ADD and m.lifetime.sec == 0 and m.lifetime.nanosec == 500_000_000
        alpha = np.array([c.a for c in m.colors])
        assert all((c.r, c.g, c.b) == pytest.approx(person_colour(m.id)) for c in m.colors)
        assert m.pose.orientation.w == 1.0
        assert all(isinstance(p, Point) for p in m.points)
        xyz = np.array([[p.x, p.y, p.z] for p in m.points])
        assert (m.color.r, m.color.g, m.color.b, m.color.a) == pytest.approx((*person_colour(m.id), 1.0))
        if m.ns == 'joints':
            assert (m.scale.x, m.scale.y, m.scale.z) == pytest.approx((0.06, 0.06, 0.06))
            np.testing.assert_array_equal(xyz, by_id[m.id])  # float64, no float32 rounding
            # opacity follows confidence: the same order, 0 still visible, 1 opaque
            np.testing.assert_allclose(alpha, MIN_ALPHA + (1 - MIN_ALPHA) * conf_of[m.id])
            assert (np.argsort(alpha) == np.argsort(conf_of[m.id])).all()
        else:
            assert m.scale.x == pytest.approx(0.03)
            assert len(m.points) == 2 * len(BONES)
            np.testing.assert_array_equal(xyz, by_id[m.id][np.array(BONES).ravel()])
            # a bone as opaque as its less sure end, both of its points alike
            bone = conf_of[m.id][np.array(BONES)].min(axis=1)
            np.testing.assert_allclose(alpha, np.repeat(MIN_ALPHA + (1 - MIN_ALPHA) * bone, 2))
    back = deserialize_message(serialize_message(array), MarkerArray)
    assert len(back.markers) == 7 and back.markers[2].ns == 'bones'


def test_markers_for_nobody():
    markers = skeleton_markers(np.zeros(0, int), np.zeros((0, 14, 3)), WORLD, confidence=np.zeros((0, 14)),
                               lifetime_s=1.0).markers
    assert len(markers) == 1 and markers[0].action == Marker.DELETEALL


def test_colours_stable_and_distinct():
    colours = [person_colour(i) for i in range(10)]
    assert colours == [person_colour(i) for i in range(10)]
    assert all(0 <= c <= 1 for rgb in colours for c in rgb)
    for a, b in itertools.combinations(colours, 2):
        assert np.linalg.norm(np.subtract(a, b)) > 0.2
    first = skeleton_markers([4], _joints(1), WORLD, confidence=_conf(1), lifetime_s=1.0).markers[1].color
    again = skeleton_markers([0, 4], _joints(2, seed=5), WORLD, confidence=_conf(2), lifetime_s=1.0).markers[3].color
    assert (first.r, first.g, first.b) == (again.r, again.g, again.b)


def test_marker_id_range():
    with pytest.raises(ValueError, match='INT32'):
        skeleton_markers([1 << 31], _joints(1), WORLD, confidence=_conf(1), lifetime_s=1.0)


def test_camera_frusta_reach_the_image_corners():
    from mvpose_ros.core.datasets.shelf_campus import shelf_cameras
    cameras = shelf_cameras(None)
    array = camera_markers(cameras, [f'cam{c}' for c in range(len(cameras))], WORLD)
    lines = [m for m in array.markers if m.ns == 'frusta']
    names = [m for m in array.markers if m.ns == 'camera names']
    assert [m.id for m in lines] == list(range(len(cameras))) and [m.text for m in names] == ['cam0', 'cam1', 'cam2',
                                                                                              'cam3', 'cam4']
    assert all(m.lifetime.sec == 0 and m.lifetime.nanosec == 0 and m.header.frame_id == 'world' for m in lines)
    for camera, marker in zip(cameras, lines):
        points = frustum(camera)
        np.testing.assert_allclose(points[0], camera.centre)
        corners = camera.project(points[1:])
        np.testing.assert_allclose(corners, [[0, 0], [camera.width, 0], [camera.width, camera.height],
                                             [0, camera.height]], atol=1e-6)
        depth = (points[1:] @ camera.R.T + camera.t)[:, 2]
        np.testing.assert_allclose(depth, 0.5)
        assert len(marker.points) == 16  # 4 edges from the centre, 4 around the image
