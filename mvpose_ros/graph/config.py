"""The graph's configuration: the ROS 2 parameter file read as data, the runner's own settings
in it (pseudo node `mvpose_graph`), and the nodes of the graph with their command lines.

The parameter file is handed to every node unchanged (`--params-file`); per-process values (a
detector's camera, the player's bag and rate) follow it as `-p` overrides, because ROS applies
parameter arguments in order and the last one wins.
"""
from __future__ import annotations

import json
import sys
from dataclasses import dataclass, field
from pathlib import Path
from typing import Mapping, Sequence, get_type_hints

import yaml

from mvpose_ros.core.defaults import FRAME_RATE, SYNC_TIMEOUT_S, max_skew_or_default
from mvpose_ros.core.geometry.rig import Rig
from mvpose_ros.topics import BUNDLES, OPENPOSE, PEOPLE2D, SKELETONS, camera_namespace, camera_topic

RUNNER_SECTION = 'mvpose_graph'
ALL_NODES = '/**'
# The runner's settings every node shares: taken from the '/**' section unless its own sets them.
SHARED_SETTINGS = ('frame_rate',)
PARAMS_KEY = 'ros__parameters'
NODE_PACKAGE = 'mvpose_ros.nodes'

# ROS parameter type names, as `ros2 param describe` prints them.
_TYPE_NAMES = {bool: 'bool', int: 'integer', float: 'double', str: 'string'}


@dataclass(frozen=True)
class GraphSettings:
    """The runner's settings (section `mvpose_graph`); paths relative to the working directory."""

    dataset: str
    cameras: int
    bag: str
    predictions: str
    frame_rate: float
    rate: float
    timeout: float

    def __post_init__(self) -> None:
        if self.cameras < 1:
            raise ValueError(f'cameras must be >= 1; got {self.cameras}')
        if not self.frame_rate > 0 or not self.timeout > 0 or not self.rate >= 0:
            raise ValueError(f'frame_rate and timeout must be > 0 and rate >= 0; '
                             f'got {self.frame_rate}, {self.timeout}, {self.rate}')


@dataclass(frozen=True)
class NodeSpec:
    """One node process: its executable (= node name), namespace ('' = root) and the parameters
    given on its command line after the parameter file."""

    executable: str
    namespace: str = ''
    parameters: dict[str, bool | int | float | str] = field(default_factory=dict)

    @property
    def name(self) -> str:
        """Process name: 'cam2/heatmap_detector', 'association'."""
        return f'{self.namespace}/{self.executable}' if self.namespace else self.executable


def load_params(path: str | Path) -> dict[str, dict[str, object]]:
    """Node key (e.g. 'bag_player', '/**/heatmap_detector') -> its `ros__parameters` mapping."""
    try:
        with open(path, encoding='utf-8') as f:
            doc = yaml.safe_load(f)
    except FileNotFoundError:
        raise FileNotFoundError(f'parameter file not found: {path}') from None
    except yaml.YAMLError as exc:
        raise ValueError(f'{path}: not YAML ({" ".join(str(exc).split())})') from None
    if not isinstance(doc, dict):
        raise ValueError(f'{path}: expected a mapping of node names, got {type(doc).__name__}')
    out = {}
    for node, section in doc.items():
        params = section.get(PARAMS_KEY) if isinstance(section, dict) else None
        if not isinstance(params, dict):
            raise ValueError(f'{path}: {node}: expected a mapping with {PARAMS_KEY}')
        out[str(node)] = params
    return out


def _typed(path: str | Path, key: str, value: object, kind: type) -> object:
    # Strict like ROS: a double parameter rejects `120` (integer), a string rejects `5`.
    if type(value) is not kind:
        raise ValueError(f'{path}: {RUNNER_SECTION}.{key}: expected {_TYPE_NAMES[kind]}, '
                         f'got {_TYPE_NAMES.get(type(value), type(value).__name__)} {value!r}')
    return value


