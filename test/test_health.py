"""core.health: input and node statuses by the documented thresholds, the per-camera
reprojection residual (a bumped camera, and only it, goes WARN), and the diagnostics message."""
from __future__ import annotations

import numpy as np
import pytest
from builtin_interfaces.msg import Time

from msg_adapters.diagnostics_msg import msg_to_statuses, statuses_to_msg
from mvpose_ros.core.association.approximate_sync import stamp_rate
from mvpose_ros.core.datasets.shelf_campus import SHELF_TEST_FRAMES
from mvpose_ros.core.detection.openpose import OpenPoseFrame
from mvpose_ros.core.detection.openpose_detector import OpenPoseDetectorConfig, detect_people
from mvpose_ros.core.geometry.bump import axis_rotation, bumped_camera, bumped_pixels
from mvpose_ros.core.health.links import links_status, unmatched_links
from mvpose_ros.core.health.monitor import InputMonitor, NodeMonitor, frame_rate_status, input_statuses, node_status
from mvpose_ros.core.health.residual import ResidualMonitor, frame_residuals, residual_levels
from mvpose_ros.core.health.status import Level, Status
from mvpose_ros.core.health.thresholds import HealthThresholds, health_parameters
from mvpose_ros.core.parameters import Param
from mvpose_ros.core.stage import Stage3D, StageConfig

T = HealthThresholds()


def _inputs(rates: list[float], until: float, stop: dict[int, float] | None = None) -> list[InputMonitor]:
    """Monitors of cameras sending at `rates` Hz from 0 to `until` s (camera c stops at stop[c])."""
    monitors = [InputMonitor(f'cam{c}', 0.0) for c in range(len(rates))]
    for c, rate in enumerate(rates):
        for t in np.arange(0.0, min(until, (stop or {}).get(c, until)), 1 / rate):
            monitors[c].received(float(t), int(t * 1e9))
    return monitors


def _levels(monitors: list[InputMonitor], now: float, t: HealthThresholds = T) -> list[Level]:
    return [s.level for s in input_statuses('association', [m.stats(now, t.window) for m in monitors], t)]


def test_inputs_sending_at_the_same_rate_are_ok():
    monitors = _inputs([25.0] * 5, 10.0)
    statuses = input_statuses('association', [m.stats(10.0, T.window) for m in monitors], T)
    assert [s.level for s in statuses] == [Level.OK] * 5
    assert statuses[0].name == 'association: input cam0' and statuses[0].values['rate (Hz)'] == '25.00'


def test_a_camera_that_stops_while_the_others_send_is_error_after_stale_error():
    before = 6.0 + T.stale_error - 0.1
    assert _levels(_inputs([25.0] * 5, before, stop={3: 6.0}), before) == [Level.OK] * 5
    monitors = _inputs([25.0] * 5, 10.0, stop={3: 6.0})
    levels = _levels(monitors, 10.0)
    assert levels == [Level.OK, Level.OK, Level.OK, Level.ERROR, Level.OK]
    status = input_statuses('association', [m.stats(10.0, T.window) for m in monitors], T)[3]
    assert status.message.startswith('no message for 4.0 s while cam0, cam1, cam2, cam4 send')


def test_every_input_silent_is_only_warn_and_a_slow_camera_is_warn():
    monitors = _inputs([25.0] * 3, 10.0)
    assert _levels(monitors, 20.0) == [Level.WARN] * 3  # idle (the end of a replay), nobody singled out
    slow = _inputs([25.0, 25.0, 10.0], 10.0)
    assert _levels(slow, 10.0) == [Level.OK, Level.OK, Level.WARN]  # 10 Hz < 0.5 x 25 Hz


def test_typical_interval_is_the_median_gap_of_the_window_and_ignores_bursts_and_older_arrivals():
    monitor = _inputs([25.0], 10.0)[0]
    assert monitor.typical_interval(10.0, 5.0) == pytest.approx(0.04)
    for t in (10.0, 10.001, 10.002):  # a burst after a stall moves the median little
        monitor.received(t)
    assert monitor.typical_interval(10.0, 5.0) == pytest.approx(0.04)
    assert monitor.typical_interval(20.0, 5.0) is None  # nothing in the window: no pace known
    slow = _inputs([2.0], 10.0)[0]
    assert slow.typical_interval(10.0, 5.0) == pytest.approx(0.5)
    assert InputMonitor('cam0', 0.0).typical_interval(1.0, 5.0) is None


