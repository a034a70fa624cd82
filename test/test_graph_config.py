"""config/shelf.yaml as the real nodes read it, the runner's settings and their errors, the node
command lines, and the runner's pure report helpers."""
from __future__ import annotations

import importlib
import io
from collections import Counter
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest
import rclpy
import yaml
from rclpy.signals import SignalHandlerOptions
from sensor_msgs.msg import PointCloud2

from mvpose_ros.bags.io import write_bag
from mvpose_ros.graph.config import (ALL_NODES, RUNNER_SECTION, GraphSettings, NodeSpec, expected_connections,
                                     graph_nodes, graph_settings, load_params, node_command, played_connections,
                                     composed_command, node_section, processes, rig_sync,
                                     section_keys, unknown_nodes)
from mvpose_ros.nodes import composed
from mvpose_ros.graph.report import frame_ranges, latency_ms, print_latency, report
from ros_harness import ros_domain

CONFIG = Path(__file__).resolve().parents[1] / 'config' / 'shelf.yaml'
SECTIONS = {'bag_player': 'bag_player', 'heatmap_detector': '/**/heatmap_detector',
            'association': 'association', 'bp_solver': 'bp_solver'}
NODE_CLASSES = {'bag_player': 'BagPlayerNode', 'heatmap_detector': 'HeatmapDetectorNode',
                'association': 'AssociationNode', 'bp_solver': 'BpSolverNode'}
# The contract's runner settings (section mvpose_graph).
RUNNER_DEFAULTS = GraphSettings(dataset='shelf', cameras=5, bag='bags/shelf', predictions='out/shelf_graph.jsonl',
                                frame_rate=25.0, rate=1.0, timeout=120.0)


def test_sections_and_runner_settings():
    assert set(load_params(CONFIG)) == {ALL_NODES, *SECTIONS.values(), RUNNER_SECTION}
    assert graph_settings(CONFIG) == RUNNER_DEFAULTS


@pytest.mark.parametrize('name', ['shelf.yaml', 'shelf_images.yaml'])
def test_the_frame_rate_is_given_once_for_every_node_and_the_runner(name):
    params = load_params(CONFIG.with_name(name))
    assert [node for node, section in params.items() if 'frame_rate' in section] == [ALL_NODES]
    assert graph_settings(CONFIG.with_name(name)).frame_rate == params[ALL_NODES]['frame_rate'] == 25.0


def test_the_runners_own_frame_rate_wins_and_one_is_needed(tmp_path):
    assert graph_settings(_edited(tmp_path, frame_rate=30.0)).frame_rate == 30.0
    doc = yaml.safe_load(CONFIG.read_text())
    del doc[ALL_NODES]
    path = tmp_path / 'none.yaml'
    path.write_text(yaml.safe_dump(doc))
    with pytest.raises(ValueError, match=rf'^{path}: {RUNNER_SECTION}\.frame_rate: missing \(here or in /\*\*\)$'):
        graph_settings(path)


def test_real_nodes_take_every_value_of_the_file(tmp_path, monkeypatch):
    """Each node class, started with its runner command line: every key of its section is a
    parameter it declares (ROS silently ignores others) and arrives with the file's value and type
    (a double written as `1` would stop the node), the per-process overrides after it, and the
    namespace from the remap."""
    bag = tmp_path / '2024'  # a name ROS would read as an integer unless quoted
    write_bag(bag, [('/cam0/openpose', PointCloud2(), 12_000_000_000)])
    params = load_params(CONFIG)
    nodes = graph_nodes(5, str(bag), 0.5, start_topic='bag_player/start')
    assert [n.name for n in nodes] == [*(f'cam{c}/heatmap_detector' for c in range(5)), 'association',
                                       'bp_solver', 'bag_player']
    with ros_domain(monkeypatch):
        _check_nodes(nodes[3:], params)  # cam3, cam4 and every other node


