"""Each processing node as its own process, fed real Shelf data by an in-test probe node over
DDS: one output per good input frame, the same numbers as the ROS-free core, and bad input
logged with a reason while the node keeps going."""
from __future__ import annotations

import dataclasses
import re
import time
from typing import Callable

import numpy as np
import pytest
from builtin_interfaces.msg import Time
from rclpy.publisher import Publisher
from rclpy.serialization import serialize_message
from sensor_msgs.msg import CameraInfo, PointCloud2, PointField
from std_msgs.msg import Header
from visualization_msgs.msg import MarkerArray

from msg_adapters.camera_info_msg import camera_to_info
from msg_adapters.cdr_header import CLOUD_OVERHEAD
from msg_adapters.openpose_msg import max_openpose_bytes, openpose_to_msg
from msg_adapters.people_msg import bundles_to_msg, max_people_bytes, msg_to_bundles, msg_to_people, people_to_msg
from msg_adapters.skeleton_msg import msg_to_skeletons
from msg_adapters.stamp import frame_of_stamp, stamp_ns, stamp_of_frame
from mvpose_ros.core.association.associator import AssociationConfig, Associator
from mvpose_ros.core.defaults import FRAME_RATE
from mvpose_ros.core.detection.openpose_detector import OpenPoseDetectorConfig, detect_people
from mvpose_ros.core.inference.solver import Inference3D
from mvpose_ros.core.stage import StageConfig
from mvpose_ros.nodes.runtime import DATA_QOS
from ros_harness import NodeLinks, matched, node_env, probe, spin_until, start_node, stop

FIRST = 300  # first frame of the OpenPose files
# association at frame_rate 1 with the 25 Hz max_skew: a camera not heard yet is waited 1 s, not a
# 25 Hz period, so that a burst of people2d a loaded machine spreads out still gives whole sets
SLOW_FIRST_SET = ('-p', 'frame_rate:=1.0', '-p', 'max_skew:=0.02')


@pytest.fixture(scope='module')
def shelf(shelf_openpose):
    cameras, raw = shelf_openpose
    return cameras, [frames[:16] for frames in raw]


def _header(frame: int, frame_id: str) -> Header:
    return Header(stamp=stamp_of_frame(frame), frame_id=frame_id)


def _collect(node, topic: str, msg_type, into: dict):
    """Subscribe `into` (frame -> messages of that frame); returns the subscription."""
    def keep(m) -> None:
        stamp = m.header.stamp if hasattr(m, 'header') else m.markers[0].header.stamp
        into.setdefault(frame_of_stamp(stamp), []).append(m)
    return node.create_subscription(msg_type, topic, keep, DATA_QOS)


