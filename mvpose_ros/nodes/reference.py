"""The node reference (docs/nodes.md), generated: each node is started in the configurations
listed in CONFIGURATIONS, and what it declared (every parameter with its type, default,
description, range and whether it is live) and the endpoints it made (topic, message type, QoS)
are read back from rclpy and written as markdown, one uniform section per node."""
from __future__ import annotations

import difflib
import importlib
import os
import tempfile
from contextlib import contextmanager
from dataclasses import dataclass, field
from itertools import takewhile
from pathlib import Path
from typing import Any, Iterator

import rclpy
from rcl_interfaces.msg import ParameterDescriptor, ParameterType
from rclpy.node import Node
from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy

from mvpose_ros.bags.io import write_bag
from mvpose_ros.bags.recipes import ForeignRig, make_recipe, rig_file_text
from mvpose_ros.core.datasets.shelf_campus import calibration_file
from mvpose_ros.core.defaults import data_root
from mvpose_ros.core.geometry.rig import load_rig_file
from mvpose_ros.nodes.runtime import DEFAULT_RIG
from mvpose_ros.package_files import package_path

COMMAND = 'mvpose-docs nodes'  # what regenerates the page
ROS_OWN = ('/rosout', '/parameter_events')  # endpoints rclpy gives every node
RCL_OWN = ('use_sim_time', 'qos_overrides.', 'start_type_description_service')  # parameters rclpy declares itself


@dataclass(frozen=True)
class Configuration:
    """One way a node is started for the reference: its module, class, ROS arguments and what
    the configuration is, in words."""

    module: str
    cls: str
    title: str
    args: tuple[str, ...] = ()  # {bag} and {rig}: the bag and the rig file collect() writes


CONFIGURATIONS = (
    Configuration('bag_player', 'BagPlayerNode', "playing a bag of the Shelf bag's first frame",
                  ('-p', 'bag:={bag}')),
    Configuration('heatmap_detector', 'HeatmapDetectorNode', 'one camera, openpose backend, in namespace '
                  '/cam0 as in the Shelf graph', ('-r', '__ns:=/cam0', '-p', 'camera:=0')),
    Configuration('heatmap_detector', 'HeatmapDetectorNode', 'whole rig, onnx backend, person_detector_every 3',
                  ('-p', 'camera:=all', '-p', 'backend:=onnx', '-p', 'person_detector_every:=3')),
    Configuration('association', 'AssociationNode', 'the Shelf rig'),
    Configuration('association', 'AssociationNode', 'a rig file without intrinsics: the shelf_rig bag\'s, under '
                  'its driver names', ('-p', 'rig:={rig}')),
    Configuration('bp_solver', 'BpSolverNode', 'the Shelf rig'),
    Configuration('bp_solver', 'BpSolverNode', 'the shelf_rig bag\'s rig file, without intrinsics',
                  ('-p', 'rig:={rig}')),
    Configuration('overlay', 'OverlayNode', 'the Shelf rig'),
    Configuration('overlay', 'OverlayNode', 'the shelf_rig bag\'s rig file, without intrinsics', ('-p', 'rig:={rig}')),
    Configuration('skeleton_echo', 'SkeletonEcho', 'as it comes'),
    Configuration('foxglove_view', 'FoxgloveView', 'no client connected (here on any free port)', ('-p', 'port:=0')),
)


@dataclass(frozen=True)
class Parameter:
    """A declared parameter: name, type name, default as declared, description, range, live."""

    name: str
    type: str
    default: Any
    description: str
    range: str
    live: bool


@dataclass(frozen=True)
class Endpoint:
    """A publisher or subscription: 'publishes' or 'subscribes', topic, message type, QoS in words."""

    kind: str
    topic: str
    type: str
    qos: str


@dataclass
class NodeReference:
    """One node: its summary (the module docstring's first paragraph), its parameters, and its
    endpoints per configuration."""

    name: str
    summary: str
    parameters: list[Parameter] = field(default_factory=list)
    endpoints: dict[str, list[Endpoint]] = field(default_factory=dict)


_TYPE_NAMES = {ParameterType.PARAMETER_BOOL: 'bool', ParameterType.PARAMETER_INTEGER: 'int',
               ParameterType.PARAMETER_DOUBLE: 'float', ParameterType.PARAMETER_STRING: 'string',
               ParameterType.PARAMETER_STRING_ARRAY: 'string[]', ParameterType.PARAMETER_DOUBLE_ARRAY: 'float[]',
               ParameterType.PARAMETER_INTEGER_ARRAY: 'int[]', ParameterType.PARAMETER_BOOL_ARRAY: 'bool[]'}