def test_the_cameras_rate_is_taken_from_their_stamps_and_judged_against_frame_rate():
    # a replay at twice real time: arrivals 20 ms apart, stamps 40 ms apart (25 Hz cameras)
    monitors = [InputMonitor(f'cam{c}', 0.0) for c in range(3)]
    for k in range(200):
        for c, m in enumerate(monitors):
            m.received(k * 0.02, 1_000_000_000 + k * 40_000_000 + c * 3_000_000)
    now = 199 * 0.02
    assert len(monitors[0].stamps(now, 1.0)) == 51  # the last second's, by arrival (both ends in)
    rate = stamp_rate([m.stamps(now, T.window) for m in monitors])
    assert rate == pytest.approx(25.0)
    ok = frame_rate_status('rig/heatmap_detector', rate, 25.0)
    assert ok.level == Level.OK and ok.name == 'rig/heatmap_detector: frame_rate'
    assert frame_rate_status('n', rate, 27.0).level == Level.OK  # within 10 %
    off = frame_rate_status('n', 15.0, 25.0)
    assert off.level == Level.WARN and 'the cameras run at 15.0 Hz (their stamps), the frame_rate parameter is ' \
        '25 Hz' in off.message and 'set it to 15.0' in off.message
    assert off.values == {'camera rate from stamps (Hz)': '15.00', 'frame_rate parameter (Hz)': '25'}
    unknown = frame_rate_status('n', None, 25.0)  # fewer than three stamps of any camera
    assert unknown.level == Level.OK and 'not known yet' in unknown.message
    assert stamp_rate([InputMonitor('cam0', 0.0).stamps(1.0, 5.0)]) is None


def test_drops_above_the_thresholds_are_warn_then_error():
    monitors = _inputs([25.0] * 2, 10.0)
    for k in range(10):  # 10 of the last 125 messages: 8 %
        monitors[1].dropped(9.0 + k * 0.05, 'late')
    assert _levels(monitors, 10.0) == [Level.OK, Level.WARN]
    for k in range(60):
        monitors[1].dropped(9.5, 'malformed')
    status = input_statuses('association', [m.stats(10.0, T.window) for m in monitors], T)[1]
    assert status.level == Level.ERROR and 'late 10, malformed 60' in status.message
    assert status.values['late in window'] == '10'


def test_node_latency_levels_and_a_replayed_clock_is_not_judged():
    monitor = NodeMonitor()
    for k in range(10):
        monitor.processed(float(k), {'bp': 0.004, 'sampling': 0.010})
        monitor.delivered(float(k), 0.12, 1.7e9)  # a 1970 stamp on today's clock: not judged
    status = node_status('bp_solver', monitor.stats(9.0, T.window), 3, T)
    assert status.level == Level.OK and status.values['bp (ms per item)'] == '4.00'
    assert status.values['queue depth'] == '3'
    assert 'not judged' in status.values['latency from capture stamp (ms, median / max)']
    slow = NodeMonitor()
    for k in range(10):
        slow.delivered(float(k), 0.1, 2.0 if k < 5 else 9.0)  # capture latency median 5.5 s
    assert node_status('x', slow.stats(9.0, 10.0), 0, T).level == Level.ERROR
    assert node_status('x', slow.stats(9.0, 10.0), 0, HealthThresholds(latency_error=10.0)).level == Level.WARN


def _cloud(rng: np.random.Generator) -> np.ndarray:
    """(P, 14, 3) people standing in the middle of the Shelf room."""
    return np.array([0.0, 0.0, 1.0]) + rng.uniform(-0.8, 0.8, (3, 1, 3)) * [1, 1, 0] + rng.normal(0, 0.3, (3, 14, 3))


def _bundles(cameras, joints: np.ndarray, noise: float, rng: np.random.Generator):
    from mvpose_ros.core.types import Person2D
    out = []
    for p, person in enumerate(joints):
        views = {}
        for c, cam in enumerate(cameras):
            kp = np.zeros((16, 3))
            kp[:14, :2] = cam.project(person) + rng.normal(0, noise, (14, 2))
            kp[:14, 2] = 0.9
            views[c] = Person2D.from_keypoints(kp, 8.0, 6.0)
        out.append((p, views))
    return out


