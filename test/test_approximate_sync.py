"""Approximate-time synchronisation of N cameras, checked against these semantics (those of
message_filters' ApproximateTime policy, plus a timeout for silent cameras):

S1. A set holds at most one message per camera, all within max_skew of each other: the oldest
    pending message of all (the pivot) and, from every other camera, its oldest pending message
    stamped in [pivot, pivot + max_skew]. The set's stamp is the pivot's (the earliest member);
    skew_ns = newest - oldest member stamp.
S2. A set is released as soon as every camera is a member, has moved past the window (delivered a
    later stamp), or is absent (an earlier set waited the whole timeout for it, and nothing has
    come from it since) and max_skew s have passed since the set's last member arrived (a grace
    for a camera coming back); otherwise it waits for the missing cameras at most `timeout` s
    from its first member's arrival, then goes without them (listed in `missing`), and they are
    absent.
S3. Sets leave in strictly increasing stamp order and are numbered 0, 1, 2, ... in that order.
S4. Each message is used at most once; nothing is lost silently: a message at or before a stamp
    its camera has passed ('late'), a repeat of a pending stamp ('duplicate'), a set smaller than
    min_cameras ('unmatched') and a queue above queue_size ('overflow') are counted by reason.
S5. With max_skew = 0 the sets are exactly those of exact-stamp synchronisation (StampSync).

The scenarios are a 5-camera rig at 25 Hz (40 ms) with per-camera stamp offsets of up to +-8 ms
plus +-1 ms jitter, each message arriving 3..15 ms after its stamp, a timer calling expire()
every 10 ms, sync_timeout 0.5 s and max_skew 20 ms (half the frame period).
"""
from __future__ import annotations

import random
from dataclasses import dataclass

import pytest

from mvpose_ros.core.association.approximate_sync import ApproximateSync, Drop, SyncedSet, stamp_rate
from mvpose_ros.core.association.stamp_sync import StampSync, SyncedFrame

PERIOD_NS = 40_000_000
MS = 1_000_000
OFFSETS_MS = (-8.0, -3.0, 0.0, 4.0, 8.0)
TIMEOUT = 0.5
MAX_SKEW = 0.020
T0_NS = 1_000 * PERIOD_NS  # stamps far from 0, as real clocks are


@dataclass
class Event:
    arrival: float  # monotonic seconds
    stamp: int  # ns
    camera: int
    frame: int


def _stream(frames: int, seed: int = 0, skip: dict[int, set[int]] | None = None,
            latency: tuple[float, float] = (0.003, 0.015)) -> list[Event]:
    """Every camera's message of every frame (minus skip[camera]), in arrival order."""
    rng = random.Random(seed)
    events = []
    for f in range(frames):
        for c, offset in enumerate(OFFSETS_MS):
            if f in (skip or {}).get(c, set()):
                continue
            stamp = T0_NS + f * PERIOD_NS + round((offset + rng.uniform(-1.0, 1.0)) * MS)
            events.append(Event(stamp / 1e9 + rng.uniform(*latency), stamp, c, f))
    return sorted(events, key=lambda e: e.arrival)


@dataclass
class Released:
    at: float
    set: SyncedSet


def _run(sync: ApproximateSync, events: list[Event], tick: float = 0.010,
         tail: float = 2.0) -> list[Released]:
    """Feed events in arrival order with a timer calling expire() every `tick` s; then let the
    timer run `tail` s more (no flush: what is released must be released by the rules)."""
    out: list[Released] = []
    now = events[0].arrival if events else 0.0
    for e in events:
        while now + tick < e.arrival:
            now += tick
            out += [Released(now, s) for s in sync.expire(now)]
        now = e.arrival
        try:
            out += [Released(now, s) for s in sync.add(e.stamp, e.camera, (e.camera, e.frame), now)]
        except ValueError as exc:  # late or duplicate: counted by the sync, checked by the tests
            assert 'late' in str(exc) or 'duplicate' in str(exc)
    end = now + tail
    while now < end:
        now += tick
        out += [Released(now, s) for s in sync.expire(now)]
    return out


