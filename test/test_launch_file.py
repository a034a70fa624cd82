"""launch/shelf.launch.py, read with `ast` (launch and launch_ros are not on PyPI): it starts the
runner's nodes with the same executables, names and namespaces, with the package's shelf.yaml
and the bag and rate launch arguments."""
from __future__ import annotations

import ast
import sys
from pathlib import Path

from mvpose_ros.graph.config import graph_nodes, graph_settings

REPO = Path(__file__).resolve().parents[1]
LAUNCH = REPO / 'launch' / 'shelf.launch.py'


def _calls(tree: ast.AST, name: str) -> list[ast.Call]:
    return [n for n in ast.walk(tree) if isinstance(n, ast.Call) and isinstance(n.func, ast.Name) and n.func.id == name]


def _constants(tree: ast.Module) -> dict[str, object]:
    """Module-level NAME = <literal> assignments."""
    out = {}
    for stmt in tree.body:
        if isinstance(stmt, ast.Assign) and len(stmt.targets) == 1 and isinstance(stmt.targets[0], ast.Name):
            try:
                out[stmt.targets[0].id] = ast.literal_eval(stmt.value)
            except ValueError:
                pass
    return out


def _evaluate(expr: ast.expr, names: dict[str, object]) -> object:
    """A keyword's value, e.g. f'cam{c}', given the module constants and loop variables."""
    return eval(compile(ast.Expression(expr), str(LAUNCH), 'eval'), {'__builtins__': {'range': range}}, names)


def launched_nodes() -> list[dict[str, object]]:
    """Keyword arguments of every Node(...) the file creates, comprehensions unrolled."""
    tree = ast.parse(LAUNCH.read_text(), str(LAUNCH))
    consts = _constants(tree)
    in_comprehension = {}
    for comp in ast.walk(tree):
        if isinstance(comp, ast.ListComp) and isinstance(comp.elt, ast.Call):
            (gen,) = comp.generators
            in_comprehension[id(comp.elt)] = (gen.target.id, _evaluate(gen.iter, consts))
    nodes = []
    for call in _calls(tree, 'Node'):
        var, values = in_comprehension.get(id(call), (None, [None]))
        for value in values:
            names = {**consts, var: value} if var else consts
            evaluated = ('package', 'executable', 'name', 'namespace')
            nodes.append({kw.arg: (_evaluate(kw.value, names) if kw.arg in evaluated else kw.value)
                          for kw in call.keywords})
    return nodes


def test_same_nodes_as_the_runner():
    nodes = launched_nodes()
    settings = graph_settings(REPO / 'config' / 'shelf.yaml')
    runner = graph_nodes(settings.cameras, settings.bag, settings.rate)
    assert sorted((n['executable'], n.get('namespace', '')) for n in nodes) == \
        sorted((s.executable, s.namespace) for s in runner)
    assert all(n['package'] == 'mvpose_ros' and n['name'] == n['executable'] for n in nodes)


def test_every_node_gets_the_shelf_params_and_its_overrides():
    tree = ast.parse(LAUNCH.read_text())
    # The file is found in the installed package's share folder.
    (share,) = _calls(tree, 'get_package_share_directory')
    assert _evaluate(share.args[0], _constants(tree)) == 'mvpose_ros'
    assigned = {ast.unparse(n.targets[0]): ast.unparse(n.value) for n in ast.walk(tree) if isinstance(n, ast.Assign)}
    assert assigned['config'] == "os.path.join(get_package_share_directory(PACKAGE), 'config')"
    assert assigned['params'] == "os.path.join(config, 'shelf.yaml')"
    # The same Fast DDS profile as mvpose-graph, set before any node starts.
    env, qos = _calls(tree, 'SetEnvironmentVariable')
    assert ast.unparse(env) == ("SetEnvironmentVariable('FASTRTPS_DEFAULT_PROFILES_FILE', "
                                "os.path.join(config, 'fastdds.xml'))")
    assert ast.unparse(qos) == "SetEnvironmentVariable('RMW_FASTRTPS_USE_QOS_FROM_XML', '1')"
    actions = [ast.unparse(a) for a in _calls(tree, 'LaunchDescription')[0].args[0].elts]
    assert actions.index(ast.unparse(env)) < actions.index('*detectors')
    for node in launched_nodes():
        params = node['parameters']
        assert isinstance(params, ast.List) and ast.unparse(params.elts[0]) == 'params', node['executable']
        overrides = {ast.literal_eval(k): ast.unparse(v) for d in params.elts[1:] for k, v in zip(d.keys, d.values)}
        if node['executable'] == 'heatmap_detector':
            assert overrides == {'camera': 'c'}
        elif node['executable'] == 'bag_player':
            assert overrides == {'bag': 'bag', 'rate': 'ParameterValue(rate, value_type=float)'}
        elif node['executable'] == 'association':
            assert overrides == {'state_dir': 'state_dir'}
        else:
            assert overrides == {}


