"""Fixtures shared by the suite (the Shelf rig and its OpenPose output, read once per session) and
its markers, for selections with -m (docs/development.md):

- ros: the test starts nodes or an rclpy context (the `domain` fixture, test/ros_harness.py, or
  marked so by hand where it runs a node's process another way);
- data: it needs the data root (../shared or MVPOSE_DATA_ROOT): every module not in NO_DATA;
- slow: a test that is not `ros` and takes seconds (marked by hand).

`-m "not ros and not slow"` is the fast subset; `-m "not data"` runs without the data root.
"""
from __future__ import annotations

from pathlib import Path
from typing import Iterator

import pytest

import ros_harness
from mvpose_ros.core.detection.openpose import OpenPoseFrame
from mvpose_ros.core.evaluation.offline import shelf_openpose_raw
from mvpose_ros.core.geometry.camera import Camera
from ros_harness import STARTED, acquire_domain, release_domain, stop

# Modules whose tests read nothing under the data root; a new module needs it until listed here.
NO_DATA = {
    'test_bp', 'test_cdr_header', 'test_clips', 'test_compiled', 'test_confidence', 'test_cpu',
    'test_crop_prediction', 'test_diagnostics_recorder', 'test_error_sources', 'test_factors', 'test_frame_id',
    'test_heatmap', 'test_identities', 'test_kernel_cache', 'test_letterbox', 'test_lint', 'test_memory',
    'test_msg_records', 'test_newest_queue', 'test_overlay', 'test_overlay_node', 'test_overlay_sets',
    'test_refusals', 'test_replay', 'test_run_nodes', 'test_runtime_imports', 'test_skeleton_echo', 'test_stamp_sync',
    'test_throttled_log', 'test_view_scene', 'test_workers',
}
MARKERS = {'ros': 'starts nodes or an rclpy context', 'data': 'needs the data root (../shared)',
           'slow': 'takes seconds without starting nodes'}


def pytest_configure(config: pytest.Config) -> None:
    for name, description in MARKERS.items():
        config.addinivalue_line('markers', f'{name}: {description}')


def pytest_ignore_collect(collection_path: Path, config: pytest.Config) -> bool | None:
    """With -m "not data", the modules that need the data root are not even imported (some read it
    at import), so that selection runs without one."""
    if 'not data' in (config.option.markexpr or '') and collection_path.suffix == '.py' \
            and collection_path.stem.startswith('test_') and collection_path.stem not in NO_DATA:
        return True
    return None


def pytest_collection_modifyitems(items: list[pytest.Item]) -> None:
    """ros and data, marked from what each test uses (see the module)."""
    for item in items:
        module = item.module
        harness = any(value is ros_harness or getattr(value, '__module__', None) == ros_harness.__name__
                      for value in vars(module).values())
        if 'domain' in item.fixturenames or harness:
            item.add_marker(pytest.mark.ros)
        if module.__name__.rpartition('.')[2] not in NO_DATA:
            item.add_marker(pytest.mark.data)


@pytest.fixture(scope='session')
def shelf_openpose() -> tuple[list[Camera], list[list[OpenPoseFrame]]]:
    """The five Shelf cameras and, per camera, the OpenPose output of every test frame (300..600)."""
    return shelf_openpose_raw(None)


@pytest.fixture(scope='session')
def shelf_rig(shelf_openpose) -> list[Camera]:
    """The five Shelf cameras at their image size."""
    return shelf_openpose[0]


@pytest.fixture
def domain() -> Iterator[int]:
    """A ROS_DOMAIN_ID of this test's own: no other test or concurrently running suite uses it."""
    held = acquire_domain()
    try:
        yield held
    finally:
        release_domain(held)


@pytest.fixture(autouse=True)
def no_node_outlives_its_test() -> Iterator[None]:
    """Stop any node process a test left running (a failed assertion before its own stop), so it
    cannot load the machine for the tests after it."""
    yield
    while STARTED:
        stop(STARTED.pop())
