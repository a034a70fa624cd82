"""Running the graph on a recorded rig, without ROS processes: the synchronised sets of a rig bag
(offset and jittered stamps, a late camera, dropped frames), the shelf_rig recipe's stamps, the
`mvpose-graph --rig` arguments, the nodes and parameter files it runs, its report and its
predictions lines."""
from __future__ import annotations

import json
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest
import yaml

from msg_adapters.cdr_header import header_stamp_ns
from msg_adapters.skeleton_msg import Skeletons
from mvpose_ros.bags.io import read_bag
from mvpose_ros.bags.recipes import ForeignRig, shelf_rig_stamps
from mvpose_ros.bags.replay import InFlight, group_sets
from mvpose_ros.cli.graph import main as graph_main
from mvpose_ros.graph.config import (LOCKSTEP_ACK, RIG_TEMPLATE, RigRun, load_params, rig_connections,
                                     rig_graph_nodes, rig_played_connections, rig_sync, write_overrides)
from mvpose_ros.graph.report import (count_under_sets, frame_rate_note, rig_prediction_lines, rig_report,
                                     set_skews_ms)
from mvpose_ros.graph.session import rig_run_plan
from mvpose_ros.package_files import package_path

S = 1_000_000_000
MS = 1_000_000
PERIOD = 40 * MS


def _cdr(stamp: int) -> bytes:
    """A little-endian CDR message whose header stamp is `stamp` (ns)."""
    sec, nsec = divmod(stamp, S)
    return b'\x00\x01\x00\x00' + sec.to_bytes(4, 'little', signed=True) + nsec.to_bytes(4, 'little') + b'frame'


def _messages(stamps: dict[str, list[int | None]]):
    """Driver-style: per camera and capture a camera_info and an image of that stamp, logged then."""
    out = []
    for name, per_set in stamps.items():
        for stamp in per_set:
            if stamp is not None:
                out.append((stamp, 0, f'/rig/{name}/camera_info', 'sensor_msgs/msg/CameraInfo', _cdr(stamp)))
                out.append((stamp, 1, f'/rig/{name}/image', 'sensor_msgs/msg/CompressedImage', _cdr(stamp)))
    out.sort(key=lambda m: m[:2])
    return [(topic, kind, stamp, cdr) for stamp, _, topic, kind, cdr in out]


def test_sets_of_a_driver_rig_follow_the_approximate_sync_rules():
    stamps = shelf_rig_stamps()
    names = list(stamps)
    cameras = [f'/rig/{n}/image' for n in names]
    sets = list(group_sets(_messages(stamps), cameras, max_skew=0.02))
    assert [s.index for s in sets] == list(range(ForeignRig.SETS))
    for k, s in enumerate(sets):
        expected = {f'/rig/{n}/image': stamps[n][k] for n in names if stamps[n][k] is not None}
        assert s.members == expected  # one capture per set, whatever the offsets
        assert s.stamp_ns == min(expected.values())  # the set's stamp: its earliest member's
        assert s.skew_ns == max(expected.values()) - min(expected.values()) <= 20 * MS
        # each camera's CameraInfo goes with its image, before it (bag order)
        topics = [m[0] for m in s.messages]
        assert sorted(topics) == sorted([t.replace('/image', '/camera_info') for t in expected] + list(expected))
        for t in expected:
            assert topics.index(t.replace('/image', '/camera_info')) < topics.index(t)
        assert {header_stamp_ns(m[2]) for m in s.messages} == set(expected.values())
    assert [len(s.members) for s in sets[:4]] == [4, 4, 4, 5]  # the late camera
    assert [k for k, s in enumerate(sets) if len(s.members) == 4] == [0, 1, 2, *ForeignRig.DROPPED_SETS]


