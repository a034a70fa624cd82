"""Replay pacing without ROS: frames, loop stamp offsets, due times and the in-flight rule."""
from __future__ import annotations

import numpy as np
import pytest

from mvpose_ros.bags.replay import (FRAME_PERIOD_NS, Frame, InFlight, SyncSet, due_s, group_frames, loop_offset_ns,
                                    looped)

S = 1_000_000_000


def _messages(stamps_ns, topics=('/cam0/openpose', '/cam1/openpose')):
    return [(t, 'sensor_msgs/msg/PointCloud2', s, f'{t}@{s}'.encode()) for s in stamps_ns for t in topics]


def test_messages_of_one_stamp_form_one_frame_in_bag_order():
    stamps = [12 * S, 12 * S + FRAME_PERIOD_NS, 12 * S + 3 * FRAME_PERIOD_NS]
    frames = list(group_frames(_messages(stamps)))
    assert [f.stamp_ns for f in frames] == stamps
    for f in frames:
        assert [m[0] for m in f.messages] == ['/cam0/openpose', '/cam1/openpose']
        assert [m[2] for m in f.messages] == [f'/cam{c}/openpose@{f.stamp_ns}'.encode() for c in (0, 1)]
    assert list(group_frames([])) == []


def test_out_of_order_messages_are_an_error():
    messages = _messages([2 * S]) + _messages([S])
    with pytest.raises(ValueError, match='out of log-time order'):
        list(group_frames(messages))


def test_loop_offsets_keep_the_frame_spacing_across_the_seam():
    first, last = 12 * S, 24 * S
    assert loop_offset_ns(0, first, last) == 0
    assert loop_offset_ns(1, first, last) == 12 * S + FRAME_PERIOD_NS
    assert loop_offset_ns(3, first, last) == 3 * (12 * S + FRAME_PERIOD_NS)
    # one-frame bag: each loop is one frame period later
    assert loop_offset_ns(2, first, first) == 2 * FRAME_PERIOD_NS
    with pytest.raises(ValueError):
        loop_offset_ns(-1, first, last)


def test_looped_replays_every_frame_with_strictly_increasing_stamps():
    stamps = [300 * FRAME_PERIOD_NS, 301 * FRAME_PERIOD_NS, 305 * FRAME_PERIOD_NS]
    passes = []

    def frames_of_pass():
        passes.append(1)
        return group_frames(_messages(stamps))

    out = list(looped(frames_of_pass, 3))
    assert len(passes) == 3
    assert [loop for loop, _, _ in out] == [0] * 3 + [1] * 3 + [2] * 3
    shifted = [frame.stamp_ns + offset for _, offset, frame in out]
    assert np.all(np.diff(shifted) > 0)
    period = stamps[-1] - stamps[0] + FRAME_PERIOD_NS
    assert shifted == [s + k * period for k in range(3) for s in stamps]
    # the last frame of a pass and the first of the next are one frame period apart
    assert shifted[3] - shifted[2] == FRAME_PERIOD_NS
    with pytest.raises(ValueError):
        list(looped(frames_of_pass, 0))
    assert list(looped(lambda: iter(()), 2)) == []


def test_frames_are_due_at_the_recorded_spacing_divided_by_the_rate():
    first = 12 * S
    assert due_s(first, first, 1.0) == 0.0
    assert due_s(first + 25 * FRAME_PERIOD_NS, first, 1.0) == pytest.approx(1.0)
    assert due_s(first + 25 * FRAME_PERIOD_NS, first, 2.0) == pytest.approx(0.5)
    assert due_s(first + 25 * FRAME_PERIOD_NS, first, 0.5) == pytest.approx(2.0)
    with pytest.raises(ValueError):
        due_s(first, first, 0.0)


def test_in_flight_limits_frames_ahead_of_downstream():
    flight = InFlight(3)
    for k in range(3):
        assert not flight.full
        flight.published(k * FRAME_PERIOD_NS)
    assert flight.full and len(flight) == 3
    assert flight.acked(-1) == 0 and flight.full  # a stamp before every frame releases nothing
    assert flight.acked(0) == 1 and not flight.full
    flight.published(3 * FRAME_PERIOD_NS)
    # an ack covers every frame up to its stamp (downstream may skip one)
    assert flight.acked(2 * FRAME_PERIOD_NS + 1) == 2 and len(flight) == 1
    assert flight.acked(2 * FRAME_PERIOD_NS) == 0  # late, repeated acks change nothing
    assert flight.acked(10 * S) == 1 and len(flight) == 0
    with pytest.raises(ValueError):
        flight.published(3 * FRAME_PERIOD_NS)  # not after the last published stamp
    with pytest.raises(ValueError):
        InFlight(0)


def test_frame_defaults_to_no_messages():
    assert Frame(5).messages == []


def test_a_set_moved_to_a_later_pass_moves_its_members_with_it():
    s = SyncSet(1_000, [('/a', 'T', b'x')], index=3, members={'/a': 1_000, '/b': 1_005}, skew_ns=5)
    later = s.moved(500, 13)
    assert (later.stamp_ns, later.index, later.members, later.skew_ns, later.messages) == (
        1_500, 13, {'/a': 1_500, '/b': 1_505}, 5, [])
    assert s.members == {'/a': 1_000, '/b': 1_005}  # the first pass's set is left as it was