def graph_settings(path: str | Path) -> GraphSettings:
    """The runner's settings from the parameter file (SHARED_SETTINGS from its '/**' section unless
    the runner's sets them); ValueError naming the file and key when one is missing, unknown, of the
    wrong type or out of range."""
    params = load_params(path)
    if RUNNER_SECTION not in params:
        raise ValueError(f'{path}: no {RUNNER_SECTION} section')
    shared = {k: v for k, v in params.get(ALL_NODES, {}).items() if k in SHARED_SETTINGS}
    section = shared | params[RUNNER_SECTION]
    kinds = get_type_hints(GraphSettings)
    unknown = sorted(set(section) - set(kinds))
    if unknown:
        raise ValueError(f'{path}: {RUNNER_SECTION}.{unknown[0]}: unknown setting (known: {", ".join(kinds)})')
    missing = [k for k in kinds if k not in section]
    if missing:
        where = f' (here or in {ALL_NODES})' if missing[0] in SHARED_SETTINGS else ''
        raise ValueError(f'{path}: {RUNNER_SECTION}.{missing[0]}: missing{where}')
    values = {k: _typed(path, k, section[k], kind) for k, kind in kinds.items()}
    try:
        return GraphSettings(**values)
    except ValueError as exc:
        raise ValueError(f'{path}: {RUNNER_SECTION}: {exc}') from None


def graph_nodes(cameras: int, bag: str, rate: float, data_root: str | None = None, loops: int = 1,
                start_topic: str = '') -> list[NodeSpec]:
    """The Shelf graph in start order: a heatmap_detector per camera (namespace cam{c}),
    association, bp_solver, then bag_player (`loops` passes; the runner expects one output per
    stamp of every pass; with `start_topic`, it plays once a message comes there)."""
    data = {'data_root': data_root} if data_root is not None else {}
    player: dict[str, bool | int | float | str] = {'bag': bag, 'rate': float(rate), 'loops': int(loops)}
    if start_topic:
        player['start_topic'] = start_topic
    return [*(NodeSpec('heatmap_detector', camera_namespace(c), {'camera': c, **data}) for c in range(cameras)),
            NodeSpec('association', '', dict(data)),
            NodeSpec('bp_solver', '', dict(data)),
            NodeSpec('bag_player', '', player)]


def output_topics(nodes: Sequence[NodeSpec], detector_output: str = '') -> dict[str, str]:
    """Process name -> the topic (relative) whose messages show that node at work, for telling when
    a restarted node is back: a detector's people2d in its camera namespace (a whole-rig detector
    in the root: `detector_output`, one camera's people2d), association's bundles, bp_solver's
    skeletons; not the player's."""
    out = {}
    for spec in nodes:
        if spec.executable == 'heatmap_detector':
            out[spec.name] = f'{spec.namespace}/{PEOPLE2D}' if spec.namespace else detector_output
        elif spec.executable == 'association':
            out[spec.name] = BUNDLES
        elif spec.executable == 'bp_solver':
            out[spec.name] = SKELETONS
    return out


def _ros_value(value: bool | int | float | str) -> str:
    """A `-p name:=value` value, which ROS parses as YAML: JSON strings are YAML strings, so a
    path such as '2024' or 'true' stays a string."""
    if isinstance(value, bool):
        return 'true' if value else 'false'
    if isinstance(value, (int, float)):
        return repr(value)
    return json.dumps(value)


def node_command(spec: NodeSpec, params_file: str | Path | Sequence[str | Path],
                 python: str = sys.executable) -> list[str]:
    """The command running `spec` with this interpreter, so that nodes run the runner's own code.
    Several parameter files are given in order (a later one overrides an earlier one)."""
    cmd = [python, '-m', f'{NODE_PACKAGE}.{spec.executable}', '--ros-args']
    if spec.namespace:
        cmd += ['-r', f'__ns:=/{spec.namespace}']
    for path in [params_file] if isinstance(params_file, (str, Path)) else params_file:
        cmd += ['--params-file', str(path)]
    for name, value in spec.parameters.items():
        cmd += ['-p', f'{name}:={_ros_value(value)}']
    return cmd


