"""Compiled projection of world points and pixel rays for many cameras at once: the hot loops of
the 3D stage and the association (Camera.project and Camera.directions are the same arithmetic
for one camera, in numpy). Kernels take a rig's cameras as rig_model rows: R, t, K row-major,
then the lens as lens.kernel_form gives it."""
from __future__ import annotations

from typing import Sequence

import numpy as np

from mvpose_ros.core.compiled import inline_kernel, kernel, kernel_array
from mvpose_ros.core.geometry.camera import Camera
from mvpose_ros.core.geometry.lens import FISHEYE, KERNEL_SIZE, KERNEL_SLOTS, NONE, RADIAL_TANGENTIAL


def rig_model(cameras: Sequence[Camera | None]) -> np.ndarray:
    """(C, MODEL_SIZE) every camera's projection as the kernels take it (project_point): R, t, K
    row-major, then its lens (lens.kernel_form); a camera not known yet (None) projects every point
    to NaN."""
    if not len(cameras):
        return np.zeros((0, MODEL_SIZE))
    return np.stack([cam._model if cam is not None else _UNKNOWN_MODEL for cam in cameras])


def rig_project(cameras: Sequence[Camera], which: np.ndarray, points: np.ndarray,
                of: np.ndarray | None = None) -> np.ndarray:
    """(N, K, 2) pixels of points (P, K, 3) in metres: row n is points[of[n]] (of (N,); by
    default row n) seen by cameras[which[n]] (N,); NaN at or behind the camera. Camera.project
    for rows of points in many cameras at once."""
    points = kernel_array(points, np.float64)
    which = kernel_array(which, np.int64)
    of = np.arange(len(which)) if of is None else kernel_array(of, np.int64)
    uv = np.empty((len(which), points.shape[1], 2))
    _project(rig_model(cameras), which, of, points, uv)
    return uv


_LENS = 21  # where a rig_model row's lens starts (after R, t and K)
MODEL_SIZE = _LENS + KERNEL_SIZE
_KIND = MODEL_SIZE - 1
_UNKNOWN_MODEL = np.zeros(MODEL_SIZE)  # depth 0 for every point: NaN pixels


@inline_kernel
def distort_point(lens, x, y):
    """Distorted normalised coordinates of the normalised point (x, y) through a lens of
    kernel_form (KERNEL_SIZE,); the arithmetic of distort, in the same order."""
    kind = lens[KERNEL_SLOTS]
    if kind == RADIAL_TANGENTIAL:
        k1, k2, p1, p2, k3, k4, k5, k6 = lens[0], lens[1], lens[2], lens[3], lens[4], lens[5], lens[6], lens[7]
        r2 = x * x + y * y
        radial = (1 + r2 * (k1 + r2 * (k2 + r2 * k3))) / (1 + r2 * (k4 + r2 * (k5 + r2 * k6)))
        return (x * radial + 2 * p1 * x * y + p2 * (r2 + 2 * x * x),
                y * radial + p1 * (r2 + 2 * y * y) + 2 * p2 * x * y)
    if kind == FISHEYE:
        r = np.sqrt(x * x + y * y)
        if r == 0:
            return x, y
        theta = np.arctan(r)
        t2 = theta * theta
        scale = theta * (1 + t2 * (lens[0] + t2 * (lens[1] + t2 * (lens[2] + t2 * lens[3])))) / r
        return x * scale, y * scale
    return x, y


@inline_kernel
def project_point(model, c, x, y, z):
    """Pixel (u, v) of the world point (x, y, z) m in camera c of a rig_model (C, MODEL_SIZE); NaN at
    or behind the camera. For other kernels; the arithmetic of numpy on whole arrays, in the same order."""
    depth = model[c, 6] * x + model[c, 7] * y + model[c, 8] * z + model[c, 11]
    inv = 1.0 / depth if depth > 0 else np.nan
    xn = (model[c, 0] * x + model[c, 1] * y + model[c, 2] * z + model[c, 9]) * inv
    yn = (model[c, 3] * x + model[c, 4] * y + model[c, 5] * z + model[c, 10]) * inv
    if model[c, _KIND] != NONE:
        xn, yn = distort_point(model[c, _LENS:], xn, yn)
    return (model[c, 12] * xn + model[c, 13] * yn + model[c, 14],
            model[c, 15] * xn + model[c, 16] * yn + model[c, 17])


@kernel('void(float64[:, ::1], int64[::1], int64[::1], float64[:, :, ::1], float64[:, :, ::1])')
def _project(model, which, of, points, out):
    for n in range(len(which)):
        X = points[of[n]]
        for i in range(X.shape[0]):
            out[n, i, 0], out[n, i, 1] = project_point(model, which[n], X[i, 0], X[i, 1], X[i, 2])


def rig_directions(cameras: Sequence[Camera], which: np.ndarray, uv: np.ndarray) -> np.ndarray:
    """(N, 3) unit world directions of the rays of pixels uv (N, 2), pixel n seen by
    cameras[which[n]] (N,): Camera.directions for pixels of many cameras at once. A camera with
    distortion undistorts its own pixels."""
    uv = kernel_array(uv, np.float64)
    which = kernel_array(which, np.int64)
    d = np.empty((len(uv), 3))
    _directions(np.stack([cam._pixel_to_ray for cam in cameras]) if len(cameras) else np.zeros((0, 3, 3)),
                which, uv, d)
    for i, cam in enumerate(cameras):
        if cam.has_distortion:
            mine = which == i
            d[mine] = cam.directions(uv[mine])
    return d


@kernel('void(float64[:, :, ::1], int64[::1], float64[:, ::1], float64[:, ::1])')
def _directions(to_ray, which, uv, out):
    # pixel (u, v, 1) through its camera's matrix (as for a lens without distortion), normalised
    for n in range(len(which)):
        T = to_ray[which[n]]
        u, v = uv[n, 0], uv[n, 1]
        dx = T[0, 0] * u + T[0, 1] * v + T[0, 2]
        dy = T[1, 0] * u + T[1, 1] * v + T[1, 2]
        dz = T[2, 0] * u + T[2, 1] * v + T[2, 2]
        norm = np.sqrt((dx * dx + dz * dz) + dy * dy)  # the order of numpy's einsum, for the same bits
        out[n, 0] = dx / norm
        out[n, 1] = dy / norm
        out[n, 2] = dz / norm