def test_shelf_rig_stamps_have_offsets_jitter_a_late_camera_and_three_drops():
    stamps = shelf_rig_stamps()
    assert list(stamps) == list(ForeignRig.NAMES) and all(len(v) == 40 for v in stamps.values())
    for c, name in enumerate(ForeignRig.NAMES):
        offsets = np.array([s - ForeignRig.START_NS - k * PERIOD for k, s in enumerate(stamps[name]) if s is not None])
        assert np.abs(offsets).max() <= 9 * MS
        assert abs(np.median(offsets) - ForeignRig.OFFSETS_MS[c] * MS) <= 1 * MS
        assert offsets.std() > 0.1 * MS  # jittered, not a constant offset
    assert [k for k, s in enumerate(stamps['back']) if s is None] == [0, 1, 2]
    assert [k for k, s in enumerate(stamps['door']) if s is None] == [11, 22, 33]
    assert shelf_rig_stamps() == stamps  # seeded


def test_out_of_order_or_duplicate_images_are_still_played_with_the_next_set():
    a, b = '/a/image', '/b/image'
    msgs = [(a, 'x', 0, _cdr(100 * MS)), (b, 'x', 0, _cdr(101 * MS)), (a, 'x', 0, _cdr(140 * MS)),
            (b, 'x', 0, _cdr(141 * MS)), (b, 'x', 0, _cdr(101 * MS)),  # a late repeat
            ('/tf', 'y', 0, b'no header'), (a, 'x', 0, _cdr(180 * MS))]
    sets = list(group_sets(msgs, [a, b], 0.02, stamped=lambda t: t != 'y'))
    assert [s.stamp_ns for s in sets] == [100 * MS, 140 * MS, 180 * MS]
    assert sum(len(s.messages) for s in sets) == len(msgs)
    with pytest.raises(ValueError, match='no header'):
        list(group_sets([(a, 'y', 0, b'')], [a], 0.02, stamped=lambda t: t != 'y'))
    with pytest.raises(ValueError, match='camera topic'):
        list(group_sets([], [], 0.02))


def test_in_flight_give_up():
    flight = InFlight(1)
    flight.published(5)
    assert flight.full and flight.give_up() == 5 and not flight.full
    with pytest.raises(ValueError):
        flight.give_up()


@pytest.fixture
def rig_file(tmp_path) -> Path:
    path = tmp_path / 'rig.yaml'
    path.write_text(yaml.safe_dump({'cameras': [
        {'name': n, 'image': f'/rig/{n}/image', 'camera_info': f'/rig/{n}/camera_info', 'position': [0, 0, i],
         'orientation': [0, 0, 0, 1]} for i, n in enumerate(('a', 'b'))]}))
    return path


@pytest.mark.parametrize('argv, needle', [
    (['--rig', 'RIG'], '--rig needs --bag'),
    ([], 'one of --config'),
    (['--config', 'config/shelf.yaml', '--lockstep'], '--lockstep needs --rig'),
    (['--config', 'config/shelf.yaml', '--qos', 'sensor'], '--qos needs --rig'),
    (['--config', 'config/shelf.yaml', '--overlay', 'out'], '--overlay needs --rig'),
    (['--rig', 'RIG', '--bag', 'B', '--lockstep', '--rate', '2'], 'exclude each other'),
    (['--rig', 'RIG', '--bag', 'B', '--loops', '0'], '--loops must be >= 1'),
    (['--rig', 'RIG', '--bag', 'B', '--ground-truth', 'shelf'], '--frame'),
    (['--rig', 'nowhere.yaml', '--bag', 'B'], 'nowhere.yaml'),
    (['--rig', 'RIG', '--bag', 'BAG', '--rate', '0'], '--rate must be > 0'),
    (['--rig', 'RIG', '--bag', 'OTHER'], 'no topic /rig/b/image'),
])
def test_rig_arguments_are_one_line_errors(argv, needle, rig_file, tmp_path, capsys):
    from mvpose_ros.bags.io import write_bag
    from sensor_msgs.msg import CompressedImage
    from std_msgs.msg import Header
    bag, other = tmp_path / 'bag', tmp_path / 'other'
    write_bag(bag, [(f'/rig/{n}/image', CompressedImage(header=Header(frame_id=n)), 1) for n in 'ab'])
    write_bag(other, [('/rig/a/image', CompressedImage(header=Header(frame_id='a')), 1)])
    subst = {'RIG': str(rig_file), 'BAG': str(bag), 'OTHER': str(other)}
    assert graph_main([subst.get(a, a) for a in argv]) == 2
    err = capsys.readouterr().err
    assert needle in err and len(err.strip().splitlines()) == 1, err