# --compose: which nodes share a process (nodes.composed); the player always has its own, as its
# exit ends the bag. 'none': a process per node.
COMPOSED = {'none': ('', ()),
            'detectors': ('heatmap_detectors', ('heatmap_detector',)),
            'detectors+association': ('detectors_association', ('heatmap_detector', 'association')),
            'all': ('composed', ('heatmap_detector', 'association', 'bp_solver'))}
# Every node but the player in one process: as fast as a process per node, on less CPU and a
# fraction of the memory (docs/footprint.md).
DEFAULT_COMPOSE = 'all'


def processes(nodes: Sequence[NodeSpec], compose: str | None = None) -> list[tuple[str, list[NodeSpec]]]:
    """The graph's processes in the nodes' order: (process name, its nodes); with `compose` (a key
    of COMPOSED), the nodes it names in one process, at the place of the first of them."""
    name, executables = COMPOSED[compose or 'none']
    out: list[tuple[str, list[NodeSpec]]] = []
    for spec in nodes:
        if spec.executable not in executables:
            out.append((spec.name, [spec]))
        elif out and any(n == name for n, _ in out):
            next(specs for n, specs in out if n == name).append(spec)
        else:
            out.append((name, [spec]))
    return out


def composed_command(specs: Sequence[NodeSpec], params_file: str | Path | Sequence[str | Path],
                     python: str = sys.executable) -> list[str]:
    """The command of one process running the nodes `specs` (nodes.composed): each node's
    arguments, as node_command gives them, after `--node <executable>`."""
    cmd = [python, '-m', f'{NODE_PACKAGE}.composed']
    for spec in specs:
        cmd += ['--node', spec.executable, *node_command(spec, params_file, python)[3:]]
    return cmd


def detector_backend(params: Mapping[str, Mapping[str, object]]) -> str:
    """The `backend` the file gives the heatmap detectors ('openpose', the node's default, when
    none does); ValueError when its heatmap_detector sections disagree."""
    backends = {str(section['backend']) for node, section in params.items()
                if node.rsplit('/', 1)[-1] == 'heatmap_detector' and 'backend' in section}
    if len(backends) > 1:
        raise ValueError(f'heatmap_detector sections give different backends {sorted(backends)}: '
                         f'the runner needs one input topic for every camera')
    return backends.pop() if backends else 'openpose'


def expected_connections(cameras: int, input_topic: str = OPENPOSE) -> dict[str, Sequence[str]]:
    """Topic (relative to the rig's namespace) -> endpoints ('pub', 'sub') that must exist before
    the player may start; each detector reads cam<c>/<input_topic>."""
    topics: dict[str, Sequence[str]] = {}
    for c in range(cameras):
        topics[camera_topic(c, input_topic)] = ('sub',)
        topics[camera_topic(c, PEOPLE2D)] = ('pub', 'sub')
    topics[BUNDLES] = ('pub', 'sub')
    topics[SKELETONS] = ('pub',)
    return topics


def played_connections(cameras: int, input_topic: str = OPENPOSE) -> dict[str, Sequence[str]]:
    """The Shelf graph's links from the player that must be matched before it plays: each
    detector's cam<c>/<input_topic>."""
    return {camera_topic(c, input_topic): ('pub', 'sub') for c in range(cameras)}


def unknown_nodes(params: Mapping[str, object], nodes: Sequence[NodeSpec]) -> list[str]:
    """Sections of the parameter file that match none of `nodes` (typos) besides the runner's."""
    known = {RUNNER_SECTION}.union(*(section_keys(spec.executable, spec.namespace) for spec in nodes))
    return sorted(set(params) - known)