def test_heatmap_detector_turns_raw_openpose_into_people_and_logs_bad_frames(domain, shelf, tmp_path):
    cameras, raw = shelf
    log = tmp_path / 'detector.log'
    with probe(domain, 'detector_probe') as (node, executor):
        out: dict[int, list] = {}
        sub = _collect(node, '/cam1/people2d', PointCloud2, out)
        pub = node.create_publisher(PointCloud2, '/cam1/openpose', DATA_QOS)
        info = node.create_publisher(CameraInfo, '/cam1/camera_info', DATA_QOS)
        links = NodeLinks(node)
        proc = start_node('heatmap_detector', domain, log, '-r', '__ns:=/cam1', '-p', 'camera:=1')
        try:
            assert spin_until(executor, lambda: matched([pub, info, sub])
                              and links.reads('cam1/heatmap_detector', '/cam1/openpose')), log.read_text()
            info.publish(camera_to_info(cameras[1], _header(300, 'cam1')))  # agrees: nothing said
            wrong = camera_to_info(dataclasses.replace(cameras[1], K=cameras[1].K * [[1.1], [1], [1]]),
                                   _header(301, 'cam1'))
            # camera_info is a best-effort subscription: what is sent before it has matched this
            # writer is lost, so the wrong info goes out until the node has said so (once)
            assert spin_until(executor, lambda: info.publish(wrong) or 'contradicts' in log.read_text()), \
                log.read_text()
            info.publish(wrong)  # the same problem again: said once
            for f in (300, 301, 302):
                pub.publish(openpose_to_msg(raw[1][f - FIRST], _header(f, 'cam1')))
            pub.publish(openpose_to_msg(raw[1][303 - FIRST], _header(303, 'cam7')))  # not this camera
            pub.publish(PointCloud2(header=_header(304, 'cam1'), fields=[PointField(name='x', datatype=7, count=1)]))
            # serialised junk, refused before it is deserialised: cut short, and over the size bound
            real = serialize_message(openpose_to_msg(raw[1][304 - FIRST], _header(304, 'cam1')))
            pub.publish(real[:-7])
            big = PointCloud2(header=_header(304, 'cam1'), data=bytes(max_openpose_bytes() + CLOUD_OVERHEAD))
            pub.publish(serialize_message(big))
            pub.publish(b'\x07\x07' + real[2:])  # no CDR header
            pub.publish(openpose_to_msg(raw[1][305 - FIRST], _header(305, 'cam1')))
            assert spin_until(executor, lambda: 305 in out), log.read_text()
            spin_until(executor, lambda: False, 0.5)
        finally:
            stop(proc)
    assert sorted(out) == [300, 301, 302, 305] and all(len(v) == 1 for v in out.values())
    for f, [msg] in out.items():
        assert msg.header.frame_id == 'cam1'
        expected = detect_people(raw[1][f - FIRST], OpenPoseDetectorConfig())
        got = msg_to_people(msg)
        assert len(got) == len(expected) > 0
        for a, b in zip(got, expected):
            np.testing.assert_allclose(a.keypoints, b.keypoints, rtol=1e-6, atol=1e-4)
    text = log.read_text()
    assert "stamp 12120000000 ns dropped: frame_id 'cam7' is not 'cam1'; set frame_id: cam7 in the rig file" in text
    assert 'stamp 12160000000 ns dropped' in text
    assert 'stamp 12160000000 ns dropped: failed to deserialize' in text
    assert f'more than one image can have ({max_openpose_bytes()} data bytes)' in text
    assert 'openpose with no readable stamp dropped: not a plain CDR message' in text
    # the CameraInfo that contradicts the calibration parameter: named, once; the node goes on
    assert text.count('contradicts the calibration parameter: CameraInfo fx') == 1, text
    assert 'camera_info stamp 12040000000 ns' in text and 'camera_info stamp 12000000000' not in text


def test_whole_rig_detector_announces_a_set_short_of_min_cameras_on_skeletons_dropped(domain, shelf, tmp_path):
    """One heatmap_detector for the whole Shelf rig (camera all, min_cameras 2): frame 302 comes
    from camera 0 alone, so its set is dropped as unmatched and its stamp published on
    skeletons/dropped, once, in the world frame; the other sets go out from every camera (all wait
    their turn: waiting_sets 8)."""
    cameras, raw = shelf
    frames = (300, 301, 302, 303)
    log = tmp_path / 'detector.log'
    with probe(domain, 'rig_detector_probe') as (node, executor):
        out: list[dict[int, list]] = [{} for _ in range(5)]
        for c in range(5):
            _collect(node, f'/cam{c}/people2d', PointCloud2, out[c])
        lost: list[Header] = []
        node.create_subscription(Header, '/skeletons/dropped', lost.append, DATA_QOS)
        pubs = [node.create_publisher(PointCloud2, f'/cam{c}/openpose', DATA_QOS) for c in range(5)]
        proc = start_node('heatmap_detector', domain, log, '-p', 'camera:=all', '-p', 'min_cameras:=2',
                          '-p', 'max_skew:=0.005', '-p', 'sync_timeout:=5.0', '-p', 'waiting_sets:=8',
                          '-p', 'frame_rate:=1.0')  # a camera not heard yet waited 1 s: a burst stays whole
        try:
            assert spin_until(executor, lambda: all(p.get_subscription_count() for p in pubs)), log.read_text()
            for f in frames:
                for c in range(5):
                    if f != 302 or c == 0:
                        pubs[c].publish(openpose_to_msg(raw[c][f - FIRST], _header(f, f'cam{c}')))
            assert spin_until(executor, lambda: all(303 in o for o in out) and lost), log.read_text()
            spin_until(executor, lambda: False, 0.5)
        finally:
            stop(proc)
    assert all(sorted(o) == [300, 301, 303] for o in out), [sorted(o) for o in out]
    assert [(stamp_ns(m.stamp), m.frame_id) for m in lost] == [(stamp_ns(stamp_of_frame(302)), 'world')]


