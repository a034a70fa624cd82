"""What every mvpose_ros node shares: typed parameter declaration, the data QoS, the rig from
the `calibration` parameter, one-line start-up errors, and the rclpy main loop."""
from __future__ import annotations

import sys
from pathlib import Path
from typing import Any, Callable, Sequence

import rclpy
from rcl_interfaces.msg import ParameterDescriptor, ParameterType
from rclpy.exceptions import ParameterException
from rclpy.executors import ExternalShutdownException
from rclpy.node import Node
from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy

from mvpose_ros.core.geometry.camera import Camera, load_rig
from mvpose_ros.core.evaluation.datasets import IMAGE_SIZES, calibration_path, data_root

# Reliable and keep-all: a node that falls behind queues frames (and in the end slows its
# publishers down) rather than dropping them; no frame may be lost silently.
DATA_QOS = QoSProfile(history=HistoryPolicy.KEEP_ALL, reliability=ReliabilityPolicy.RELIABLE,
                      durability=DurabilityPolicy.VOLATILE)

# (name, default, description); string and array defaults carry their type explicitly
ParameterSpec = tuple[str, Any, str]

_TYPES = {str: ParameterType.PARAMETER_STRING, list: ParameterType.PARAMETER_STRING_ARRAY}


class StartupError(Exception):
    """A bad parameter or file: the node cannot start (one line, exit code 2)."""


def declare(node: Node, specs: Sequence[ParameterSpec]) -> dict[str, Any]:
    """Declare typed, described parameters; returns their values (from -p or --params-file)."""
    for name, default, description in specs:
        descriptor = ParameterDescriptor(description=description)
        if type(default) in _TYPES:
            descriptor.type = _TYPES[type(default)]
        try:
            node.declare_parameter(name, default, descriptor)
        except ParameterException as exc:
            raise StartupError(f'parameter {name}: {exc}') from None
    return {name: node.get_parameter(name).value for name, *_ in specs}


def rig_parameters() -> list[ParameterSpec]:
    """The parameters naming the rig: its calibration and image size (Shelf's by default)."""
    width, height = IMAGE_SIZES['shelf']
    return [
        ('data_root', '', "folder holding data/ and models/ ('' = $MVPOSE_DATA_ROOT or ../shared)"),
        ('calibration', str(calibration_path('shelf')),
         'calibration json (Shelf layout); relative paths are under data_root'),
        ('image_width', width, "the calibrated cameras' image width, pixels"),
        ('image_height', height, "the calibrated cameras' image height, pixels"),
    ]


def load_rig_parameter(values: dict[str, Any]) -> list[Camera]:
    """The rig named by the `calibration`, `image_width`, `image_height` and `data_root` values."""
    path = Path(values['calibration'])
    try:
        if not path.is_absolute():
            path = data_root(values['data_root'] or None) / path
        return load_rig(path, values['image_width'], values['image_height'])
    except (OSError, ValueError, KeyError) as exc:
        raise StartupError(f'parameter calibration: {" ".join(str(exc).split())}') from None


def params_files(args: Sequence[str]) -> list[str]:
    """The files given with --params-file in a node's command line."""
    return [args[i + 1] for i, a in enumerate(args[:-1]) if a == '--params-file']


def run(factory: Callable[[], Node], args: list[str] | None = None) -> None:
    """rclpy main: spin the node until Ctrl-C or shutdown, or, for a node with a `finished`
    future, until it completes (its result is the exit code). A bad parameter, parameter file or
    data file (StartupError, or a parameter file rcl cannot parse) exits with code 2 after one
    fatal log line naming the parameter files, not a traceback."""
    files = params_files(sys.argv if args is None else args)
    where = f'{", ".join(files)}: ' if files else ''
    try:
        rclpy.init(args=args)
    except RuntimeError as exc:  # rcl's RCLError: e.g. a parameter file that is not valid YAML
        rclpy.logging.get_logger('mvpose_ros').fatal(f'{where}{" ".join(str(exc).split())}')
        raise SystemExit(2) from None
    node = None
    code = 0
    try:
        node = factory()
        finished = getattr(node, 'finished', None)
        if finished is None:
            rclpy.spin(node)
        else:
            rclpy.spin_until_future_complete(node, finished)
            code = finished.result() or 0
    except StartupError as exc:
        rclpy.logging.get_logger('mvpose_ros').fatal(f'{where}{exc}')
        code = 2
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    finally:
        if node is not None:
            node.destroy_node()
        rclpy.try_shutdown()
    if code:
        raise SystemExit(code)
