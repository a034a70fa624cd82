"""Calibrated pinhole cameras with OpenCV lens distortion, rig loading, and ray geometry.

Convention: a world point X (metres) maps to camera coordinates x_cam = R @ X + t, then to
normalised coordinates (x/z, y/z), through the lens distortion (core.geometry.lens: plumb_bob,
rational_polynomial or equidistant, with CameraInfo's coefficients), and to pixels through K.
"""
from __future__ import annotations

import dataclasses
import json
import re
from pathlib import Path
from typing import Sequence

import numpy as np
import scipy.linalg

from mvpose_ros.core.compiled import inline_kernel, kernel, kernel_array
from mvpose_ros.core.geometry import lens
from mvpose_ros.core.geometry.lens import distort_point


@dataclasses.dataclass(frozen=True, eq=False)
class Camera:
    """One calibrated camera.

    K: (3, 3) intrinsics; R: (3, 3) world-to-camera rotation; t: (3,) metres; dist: the
    coefficients of distortion_model in CameraInfo's order (lens.MODELS: plumb_bob (5,) k1, k2, p1,
    p2, k3, zeros for none); width, height: image size in pixels.
    """

    name: str
    K: np.ndarray
    R: np.ndarray
    t: np.ndarray
    dist: np.ndarray
    width: int
    height: int
    distortion_model: str = lens.DEFAULT_MODEL

    def __post_init__(self) -> None:
        if self.distortion_model not in lens.MODELS:
            raise ValueError(f'camera {self.name}: distortion_model {self.distortion_model!r} is not one of '
                             f'{", ".join(lens.MODELS)}')
        n = len(lens.MODELS[self.distortion_model])
        for field, shape in (('K', (3, 3)), ('R', (3, 3)), ('t', (3,)), ('dist', (n,))):
            value = np.array(getattr(self, field), dtype=float, order='C').reshape(shape)  # C: what kernels take
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
        object.__setattr__(self, '_distorted', lens.distorts(self.distortion_model, self.dist))
        centre = -self.R.T @ self.t
        centre.flags.writeable = False
        object.__setattr__(self, '_centre', centre)
        # the projection's parameters as project_point takes them: R, t, K row-major, then the lens
        object.__setattr__(self, '_model', np.concatenate([self.R.ravel(), self.t, self.K.ravel(),
                                                           lens.kernel_form(self.distortion_model, self.dist)]))

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
        """The lens moves points (a non-zero coefficient, or a fisheye; most rigs have none)."""
        return self._distorted

    def project(self, X: np.ndarray) -> np.ndarray:
        """(..., 3) world points -> (..., 2) pixels; NaN for points at or behind the camera."""
        X = kernel_array(X, np.float64)
        uv = np.empty(X.shape[:-1] + (2,))
        _project(self._model[None], _ZERO, _ZERO, X.reshape(1, -1, 3), uv.reshape(1, -1, 2))
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
            xy = lens.undistort(self.distortion_model, self.dist, xy)
        d = xy @ self.R[:2] + self.R[2]  # R.T @ (x, y, 1) for each ray
        d /= np.sqrt(np.einsum('...i,...i->...', d, d))[..., None]
        return d


def image_corners(width: int, height: int) -> np.ndarray:
    """(4, 2) pixels of an image's corners: top left, top right, bottom right, bottom left."""
    return np.array([[0, 0], [width, 0], [width, height], [0, height]], dtype=float)


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


_ZERO = np.zeros(1, dtype=np.int64)  # one row, of the first camera
_LENS = 21  # where a rig_model row's lens starts (after R, t and K)
MODEL_SIZE = _LENS + lens.KERNEL_SIZE
_KIND = MODEL_SIZE - 1
_UNKNOWN_MODEL = np.zeros(MODEL_SIZE)  # depth 0 for every point: NaN pixels


