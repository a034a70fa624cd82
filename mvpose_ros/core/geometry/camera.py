"""Calibrated pinhole cameras with OpenCV lens distortion, rig loading, and ray geometry.

Convention: a world point X (metres) maps to camera coordinates x_cam = R @ X + t, then to
normalised coordinates (x/z, y/z), through the radial-tangential distortion (OpenCV order k1, k2,
p1, p2, k3), and to pixels through K.
"""
from __future__ import annotations

import dataclasses
import json
import re
from pathlib import Path
from typing import Sequence

import numpy as np
import scipy.linalg


# Newton steps for undistortion; quadratic convergence makes this exact to float precision for
# any lens whose distortion map is monotone over the image.
_UNDISTORT_ITERATIONS = 10


@dataclasses.dataclass(frozen=True, eq=False)
class Camera:
    """One calibrated camera.

    K: (3, 3) intrinsics; R: (3, 3) world-to-camera rotation; t: (3,) metres;
    dist: (5,) k1, k2, p1, p2, k3 (zeros = no distortion); width, height: image size in pixels.
    """

    name: str
    K: np.ndarray
    R: np.ndarray
    t: np.ndarray
    dist: np.ndarray
    width: int
    height: int

    def __post_init__(self) -> None:
        for field, shape in (('K', (3, 3)), ('R', (3, 3)), ('t', (3,)), ('dist', (5,))):
            value = np.array(getattr(self, field), dtype=float).reshape(shape)
            value.flags.writeable = False  # frozen means the arrays too
            object.__setattr__(self, field, value)
        object.__setattr__(self, 'width', int(self.width))
        object.__setattr__(self, 'height', int(self.height))
        # derived once: rays() and project() run for every skeleton of every frame
        object.__setattr__(self, '_k_inv', np.linalg.inv(self.K[:2, :2]).T)
        # pixel (u, v, 1) -> world direction of its ray (not unit) for a lens without distortion
        to_normalised = np.eye(3)
        to_normalised[:2, :2] = self._k_inv.T
        to_normalised[:2, 2] = -self._k_inv.T @ self.K[:2, 2]
        object.__setattr__(self, '_pixel_to_ray', self.R.T @ to_normalised)
        object.__setattr__(self, '_distorted', bool(np.any(self.dist != 0)))
        centre = -self.R.T @ self.t
        centre.flags.writeable = False
        object.__setattr__(self, '_centre', centre)

    @classmethod
    def from_projection(cls, name: str, P: np.ndarray, width: int, height: int) -> Camera:
        """Camera without distortion from a (3, 4) projection matrix (any scale or sign)."""
        P = np.asarray(P, dtype=float).reshape(3, 4)
        # P is defined up to a scale whose sign decides which side of the camera is "in front":
        # with positive focal lengths and det(R) = +1 that scale must make det(P[:, :3]) > 0.
        if np.linalg.det(P[:, :3]) < 0:
            P = -P
        K, R = scipy.linalg.rq(P[:, :3])
        flip = np.diag(np.sign(np.diag(K)))
        K, R = K @ flip, flip @ R
        t = np.linalg.solve(K, P[:, 3])
        return cls(name, K / K[2, 2], R, t, np.zeros(5), width, height)

    @property
    def P(self) -> np.ndarray:
        """(3, 4) projection matrix K [R | t] (ignores distortion)."""
        return self.K @ np.column_stack([self.R, self.t])

    @property
    def centre(self) -> np.ndarray:
        """(3,) world position of the optical centre."""
        return self._centre

    @property
    def has_distortion(self) -> bool:
        """Any non-zero distortion coefficient (most rigs have none)."""
        return self._distorted

    def project(self, X: np.ndarray) -> np.ndarray:
        """(..., 3) world points -> (..., 2) pixels; NaN for points at or behind the camera."""
        # coordinate by coordinate on whole arrays: matmuls and broadcasts over a last axis of 2
        # or 3 took 2.7 times as long
        x, y, z = np.moveaxis(np.asarray(X, dtype=float), -1, 0)
        R, t = self.R, self.t
        depth = R[2, 0] * x + R[2, 1] * y + R[2, 2] * z + t[2]
        with np.errstate(divide='ignore', invalid='ignore'):
            inv = np.where(depth > 0, 1.0 / depth, np.nan)
        xn = (R[0, 0] * x + R[0, 1] * y + R[0, 2] * z + t[0]) * inv
        yn = (R[1, 0] * x + R[1, 1] * y + R[1, 2] * z + t[1]) * inv
        if self.has_distortion:
            xn, yn = np.moveaxis(self._distort(np.stack([xn, yn], axis=-1)), -1, 0)
        K = self.K
        uv = np.empty(xn.shape + (2,))
        uv[..., 0] = K[0, 0] * xn + K[0, 1] * yn + K[0, 2]
        uv[..., 1] = K[1, 0] * xn + K[1, 1] * yn + K[1, 2]
        return uv

    def rays(self, uv: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(..., 2) pixels -> world rays: origins (..., 3) (the centre), unit dirs (..., 3)."""
        d = self.directions(uv)
        return np.broadcast_to(self.centre, d.shape).copy(), d

    def directions(self, uv: np.ndarray) -> np.ndarray:
        """(..., 2) pixels -> (..., 3) unit world directions of their rays (from the centre)."""
        uv = np.asarray(uv, dtype=float)
        xy = (uv - self.K[:2, 2]) @ self._k_inv
        if self.has_distortion:
            xy = self._undistort(xy)
        d = xy @ self.R[:2] + self.R[2]  # R.T @ (x, y, 1) for each ray
        d /= np.sqrt(np.einsum('...i,...i->...', d, d))[..., None]
        return d

    def _distort(self, xy: np.ndarray) -> np.ndarray:
        """(..., 2) undistorted -> distorted normalised coordinates."""
        k1, k2, p1, p2, k3 = self.dist
        x, y = xy[..., 0], xy[..., 1]
        r2 = x * x + y * y
        radial = 1 + r2 * (k1 + r2 * (k2 + r2 * k3))
        return np.stack([x * radial + 2 * p1 * x * y + p2 * (r2 + 2 * x * x),
                         y * radial + p1 * (r2 + 2 * y * y) + 2 * p2 * x * y], axis=-1)

    def _undistort(self, xy_d: np.ndarray) -> np.ndarray:
        """(..., 2) distorted -> undistorted normalised coordinates by Newton's method."""
        k1, k2, p1, p2, k3 = self.dist
        xy = xy_d.copy()
        for _ in range(_UNDISTORT_ITERATIONS):
            x, y = xy[..., 0], xy[..., 1]
            r2 = x * x + y * y
            radial = 1 + r2 * (k1 + r2 * (k2 + r2 * k3))
            d_radial = 2 * (k1 + r2 * (2 * k2 + 3 * k3 * r2))  # d radial / d r2, times 2
            # Jacobian of _distort at (x, y).
            j_xx = radial + x * x * d_radial + 2 * p1 * y + 6 * p2 * x
            j_xy = x * y * d_radial + 2 * p1 * x + 2 * p2 * y  # symmetric: also d y_d / d x
            j_yy = radial + y * y * d_radial + 6 * p1 * y + 2 * p2 * x
            r = self._distort(xy) - xy_d
            det = j_xx * j_yy - j_xy * j_xy
            xy = xy - np.stack([j_yy * r[..., 0] - j_xy * r[..., 1],
                                j_xx * r[..., 1] - j_xy * r[..., 0]], axis=-1) / det[..., None]
        return xy


def _image_size(path: Path, width: int | None, height: int | None) -> tuple[int, int]:
    """The image size (pixels) given by the caller: calibration files do not record it, and it
    is never guessed (from a file name or the principal point). ValueError naming the file when
    either is missing or below 1."""
    if width is None or height is None:
        raise ValueError(f'{path}: image size unknown: the calibration does not record it, so give width and '
                         f'height (got {width}, {height})')
    if not (int(width) >= 1 and int(height) >= 1):
        raise ValueError(f'{path}: image size must be at least 1x1 pixels, got {width}x{height}')
    return int(width), int(height)


def _load_json(path: Path, width: int | None, height: int | None) -> list[Camera]:
    try:
        with open(path) as f:
            entries = json.load(f)
    except (ValueError, UnicodeDecodeError) as exc:
        raise ValueError(f'{path}: not valid JSON ({exc})') from None
    if not isinstance(entries, dict) or not entries:
        raise ValueError(f'{path}: expected an object of cameras, got {type(entries).__name__}')
    return [_camera_from_json(path, name, entries[name], width, height)
            for name in sorted(entries, key=lambda n: (len(n), n))]


def _camera_from_json(path: Path, name: str, e: object, width: int | None, height: int | None) -> Camera:
    """One camera of a Shelf-layout calibration; ValueError naming the file, camera and field."""
    where = f'{path}: camera {name!r}'
    if not isinstance(e, dict):
        raise ValueError(f'{where}: expected an object, got {type(e).__name__}')
    missing = [k for k in ('R', 'T', 'fx', 'fy', 'cx', 'cy') if k not in e]
    if missing:
        raise ValueError(f'{where}: missing {", ".join(missing)}')
    try:
        R_raw = np.asarray(e['R'], dtype=float).reshape(3, 3)
        centre = np.asarray(e['T'], dtype=float).reshape(3) / 1000.0  # mm -> m
        fx, fy, cx, cy = (float(e[k]) for k in ('fx', 'fy', 'cx', 'cy'))
        k = np.ravel(e.get('k', [])).astype(float)
        p = np.ravel(e.get('p', [])).astype(float)
    except (TypeError, ValueError) as exc:
        raise ValueError(f'{where}: R (3x3), T (3), fx, fy, cx, cy, k, p must be numbers ({exc})') from None
    if k.size > 3 or p.size > 2:
        raise ValueError(f'{where}: expected at most 3 radial (k) and 2 tangential (p) coefficients')
    values = np.concatenate([R_raw.ravel(), centre, [fx, fy, cx, cy], k, p])
    if not np.isfinite(values).all():
        raise ValueError(f'{where}: non-finite values')
    # The files round R to 6 decimals; snap it back onto SO(3) so that R.T inverts it. A matrix
    # far from a rotation (singular, a reflection) is an error, not something to snap.
    if not abs(np.linalg.det(R_raw) - 1.0) < 1e-3:
        raise ValueError(f'{where}: R is not a rotation (determinant {np.linalg.det(R_raw):.6g})')
    if not (fx > 0 and fy > 0):
        raise ValueError(f'{where}: focal lengths fx, fy must be > 0 (a singular K), got {fx}, {fy}')
    u, _, vt = np.linalg.svd(R_raw)
    R = u @ vt
    k = np.pad(k, (0, 3 - k.size))
    p = np.pad(p, (0, 2 - p.size))
    K = np.array([[fx, 0.0, cx], [0.0, fy, cy], [0.0, 0.0, 1.0]])
    w, h = _image_size(path, width, height)
    return Camera(name, K, R, -R @ centre, np.array([k[0], k[1], p[0], p[1], k[2]]), w, h)


def _load_projections(files: list[Path], width: int | None, height: int | None) -> list[Camera]:
    cams = []
    for f in files:
        P = np.array(f.read_text().replace(',', ' ').split(), dtype=float).reshape(3, 4)
        cam = Camera.from_projection(f.name[1:-4], P, 0, 0)
        w, h = _image_size(f, width, height)
        cams.append(dataclasses.replace(cam, width=w, height=h))
    return cams


def load_rig(path: str | Path, width: int | None = None, height: int | None = None) -> list[Camera]:
    """Cameras of a rig, ordered by index.

    path: a calibration json (Shelf layout: {cam: {R, T (mm, centre in world), fx, fy, cx, cy,
    k, p}}) or a folder holding one (calibration_*.json, preferred: it carries distortion) or
    P{i}.txt projection matrices (world metres -> pixels). width, height: the image size in
    pixels, required (these files do not record it): a ValueError naming the file without it.
    """
    path = Path(path)
    if path.is_file():
        if path.suffix == '.json':
            return _load_json(path, width, height)
        if re.fullmatch(r'P\d+\.txt', path.name):
            return _load_projections([path], width, height)
        raise ValueError(f'{path}: not a calibration json or P<i>.txt file')
    if not path.is_dir():
        raise FileNotFoundError(f'calibration not found: {path}')
    jsons = sorted(path.glob('calibration_*.json'))
    if jsons:
        return _load_json(jsons[0], width, height)
    projections = sorted((f for f in path.glob('P*.txt') if re.fullmatch(r'P\d+\.txt', f.name)),
                         key=lambda f: int(f.name[1:-4]))
    if projections:
        return _load_projections(projections, width, height)
    raise FileNotFoundError(f'{path}: no calibration_*.json or P<i>.txt files')


def rig_directions(cameras: Sequence[Camera], which: np.ndarray, uv: np.ndarray) -> np.ndarray:
    """(N, 3) unit world directions of the rays of pixels uv (N, 2), pixel n seen by
    cameras[which[n]] (N,): Camera.directions for pixels of many cameras at once. The cameras
    without distortion take one pass over every pixel (a pass per camera over masked copies
    cost more than the arithmetic); a camera with distortion undistorts its own pixels."""
    uv = np.asarray(uv, dtype=float)
    which = np.asarray(which, dtype=np.intp)
    to_ray = np.stack([cam._pixel_to_ray for cam in cameras])[which]  # (N, 3, 3)
    d = to_ray[:, :, 0] * uv[:, :1] + to_ray[:, :, 1] * uv[:, 1:] + to_ray[:, :, 2]
    d /= np.sqrt(np.einsum('ni,ni->n', d, d))[:, None]
    for i, cam in enumerate(cameras):
        if cam.has_distortion:
            mine = which == i
            d[mine] = cam.directions(uv[mine])
    return d


def line_terms(origins: np.ndarray, dirs: np.ndarray, out: np.ndarray | None = None) -> np.ndarray:
    """(..., 3) lines with unit directions -> (9, ...) each line's share of the least-squares
    system A x = b of the point closest to several lines: A = I - d d^T as its six entries
    (xx, xy, xz, yy, yz, zz), then b = o - d (d . o). Summing the terms of some lines and
    solving (solve_line_terms) gives their closest point, so a set of lines used by many
    solves is prepared once. Component-major, so every step runs on contiguous arrays; out:
    where to write them (9, ...)."""
    o = np.moveaxis(np.asarray(origins, dtype=float), -1, 0)
    dx, dy, dz = np.ascontiguousarray(np.moveaxis(np.asarray(dirs, dtype=float), -1, 0))
    if out is None:
        out = np.empty((9,) + dx.shape)
    along = dx * o[0] + dy * o[1] + dz * o[2]
    for k, (a, b) in enumerate(((dx, dx), (dx, dy), (dx, dz), (dy, dy), (dy, dz), (dz, dz))):
        np.multiply(a, b, out=out[k])
        np.negative(out[k], out=out[k])
    out[[0, 3, 5]] += 1.0
    for k, (oc, dc) in enumerate(zip(o, (dx, dy, dz)), start=6):
        np.multiply(dc, along, out=out[k])
        np.subtract(oc, out[k], out=out[k])
    return out


def solve_line_terms(terms: np.ndarray, n_lines: int) -> np.ndarray:
    """(9, ...) summed line_terms -> (..., 3) the closest point, by Cramer's rule on the
    symmetric 3x3 system; NaN where it is degenerate (fewer than two non-parallel lines, or not
    finite). n_lines: the most lines in any sum (scales the singularity threshold)."""
    a00, a01, a02, a11, a12, a22, b0, b1, b2 = terms
    c00, c01, c02 = a11 * a22 - a12 * a12, a02 * a12 - a01 * a22, a01 * a12 - a02 * a11
    c11, c12, c22 = a00 * a22 - a02 * a02, a01 * a02 - a00 * a12, a00 * a11 - a01 * a01
    det = a00 * c00 + a01 * c01 + a02 * c02
    with np.errstate(invalid='ignore'):
        ok = np.isfinite(det) & np.isfinite(b0 + b1 + b2) & (np.abs(det) > 1e-12 * n_lines ** 3)
    inv = 1.0 / np.where(ok, det, 1.0)
    x = np.stack([(c00 * b0 + c01 * b1 + c02 * b2) * inv,
                  (c01 * b0 + c11 * b1 + c12 * b2) * inv,
                  (c02 * b0 + c12 * b1 + c22 * b2) * inv], axis=-1)
    return np.where(ok[..., None], x, np.nan)


def closest_point_to_rays(origins: np.ndarray, dirs: np.ndarray, weights: np.ndarray | None = None) -> np.ndarray:
    """(..., K, 3) lines (K >= 2) -> (..., 3) point minimising the sum of squared distances.

    Directions need not be unit. weights (..., K), optional: 0 leaves a line out, so sets of
    different sizes can share one padded call. Degenerate sets (fewer than two non-parallel
    lines, or non-finite input) give NaN.
    """
    d = np.asarray(dirs, dtype=float)
    with np.errstate(invalid='ignore', divide='ignore'):  # zero or NaN directions of left-out lines
        d = d / np.linalg.norm(d, axis=-1, keepdims=True)
    w = np.ones(d.shape[:-1]) if weights is None else np.broadcast_to(np.asarray(weights, dtype=float), d.shape[:-1])
    terms = line_terms(np.broadcast_to(origins, d.shape), d)
    terms = np.where(w > 0, terms * w, 0.0).sum(axis=-1)  # left-out lines may hold NaN
    return solve_line_terms(terms, d.shape[-2])


def ray_ray_distance(o1: np.ndarray, d1: np.ndarray, o2: np.ndarray, d2: np.ndarray) -> np.ndarray:
    """(..., 3) two lines each -> (...) distance between their closest points (lines, not rays)."""
    o1, d1, o2, d2 = (np.asarray(a, dtype=float) for a in (o1, d1, o2, d2))
    d1 = d1 / np.linalg.norm(d1, axis=-1, keepdims=True)
    d2 = d2 / np.linalg.norm(d2, axis=-1, keepdims=True)
    gap = o2 - o1
    n = np.cross(d1, d2)
    n_norm = np.linalg.norm(n, axis=-1)
    parallel = n_norm < 1e-9
    with np.errstate(divide='ignore', invalid='ignore'):
        skew = np.abs(np.sum(gap * n, axis=-1)) / n_norm
    # Parallel lines: distance from o2 to line 1.
    side = np.linalg.norm(np.cross(gap, d1), axis=-1)
    return np.where(parallel, side, skew)
