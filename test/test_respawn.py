"""Respawn of dead nodes (mvpose-graph --respawn): the policy (delay, the cap per minute, the
exit cause) and what a restart did to the output (frames lost, the times until output resumed,
the ids before and after), and a real bp_solver killed during a graph run. The runner's path
with fake nodes is in test_processes."""
from __future__ import annotations

import io
import itertools
import json
import re
import signal
from collections import Counter
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest

from msg_adapters.stamp import stamp_ns, stamp_of_frame
from mvpose_ros.bags.io import write_bag
from mvpose_ros.bags.recipes import shelf_recipe
from mvpose_ros.cli import graph
from mvpose_ros.core.datasets.shelf_campus import SHELF_TEST_FRAMES, dataset_dir
from mvpose_ros.core.evaluation.predictions import read_predictions
from mvpose_ros.graph import runner, session
from mvpose_ros.graph.config import GraphSettings, NodeSpec, graph_nodes, output_topics
from mvpose_ros.graph.processes import ProcessGroup
from mvpose_ros.graph.recorder import SkeletonRecorder
from mvpose_ros.graph.report import print_restarts, report, restart_effects
from mvpose_ros.graph.respawn import Respawner, Restart, exit_cause
from ros_harness import ros_domain

REPO = Path(__file__).resolve().parents[1]

MS = 1_000_000


def test_exit_cause_names_the_signal_or_the_code():
    assert exit_cause(-signal.SIGKILL) == 'killed by SIGKILL'
    assert exit_cause(-signal.SIGSEGV) == 'killed by SIGSEGV'
    assert exit_cause(3) == 'exited with code 3'
    assert exit_cause(0) == 'exited with code 0'


def test_restart_after_the_delay_and_counted_per_node():
    lines = []
    r = Respawner(delay=1.0, limit=5, log=lines.append)
    assert r.exited('bp_solver', -9, 'last line of its log', now=100.0) is None
    assert r.pending('bp_solver') and r.due(now=100.5) == []
    (due,) = r.due(now=101.0)
    assert (due.node, due.cause, due.count) == ('bp_solver', 'killed by SIGKILL', 1)
    r.restarted('bp_solver')
    assert not r.pending('bp_solver') and due.restarted_ns >= due.died_ns
    assert r.exited('association', 1, now=102.0) is None
    assert r.exited('bp_solver', -15, now=103.0) is None
    assert [(x.node, x.count) for x in r.restarts] == [('bp_solver', 1), ('association', 1), ('bp_solver', 2)]
    assert lines[0] == 'node bp_solver killed by SIGKILL; restart 1 in 1 s (1 within 60 s, at most 5)'
    assert lines[1] == '  | last line of its log'
    assert 'node bp_solver started again (restart 1)' in lines


def test_a_node_dying_at_once_every_time_is_given_up_after_the_limit_per_minute():
    r = Respawner(delay=0.0, limit=3)
    for k in range(3):
        assert r.exited('cam1/heatmap_detector', 2, now=10.0 + k) is None
        r.restarted('cam1/heatmap_detector')
    why = r.exited('cam1/heatmap_detector', 2, now=13.0)
    assert why == 'exited with code 2 after 3 restarts within 60 s: not restarted again'
    # the deaths a minute old no longer count
    r = Respawner(delay=0.0, limit=3)
    for t in (0.0, 1.0, 2.0):
        assert r.exited('a', 1, now=t) is None
        r.restarted('a')
    assert r.exited('a', 1, now=61.5) is None


@pytest.mark.parametrize('delay, limit', [(-1.0, 5), (1.0, 0)])
def test_bad_respawn_settings(delay, limit):
    with pytest.raises(ValueError, match='respawn delay must be >= 0 s and limit >= 1'):
        Respawner(delay, limit)


def test_every_node_but_the_player_has_an_output_topic():
    nodes = graph_nodes(2, 'bag', 1.0)
    assert output_topics(nodes) == {'cam0/heatmap_detector': 'cam0/people2d', 'cam1/heatmap_detector': 'cam1/people2d',
                                    'association': 'people/bundles', 'bp_solver': 'skeletons'}
    assert output_topics([NodeSpec('heatmap_detector')], 'door/people2d') == {'heatmap_detector': 'door/people2d'}


