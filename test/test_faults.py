"""Timing, process and file faults at the nodes, each its own process fed real Shelf data: at
bp_solver a burst far above the frame rate, a gap in the stamps, late and duplicate frames,
a kill and restart mid-stream; at association a camera gone for good, a camera that sees nobody,
repeated and out-of-order stamps; bad parameter and calibration files. Every input frame yields
one output or a logged reason."""
from __future__ import annotations

import json
import re
import signal

import numpy as np
import pytest
from sensor_msgs.msg import PointCloud2
from std_msgs.msg import Header

from msg_adapters.cdr_header import CLOUD_OVERHEAD
from msg_adapters.people_msg import bundles_to_msg, max_bundles_bytes, msg_to_bundles, people_to_msg
from msg_adapters.skeleton_msg import msg_to_skeletons
from msg_adapters.stamp import frame_of_stamp, stamp_of_frame
from mvpose_ros.core.association.associator import AssociationConfig, Associator
from mvpose_ros.core.datasets.shelf_campus import calibration_file, dataset_dir
from mvpose_ros.core.defaults import FRAME_RATE
from mvpose_ros.core.detection.openpose import read_body25
from mvpose_ros.core.detection.openpose_detector import OpenPoseDetectorConfig, detect_people
from mvpose_ros.nodes.runtime import DATA_QOS
from ros_harness import probe, spin_until, start_node, stop

FIRST = 300  # first frame of the OpenPose files
N_FRAMES = 60
WINDOW, LAG = 6, 2
SOLVER_ARGS = ('-p', f'window:={WINDOW}', '-p', f'lag:={LAG}', '-p', 'idle_flush:=0.5')


@pytest.fixture(scope='module')
def bundles(shelf_openpose) -> dict[int, PointCloud2]:
    """Bundle messages (encoding C) of Shelf frames 300..359, from the core's association."""
    cameras, raw = shelf_openpose
    associator = Associator(cameras, AssociationConfig())
    out = {}
    for k in range(N_FRAMES):
        people = [detect_people(raw[c][k], OpenPoseDetectorConfig(stride=8.0)) for c in range(len(cameras))]
        obs = associator.update((FIRST + k) / FRAME_RATE, people)
        out[FIRST + k] = bundles_to_msg([(o.person_id, o.views) for o in obs],
                                        Header(stamp=stamp_of_frame(FIRST + k), frame_id='world'))
    return out


def _outputs(node) -> dict[int, list]:
    got: dict[int, list] = {}
    node.create_subscription(PointCloud2, '/skeletons',
                             lambda m: got.setdefault(frame_of_stamp(m.header.stamp), []).append(m), DATA_QOS)
    return got


def _connected(executor, pub, got: dict[int, list], frames: range) -> None:
    """Warm up until bp_solver answers: empty bundles stamped at `frames` (before the test's own,
    far enough back to break every chain), one at a time, until the first comes out and then all
    that were sent (a reliable volatile reader drops what comes before it has matched the writer,
    which the writer's side cannot see)."""
    sent = []
    for f in frames:
        pub.publish(bundles_to_msg([], Header(stamp=stamp_of_frame(f), frame_id='world')))
        sent.append(f)
        if spin_until(executor, lambda: any(s in got for s in sent), 0.2):
            break
    assert spin_until(executor, lambda: sent[-1] in got), 'bp_solver never answered the warm-up bundles'


def _readers(node) -> set[bytes]:
    """Endpoint ids of the subscriptions to /people/bundles."""
    return {bytes(info.endpoint_gid) for info in node.get_subscriptions_info_by_topic('/people/bundles')}


def test_burst_gap_late_and_duplicate_frames(domain, bundles, tmp_path):
    burst = list(range(300, 330))  # 30 frames published back to back: > 100 x the 25 Hz rate
    after_gap = list(range(340, 350))  # frames 330..339 never come
    log = tmp_path / 'bp.log'
    with probe(domain, 'fault_probe') as (node, executor):
        got = _outputs(node)
        pub = node.create_publisher(PointCloud2, '/people/bundles', DATA_QOS)
        proc = start_node('bp_solver', domain, log, *SOLVER_ARGS)
        try:
            assert spin_until(executor, lambda: pub.get_subscription_count() > 0), log.read_text()
            _connected(executor, pub, got, range(200, 250))
            for f in burst:
                pub.publish(bundles[f])
            for f in after_gap[:5]:
                pub.publish(bundles[f])
            pub.publish(bundles[342])  # duplicate
            pub.publish(bundles[310])  # late: the window moved on long ago
            for f in after_gap[5:]:
                pub.publish(bundles[f])
            expected = burst + after_gap
            assert spin_until(executor, lambda: set(got) >= set(expected), 30.0), log.read_text()
            spin_until(executor, lambda: False, 0.5)  # nothing more may come
        finally:
            stop(proc)
    assert sorted(f for f in got if f >= FIRST) == expected and all(len(v) == 1 for v in got.values())
    people = [len(np.unique(msg_to_skeletons(got[f][0])[0])) for f in expected]
    assert min(people) >= 2  # the gap (0.44 s > max_gap) breaks the chains, it does not empty the frames after it
    text = log.read_text()
    assert 'bundles stamp 13680000000 ns came after stamp 13760000000 ns: late or duplicate, dropped' in text
    # the second late one within a few seconds is counted, not logged: the totals when the node stops
    assert 'bundles stamp 12400000000 ns came after' not in text
    assert 'problems: bundles: 2 x late' in text