def test_rig_plan_nodes_and_parameter_files(rig_file, tmp_path, monkeypatch):
    from mvpose_ros.bags.io import write_bag
    monkeypatch.setenv('MVPOSE_DATA_ROOT', str(tmp_path / 'no-data'))  # the rig file needs no data root
    from sensor_msgs.msg import CompressedImage
    from std_msgs.msg import Header
    items = []
    for k in range(3):
        for c, n in enumerate('ab'):
            header = Header(frame_id=n)
            header.stamp.sec, header.stamp.nanosec = divmod(S + k * PERIOD + c * 5 * MS, S)
            items.append((f'/rig/{n}/image', CompressedImage(header=header), S + k * PERIOD + c * 5 * MS))
    write_bag(tmp_path / 'bag', items)
    config = tmp_path / 'mine.yaml'
    config.write_text('/**/association:\n  ros__parameters:\n    max_skew: 0.01\n'
                      'mvpose_graph:\n  ros__parameters:\n    rate: 2.0\n')
    crowd = tmp_path / 'crowd.yaml'
    crowd.write_text('bp_solver:\n  ros__parameters:\n    hypotheses: 32\n')
    args = SimpleNamespace(rig=rig_file, bag=str(tmp_path / 'bag'), config=config, data_root=None, lockstep=False,
                           rate=None, qos=None, predictions=None, loops=2, overrides=[crowd])
    rig, run, settings, files, sets = rig_run_plan(args)
    sets = sets.result()
    assert files == [package_path(RIG_TEMPLATE), config.resolve(), crowd.resolve()]
    # the template's frame_rate, and the bag's cameras' rate (40 ms apart), so nothing to say
    assert run.frame_rate == 25.0 and run.bag_rate == pytest.approx(25.0) and not run.rate_from_bag
    assert frame_rate_note(run.bag_rate, run.frame_rate) is None
    assert run.rate == 2.0 and run.qos == 'sensor' and run.max_skew == 0.01 and not run.lockstep
    # two passes: the second moved on by the bag's log span plus a period, as the player moves it
    span = 2 * PERIOD + 5 * MS + PERIOD
    assert [s.stamp_ns for s in sets] == [S + k * PERIOD + p * span for p in range(2) for k in range(3)]
    # and so are its members: an output under a member's stamp is counted as that pass's set
    assert [sorted(s.members.values()) for s in sets] == [[s.stamp_ns, s.stamp_ns + 5 * MS] for s in sets]
    assert [s.index for s in sets] == list(range(6)) and settings.cameras == 2 and run.loops == 2
    assert rig_connections(rig) == {'/rig/a/image': ('sub',), 'a/people2d': ('pub', 'sub'), '/rig/b/image': ('sub',),
                                    'b/people2d': ('pub', 'sub'), 'people/bundles': ('pub', 'sub'),
                                    'skeletons': ('pub',)}
    # the player's links, waited for once it is up: both ends of every camera's image and info
    assert rig_played_connections(rig) == {t: ('pub', 'sub') for c in rig.cameras for t in (c.image, c.camera_info)}
    assert len(rig_played_connections(rig)) == 4
    assert rig_played_connections(rig, lockstep=True) == {**rig_played_connections(rig), LOCKSTEP_ACK: ('pub', 'sub')}
    # --rig alone: the template's defaults (association max_skew 0 = half a 25 Hz period)
    assert rig_sync([load_params(package_path(RIG_TEMPLATE))]) == (0.02, 0.5)
    # what --config leaves out comes from the template's runner section, where alone it is defined
    template = load_params(package_path(RIG_TEMPLATE))['mvpose_graph']
    assert (settings.predictions, settings.timeout, run.ack_timeout) == (
        template['predictions'], template['timeout'], template['ack_timeout'])