# What `mvpose-graph --rig` runs when --config does not say otherwise (package file, see its comments).
RIG_TEMPLATE = 'config/rig_template.yaml'
# The runner's own settings of a --rig run; their defaults are the template's mvpose_graph section.
RIG_RUNNER_KEYS = ('predictions', 'rate', 'timeout', 'qos', 'ack_timeout')
LOCKSTEP_ACK = BUNDLES  # a set is done once its bundle is out (the 3D stage holds skeletons back `lag` sets)
# Lockstep: a set the sync releases late (a camera missing from it, decided by the next set's
# image or the sync timeout) can leave together with the next; the detector keeps both.
LOCKSTEP_WAITING_SETS = 8


@dataclass(frozen=True)
class RigRun:
    """A run of the graph on a recorded rig: the rig file (absolute), the bag, lockstep or `rate`,
    the player's QoS ('sensor' or 'reliable'), the set synchronisation (max_skew, sync_timeout,
    s, as the graph's association), and ack_timeout (lockstep: s after which a set the graph
    dropped is given up); loops: passes over the bag (stamps moved on as the player does);
    frame_rate: the nodes' (Hz; max_skew's default and bp_solver's nominal step follow it);
    bag_rate: the rate of the bag's cameras (Hz, approximate_sync.stamp_rate; None: too few stamps);
    rate_from_bag: frame_rate is bag_rate, which the runner gives the nodes (no parameter file
    of the user's sets frame_rate, and the template's is too far from the bag's)."""

    rig: str
    bag: str
    lockstep: bool
    rate: float
    qos: str
    max_skew: float
    sync_timeout: float
    ack_timeout: float
    loops: int = 1
    frame_rate: float = FRAME_RATE
    bag_rate: float | None = None
    rate_from_bag: bool = False


def runner_section(params_list: Sequence[Mapping[str, Mapping[str, object]]]) -> dict[str, object]:
    """The merged mvpose_graph sections of parameter files (a later file overrides)."""
    out: dict[str, object] = {}
    for params in params_list:
        out |= dict(params.get(RUNNER_SECTION, {}))
    return out


def rig_sync(params_list: Sequence[Mapping[str, Mapping[str, object]]],
             frame_rate: float | None = None) -> tuple[float, float]:
    """max_skew and sync_timeout (s) the association node gets from these parameter files (its
    defaults: max_skew 0 = half a frame period of frame_rate, theirs unless given, 25 Hz;
    sync_timeout 0.5 s)."""
    section = node_section(params_list, 'association')
    rate = rig_frame_rate(params_list) if frame_rate is None else frame_rate
    max_skew = max_skew_or_default(float(section.get('max_skew', 0.0)), rate)
    return max_skew, float(section.get('sync_timeout', SYNC_TIMEOUT_S))


def rig_frame_rate(params_list: Sequence[Mapping[str, Mapping[str, object]]]) -> float:
    """The frame_rate (Hz) the association node gets from these parameter files (default 25)."""
    return float(node_section(params_list, 'association').get('frame_rate', FRAME_RATE))


def sets_frame_rate(params_list: Sequence[Mapping[str, Mapping[str, object]]]) -> bool:
    """Whether any node section of these parameter files sets frame_rate."""
    return any('frame_rate' in values for params in params_list for node, values in params.items()
               if node != RUNNER_SECTION)


def section_keys(node: str, namespace: str = '') -> set[str]:
    """The keys of a parameter file's sections that ROS hands the node `node` in `namespace`: every
    node's '/**', its bare name, its full name and '/**/<node>' (any namespace)."""
    full = f'/{namespace}/{node}' if namespace else f'/{node}'
    return {ALL_NODES, node, full, f'/**/{node}'}


def node_section(params_list: Sequence[Mapping[str, Mapping[str, object]]], node: str) -> dict[str, object]:
    """The parameters these files give the node `node` (in the root namespace), a later section winning."""
    keys = section_keys(node)
    section: dict[str, object] = {}
    for params in params_list:
        for key, values in params.items():
            if key in keys:
                section |= dict(values)
    return section