def test_killed_and_restarted_solver_resumes_within_a_window(domain, bundles, tmp_path):
    first, second = list(range(300, 320)), list(range(320, 360))
    with probe(domain, 'restart_probe') as (node, executor):
        got = _outputs(node)
        pub = node.create_publisher(PointCloud2, '/people/bundles', DATA_QOS)
        proc = start_node('bp_solver', domain, tmp_path / 'bp1.log', *SOLVER_ARGS)
        try:
            assert spin_until(executor, lambda: pub.get_subscription_count() > 0)
            _connected(executor, pub, got, range(200, 250))
            for f in first:
                pub.publish(bundles[f])
            assert spin_until(executor, lambda: 319 - LAG in got)
            old = _readers(node)
            proc.send_signal(signal.SIGKILL)  # a crash: no flush, the pending frames are lost
            proc.wait(5)
            proc = start_node('bp_solver', domain, tmp_path / 'bp2.log', *SOLVER_ARGS)
            # the dead reader stays discovered until its lease ends: wait for the new one, then
            # until it answers (the node's own start is what is measured)
            assert spin_until(executor, lambda: _readers(node) - old)
            _connected(executor, pub, got, range(250, 300))
            for f in second:
                pub.publish(bundles[f])
                spin_until(executor, lambda: False, 0.04)  # ~ the recorded rate
            assert spin_until(executor, lambda: 359 in got, 20.0), (tmp_path / 'bp2.log').read_text()
        finally:
            stop(proc)
    restarted = sorted(f for f in got if f >= 320)
    assert restarted == second  # every frame sent to the new process has its output
    assert all(len(got[f]) == 1 for f in got)
    # the new process answers from the first frame it gets: output resumes `lag` frames after
    # it is connected, within one window, with no frame of the new stream lost
    assert min(restarted) == second[0]
    assert all(len(msg_to_skeletons(got[f][0])[0]) for f in second)


def test_oversize_bundles_are_refused_undecoded_and_answered_with_no_people(domain, tmp_path):
    """The byte bound of a rig of two 64 x 48 cameras: a message far over it is not even
    deserialised (its serialised size said), one a byte over it is not decoded; each is answered (no
    people), logged (the second within the throttle: counted) and counted; the frames around go on."""
    rig = tmp_path / 'rig.yaml'
    rig.write_text('world_frame: world\ncameras:\n' + ''.join(
        f'  - name: c{c}\n    image: c{c}/image\n    camera_info: c{c}/camera_info\n'
        f'    position: [{c}.0, 0.0, 0.0]\n    orientation: [0.0, 0.0, 0.0, 1.0]\n'
        f'    width: 64\n    height: 48\n    K: [50.0, 0.0, 32.0, 0.0, 50.0, 24.0, 0.0, 0.0, 1.0]\n' for c in range(2)))
    limit = max_bundles_bytes([(64, 48)] * 2)
    big = 10 * limit + CLOUD_OVERHEAD
    bomb = PointCloud2(header=Header(stamp=stamp_of_frame(301), frame_id='world'), height=1, width=big,
                       point_step=1, row_step=big, data=bytes(big))
    junk = PointCloud2(header=Header(stamp=stamp_of_frame(303), frame_id='world'), height=1, width=limit + 1,
                       point_step=1, row_step=limit + 1, data=bytes(limit + 1))
    log = tmp_path / 'bp.log'
    with probe(domain, 'oversize_probe') as (node, executor):
        got = _outputs(node)
        pub = node.create_publisher(PointCloud2, '/people/bundles', DATA_QOS)
        proc = start_node('bp_solver', domain, log, *SOLVER_ARGS, '-p', f'rig:={rig}')
        try:
            assert spin_until(executor, lambda: pub.get_subscription_count() > 0), log.read_text()
            _connected(executor, pub, got, range(200, 250))
            pub.publish(bundles_to_msg([], Header(stamp=stamp_of_frame(300), frame_id='world')))
            pub.publish(bomb)
            pub.publish(bundles_to_msg([], Header(stamp=stamp_of_frame(302), frame_id='world')))
            pub.publish(junk)
            pub.publish(bundles_to_msg([], Header(stamp=stamp_of_frame(304), frame_id='world')))
            assert spin_until(executor, lambda: {300, 301, 302, 303, 304} <= set(got), 20.0), log.read_text()
        finally:
            stop(proc)
    assert len(msg_to_skeletons(got[301][0])[0]) == 0 and len(msg_to_skeletons(got[303][0])[0]) == 0
    text = log.read_text()
    assert re.search(rf'bundles stamp 12040000000 ns: \d+ serialised bytes, more than the views of 64 people in '
                     rf'every camera take \({limit} \+ {CLOUD_OVERHEAD}\); published with no people', text), text
    assert 'bundles: 2 x oversize' in text