def _frames(released: list[Released]) -> list[dict[int, int]]:
    """Per set, {camera: frame} of its members."""
    return [{item[0]: item[1] for item in r.set.items if item is not None} for r in released]


def _check_invariants(released: list[Released], cameras: int = 5, max_skew_ns: int = 20 * MS) -> None:
    """S1 and S3 on every released set."""
    stamps = [r.set.stamp_ns for r in released]
    assert stamps == sorted(set(stamps))  # strictly increasing
    assert [r.set.index for r in released] == list(range(len(released)))
    for r in released:
        s = r.set
        present = [x for x in s.stamps if x is not None]
        assert len(s.items) == len(s.stamps) == cameras
        assert [c for c, x in enumerate(s.stamps) if x is None] == s.missing
        assert s.stamp_ns == min(present) and s.skew_ns == max(present) - min(present) <= max_skew_ns


def _sync(**kw) -> ApproximateSync:
    return ApproximateSync(5, timeout=kw.pop('timeout', TIMEOUT), max_skew=kw.pop('max_skew', MAX_SKEW), **kw)


def test_offsets_and_jitter_give_one_complete_set_per_frame():
    sync = _sync()
    events = _stream(200, seed=1)
    released = _run(sync, events)
    _check_invariants(released)
    assert _frames(released) == [{c: f for c in range(5)} for f in range(200)]
    assert max(r.set.skew_ns for r in released) <= 18 * MS  # 16 ms of offsets + 2 ms of jitter
    assert min(r.set.skew_ns for r in released) >= 14 * MS
    # S2: each set leaves when its last member arrives, not on a timer
    last_arrival = {}
    for e in events:
        last_arrival[e.frame] = max(last_arrival.get(e.frame, 0.0), e.arrival)
    assert all(r.at == last_arrival[f] for f, r in enumerate(released))
    assert sum(sync.dropped.values()) == 0 and sync.sets == 200


def test_a_camera_starting_late_within_the_timeout_holds_the_first_sets_until_it_is_heard():
    sync = _sync()
    events = _stream(40, seed=2, skip={3: set(range(5))})  # camera 3 starts at frame 5 (200 ms)
    released = _run(sync, events)
    _check_invariants(released)
    frames = _frames(released)
    assert frames == [{c: f for c in range(5) if not (c == 3 and f < 5)} for f in range(40)]
    first3 = next(e for e in events if e.camera == 3)
    # frames 0..4 wait for camera 3 (not silent yet, never past them) until its first message
    assert all(r.at == first3.arrival for r in released[:5]) and all(r.set.missing == [3] for r in released[:5])
    assert sum(sync.dropped.values()) == 0


def test_a_camera_starting_late_beyond_the_timeout_is_left_out_until_it_starts():
    sync = _sync()
    events = _stream(60, seed=3, skip={3: set(range(25))})  # camera 3 starts at frame 25 (1 s)
    released = _run(sync, events)
    _check_invariants(released)
    frames = _frames(released)
    assert len(frames) == 60 and [sorted(fr.values())[0] for fr in frames] == list(range(60))
    assert all(3 not in fr for fr in frames[:25]) and all(3 in fr for fr in frames[26:])
    # set 25 either has camera 3 or camera 3's first message came after the set went (late)
    assert (3 in frames[25]) == (sync.dropped['late'] == 0) and sync.dropped['late'] <= 1
    start = events[0].arrival
    for f, r in enumerate(released[:25]):
        # set 0 waits for camera 3 until start + timeout; camera 3 is then absent, and every set
        # goes without it once its grace (max_skew after its last member) has passed
        ready = max(e.arrival for e in events if e.frame == f) + (MAX_SKEW if f else 0.0)
        assert r.at == pytest.approx(max(ready, start + TIMEOUT), abs=0.0101)


