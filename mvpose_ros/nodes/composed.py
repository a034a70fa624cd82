"""Several nodes in one process (what ROS users know as composition): each keeps its name,
namespace, parameters and topics, and they share one interpreter and one DDS participant, so what
a process holds (numba and its compiled kernels, rclpy, the DDS shared memory) is held once.

    python -m mvpose_ros.nodes.composed --node heatmap_detector --ros-args -r __ns:=/cam0 \
        --params-file shelf.yaml -p camera:=0 --node heatmap_detector --ros-args ...

Each `--node EXECUTABLE` is followed by that node's own ROS arguments, as its own process would
take them (nodes.runtime.run_nodes; `mvpose-graph --compose`). The nodes run in the events
executor, but for a node that needs rclpy's single-threaded one (bp_solver), which spins in a
thread of its own.
"""
from __future__ import annotations

import importlib
import sys
from functools import partial
from typing import Callable, Sequence

from rclpy.node import Node

from mvpose_ros.nodes.runtime import run_nodes

NODE_MARK = '--node'
# executable -> its node class, in mvpose_ros.nodes.<executable>; imported only when composed
COMPOSABLE = {'heatmap_detector': 'HeatmapDetectorNode', 'association': 'AssociationNode',
              'bp_solver': 'BpSolverNode'}


def parse(argv: Sequence[str]) -> list[tuple[str, list[str]]]:
    """`--node EXE ARGS... --node EXE ARGS...` -> [(EXE, ARGS)]; ValueError naming what is wrong."""
    if not argv or argv[0] != NODE_MARK:
        raise ValueError(f'expected {NODE_MARK} EXECUTABLE [--ros-args ...], repeated; got {list(argv[:3])}')
    nodes: list[tuple[str, list[str]]] = []
    for token in argv:
        if token == NODE_MARK:
            nodes.append(('', []))
        elif not nodes[-1][0]:
            if token not in COMPOSABLE:
                raise ValueError(f'{token!r} is not a node that can be composed ({", ".join(COMPOSABLE)})')
            nodes[-1] = (token, [])
        else:
            nodes[-1][1].append(token)
    if any(not exe for exe, _ in nodes):
        raise ValueError(f'{NODE_MARK} without an executable')
    return nodes


def factories(nodes: Sequence[tuple[str, list[str]]]) -> tuple[list[Callable[[], Node]], list[bool]]:
    """A factory per node (its class with its own arguments) and, per node, whether it can run
    in the events executor."""
    made: list[Callable[[], Node]] = []
    events: list[bool] = []
    for exe, args in nodes:
        module = importlib.import_module(f'mvpose_ros.nodes.{exe}')
        made.append(partial(getattr(module, COMPOSABLE[exe]), cli_args=args))
        events.append(getattr(module, 'EVENTS_EXECUTOR', True))
    return made, events


def main(argv: list[str] | None = None) -> None:
    """Entry point of `ros2 run mvpose_ros composed --node EXE --ros-args ... --node EXE ...`."""
    argv = sys.argv if argv is None else argv
    try:
        nodes = parse(argv[1:])
    except ValueError as exc:
        print(f'composed: {exc}', file=sys.stderr)
        raise SystemExit(2) from None
    made, events = factories(nodes)
    run_nodes(made, [argv[0]], events)  # no global ROS arguments: each node has its own


if __name__ == '__main__':
    main()
