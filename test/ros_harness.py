"""Test harness for nodes as separate processes: a private DDS domain per test, confined to this
machine (`ros_domain`, `ros_env`), an in-test rclpy probe node, node processes, and waits on events
(a message seen, a reader or writer matched), never on elapsed time."""
from __future__ import annotations

import fcntl
import itertools
import os
import subprocess
import sys
import tempfile
import time
from contextlib import contextmanager
from pathlib import Path
from typing import Callable, Iterable, Iterator, Mapping

import rclpy
from diagnostic_msgs.msg import DiagnosticArray
from rclpy.context import Context
from rclpy.executors import SingleThreadedExecutor
from rclpy.node import Node
from std_msgs.msg import Empty

from msg_adapters.diagnostics_msg import msg_to_statuses
from mvpose_ros.core.health.links import LINKS, WRITERS
from mvpose_ros.graph.session import DDS_QOS_FROM_XML_ENV
from mvpose_ros.nodes.bag_player import START_QOS
from mvpose_ros.nodes.health import DIAGNOSTICS_QOS
from mvpose_ros.topics import DIAGNOSTICS

REPO = Path(__file__).resolve().parents[1]
FASTDDS_PROFILE = REPO / 'config' / 'fastdds.xml'
PROFILE_VARS = ('FASTRTPS_DEFAULT_PROFILES_FILE', 'FASTDDS_DEFAULT_PROFILES_FILE')  # Fast DDS 2 and 3
QOS_FROM_XML = DDS_QOS_FROM_XML_ENV  # the profile's history memory policy applies only with it
# Domains 1..101: valid with the default port mapping on Linux (0 is everybody's default: never).
DOMAINS = range(1, 102)
_LOCK_DIR = Path(tempfile.gettempdir()) / 'mvpose_ros_test_domains'
_held: dict[int, int] = {}  # domain -> file descriptor of its lock
_counter = itertools.count()


def _try_lock(domain: int) -> int | None:
    _LOCK_DIR.mkdir(exist_ok=True)
    fd = os.open(_LOCK_DIR / f'{domain}.lock', os.O_RDWR | os.O_CREAT, 0o666)
    try:
        fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
    except OSError:
        os.close(fd)
        return None
    return fd


def acquire_domain() -> int:
    """A ROS_DOMAIN_ID no other process on this machine holds (a lock file per domain, released by
    `release_domain` or when this process ends), so that tests and concurrently running suites
    never see each other's nodes. The search starts from this process's pid and a counter."""
    start = os.getpid() * 7 + next(_counter)
    for k in range(len(DOMAINS)):
        domain = DOMAINS[(start + k) % len(DOMAINS)]
        if domain in _held:
            continue
        fd = _try_lock(domain)
        if fd is not None:
            _held[domain] = fd
            return domain
    raise RuntimeError(f'every ROS domain {DOMAINS.start}..{DOMAINS.stop - 1} is in use by a test')


def release_domain(domain: int) -> None:
    """Give `domain` back (its nodes must be gone)."""
    fd = _held.pop(domain, None)
    if fd is not None:
        os.close(fd)


def ros_env(domain: int, profile: Path | None = FASTDDS_PROFILE, base: Mapping[str, str] | None = None,
            **extra: str) -> dict[str, str]:
    """The environment of a node process (and of this one) on `domain`, discovery on localhost only,
    this checkout importable, one BLAS thread, the Fast DDS profile `profile` (None: Fast DDS's
    defaults); `extra` on top."""
    env = {k: v for k, v in (os.environ if base is None else base).items()
           if k not in ('ROS_STATIC_PEERS', 'ROS_LOCALHOST_ONLY', QOS_FROM_XML, *PROFILE_VARS)}
    env |= {'PYTHONPATH': str(REPO), 'ROS_DOMAIN_ID': str(domain), 'ROS_AUTOMATIC_DISCOVERY_RANGE': 'LOCALHOST',
            'OMP_NUM_THREADS': '1', 'OPENBLAS_NUM_THREADS': '1', 'PYTHONUNBUFFERED': '1'}
    if profile is not None:
        env |= {var: str(profile) for var in PROFILE_VARS} | {QOS_FROM_XML: '1'}
    return env | extra


@contextmanager
def ros_domain(monkeypatch=None, profile: Path | None = FASTDDS_PROFILE) -> Iterator[int]:
    """A fresh domain for one test; with pytest's `monkeypatch`, this process's environment is set
    to `ros_env(domain, profile)` (for rclpy contexts and child processes made in the test)."""
    domain = acquire_domain()
    try:
        if monkeypatch is not None:
            for var in (*PROFILE_VARS, QOS_FROM_XML):
                monkeypatch.delenv(var, raising=False)
            for key, value in ros_env(domain, profile, base={}).items():
                if key != 'PYTHONPATH':
                    monkeypatch.setenv(key, value)
        yield domain
    finally:
        release_domain(domain)