def test_a_camera_that_has_sent_nothing_yet_holds_a_set_back_first_wait_at_most():
    """first_wait one frame period: camera 3, starting at frame 5, holds set 0 back one period
    after its last member and is then left out until it starts; a camera heard before is still
    waited for the timeout."""
    sync = _sync(first_wait=PERIOD_NS / 1e9)
    events = _stream(40, seed=2, skip={3: set(range(5)), 1: {20}})
    released = _run(sync, events)
    _check_invariants(released)
    frames = _frames(released)
    assert frames == [{c: f for c in range(5) if not (c == 3 and f < 5) and not (c == 1 and f == 20)}
                      for f in range(40)]
    last = max(e.arrival for e in events if e.frame == 0)
    assert released[0].at == pytest.approx(last + PERIOD_NS / 1e9, abs=0.0101)
    for f in range(1, 5):  # then absent: each set goes once its grace has passed
        ready = max(e.arrival for e in events if e.frame == f) + MAX_SKEW
        assert released[f].at == pytest.approx(ready, abs=0.0101)
    # camera 1, heard before, missing from frame 20: that set waits until its frame 21 comes
    assert released[20].at == min(e.arrival for e in events if e.camera == 1 and e.frame == 21)


def test_a_camera_dropping_three_frames_leaves_exactly_those_sets_without_it():
    sync = _sync()
    events = _stream(40, seed=4, skip={2: {10, 11, 12}})
    released = _run(sync, events)
    _check_invariants(released)
    frames = _frames(released)
    assert frames == [{c: f for c in range(5) if not (c == 2 and f in (10, 11, 12))} for f in range(40)]
    assert [r.set.missing for r in released[10:13]] == [[2]] * 3
    # released once camera 2 has moved past them: at the arrival of its frame 13
    back = next(e for e in events if e.camera == 2 and e.frame == 13)
    assert all(r.at == back.arrival for r in released[10:13])
    assert sum(sync.dropped.values()) == 0


def test_a_camera_gone_for_good_is_waited_for_once_then_left_out_without_delay():
    sync = _sync()
    events = _stream(60, seed=5, skip={4: set(range(20, 60))})
    released = _run(sync, events)
    _check_invariants(released)
    frames = _frames(released)
    assert frames == [{c: f for c in range(5) if not (c == 4 and f >= 20)} for f in range(60)]
    waited = min(e.arrival for e in events if e.frame == 20) + TIMEOUT  # set 20 waits once
    for f, r in enumerate(released):
        ready = max(e.arrival for e in events if e.frame == f)
        if f >= 20:
            grace = MAX_SKEW if f > 20 else 0.0
            assert r.at == pytest.approx(max(ready + grace, waited), abs=0.0101)
        else:
            assert r.at == ready
    # once it is absent, a set waits only the grace for it
    assert released[-1].at == pytest.approx(max(e.arrival for e in events) + MAX_SKEW, abs=0.0101)
    assert sync.absent == [4]


def test_sets_arriving_in_bursts_far_apart_stay_whole():
    """People from a detector that needs a second per set: every camera is quiet between bursts
    (far longer than the timeout), yet each burst is a whole set, released when it is complete."""
    sync = _sync()
    released = []
    for k in range(6):
        burst = 2.0 * k  # s
        stamp = T0_NS + k * 10 * PERIOD_NS
        for c in range(5):
            arrival = burst + 0.001 * c
            released += [Released(arrival, s) for s in sync.add(stamp + OFFSETS_MS[c] * MS, c, None, arrival)]
        released += [Released(burst + 0.1, s) for s in sync.expire(burst + 0.1)]
    assert [sorted(c for c, item in enumerate(r.set.stamps) if item is not None) for r in released] == \
        [list(range(5))] * 6
    assert [r.at for r in released] == [2.0 * k + 0.004 for k in range(6)] and sync.absent == []