def _bag_at_15_hz(path: Path) -> None:
    """Cameras a and b at 15 Hz, b 25 ms after a: one set each capture only with a 15 Hz max_skew
    (half its period, 33 ms), not with 25 Hz's (20 ms)."""
    from mvpose_ros.bags.io import write_bag
    from sensor_msgs.msg import CompressedImage
    from std_msgs.msg import Header
    items = []
    for k in range(6):
        for c, n in enumerate('ab'):
            stamp = S + k * 200 * MS // 3 + c * 25 * MS
            header = Header(frame_id=n)
            header.stamp.sec, header.stamp.nanosec = divmod(stamp, S)
            items.append((f'/rig/{n}/image', CompressedImage(header=header), stamp))
    write_bag(path, items)


@pytest.mark.parametrize('mine', [None, '/**:\n  ros__parameters:\n    frame_rate: 25.0\n',
                                  '/**/bp_solver:\n  ros__parameters:\n    frame_rate: 25.0\n'])
def test_rig_plan_takes_the_bags_frame_rate_unless_a_file_of_the_users_sets_one(mine, rig_file, tmp_path, monkeypatch):
    monkeypatch.setenv('MVPOSE_DATA_ROOT', str(tmp_path / 'no-data'))
    _bag_at_15_hz(tmp_path / 'bag')
    config = None
    if mine is not None:
        config = tmp_path / 'mine.yaml'
        config.write_text(mine)
    args = SimpleNamespace(rig=rig_file, bag=str(tmp_path / 'bag'), config=config, data_root=None, lockstep=True,
                           rate=None, qos=None, predictions=None, loops=1, overrides=[])
    import mvpose_ros.graph.session as session
    reads = []
    monkeypatch.setattr(session, 'read_bag', lambda *a: reads.append(a) or read_bag(*a))
    rig, run, settings, files, sets = rig_run_plan(args)
    sets = sets.result()
    assert len(reads) == 2  # its first HEAD_S s for the rate, then all of it for the sets (in a thread)
    assert run.bag_rate == pytest.approx(15.0)
    detector, association, solver, player = (n.parameters for n in rig_graph_nodes(run))
    if mine is None:  # the template's 25 Hz is 10 % off: the bag's rate, for every node
        assert run.rate_from_bag and run.frame_rate == 15.0 and run.max_skew == pytest.approx(1 / 30)
        assert detector['frame_rate'] == association['frame_rate'] == solver['frame_rate'] == 15.0
        assert player['max_skew'] == pytest.approx(1 / 30) and frame_rate_note(run.bag_rate, run.frame_rate) is None
        assert [sorted(s.members) for s in sets] == [['/rig/a/image', '/rig/b/image']] * 6
    else:  # the user's 25 Hz is kept, and said to be off the bag's
        assert not run.rate_from_bag and run.frame_rate == 25.0 and run.max_skew == 0.02
        assert all('frame_rate' not in p for p in (detector, association, solver))
        assert 'set it to 15.0' in frame_rate_note(run.bag_rate, run.frame_rate)
        assert all(len(s.members) == 1 for s in sets)  # 25 ms apart: no set of two within 20 ms


def test_rig_plan_names_a_runner_setting_the_template_lacks(rig_file, tmp_path, monkeypatch):
    import mvpose_ros.graph.session as session
    lines = package_path(RIG_TEMPLATE).read_text().splitlines(keepends=True)
    broken = tmp_path / 'template.yaml'
    broken.write_text(''.join(line for line in lines if not line.lstrip().startswith('ack_timeout:')))
    monkeypatch.setattr(session, 'RIG_TEMPLATE', str(broken))
    args = SimpleNamespace(rig=rig_file, bag=str(tmp_path / 'bag'), config=None, data_root=None, lockstep=True,
                           rate=None, qos=None, predictions=None, loops=1, overrides=[])
    with pytest.raises(ValueError, match=r'template\.yaml: mvpose_graph\.ack_timeout: missing'):
        rig_run_plan(args)


