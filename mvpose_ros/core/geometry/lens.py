"""Lens distortion: the models a ROS CameraInfo names (sensor_msgs/distortion_models.hpp), with
their coefficients in D's order, between normalised coordinates (x/z, y/z) and distorted ones.

- plumb_bob: OpenCV's radial-tangential model, D = k1 k2 p1 p2 k3; computed as
  rational_polynomial with k4 = k5 = k6 = 0, to the bit of the 5-coefficient formula;
- rational_polynomial: the same with a rational radial factor, D = k1 k2 p1 p2 k3 k4 k5 k6;
- equidistant: cv2.fisheye's model, D = k1 k2 k3 k4: a ray at angle theta from the optical axis
  lands at radius theta (1 + k1 theta^2 + k2 theta^4 + k3 theta^6 + k4 theta^8); never the
  identity (zero coefficients map angles, not tangents, to radii).

Kernels (core.geometry.projection) take a lens as KERNEL_SIZE numbers (kernel_form): the
coefficients in KERNEL_SLOTS slots, then its kind (NONE, RADIAL_TANGENTIAL, FISHEYE)."""
from __future__ import annotations

import numpy as np

PLUMB_BOB, RATIONAL_POLYNOMIAL, EQUIDISTANT = 'plumb_bob', 'rational_polynomial', 'equidistant'
# model -> its coefficients, in D's order
MODELS: dict[str, tuple[str, ...]] = {
    PLUMB_BOB: ('k1', 'k2', 'p1', 'p2', 'k3'),
    RATIONAL_POLYNOMIAL: ('k1', 'k2', 'p1', 'p2', 'k3', 'k4', 'k5', 'k6'),
    EQUIDISTANT: ('k1', 'k2', 'k3', 'k4'),
}
DEFAULT_MODEL = PLUMB_BOB
# OpenCV's full model: rational_polynomial's 8 then thin prism s1-s4 and sensor tilt tau_x, tau_y;
# some drivers send all 14 (OAK), which is rational_polynomial while the last 6 are 0
OPENCV_FULL = 14
NONE, RADIAL_TANGENTIAL, FISHEYE = 0, 1, 2
KERNEL_SLOTS = 8
KERNEL_SIZE = KERNEL_SLOTS + 1
_NEWTON_ITERATIONS = 10  # quadratic convergence: exact to float precision for a lens monotone over the image
_FOLD_SAMPLES = 4096  # radii fold() looks at: 0.34% apart (a pinhole's), or 0.02 degrees (a fisheye's)


def describe(model: str) -> str:
    """'plumb_bob (k1 k2 p1 p2 k3)', for messages."""
    return f'{model} ({" ".join(MODELS[model])})'


def unsupported(model: str) -> str:
    """What to say of a model that is not in MODELS."""
    return (f'distortion_model: {model!r} is not supported (supported: '
            f'{", ".join(describe(m) for m in MODELS)})')


def coefficients(model: str, values: np.ndarray, what: str = 'D') -> np.ndarray:
    """The coefficients of model (in MODELS) from values (1-D, finite; called `what` in errors),
    the missing trailing ones 0: (n,) for the model's n. ValueError of one line starting with
    `what` for more values than the model has (but rational_polynomial's 14 of OpenCV's full model
    with the last 6 zero)."""
    n = len(MODELS[model])
    values = np.asarray(values, dtype=np.float64).ravel()
    if model == RATIONAL_POLYNOMIAL and values.size == OPENCV_FULL:
        if np.any(values[n:] != 0):
            raise ValueError(f'{what}: thin prism and tilt terms (s1-s4, tau_x, tau_y) are not supported, '
                             f'got {values[n:].tolist()}')
        values = values[:n]
    if values.size > n:
        raise ValueError(f'{what}: {model} has at most {n} coefficients ({" ".join(MODELS[model])}), '
                         f'got {values.size}')
    return np.pad(values, (0, n - values.size))


def distorts(model: str, dist: np.ndarray) -> bool:
    """Whether the lens moves any point: a fisheye always, the others with a non-zero coefficient."""
    return model == EQUIDISTANT or bool(np.any(dist != 0))


def fold(model: str, dist: np.ndarray, reach: float) -> float | None:
    """Where the lens's radial map stops growing, as a distorted normalised radius, when that is
    within `reach` (the largest distorted normalised radius the image holds: its corners), else
    None. Beyond such a fold two rays land on one pixel, and undistorting a pixel there has no one
    answer: a calibration fitted with too few views near the corners does this. The tangential
    terms are left out (they are small where a calibration is sound). A pinhole image whose
    corners lie beyond every radius the lens reaches before 90 degrees off axis folds at the
    largest; a fisheye's corners may lie outside its image circle (dark), so only its fold counts."""
    if not distorts(model, dist):
        return None
    r_d = _distorted_radii(model, np.asarray(dist, dtype=np.float64))
    reached = np.flatnonzero(r_d >= reach)
    end = reached[0] if reached.size else len(r_d) - 1
    stops = np.flatnonzero(np.diff(r_d[:end + 1]) <= 0)
    if stops.size:
        return float(r_d[stops[0]])
    if not reached.size and model != EQUIDISTANT:
        return float(r_d.max())
    return None