def test_a_set_waits_at_most_the_timeout_for_a_camera_that_is_not_silent():
    """Camera 1 keeps sending, but far behind (stamps 1 s old): the others' sets go without it
    after the timeout, and its old messages are then late (counted)."""
    sync = _sync()
    events = [e for e in _stream(50, seed=6) if e.camera != 1]
    events += [Event(e.arrival + 1.0, e.stamp, 1, e.frame) for e in _stream(50, seed=6) if e.camera == 1]
    events.sort(key=lambda e: e.arrival)
    released = _run(sync, events)
    _check_invariants(released)
    assert all(r.set.missing == [1] for r in released)
    first_arrival = {}
    for e in events:
        first_arrival.setdefault(e.frame, e.arrival)
    assert all(r.at - first_arrival[f] <= TIMEOUT + 0.0101 for f, r in enumerate(released))
    assert sync.dropped['late'] == sync.dropped_by_camera[1]['late'] > 0
    assert len(released) + sync.dropped['late'] >= 50


def test_bursts_keep_every_set_whole_and_in_order():
    sync = _sync()
    events = _stream(30, seed=7)
    # all 30 frames of every camera arrive at one instant, cameras interleaved at random (each
    # camera's own messages in order)
    queues = [[Event(5.0, e.stamp, e.camera, e.frame) for e in events if e.camera == c] for c in range(5)]
    rng, burst = random.Random(8), []
    while any(queues):
        burst.append(rng.choice([q for q in queues if q]).pop(0))
    released = _run(sync, burst)
    _check_invariants(released)
    assert _frames(released) == [{c: f for c in range(5)} for f in range(30)]
    # one camera stalls 300 ms (< timeout) and then delivers its backlog at once
    sync = _sync()
    stalled = [Event(max(e.arrival, T0_NS / 1e9 + 0.3), e.stamp, e.camera, e.frame) if e.camera == 0 else e
               for e in _stream(30, seed=9)]
    released = _run(sync, sorted(stalled, key=lambda e: e.arrival))
    _check_invariants(released)
    assert _frames(released) == [{c: f for c in range(5)} for f in range(30)]
    assert sum(sync.dropped.values()) == 0


def test_out_of_order_duplicate_and_late_messages():
    sync = ApproximateSync(2, timeout=0.5, max_skew=0.010)
    assert sync.add(200 * MS, 0, 'b0', now=0.0) == []
    assert sync.add(100 * MS, 0, 'a0', now=0.001) == []  # out of order, but nothing released yet
    with pytest.raises(ValueError, match=r'camera 0 delivered stamp 200000000 ns twice \(duplicate\)'):
        sync.add(200 * MS, 0, 'b0 again', now=0.002)
    [a] = sync.add(105 * MS, 1, 'a1', now=0.003)
    assert (a.stamp_ns, a.items, a.stamps, a.skew_ns, a.index) == (100 * MS, ['a0', 'a1'], [100 * MS, 105 * MS],
                                                                   5 * MS, 0)
    with pytest.raises(ValueError, match='late'):
        sync.add(100 * MS, 0, 'a0 again', now=0.004)  # a duplicate of a released message
    with pytest.raises(ValueError, match='late'):
        sync.add(103 * MS, 1, 'older than its member', now=0.004)
    [b] = sync.add(195 * MS, 1, 'b1', now=0.005)
    assert (b.stamp_ns, b.items, b.skew_ns, b.index) == (195 * MS, ['b0', 'b1'], 5 * MS, 1)
    assert sync.dropped == {'duplicate': 1, 'late': 2}
    assert sync.dropped_by_camera[0] == {'duplicate': 1, 'late': 1} and sync.dropped_by_camera[1] == {'late': 1}
    with pytest.raises(ValueError, match='camera 2 is not in 0..1'):
        sync.add(300 * MS, 2, 'x', now=0.006)