def _type_name(value: Any, descriptor: ParameterDescriptor) -> str:
    if descriptor.dynamic_typing:
        return 'any'
    if isinstance(value, rclpy.Parameter.Type):
        return _TYPE_NAMES[value.value]
    return _TYPE_NAMES[rclpy.Parameter.Type.from_parameter_value(value).value]


def _number(x: float) -> str:
    if abs(x) == float('inf'):
        return 'inf' if x > 0 else '-inf'
    return str(int(x)) if x == int(x) else repr(x)


def _range(descriptor: ParameterDescriptor) -> str:
    bounds = descriptor.integer_range or descriptor.floating_point_range
    if not bounds:
        return ''
    low, high = bounds[0].from_value, bounds[0].to_value
    big = 2 ** 63 - 1
    low = -float('inf') if low == -big else low
    high = float('inf') if high == big else high
    return f'{_number(low)} .. {_number(high)}'


def _default(value: Any) -> str:
    if isinstance(value, rclpy.Parameter.Type):
        return '[]'
    if isinstance(value, bool):
        return str(value).lower()
    if isinstance(value, str):
        return repr(value)
    return str(value)


def _qos(profile: QoSProfile) -> str:
    reliability = {ReliabilityPolicy.RELIABLE: 'reliable', ReliabilityPolicy.BEST_EFFORT: 'best effort'}
    durability = {DurabilityPolicy.VOLATILE: 'volatile', DurabilityPolicy.TRANSIENT_LOCAL: 'transient local'}
    history = 'keep all' if profile.history == HistoryPolicy.KEEP_ALL else f'keep last {profile.depth}'
    return f'{reliability[profile.reliability]}, {durability[profile.durability]}, {history}'


def _message_type(msg_type: type) -> str:
    package = msg_type.__module__.split('.')[0]
    return f'{package}/{msg_type.__name__}'


@contextmanager
def _recorded_declarations() -> Iterator[list[tuple[str, Any, ParameterDescriptor]]]:
    """Every Node.declare_parameter call made meanwhile: (name, declared default, descriptor)."""
    calls: list[tuple[str, Any, ParameterDescriptor]] = []
    original = Node.declare_parameter

    def declare_parameter(self, name, value=None, descriptor=None, ignore_override=False):
        calls.append((name, value, descriptor or ParameterDescriptor()))
        return original(self, name, value, descriptor, ignore_override)

    Node.declare_parameter = declare_parameter
    try:
        yield calls
    finally:
        Node.declare_parameter = original


def _shelf_first_frame_bag(folder: Path) -> Path:
    """A bag of the Shelf bag's first frame (every message of its first log stamp)."""
    items = iter(make_recipe('shelf').items())
    first = next(items)
    path = folder / 'shelf_first_frame'
    write_bag(path, [first, *takewhile(lambda item: item[2] == first[2], items)])
    return path


def _camera_names() -> list[str]:
    """The names the page writes as <camera>: the Shelf rig's and the shelf_rig bag's."""
    shelf = load_rig_file(package_path(DEFAULT_RIG), data_root=data_root)
    return [c.name for c in shelf.cameras] + list(ForeignRig.NAMES)


def _generalised(topic: str, cameras: list[str]) -> str:
    """The topic as the page writes it: a camera's name as <camera>."""
    return '/'.join('<camera>' if p in cameras else p for p in topic.split('/'))


Declared = list[tuple[str, Any, ParameterDescriptor]]  # (name, declared default, descriptor)
Endpoints = list[tuple[str, str, type, QoSProfile]]  # (publishes or subscribes, topic, message class, QoS)


def _started(configuration: Configuration, bag: Path, rig: Path) -> tuple[Declared, Endpoints]:
    """Start the node of `configuration` in a context of its own; its declarations and endpoints."""
    args = ['--ros-args', *(a.format(bag=bag, rig=rig) for a in configuration.args)]
    context = rclpy.Context()
    rclpy.init(args=args, context=context)  # ROS_DOMAIN_ID's domain; discovery kept on this host
    node = None
    try:
        cls = getattr(importlib.import_module(f'mvpose_ros.nodes.{configuration.module}'), configuration.cls)
        with _recorded_declarations() as declared:
            node = _in_context(cls, context)
        endpoints = [('publishes', p.topic_name, p.msg_type, p.qos_profile) for p in node.publishers]
        endpoints += [('subscribes', s.topic_name, s.msg_type, s.qos_profile) for s in node.subscriptions]
        return declared, endpoints
    finally:
        if node is not None:
            node.destroy_node()
        rclpy.shutdown(context=context)