def _check_nodes(nodes, params):
    for spec in nodes:
        cmd = node_command(spec, CONFIG, python='python')
        assert cmd[:4] == ['python', '-m', f'mvpose_ros.nodes.{spec.executable}', '--ros-args']
        node_class = getattr(importlib.import_module(f'mvpose_ros.nodes.{spec.executable}'),
                             NODE_CLASSES[spec.executable])
        rclpy.init(args=['prog', *cmd[3:]], signal_handler_options=SignalHandlerOptions.NO)
        node = None
        try:
            node = node_class()
            declared = set(node.list_parameters([], 0).names)
            section = params[SECTIONS[spec.executable]]
            assert set(section) <= declared, f'{spec.name}: not parameters of the node: {set(section) - declared}'
            every = {k: v for k, v in params[ALL_NODES].items() if k in declared}  # e.g. frame_rate
            expected = {**every, **section, **spec.parameters}
            got = {name: node.get_parameter(name).value for name in expected}
            fqn = node.get_fully_qualified_name()
        finally:
            if node is not None:
                node.destroy_node()
            rclpy.try_shutdown()
        assert got == expected, spec.name
        assert {k: type(v) for k, v in got.items()} == {k: type(v) for k, v in expected.items()}, spec.name
        assert fqn == f'/{spec.name}'


def test_composed_nodes_take_their_own_arguments_in_one_process(monkeypatch):
    """--compose all: one process with every node but the player, each node with its own namespace,
    the file's values and its own per-process overrides (a camera index each), as if alone."""
    nodes = graph_nodes(5, 'b', 1.0)
    assert [name for name, _ in processes(nodes, 'detectors')] == ['heatmap_detectors', 'association', 'bp_solver',
                                                                   'bag_player']
    assert [name for name, _ in processes(nodes)] == [n.name for n in nodes]
    assert [name for name, _ in processes(nodes, 'none')] == [n.name for n in nodes]
    front = processes(nodes, 'detectors+association')
    assert [name for name, _ in front] == ['detectors_association', 'bp_solver', 'bag_player']
    (name, specs), player = processes(nodes, 'all')
    assert (name, player[0]) == ('composed', 'bag_player')
    assert [s.name for s in specs] == [n.name for n in nodes[:-1]]
    cmd = composed_command(specs, CONFIG, python='python')
    assert cmd[:3] == ['python', '-m', 'mvpose_ros.nodes.composed']
    parsed = composed.parse(cmd[3:])
    assert [exe for exe, _ in parsed] == [s.executable for s in specs]
    factories, events = composed.factories(parsed)
    # bp_solver needs rclpy's single-threaded executor, the others take the events executor
    assert events == [s.executable != 'bp_solver' for s in specs]
    params = load_params(CONFIG)
    with ros_domain(monkeypatch):
        rclpy.init(args=['prog'], signal_handler_options=SignalHandlerOptions.NO)
        made = []
        try:
            for factory in factories:
                made.append(factory())
            for spec, node in zip(specs, made):
                assert node.get_fully_qualified_name() == f'/{spec.name}'
                section = params[SECTIONS[spec.executable]]
                expected = {**section, **spec.parameters}
                assert {k: node.get_parameter(k).value for k in expected} == expected, spec.name
        finally:
            for node in made:
                node.destroy_node()
            rclpy.try_shutdown()


@pytest.mark.parametrize('argv, message', [([], 'expected --node'),
                                           (['--node', 'bag_player'], 'not a node that can be composed'),
                                           (['--node'], 'without an executable')])
def test_a_composed_command_line_is_checked(argv, message):
    with pytest.raises(ValueError, match=message):
        composed.parse(argv)


def _started_parameters(executable: str, module: str, cls: str, files: list, names: tuple, monkeypatch) -> dict:
    """The values of `names` that the graph's first `executable` node takes from parameter files."""
    spec = next(n for n in graph_nodes(5, 'b', 1.0) if n.executable == executable)
    cmd = node_command(spec, files, python='python')
    with ros_domain(monkeypatch):
        rclpy.init(args=['prog', *cmd[3:]], signal_handler_options=SignalHandlerOptions.NO)
        node = getattr(importlib.import_module(module), cls)()
        try:
            return {k: node.get_parameter(k).value for k in names}
        finally:
            node.destroy_node()
            rclpy.try_shutdown()