def test_a_camera_without_a_message_in_the_window_is_missing_and_then_late():
    sync = ApproximateSync(2, timeout=0.5, max_skew=0.010)
    sync.add(100 * MS, 0, 'a0', now=0.0)
    [a] = sync.add(130 * MS, 1, 'c1', now=0.0)  # camera 1 moved past [100, 110] ms
    assert (a.stamp_ns, a.items, a.missing) == (100 * MS, ['a0', None], [1])
    with pytest.raises(ValueError, match=r'late: this camera is past 110000000 ns'):
        sync.add(108 * MS, 1, 'a1', now=0.01)  # in the released window
    assert sync.add(111 * MS, 1, 'between', now=0.01) == []  # after it: a set of its own
    [between, c] = sync.add(135 * MS, 0, 'c0', now=0.02)
    assert (between.items, between.missing) == ([None, 'between'], [0])
    assert (c.stamp_ns, c.items, c.skew_ns) == (130 * MS, ['c0', 'c1'], 5 * MS)


def test_min_cameras_drops_smaller_sets_as_unmatched():
    sync = ApproximateSync(3, timeout=0.5, max_skew=0.010, min_cameras=2)
    sync.add(100 * MS, 0, 'lonely', now=0.0)
    sync.add(200 * MS, 1, 'b1', now=0.0)
    assert sync.add(202 * MS, 0, 'b0', now=0.0) == []  # camera 2 has not moved past 100 ms yet
    released = sync.add(205 * MS, 2, 'b2', now=0.0)
    assert [(s.index, s.items) for s in released] == [(0, ['b0', 'b1', 'b2'])]
    assert sync.take_drops() == [Drop(0, 100 * MS, 'unmatched')] and sync.take_drops() == []
    assert sync.dropped == {'unmatched': 1}
    assert sync.take_lost() == [100 * MS] and sync.take_lost() == []


def test_a_set_short_of_min_cameras_is_one_lost_stamp_however_many_members_it_drops():
    """Two cameras of four reach a set (min_cameras 3): both messages are dropped, the set is
    lost once, at its pivot's (earliest) stamp; a camera's own partnerless drop elsewhere is a
    set of its own."""
    sync = ApproximateSync(4, timeout=0.5, max_skew=0.010, min_cameras=3)
    released = sync.add(104 * MS, 1, 'a1', now=0.0) + sync.add(100 * MS, 0, 'a0', now=0.0)
    for c in range(4):
        released += sync.add(200 * MS + c * MS, c, f'b{c}', now=0.1)
    released += sync.add(300 * MS, 2, 'c2', now=0.2) + sync.expire(now=1.0)
    assert [s.stamp_ns for s in released] == [200 * MS]
    assert sorted(d.stamp_ns for d in sync.take_drops()) == [100 * MS, 104 * MS, 300 * MS]
    assert sync.take_lost() == [100 * MS, 300 * MS]


def test_queue_overflow_drops_the_oldest_and_counts_it():
    sync = ApproximateSync(2, timeout=100.0, max_skew=0.010, queue_size=3)
    for k in range(5):  # camera 1 stamps 10 s ahead: never in camera 0's windows
        sync.add(10_000 * MS + k * 40 * MS, 1, k, now=0.0)
    assert sync.take_drops() == [Drop(1, 10_000 * MS, 'overflow'), Drop(1, 10_040 * MS, 'overflow')]
    [a] = sync.add(0, 0, 'a0', now=0.0)
    assert a.missing == [1]
    assert [s.items for s in sync.flush()] == [[None, 2], [None, 3], [None, 4]]


def test_flush_releases_everything_in_order():
    sync = _sync(timeout=100.0)
    for stamp in (300 * MS, 100 * MS, 200 * MS):
        sync.add(stamp, 1, stamp, now=0.0)
    assert [(s.stamp_ns, s.index) for s in sync.flush()] == [(100 * MS, 0), (200 * MS, 1), (300 * MS, 2)]
    assert sync.flush() == []