def test_every_node_but_the_player_is_respawned_after_the_runners_delay():
    """respawn=True with mvpose-graph's delay; not the player: a new one would play the bag again."""
    from mvpose_ros.graph.respawn import RESPAWN_DELAY_S
    for path in (LAUNCH, RIG_LAUNCH):
        tree = ast.parse(path.read_text())
        for call in _calls(tree, 'Node'):
            keywords = {kw.arg: ast.unparse(kw.value) for kw in call.keywords}
            player = keywords.get('executable') == "'bag_player'"
            assert ('respawn' not in keywords) if player else (keywords['respawn'] == 'True'), path
            assert player or keywords['respawn_delay'] == 'RESPAWN_DELAY_S', path
        imported = {(n.module, a.name) for n in ast.walk(tree) if isinstance(n, ast.ImportFrom) for a in n.names}
        assert ('mvpose_ros.graph.respawn', 'RESPAWN_DELAY_S') in imported
        (state,) = [c for c in _calls(tree, 'DeclareLaunchArgument') if ast.literal_eval(c.args[0]) == 'state_dir']
        default = next(k.value for k in state.keywords if k.arg == 'default_value')
        assert ast.unparse(default) == "os.path.join(ros_home, 'mvpose_ros')"
    assert RESPAWN_DELAY_S > 0 and [n['executable'] for n in launched_nodes()].count('bag_player') == 1


def test_launch_arguments_and_imports():
    tree = ast.parse(LAUNCH.read_text())
    args = {ast.literal_eval(c.args[0]): ast.unparse(next(k.value for k in c.keywords if k.arg == 'default_value'))
            for c in _calls(tree, 'DeclareLaunchArgument')}
    assert args == {'bag': "'bags/shelf'", 'rate': "'1.0'", 'state_dir': "os.path.join(ros_home, 'mvpose_ros')"}
    configs = {ast.unparse(n.targets[0]): ast.literal_eval(n.value.args[0]) for n in ast.walk(tree)
               if isinstance(n, ast.Assign) and isinstance(n.value, ast.Call)
               and ast.unparse(n.value.func) == 'LaunchConfiguration'}
    assert configs == {'bag': 'bag', 'rate': 'rate', 'state_dir': 'state_dir'}
    imported = {(n.module, a.name) for n in ast.walk(tree) if isinstance(n, ast.ImportFrom) for a in n.names}
    assert imported == {('ament_index_python.packages', 'get_package_share_directory'),
                        ('launch', 'LaunchDescription'), ('launch.actions', 'DeclareLaunchArgument'),
                        ('launch.actions', 'SetEnvironmentVariable'),
                        ('launch.substitutions', 'LaunchConfiguration'), ('launch_ros.actions', 'Node'),
                        ('launch_ros.parameter_descriptions', 'ParameterValue'),
                        ('mvpose_ros.graph.respawn', 'RESPAWN_DELAY_S')}
    (gen,) = [f for f in tree.body if isinstance(f, ast.FunctionDef)]
    assert gen.name == 'generate_launch_description'


RIG_LAUNCH = REPO / 'launch' / 'rig.launch.py'