def _run(frames: int, gone: set[int], died_ns: int, ids_of=lambda f: [0, 1]):
    """A recorded run of `frames` frames, 40 ms apart, each output 100 ms after its input, but for
    the frames in `gone`."""
    stamps = [f * 40 * MS for f in range(frames)]
    t0 = 1_795_000_000_000_000_000
    node = SimpleNamespace(
        info_at={s: t0 + s for s in stamps},
        outputs={s: (np.array(ids_of(f)), np.zeros((len(ids_of(f)), 14, 3))) for f, s in enumerate(stamps)
                 if f not in gone},
        received=Counter(), bad=[], first_after={}, live_at={}, dropped=set())
    node.output_at = {s: t0 + s + 100 * MS for s in node.outputs}
    node.received.update(node.outputs.keys())
    return stamps, node, t0 + died_ns


def test_frames_lost_in_a_restart_are_the_gap_around_it_and_not_missing():
    # the solver died at 2.05 s (frames up to 48 were out, 49..51 in its window); frames 49..99
    # never came out; the first frame input after the death with an output is 100
    gone = set(range(49, 100))
    stamps, node, died = _run(200, gone, 2050 * MS, ids_of=lambda f: [0, 1] if f < 150 else [0, 1, 2])
    node.first_after[('skeletons', died)] = node.output_at[stamps[100]] - 5 * MS
    restart = Restart('bp_solver', 'killed by SIGKILL', 1, died, died + 1000 * MS)
    (effect,) = restart_effects(stamps, node, [restart], {'bp_solver': 'skeletons'}, 25.0)
    assert effect.lost == stamps[49:100]
    assert effect.graph_back_s == pytest.approx(4.1 - 2.05)  # frame 100: in at 4.0 s, out at 4.1 s
    assert effect.node_back_s == pytest.approx(4.095 - 2.05)
    assert effect.ids_before == [0, 1] and effect.ids_after == [0, 1]  # the second before and after
    out = io.StringIO()
    settings = GraphSettings('shelf', 5, 'b', 'p', 25.0, 1.0, 10.0)
    assert report(stamps, node, settings, out, [effect]) == []
    assert 'missing 0: none; lost in restarts 51; duplicate 0' in out.getvalue()
    out = io.StringIO()
    print_restarts([effect], node.info_at[stamps[0]], {'bp_solver': 'skeletons'}, 25.0, out)
    assert out.getvalue().splitlines() == [
        'restarts 1, frames lost in them 51:',
        '  bp_solver killed by SIGKILL (restart 1) at 2.1 s, started again 1.0 s later; /skeletons back after 2.0 s, '
        '/skeletons of new frames after 2.1 s; lost 51 (frames 49-99); ids [0, 1] before, [0, 1] after']
    # without the restart the same frames are missing: a problem
    assert report(stamps, node, settings, io.StringIO()) == ['51 of 200 input stamps got no /skeletons']


def test_a_frame_missing_away_from_a_restart_is_still_a_problem_and_no_resume_is_one():
    stamps, node, died = _run(100, {10, 60, 61}, 2400 * MS)  # death at 2.4 s: 60, 61 in flight
    settings = GraphSettings('shelf', 5, 'b', 'p', 25.0, 1.0, 10.0)
    (effect,) = restart_effects(stamps, node, [Restart('association', 'exited with code 1', 1, died)], {}, 25.0)
    assert effect.lost == stamps[60:62] and effect.node_back_s is None
    assert report(stamps, node, settings, io.StringIO(), [effect]) == ['1 of 100 input stamps got no /skeletons']
    # the node died and nothing new came out afterwards
    stamps, node, died = _run(100, set(range(60, 100)), 2400 * MS)
    (effect,) = restart_effects(stamps, node, [Restart('association', 'exited with code 1', 1, died)], {}, 25.0)
    assert effect.graph_back_s is None and effect.lost == stamps[60:]
    assert report(stamps, node, settings, io.StringIO(), [effect]) == [
        'no /skeletons of a new frame after association exited with code 1']


