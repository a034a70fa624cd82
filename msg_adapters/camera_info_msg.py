"""CameraInfo for a calibrated camera (its lens model: plumb_bob, rational_polynomial or
equidistant), the intrinsics of the images that come with one (raw or rectified, a stereo pair's
too, binned, a region of interest), and its check against the rig a node loaded itself."""
from __future__ import annotations

import dataclasses

import numpy as np
from sensor_msgs.msg import CameraInfo
from std_msgs.msg import Header

from mvpose_ros.core.geometry import lens
from mvpose_ros.core.geometry.camera import Camera
from mvpose_ros.core.geometry.rig import RigCamera

PROBE_DEPTH_M = 1.0  # depth of the points the distortion check projects (any depth works)


def camera_to_info(camera: Camera, header: Header) -> CameraInfo:
    """K, D, size; R = I (monocular, not rectified) and P = [K | 0]."""
    return CameraInfo(header=header, width=camera.width, height=camera.height,
                      distortion_model=camera.distortion_model, d=camera.dist.tolist(),
                      k=camera.K.flatten(), r=np.eye(3).ravel(),
                      p=np.column_stack([camera.K, np.zeros(3)]).ravel())


def info_to_intrinsics(msg: CameraInfo, rectified: bool = False) -> tuple[np.ndarray, np.ndarray, int, int, str]:
    """K (3, 3) pixels, dist (the model's coefficients), width, height (pixels) and distortion
    model of the images that come with a CameraInfo, as RigCamera.with_info takes them. An empty d
    is no distortion. For `rectified` images (image_proc's image_rect, which goes with the raw
    camera's CameraInfo) K is P's left 3 x 3 and there is no distortion: d and its model are not
    read. A driver that bins or cuts a region of interest (binning_x/y, roi) sends the calibration
    of the whole sensor with them: K and the size are those of the image it sends, as image_geometry
    computes them (cx' = (cx - x_offset) / binning_x, ...). A stereo pair's rectified frame is
    also turned from the camera's: see info_camera, which applies CameraInfo's R. ValueError of one
    line for a model core.geometry.lens does not have, a d of another length than the model's, a K
    (or P) that is not finite, upper-triangular with fx, fy > 0 (an uncalibrated driver publishes
    zeros), a size below 1x1, or a region of interest outside the sensor."""
    K, dist, model = _rectified(msg) if rectified else _raw(msg)
    if msg.width < 1 or msg.height < 1:
        raise ValueError(f'CameraInfo size: expected width, height >= 1, got '
                         f'{msg.width}x{msg.height}')
    width, height = int(msg.width), int(msg.height)
    roi = msg.roi
    if roi.width and roi.height:  # else the whole sensor (a zero roi means that)
        if roi.x_offset + roi.width > width or roi.y_offset + roi.height > height:
            raise ValueError(f'CameraInfo roi: {roi.width}x{roi.height} at ({roi.x_offset}, {roi.y_offset}) '
                             f'reaches outside the {width}x{height} sensor')
        K[0, 2] -= roi.x_offset
        K[1, 2] -= roi.y_offset
        width, height = int(roi.width), int(roi.height)
    binning = (max(1, int(msg.binning_x)), max(1, int(msg.binning_y)))  # 0 and 1 are none
    K[:2] /= np.array(binning, dtype=np.float64)[:, None]
    width, height = width // binning[0], height // binning[1]
    if width < 1 or height < 1:
        raise ValueError(f'CameraInfo binning: {binning[0]}x{binning[1]} leaves no pixel of the '
                         f'{msg.width}x{msg.height} sensor')
    return K, dist, width, height, model


def _raw(msg: CameraInfo) -> tuple[np.ndarray, np.ndarray, str]:
    """K, dist, model of the raw image: CameraInfo's k, d and distortion_model."""
    model = msg.distortion_model
    if model not in lens.MODELS:
        raise ValueError(f'CameraInfo {lens.unsupported(model)}')
    n = len(lens.MODELS[model])
    lengths = (0, n, lens.OPENCV_FULL) if model == lens.RATIONAL_POLYNOMIAL else (0, n)
    if len(msg.d) not in lengths:  # before copying: a message can carry millions
        raise ValueError(f'CameraInfo d: expected {" or ".join(map(str, lengths[1:]))} values for '
                         f'{lens.describe(model)} (or none), got {len(msg.d)}')
    dist = np.array(msg.d, dtype=np.float64)
    if not np.isfinite(dist).all():
        raise ValueError(f'CameraInfo d: expected finite values, got {dist.tolist()}')
    return _intrinsic_matrix('k', msg.k), lens.coefficients(model, dist, 'CameraInfo d'), model


