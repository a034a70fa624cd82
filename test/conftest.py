"""Fixtures shared by the suite: the Shelf rig and its OpenPose output, read once per session."""
from __future__ import annotations

from typing import Iterator

import pytest

from mvpose_ros.core.detection.openpose import OpenPoseFrame
from mvpose_ros.core.evaluation.offline import shelf_openpose_raw
from mvpose_ros.core.geometry.camera import Camera
from ros_harness import acquire_domain, release_domain


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
