"""What every mvpose_ros node shares: typed parameter declaration (ranges, read-only unless a
change applies live), the live-parameter callbacks, the data QoS and the camera QoS, the rig from
the `rig` parameter, one-line start-up errors, and the rclpy main loop."""
from __future__ import annotations

import ctypes
import signal
import sys
import threading
from functools import partial
from pathlib import Path
from typing import Any, Callable, Sequence

import rclpy
from rcl_interfaces.msg import FloatingPointRange, IntegerRange, ParameterDescriptor, ParameterType, SetParametersResult
from rclpy.exceptions import ParameterException
from rclpy.executors import Executor, ExternalShutdownException, SingleThreadedExecutor
from rclpy.experimental import EventsExecutor
from rclpy.signals import SignalHandlerOptions
from rclpy.node import Node
from rclpy.parameter import Parameter
from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy, qos_profile_sensor_data
from rclpy.qos_overriding_options import InvalidQosOverridesError, QoSOverridingOptions
from rclpy.subscription import Subscription
from sensor_msgs.msg import CameraInfo

from msg_adapters.camera_info_msg import info_camera
from mvpose_ros.core.defaults import data_root
from mvpose_ros.core.geometry.camera import Camera
from mvpose_ros.core.geometry.rig import Rig, load_rig_file
from mvpose_ros.core.parameters import Param
from mvpose_ros.package_files import package_path

# Reliable and keep-all between the graph's own nodes: a node that falls behind queues frames (and
# in the end slows its publishers down) rather than dropping them; no frame may be lost silently.
DATA_QOS = QoSProfile(history=HistoryPolicy.KEEP_ALL, reliability=ReliabilityPolicy.RELIABLE,
                      durability=DurabilityPolicy.VOLATILE)

# The detector's recorded input (OpenPose output), reliable as recorded data but keep-last: the
# graph's outside edge, where a foreign flood lands. Keep-all held up to Fast DDS's 5000 samples
# there, gigabytes under a junk flood. 25 is 1 s at 25 Hz.
RECORDED_INPUT_DEPTH = 25
RECORDED_INPUT_QOS = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=RECORDED_INPUT_DEPTH,
                                reliability=ReliabilityPolicy.RELIABLE, durability=DurabilityPolicy.VOLATILE)

# Camera inputs (images, CameraInfo) as a camera driver's subscribers take them: best effort, so
# that both best-effort (sensor data) and reliable publishers connect, and keep-last of a small
# depth, so that a node slower than its cameras drops old frames in the middleware rather than
# queueing them (see camera_subscription: the parameter file can override it).
CAMERA_QUEUE_DEPTH = 2

# A viewer's inputs (the overlay node, the runner's overlay files): best effort, so that it connects
# to reliable publishers too and never holds them up, a few messages deep.
VIEWER_QOS = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=10, reliability=ReliabilityPolicy.BEST_EFFORT,
                        durability=DurabilityPolicy.VOLATILE)
# Published once and kept for late subscribers (RViz opened after the solver): the camera frusta.
LATCHED_QOS = QoSProfile(depth=1, reliability=ReliabilityPolicy.RELIABLE, durability=DurabilityPolicy.TRANSIENT_LOCAL)
SPIN_ONCE_S = 0.2  # s an idle node waits per executor turn: how long a stop signal can take to act


def camera_qos(depth: int = CAMERA_QUEUE_DEPTH) -> QoSProfile:
    """A fresh camera-input profile (rclpy's QoS overriding writes into the profile it is given)."""
    return QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=depth, reliability=ReliabilityPolicy.BEST_EFFORT,
                      durability=DurabilityPolicy.VOLATILE)