def rig_graph_nodes(run: RigRun, data_root: str | None = None, start_topic: str = '',
                    overlay: bool = False) -> list[NodeSpec]:
    """The graph of a recorded rig in start order: ONE heatmap_detector for the whole rig (camera
    'all'), association, bp_solver (each with the rig, and the bag's frame_rate when
    run.rate_from_bag), with `overlay` the overlay node (in
    lockstep drawing every set), then bag_player (lockstep: sets, rate 0, one set in flight
    acknowledged on people/bundles; else `rate`, every message at its time)."""
    data = {'data_root': data_root} if data_root is not None else {}
    rate = {'frame_rate': float(run.frame_rate)} if run.rate_from_bag else {}
    rig: dict[str, bool | int | float | str] = {'rig': run.rig, **data, **rate}
    waiting = {'waiting_sets': LOCKSTEP_WAITING_SETS} if run.lockstep else {}
    player: dict[str, bool | int | float | str] = {
        'bag': run.bag, 'qos': run.qos, 'max_skew': float(run.max_skew), 'sync_timeout': float(run.sync_timeout),
        'loops': int(run.loops)}
    if run.lockstep:
        player |= {'rate': 0.0, 'sets': True, 'max_in_flight': 1, 'ack_topic': LOCKSTEP_ACK,
                   'ack_timeout': float(run.ack_timeout)}
    else:
        player |= {'rate': float(run.rate), 'sets': False}
    if start_topic:
        player['start_topic'] = start_topic
    drawing = [NodeSpec('overlay', '', {**rig, **({'max_rate': 0.0} if run.lockstep else {})})] if overlay else []
    return [NodeSpec('heatmap_detector', '', {'camera': 'all', **rig, **waiting}),
            NodeSpec('association', '', dict(rig)),
            NodeSpec('bp_solver', '', dict(rig)),
            *drawing,
            NodeSpec('bag_player', '', player)]


def rig_connections(rig: Rig) -> dict[str, Sequence[str]]:
    """Topic -> endpoints that must exist before the player of a rig bag may start: a reader of
    every camera's image topic (the detector), both ends of every <camera>/people2d and of the
    bundles, and the skeletons' writer."""
    topics: dict[str, Sequence[str]] = {}
    for camera in rig.cameras:
        topics[camera.image] = ('sub',)
        topics[camera_topic(camera.name, PEOPLE2D)] = ('pub', 'sub')
    topics[BUNDLES] = ('pub', 'sub')
    topics[SKELETONS] = ('pub',)
    return topics


def rig_played_connections(rig: Rig, lockstep: bool = False) -> dict[str, Sequence[str]]:
    """The player's links of a rig bag run that must be matched before it plays: every camera's
    image and camera_info topic (the detector, association and bp_solver read the CameraInfo of a
    rig without intrinsics) and, in lockstep, the acknowledgements it reads (a first one it missed
    would hold the next set back for ack_timeout)."""
    links: dict[str, Sequence[str]] = {topic: ('pub', 'sub') for camera in rig.cameras
                                       for topic in (camera.image, camera.camera_info)}
    if lockstep:
        links[LOCKSTEP_ACK] = ('pub', 'sub')
    return links


def write_overrides(nodes: Sequence[NodeSpec], path: str | Path) -> Path:
    """A parameter file with every node's command-line values under '/**/<node>', to be given
    after the others: a '/**/<node>' section of a parameter file wins over `-p` arguments, so the
    runner's values must come as the last such file to win."""
    doc = {f'/**/{spec.executable}': {PARAMS_KEY: dict(spec.parameters)} for spec in nodes if spec.parameters}
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text('# Written by mvpose-graph: the values it gives each node (they override the files before).\n'
                    + yaml.safe_dump(doc, sort_keys=False), encoding='utf-8')
    return path
