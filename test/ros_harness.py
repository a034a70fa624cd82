"""Test harness for nodes as separate processes: an in-test rclpy probe node and node
processes, all on one private DDS domain confined to this machine."""
from __future__ import annotations

import os
import subprocess
import sys
import time
from contextlib import contextmanager
from pathlib import Path
from typing import Callable, Iterator

import rclpy
from rclpy.context import Context
from rclpy.executors import SingleThreadedExecutor
from rclpy.node import Node

REPO = Path(__file__).resolve().parents[1]


FASTDDS_PROFILE = REPO / 'config' / 'fastdds.xml'


def node_env(domain_id: int) -> dict[str, str]:
    return dict(os.environ, PYTHONPATH=str(REPO), ROS_AUTOMATIC_DISCOVERY_RANGE='LOCALHOST',
                ROS_DOMAIN_ID=str(domain_id), FASTRTPS_DEFAULT_PROFILES_FILE=str(FASTDDS_PROFILE),
                OMP_NUM_THREADS='1', OPENBLAS_NUM_THREADS='1')


@contextmanager
def probe(domain_id: int, name: str) -> Iterator[tuple[Node, SingleThreadedExecutor]]:
    """An rclpy node with its own context and executor on domain_id."""
    os.environ['ROS_AUTOMATIC_DISCOVERY_RANGE'] = 'LOCALHOST'
    os.environ['FASTRTPS_DEFAULT_PROFILES_FILE'] = str(FASTDDS_PROFILE)  # read at context init
    context = Context()
    rclpy.init(context=context, domain_id=domain_id)
    node = Node(name, context=context)
    executor = SingleThreadedExecutor(context=context)
    executor.add_node(node)
    try:
        yield node, executor
    finally:
        executor.shutdown()
        node.destroy_node()
        context.try_shutdown()


def start_node(module: str, domain_id: int, log: Path, *ros_args: str) -> subprocess.Popen:
    """`python -m mvpose_ros.nodes.<module> --ros-args ...` with stderr to log."""
    with open(log, 'w') as err:
        return subprocess.Popen([sys.executable, '-m', f'mvpose_ros.nodes.{module}', '--ros-args', *ros_args],
                                env=node_env(domain_id), stdout=err, stderr=subprocess.STDOUT, cwd=REPO)


def spin_until(executor: SingleThreadedExecutor, done: Callable[[], bool], timeout: float = 20.0) -> bool:
    deadline = time.monotonic() + timeout
    while not done() and time.monotonic() < deadline:
        executor.spin_once(timeout_sec=0.02)
    return done()


def stop(proc: subprocess.Popen) -> None:
    if proc.poll() is None:
        proc.send_signal(subprocess.signal.SIGINT)
        try:
            proc.wait(5)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait()