@contextmanager
def node_in_process(monkeypatch, factory: Callable[[], Node], *ros_args: str) -> Iterator[Node]:
    """A node made by factory in this process (the global rclpy context, --ros-args ros_args) on a
    fresh domain, destroyed and the context shut down after the test."""
    from rclpy.signals import SignalHandlerOptions
    with ros_domain(monkeypatch):
        rclpy.init(args=['prog', '--ros-args', *ros_args], signal_handler_options=SignalHandlerOptions.NO)
        node = None
        try:
            node = factory()
            yield node
        finally:
            if node is not None:
                node.destroy_node()
            rclpy.try_shutdown()


def node_env(domain_id: int) -> dict[str, str]:
    """`ros_env` with the shared-memory profile (kept for callers that name it so)."""
    return ros_env(domain_id)


@contextmanager
def probe(domain_id: int, name: str) -> Iterator[tuple[Node, SingleThreadedExecutor]]:
    """An rclpy node with its own context and executor on domain_id."""
    os.environ['ROS_AUTOMATIC_DISCOVERY_RANGE'] = 'LOCALHOST'
    os.environ['FASTRTPS_DEFAULT_PROFILES_FILE'] = str(FASTDDS_PROFILE)  # read at context init
    os.environ[QOS_FROM_XML] = '1'
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


STARTED: list[subprocess.Popen] = []  # every node process a test started (conftest stops leftovers)


def start_node(module: str, domain_id: int, log: Path, *ros_args: str,
               env: Mapping[str, str] | None = None) -> subprocess.Popen:
    """`python -m mvpose_ros.nodes.<module> --ros-args ...` with stdout and stderr to log."""
    with open(log, 'w') as err:
        proc = subprocess.Popen([sys.executable, '-m', f'mvpose_ros.nodes.{module}', '--ros-args', *ros_args],
                                env=dict(env) if env is not None else node_env(domain_id), stdout=err,
                                stderr=subprocess.STDOUT, cwd=REPO)
    STARTED.append(proc)
    return proc


def spin_until(executor: SingleThreadedExecutor, done: Callable[[], bool], timeout: float = 20.0) -> bool:
    """Spin until done() (an event: a message, a match) or timeout s (a bound for failures only)."""
    deadline = time.monotonic() + timeout
    while not done() and time.monotonic() < deadline:
        executor.spin_once(timeout_sec=0.02)
    return done()


def matched(endpoints: Iterable) -> bool:
    """Every publisher has a matched reader and every subscription a matched writer (as each of
    them sees it: a reader that has matched a writer no longer drops what it sends)."""
    return all((e.get_subscription_count() if hasattr(e, 'get_subscription_count') else e.get_publisher_count()) > 0
               for e in endpoints)


class NodeLinks:
    """The links the nodes report on /diagnostics (core.health.links), as a probe reads them. A
    test's writer seeing a node's reader does not say that reader has matched the writer, and a
    volatile reader gets nothing sent before it has: wait for `reads` too."""

    def __init__(self, node: Node) -> None:
        self._values: dict[str, dict[str, str]] = {}  # node name -> its latest links values
        node.create_subscription(DiagnosticArray, DIAGNOSTICS, self._on_diagnostics, DIAGNOSTICS_QOS)

    def _on_diagnostics(self, msg: DiagnosticArray) -> None:
        for status in msg_to_statuses(msg):
            if status.name.endswith(f': {LINKS}'):
                self._values[status.name[:-len(LINKS) - 2]] = status.values

    def reads(self, node: str, topic: str) -> bool:
        """Whether `node` (as its statuses name it: 'bp_solver', 'cam1/heatmap_detector') reports its
        reader of `topic` (fully qualified) matched to a writer."""
        return int(self._values.get(node, {}).get(WRITERS + topic, '0')) > 0


def open_start_gate(node: Node, topic: str = 'bag_player/start'):
    """Let a bag_player started with `start_topic:=<topic>` play: a latched message it gets once
    its reader matches, whenever that is. Call it once this side's readers have matched the
    player's writers (`matched`). Returns the publisher (keep it until the player is done)."""
    gate = node.create_publisher(Empty, topic, START_QOS)
    gate.publish(Empty())
    return gate


def stop(proc: subprocess.Popen) -> None:
    """SIGINT, then SIGKILL after 5 s."""
    if proc.poll() is None:
        proc.send_signal(subprocess.signal.SIGINT)
        try:
            proc.wait(5)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait()