def test_crowd_overrides_reach_the_nodes_after_the_file(monkeypatch):
    """config/crowd.yaml (mvpose-graph --overrides) holds bp_solver and detector values only; given
    after shelf.yaml, the real nodes take them and keep the file's others."""
    crowd = CONFIG.with_name('crowd.yaml')
    overrides = load_params(crowd)
    assert set(overrides) == {'bp_solver', '/**/heatmap_detector'}
    shelf = load_params(CONFIG)
    got = _started_parameters('bp_solver', 'mvpose_ros.nodes.bp_solver', 'BpSolverNode', [CONFIG, crowd],
                              ('hypotheses', 'bp_hypotheses', 'window', 'lag'), monkeypatch)
    assert got == {**overrides['bp_solver'], 'window': shelf['bp_solver']['window'], 'lag': shelf['bp_solver']['lag']}
    assert got['hypotheses'] != shelf['bp_solver']['hypotheses']
    got = _started_parameters('heatmap_detector', 'mvpose_ros.nodes.heatmap_detector', 'HeatmapDetectorNode',
                              [CONFIG, crowd], ('secondary_radius', 'stride'), monkeypatch)
    detector = shelf['/**/heatmap_detector']
    assert got == {**overrides['/**/heatmap_detector'], 'stride': detector['stride']}
    assert got['secondary_radius'] != detector['secondary_radius']


def test_overrides_take_node_sections_only(tmp_path):
    from mvpose_ros.graph.session import _override_files
    bad = tmp_path / 'bad.yaml'
    bad.write_text(f'{RUNNER_SECTION}:\n  ros__parameters:\n    rate: 2.0\n')
    with pytest.raises(ValueError, match=f'bad.yaml: --overrides takes node sections only, not {RUNNER_SECTION}'):
        _override_files([bad])
    assert _override_files([CONFIG.with_name('crowd.yaml')]) == [CONFIG.with_name('crowd.yaml').resolve()]


def test_command_puts_overrides_after_the_file():
    spec = NodeSpec('heatmap_detector', 'cam3', {'camera': 3, 'data_root': 'true'})
    cmd = node_command(spec, '/p.yaml', python='py')
    assert cmd == ['py', '-m', 'mvpose_ros.nodes.heatmap_detector', '--ros-args', '-r', '__ns:=/cam3',
                   '--params-file', '/p.yaml', '-p', 'camera:=3', '-p', 'data_root:="true"']
    assert [n.parameters.get('data_root') for n in graph_nodes(2, 'b', 1.0, data_root='/d')] == ['/d'] * 4 + [None]
    # the player waits for a start signal only when asked to
    assert 'start_topic' not in graph_nodes(2, 'b', 1.0)[-1].parameters
    assert graph_nodes(2, 'b', 1.0, start_topic='bag_player/start')[-1].parameters['start_topic'] == 'bag_player/start'


def test_expected_connections_and_unknown_sections():
    links = expected_connections(2)
    assert links == {'cam0/openpose': ('sub',), 'cam0/people2d': ('pub', 'sub'), 'cam1/openpose': ('sub',),
                     'cam1/people2d': ('pub', 'sub'), 'people/bundles': ('pub', 'sub'), 'skeletons': ('pub',)}
    assert expected_connections(1, 'image_raw') == {'cam0/image_raw': ('sub',), 'cam0/people2d': ('pub', 'sub'),
                                                    'people/bundles': ('pub', 'sub'), 'skeletons': ('pub',)}
    assert played_connections(2) == {'cam0/openpose': ('pub', 'sub'), 'cam1/openpose': ('pub', 'sub')}
    nodes = graph_nodes(5, 'b', 1.0)
    params = {'bag_player': {}, '/**/heatmap_detector': {}, '/cam1/heatmap_detector': {}, '/**/heatmap_detectr': {},
              'association': {}, 'bpsolver': {}, RUNNER_SECTION: {}}
    assert unknown_nodes(params, nodes) == ['/**/heatmap_detectr', 'bpsolver']