def test_a_killed_bp_solver_in_a_real_graph_is_restarted_and_its_output_resumes(tmp_path, monkeypatch, capsys):
    """The real nodes (3 cameras of Shelf, 250 frames as fast as they are solved): bp_solver is killed
    (SIGKILL) once 30 frames are out; it is restarted, the skeletons of the frames after its
    restart come, the gap is counted lost, and the people keep their ids (association owns them)."""
    with ros_domain(monkeypatch, profile=None) as domain:  # the runner sets the profile: undone after
        end = stamp_ns(stamp_of_frame(SHELF_TEST_FRAMES.start + 250))
        bag = tmp_path / 'bag'
        items = itertools.takewhile(lambda item: item[2] < end, shelf_recipe(dataset_dir('shelf')).items())
        write_bag(bag, (item for item in items if int(item[0].split('/')[1][3:]) < 3))  # '/cam<c>/...'

        (tmp_path / 'fastdds.xml').write_text((REPO / 'config' / 'fastdds.xml').read_text())
        config = tmp_path / 'graph.yaml'
        # Played as fast as the skeletons come (rate 0), a frame given up after 1 s without them: the
        # player waits on the graph, not on a clock, so however long the restart takes, frames
        # are left to show the output resuming (at the recorded rate a slow restart outlasted the bag).
        text = (REPO / 'config' / 'shelf.yaml').read_text().replace('cameras: 5', 'cameras: 3')
        text = text.replace('    rate: 1.0\n    timeout:', '    rate: 0.0\n    timeout:')
        text = text.replace('    max_in_flight: 16\n', '    max_in_flight: 4\n    ack_timeout: 1.0\n')
        assert text.count('rate: 0.0') == 1 and 'ack_timeout: 1.0' in text
        config.write_text(text)
        groups = []

        class Kept(ProcessGroup):
            def __enter__(self):
                groups.append(self)
                return super().__enter__()

        class Killing(SkeletonRecorder):
            def _on_skeletons(self, cdr, info):
                super()._on_skeletons(cdr, info)
                if len(self.outputs) == 30 and not killed:
                    killed.append(groups[0].procs['bp_solver'].pid)
                    groups[0].procs['bp_solver'].send_signal(signal.SIGKILL)

        killed = []
        monkeypatch.setattr(runner, 'ProcessGroup', Kept)
        monkeypatch.setattr(session, 'SkeletonRecorder', Killing)
        predictions = tmp_path / 'out' / 'p.jsonl'
        code = graph.main(['--config', str(config), '--bag', str(bag), '--predictions', str(predictions),
                           '--respawn', '--domain-id', str(domain)])
    out, err = capsys.readouterr()
    assert killed and code == 0, out + err
    assert 'node bp_solver killed by SIGKILL; restart 1 in 1 s' in err
    line = next(x for x in out.splitlines() if x.startswith('  bp_solver killed by SIGKILL (restart 1)'))
    lost = int(re.search(r'; lost (\d+)', line)[1])
    got = read_predictions(predictions)
    assert lost > 0 and len(got) + lost == 250 and max(got) == SHELF_TEST_FRAMES.start + 249, out
    assert 'missing 0: none' in out
    before, after = (set(json.loads(x)) for x in re.search(r'ids (\[.*\]) before, (\[.*\]) after', line).groups())
    assert before & after, line  # the same people, the same ids


@pytest.mark.parametrize('args, problem', [
    (['--respawn-delay', '2'], '--respawn-delay needs --respawn'),
    (['--respawn-limit', '2'], '--respawn-limit needs --respawn'),
    (['--report-every', '0'], '--report-every must be > 0 s, got 0'),
    (['--respawn', '--respawn-delay', '-1'], '--respawn-delay must be >= 0 s, got -1'),
    (['--respawn', '--respawn-limit', '0'], '--respawn-limit must be >= 1, got 0'),
    (['--domain-id', '233'], '--domain-id must be in 0-232 (DDS has no port for a higher one), got 233'),
    (['--respawn', '--compose', 'detectors'], 'not with --compose detectors'),
])
def test_respawn_options_are_checked(args, problem, capsys):
    assert graph.main(['--config', str(REPO / 'config' / 'shelf.yaml'), '--bag', str(REPO / 'nowhere'), *args]) == 2
    assert problem in capsys.readouterr().err


@pytest.mark.parametrize('args, compose', [([], 'all'), (['--respawn'], 'none'),
                                           (['--compose', 'detectors'], 'detectors'),
                                           (['--respawn', '--compose', 'none'], 'none')])
def test_nodes_share_processes_by_default_and_each_has_its_own_with_respawn(args, compose):
    parsed = graph.build_parser().parse_args(['--config', str(REPO / 'config' / 'shelf.yaml'), *args])
    assert graph._compose(parsed) == compose