def test_lockstep_nodes_and_their_overrides_file(tmp_path):
    run = RigRun('/r/rig.yaml', '/b', True, 0.0, 'sensor', 0.02, 0.5, 10.0)
    nodes = rig_graph_nodes(run, start_topic='bag_player/start')
    assert [(n.executable, n.namespace) for n in nodes] == [
        ('heatmap_detector', ''), ('association', ''), ('bp_solver', ''), ('bag_player', '')]
    detector, association, solver, player = (n.parameters for n in nodes)
    assert detector['camera'] == 'all' and detector['rig'] == association['rig'] == solver['rig'] == '/r/rig.yaml'
    assert player | {} == {'bag': '/b', 'qos': 'sensor', 'max_skew': 0.02, 'sync_timeout': 0.5, 'loops': 1, 'rate': 0.0,
                           'sets': True, 'max_in_flight': 1, 'ack_topic': LOCKSTEP_ACK, 'ack_timeout': 10.0,
                           'start_topic': 'bag_player/start'}
    paced = rig_graph_nodes(RigRun('/r/rig.yaml', '/b', False, 1.0, 'reliable', 0.02, 0.5, 10.0))[-1].parameters
    assert paced['rate'] == 1.0 and paced['sets'] is False and 'max_in_flight' not in paced
    written = load_params(write_overrides(nodes, tmp_path / 'o.yaml'))
    assert written['/**/heatmap_detector'] == detector and written['/**/bag_player'] == player


def test_a_set_that_came_out_under_a_later_members_stamp_counts_as_that_set():
    """Set 1's earliest image was lost: the graph stamped the set with its next member's stamp."""
    stamps = [S + k * PERIOD for k in range(3)]
    later = stamps[1] + 7 * MS
    set_of_member = {m: s for s in stamps for m in (s, s + 7 * MS, s + 13 * MS)}
    out = Skeletons(np.array([3]), np.zeros((1, 14, 3)), np.full((1, 14), 0.5))
    node = SimpleNamespace(outputs={stamps[0]: out, later: out}, output_at={stamps[0]: 900 * MS, later: 960 * MS},
                           live_at={later: 950 * MS}, dropped=set(), info_at={stamps[0]: 800 * MS, stamps[1]: 840 * MS},
                           received={stamps[0]: 1, later: 1}, bad=[])
    quiet = SimpleNamespace(write=lambda s: None)
    unexpected = '1 /skeletons stamps are not set stamps of the bag'
    assert rig_report(stamps, [0] * 3, node, {}, 20 * MS, False, quiet) == [unexpected]
    assert count_under_sets(node, set_of_member) == 1
    assert node.received == {stamps[0]: 1, stamps[1]: 1} and set(node.outputs) == {stamps[0], stamps[1]}
    assert node.output_at[stamps[1]] == 960 * MS and node.live_at == {stamps[1]: 950 * MS}
    assert rig_report(stamps, [0] * 3, node, {}, 20 * MS, False, quiet) == []
    assert count_under_sets(node, set_of_member) == 0


