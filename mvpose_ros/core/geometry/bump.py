"""A camera knocked out of its calibrated orientation (bumped): it turns about its own optical
centre while its calibration stays as it was, so what it sees moves in its image. Used to make a
recording of a bumped camera from a good one (mvpose-make-bag shelf --rotate-camera) and to check
that diagnostics notice it."""
from __future__ import annotations

import dataclasses

import numpy as np

from mvpose_ros.core.geometry.camera import Camera

AXES = {'x': 0, 'y': 1, 'z': 2}  # the camera's optical frame: x right, y down, z forward


def axis_rotation(axis: str, degrees: float) -> np.ndarray:
    """(3, 3) rotation by `degrees` about the camera's `axis` ('y': a pan, 'x': a tilt, 'z': a roll)."""
    if axis not in AXES:
        raise ValueError(f'axis {axis!r}: expected one of {", ".join(AXES)}')
    a = np.radians(degrees)
    i, j = [k for k in range(3) if k != AXES[axis]]
    r = np.eye(3)
    r[i, i] = r[j, j] = np.cos(a)
    r[i, j], r[j, i] = -np.sin(a), np.sin(a)
    if AXES[axis] == 1:  # keep the right-handed sense for the middle axis
        r = r.T
    return r


def bumped_camera(camera: Camera, rotation: np.ndarray) -> Camera:
    """The camera turned by `rotation` (3, 3, in its own frame) about its optical centre: same
    intrinsics and centre, world-to-camera rotation rotation @ R."""
    R = np.asarray(rotation) @ camera.R
    return dataclasses.replace(camera, R=R, t=-R @ camera.centre)


def bumped_pixels(camera: Camera, bumped: Camera, uv: np.ndarray) -> np.ndarray:
    """(..., 2) pixels where the bumped camera sees what `camera` saw at uv (..., 2): the same world
    ray, imaged with the same intrinsics and distortion after the turn."""
    return bumped.project(camera.centre + camera.directions(uv))
