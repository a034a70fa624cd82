"""Record the graph's /diagnostics and tell when each status went WARN or ERROR.

    python -m mvpose_ros.graph.diagnostics_recorder --output out/diag.jsonl [--duration S]
    python -m mvpose_ros.graph.diagnostics_recorder --summary out/diag.jsonl [--mark-stamp NS]

Recording (beside a running graph, on its ROS_DOMAIN_ID): every DiagnosticArray as one JSON line
`{"t": <receipt, s of the system clock>, "statuses": [{"name", "level", "message", "values"}]}`,
until Ctrl-C or --duration s. Summary: per status its worst level, and the first line at each
level above OK with its message, in seconds after the first line, or with --mark-stamp after the
first line in which a status reports a newest stamp >= NS (when the graph had seen that frame):
e.g. the stamp of the frame from which a camera was bumped or unplugged.
"""
from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path
from typing import Any, Iterable, Sequence, TextIO

from mvpose_ros.core.health.status import Level

NEWEST = 'newest stamp (ns)'


def summarise(lines: Sequence[dict[str, Any]], mark_stamp: int | None = None) -> list[dict[str, Any]]:
    """Per status name (in first-seen order): worst level, and for WARN and ERROR the first line's
    time (s after the origin: the first line, or the first one reporting a newest stamp >=
    mark_stamp) and message. Also 'origin' (s of the system clock) on every row."""
    if not lines:
        return []
    origin = lines[0]['t']
    if mark_stamp is not None:
        origin = next((line['t'] for line in lines for s in line['statuses']
                       if s['values'].get(NEWEST, '').isdigit() and int(s['values'][NEWEST]) >= mark_stamp), None)
        if origin is None:
            raise ValueError(f'no status reported a stamp >= {mark_stamp} ns')
    rows: dict[str, dict[str, Any]] = {}
    for line in lines:
        for s in line['statuses']:
            row = rows.setdefault(s['name'], {'name': s['name'], 'worst': Level.OK, 'origin': origin})
            level = Level(s['level'])
            row['worst'] = max(row['worst'], level)
            if level > Level.OK and level.name not in row:
                row[level.name] = (line['t'] - origin, s['message'])
    return list(rows.values())


def format_summary(rows: Iterable[dict[str, Any]]) -> str:
    """One line per status: worst level, then when it first went WARN / ERROR and why."""
    out = []
    for row in rows:
        seen = [f'{name} at {t:+.1f} s: {message}' for name in ('WARN', 'ERROR') if name in row
                for t, message in [row[name]]]
        out.append(f'{row["worst"].name:5}  {row["name"]}' + (f'  [{"; ".join(seen)}]' if seen else ''))
    return '\n'.join(out)


def read_lines(path: Path) -> list[dict[str, Any]]:
    """The recorded lines of a file written by record()."""
    with open(path, encoding='utf-8') as f:
        return [json.loads(line) for line in f if line.strip()]


def record(output: Path, duration: float | None) -> int:
    """Write every /diagnostics message to `output` as it comes, until Ctrl-C or `duration` s."""
    import rclpy
    from diagnostic_msgs.msg import DiagnosticArray
    from rclpy.executors import ExternalShutdownException

    from msg_adapters.diagnostics_msg import msg_to_statuses
    from mvpose_ros import topics
    from mvpose_ros.nodes.health import DIAGNOSTICS_QOS

    rclpy.init()
    node = rclpy.create_node('diagnostics_recorder')
    output.parent.mkdir(parents=True, exist_ok=True)
    with open(output, 'w', encoding='utf-8') as f:
        def on_msg(msg: DiagnosticArray) -> None:
            statuses = [{'name': s.name, 'level': int(s.level), 'message': s.message, 'values': s.values}
                        for s in msg_to_statuses(msg)]
            f.write(json.dumps({'t': time.time(), 'statuses': statuses}) + '\n')
            f.flush()

        node.create_subscription(DiagnosticArray, topics.DIAGNOSTICS, on_msg, DIAGNOSTICS_QOS)
        end = None if duration is None else time.monotonic() + duration
        try:
            while rclpy.ok() and (end is None or time.monotonic() < end):
                rclpy.spin_once(node, timeout_sec=0.1)
        except (KeyboardInterrupt, ExternalShutdownException):
            pass
        finally:
            node.destroy_node()
            rclpy.try_shutdown()
    return 0


def main(argv: Sequence[str] | None = None, out: TextIO | None = None) -> int:
    """Entry point of `python -m mvpose_ros.graph.diagnostics_recorder`; returns the exit code."""
    p = argparse.ArgumentParser(prog='python -m mvpose_ros.graph.diagnostics_recorder',
                                description=__doc__.split('\n')[0])
    what = p.add_mutually_exclusive_group(required=True)
    what.add_argument('--output', type=Path, help='record /diagnostics to this JSON lines file')
    what.add_argument('--summary', type=Path, help='summarise a recorded file')
    p.add_argument('--duration', type=float, help='record this many s (default: until Ctrl-C)')
    p.add_argument('--mark-stamp', type=int, help='summary: times after the graph saw this stamp (ns)')
    args = p.parse_args(argv)
    if args.output:
        return record(args.output, args.duration)
    try:
        print(format_summary(summarise(read_lines(args.summary), args.mark_stamp)), file=out or sys.stdout)
    except (OSError, ValueError) as exc:
        print(f'{args.summary}: {exc}', file=sys.stderr)
        return 2
    return 0


if __name__ == '__main__':
    sys.exit(main())
