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

import pytest
from sensor_msgs.msg import PointCloud2

from mvpose_ros.bags.io import read_bag, write_bag
from mvpose_ros.bags.replay import group_frames, looped
from mvpose_ros.cli import graph
from mvpose_ros.core.evaluation.predictions import read_predictions
from mvpose_ros.graph.processes import ProcessGroup

DOMAIN_ID = 171
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
    assert time.monotonic() - t0 < 5.0
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
        import subprocess, sys
        from mvpose_ros.graph.processes import Interrupted, ProcessGroup
        try:
            with ProcessGroup({str(tmp_path / 'logs')!r}, grace=0.5) as group:
                group.start('parent', ['sh', '-c', 'sleep 60 & echo $!; wait'])
                print(group.procs['parent'].pid, flush=True)
                subprocess.run(['sleep', '60'])
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
    monkeypatch.setenv('ROS_AUTOMATIC_DISCOVERY_RANGE', 'LOCALHOST')
    monkeypatch.setenv('ROS_DOMAIN_ID', str(DOMAIN_ID))
    monkeypatch.delenv('FASTRTPS_DEFAULT_PROFILES_FILE', raising=False)  # the runner sets it: undo after
    bag = tmp_path / 'bag'
    write_bag(bag, [('/cam0/openpose', PointCloud2(), int(f * 1e9) // 25) for f in range(300, 303)])
    pids = tmp_path / 'pids'
    pids.mkdir()

    def dummy_node(spec, params_file, python=sys.executable):
        # Every dummy records its pid; cam2's detector fails at start-up like a bad parameter would.
        name = spec.name.replace('/', '_')
        crash = spec.name == 'cam2/heatmap_detector'
        return py(f'''
            import os, sys, time
            open('{pids}/{name}', 'w').write(str(os.getpid()))
            time.sleep(0.5 if {crash} else 60)
            if {crash}:
                sys.exit('[FATAL] [heatmap_detector]: calibration not found: /nowhere.json')''')

    monkeypatch.setattr(graph, 'node_command', dummy_node)
    t0 = time.monotonic()
    code = graph.main(['--config', str(REPO / 'config' / 'shelf.yaml'), '--bag', str(bag),
                       '--predictions', str(tmp_path / 'out' / 'p.jsonl'), '--domain-id', str(DOMAIN_ID)])
    err = capsys.readouterr().err
    assert code == 1
    assert time.monotonic() - t0 < 15
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
# frames FAKE_FRAMES; the solver answers each /cam0/camera_info once.
FAKE_NODE = '''
import os, sys, time
import numpy as np
import rclpy
from rclpy.node import Node
from rclpy.qos import HistoryPolicy, QoSProfile, ReliabilityPolicy
from sensor_msgs.msg import CameraInfo, PointCloud2
from msg_adapters.skeleton_msg import skeletons_to_msg
from msg_adapters.stamp import frame_of_stamp, stamp_of_frame

QOS = QoSProfile(reliability=ReliabilityPolicy.RELIABLE, history=HistoryPolicy.KEEP_LAST, depth=100)
CAMERAS = range(int(os.environ['FAKE_CAMERAS']))
role = sys.argv[1]
rclpy.init(args=sys.argv)
node = Node(role)
open(os.path.join(os.environ['FAKE_PIDS'], node.get_fully_qualified_name().strip('/').replace('/', '_')),
     'w').write(f"{os.getpid()}\\n{os.environ.get('FASTRTPS_DEFAULT_PROFILES_FILE', '')}")
if role == 'heatmap_detector':
    pub = node.create_publisher(PointCloud2, 'people2d', QOS)
    node.create_subscription(PointCloud2, 'openpose', lambda m: pub.publish(PointCloud2(header=m.header)), QOS)
elif role == 'association':
    node.create_publisher(PointCloud2, '/people/bundles', QOS)
    for c in CAMERAS:
        node.create_subscription(PointCloud2, f'/cam{c}/people2d', lambda m: None, QOS)
elif role == 'bp_solver':
    pub = node.create_publisher(PointCloud2, '/skeletons', QOS)
    node.create_subscription(PointCloud2, '/people/bundles', lambda m: None, QOS)
    def answer(info):
        frame = frame_of_stamp(info.header.stamp)
        joints = np.full((1, 14, 3), frame / 1000.0)
        pub.publish(skeletons_to_msg(np.array([7]), joints, info.header))
    node.create_subscription(CameraInfo, '/cam0/camera_info', answer, QOS)
elif role == 'bag_player':
    openpose = [node.create_publisher(PointCloud2, f'/cam{c}/openpose', QOS) for c in CAMERAS]
    info = node.create_publisher(CameraInfo, '/cam0/camera_info', QOS)
    # The runner and the solver both listen to the camera info: wait until both are matched.
    while any(p.get_subscription_count() == 0 for p in openpose) or info.get_subscription_count() < 2:
        time.sleep(0.02)
    first, end = map(int, os.environ['FAKE_FRAMES'].split(':'))
    for frame in range(first, end):
        header = CameraInfo().header
        header.stamp = stamp_of_frame(frame)
        for p in openpose:
            p.publish(PointCloud2(header=header))
        info.publish(CameraInfo(header=header))
        with open(os.path.join(os.environ['FAKE_PIDS'], os.pardir, 'played'), 'w') as f:
            f.write(str(frame))
        time.sleep(0.01)
    sys.exit(0)
try:
    rclpy.spin(node)
except KeyboardInterrupt:
    pass
'''


@pytest.fixture
def fake_graph(tmp_path, monkeypatch):
    """Runner arguments for a 2-camera fake graph over frames 300..319 (timeout 2 s: a failure ends fast)."""
    monkeypatch.setenv('ROS_AUTOMATIC_DISCOVERY_RANGE', 'LOCALHOST')
    monkeypatch.setenv('ROS_DOMAIN_ID', str(DOMAIN_ID))
    monkeypatch.delenv('FASTRTPS_DEFAULT_PROFILES_FILE', raising=False)  # the runner sets it: undo after
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
                      .replace('timeout: 120.0', 'timeout: 2.0'))

    def fake_command(spec, params_file, python=sys.executable):
        assert Path(params_file) == config.resolve()
        return [python, str(script), spec.executable, '--ros-args', *(['-r', f'__ns:=/{spec.namespace}']
                                                                      if spec.namespace else [])]

    monkeypatch.setattr(graph, 'node_command', fake_command)
    predictions = tmp_path / 'out' / 'p.jsonl'
    return ['--config', str(config), '--bag', str(bag), '--predictions', str(predictions)], predictions, frames


def test_runner_plays_collects_and_scores(fake_graph, tmp_path, monkeypatch, capsys):
    args, predictions, frames = fake_graph
    code = graph.main(args)
    out, err = capsys.readouterr()
    assert code == 0, err
    # A reader may match the player a moment after the player matched it (DDS discovery is not
    # symmetric in time), so the first camera infos can be lost: latency covers those seen.
    counts = re.search(r'frames in (\d+) \(seen on /cam0/camera_info: (\d+)\), frames out (\d+)', out)
    assert counts and int(counts[1]) == int(counts[3]) == len(frames) and 1 <= int(counts[2]) <= len(frames)
    assert 'missing 0: none; duplicate 0: none; unexpected 0: none' in out
    assert re.search(r'latency /cam0/camera_info -> /skeletons: p50 [0-9.]+ ms, p95 [0-9.]+ ms, max [0-9.]+ ms '
                     rf'\({counts[2]} frames\)', out)
    lines = [json.loads(line) for line in predictions.read_text().splitlines()]
    assert [r['frame'] for r in lines] == list(frames)
    assert all(r['people'][0]['id'] == 7 and r['people'][0]['joints'][0] == [r['frame'] / 1000] * 3 for r in lines)
    assert 'PCP (%), alpha=0.5' in out and 'Actor 1 strict' in out  # mvpose-eval's table
    started = {p.name: p.read_text().split('\n') for p in (tmp_path / 'pids').iterdir()}
    assert set(started) == {'cam0_heatmap_detector', 'cam1_heatmap_detector', 'association', 'bp_solver', 'bag_player'}
    assert [n for n, (pid, _) in started.items() if alive(int(pid))] == []
    # Every node used the Fast DDS profile beside the parameter file.
    assert {profile for _, profile in started.values()} == {str(tmp_path / 'fastdds.xml')}


def test_runner_interrupted_stops_everything_and_writes_what_it_has(fake_graph, tmp_path, monkeypatch, capsys):
    args, predictions, _ = fake_graph
    frames = range(300, 700)  # ~4 s of playing: long enough to be interrupted in the middle
    monkeypatch.setenv('FAKE_FRAMES', f'{frames.start}:{frames.stop}')
    bag = tmp_path / 'long_bag'
    write_bag(bag, [('/cam0/openpose', PointCloud2(), f * 1_000_000_000 // 25) for f in frames])
    args = [a if a != args[args.index('--bag') + 1] else str(bag) for a in args]
    predictions.parent.mkdir(parents=True, exist_ok=True)
    predictions.write_text('an older run\n')

    def ctrl_c_once_playing():
        played = tmp_path / 'played'
        deadline = time.monotonic() + 60
        while time.monotonic() < deadline and not (played.exists() and played.read_text()
                                                   and int(played.read_text()) >= 400):
            time.sleep(0.05)
        os.kill(os.getpid(), signal.SIGINT)

    threading.Thread(target=ctrl_c_once_playing, daemon=True).start()
    code = graph.main(args)
    err = capsys.readouterr().err
    assert code == 128 + signal.SIGINT, err
    assert 'interrupted by SIGINT; every node stopped' in err
    written = read_predictions(predictions)  # a whole, valid file: not the older run, not cut short
    assert 0 < len(written) < len(frames)
    assert list(written) == list(range(300, 300 + len(written)))
    assert not predictions.with_name(predictions.name + '.partial').exists()
    started = {p.name: int(p.read_text().split('\n')[0]) for p in (tmp_path / 'pids').iterdir()}
    assert 'bag_player' in started and [n for n, pid in started.items() if alive(pid)] == []


def test_runner_expects_the_stamps_of_every_loop_as_the_player_sends_them(tmp_path):
    frames = range(300, 310)
    bag = tmp_path / 'bag'
    write_bag(bag, [('/cam0/openpose', PointCloud2(), f * 1_000_000_000 // 25) for f in frames])
    stamps = graph.input_stamps(bag, '/cam0/openpose', loops=3)
    player = [frame.stamp_ns + offset for _, offset, frame in
              looped(lambda: group_frames(read_bag(bag, ['/cam0/openpose'])), 3)]
    assert stamps == player and len(set(stamps)) == 30
    assert [round(s * 25 / 1e9) for s in stamps] == list(range(300, 330))  # the timeline goes on