def test_rig_report_counts_sets_skew_and_latency_and_predictions_lines():
    stamps = [S + k * PERIOD for k in range(4)]
    joints = np.arange(2 * 14 * 3, dtype=float).reshape(2, 14, 3) / 100
    confidence = np.full((2, 14), 0.5)
    node = SimpleNamespace(outputs={stamps[0]: Skeletons(np.array([3, 7]), joints, confidence),
                                    stamps[2]: Skeletons(np.array([3]), joints[:1], confidence[:1])},
                           output_at={stamps[0]: 1_000 * MS, stamps[2]: 1_500 * MS}, live_at={}, dropped=set(),
                           info_at={stamps[0]: 900 * MS, stamps[2]: 1_300 * MS}, received={stamps[0]: 1, stamps[2]: 1},
                           bad=[])
    people = {'a/people2d': [stamps[0], stamps[2]], 'b/people2d': [stamps[0] + 6 * MS, stamps[2] + 12 * MS]}
    assert set_skews_ms([stamps[0], stamps[2]], people, 20 * MS).tolist() == [6.0, 12.0]
    lines = []
    problems = rig_report(stamps, [6 * MS] * 4, node, people, 20 * MS, True, SimpleNamespace(write=lines.append))
    text = ''.join(lines)
    assert 'sets in 4, processed 2, dropped 2 (set numbers 1, 3)' in text
    assert 'p50 6.0 ms, max 6.0 ms' in text and 'p50 9.0 ms, max 12.0 ms' in text
    assert 'p50 150.0 ms' in text and problems == ['2 of 4 sets got no /skeletons']
    assert 'per second of bag time' not in text  # lockstep: the graph sets the pace
    lines.clear()
    assert rig_report(stamps, [0] * 4, node, people, 20 * MS, False, SimpleNamespace(write=lines.append)) == []
    per_second = 1e9 / PERIOD
    assert f'sets processed per second of bag time: {per_second / 2:.2f} of {per_second:.2f} sent' in ''.join(lines)
    records = [json.loads(line) for line in rig_prediction_lines(stamps, node.outputs)]
    assert [(r['frame'], r['stamp']) for r in records] == [(0, stamps[0]), (2, stamps[2])]
    assert list(records[0]) == ['frame', 'stamp', 'people']
    assert [p['id'] for p in records[0]['people']] == [3, 7]
    assert np.allclose(records[0]['people'][1]['joints'], joints[1], atol=1e-3)
    assert np.array(records[1]['people'][0]['joints']).shape == (14, 3)
    assert records[1]['people'][0]['confidence'] == [0.5] * 14


def test_sets_are_scored_one_line_each_against_the_frame_they_show(tmp_path):
    from mvpose_ros.core.datasets.shelf_campus import dataset_dir, load_actors_gt
    from mvpose_ros.graph.report import score_sets
    truth = load_actors_gt(dataset_dir('shelf') / 'actorsGT.mat', [572]).poses[0]  # (A, 14, 3)
    actors = [a for a in range(len(truth)) if not np.isnan(truth[a]).any()]
    off = np.array([0.1, 0.0, 0.0])  # 100 mm on every joint
    sets = [[{'id': 5 + a, 'joints': (truth[a] + k * off).tolist()} for a in actors] for k in range(2)] + [[]]
    path = tmp_path / 'p.jsonl'
    path.write_text(''.join(json.dumps({'frame': k, 'stamp': k, 'people': p}) + '\n' for k, p in enumerate(sets)))
    lines = []
    score_sets(path, 572, None, SimpleNamespace(write=lines.append))
    text = ''.join(lines).splitlines()
    first = actors[0] + 1
    assert text[0].startswith('set   0: ') and f'actor {first}   0.0 mm (id {5 + actors[0]})' in text[0]
    assert f'actor {actors[1] + 1} 100.0 mm (id {5 + actors[1]})' in text[1]
    assert text[2] == 'set   2: ' + ', '.join(f'actor {a + 1} not found' for a in actors)
    assert 'found in 2 of 3 sets' in text[3]
    assert f'Actor {first}: found in 2 sets, MPJPE mean 50.0 mm, min 0.0, max 100.0; ids' in text[4]
    # a set the bag has without some camera is named so, and kept apart in the summary
    lines.clear()
    score_sets(path, 572, None, SimpleNamespace(write=lines.append), {0: [], 1: ['back', 'door'], 2: []})
    text = ''.join(lines).splitlines()
    assert text[0].startswith('set   0: ') and text[1].startswith('set   1 (without back, door): ')
    assert (f'Actor {first}: found in 2 sets, MPJPE mean 50.0 mm, min 0.0, max 100.0; in the 1 with every camera '
            f'mean 0.0, max 0.0; ids') in text[4]