@pytest.mark.parametrize('content, problem', [
    ('bp_solver:\n  ros__parameters:\n    window: "eight"\n',
     "parameter window: Trying to set parameter 'window' to 'eight' of type 'STRING', expecting type 'INTEGER'"),
    ('bp_solver:\n  ros__parameters:\n    window: [1, 2\n', "Couldn't parse params file"),
    ('bp_solver:\n  ros__parameters:\n    rig: RIG\n', "camera '1': missing fx"),
    ('bp_solver:\n  ros__parameters:\n    rig: CALIBRATION\n', 'give width and height'),
    ('bp_solver:\n  ros__parameters:\n    rig: no/such/rig.yaml\n', 'no/such/rig.yaml: not found'),
])
def test_bad_parameter_or_calibration_file_is_one_fatal_line_and_exit_2(domain, tmp_path, content, problem):
    calibration = tmp_path / 'calibration_shelf.json'
    entries = json.loads((calibration_file('shelf')).read_text())
    del entries['1']['fx']
    calibration.write_text(json.dumps(entries))
    rig = tmp_path / 'rig.yaml'
    rig.write_text(f'calibration: {calibration}\nwidth: 1032\nheight: 776\n')
    params = tmp_path / 'params.yaml'
    params.write_text(content.replace('CALIBRATION', str(calibration)).replace('RIG', str(rig)))
    log = tmp_path / 'bp.log'
    proc = start_node('bp_solver', domain, log, '--params-file', str(params))
    try:
        assert proc.wait(30) == 2
    finally:
        stop(proc)  # a node that did not stop must not outlive the test
    text = log.read_text()
    fatal = [line for line in text.splitlines() if '[FATAL]' in line]
    assert len(fatal) == 1 and str(params) in fatal[0] and problem in fatal[0], text
    assert 'Traceback' not in text


def test_association_with_a_camera_gone_for_good_and_stamps_out_of_order_or_repeated(domain, tmp_path):
    root = dataset_dir('shelf')
    raw = [read_body25(root / 'openpose_body25' / f'{c}.txt')[:12] for c in range(5)]
    frames = range(300, 312)
    people = {f: [detect_people(raw[c][f - FIRST], OpenPoseDetectorConfig(stride=8.0)) for c in range(5)]
              for f in frames}
    log = tmp_path / 'association.log'
    with probe(domain, 'association_faults') as (node, executor):
        got: dict[int, list] = {}
        node.create_subscription(PointCloud2, '/people/bundles',
                                 lambda m: got.setdefault(frame_of_stamp(m.header.stamp), []).append(m), DATA_QOS)
        pubs = [node.create_publisher(PointCloud2, f'/cam{c}/people2d', DATA_QOS) for c in range(5)]
        proc = start_node('association', domain, log, '-p', 'sync_timeout:=0.3')
        try:
            assert spin_until(executor, lambda: all(p.get_subscription_count() for p in pubs)), log.read_text()

            def send(c: int, f: int, nobody: bool = False) -> None:
                header = Header(stamp=stamp_of_frame(f), frame_id=f'cam{c}')
                pubs[c].publish(people_to_msg([] if nobody else people[f][c], header))

            # warm up until a set of nobody comes out: a reliable volatile reader that has not yet
            # matched a writer the writer already sees gets its first samples late, out of order
            for f in range(200, 250):
                for c in range(5):
                    send(c, f, nobody=True)
                if spin_until(executor, lambda: f in got, 0.2):
                    break
            assert got, log.read_text()
            for f in frames:
                for c in range(5):
                    if c == 4 and f >= 304:
                        continue  # camera 4 is gone for good from frame 304
                    if (c, f) == (1, 303):
                        continue  # comes late, below
                    send(c, f, nobody=(c, f) == (0, 305))  # camera 0 sees nobody at 305
                if f == 306:
                    send(2, 306)  # a repeated stamp
                if f == 308:
                    send(1, 303)  # out of order: frame 303 has gone on without camera 1
                spin_until(executor, lambda: False, 0.04)
            assert spin_until(executor, lambda: set(got) >= set(frames), 20.0), log.read_text()
            spin_until(executor, lambda: False, 0.5)
        finally:
            stop(proc)
    assert sorted(f for f in got if f >= FIRST) == list(frames) and all(len(v) == 1 for v in got.values())
    bundles = {f: msg_to_bundles(got[f][0]) for f in frames}
    assert all(len(bundles[f]) >= 2 for f in frames)  # the four cameras left still see everybody twice
    assert all(4 not in views for f in frames if f >= 304 for _, views in bundles[f])
    assert all(0 not in views for _, views in bundles[305])
    text = log.read_text()
    # camera 4 missing from every set from 304 on: logged at once, then throttled
    assert text.count('no data from cam4; going on without') >= 1
    assert 'cam2 people2d stamp 12240000000 ns dropped (duplicate)' in text  # the repeat
    assert 'cam1 people2d stamp 12120000000 ns dropped (late)' in text  # the late one
