"""Which image and 2D people of each camera go with a skeleton set (core.overlay_sets), and the
bounded buffers they wait in."""
from __future__ import annotations

import pytest

from mvpose_ros.core.overlay_sets import RecentByStamp, set_members

MS = 1_000_000  # ns


def test_items_older_than_keep_behind_the_newest_fall_out():
    recent = RecentByStamp(keep_ns=100 * MS)
    for t in range(0, 300, 40):
        recent.add(t * MS, f'image {t}')
    assert [recent.get(t * MS) for t in (160, 200, 240, 280)] == [None, 'image 200', 'image 240', 'image 280']
    assert len(recent) == 3


def test_bytes_bound_drops_the_oldest_first_and_keeps_the_newest_even_when_too_large():
    recent = RecentByStamp(keep_ns=10**12, max_bytes=10)
    for t in range(5):
        recent.add(t, t, size=4)
    assert [recent.get(t) for t in range(5)] == [None, None, None, 3, 4] and recent.bytes == 8
    recent.add(9, 'huge', size=50)
    assert len(recent) == 1 and recent.get(9) == 'huge' and recent.bytes == 50


def test_a_late_message_is_kept_in_stamp_order_and_a_repeated_stamp_replaces():
    recent = RecentByStamp(keep_ns=10**12, max_bytes=100)
    recent.add(30, 'c', 10)
    recent.add(10, 'a', 10)
    recent.add(20, 'b', 10)
    recent.add(20, 'b2', 30)
    assert recent.first_in(0, 100) == (10, 'a') and recent.first_in(11, 25) == (20, 'b2')
    assert recent.first_in(21, 29) is None and recent.bytes == 50


def test_invalid_bounds_are_refused():
    with pytest.raises(ValueError, match='keep_ns and max_bytes'):
        RecentByStamp(-1)
    with pytest.raises(ValueError, match='keep_ns and max_bytes'):
        RecentByStamp(1, max_bytes=-5)


def _buffers(stamps_of_cameras: list[list[int]], people_of_cameras: list[list[int]]):
    images = [RecentByStamp(10**12) for _ in stamps_of_cameras]
    people = [RecentByStamp(10**12) for _ in stamps_of_cameras]
    for c, stamps in enumerate(stamps_of_cameras):
        for t in stamps:
            images[c].add(t, f'cam{c}@{t}')
    for c, stamps in enumerate(people_of_cameras):
        for t in stamps:
            people[c].add(t, [f'people of cam{c}@{t}'])
    return images, people


def test_each_camera_gives_its_member_of_the_set_with_its_own_stamp():
    """Cameras stamped 0, +3 and +8 ms (jitter on top) at 25 Hz: the set stamped by its earliest
    member gets each camera's image of the same capture, never the next one, 40 ms later."""
    offsets = [0, 3 * MS, 8 * MS]
    stamps = [[k * 40 * MS + o + (k % 2) * MS for k in range(5)] for o in offsets]
    images, people = _buffers(stamps, stamps)
    for k in range(5):
        members = set_members(stamps[0][k], 20 * MS, images, people)
        assert [(m.camera, m.stamp_ns) for m in members] == [(c, stamps[c][k]) for c in range(3)]
        assert all(m.image == f'cam{m.camera}@{m.stamp_ns}' and m.people == [f'people of {m.image}']
                   for m in members)


def test_a_camera_without_an_image_in_the_window_is_left_out_and_one_without_people_is_drawn_bare():
    images, people = _buffers([[0], [5 * MS], [45 * MS]], [[0], [], [45 * MS]])
    members = set_members(0, 20 * MS, images, people)
    assert [(m.camera, m.stamp_ns, m.people) for m in members] == [(0, 0, ['people of cam0@0']), (1, 5 * MS, None)]


def test_the_image_the_people_were_detected_in_wins_over_an_earlier_one_in_the_window():
    """A camera with two images in the window (a burst) whose people came from the second."""
    images, people = _buffers([[0], [2 * MS, 9 * MS]], [[0], [9 * MS]])
    (_, member) = set_members(0, 20 * MS, images, people)
    assert member.stamp_ns == 9 * MS and member.image == f'cam1@{9 * MS}'


def test_the_members_are_those_the_synchroniser_put_in_each_set():
    """Five cameras at 25 Hz, offsets up to +-8 ms, 1 ms of jitter, dropped frames: every set that
    core.association.approximate_sync releases (as the association does, at half a frame period)
    gets from set_members exactly its members' stamps, people and images."""
    import numpy as np

    from mvpose_ros.core.association.approximate_sync import ApproximateSync
    from mvpose_ros.core.defaults import default_max_skew
    rng = np.random.default_rng(3)
    max_skew = default_max_skew(25.0)
    offsets = rng.uniform(-8, 8, 5) * MS
    stamps = [[int(1e9 + k * 40 * MS + o + rng.uniform(-1, 1) * MS) for k in range(60) if rng.random() > 0.1]
              for o in offsets]
    sync = ApproximateSync(5, 0.5, max_skew)
    arrivals = sorted((t, c) for c, ts in enumerate(stamps) for t in ts)
    released = [s for t, c in arrivals for s in sync.add(t, c, t, t / 1e9)] + sync.flush()
    images, people = _buffers(stamps, stamps)
    assert len(released) > 50
    for s in released:
        members = set_members(s.stamp_ns, round(max_skew * 1e9), images, people)
        assert {m.camera: m.stamp_ns for m in members} == {c: t for c, t in enumerate(s.stamps) if t is not None}


def test_dropped_sets_do_not_take_the_place_of_sets_with_skeletons():
    from mvpose_ros.core.overlay_sets import DROPPED_PERIOD_S, due
    assert due(10.6, 10.0, 0.5, dropped=False) and not due(10.4, 10.0, 0.5, dropped=False)
    assert not due(10.6, 10.0, 0.5, dropped=True) and due(10.0 + DROPPED_PERIOD_S, 10.0, 0.5, dropped=True)
    assert due(10.0, 10.0, 0.0, dropped=True) and due(10.0, 10.0, 0.0, dropped=False)  # max_rate 0: every set
    assert due(14.0, 10.0, 3.0, dropped=True) and not due(12.5, 10.0, 3.0, dropped=True)  # the longer wait wins
