"""CameraInfo for a calibrated camera (plumb_bob distortion, no rectification) and its check
against the rig a node loaded itself."""
from __future__ import annotations

import dataclasses

import numpy as np
from sensor_msgs.msg import CameraInfo
from std_msgs.msg import Header

from mvpose_ros.core.geometry.camera import Camera

DISTORTION_MODEL = 'plumb_bob'  # k1, k2, p1, p2, k3: OpenCV's order, as Camera.dist
PROBE_DEPTH_M = 1.0  # depth of the points the distortion check projects (any depth works)


def camera_to_info(camera: Camera, header: Header) -> CameraInfo:
    """K, D, size; R = I (monocular, not rectified) and P = [K | 0]."""
    return CameraInfo(header=header, width=camera.width, height=camera.height,
                      distortion_model=DISTORTION_MODEL, d=camera.dist.tolist(),
                      k=camera.K.flatten(), r=np.eye(3).ravel(),
                      p=np.column_stack([camera.K, np.zeros(3)]).ravel())


def info_key(msg: CameraInfo) -> tuple | None:
    """What info_to_intrinsics and check_info read of a CameraInfo, as a hashable value: a driver
    sends the same CameraInfo with every image, so a node checks it once per content. None when d
    holds more values than plumb_bob has (such a message is refused anyway, and is not copied)."""
    if len(msg.d) > 5:
        return None
    return msg.distortion_model, int(msg.width), int(msg.height), tuple(msg.k), tuple(msg.d)


def info_to_intrinsics(msg: CameraInfo) -> tuple[np.ndarray, np.ndarray, int, int]:
    """K (3, 3) pixels, dist (5,) plumb_bob k1, k2, p1, p2, k3, width, height (pixels) of a
    CameraInfo, as RigCamera.with_info takes them. An empty d is no distortion. ValueError of one
    line for another distortion model, a K that is not finite, upper-triangular with fx, fy > 0
    (an uncalibrated driver publishes zeros), or a size below 1x1."""
    if msg.distortion_model != DISTORTION_MODEL:
        raise ValueError(f'CameraInfo distortion_model: expected {DISTORTION_MODEL!r} (k1 k2 p1 p2 k3), '
                         f'got {msg.distortion_model!r}')
    if len(msg.d) not in (0, 5):  # before copying: a message can carry millions
        raise ValueError(f'CameraInfo d: expected 5 values (or none), got {len(msg.d)}')
    dist = np.array(msg.d, dtype=np.float64)
    if dist.size == 0:
        dist = np.zeros(5)
    if dist.shape != (5,) or not np.isfinite(dist).all():
        raise ValueError(f'CameraInfo d: expected 5 finite values, got {dist.tolist()}')
    K = np.array(msg.k, dtype=np.float64).reshape(3, 3)
    if not (np.isfinite(K).all() and K[0, 0] > 0 and K[1, 1] > 0
            and (K[1, 0], K[2, 0], K[2, 1], K[2, 2]) == (0, 0, 0, 1)):
        hint = ' (all zeros: the camera is not calibrated)' if not K.any() else ''
        raise ValueError(f'CameraInfo k: expected a finite upper-triangular K with fx, fy > 0 and '
                         f'K[2, 2] = 1, got {K.ravel().tolist()}{hint}')
    if msg.width < 1 or msg.height < 1:
        raise ValueError(f'CameraInfo size: expected width, height >= 1, got '
                         f'{msg.width}x{msg.height}')
    return K, dist, int(msg.width), int(msg.height)


def check_info(msg: CameraInfo, camera: Camera, tol_px: float = 0.5) -> None:
    """Raise ValueError naming the first item (size, fx, fy, cx, cy, skew, distortion) where msg
    disagrees with camera; intrinsics within tol_px pixels pass. Distortion is compared by
    where it moves the image's corners, edge midpoints and centre."""
    K, dist, width, height = info_to_intrinsics(msg)
    if (width, height) != (camera.width, camera.height):
        raise ValueError(f'CameraInfo size: {width}x{height}, camera {camera.name} is '
                         f'{camera.width}x{camera.height}')
    for name, (r, c) in (('fx', (0, 0)), ('fy', (1, 1)), ('cx', (0, 2)), ('cy', (1, 2)),
                         ('skew', (0, 1))):
        if not abs(K[r, c] - camera.K[r, c]) <= tol_px:
            raise ValueError(f'CameraInfo {name}: {K[r, c]}, camera {camera.name} has '
                             f'{camera.K[r, c]} (tolerance {tol_px} px)')
    probe = np.stack(np.meshgrid([0, width / 2, width], [0, height / 2, height]), axis=-1)
    origins, dirs = camera.rays(probe.reshape(-1, 2))
    X = origins + PROBE_DEPTH_M * dirs / (dirs @ camera.R[2])[:, None]
    moved = np.abs(dataclasses.replace(camera, dist=dist).project(X) - camera.project(X)).max()
    if not moved <= tol_px:
        raise ValueError(f'CameraInfo distortion: {dist.tolist()} moves image points by {moved:.3g}'
                         f' px from camera {camera.name} {camera.dist.tolist()} '
                         f'(tolerance {tol_px} px)')
