"""Fixtures shared by the suite: the Shelf rig and its OpenPose output, read once per session."""
from __future__ import annotations

from typing import Iterator

import pytest

from mvpose_ros.core.detection.openpose import OpenPoseFrame
from mvpose_ros.core.evaluation.offline import shelf_openpose_raw
from mvpose_ros.core.geometry.camera import Camera
from ros_harness import STARTED, acquire_domain, release_domain, stop


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
