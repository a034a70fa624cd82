"""Calibrated pinhole cameras with OpenCV lens distortion, and rig loading (numpy only: every node
loads its cameras; the compiled projection of many cameras at once is core.geometry.projection,
ray geometry core.geometry.rays).

Convention: a world point X (metres) maps to camera coordinates x_cam = R @ X + t, then to
normalised coordinates (x/z, y/z), through the lens distortion (core.geometry.lens: plumb_bob,
rational_polynomial or equidistant, with CameraInfo's coefficients), and to pixels through K.
"""
from __future__ import annotations

import dataclasses
import json
import re
from pathlib import Path

import numpy as np

from mvpose_ros.core.geometry import lens


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
        # the projection's parameters as projection.rig_model takes them: R, t, K row-major, then the lens
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
        K, R = _rq(P[:, :3])
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
        X = np.asarray(X, dtype=np.float64)
        x, y, z = X[..., 0], X[..., 1], X[..., 2]
        R, t, K = self.R, self.t, self.K
        # the arithmetic of projection.project_point, in its order: the same bits (a fisheye's arctan: 1e-13 px)
        depth = R[2, 0] * x + R[2, 1] * y + R[2, 2] * z + t[2]
        with np.errstate(divide='ignore'):
            inv = np.where(depth > 0, 1.0 / depth, np.nan)
        xy = np.stack([(R[0, 0] * x + R[0, 1] * y + R[0, 2] * z + t[0]) * inv,
                       (R[1, 0] * x + R[1, 1] * y + R[1, 2] * z + t[1]) * inv], axis=-1)
        if self.has_distortion:
            xy = lens.distort(self.distortion_model, self.dist, xy)
        xn, yn = xy[..., 0], xy[..., 1]
        return np.stack([K[0, 0] * xn + K[0, 1] * yn + K[0, 2], K[1, 0] * xn + K[1, 1] * yn + K[1, 2]], axis=-1)

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


def _rq(M: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(3, 3) M = R Q with R upper triangular and Q orthonormal (signs not fixed), from numpy's QR of
    M reversed and transposed."""
    q, r = np.linalg.qr(M[::-1].T)
    return r.T[::-1, ::-1], q.T[::-1]