def test_a_bumped_camera_and_only_it_has_a_high_residual(shelf_rig):
    rng = np.random.default_rng(0)
    monitor = ResidualMonitor(len(shelf_rig), 20)
    bumped = bumped_camera(shelf_rig[2], axis_rotation('y', 2.0))
    for frame in range(40):
        joints = _cloud(rng)
        seen = list(shelf_rig)
        if frame >= 20:
            seen[2] = bumped  # the detections come from the turned camera, the calibration stays
        residuals = frame_residuals(shelf_rig, [0, 1, 2], joints, _bundles(seen, joints, 3.0, rng), 0.3)
        monitor.add(residuals)
        if frame == 19:
            medians, counts = monitor.medians()
            assert all(level == Level.OK for level, _ in residual_levels(medians, T.residual_ratio,
                                                                         T.residual_floor))
            assert np.all(medians < 6) and np.all(counts == 20)
    medians, _ = monitor.medians()
    levels = residual_levels(medians, T.residual_ratio, T.residual_floor)
    assert [level for level, _ in levels] == [Level.OK, Level.OK, Level.WARN, Level.OK, Level.OK]
    assert medians[2] > 25 and 'moved out of its calibration' in levels[2][1]


def test_residual_levels_need_both_the_ratio_and_the_floor():
    assert [lv for lv, _ in residual_levels(np.array([4.0, 5.0, 9.0]), 2.0, 10.0)] == [Level.OK] * 3  # < floor
    assert [lv for lv, _ in residual_levels(np.array([40.0, 50.0, 90.0]), 2.0, 10.0)] == [Level.OK] * 3  # < ratio
    assert [lv for lv, _ in residual_levels(np.array([4.0, np.nan, 30.0]), 2.0, 10.0)] == [Level.OK, Level.OK,
                                                                                           Level.WARN]


@pytest.mark.parametrize('bumped', [None, 2])
def test_on_shelf_a_camera_turned_2_degrees_goes_warn_within_about_a_second(shelf_openpose, bumped):
    """The real Shelf detections through the graph's 3D stage; camera 2 turned 2 degrees from
    frame 450 on (its detections moved, its calibration not): only it goes WARN, within 50 frames."""
    cameras, raw = shelf_openpose
    turned = bumped_camera(cameras[2], axis_rotation('y', 2.0))
    stage = Stage3D(cameras, StageConfig.from_params({'window': 6, 'lag': 3, 'bp_hypotheses': 16}))
    detector = OpenPoseDetectorConfig(stride=8.0)
    monitor = ResidualMonitor(len(cameras), T.residual_frames)
    pending, warned = {}, {}
    for i, f in enumerate(range(420, 520)):
        people = []
        for c in range(len(cameras)):
            frame = raw[c][f - SHELF_TEST_FRAMES.start]
            if c == bumped and f >= 450:
                frame = OpenPoseFrame([np.column_stack([bumped_pixels(cameras[c], turned, x[:, :2]), x[:, 2]])
                                       for x in frame.candidates], frame.pafs)
            people.append(detect_people(frame, detector))
        pending[i] = stage.associate(i, people)
        for result in stage.solver.push(i, pending[i]):
            monitor.add(frame_residuals(cameras, result.person_ids, result.joints, pending.pop(result.frame),
                                        T.residual_min_score))
            levels = residual_levels(monitor.medians()[0], T.residual_ratio, T.residual_floor)
            for c, (level, _) in enumerate(levels):
                if level == Level.WARN:
                    warned.setdefault(c, 420 + result.frame)
    if bumped is None:
        assert warned == {}
    else:
        assert list(warned) == [2] and 450 < warned[2] <= 500


def test_bumped_pixels_turn_the_image_by_the_angle(shelf_rig):
    cam = shelf_rig[0]
    centre = cam.K[:2, 2]
    moved = bumped_pixels(cam, bumped_camera(cam, axis_rotation('y', 2.0)), centre)
    assert abs(abs(moved[0] - centre[0]) - cam.K[0, 0] * np.tan(np.radians(2.0))) < 2.0  # a pan: along u
    assert abs(moved[1] - centre[1]) < 1.0
    np.testing.assert_allclose(bumped_pixels(cam, bumped_camera(cam, np.eye(3)), centre), centre, atol=1e-6)