def _rectified(msg: CameraInfo) -> tuple[np.ndarray, np.ndarray, str]:
    """K, dist, model of a rectified image: P's left 3 x 3, none, plumb_bob. P's last column (a
    stereo pair's baseline, Tx = -fx' B) places the second camera in the first one's frame; each
    camera's own pose comes from the rig, so it is not used, but a P that does not project
    (P[2, 3] != 0) is refused."""
    P = np.array(msg.p, dtype=np.float64).reshape(3, 4)
    K = _intrinsic_matrix('p', P[:, :3])
    if not (np.isfinite(P[:, 3]).all() and P[2, 3] == 0):
        raise ValueError(f'CameraInfo p: expected a last column [Tx, Ty, 0] (a stereo baseline, or zeros), '
                         f'got {P[:, 3].tolist()}')
    return K, np.zeros(len(lens.MODELS[lens.DEFAULT_MODEL])), lens.DEFAULT_MODEL


def rectification(msg: CameraInfo) -> np.ndarray:
    """(3, 3) CameraInfo's R, the rotation from the camera's optical frame to its rectified image's
    (x_rect = R @ x_camera): a stereo pair's rectified frames are turned so that their rows are
    epipolar lines; all zeros (not given) is the identity. ValueError of one line when it is not a
    rotation."""
    R = np.array(msg.r, dtype=np.float64).reshape(3, 3)
    if not R.any():
        return np.eye(3)
    if not (np.isfinite(R).all() and np.allclose(R @ R.T, np.eye(3), rtol=0, atol=1e-6)
            and np.linalg.det(R) > 0):
        raise ValueError(f'CameraInfo r: {R.ravel().tolist()} is not a rotation')
    return R


def info_camera(rig_camera: RigCamera, msg: CameraInfo) -> Camera:
    """rig_camera's Camera with the intrinsics of the images that come with msg (info_to_intrinsics);
    of rectified images (rig_camera.rectified) turned by msg's R (rectification), so that a stereo
    pair's rectified images, at their cameras' poses in the rig, are each where they are. ValueError
    of one line naming the camera or CameraInfo's field."""
    turn = rectification(msg) if rig_camera.rectified else None
    return rig_camera.with_info(*info_to_intrinsics(msg, rig_camera.rectified), rectification=turn)


def _intrinsic_matrix(field: str, values: np.ndarray) -> np.ndarray:
    """(3, 3) of CameraInfo's `field` (k, or P's left 3 x 3), checked: finite, upper triangular,
    fx, fy > 0, 1 at [2, 2]."""
    K = np.array(values, dtype=np.float64).reshape(3, 3)
    if not (np.isfinite(K).all() and K[0, 0] > 0 and K[1, 1] > 0
            and (K[1, 0], K[2, 0], K[2, 1], K[2, 2]) == (0, 0, 0, 1)):
        hint = ' (all zeros: the camera is not calibrated)' if not K.any() else ''
        raise ValueError(f'CameraInfo {field}: expected a finite upper-triangular {field.upper()} with fx, fy > 0 '
                         f'and {field.upper()}[2, 2] = 1, got {K.ravel().tolist()}{hint}')
    return K


def check_info(msg: CameraInfo, camera: Camera, tol_px: float = 0.5, rectified: bool = False,
               raw_R: np.ndarray | None = None) -> None:
    """Raise ValueError naming the first item (size, fx, fy, cx, cy, skew, distortion, r) where msg
    disagrees with camera (of `rectified` images: info_to_intrinsics); intrinsics within tol_px
    pixels pass. Distortion is compared by where it moves the image's corners, edge midpoints and
    centre. Of rectified images, given raw_R (3, 3: the rig camera's own world -> optical rotation),
    also R: how far the rectified frame it gives is turned from camera's (camera.R @ raw_R.T), in
    pixels at the larger focal length."""
    K, dist, width, height, model = info_to_intrinsics(msg, rectified)
    if rectified and raw_R is not None:
        turn = rectification(msg) @ (camera.R @ np.asarray(raw_R, dtype=np.float64).T).T
        angle = float(np.arccos(np.clip((np.trace(turn) - 1.0) / 2.0, -1.0, 1.0)))
        moved = angle * max(K[0, 0], K[1, 1])
        if not moved <= tol_px:
            raise ValueError(f'CameraInfo r: turns the rectified frame {np.degrees(angle):.3g} degrees from the R in '
                             f'use ({moved:.3g} px at its focal length; tolerance {tol_px} px)')
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
    theirs = dataclasses.replace(camera, dist=dist, distortion_model=model)
    moved = np.abs(theirs.project(X) - camera.project(X)).max()
    if not moved <= tol_px:
        raise ValueError(f'CameraInfo distortion: {model} {dist.tolist()} moves image points by {moved:.3g}'
                         f' px from camera {camera.name} {camera.distortion_model} {camera.dist.tolist()} '
                         f'(tolerance {tol_px} px)')
