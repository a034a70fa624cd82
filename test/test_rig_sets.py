"""Whole-rig set handling without ROS (core.detection.rig_sets): sets detected one at a time in
stamp order on the worker, only the newest waiting while one is detected (the older ones dropped
whole and announced lost), inputs left out of every set reported with their cause, a set that
reaches no camera announced, a failing set reported without stopping the worker."""
from __future__ import annotations

import threading
from types import SimpleNamespace

import numpy as np
import pytest

from mvpose_ros.core.detection.rig_sets import RigSets, SetCallbacks, SetSettings, without_numbers
from mvpose_ros.core.health.monitor import InputMonitor, NodeMonitor
from mvpose_ros.core.throttled_log import ThrottledLog

MS = 1_000_000
SETTINGS = SetSettings(frame_rate=25.0, sync_timeout=0.5, max_skew=0.02, min_cameras=1, waiting_sets=1)


class _Calls:
    """The callbacks, recorded; detect waits for `go` and sends `sent` cameras (or raises)."""

    def __init__(self, sent: int = 2) -> None:
        self.sent, self.go, self.busy = sent, threading.Event(), threading.Event()
        self.detected, self.dropped, self.lost, self.delivered, self.errors = [], [], [], [], []
        self.go.set()
        self.idle = threading.Semaphore(0)

    def detect(self, synced):
        self.busy.set()
        self.go.wait(10.0)
        self.detected.append(synced.stamp_ns)
        if self.sent < 0:
            raise RuntimeError('a bug in one set')
        return self.sent

    def callbacks(self) -> SetCallbacks:
        def delivered(stamps, released, seconds):
            self.delivered.append(stamps)
            self.idle.release()
        return SetCallbacks(self.detect, lambda c, s, cause: self.dropped.append((c, s, cause)), self.lost.append,
                            delivered, self.errors.append)


def _sets(calls: _Calls, settings: SetSettings = SETTINGS, cameras: int = 2) -> RigSets:
    log = ThrottledLog(SimpleNamespace(error=lambda *_: None, warning=lambda *_: None, info=lambda *_: None))
    return RigSets(settings, [InputMonitor(f'c{c}', 0.0) for c in range(cameras)], NodeMonitor(), log,
                   calls.callbacks())


def test_whole_sets_are_detected_in_stamp_order():
    calls = _Calls()
    sets = _sets(calls, SetSettings(25.0, 0.5, 0.02, min_cameras=1, waiting_sets=3))  # a replay's: none lost
    try:
        for frame in range(3):
            for camera in range(2):
                sets.add(camera, (frame * 40 + camera) * MS, f'{frame}/{camera}', 0.01 * frame)
        sets.expire(10.0)
        for _ in range(3):
            assert calls.idle.acquire(timeout=10.0)
        assert calls.detected == [0, 40 * MS, 80 * MS] and not calls.lost and not calls.dropped
        assert calls.delivered[0] == [0, 1 * MS]
        assert sets.statistics() == {'sets released': '3', 'sets detected': '3',
                                     'sets dropped whole while detecting': '0'}
    finally:
        assert sets.close().startswith('sets: 3 released, 3 detected, 0 dropped whole while detecting')


def test_while_one_set_is_detected_only_the_newest_waits_and_the_older_ones_are_lost():
    calls = _Calls()
    calls.go.clear()
    sets = _sets(calls)
    try:
        for frame in range(4):
            for camera in range(2):
                sets.add(camera, frame * 40 * MS, 'x', 0.0)
            if frame == 0:
                assert calls.busy.wait(10.0)  # the worker holds the first set
        sets.expire(10.0)
        assert calls.lost == [40 * MS, 80 * MS] and sets.waiting.dropped == 2  # set 3 waits, 1 and 2 were dropped
        calls.go.set()
        assert calls.idle.acquire(timeout=10.0) and calls.idle.acquire(timeout=10.0)
        assert calls.detected == [0, 120 * MS]
    finally:
        sets.close()


def test_inputs_out_of_every_set_are_reported_and_a_set_that_reaches_no_camera_is_lost():
    calls = _Calls(sent=0)  # every camera's input unusable
    sets = _sets(calls, SetSettings(25.0, 0.5, 0.02, min_cameras=2, waiting_sets=1))
    try:
        sets.add(0, 0, 'a', 0.0)  # camera 1 never sends frame 0
        sets.add(0, 40 * MS, 'b', 0.01)
        sets.add(1, 40 * MS, 'c', 0.02)
        sets.add(1, 40 * MS, 'c', 0.03)  # again
        assert calls.idle.acquire(timeout=10.0)
        assert calls.dropped[0] == (0, 0, 'not synchronised (unmatched): its set had fewer than min_cameras cameras')
        assert calls.dropped[1][:2] == (1, 40 * MS) and calls.dropped[1][2].startswith('not synchronised (late): ')
        assert calls.lost == [0, 40 * MS]  # the unmatched set's stamp, then the set detected for no camera
    finally:
        sets.close()