def test_a_bag_at_another_rate_than_frame_rate_is_said_with_the_rate_to_set():
    assert frame_rate_note(None, 25.0) is None  # too few stamps to tell
    assert frame_rate_note(26.0, 25.0) is None and frame_rate_note(23.0, 25.0) is None  # within 10 %
    note = frame_rate_note(15.0, 25.0)
    assert note.startswith("the bag's cameras run at 15.0 Hz, the parameters' frame_rate is 25 Hz") and '\n' not in note
    assert 'set it to 15.0' in note and frame_rate_note(60.0, 25.0).startswith("the bag's cameras run at 60.0 Hz")


def test_the_run_summary_lists_the_refusals_by_camera_and_cause():
    import io
    from collections import Counter
    from mvpose_ros.graph.report import print_refusals
    out = io.StringIO()
    print_refusals({'b': Counter({'no intrinsics yet': 2, 'frame_id x': 5}), 'a': Counter()}, out)
    assert out.getvalue() == 'refused inputs, by camera and cause:\n  b: 5 x frame_id x\n  b: 2 x no intrinsics yet\n'
    out = io.StringIO()
    print_refusals({'a': Counter()}, out)
    assert out.getvalue() == 'refused inputs: none\n'


def test_the_rig_plan_reads_only_the_bags_first_seconds_before_the_graph_starts(rig_file, tmp_path, monkeypatch):
    """A long recording starts at once: the plan reads HEAD_S s of it for the cameras' rate and
    groups the whole bag's sets in a thread, whose future the run takes."""
    from mvpose_ros.bags.io import write_bag
    from sensor_msgs.msg import CompressedImage
    from std_msgs.msg import Header
    import mvpose_ros.graph.session as session
    monkeypatch.setenv('MVPOSE_DATA_ROOT', str(tmp_path / 'no-data'))
    seconds, rate = 3 * session.HEAD_S, 5
    items = []
    for k in range(int(seconds * rate)):
        for n in 'ab':
            header = Header(frame_id=n)
            header.stamp.sec, header.stamp.nanosec = divmod(S + k * S // rate, S)
            items.append((f'/rig/{n}/image', CompressedImage(header=header), S + k * S // rate))
    write_bag(tmp_path / 'bag', items)
    taken: list[int] = []  # messages taken from each read, in the order the reads began
    release = __import__('threading').Event()

    def counted(*args):
        index = len(taken)
        taken.append(0)
        if index:  # the sets' read waits until the plan has returned: it must not need it
            release.wait(10)
        for message in read_bag(*args):
            taken[index] += 1
            yield message
    monkeypatch.setattr(session, 'read_bag', counted)
    args = SimpleNamespace(rig=rig_file, bag=str(tmp_path / 'bag'), config=None, data_root=None, lockstep=False,
                           rate=None, qos=None, predictions=None, loops=1, overrides=[])
    rig, run, settings, files, sets = rig_run_plan(args)
    assert not sets.done() and run.bag_rate == pytest.approx(rate)
    assert taken[0] == 2 * session.HEAD_S * rate + 2 + 1  # up to the first message past HEAD_S
    release.set()
    assert [s.stamp_ns for s in sets.result(10)] == [S + k * S // rate for k in range(int(seconds * rate))]
    assert taken[1] == len(items)


def test_the_first_seconds_sets_are_shown_stage_by_stage():
    import io
    from mvpose_ros.graph.report import print_first_second
    node = SimpleNamespace(info_at={S: 100 * MS, S + PERIOD: 140 * MS, 3 * S: 0},
                           output_at={S: 400 * MS, S + PERIOD: 460 * MS})
    out = io.StringIO()
    stamps = [S, S + PERIOD, S + 2 * PERIOD, 3 * S]
    print_first_second(stamps, [[S, S + 5 * MS], [S + PERIOD], [S + 2 * PERIOD], [3 * S]], node,
                       {S: 300 * MS, S + 5 * MS: 310 * MS, S + PERIOD: 350 * MS}, {S: 390 * MS}, out)
    lines = out.getvalue().splitlines()
    # set 2 never reached detection; the set at 3 s is past the first second
    assert lines[1:] == ['  set   0 (2 cameras): 210 / 290 / 300', '  set   1 (1 cameras): 210 / - / 320']
