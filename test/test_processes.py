"""The process supervisor: exit codes and logs, complete stops (grandchildren, ignored signals),
the supervisor's own SIGTERM, and the graph runner's crash path with dummy nodes."""
from __future__ import annotations

import json
import os
import re
import signal
import subprocess
import sys
import textwrap
import threading
import time
from pathlib import Path

import numpy as np
import pytest
from sensor_msgs.msg import PointCloud2

from mvpose_ros.bags.io import read_bag, write_bag
from mvpose_ros.bags.replay import group_frames, looped
from mvpose_ros.cli import graph
from mvpose_ros.graph import session
from mvpose_ros.core.evaluation.predictions import read_predictions
from mvpose_ros.graph import runner
from mvpose_ros.graph.config import NodeSpec
from mvpose_ros.graph.processes import ProcessGroup
from mvpose_ros.graph.recorder import SkeletonRecorder
from mcap_check import decoded_messages, decoded_skeletons
from ros_harness import ros_domain

REPO = Path(__file__).resolve().parents[1]


def alive(pid: int) -> bool:
    """Running (a zombie waiting to be reaped by init is dead)."""
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    try:
        return Path(f'/proc/{pid}/stat').read_text().rpartition(')')[2].split()[0] not in ('Z', 'X')
    except FileNotFoundError:
        return False


def wait_for(predicate, timeout: float = 10.0) -> None:
    deadline = time.monotonic() + timeout
    while not predicate():
        assert time.monotonic() < deadline, 'timed out'
        time.sleep(0.02)


def py(code: str) -> list[str]:
    return [sys.executable, '-c', textwrap.dedent(code)]


def test_exit_codes_and_logs(tmp_path):
    with ProcessGroup(tmp_path) as group:
        group.start('ok', ['sh', '-c', 'echo hello; echo to-stderr >&2'])
        group.start('crash', ['sh', '-c', 'echo about to fail; exit 3'])
        group.start('cam1/node', ['sh', '-c', 'echo namespaced'])
        wait_for(lambda: len(group.poll()) == 3)
        assert group.poll() == {'ok': 0, 'crash': 3, 'cam1/node': 0}
        assert group.log_tail('ok').splitlines() == ['hello', 'to-stderr']
        assert group.log_tail('crash', 1) == 'about to fail'
        assert (tmp_path / 'cam1_node.log').read_text() == 'namespaced\n'
        with pytest.raises(ValueError, match='already used'):
            group.start('ok', ['true'])


def test_stop_leaves_nothing_alive(tmp_path):
    ready = tmp_path / 'ready'
    ready.mkdir()
    # Each child reports its pid (and its grandchild's) in ready/ once its signal handling is set up.
    commands = {
        'sleeper': py(f'''
            import os, time
            open('{ready}/sleeper', 'w').write(str(os.getpid()))
            time.sleep(60)'''),
        'ignores_sigint': py(f'''
            import os, signal, time
            signal.signal(signal.SIGINT, signal.SIG_IGN)
            open('{ready}/ignores_sigint', 'w').write(str(os.getpid()))
            time.sleep(60)'''),
        'ignores_all': py(f'''
            import os, signal, time
            signal.signal(signal.SIGINT, signal.SIG_IGN)
            signal.signal(signal.SIGTERM, signal.SIG_IGN)
            open('{ready}/ignores_all', 'w').write(str(os.getpid()))
            time.sleep(60)'''),
        # A non-interactive shell starts background jobs with SIGINT ignored: the grandchild
        # outlives the SIGINT that ends its parent.
        'parent': ['sh', '-c', f'sleep 60 & echo $! > {ready}/grandchild; echo $$ > {ready}/parent; wait'],
        # The parent exits at once and leaves an orphan in its group.
        'orphaner': ['sh', '-c', f'sleep 60 & echo $! > {ready}/orphan'],
    }
    group = ProcessGroup(tmp_path / 'logs', grace=0.5, term_grace=0.5)
    for name, cmd in commands.items():
        group.start(name, cmd)
    names = ('sleeper', 'ignores_sigint', 'ignores_all', 'grandchild', 'parent', 'orphan')
    wait_for(lambda: all((ready / n).is_file() and (ready / n).read_text().strip() for n in names))
    pids = {n: int((ready / n).read_text()) for n in names}
    assert all(alive(p) for n, p in pids.items())
    assert group.poll() == {'orphaner': 0} or group.poll() == {}

    t0 = time.monotonic()
    codes = group.stop()
    # SIGINT, SIGTERM after 0.5 s, SIGKILL after 0.5 s more: bounded, whatever a child ignores
    assert time.monotonic() - t0 < 30.0
    assert [n for n, p in pids.items() if alive(p)] == []
    assert codes['sleeper'] != 0  # ended by the SIGINT (KeyboardInterrupt)
    assert codes['ignores_sigint'] == -signal.SIGTERM
    assert codes['ignores_all'] == -signal.SIGKILL
    assert codes['orphaner'] == 0
    assert group.stop() == codes  # idempotent: nothing left to signal