def camera_subscription(node: Node, msg_type: type, topic: str, callback: Callable[[Any], None],
                        depth: int = CAMERA_QUEUE_DEPTH, raw: bool = False) -> Subscription:
    """A camera-input subscription (camera_qos(depth); raw: the callback takes the serialised
    bytes) whose history, depth and reliability the parameter file can override, as rclpy's QoS
    overriding options read them: parameters
    `qos_overrides.<resolved topic>.subscription.{history,depth,reliability}`, e.g.::

        /**/heatmap_detector:
          ros__parameters:
            qos_overrides:
              /cam0/image_raw:
                subscription: {reliability: reliable, depth: 5}

    A bad override is a StartupError."""
    try:
        return node.create_subscription(msg_type, topic, callback, camera_qos(depth), raw=raw,
                                        qos_overriding_options=QoSOverridingOptions.with_default_policies())
    except (InvalidQosOverridesError, RuntimeError, ParameterException, ValueError) as exc:
        raise StartupError(f'QoS of {node.resolve_topic_name(topic)}: {" ".join(str(exc).split())}') from None


DEFAULT_RIG = 'config/rigs/shelf.yaml'

_TYPES = {str: ParameterType.PARAMETER_STRING, list: ParameterType.PARAMETER_STRING_ARRAY}
_INT64 = 2 ** 63 - 1
RESTART = 'read-only: a change needs a restart'


class StartupError(Exception):
    """A bad parameter or file: the node cannot start (one line, exit code 2)."""


def descriptor(spec: Param) -> ParameterDescriptor:
    """The ParameterDescriptor of `spec`: typed, described, its range, read-only unless live."""
    d = ParameterDescriptor(description=spec.description, read_only=not spec.live,
                            additional_constraints='' if spec.live else RESTART)
    if isinstance(spec.default, Parameter.Type):  # declared by type (an empty list cannot type itself)
        d.type = spec.default.value
    elif type(spec.default) in _TYPES:
        d.type = _TYPES[type(spec.default)]
    elif isinstance(spec.default, int) and not isinstance(spec.default, bool):
        d.integer_range = [IntegerRange(from_value=-_INT64 if spec.low is None else int(spec.low),
                                        to_value=_INT64 if spec.high is None else int(spec.high), step=1)]
    elif isinstance(spec.default, float):
        d.floating_point_range = [FloatingPointRange(from_value=-float('inf') if spec.low is None else float(spec.low),
                                                     to_value=float('inf') if spec.high is None else float(spec.high),
                                                     step=0.0)]
    return d


def declare(node: Node, specs: Sequence[Param]) -> dict[str, Any]:
    """Declare typed, described, ranged parameters; returns their values (from -p or --params-file).
    A value out of its range is a StartupError naming it."""
    values = {}
    for spec in specs:
        try:
            values[spec.name] = node.declare_parameter(spec.name, spec.default, descriptor(spec)).value
        except ParameterException as exc:
            raise StartupError(f'parameter {spec.name}: {" ".join(str(exc).split())}') from None
    return values


def live_parameters(node: Node, names: Sequence[str], check: Callable[[dict[str, Any]], str | None],
                    apply: Callable[[dict[str, Any]], None]) -> None:
    """Let the parameters `names` (declared live) change while the node runs: a set request naming
    any of them is refused with check(changes)'s reason when it returns one, else applied with
    apply(changes) once rclpy has stored the values. changes: name -> new value, of `names` only.
    (Read-only parameters are refused by rclpy itself: 'Trying to set a read-only parameter'.)"""
    wanted = set(names)

    def changes_of(parameters: list[Parameter]) -> dict[str, Any]:
        return {p.name: p.value for p in parameters if p.name in wanted}

    def on_set(parameters: list[Parameter]) -> SetParametersResult:
        changes = changes_of(parameters)
        reason = check(changes) if changes else None
        return SetParametersResult(successful=reason is None, reason=reason or '')

    def on_applied(parameters: list[Parameter]) -> None:
        changes = changes_of(parameters)
        if changes:
            apply(changes)
            node.get_logger().info('parameters changed: ' + ', '.join(f'{k} = {v}' for k, v in changes.items()))

    node.add_on_set_parameters_callback(on_set)
    node.add_post_set_parameters_callback(on_applied)