def test_rig_launch_starts_one_set_mode_detector_association_and_bp_solver():
    """launch/rig.launch.py rig:=FILE: the live graph of `mvpose-graph --rig` without the player, every
    node with the parameter file (default: the package's rig_template.yaml) and the rig file."""
    from mvpose_ros.graph.config import RigRun, rig_graph_nodes
    tree = ast.parse(RIG_LAUNCH.read_text(), str(RIG_LAUNCH))
    consts = _constants(tree)
    (comp,) = [c for c in ast.walk(tree)
               if isinstance(c, ast.ListComp) and ast.unparse(c.generators[0].iter) == 'NODES']
    (gen,) = comp.generators
    names = _evaluate(gen.iter, consts)
    call = comp.elt
    keywords = {kw.arg: kw.value for kw in call.keywords}
    launched = [(_evaluate(keywords['executable'], {**consts, gen.target.id: n}),
                 _evaluate(keywords['name'], {**consts, gen.target.id: n})) for n in names]
    runner = rig_graph_nodes(RigRun('r', 'b', True, 0.0, 'sensor', 0.02, 0.5, 5.0))
    assert [e for e, _ in launched] == [s.executable for s in runner if s.executable != 'bag_player']
    assert all(e == n for e, n in launched) and _evaluate(keywords['package'], consts) == 'mvpose_ros'
    assert ast.unparse(keywords['parameters']) == '[params, overrides[name]]'
    assert ast.unparse(keywords['namespace']) == 'namespace'
    overrides = next(n.value for n in ast.walk(tree) if isinstance(n, ast.Assign)
                     and ast.unparse(n.targets[0]) == 'overrides')
    values = {ast.literal_eval(k): {ast.literal_eval(kk): ast.unparse(vv) for kk, vv in zip(v.keys, v.values)}
              for k, v in zip(overrides.keys, overrides.values)}
    assert values == {'heatmap_detector': {'rig': 'rig', 'camera': "'all'"},
                      'association': {'rig': 'rig', 'state_dir': 'state_dir'}, 'bp_solver': {'rig': 'rig'}}
    args = {ast.literal_eval(c.args[0]): {k.arg: ast.unparse(k.value) for k in c.keywords}
            for c in _calls(tree, 'DeclareLaunchArgument')}
    assert set(args) == {'rig', 'params', 'namespace', 'state_dir', 'tf', 'overlay'}
    assert 'default_value' not in args['rig']
    assert args['params']['default_value'] == "os.path.join(config, 'rig_template.yaml')"
    env, qos = _calls(tree, 'SetEnvironmentVariable')
    assert ast.unparse(env) == ("SetEnvironmentVariable('FASTRTPS_DEFAULT_PROFILES_FILE', "
                                "os.path.join(config, 'fastdds.xml'))")
    assert ast.unparse(qos) == "SetEnvironmentVariable('RMW_FASTRTPS_USE_QOS_FROM_XML', '1')"
    assert (REPO / 'config' / 'rig_template.yaml').is_file()


def test_rig_template_sections_match_the_rig_graph_and_leave_command_line_values_out():
    from mvpose_ros.graph.config import load_params
    params = load_params(REPO / 'config' / 'rig_template.yaml')
    assert set(params) == {'/**', '/**/heatmap_detector', '/**/association', '/**/bp_solver', 'mvpose_graph'}
    assert params['/**/heatmap_detector']['camera'] == 'all' and params['/**/heatmap_detector']['backend'] == 'onnx'
    # a '/**/<node>' section wins over -p: it must not set what rig:= / the runner set
    assert all('rig' not in section for section in params.values())
    # the cameras' rate once, for every node that reads it (detector, association, bp_solver, overlay)
    assert [node for node, section in params.items() if 'frame_rate' in section] == ['/**']


class _Action:
    """A launch or launch_ros class as recorded by the stubs below: its arguments, unrun."""

    def __init__(self, *args, **kwargs) -> None:
        self.args, self.kwargs = args, kwargs


class _LaunchConfiguration(_Action):
    def perform(self, context: dict[str, str]) -> str:
        return context[self.args[0]]


def _stub_launch_modules(monkeypatch) -> dict[str, type]:
    """launch, launch_ros and the ament index as recording stubs (none is on PyPI or installed here)."""
    import types
    classes = {name: type(name, (_Action,), {}) for name in
               ('LaunchDescription', 'DeclareLaunchArgument', 'OpaqueFunction', 'SetEnvironmentVariable',
                'IfCondition', 'Node')}
    classes['LaunchConfiguration'] = _LaunchConfiguration
    modules = {'launch': ['LaunchDescription'],
               'launch.actions': ['DeclareLaunchArgument', 'OpaqueFunction', 'SetEnvironmentVariable'],
               'launch.conditions': ['IfCondition'], 'launch.substitutions': ['LaunchConfiguration'],
               'launch_ros': [], 'launch_ros.actions': ['Node']}
    for name, members in modules.items():
        module = types.ModuleType(name)
        for member in members:
            setattr(module, member, classes[member])
        monkeypatch.setitem(sys.modules, name, module)
    ament = types.ModuleType('ament_index_python.packages')
    ament.get_package_share_directory = lambda package: f'/opt/share/{package}'
    monkeypatch.setitem(sys.modules, 'ament_index_python.packages', ament)
    return classes