def test_context_manager_stops_on_exception(tmp_path):
    with pytest.raises(RuntimeError, match='boom'):
        with ProcessGroup(tmp_path, grace=1.0) as group:
            proc = group.start('sleeper', ['sleep', '60'])
            raise RuntimeError('boom')
    assert not alive(proc.pid)
    assert proc.returncode == -signal.SIGINT


def test_supervisor_sigterm_stops_children(tmp_path):
    """The supervisor's own SIGTERM unwinds its `with` block, which stops every child."""
    script = f'''
        import sys, time
        from mvpose_ros.graph.processes import Interrupted, ProcessGroup
        try:
            with ProcessGroup({str(tmp_path / 'logs')!r}, grace=0.5) as group:
                group.start('parent', ['sh', '-c', 'sleep 60 & echo $!; wait'])
                print(group.procs['parent'].pid, flush=True)
                # Blocked in this process itself: a child of its own (not in the group) would keep
                # the test's pipe open after the supervisor exits.
                time.sleep(60)
        except Interrupted as exc:
            print(exc, flush=True)
            sys.exit(128 + exc.signum)
        '''
    sup = subprocess.Popen(py(script), stdout=subprocess.PIPE, text=True, cwd=REPO,
                           env=dict(os.environ, PYTHONPATH=str(REPO)))
    try:
        child = int(sup.stdout.readline())
        log = tmp_path / 'logs' / 'parent.log'
        wait_for(lambda: log.is_file() and log.read_text().strip())
        grandchild = int(log.read_text())
        assert alive(child) and alive(grandchild)
        sup.send_signal(signal.SIGTERM)
        assert sup.wait(timeout=10) == 128 + signal.SIGTERM
        assert 'SIGTERM' in sup.stdout.read()
        assert not alive(child) and not alive(grandchild)
    finally:
        sup.kill()
        sup.wait()


def test_runner_names_the_crashed_node_and_stops_the_rest(tmp_path, monkeypatch, capsys):
    with ros_domain(monkeypatch, profile=None) as domain:  # the runner sets the profile: undone after
        _crash(tmp_path, monkeypatch, capsys, domain)