def test_a_set_that_raises_is_reported_and_the_worker_goes_on():
    calls = _Calls(sent=-1)
    sets = _sets(calls, SetSettings(25.0, 0.5, 0.02, min_cameras=1, waiting_sets=2), cameras=1)
    try:
        sets.add(0, 0, 'a', 0.0)
        sets.add(0, 40 * MS, 'b', 0.04)
        sets.expire(10.0)
        for _ in range(50):
            if len(calls.errors) == 2:
                break
            threading.Event().wait(0.1)
        assert len(calls.errors) == 2 and 'set 0: Traceback' in calls.errors[0]
        assert 'a bug in one set' in calls.errors[0]
        assert sets.processed == 0 and not calls.delivered
    finally:
        sets.close()


def test_settings_and_live_changes_are_checked():
    with pytest.raises(ValueError, match=r'1 <= min_cameras <= 2 .* got 0.5, 0.02, 3, 1'):
        _sets(_Calls(), SetSettings(25.0, 0.5, 0.02, min_cameras=3, waiting_sets=1))
    sets = _sets(_Calls())
    try:
        assert sets.sync_settings({'max_skew': 0.01}) == (0.5, 0.01)
        with pytest.raises(ValueError):
            sets.retune({'sync_timeout': 0.0})
        sets.retune({'sync_timeout': 0.25})
        assert sets.sync.timeout == 0.25
    finally:
        sets.close()
    assert without_numbers('stamp 123 ns (45): late') == 'stamp <n> ns <n> late'


class _Detector:
    """What ImageSetDetector uses of OnnxPoseDetector: its workers, reduced_decoding, detect_set."""

    config = SimpleNamespace(multipose_workers=2)

    def __init__(self) -> None:
        self.calls = []

    def reduced_decoding(self, width: int, height: int, boxes=None) -> int:
        return 2 if boxes is None else 4  # 4: from the camera's planned crops

    def detect_set(self, images, boxes, previous, sizes, turns):
        self.calls.append((images, boxes, sizes, turns))
        return [None if image is None else [] for image in images]


def test_a_set_of_images_is_decoded_side_by_side_then_detected_once():
    from mvpose_ros.core.detection.image_sets import TRACK_MAX_AGE_S, ImageSetDetector
    from mvpose_ros.core.datasets.shelf_campus import shelf_cameras
    cameras = shelf_cameras()[:3]
    detector = _Detector()

    def decode(c, item, reduce):
        if item == 'junk':
            raise ValueError('not a JPEG or PNG')
        return (item, reduce)

    images = ImageSetDetector(detector, cameras, every=3)
    try:
        found, errors = images.detect(0, ['a', None, 'junk'], cameras, [0, 0, 2], decode)
        assert found == [[], None, None] and [(c, str(e)) for c, e in errors] == [(2, 'not a JPEG or PNG')]
        ((decoded, boxes, sizes, turns),) = detector.calls
        assert decoded == [('a', 2), None, None] and boxes == [None] * 3 and turns == [0, 0, 2]
        assert sizes == [(c.width, c.height) for c in cameras]
        assert images.tracking and TRACK_MAX_AGE_S == 1.0
        # skeletons known: at the next set camera 2 searches its whole image in turn, cameras 0 and
        # 1 are decoded as far as their planned crops allow
        from mvpose_ros.core.datasets.shelf_campus import dataset_dir, load_actors_gt
        actors = load_actors_gt(dataset_dir('shelf') / 'actorsGT.mat', [572]).poses[0]
        actors = actors[np.isfinite(actors).all(axis=(1, 2))]
        images.track(0, actors, np.arange(len(actors)))
        images.detect(1, ['a', 'b', 'c'], cameras, [0, 0, 0], decode)
        decoded, boxes = detector.calls[-1][:2]
        assert [b is None for b in boxes] == [False, False, True] and decoded == [('a', 4), ('b', 4), ('c', 2)]
    finally:
        images.close()
    untracked = ImageSetDetector(detector, cameras)
    untracked.detect(0, ['a', 'b', 'c'], cameras, [0, 0, 0], decode)
    assert detector.calls[-1][1] is None and not untracked.tracking  # no plan: MultiPose on every image
    untracked.close()