def test_heatmap_detector_with_a_bad_parameter_exits_2_with_one_line(domain, tmp_path):
    log = tmp_path / 'bad.log'
    proc = start_node('heatmap_detector', domain, log, '-p', 'camera:=9')
    assert proc.wait(30) == 2
    assert 'parameter camera: 9 is not in 0..4' in log.read_text()
    assert 'Traceback' not in log.read_text()


OFFSETS_NS = (-8_000_000, -3_000_000, 0, 4_000_000, 8_000_000)  # per-camera stamp offsets of a free-running rig


def test_association_syncs_offset_jittered_cameras_into_one_bundle_per_set(domain, shelf, tmp_path):
    """Cameras stamping up to +-8 ms off the frame, +-1 ms jitter, in shuffled order, camera 3
    losing frame 302: approximate sync (max_skew half a 25 Hz period) forms one set per frame, each
    bundled once, stamped with its earliest member stamp, numbered by set order; the bundles
    are the core's association of the same sets."""
    cameras, raw = shelf
    frames = range(300, 306)
    people = {f: [detect_people(raw[c][f - FIRST], OpenPoseDetectorConfig()) for c in range(5)] for f in frames}
    rng = np.random.default_rng(0)
    stamps = {(f, c): stamp_ns(stamp_of_frame(f)) + OFFSETS_NS[c] + int(rng.integers(-1_000_000, 1_000_001))
              for f in frames for c in range(5)}
    sent = {(f, c) for f in frames for c in range(5)} - {(302, 3)}  # camera 3 loses frame 302

    def header(f: int, c: int) -> Header:
        return Header(stamp=Time(sec=stamps[f, c] // 10**9, nanosec=stamps[f, c] % 10**9), frame_id=f'cam{c}')

    log = tmp_path / 'association.log'
    with probe(domain, 'association_probe') as (node, executor):
        out: dict[int, list] = {}
        _collect(node, '/people/bundles', PointCloud2, out)
        pubs = [node.create_publisher(PointCloud2, f'/cam{c}/people2d', DATA_QOS) for c in range(5)]
        # cam3 moving on releases 302; a camera not heard yet is waited a frame period: 1 s at
        # frame_rate 1, so that a burst a loaded machine spreads out still gives whole sets
        proc = start_node('association', domain, log, '-p', 'sync_timeout:=5.0', *SLOW_FIRST_SET)
        try:
            assert spin_until(executor, lambda: all(p.get_subscription_count() for p in pubs)), log.read_text()
            for f in frames:
                for c in rng.permutation(5).tolist():
                    if (f, c) in sent:
                        pubs[c].publish(people_to_msg(people[f][c], header(f, c)))
            assert spin_until(executor, lambda: len(out) == len(frames)), log.read_text()
            spin_until(executor, lambda: False, 0.5)
        finally:
            stop(proc)
    assert sorted(out) == list(frames) and all(len(v) == 1 for v in out.values())
    # the same association as the core given the same (quantised) people at the sets' stamps
    associator = Associator(cameras, AssociationConfig())
    for f in frames:
        msg = out[f][0]
        assert stamp_ns(msg.header.stamp) == min(stamps[f, c] for c in range(5) if (f, c) in sent)
        assert msg.header.frame_id == 'world'
        decoded = [msg_to_people(people_to_msg(people[f][c], header(f, c))) if (f, c) in sent else None
                   for c in range(5)]
        observed = associator.update(stamp_ns(msg.header.stamp) / 1e9, decoded)
        expected = sorted((o.person_id, sorted(o.views)) for o in observed)
        got = [(pid, sorted(views)) for pid, views in msg_to_bundles(msg)]
        assert got == expected and len(got) >= 2
    assert all(3 not in views for _, views in msg_to_bundles(out[302][0]))
    text = log.read_text()
    assert f'set 2 stamp {stamps[302, 0]} ns: no data from cam3; going on without' in text
    assert 'max skew 20.0 ms' in text and 'dropped' not in text


def test_association_drops_a_wrong_frame_id_and_a_camera_with_no_partner_and_counts_them(domain, shelf, tmp_path):
    """A message whose frame_id is not its rig camera's is dropped (frame_id); one far larger than
    a people2d of its camera can be is dropped from its bytes, not deserialised (oversize), and the
    camera's real message of that stamp is still used; a set that only one camera reaches (camera 0
    stamping 20 ms late once, max_skew 5 ms) is dropped as unmatched (min_cameras 2) and its stamp
    published on skeletons/dropped, once; the others are bundled as usual."""
    cameras, raw = shelf
    frames = range(300, 306)
    people = {f: [detect_people(raw[c][f - FIRST], OpenPoseDetectorConfig()) for c in range(5)] for f in frames}
    limit = max_people_bytes(1032, 776)
    log = tmp_path / 'association.log'
    with probe(domain, 'association_drops') as (node, executor):
        out: dict[int, list] = {}
        node.create_subscription(PointCloud2, '/people/bundles',
                                 lambda m: out.setdefault(stamp_ns(m.header.stamp), []).append(m), DATA_QOS)
        lost: list[Header] = []
        node.create_subscription(Header, '/skeletons/dropped', lost.append, DATA_QOS)
        pubs = [node.create_publisher(PointCloud2, f'/cam{c}/people2d', DATA_QOS) for c in range(5)]
        proc = start_node('association', domain, log, '-p', 'sync_timeout:=5.0', '-p', 'max_skew:=0.005',
                          '-p', 'frame_rate:=1.0')
        try:
            assert spin_until(executor, lambda: all(p.get_subscription_count() for p in pubs)), log.read_text()
            for f in frames:
                for c in range(5):
                    stamp = stamp_of_frame(f)
                    if (f, c) == (303, 0):
                        stamp = Time(sec=12, nanosec=140_000_000)  # 20 ms late: alone between two sets
                    frame_id = 'cam9' if (f, c) == (304, 2) else f'cam{c}'
                    if (f, c) == (305, 3):
                        pubs[c].publish(PointCloud2(header=Header(stamp=stamp, frame_id=frame_id), height=1,
                                                    width=2 * limit, point_step=1, row_step=2 * limit,
                                                    data=bytes(2 * limit)))
                    pubs[c].publish(people_to_msg(people[f][c], Header(stamp=stamp, frame_id=frame_id)))
            assert spin_until(executor, lambda: len(out) == len(frames)), log.read_text()
            spin_until(executor, lambda: False, 0.5)
        finally:
            stop(proc)
    assert sorted(out) == [stamp_ns(stamp_of_frame(f)) for f in frames] and all(len(v) == 1 for v in out.values())
    assert [(stamp_ns(m.stamp), m.frame_id) for m in lost] == [(12_140_000_000, 'world')]
    bundles = {f: msg_to_bundles(out[stamp_ns(stamp_of_frame(f))][0]) for f in frames}
    assert all(0 not in views for _, views in bundles[303]) and all(2 not in views for _, views in bundles[304])
    assert all(len(bundles[f]) >= 2 for f in frames) and any(3 in views for _, views in bundles[305])
    text = log.read_text()
    assert re.search(rf'cam3 people2d stamp 12200000000 ns dropped \(oversize\): \d+ serialised bytes, more than a '
                     rf'people2d of a 1032x776 camera carries \({limit} \+ {CLOUD_OVERHEAD}\)', text), text
    assert "cam2 people2d stamp 12160000000 ns dropped (frame_id): frame_id 'cam9' is not 'cam2'; set frame_id" in text
    assert 'cam0 people2d stamp 12140000000 ns dropped (unmatched)' in text and 'max skew 5.0 ms' in text


def test_bp_solver_numbers_frames_by_arrival_and_bridges_uneven_gaps_like_the_core(domain, shelf, tmp_path):
    """Bundles of Shelf frames with some frames missing upstream (gaps of 40 to 120 ms): frames
    are numbered by arrival and the temporal term uses the real times, exactly as the core fed
    the same numbers and times; one skeleton message per bundle with its stamp, and one causal
    estimate on skeletons/live as the core's live(); a late and a
    repeated stamp are dropped with a logged reason; an unreadable bundle gives an empty one."""
    cameras, raw = shelf
    frames = [300, 301, 303, 304, 305, 308, 309, 311, 312, 313, 314, 315]
    associator = Associator(cameras, AssociationConfig())
    wire = {}
    for f in frames:
        people = [detect_people(raw[c][f - FIRST], OpenPoseDetectorConfig()) for c in range(5)]
        bundles = [(o.person_id, o.views) for o in associator.update(f / FRAME_RATE, people)]
        wire[f] = bundles_to_msg(bundles, _header(f, 'world'))
    core = Inference3D(cameras, StageConfig.from_params({'window': 6, 'lag': 2}).solver)
    first = stamp_ns(wire[frames[0]].header.stamp)
    pushed, live_expected = [], {}
    for k, f in enumerate(frames):
        pushed.append(core.push(k, msg_to_bundles(wire[f]), (stamp_ns(wire[f].header.stamp) - first) / 1e9))
        live_expected[f] = core.live()
    expected = {frames[r.frame]: r for out in pushed for r in out}
    expected.update({frames[r.frame]: r for r in core.flush()})

    log = tmp_path / 'bp.log'
    with probe(domain, 'bp_probe') as (node, executor):
        markers: dict[int, list] = {}
        # markers are built only while the node has a subscriber
        marker_sub = _collect(node, '/skeletons/markers', MarkerArray, markers)
        skeletons, live, pub, linked = _solver_io(node, marker_sub)
        proc = start_node('bp_solver', domain, log, '-p', 'window:=6', '-p', 'lag:=2', '-p', 'idle_flush:=0.3')
        try:
            assert spin_until(executor, linked), log.read_text()
            for f in frames:
                pub.publish(wire[f])
                if f == 305:
                    pub.publish(wire[304])  # late
                    pub.publish(wire[305])  # repeated
            pub.publish(PointCloud2(header=_header(316, 'world')))  # no fields at all
            assert spin_until(executor, lambda: len(skeletons) == len(live) == len(frames) + 1), log.read_text()
            spin_until(executor, lambda: False, 0.5)
        finally:
            stop(proc)
    assert sorted(skeletons) == [*frames, 316] and all(len(v) == 1 for v in skeletons.values())
    for f in frames:
        ids, joints, confidence = msg_to_skeletons(skeletons[f][0])
        assert ids.tolist() == expected[f].person_ids and len(ids) >= 2
        np.testing.assert_allclose(joints, expected[f].joints, atol=1e-5)
        np.testing.assert_allclose(confidence, expected[f].confidence, atol=1e-6)
        assert skeletons[f][0].header.stamp == wire[f].header.stamp
        assert skeletons[f][0].header.frame_id == 'world'
        assert len(markers[f]) == 1
        live_ids, live_joints, _ = msg_to_skeletons(live[f][0])  # the causal estimate, at once
        assert live_ids.tolist() == live_expected[f].person_ids and len(live[f]) == 1
        np.testing.assert_allclose(live_joints, live_expected[f].joints, atol=1e-5)
    assert any(not np.allclose(msg_to_skeletons(live[f][0])[1], msg_to_skeletons(skeletons[f][0])[1])
               for f in frames)  # the lagged output saw the frames after
    assert msg_to_skeletons(skeletons[316][0])[0].size == 0 and msg_to_skeletons(live[316][0])[0].size == 0
    text = log.read_text()
    assert 'bundles stamp 12160000000 ns came after stamp 12200000000 ns: late or duplicate, dropped' in text
    assert 'bundles stamp 12200000000 ns came after stamp 12200000000 ns: late or duplicate, dropped' in text
    assert 'bundles stamp 12640000000 ns' in text and 'published with no people' in text


def _solver_io(node, *readers) -> tuple[dict[int, list], dict[int, list], Publisher, Callable[[], bool]]:
    """On the probe node: frame -> messages of skeletons and of skeletons/live, a bundles publisher,
    and whether bp_solver and the probe are linked both ways (with `readers`, the probe's other
    readers of it): before that, what either sends may be lost."""
    skeletons: dict[int, list] = {}
    live: dict[int, list] = {}
    subs = [_collect(node, '/skeletons', PointCloud2, skeletons), _collect(node, '/skeletons/live', PointCloud2, live)]
    pub = node.create_publisher(PointCloud2, '/people/bundles', DATA_QOS)
    links = NodeLinks(node)
    return skeletons, live, pub, lambda: matched([pub, *subs, *readers]) and links.reads('bp_solver', '/people/bundles')


def _bundles_wire(cameras, raw, frames: list[int]) -> list[PointCloud2]:
    """The bundles messages association would send for these Shelf frames, in order."""
    associator = Associator(cameras, AssociationConfig())
    wire = []
    for f in frames:
        people = [detect_people(raw[c][f - FIRST], OpenPoseDetectorConfig()) for c in range(5)]
        wire.append(bundles_to_msg([(o.person_id, o.views) for o in associator.update(f / FRAME_RATE, people)],
                                   _header(f, 'world')))
    return wire


def test_bp_solver_outputs_the_last_frames_a_few_input_intervals_after_the_input_ends(domain, shelf, tmp_path):
    """Default idle_flush (automatic): a first bundle, answered (the node is up and matched), then
    bundles every ~0.1 s, then none. The frames still held back by the lag come out when the input
    has been silent for IDLE_PERIODS (3) times its typical interval, as the node logs it: about 0.3
    s here, set by the input's pace (the fixed wait was 1 s). Every frame comes out once, whether or
    not a stall of this test's own process made the node flush earlier too."""
    frames = list(range(300, 312))
    wire = _bundles_wire(*shelf, frames)
    log = tmp_path / 'bp.log'
    with probe(domain, 'bp_probe') as (node, executor):
        skeletons, live, pub, linked = _solver_io(node)
        proc = start_node('bp_solver', domain, log, '-p', 'window:=6', '-p', 'lag:=3')
        try:
            assert spin_until(executor, linked), log.read_text()
            pub.publish(wire[0])
            assert spin_until(executor, lambda: frames[0] in live), log.read_text()
            sent = []
            for msg in wire[1:]:
                pub.publish(msg)
                sent.append(time.monotonic())
                spin_until(executor, lambda: False, 0.1)  # the input's pace, not a wait for a result
            assert spin_until(executor, lambda: len(skeletons) == len(frames)), log.read_text()
        finally:
            stop(proc)
    flushes = [float(x) for x in re.findall(r'no input for ([0-9.]+) s: output the 3 pending frames', log.read_text())]
    assert flushes, log.read_text()
    assert flushes[-1] == pytest.approx(3 * np.median(np.diff(sent)), rel=0.5)
    assert sorted(skeletons) == frames and all(len(v) == 1 for v in skeletons.values())


def test_bp_solver_drops_bundles_that_waited_longer_than_max_wait_and_counts_them(domain, shelf_openpose, tmp_path):
    """A burst of bundles far faster than solving, max_wait 50 ms: a bundle that waited longer
    since DDS received it is dropped unsolved, so the queue drains; every bundle is either solved
    (its causal estimate, then its lagged output) or dropped, counted in the node's totals and its
    stamp published on skeletons/dropped, and the first of the burst, which waited for nothing (the
    node already spinning: a frame before it was handled), is solved. Bundles are handled in order, so a later one
    solved says the burst is done (a sentinel that itself waited too long is dropped: the next goes)."""
    # 39 bundles after the first: even at 1-2 ms a solve on a fast machine, the burst outlasts max_wait
    frames = list(range(300, 340))
    sentinel_frames = list(range(340, 344))
    wire = _bundles_wire(*shelf_openpose, frames + sentinel_frames)
    log = tmp_path / 'bp.log'
    with probe(domain, 'bp_probe') as (node, executor):
        gone: dict[int, list[Header]] = {}
        dropped_sub = node.create_subscription(
            Header, '/skeletons/dropped', lambda m: gone.setdefault(frame_of_stamp(m.stamp), []).append(m), DATA_QOS)
        skeletons, live, pub, linked = _solver_io(node, dropped_sub)
        proc = start_node('bp_solver', domain, log, '-p', 'max_wait:=0.05', '-p', 'idle_flush:=0.3')
        try:
            assert spin_until(executor, linked), log.read_text()
            # a frame alone first, so the burst finds the node spinning: a node still starting up
            # lets its first bundle wait (60 and 120 ms on a loaded machine) and may drop it
            pub.publish(wire[0])
            assert spin_until(executor, lambda: frames[0] in live or frames[0] in gone), log.read_text()
            for msg in wire[1:len(frames)]:
                pub.publish(msg)
            # the first drop: from there on the rest of the burst drains at once
            assert spin_until(executor, lambda: 'dropped unsolved' in log.read_text()), log.read_text()
            sent = []
            for f, msg in zip(sentinel_frames, wire[len(frames):]):
                pub.publish(msg)
                sent.append(f)
                if spin_until(executor, lambda: f in live):
                    break
            assert sent[-1] in live, log.read_text()
            # the lagged outputs come with the idle flush
            assert spin_until(executor, lambda: sorted(skeletons) == sorted(live)), log.read_text()
            assert spin_until(executor, lambda: set(live) | set(gone) == set(frames + sent)), log.read_text()
        finally:
            stop(proc)
    text = log.read_text()
    dropped = int(text.split('bundles: ')[1].split(' x behind')[0]) if ' x behind' in text else 0
    assert not set(live) & set(gone) and len(gone) == dropped and all(len(v) == 1 for v in gone.values())
    assert all(m.frame_id == 'world' for [m] in gone.values())
    # every sentinel but the last one solved was dropped, and maybe the frame before the burst
    dropped_in_burst = dropped - (len(sent) - 1) - (frames[0] in gone)
    burst = frames[1:]
    solved = [f for f in live if f in burst]
    assert set(live) <= set(frames + sent) and all(len(v) == 1 for v in live.values())
    assert burst[0] in live and 1 <= dropped_in_burst and len(solved) + dropped_in_burst == len(burst), text
    assert 'solving is slower than the input; dropped unsolved' in text


def test_association_of_a_rig_without_intrinsics_waits_for_every_camera_info(domain, shelf, tmp_path):
    """A rig file with extrinsics only, driver-style names: a camera's people before its
    CameraInfo is in are dropped (no intrinsics, logged); after, they are bundled on the rig's own
    topics and frame ids, in the rig's world frame, and the node no longer listens to CameraInfo.
    On a host without the shared data (MVPOSE_DATA_ROOT names no folder): such a rig needs none."""
    import yaml
    from rclpy.qos import qos_profile_sensor_data

    from mvpose_ros.core.geometry.rig import matrix_to_quaternion
    cameras, raw = shelf
    names = [f'left{c}' for c in range(5)]
    entries = [{'name': n, 'frame_id': f'{n}_optical', 'position': (-cam.R.T @ cam.t).tolist(),
                'orientation': matrix_to_quaternion(cam.R.T).tolist()} for n, cam in zip(names, cameras)]
    rig = tmp_path / 'rig.yaml'
    rig.write_text(yaml.safe_dump({'world_frame': 'map', 'cameras': entries}))
    people = {f: [detect_people(raw[c][f - FIRST], OpenPoseDetectorConfig()) for c in range(5)] for f in (300, 301)}
    log = tmp_path / 'association.log'
    with probe(domain, 'association_rig') as (node, executor):
        out: dict[int, list] = {}
        _collect(node, '/people/bundles', PointCloud2, out)
        pubs = [node.create_publisher(PointCloud2, f'/{n}/people2d', DATA_QOS) for n in names]
        infos = [node.create_publisher(CameraInfo, f'/{n}/camera_info', qos_profile_sensor_data) for n in names]
        proc = start_node('association', domain, log, '-p', f'rig:={rig}', '-p', 'sync_timeout:=5.0', *SLOW_FIRST_SET,
                          env={**node_env(domain), 'MVPOSE_DATA_ROOT': str(tmp_path / 'no-data')})
        try:
            assert spin_until(executor, lambda: all(p.get_subscription_count() for p in pubs + infos)), \
                log.read_text()
            for c in range(5):
                pubs[c].publish(people_to_msg(people[300][c], _header(300, f'{names[c]}_optical')))
            dropped = [f'{n} people2d stamp 12000000000 ns dropped (no intrinsics)' for n in names]
            assert spin_until(executor, lambda: all(d in log.read_text() for d in dropped)), log.read_text()

            def intrinsics_in() -> bool:  # best effort may lose one: resend until every camera took it
                if log.read_text().count(': intrinsics from /') == 5:
                    return True
                for c in range(5):
                    infos[c].publish(camera_to_info(cameras[c], _header(300, f'{names[c]}_optical')))
                return spin_until(executor, lambda: log.read_text().count(': intrinsics from /') == 5, 0.2)
            assert spin_until(executor, intrinsics_in), log.read_text()
            assert spin_until(executor, lambda: not any(i.get_subscription_count() for i in infos)), log.read_text()
            for c in range(5):
                pubs[c].publish(people_to_msg(people[301][c], _header(301, f'{names[c]}_optical')))
            assert spin_until(executor, lambda: 301 in out), log.read_text()
            spin_until(executor, lambda: False, 0.5)
        finally:
            stop(proc)
    assert sorted(out) == [301] and len(out[301]) == 1 and out[301][0].header.frame_id == 'map'
    assert len(msg_to_bundles(out[301][0])) >= 2
    assert 'left0 people2d stamp 12000000000 ns dropped (no intrinsics)' in log.read_text()