def rig_parameters() -> list[Param]:
    """The parameters naming the rig: a rig file (see core.geometry.rig) and the data root."""
    return [
        Param('data_root', '', "folder holding data/ and models/ ('' = $MVPOSE_DATA_ROOT or ../shared)"),
        Param('rig', DEFAULT_RIG, 'rig file (YAML; or a calibration json, see core.geometry.rig); a relative path '
                                  "is looked up from the working directory, then among the package's files"),
    ]


def load_rig_parameter(values: dict[str, Any]) -> Rig:
    """The rig named by the `rig` and `data_root` parameter values."""
    path = Path(values['rig'])
    try:
        if not path.is_absolute() and not path.is_file():
            path = package_path(path)
        return load_rig_file(path, data_root=partial(data_root, values['data_root'] or None))
    except (OSError, ValueError, KeyError) as exc:
        raise StartupError(f'parameter rig: {" ".join(str(exc).split())}') from None


def rig_cameras(values: dict[str, Any]) -> list[Camera]:
    """The calibrated cameras of the rig parameter (every camera's intrinsics in the rig file)."""
    try:
        return load_rig_parameter(values).calibrated_cameras()
    except ValueError as exc:
        raise StartupError(f'parameter rig: {" ".join(str(exc).split())}') from None


class RigIntrinsics:
    """The rig's Cameras, completing the intrinsics the rig file leaves out from each camera's
    CameraInfo (its own topic from the rig file; sensor-data QoS, which reliable publishers reach
    too). `cameras` is None until every camera is known; a CameraInfo that cannot be used is
    logged once per camera and cause. A camera's subscription ends with its first usable
    CameraInfo: a driver sends one with every image, and each would wake the node for nothing."""

    def __init__(self, node: Node, rig: Rig) -> None:
        self._node = node
        self._rig = rig
        self._cameras: list[Camera | None] = [c.camera for c in rig.cameras]
        self._problems: set[tuple[str, str]] = set()
        self._subscriptions: dict[int, Subscription] = {}
        for index, rig_camera in enumerate(rig.cameras):
            if rig_camera.camera is None:
                self._subscriptions[index] = node.create_subscription(
                    CameraInfo, rig_camera.camera_info, partial(self._on_info, index), qos_profile_sensor_data)

    @property
    def cameras(self) -> list[Camera] | None:
        """Every camera in rig order once all intrinsics are known, else None."""
        return None if any(c is None for c in self._cameras) else list(self._cameras)

    @property
    def known(self) -> list[Camera | None]:
        """Every camera in rig order, None where its intrinsics are not known yet."""
        return list(self._cameras)

    @property
    def missing(self) -> list[str]:
        """Names of the cameras whose intrinsics are still unknown."""
        return [rc.name for rc, c in zip(self._rig.cameras, self._cameras) if c is None]

    def _on_info(self, index: int, msg: CameraInfo) -> None:
        if self._cameras[index] is not None:
            return
        rig_camera = self._rig.cameras[index]
        try:
            self._cameras[index] = info_camera(rig_camera, msg)
        except ValueError as exc:
            problem = " ".join(str(exc).split())
            if (rig_camera.name, problem) not in self._problems:
                self._problems.add((rig_camera.name, problem))
                self._node.get_logger().error(f'{rig_camera.name}: CameraInfo unusable: {problem}')
            return
        topic = self._node.resolve_topic_name(rig_camera.camera_info)
        self._node.get_logger().info(f'{rig_camera.name}: intrinsics from {topic}')
        self._node.destroy_subscription(self._subscriptions.pop(index))


def params_files(args: Sequence[str]) -> list[str]:
    """The files given with --params-file in a node's command line."""
    return [args[i + 1] for i, a in enumerate(args[:-1]) if a == '--params-file']


def run(factory: Callable[[], Node], args: list[str] | None = None, events: bool = True) -> None:
    """rclpy main of one node: run_nodes with its factory."""
    run_nodes([factory], args, events)