def _distorted_radii(model: str, dist: np.ndarray) -> np.ndarray:
    """(N,) the distorted radii of normalised radii growing densely up to about 90 degrees off axis."""
    if model == EQUIDISTANT:
        r = np.tan(np.linspace(0.0, np.pi / 2, _FOLD_SAMPLES)[1:-1])
        return r * _fisheye_scale(dist, r)
    k1, k2, _, _, k3, k4, k5, k6 = np.pad(dist, (0, KERNEL_SLOTS - len(dist)))
    r = np.geomspace(1e-3, 1e3, _FOLD_SAMPLES)  # up to 89.94 degrees
    r2 = r * r
    return r * (1 + r2 * (k1 + r2 * (k2 + r2 * k3))) / (1 + r2 * (k4 + r2 * (k5 + r2 * k6)))


def kernel_form(model: str, dist: np.ndarray) -> np.ndarray:
    """(KERNEL_SIZE,) the lens as projection.distort_point takes it: the coefficients in D's order, padded with
    zeros (plumb_bob k1 k2 p1 p2 k3 is rational_polynomial's first five), then its kind."""
    kind = FISHEYE if model == EQUIDISTANT else RADIAL_TANGENTIAL if distorts(model, dist) else NONE
    return np.concatenate([dist, np.zeros(KERNEL_SLOTS - len(dist)), [kind]])


def distort(model: str, dist: np.ndarray, xy: np.ndarray) -> np.ndarray:
    """(..., 2) normalised -> distorted normalised coordinates."""
    x, y = xy[..., 0], xy[..., 1]
    if model == EQUIDISTANT:
        return xy * _fisheye_scale(dist, np.sqrt(x * x + y * y))[..., None]
    k1, k2, p1, p2, k3, k4, k5, k6 = np.pad(dist, (0, KERNEL_SLOTS - len(dist)))
    r2 = x * x + y * y
    radial = (1 + r2 * (k1 + r2 * (k2 + r2 * k3))) / (1 + r2 * (k4 + r2 * (k5 + r2 * k6)))
    return np.stack([x * radial + 2 * p1 * x * y + p2 * (r2 + 2 * x * x),
                     y * radial + p1 * (r2 + 2 * y * y) + 2 * p2 * x * y], axis=-1)


def undistort(model: str, dist: np.ndarray, xy_d: np.ndarray) -> np.ndarray:
    """(..., 2) distorted -> normalised coordinates, by Newton's method (on the angle, for a fisheye)."""
    if model == EQUIDISTANT:
        return _fisheye_undistort(dist, xy_d)
    k1, k2, p1, p2, k3, k4, k5, k6 = np.pad(dist, (0, KERNEL_SLOTS - len(dist)))
    xy = xy_d.copy()
    for _ in range(_NEWTON_ITERATIONS):
        x, y = xy[..., 0], xy[..., 1]
        r2 = x * x + y * y
        num = 1 + r2 * (k1 + r2 * (k2 + r2 * k3))
        den = 1 + r2 * (k4 + r2 * (k5 + r2 * k6))
        radial = num / den
        d_num = k1 + r2 * (2 * k2 + 3 * k3 * r2)
        d_den = k4 + r2 * (2 * k5 + 3 * k6 * r2)
        d_radial = 2 * (d_num * den - num * d_den) / (den * den)  # d radial / d r2, times 2
        # Jacobian of distort at (x, y)
        j_xx = radial + x * x * d_radial + 2 * p1 * y + 6 * p2 * x
        j_xy = x * y * d_radial + 2 * p1 * x + 2 * p2 * y  # symmetric: also d y_d / d x
        j_yy = radial + y * y * d_radial + 6 * p1 * y + 2 * p2 * x
        r = distort(model, dist, xy) - xy_d
        det = j_xx * j_yy - j_xy * j_xy
        xy = xy - np.stack([j_yy * r[..., 0] - j_xy * r[..., 1],
                            j_xx * r[..., 1] - j_xy * r[..., 0]], axis=-1) / det[..., None]
    return xy


def _fisheye_scale(dist: np.ndarray, r: np.ndarray) -> np.ndarray:
    """Distorted radius / radius of normalised radii r (...), 1 at the axis."""
    k1, k2, k3, k4 = dist
    theta = np.arctan(r)
    t2 = theta * theta
    with np.errstate(invalid='ignore', divide='ignore'):
        scale = theta * (1 + t2 * (k1 + t2 * (k2 + t2 * (k3 + t2 * k4)))) / r
    return np.where(r > 0, scale, 1.0)


def _fisheye_undistort(dist: np.ndarray, xy_d: np.ndarray) -> np.ndarray:
    """The angle theta from theta_d = theta (1 + k1 theta^2 + ...), then the tangent's radius."""
    k1, k2, k3, k4 = dist
    theta_d = np.sqrt(np.einsum('...i,...i->...', xy_d, xy_d))
    theta = np.minimum(theta_d, np.pi / 2)
    for _ in range(_NEWTON_ITERATIONS):
        t2 = theta * theta
        f = theta * (1 + t2 * (k1 + t2 * (k2 + t2 * (k3 + t2 * k4)))) - theta_d
        df = 1 + t2 * (3 * k1 + t2 * (5 * k2 + t2 * (7 * k3 + t2 * 9 * k4)))
        theta = np.clip(theta - f / df, 0.0, np.nextafter(np.pi / 2, 0))
    with np.errstate(invalid='ignore', divide='ignore'):
        scale = np.tan(theta) / theta_d
    return xy_d * np.where(theta_d > 0, scale, 1.0)[..., None]