def _in_context(cls: type[Node], context: rclpy.Context) -> Node:
    """An instance of a node class whose constructor takes no context: its Node.__init__ is given
    `context` (the nodes are written for rclpy's default context)."""
    original = Node.__init__

    def init(self, node_name, *args, **kwargs):
        kwargs.setdefault('context', context)
        original(self, node_name, *args, **kwargs)

    Node.__init__ = init
    try:
        return cls()
    finally:
        Node.__init__ = original


def collect() -> list[NodeReference]:
    """Every node of CONFIGURATIONS started, read back and stopped, in order."""
    os.environ['ROS_AUTOMATIC_DISCOVERY_RANGE'] = 'LOCALHOST'
    cameras = _camera_names()
    nodes: dict[str, NodeReference] = {}
    with tempfile.TemporaryDirectory() as tmp:
        bag = _shelf_first_frame_bag(Path(tmp))
        rig = Path(tmp) / 'shelf_rig.yaml'
        rig.write_text(rig_file_text(calibration_file('shelf')))
        for configuration in CONFIGURATIONS:
            declared, endpoints = _started(configuration, bag, rig)
            module = importlib.import_module(f'mvpose_ros.nodes.{configuration.module}')
            summary = ' '.join((module.__doc__ or '').split('\n\n')[0].split())
            summary = summary[:-1] + '.' if summary.endswith(':') else summary
            ref = nodes.setdefault(configuration.module, NodeReference(configuration.module, summary))
            if not ref.parameters:
                ref.parameters = [Parameter(name, _type_name(value, d), _default(value),
                                            ' '.join(d.description.split()), _range(d), not d.read_only)
                                  for name, value, d in declared if not name.startswith(RCL_OWN)]
            rows = []
            for kind, topic, msg_type, qos in endpoints:
                if topic in ROS_OWN:
                    continue
                row = Endpoint(kind, _generalised(topic, cameras), _message_type(msg_type), _qos(qos))
                if row not in rows:
                    rows.append(row)
            ref.endpoints[configuration.title] = rows
    return list(nodes.values())


def _cell(text: str) -> str:
    return text.replace('|', '\\|')


def render(nodes: list[NodeReference]) -> str:
    """The markdown page."""
    lines = [
        '# Node reference',
        '',
        f'Generated by `{COMMAND}` (mvpose_ros/nodes/reference.py) from the nodes themselves: each node',
        'is started in the configurations named below, and its declared parameters and the publishers',
        'and subscriptions it made are read back from rclpy. Do not edit by hand; `test/test_docs.py`',
        'fails when this page is stale.',
        '',
        'Topic names are shown as they resolve with the node in the root namespace (the one-camera',
        'detector: in its camera\'s); the code names every topic but `/diagnostics` relative, so a',
        'namespace (`-r __ns:=/rig1`, `namespace:=` of the launch files) moves them all. `<camera>` is',
        "a rig camera's name; image and CameraInfo topics are the rig file's (the Shelf rig's relative,",
        "the shelf_rig bag's absolute, under `/rig`). A",
        'parameter marked *live* takes a change at once (`ros2 param set`); the others are read-only',
        '(a change needs a restart). A numeric value outside its range is refused at start-up and',
        'when set. `diagnostics.*` are described in [operations](operations.md#health-and-diagnostics).',
        '',
    ]
    for ref in nodes:
        lines += [f'## {ref.name}', '', ref.summary, '']
        for title, rows in ref.endpoints.items():
            lines += [f'Topics ({title}):', '', '| | topic | type | QoS |', '|---|---|---|---|']
            lines += [f'| {e.kind} | `{e.topic}` | {e.type} | {e.qos} |' for e in rows]
            lines.append('')
        if ref.parameters:
            lines += ['| parameter | type | default | range | live | description |', '|---|---|---|---|---|---|']
            lines += [f'| `{p.name}` | {p.type} | `{_cell(p.default)}` | {p.range} | {"live" if p.live else ""} | '
                      f'{_cell(p.description)} |' for p in ref.parameters]
        else:
            lines.append('No parameters.')
        lines.append('')
    return '\n'.join(lines)


def page() -> str:
    """docs/nodes.md as the nodes declare it today."""
    return render(collect())


def stale_lines(current: str, fresh: str) -> list[str]:
    """The lines that differ (unified diff), empty when the page is up to date."""
    return list(difflib.unified_diff(current.splitlines(), fresh.splitlines(), 'docs/nodes.md', COMMAND, lineterm=''))


def default_page_path() -> Path:
    """docs/nodes.md of the checkout this module is in."""
    return Path(__file__).resolve().parents[2] / 'docs' / 'nodes.md'
