"""Ray geometry, compiled: the point closest to several lines (least squares, as summed per-line
terms) and the distance between two lines; the `*_into` kernels and line_distance are also
called from other modules' kernels."""
from __future__ import annotations

import numpy as np

from mvpose_ros.core.compiled import kernel, kernel_array


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
