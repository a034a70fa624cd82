"""The diagnostics recorder: every /diagnostics message of a running graph as a JSON line, and the
summary of a recording (each status's worst level, when it first went WARN and ERROR, from the
first line or from when the graph saw a given stamp)."""
from __future__ import annotations

import io
import json
import subprocess
import sys

import pytest
from diagnostic_msgs.msg import DiagnosticArray

from msg_adapters.diagnostics_msg import statuses_to_msg
from mvpose_ros.core.health.status import Level, Status
from mvpose_ros.graph.diagnostics_recorder import NEWEST, format_summary, main, read_lines, summarise
from mvpose_ros.nodes.health import DIAGNOSTICS_QOS
from ros_harness import REPO, node_env, probe, spin_until


def _line(t: float, *statuses: tuple[str, Level, str, str]) -> dict:
    return {'t': t, 'statuses': [{'name': n, 'level': int(level), 'message': m, 'values': {NEWEST: stamp}}
                                 for n, level, m, stamp in statuses]}


LINES = [_line(100.0, ('det: input a', Level.OK, '25 Hz', '10'), ('det: input b', Level.OK, '25 Hz', '10')),
         _line(101.0, ('det: input a', Level.WARN, 'slow', '20'), ('det: input b', Level.OK, '25 Hz', '20')),
         _line(102.5, ('det: input a', Level.ERROR, 'silent', '30'), ('det: input b', Level.WARN, 'late', '30')),
         _line(103.0, ('det: input a', Level.WARN, 'slow again', '40'))]


def test_the_summary_gives_each_status_its_worst_level_and_first_warn_and_error():
    rows = summarise(LINES)
    assert [(r['name'], r['worst']) for r in rows] == [('det: input a', Level.ERROR), ('det: input b', Level.WARN)]
    assert rows[0]['WARN'] == (1.0, 'slow') and rows[0]['ERROR'] == (2.5, 'silent') and 'ERROR' not in rows[1]
    assert format_summary(rows).splitlines() == [
        'ERROR  det: input a  [WARN at +1.0 s: slow; ERROR at +2.5 s: silent]',
        'WARN   det: input b  [WARN at +2.5 s: late]']
    # from when the graph saw stamp 20: the first line reporting it
    marked = summarise(LINES, mark_stamp=20)
    assert marked[0]['WARN'] == (0.0, 'slow') and marked[0]['origin'] == 101.0
    with pytest.raises(ValueError, match='no status reported a stamp >= 99 ns'):
        summarise(LINES, mark_stamp=99)
    assert summarise([]) == []


def test_the_command_summarises_a_file_and_names_one_it_cannot_read(tmp_path, capsys):
    path = tmp_path / 'diag.jsonl'
    path.write_text(''.join(json.dumps(line) + '\n' for line in LINES) + '\n')
    assert read_lines(path) == LINES
    out = io.StringIO()
    assert main(['--summary', str(path), '--mark-stamp', '30'], out) == 0
    # times from the line that first reports stamp 30: the first WARN came before it
    assert out.getvalue().startswith('ERROR  det: input a  [WARN at -1.5 s: slow; ERROR at +0.0 s: silent]')
    assert main(['--summary', str(tmp_path / 'none.jsonl')]) == 2
    assert 'none.jsonl' in capsys.readouterr().err


def test_it_records_every_diagnostics_message_of_a_running_graph(domain, tmp_path):
    output = tmp_path / 'diag.jsonl'
    proc = subprocess.Popen([sys.executable, '-m', 'mvpose_ros.graph.diagnostics_recorder', '--output', str(output),
                             '--duration', '60'], env=node_env(domain), cwd=REPO)
    try:
        with probe(domain, 'diagnostics_probe') as (node, executor):
            pub = node.create_publisher(DiagnosticArray, '/diagnostics', DIAGNOSTICS_QOS)
            assert spin_until(executor, lambda: pub.get_subscription_count() > 0, 30.0)
            for k in range(3):
                status = Status('det: input a', Level.WARN if k else Level.OK, f'message {k}', {NEWEST: str(k)}, 'a')
                pub.publish(statuses_to_msg([status], node.get_clock().now().to_msg()))
            assert spin_until(executor, lambda: output.is_file() and len(read_lines(output)) == 3, 30.0)
    finally:
        proc.terminate()
        proc.wait(30)
    lines = read_lines(output)
    assert [s['message'] for line in lines for s in line['statuses']] == ['message 0', 'message 1', 'message 2']
    assert [line['t'] for line in lines] == sorted(line['t'] for line in lines)
    assert summarise(lines)[0]['worst'] == Level.WARN