@inline_kernel
def project_point(model, c, x, y, z):
    """Pixel (u, v) of the world point (x, y, z) m in camera c of a rig_model (C, MODEL_SIZE); NaN at
    or behind the camera. For other kernels; the arithmetic of numpy on whole arrays, in the same order."""
    depth = model[c, 6] * x + model[c, 7] * y + model[c, 8] * z + model[c, 11]
    inv = 1.0 / depth if depth > 0 else np.nan
    xn = (model[c, 0] * x + model[c, 1] * y + model[c, 2] * z + model[c, 9]) * inv
    yn = (model[c, 3] * x + model[c, 4] * y + model[c, 5] * z + model[c, 10]) * inv
    if model[c, _KIND] != lens.NONE:
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


def line_terms(origins: np.ndarray, dirs: np.ndarray, out: np.ndarray | None = None) -> np.ndarray:
    """(..., 3) lines with unit directions -> (9, ...) each line's share of the least-squares
    system A x = b of the point closest to several lines: A = I - d d^T as its six entries
    (xx, xy, xz, yy, yz, zz), then b = o - d (d . o). Summing the terms of some lines and
    solving (solve_line_terms) gives their closest point, so a set of lines used by many
    solves is prepared once. Component-major, so that a term of many lines is contiguous; out:
    where to write them (9, ...)."""
    dirs = kernel_array(dirs, np.float64)
    origins = np.asarray(origins, dtype=np.float64)
    if origins.shape != dirs.shape:
        origins = np.broadcast_to(origins, dirs.shape)
    origins = kernel_array(origins, np.float64)  # a broadcast is read-only: a copy
    if out is None:
        out = np.empty((9,) + dirs.shape[:-1])
    _line_terms(origins.reshape(-1, 3), dirs.reshape(-1, 3), out.reshape(9, -1))
    return out


@kernel('void(float64[::1], float64[::1], float64[::1])')
def line_terms_into(o, d, out):
    """line_terms of one line (origin o, unit direction d (3,)) into out (9,), for other kernels; the
    arithmetic numpy had on whole arrays, so the same bits."""
    dx, dy, dz = d[0], d[1], d[2]
    along = dx * o[0] + dy * o[1] + dz * o[2]
    out[0] = -(dx * dx) + 1.0
    out[1] = -(dx * dy)
    out[2] = -(dx * dz)
    out[3] = -(dy * dy) + 1.0
    out[4] = -(dy * dz)
    out[5] = -(dz * dz) + 1.0
    out[6] = o[0] - dx * along
    out[7] = o[1] - dy * along
    out[8] = o[2] - dz * along


@kernel('void(float64[:, ::1], float64[:, ::1], float64[:, :])')
def _line_terms(o, d, out):
    terms = np.empty(9)
    for n in range(len(d)):
        line_terms_into(o[n], d[n], terms)
        out[:, n] = terms


def solve_line_terms(terms: np.ndarray, n_lines: int) -> np.ndarray:
    """(9, ...) summed line_terms -> (..., 3) the closest point, by Cramer's rule on the
    symmetric 3x3 system; NaN where it is degenerate (fewer than two non-parallel lines, or not
    finite). n_lines: the most lines in any sum (scales the singularity threshold)."""
    terms = kernel_array(terms, np.float64)
    x = np.empty(terms.shape[1:] + (3,))
    _solve_line_terms(terms.reshape(9, -1), 1e-12 * n_lines ** 3, x.reshape(-1, 3))
    return x


@kernel('void(float64[::1], float64, float64[::1])')
def solve_line_terms_into(terms, singular, out):
    """solve_line_terms of one sum of terms (9,) into out (3,), for other kernels; singular:
    1e-12 n_lines^3, the threshold on the determinant."""
    a00, a01, a02, a11, a12, a22 = terms[0], terms[1], terms[2], terms[3], terms[4], terms[5]
    b0, b1, b2 = terms[6], terms[7], terms[8]
    c00, c01, c02 = a11 * a22 - a12 * a12, a02 * a12 - a01 * a22, a01 * a12 - a02 * a11
    c11, c12, c22 = a00 * a22 - a02 * a02, a01 * a02 - a00 * a12, a00 * a11 - a01 * a01
    det = a00 * c00 + a01 * c01 + a02 * c02
    if np.isfinite(det) and np.isfinite(b0 + b1 + b2) and np.abs(det) > singular:
        inv = 1.0 / det
        out[0] = (c00 * b0 + c01 * b1 + c02 * b2) * inv
        out[1] = (c01 * b0 + c11 * b1 + c12 * b2) * inv
        out[2] = (c02 * b0 + c12 * b1 + c22 * b2) * inv
    else:
        out[:] = np.nan