def test_thresholds_are_parameters_with_ranges_and_the_message_round_trips():
    specs = {p.name: p for p in health_parameters(residual=True)}
    assert specs['diagnostics.stale_error'].default == T.stale_error and specs['diagnostics.stale_error'].live
    assert not specs['diagnostics.period'].live and 'diagnostics.residual_ratio' not in {
        p.name for p in health_parameters()}
    assert HealthThresholds.from_params({'diagnostics.window': 9.0, 'other': 1}).window == 9.0
    with pytest.raises(ValueError, match='needs a range'):
        Param('x', 1.0, 'no range')
    with pytest.raises(ValueError, match='outside'):
        Param('x', 5, 'out', 0, 1)
    statuses = [Status('a: input cam0', Level.ERROR, 'no message', {'rate (Hz)': '0.00'}, 'cam0'),
                Status('a: node', Level.OK, 'fine')]
    msg = statuses_to_msg(statuses, statuses_to_msg([], None).header.stamp)
    assert msg.status[0].level == b'\x02' and msg_to_statuses(msg) == statuses
    msg.status[1].level = b'\x07'
    with pytest.raises(ValueError, match='level 7'):
        msg_to_statuses(msg)


def test_links_statuses_tell_which_link_between_two_nodes_is_not_matched_yet():
    """The runner plays once every link it sees is matched at both ends: a writer that has not
    matched every reader, a reader not every writer, or a node not heard from holds it back."""
    seen = {'/cam0/people2d': (1, 1), '/bundles': (1, 2)}  # topic -> (writers, readers) in the graph

    def statuses(people_readers: int, people_writers: int, bundles_readers: int) -> list[Status]:
        return [links_status('cam0/heatmap_detector', {'/cam0/people2d': people_readers}, {'/cam0/openpose': 1}),
                links_status('association', {'/bundles': bundles_readers}, {'/cam0/people2d': people_writers}),
                links_status('bp_solver', {'/skeletons': 0}, {'/bundles': 1}),
                links_status('lockstep', {}, {'/bundles': 1})]

    assert unmatched_links(statuses(1, 1, 2), seen) == []
    assert unmatched_links(statuses(0, 1, 2), seen) == ['/cam0/people2d: a writer has matched 0 of 1 readers']
    assert unmatched_links(statuses(1, 0, 2), seen) == ['/cam0/people2d: a reader has matched 0 of 1 writers']
    assert unmatched_links(statuses(1, 1, 1), seen) == ['/bundles: a writer has matched 1 of 2 readers']
    assert unmatched_links(statuses(1, 1, 2)[:1], seen) == ['/cam0/people2d: no reader has reported its links yet',
                                                            '/bundles: no writer has reported its links yet',
                                                            '/bundles: no reader has reported its links yet']
    # through the diagnostics message, as the runner reads it, with the other statuses beside
    other = Status('association: node', Level.OK, '25 items/s', {'queue depth': '0'})
    msg = statuses_to_msg([other, *statuses(0, 1, 2)], Time())
    assert unmatched_links(msg_to_statuses(msg), seen) == ['/cam0/people2d: a writer has matched 0 of 1 readers']


def test_a_person_one_camera_alone_sees_says_nothing_of_its_calibration(shelf_rig):
    """A bundle of one view (single_view_people): its 3D person comes from that view alone, so it is left
    out of the residuals: the bumped camera's residual is that of its people seen twice or more."""
    rng = np.random.default_rng(1)
    joints = _cloud(rng)
    seen = list(shelf_rig)
    seen[2] = bumped_camera(shelf_rig[2], axis_rotation('y', 2.0))
    bundles = _bundles(seen, joints, 3.0, rng)
    both = frame_residuals(shelf_rig, [0, 1, 2], joints, bundles, 0.3)
    alone = [(pid, {2: views[2]}) for pid, views in bundles[:2]] + bundles[2:]
    only_third = frame_residuals(shelf_rig, [0, 1, 2], joints, alone, 0.3)
    assert both[2] > 25 and only_third[2] > 25
    np.testing.assert_allclose(only_third[2], frame_residuals(shelf_rig, [2], joints[2:], bundles[2:], 0.3)[2])
