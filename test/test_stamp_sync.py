"""Exact-stamp camera synchronisation: release order, missing cameras, timeouts, late and
duplicate messages."""
from __future__ import annotations

import pytest

from mvpose_ros.core.association.stamp_sync import StampSync


def test_a_frame_is_released_when_every_camera_delivered_it():
    sync = StampSync(3, timeout=0.5)
    assert sync.add(100, 0, 'a0', now=0.0) == []
    assert sync.add(100, 2, 'a2', now=0.01) == []
    [frame] = sync.add(100, 1, 'a1', now=0.02)
    assert frame.stamp_ns == 100 and frame.items == ['a0', 'a1', 'a2'] and frame.missing == []


def test_a_camera_that_moved_past_a_stamp_releases_it_without_waiting():
    sync = StampSync(2, timeout=10.0)
    sync.add(100, 0, 'a0', now=0.0)
    [old] = sync.add(200, 1, 'b1', now=0.0)  # camera 1 skipped 100: it is never coming
    assert (old.stamp_ns, old.items, old.missing) == (100, ['a0', None], [1])
    [new] = sync.add(200, 0, 'b0', now=0.0)
    assert (new.stamp_ns, new.items) == (200, ['b0', 'b1'])


def test_a_silent_camera_times_out_and_frames_keep_their_order():
    sync = StampSync(2, timeout=0.5)
    sync.add(100, 0, 'a0', now=0.0)
    sync.add(140, 0, 'b0', now=0.04)
    assert sync.expire(now=0.49) == []
    released = sync.expire(now=0.5)
    assert [f.stamp_ns for f in released] == [100]  # 140 has not waited long enough yet
    assert released[0].missing == [1]
    assert [f.stamp_ns for f in sync.expire(now=0.54)] == [140]


def test_late_duplicate_and_unknown_camera_messages_are_refused_with_a_reason():
    sync = StampSync(2, timeout=0.5)
    sync.add(100, 0, 'a0', now=0.0)
    sync.add(100, 1, 'a1', now=0.0)
    with pytest.raises(ValueError, match='after that frame was released'):
        sync.add(100, 0, 'again', now=0.1)
    with pytest.raises(ValueError, match='after that frame was released'):
        sync.add(60, 1, 'old', now=0.1)
    sync.add(200, 0, 'b0', now=0.2)
    with pytest.raises(ValueError, match='twice'):
        sync.add(200, 0, 'b0 again', now=0.2)
    with pytest.raises(ValueError, match='camera 2 is not in 0..1'):
        sync.add(300, 2, 'x', now=0.2)


def test_flush_releases_everything_in_order():
    sync = StampSync(3, timeout=5.0)
    for stamp in (300, 100, 200):
        sync.add(stamp, 1, stamp, now=0.0)
    assert [f.stamp_ns for f in sync.flush()] == [100, 200, 300]
    assert sync.flush() == []


@pytest.mark.parametrize('cameras, timeout', [(0, 1.0), (2, 0.0)])
def test_bad_construction_is_refused(cameras, timeout):
    with pytest.raises(ValueError):
        StampSync(cameras, timeout)