def test_a_node_takes_the_sections_ros_hands_it_and_a_later_one_wins():
    assert section_keys('heatmap_detector', 'cam1') == {'/**', 'heatmap_detector', '/cam1/heatmap_detector',
                                                        '/**/heatmap_detector'}
    first = {'/**': {'frame_rate': 15.0, 'seed': 1}, 'association': {'max_skew': 0.01}, 'bp_solver': {'seed': 2}}
    second = {'/**/association': {'max_skew': 0.03}, '/cam0/association': {'max_skew': 9.0}}
    assert node_section([first, second], 'association') == {'frame_rate': 15.0, 'seed': 1, 'max_skew': 0.03}
    # association's own defaults where the files say nothing: max_skew 0 is half a period of frame_rate
    assert rig_sync([{'/**': {'frame_rate': 10.0}}]) == (0.05, 0.5)


def _edited(tmp_path: Path, **changes) -> Path:
    doc = yaml.safe_load(CONFIG.read_text())
    section = doc[RUNNER_SECTION]['ros__parameters']
    for key, value in changes.items():
        if value is None:
            del section[key]
        else:
            section[key] = value
    path = tmp_path / 'edited.yaml'
    path.write_text(yaml.safe_dump(doc))
    return path


@pytest.mark.parametrize('changes, message', [
    ({'timeout': '120'}, r'mvpose_graph\.timeout: expected double, got string'),
    ({'timeout': 120}, r'mvpose_graph\.timeout: expected double, got integer 120'),
    ({'cameras': 5.0}, r'mvpose_graph\.cameras: expected integer, got double'),
    ({'cameras': True}, r'mvpose_graph\.cameras: expected integer, got bool'),
    ({'dataset': 3}, r'mvpose_graph\.dataset: expected string'),
    ({'predictions': None}, r'mvpose_graph\.predictions: missing'),
    ({'timout': 1.0}, r'mvpose_graph\.timout: unknown setting'),
    ({'rate': -1.0}, r'mvpose_graph: .*rate >= 0'),
    ({'cameras': 0}, r'mvpose_graph: cameras must be >= 1'),
])
def test_bad_runner_settings_name_file_and_key(tmp_path, changes, message):
    path = _edited(tmp_path, **changes)
    with pytest.raises(ValueError, match=f'^{path}: {message}'):
        graph_settings(path)


@pytest.mark.parametrize('text, message', [
    ('bag_player: [1, 2\n', 'not YAML'),
    ('- a\n- b\n', 'expected a mapping of node names'),
    ('bag_player:\n  rate: 1.0\n', 'bag_player: expected a mapping with ros__parameters'),
    ('bag_player:\n  ros__parameters:\n    rate: 1.0\n', 'no mvpose_graph section'),
])
def test_malformed_files(tmp_path, text, message):
    path = tmp_path / 'bad.yaml'
    path.write_text(text)
    with pytest.raises(ValueError, match=message):
        graph_settings(path)


def test_missing_file(tmp_path):
    with pytest.raises(FileNotFoundError, match=f'parameter file not found: {tmp_path}/none.yaml'):
        graph_settings(tmp_path / 'none.yaml')


def test_frame_ranges_and_latency():
    assert frame_ranges([305, 300, 301, 302, 410, 303, 304, 412, 411, 500]) == '300-305, 410-412, 500'
    assert frame_ranges([]) == 'none'
    t0 = 1_795_000_000_000_000_000  # ns since the epoch: int64 keeps every nanosecond
    lat = latency_ms({1: t0, 2: t0 + 40_000_000, 3: t0 + 80_000_000},
                     {2: t0 + 290_000_000, 3: t0 + 580_000_001, 4: t0})
    np.testing.assert_allclose(lat, [250.0, 500.000001], rtol=0, atol=1e-9)