@pytest.mark.parametrize('seed', range(20))
def test_zero_skew_is_exact_synchronisation(seed):
    """S5: random streams (stamps on a shared timeline, cameras dropping and repeating frames,
    slightly out of order): the same sets, refusals and order as StampSync."""
    rng = random.Random(seed)
    cameras = rng.randint(1, 4)
    exact, ours = StampSync(cameras, timeout=1e9), ApproximateSync(cameras, timeout=1e9, max_skew=0.0)
    got_exact, got_ours = [], []
    for step in range(200):
        camera = rng.randrange(cameras)
        stamp = rng.randrange(0, 60) * PERIOD_NS + step // 4 * PERIOD_NS
        outcome = []
        for sync, got in ((exact, got_exact), (ours, got_ours)):
            try:
                got += [(f.stamp_ns, f.items, f.missing) for f in sync.add(stamp, camera, (camera, stamp), now=0.0)]
                outcome.append('ok')
            except ValueError:
                outcome.append('refused')
        assert outcome[0] == outcome[1]
    got_exact += [(f.stamp_ns, f.items, f.missing) for f in exact.flush()]
    got_ours += [(f.stamp_ns, f.items, f.missing) for f in ours.flush()]
    assert got_ours == got_exact and len(got_ours) > 0


def test_a_synced_set_is_a_synced_frame_for_the_node():
    assert ApproximateSync(2, timeout=0.5, max_skew=0.0).add(5, 0, 'x', now=0.0) == []  # waits for camera 1
    sync = ApproximateSync(1, timeout=0.5, max_skew=0.0)
    [s] = sync.add(5, 0, 'x', now=0.0)
    assert isinstance(s, SyncedFrame) and (s.stamp_ns, s.items, s.missing) == (5, ['x'], [])


@pytest.mark.parametrize('kw', [dict(cameras=0), dict(timeout=0.0), dict(max_skew=-0.001), dict(min_cameras=3),
                                dict(min_cameras=0), dict(queue_size=0), dict(first_wait=0.0)])
def test_bad_construction_is_refused(kw):
    args = dict(cameras=2, timeout=0.5, max_skew=0.02) | kw
    with pytest.raises(ValueError, match='ApproximateSync needs'):
        ApproximateSync(**args)


def test_an_absent_camera_coming_back_joins_within_the_grace_or_is_waited_for_after():
    """Camera 4 misses set 1 (the set goes without it after the timeout). Back at set 2, its image
    comes after the other cameras': within the grace (max_skew after the set's last member) it
    joins set 2; after the grace set 2 has gone without it, its image is late, and set 3 waits
    for it again (a late message says the camera is sending)."""
    for delay, set2_missing in ((0.5 * MAX_SKEW, []), (3 * MAX_SKEW, [4])):
        sync = _sync()
        released: list[SyncedSet] = []
        for k in range(4):
            stamp, now = T0_NS + k * PERIOD_NS, k * 1.0
            for c in range(4):
                released += sync.add(stamp, c, c, now)
            if k == 1:
                released += sync.expire(now + TIMEOUT)  # the wait for camera 4 runs out
            elif k == 2:
                released += sync.expire(now + delay - 0.001)
                if set2_missing:
                    released += sync.expire(now + delay)
                    with pytest.raises(ValueError, match='late'):
                        sync.add(stamp, 4, 4, now + delay)
                else:
                    released += sync.add(stamp, 4, 4, now + delay)
            else:
                released += sync.add(stamp, 4, 4, now)
        assert [s.missing for s in released] == [[], [4], set2_missing, []] and sync.absent == []


def test_the_rate_of_cameras_from_their_stamps_ignores_drops_late_starts_and_order():
    ms = 1_000_000
    steady = [k * 66_667 * 1000 for k in range(30)]  # 15 Hz
    dropped = [t + 3 * ms for k, t in enumerate(steady) if k % 7 != 3]  # offset, a frame dropped every 7
    late = steady[12:][::-1]  # started late, stamps out of order
    assert stamp_rate([steady, dropped, late]) == pytest.approx(15.0, rel=1e-3)
    assert stamp_rate([[0, 40 * ms], [5 * ms]]) is None  # fewer than three stamps: no interval to trust
    assert stamp_rate([]) is None