def _rig_launch_actions(monkeypatch) -> tuple[dict[str, type], list]:
    """The stub classes and the actions of rig.launch.py's launch description, run against them."""
    import importlib.util
    classes = _stub_launch_modules(monkeypatch)
    spec = importlib.util.spec_from_file_location('rig_launch', RIG_LAUNCH)
    launch_file = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(launch_file)
    return classes, launch_file.generate_launch_description().args[0]


def test_rig_launch_tf_starts_one_static_transform_publisher_per_camera_when_asked(monkeypatch):
    """tf:=true (default false) runs the launch file's camera_frames: the rig file, read when the
    launch runs, gives one static_transform_publisher per camera, in the graph's namespace and
    respawned like the graph's nodes, with static_tf's arguments."""
    from mvpose_ros.core.defaults import data_root
    from mvpose_ros.core.geometry.rig import load_rig_file
    from mvpose_ros.graph.respawn import RESPAWN_DELAY_S
    from mvpose_ros.graph.static_tf import static_transform_nodes
    classes, actions = _rig_launch_actions(monkeypatch)
    (tf,) = [a for a in actions if isinstance(a, classes['DeclareLaunchArgument']) and a.args[0] == 'tf']
    assert tf.kwargs['default_value'] == 'false'
    (frames,) = [a for a in actions if isinstance(a, classes['OpaqueFunction'])]
    condition = frames.kwargs['condition']
    assert isinstance(condition, classes['IfCondition']) and condition.args[0].args == ('tf',)
    (namespace,) = frames.kwargs['args']
    assert namespace.args == ('namespace',)
    monkeypatch.setenv('MVPOSE_DATA_ROOT', str(data_root()))
    rig = REPO / 'config' / 'rigs' / 'shelf.yaml'
    nodes = frames.kwargs['function']({'rig': str(rig)}, *frames.kwargs['args'])
    expected = static_transform_nodes(load_rig_file(rig, data_root=data_root()))
    assert len(nodes) == len(expected) == 5 and all(isinstance(n, classes['Node']) for n in nodes)
    for node, want in zip(nodes, expected):
        assert node.kwargs == {**want, 'namespace': namespace, 'output': 'screen', 'respawn': True,
                               'respawn_delay': RESPAWN_DELAY_S}


def test_rig_launch_overlay_starts_the_overlay_node_when_asked(monkeypatch):
    """overlay:=true (default false) adds the overlay node, as `mvpose-graph --rig --overlay` does:
    in the graph's namespace, with the parameter file and the rig file, respawned."""
    from mvpose_ros.graph.config import RigRun, rig_graph_nodes
    from mvpose_ros.graph.respawn import RESPAWN_DELAY_S
    classes, actions = _rig_launch_actions(monkeypatch)
    (argument,) = [a for a in actions if isinstance(a, classes['DeclareLaunchArgument']) and a.args[0] == 'overlay']
    assert argument.kwargs['default_value'] == 'false'
    (node,) = [a for a in actions if isinstance(a, classes['Node']) and a.kwargs['executable'] == 'overlay']
    kw = node.kwargs
    assert kw['package'] == 'mvpose_ros' and kw['name'] == 'overlay' and kw['namespace'].args == ('namespace',)
    params, rig = kw['parameters']
    assert params.args == ('params',) and list(rig) == ['rig'] and rig['rig'].args == ('rig',)
    assert kw['respawn'] is True and kw['respawn_delay'] == RESPAWN_DELAY_S
    assert isinstance(kw['condition'], classes['IfCondition']) and kw['condition'].args[0].args == ('overlay',)
    plain = [s.executable for s in rig_graph_nodes(RigRun('r', 'b', True, 0.0, 'sensor', 0.02, 0.5, 5.0))]
    drawn = rig_graph_nodes(RigRun('r', 'b', True, 0.0, 'sensor', 0.02, 0.5, 5.0), overlay=True)
    assert [s.executable for s in drawn] == [*plain[:-1], 'overlay', 'bag_player']
    assert drawn[-2].parameters == {'rig': 'r', 'max_rate': 0.0}  # lockstep: every set