def test_report_counts_missing_duplicate_unexpected_and_bad_outputs():
    ns = [f * 40_000_000 for f in range(300, 306)]  # frames 300..305 at 25 Hz
    stray = 400 * 40_000_000
    one = (np.array([0]), np.zeros((1, 14, 3)))
    node = SimpleNamespace(
        info_at={s: 1_000 + i for i, s in enumerate(ns)},
        outputs={s: one for s in ns[:2] + ns[4:] + [stray]},  # 302 and 303 missing
        output_at={s: 2_001_000 + i for i, s in enumerate(ns[:2] + ns[4:] + [stray])},
        live_at={s: 1_501_000 for s in ns},  # the causal estimate of every frame, sooner
        dropped=set(),
        received=Counter({**{s: 1 for s in ns[:2] + ns[4:] + [stray]}, ns[1]: 3}),
        bad=['12040000000 ns: person 0 has 13 joints'])
    out = io.StringIO()
    problems = report(ns, node, RUNNER_DEFAULTS, out)
    lines = out.getvalue().splitlines()
    assert lines[0] == 'frames in 6 (seen on /cam0/camera_info: 6), frames out 4'
    assert lines[1] == 'missing 2: 302-303; duplicate 1: 301; unexpected 1: 400'
    assert lines[2].startswith('latency /cam0/camera_info -> /skeletons: p50 2.0 ms')
    assert lines[2].endswith('(4 frames)')
    assert lines[5].startswith('latency /cam0/camera_info -> /skeletons/live: p50 1.5 ms')
    assert lines[5].endswith('(6 frames)')
    assert problems == ['2 of 6 input stamps got no /skeletons', '1 stamps got more than one /skeletons',
                        '1 /skeletons stamps are not in the bag',
                        '1 undecodable /skeletons messages, first: 12040000000 ns: person 0 has 13 joints']
    # a frame the graph dropped (skeletons/dropped) is counted apart, not as missing
    node.dropped = {ns[3]}
    out = io.StringIO()
    problems = report(ns, node, RUNNER_DEFAULTS, out)
    assert out.getvalue().splitlines()[1] == ('missing 1: 302; dropped (skeletons/dropped: too few cameras in a set, '
                                              'or behind the input) 1: 303; duplicate 1: 301; unexpected 1: 400')
    assert problems[0] == '1 of 6 input stamps got no /skeletons'


def test_latency_is_reported_by_quarter_of_the_run():
    """A graph falling behind in its last quarter: p50 and p95 of each quarter, in run order."""
    lat = np.concatenate([np.full(10, 100.0), np.full(10, 110.0), np.full(10, 120.0), np.arange(10) * 100.0 + 200])
    out = io.StringIO()
    print_latency(lat, '/cam0/camera_info', 'frames', out)
    lines = out.getvalue().splitlines()
    assert lines[1] == 'latency p50 by quarter of the run: 100, 110, 120, 650 ms'
    assert lines[2] == 'latency p95 by quarter of the run: 100, 110, 120, 1055 ms'


def test_tracked_crops_overrides_turn_the_rig_detector_to_lightning_on_tracked_crops():
    """config/tracked_crops.yaml (mvpose-graph --overrides) holds detector values only; after the
    rig template they give a valid detector configuration: MoveNet Lightning on crops, MultiPose's
    whole-image search every 10th set, the template's workers kept."""
    from mvpose_ros.core.detection.detector_settings import DetectorConfig
    from mvpose_ros.graph.config import node_section
    template = load_params(CONFIG.with_name('rig_template.yaml'))
    overrides = load_params(CONFIG.with_name('tracked_crops.yaml'))
    assert set(overrides) == {'/**/heatmap_detector'}
    settings = DetectorConfig.from_params(node_section([template, overrides], 'heatmap_detector'))
    onnx = settings.onnx
    assert (onnx.heatmaps, onnx.model, settings.person_detector_every) == ('efficientpose', 'lightning', 10)
    assert settings.onnx.crop_workers == template['/**/heatmap_detector']['crop_workers'] == 2