@kernel('void(float64[:, ::1], float64, float64[:, ::1])')
def _solve_line_terms(terms, singular, out):
    summed = np.empty(9)
    for n in range(terms.shape[1]):
        summed[:] = terms[:, n]
        solve_line_terms_into(summed, singular, out[n])


def closest_points_of_ray_sets(centres: np.ndarray, of: np.ndarray, dirs: np.ndarray, sets: np.ndarray) -> np.ndarray:
    """(N, 3) the point closest to each of N sets of rays, as line_terms then solve_line_terms
    (the same arithmetic, each set's terms summed in its order): set n is the rays sets[n]
    (N, K) (-1: no ray, padding), ray r going from centres[of[r]] ((C, 3) metres, (R,)) along the
    unit dirs[r] (R, 3). NaN where a set is degenerate; K scales the singularity threshold as
    solve_line_terms' n_lines. Without the (9, R) terms of every ray and (9, N) of every set."""
    sets = kernel_array(sets, np.int64)
    out = np.empty((len(sets), 3))
    _closest_points(kernel_array(centres, np.float64), kernel_array(of, np.int64),
                    kernel_array(dirs, np.float64), sets, 1e-12 * sets.shape[1] ** 3, out)
    return out


@kernel('void(float64[:, ::1], int64[::1], float64[:, ::1], int64[:, ::1], float64, float64[:, ::1])')
def _closest_points(centres, of, dirs, sets, singular, out):
    terms = np.empty(9)
    summed = np.empty(9)
    for n in range(len(sets)):
        summed[:] = 0.0
        for k in range(sets.shape[1]):
            r = sets[n, k]
            if r >= 0:  # -1: padding, no ray
                line_terms_into(centres[of[r]], dirs[r], terms)
                for t in range(9):
                    summed[t] += terms[t]
        solve_line_terms_into(summed, singular, out[n])


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
    """(..., 3) two lines each (broadcast together) -> (...) distance between their closest points
    (lines, not rays)."""
    arrays = np.broadcast_arrays(*(np.asarray(a, dtype=np.float64) for a in (o1, d1, o2, d2)))
    shape = arrays[0].shape[:-1]
    flat = [kernel_array(a, np.float64).reshape(-1, 3) for a in arrays]
    out = np.empty(len(flat[0]))
    _line_distances(*flat, out)
    return out.reshape(shape)


@kernel('float64(float64[::1], float64[::1], float64[::1], float64[::1])')
def line_distance(o1, d1, o2, d2):
    """Distance between two lines (origins o, directions d (3,), any length), for other kernels:
    along the common normal, or for parallel lines from o2 to line 1."""
    u = d1 / np.sqrt(d1[0] * d1[0] + d1[1] * d1[1] + d1[2] * d1[2])
    v = d2 / np.sqrt(d2[0] * d2[0] + d2[1] * d2[1] + d2[2] * d2[2])
    gap = o2 - o1
    normal = np.cross(u, v)
    normal_norm = np.sqrt(normal[0] * normal[0] + normal[1] * normal[1] + normal[2] * normal[2])
    if normal_norm < 1e-9:  # parallel
        side = np.cross(gap, u)
        return np.sqrt(side[0] * side[0] + side[1] * side[1] + side[2] * side[2])
    return abs(gap[0] * normal[0] + gap[1] * normal[1] + gap[2] * normal[2]) / normal_norm


@kernel('void(float64[:, ::1], float64[:, ::1], float64[:, ::1], float64[:, ::1], float64[::1])')
def _line_distances(o1, d1, o2, d2, out):
    for i in range(len(out)):
        out[i] = line_distance(o1[i], d1[i], o2[i], d2[i])
