"""Encoding A (raw OpenPose BODY25 per camera frame) on the real Shelf detections."""
from __future__ import annotations

import numpy as np
import pytest
from rclpy.serialization import deserialize_message, serialize_message
from sensor_msgs.msg import PointCloud2
from std_msgs.msg import Header

from msg_adapters.openpose_msg import OPENPOSE_DTYPE, msg_to_openpose, openpose_to_msg
from msg_adapters.records import from_cloud, to_cloud
from msg_adapters.stamp import stamp_of_frame
from mvpose_ros.core.datasets.shelf_campus import dataset_dir
from mvpose_ros.core.detection.openpose import BODY25_PAF_PAIRS, OpenPoseFrame, read_body25

LINES = (0, 4, 100, 272, 300)  # actorsGT frames 300, 304, 400, 572, 600


@pytest.fixture(scope='module')
def frames():
    all_frames = read_body25(dataset_dir('shelf') / 'openpose_body25' / '0.txt')
    return [all_frames[i] for i in LINES]


def _header(line: int = 0) -> Header:
    return Header(frame_id='cam0', stamp=stamp_of_frame(300 + line))


def _assert_same(frame: OpenPoseFrame, back: OpenPoseFrame):
    assert len(back.candidates) == 25 and len(back.pafs) == 26
    for a, b in zip(frame.candidates, back.candidates):
        assert b.shape == a.shape and np.array_equal(b, a.astype(np.float32))
    for a, b in zip(frame.pafs, back.pafs):
        assert b.shape == a.shape and np.array_equal(b, a.astype(np.float32))


def test_real_frames_round_trip(frames):
    assert any(len(c) == 0 for f in frames for c in f.candidates)  # an empty joint is covered
    for line, frame in zip(LINES, frames):
        msg = openpose_to_msg(frame, _header(line))
        n_cand = sum(len(c) for c in frame.candidates)
        n_paf = sum(p.size for p in frame.pafs)
        assert msg.width == n_cand + n_paf and msg.point_step == 18
        assert msg.header.frame_id == 'cam0'
        _assert_same(frame, msg_to_openpose(msg))


def test_serialized_round_trip(frames):
    msg = openpose_to_msg(frames[3], _header(272))
    back = deserialize_message(serialize_message(msg), PointCloud2)
    assert back.header.stamp.sec == 22 and back.header.stamp.nanosec == 880_000_000
    _assert_same(frames[3], msg_to_openpose(back))


def test_any_record_order(frames):
    records = from_cloud(openpose_to_msg(frames[2], _header()), OPENPOSE_DTYPE)
    shuffled = records[np.random.default_rng(1).permutation(len(records))]
    _assert_same(frames[2], msg_to_openpose(to_cloud(shuffled, _header())))


def test_empty_frame():
    frame = OpenPoseFrame([np.zeros((0, 3))] * 25, [np.zeros((0, 0))] * 26)
    msg = openpose_to_msg(frame, _header())
    assert msg.width == 0
    _assert_same(frame, msg_to_openpose(msg))


def _tampered(frame: OpenPoseFrame, change) -> PointCloud2:
    records = from_cloud(openpose_to_msg(frame, _header()), OPENPOSE_DTYPE)
    return to_cloud(change(records), _header())


def _candidate(records, joint):
    return np.flatnonzero((records['kind'] == 0) & (records['part'] == joint))


def _affinity(records, limb):
    return np.flatnonzero((records['kind'] == 1) & (records['part'] == limb))


def _set(records, index, field, value):
    records[field][index] = value
    return records


def _limb_with_entries(frame):
    return next(k for k, p in enumerate(frame.pafs) if p.size >= 2)


def _joint_with(frame, n):
    return next(j for j, c in enumerate(frame.candidates) if len(c) >= n)


@pytest.mark.parametrize('change, match', [
    (lambda r, f: _set(r, 0, 'kind', 2), 'kind value 2'),
    (lambda r, f: _set(r, _candidate(r, _joint_with(f, 2))[1], 'a', 0),
     'duplicated candidate index 0'),
    (lambda r, f: _set(r, _candidate(r, _joint_with(f, 2))[0], 'a', 7),
     'missing candidate index 0'),
    (lambda r, f: np.delete(r, _affinity(r, _limb_with_entries(f))[0]), 'missing entries'),
    (lambda r, f: np.concatenate([r, r[_affinity(r, _limb_with_entries(f))[:1]]]),
     'given twice'),
    (lambda r, f: _set(r, _affinity(r, _limb_with_entries(f))[0], 'a', 999), 'outside'),
    (lambda r, f: _set(r, _candidate(r, 1)[0], 'score', np.nan), 'candidate score not finite'),
    (lambda r, f: _set(r, _candidate(r, 1)[0], 'b', 1), 'candidate b is not 0'),
    (lambda r, f: _set(r, _candidate(r, 1)[0], 'part', 25), r'part \(joint\) >= 25'),
    (lambda r, f: _set(r, _affinity(r, 0)[0], 'part', 26), r'part \(limb\) >= 26'),
    (lambda r, f: _set(r, _affinity(r, 0)[0], 'u', 3.0), 'affinity u, v not NaN'),
    (lambda r, f: _set(r, _affinity(r, 0)[0], 'score', np.inf), 'affinity score not finite'),
])
def test_decoder_rejects(frames, change, match):
    frame = frames[0]
    with pytest.raises(ValueError, match=match):
        msg_to_openpose(_tampered(frame, lambda r: change(r, frame)))


def test_encoder_rejects(frames):
    frame = frames[0]
    with pytest.raises(ValueError, match='expected 25 joints'):
        openpose_to_msg(OpenPoseFrame(frame.candidates[:24], frame.pafs), _header())
    k = _limb_with_entries(frame)
    pafs = list(frame.pafs)
    pafs[k] = pafs[k][:, :-1]
    with pytest.raises(ValueError, match=f'paf {k} .*expected shape'):
        openpose_to_msg(OpenPoseFrame(frame.candidates, pafs), _header())
    candidates = [c.copy() for c in frame.candidates]
    candidates[1][0, 2] = np.nan
    with pytest.raises(ValueError, match='joint 1: non-finite'):
        openpose_to_msg(OpenPoseFrame(candidates, frame.pafs), _header())


def test_paf_pairs_are_the_limbs(frames):
    frame = frames[0]
    for (a, b), paf in zip(BODY25_PAF_PAIRS, msg_to_openpose(openpose_to_msg(frame, _header())).pafs):
        assert paf.shape == (len(frame.candidates[a]), len(frame.candidates[b]))