def _crash(tmp_path, monkeypatch, capsys, domain):
    bag = tmp_path / 'bag'
    write_bag(bag, [('/cam0/openpose', PointCloud2(), int(f * 1e9) // 25) for f in range(300, 303)])
    pids = tmp_path / 'pids'
    pids.mkdir()

    def dummy_node(spec, params_file, python=sys.executable):
        # Every dummy records its pid (written beside and renamed: whole when seen); cam2's
        # detector fails at start-up like a bad parameter would, once the 7 processes have
        # recorded theirs.
        name = spec.name.replace('/', '_')
        crash = spec.name == 'cam2/heatmap_detector'
        return py(f'''
            import os, sys, time
            open('{pids}/{name}.tmp', 'w').write(str(os.getpid()))
            os.replace('{pids}/{name}.tmp', '{pids}/{name}')
            while {crash} and len([n for n in os.listdir('{pids}') if not n.endswith('.tmp')]) < 7:
                time.sleep(0.01)
            if {crash}:
                sys.exit('[FATAL] [heatmap_detector]: calibration not found: /nowhere.json')
            time.sleep(60)''')

    monkeypatch.setattr(runner, 'node_command', dummy_node)
    t0 = time.monotonic()
    code = graph.main(['--config', str(REPO / 'config' / 'shelf.yaml'), '--bag', str(bag),
                       '--predictions', str(tmp_path / 'out' / 'p.jsonl'), '--domain-id', str(domain),
                       '--compose', 'none'])
    err = capsys.readouterr().err
    assert code == 1
    assert time.monotonic() - t0 < runner.STARTUP_TIMEOUT_S  # on the crash, not after waiting for the graph
    first = [line for line in err.splitlines() if 'error' in line][0]
    assert 'node cam2/heatmap_detector exited with code 1' in first
    assert 'calibration not found: /nowhere.json' in err  # the end of its log
    started = {p.name: int(p.read_text()) for p in pids.iterdir()}
    # The player is only started once the graph is connected, which it never was.
    assert set(started) == {*(f'cam{c}_heatmap_detector' for c in range(5)), 'association', 'bp_solver'}
    assert [n for n, p in started.items() if alive(p)] == []
    assert not (tmp_path / 'out' / 'p.jsonl').exists()


# A stand-in for the real nodes with the same topics, so that the runner's whole path (wait for
# the connections, play, collect, stop, write, score) is tested on its own. The player publishes
# frames FAKE_FRAMES (then, with FAKE_HOLD, stays without ending); the solver answers each
# cam0/camera_info once. Nothing is sent before its readers are there, both ways: the player
# waits until its writers have matched, for the runner's start signal and for the solver's (a
# latched message once the solver's camera_info reader and skeletons writer have matched).
FAKE_NODE = """
import os, signal, sys, time
import numpy as np
import rclpy
from rclpy.duration import Duration
from rclpy.node import Node
from rclpy.qos import HistoryPolicy, QoSProfile, ReliabilityPolicy
from sensor_msgs.msg import CameraInfo, PointCloud2
from std_msgs.msg import Empty
from visualization_msgs.msg import MarkerArray
from diagnostic_msgs.msg import DiagnosticArray
from msg_adapters.diagnostics_msg import statuses_to_msg
from msg_adapters.skeleton_msg import skeletons_to_msg
from msg_adapters.stamp import frame_of_stamp, stamp_of_frame
from mvpose_ros.nodes.bag_player import START_QOS
from mvpose_ros.nodes.health import DIAGNOSTICS_QOS, node_links

QOS = QoSProfile(reliability=ReliabilityPolicy.RELIABLE, history=HistoryPolicy.KEEP_LAST, depth=100)
CAMERAS = range(int(os.environ['FAKE_CAMERAS']))
SOLVER_READY = 'fake/solver_ready'
role, start_topic = sys.argv[1:3]
rclpy.init(args=sys.argv)
node = Node(role)
open(os.path.join(os.environ['FAKE_PIDS'], node.get_fully_qualified_name().strip('/').replace('/', '_')),
     'w').write(f"{os.getpid()}\\n{os.environ.get('FASTRTPS_DEFAULT_PROFILES_FILE', '')}")
if role == 'heatmap_detector':
    pub = node.create_publisher(PointCloud2, 'people2d', QOS)
    node.create_subscription(PointCloud2, 'openpose', lambda m: pub.publish(PointCloud2(header=m.header)), QOS)
elif role == 'association':
    node.create_publisher(PointCloud2, 'people/bundles', QOS)
    for c in CAMERAS:
        node.create_subscription(PointCloud2, f'cam{c}/people2d', lambda m: None, QOS)
elif role == 'bp_solver':
    pub = node.create_publisher(PointCloud2, 'skeletons', QOS)
    live = node.create_publisher(PointCloud2, 'skeletons/live', QOS)
    node.create_publisher(MarkerArray, 'skeletons/markers', QOS)  # never sends: nobody to draw
    node.create_subscription(PointCloud2, 'people/bundles', lambda m: None, QOS)
    def answer(info):
        frame = frame_of_stamp(info.header.stamp)
        joints = np.full((1, 14, 3), frame / 1000.0)
        live.publish(skeletons_to_msg(np.array([7]), joints, info.header, confidence=np.ones((1, 14))))
        pub.publish(skeletons_to_msg(np.array([7]), joints, info.header, confidence=np.ones((1, 14))))
        died = os.path.join(os.environ['FAKE_PIDS'], 'solver_died')
        if frame == int(os.environ.get('FAKE_DIE_AT', -1)) and not os.path.exists(died):
            open(died, 'w').close()
            # its answer is out and acknowledged first, then a crash: once, at that frame
            pub.wait_for_all_acked(Duration(seconds=5))
            os.kill(os.getpid(), signal.SIGKILL)
    info = node.create_subscription(CameraInfo, 'cam0/camera_info', answer, QOS)
    ready = node.create_publisher(Empty, SOLVER_READY, START_QOS)
    def check():
        if info.get_publisher_count() and pub.get_subscription_count():
            ready.publish(Empty())
            timer.cancel()
    timer = node.create_timer(0.02, check)
# its links, as every real node reports them, for the runner's start (the player's: while it waits)
diagnostics = node.create_publisher(DiagnosticArray, '/diagnostics', DIAGNOSTICS_QOS)
node.create_timer(0.1, lambda: diagnostics.publish(statuses_to_msg([node_links(node)],
                                                                   node.get_clock().now().to_msg())))
if role == 'bag_player':
    openpose = [node.create_publisher(PointCloud2, f'cam{c}/openpose', QOS) for c in CAMERAS]
    info = node.create_publisher(CameraInfo, 'cam0/camera_info', QOS)
    signals = set()
    node.create_subscription(Empty, start_topic, lambda m: signals.add('runner'), START_QOS)
    node.create_subscription(Empty, SOLVER_READY, lambda m: signals.add('solver'), START_QOS)
    # The runner and the solver both listen to the camera info.
    while (any(p.get_subscription_count() == 0 for p in openpose) or info.get_subscription_count() < 2
           or signals != {'runner', 'solver'}):
        rclpy.spin_once(node, timeout_sec=0.02)
    first, end = map(int, os.environ['FAKE_FRAMES'].split(':'))
    for frame in range(first, end):
        header = CameraInfo().header
        header.stamp = stamp_of_frame(frame)
        for p in openpose:
            p.publish(PointCloud2(header=header))
        info.publish(CameraInfo(header=header))
        time.sleep(float(os.environ.get('FAKE_PERIOD', 0)))
    if not os.environ.get('FAKE_HOLD'):
        for p in [*openpose, info]:
            p.wait_for_all_acked(Duration(seconds=1))  # a dead reader never acks
        sys.exit(0)
try:
    rclpy.spin(node)
except KeyboardInterrupt:
    pass
"""


@pytest.fixture
def fake_graph(tmp_path, monkeypatch):
    """Runner arguments for a 2-camera fake graph over frames 300..319 on a domain of its own
    (timeout 2 s: a failure ends fast)."""
    with ros_domain(monkeypatch, profile=None):  # the runner sets the profile: undone after
        yield from _fake_graph(tmp_path, monkeypatch, timeout=2.0)


def _fake_graph(tmp_path, monkeypatch, timeout):
    frames = range(300, 320)
    monkeypatch.setenv('FAKE_CAMERAS', '2')
    monkeypatch.setenv('FAKE_FRAMES', f'{frames.start}:{frames.stop}')
    monkeypatch.setenv('FAKE_PIDS', str(tmp_path / 'pids'))
    (tmp_path / 'pids').mkdir()
    script = tmp_path / 'fake_node.py'
    script.write_text(FAKE_NODE)
    bag = tmp_path / 'bag'
    write_bag(bag, [('/cam0/openpose', PointCloud2(), f * 1_000_000_000 // 25) for f in frames])
    config = tmp_path / 'graph.yaml'
    (tmp_path / 'fastdds.xml').write_text((REPO / 'config' / 'fastdds.xml').read_text())
    config.write_text((REPO / 'config' / 'shelf.yaml').read_text().replace('cameras: 5', 'cameras: 2')
                      .replace('timeout: 120.0', f'timeout: {timeout!r}'))

    def fake_command(spec, params_file, python=sys.executable):
        assert [Path(p) for p in params_file] == [config.resolve()]  # no --overrides
        return [python, str(script), spec.executable, str(spec.parameters.get('start_topic', '-')), '--ros-args',
                *(['-r', f'__ns:=/{spec.namespace}'] if spec.namespace else [])]

    monkeypatch.setattr(runner, 'node_command', fake_command)
    predictions = tmp_path / 'out' / 'p.jsonl'
    # a process per node: each fake node stands for one
    yield (['--config', str(config), '--bag', str(bag), '--predictions', str(predictions), '--compose', 'none'],
           predictions, frames)


def test_runner_plays_collects_and_scores(fake_graph, tmp_path, monkeypatch, capsys):
    args, predictions, frames = fake_graph
    code = graph.main(args)
    out, err = capsys.readouterr()
    assert code == 0, err
    # Every frame's camera info too: the player waited for the runner's reader to match.
    assert f'frames in {len(frames)} (seen on /cam0/camera_info: {len(frames)}), frames out {len(frames)}' in out
    assert 'missing 0: none; duplicate 0: none; unexpected 0: none' in out
    # the fake solver answers the openpose message at once, so under load a skeleton can be received
    # before its frame's camera_info: a latency may be negative here (never in the real graph)
    assert re.search(r'latency /cam0/camera_info -> /skeletons: p50 -?[0-9.]+ ms, p95 -?[0-9.]+ ms, '
                     rf'max -?[0-9.]+ ms \({len(frames)} frames\)', out), out
    # the last frame's live estimate too, though its skeletons may be taken first
    assert re.search(r'latency /cam0/camera_info -> /skeletons/live: .* \(' + str(len(frames)) + r' frames\)', out), out
    lines = [json.loads(line) for line in predictions.read_text().splitlines()]
    assert [r['frame'] for r in lines] == list(frames)
    assert all(r['people'][0]['id'] == 7 and r['people'][0]['joints'][0] == [r['frame'] / 1000] * 3 for r in lines)
    assert 'PCP (%), alpha=0.5' in out and 'Actor 1 strict' in out  # mvpose-eval's table
    started = {p.name: p.read_text().split('\n') for p in (tmp_path / 'pids').iterdir()}
    assert set(started) == {'cam0_heatmap_detector', 'cam1_heatmap_detector', 'association', 'bp_solver', 'bag_player'}
    assert [n for n, (pid, _) in started.items() if alive(int(pid))] == []
    # Every node used the Fast DDS profile beside the parameter file.
    assert {profile for _, profile in started.values()} == {str(tmp_path / 'fastdds.xml')}


def test_runner_records_its_outputs_and_inputs_as_mcap(fake_graph, tmp_path, capsys):
    args, predictions, frames = fake_graph
    folder = tmp_path / 'rec'
    code = graph.main([*args, '--record', str(folder), '--record-inputs'])
    out, err = capsys.readouterr()
    assert code == 0, err
    assert 'recorded' in out and str(folder) in out
    messages = decoded_messages(folder)
    topics = [t for t, _, _, _ in messages]
    # every frame's skeletons and live estimate, and the one input topic the bag holds: the player
    # started once the recorder's readers had matched, so the first frame is there too
    assert topics.count('/skeletons') == topics.count('/skeletons/live') == len(frames)
    assert topics.count('/cam0/openpose') == len(frames)
    assert '/cam1/openpose' not in topics and '/diagnostics' in topics
    sent = {r['stamp']: r for r in map(json.loads, predictions.read_text().splitlines())}
    got = [decoded_skeletons(d) for t, _, _, d in messages if t == '/skeletons']
    assert sorted(stamp for stamp, _ in got) == sorted(sent)
    assert all(people.ids.tolist() == [p['id'] for p in sent[stamp]['people']]
               and np.allclose(people.joints[0], sent[stamp]['people'][0]['joints'], atol=1e-6)
               for stamp, people in got)
    assert graph.main([*args, '--record', str(folder)]) == 2  # never over an earlier recording
    assert 'already exists' in capsys.readouterr().err


def test_runner_interrupted_stops_everything_and_writes_what_it_has(fake_graph, tmp_path, monkeypatch, capsys):
    args, predictions, _ = fake_graph
    # The player sends frames 300..349 of a 400-frame bag and then holds: the run cannot end
    # before the interrupt, which comes once the runner has received 20 outputs.
    frames = range(300, 700)
    monkeypatch.setenv('FAKE_FRAMES', '300:350')
    monkeypatch.setenv('FAKE_HOLD', '1')
    bag = tmp_path / 'long_bag'
    write_bag(bag, [('/cam0/openpose', PointCloud2(), f * 1_000_000_000 // 25) for f in frames])
    args = [a if a != args[args.index('--bag') + 1] else str(bag) for a in args]
    config = Path(args[args.index('--config') + 1])
    config.write_text(config.read_text().replace('timeout: 2.0', 'timeout: 120.0'))  # no stall before it
    predictions.parent.mkdir(parents=True, exist_ok=True)
    predictions.write_text('an older run\n')
    some_outputs = threading.Event()

    class Watched(SkeletonRecorder):
        def _on_skeletons(self, cdr, info):
            super()._on_skeletons(cdr, info)
            if len(self.outputs) >= 20:
                some_outputs.set()

    def ctrl_c_once_collecting():
        if some_outputs.wait(60):
            os.kill(os.getpid(), signal.SIGINT)

    monkeypatch.setattr(session, 'SkeletonRecorder', Watched)
    threading.Thread(target=ctrl_c_once_collecting, daemon=True).start()
    code = graph.main(args)
    err = capsys.readouterr().err
    assert some_outputs.is_set(), err
    assert code == 128 + signal.SIGINT, err
    assert 'interrupted by SIGINT; every node stopped' in err
    written = read_predictions(predictions)  # a whole, valid file: not the older run, not cut short
    assert 20 <= len(written) <= 50
    assert list(written) == list(range(300, 300 + len(written)))
    assert not predictions.with_name(predictions.name + '.partial').exists()
    started = {p.name: int(p.read_text().split('\n')[0]) for p in (tmp_path / 'pids').iterdir()}
    assert 'bag_player' in started and [n for n, pid in started.items() if alive(pid)] == []


def test_the_player_is_let_play_once_the_nodes_report_its_links_matched(tmp_path):
    """The gate opens after the recorder's camera_info readers have matched AND the nodes report
    every link of the player's topics matched (a volatile first message sent before would be lost)."""
    calls = []

    class Recorder:
        def timing_matched(self):
            calls.append('timing')
            return True

        def not_connected(self, played):
            calls.append('links')
            return [] if calls.count('links') > 3 else [f'{next(iter(played))}: a writer has matched 0 of 1 readers']

        def open_gate(self, topic):
            calls.append(f'gate {topic}')

    class Group:
        def start(self, name, command):
            calls.append(f'start {name}')

        def poll(self):
            return {}

    class Executor:
        def spin_once(self, timeout_sec):
            pass

    spec = NodeSpec('bag_player', '', {'start_topic': 'bag_player/start', 'bag': 'b', 'rate': 1.0, 'loops': 1})
    runner._start_player(Recorder(), Executor(), Group(), spec, tmp_path / 'p.yaml',
                         {'/cam0/openpose': ('pub', 'sub')}, runner.Supervision())
    assert calls == ['start bag_player', 'timing', 'links', 'links', 'links', 'links', 'gate bag_player/start']


def test_runner_expects_the_stamps_of_every_loop_as_the_player_sends_them(tmp_path):
    frames = range(300, 310)
    bag = tmp_path / 'bag'
    write_bag(bag, [('/cam0/openpose', PointCloud2(), f * 1_000_000_000 // 25) for f in frames])
    stamps = runner.input_stamps(bag, '/cam0/openpose', loops=3)
    player = [frame.stamp_ns + offset for _, offset, frame in
              looped(lambda: group_frames(read_bag(bag, ['/cam0/openpose'])), 3)]
    assert stamps == player and len(set(stamps)) == 30
    assert [round(s * 25 / 1e9) for s in stamps] == list(range(300, 330))  # the timeline goes on


def test_runner_respawns_a_dead_node_and_counts_the_frames_lost(fake_graph, tmp_path, monkeypatch, capsys):
    """--respawn: the fake solver kills itself (SIGKILL) once, at frame 310 of 300..399 paced at
    100 ms; it is started again, named with its cause and count, and answers the frames that come
    after; the frames between are reported lost, not missing, and the run succeeds."""
    args, predictions, _ = fake_graph
    frames = range(300, 400)
    monkeypatch.setenv('FAKE_FRAMES', f'{frames.start}:{frames.stop}')
    monkeypatch.setenv('FAKE_PERIOD', '0.1')
    monkeypatch.setenv('FAKE_DIE_AT', '310')
    bag = tmp_path / 'bag100'
    write_bag(bag, [('/cam0/openpose', PointCloud2(), f * 1_000_000_000 // 25) for f in frames])
    args = [a if a != args[args.index('--bag') + 1] else str(bag) for a in args]
    config = Path(args[args.index('--config') + 1])
    # the player's end waits for the dead solver's acks (1 s per writer): no stall before it
    config.write_text(config.read_text().replace('timeout: 2.0', 'timeout: 10.0'))
    code = graph.main([*args, '--respawn', '--respawn-delay', '0.2', '--report-every', '1'])
    out, err = capsys.readouterr()
    assert code == 0, out + err
    assert 'node bp_solver killed by SIGKILL; restart 1 in 0.2 s (1 within 60 s, at most 5)' in err
    assert 'node bp_solver started again (restart 1)' in err
    got = sorted(read_predictions(predictions))
    lost = sorted(set(frames) - set(got))
    # frames up to the one it died on are out; those published while it was down are lost; the rest flow
    assert got[:11] == list(range(300, 311)) and got[-1] == 399
    assert lost and lost == list(range(lost[0], lost[-1] + 1)) and lost[0] == 311, lost
    assert f'missing 0: none; lost in restarts {len(lost)};' in out
    line = next(x for x in out.splitlines() if x.startswith('  bp_solver killed by SIGKILL (restart 1)'))
    assert f'lost {len(lost)} (frames {lost[0]}-{lost[-1]})' in line and 'ids [7] before, [7] after' in line
    assert re.search(r'started again 0\.[0-9] s later; /skeletons back after [0-9.]+ s', line), line
    assert 'by 1 s of the run' in out  # the table by period
    log = (tmp_path / 'out' / 'p_logs' / 'bp_solver.log').read_text()
    assert '--- restarted by the supervisor: restart 1, killed by SIGKILL ---' in log


def test_runner_gives_up_a_node_that_dies_at_once_every_time(fake_graph, tmp_path, monkeypatch, capsys):
    args, predictions, _ = fake_graph
    script = tmp_path / 'fake_node.py'
    script.write_text(FAKE_NODE.replace("if role == 'heatmap_detector':",
                                        "if role == 'association':\n    sys.exit('no calibration')\n"
                                        "if role == 'heatmap_detector':"))
    code = graph.main([*args, '--respawn', '--respawn-delay', '0', '--respawn-limit', '2'])
    err = capsys.readouterr().err
    assert code == 1
    assert err.count('node association exited with code 1; restart') == 2
    assert ('error: node association exited with code 1 after 2 restarts within 60 s: not restarted again'
            in err), err
    assert 'no calibration' in err  # the end of its log
    started = {p.name: int(p.read_text().split('\n')[0]) for p in (tmp_path / 'pids').iterdir()}
    assert [n for n, pid in started.items() if alive(pid)] == []