def release_free_heap() -> None:
    """Give the C heap's free pages back to the system (glibc's malloc_trim; nothing elsewhere).

    A node's start leaves freed memory in the heap that glibc keeps mapped: the player reading a
    bag into memory passes through the decompressed chunks, and that high-water mark would stay in
    the process's resident size for the whole run."""
    try:
        ctypes.CDLL(None).malloc_trim(0)
    except (OSError, AttributeError):
        pass


def _spin(executor: Executor, running: Callable[[], bool], done: threading.Event,
          failed: list[BaseException]) -> None:
    """Spin executor while running() and until done is set; sets done on the way out, so that the
    process's other executors stop too, and keeps what ended it in failed."""
    try:
        while not done.is_set() and running():
            executor.spin_once(timeout_sec=SPIN_ONCE_S)
    except BaseException as exc:  # raised again in the main thread, once the others stopped
        failed.append(exc)
    finally:
        done.set()


def run_nodes(factories: Sequence[Callable[[], Node]], args: list[str] | None = None,
              events: bool | Sequence[bool] = True) -> None:
    """rclpy main: spin the nodes until SIGINT (Ctrl-C) or SIGTERM, or, for a node with a
    `finished` future, until it completes (its result is the exit code). A bad parameter,
    parameter file or data file (StartupError, or a parameter file rcl cannot parse) exits with
    code 2 after one fatal log line naming the parameter files, not a traceback.

    The executor is rclpy's C++ events executor: about half the CPU per message of the default
    one, which a flooded node, or a graph near its CPU limit, needs (docs/benchmarks.md). In
    these rclpy wheels its spin() runs no callback and rclpy's signal handlers do not stop its
    spin_once, so the loop is spin_once, ended by a flag the signals set. It cannot run a callback
    that takes message info (SystemError in these wheels): a node that needs the DDS receipt time
    has events False (one flag for all, or one per factory) and gets rclpy's single-threaded
    executor. Where a process holds both kinds, that one spins in a thread of its own, so the
    compiled kernels of its node, which run without the GIL, go on beside the others' callbacks."""
    files = params_files(sys.argv if args is None else args)
    where = f'{", ".join(files)}: ' if files else ''
    stop = threading.Event()
    try:
        rclpy.init(args=args, signal_handler_options=SignalHandlerOptions.NO)
    except RuntimeError as exc:  # rcl's RCLError: e.g. a parameter file that is not valid YAML
        rclpy.logging.get_logger('mvpose_ros').fatal(f'{where}{" ".join(str(exc).split())}')
        raise SystemExit(2) from None
    for signum in (signal.SIGINT, signal.SIGTERM):
        signal.signal(signum, lambda *_: stop.set())
    nodes: list[Node] = []
    code = 0
    kinds = [events] * len(factories) if isinstance(events, bool) else list(events)
    failed: list[BaseException] = []
    try:
        executors = {kind: EventsExecutor() if kind else SingleThreadedExecutor() for kind in dict.fromkeys(kinds)}
        for factory, kind in zip(factories, kinds):
            nodes.append(factory())
            executors[kind].add_node(nodes[-1])
        release_free_heap()
        finished = [f for node in nodes if (f := getattr(node, 'finished', None)) is not None]

        def running() -> bool:
            return not stop.is_set() and rclpy.ok() and not any(f.done() for f in finished)
        done = threading.Event()
        first, *others = executors.values()
        threads = [threading.Thread(target=_spin, args=(e, running, done, failed), daemon=True) for e in others]
        for thread in threads:
            thread.start()
        _spin(first, running, done, failed)
        for thread in threads:
            thread.join()
        if failed:
            raise failed[0]
        code = next((f.result() or 0 for f in finished if f.done()), 0)
    except StartupError as exc:
        rclpy.logging.get_logger('mvpose_ros').fatal(f'{where}{exc}')
        code = 2
    except ExternalShutdownException:
        pass
    finally:
        for node in nodes:
            node.destroy_node()
        rclpy.try_shutdown()
    if code:
        raise SystemExit(code)
