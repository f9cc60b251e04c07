"""Unit quaternions ``(w, x, y, z)`` rotating body-frame vectors to the world frame.

All functions are Numba kernels on scalars or small arrays; they allocate nothing.
"""
import numpy as np
from numba import njit


@njit(cache=True, error_model="numpy")
def quat_multiply_into(a, b, out):
    """``out = a * b`` (Hamilton product); ``out`` may not alias ``a`` or ``b``."""
    out[0] = a[0] * b[0] - a[1] * b[1] - a[2] * b[2] - a[3] * b[3]
    out[1] = a[0] * b[1] + a[1] * b[0] + a[2] * b[3] - a[3] * b[2]
    out[2] = a[0] * b[2] - a[1] * b[3] + a[2] * b[0] + a[3] * b[1]
    out[3] = a[0] * b[3] + a[1] * b[2] - a[2] * b[1] + a[3] * b[0]


@njit(cache=True, inline="always", error_model="numpy")
def matrix_entries(w, x, y, z):
    """The nine entries, row by row, of the rotation matrix of the unit quaternion ``(w, x, y, z)``."""
    return (1.0 - 2.0 * (y * y + z * z), 2.0 * (x * y - w * z), 2.0 * (x * z + w * y),
            2.0 * (x * y + w * z), 1.0 - 2.0 * (x * x + z * z), 2.0 * (y * z - w * x),
            2.0 * (x * z - w * y), 2.0 * (y * z + w * x), 1.0 - 2.0 * (x * x + y * y))


@njit(cache=True, inline="always", error_model="numpy")
def quat_to_matrix_into(q, m):
    """Rotation matrix ``m`` [3, 3] of the unit quaternion ``q`` [4]."""
    (m[0, 0], m[0, 1], m[0, 2], m[1, 0], m[1, 1], m[1, 2], m[2, 0], m[2, 1],
     m[2, 2]) = matrix_entries(q[0], q[1], q[2], q[3])


SERIES_ANGLE2 = 1e-4   # [rad^2]: below it, the rotation of one step by series (h = ang/2 < 5e-3)


@njit(cache=True, inline="always", error_model="numpy")
def series_factors(ang2):
    """``(sin(h) / (2 h), cos(h))`` of the half angle ``h``, ``h^2 = ang2 / 4``, by series: exact to
    round-off for ``ang2 < SERIES_ANGLE2``, no sqrt/sin/cos; constant reciprocals, not divisions
    (LLVM keeps a division by a constant: it cost 70 % of the drift of a granular step)."""
    h2 = 0.25 * ang2
    s = 0.5 * (1.0 - h2 * (1.0 / 6.0) * (1.0 - h2 * (1.0 / 20.0)))
    c = 1.0 - 0.5 * h2 * (1.0 - h2 * (1.0 / 12.0) * (1.0 - h2 * (1.0 / 30.0)))
    return s, c


@njit(cache=True, inline="always", error_model="numpy")
def turned(c, s, ax, ay, az, w0, x0, y0, z0):
    """``exp(a / 2) * q`` renormalised, for the rotation vector ``a`` of one step [rad] with
    ``s = sin(|a|/2) / |a|``, ``c = cos(|a|/2)`` and ``q = (w0, x0, y0, z0)``."""
    dw, dx, dy, dz = c, ax * s, ay * s, az * s
    nw = dw * w0 - dx * x0 - dy * y0 - dz * z0
    nx = dw * x0 + dx * w0 + dy * z0 - dz * y0
    ny = dw * y0 - dx * z0 + dy * w0 + dz * x0
    nz = dw * z0 + dx * y0 - dy * x0 + dz * w0
    inv = 1.0 / np.sqrt(nw * nw + nx * nx + ny * ny + nz * nz)
    return nw * inv, nx * inv, ny * inv, nz * inv


@njit(cache=True, inline="always", error_model="numpy")
def rotate_world(q, w, dt):
    """Advance ``q`` in place by the exact exponential of the world-frame rotation ``w dt``.

    ``q <- exp(w dt / 2) * q``, then renormalised against round-off drift.
    """
    ax = w[0] * dt
    ay = w[1] * dt
    az = w[2] * dt
    ang2 = ax * ax + ay * ay + az * az
    if ang2 == 0.0:
        return
    if ang2 < SERIES_ANGLE2:
        s, c = series_factors(ang2)
    else:
        ang = np.sqrt(ang2)
        s = np.sin(0.5 * ang) / ang
        c = np.cos(0.5 * ang)
    q[0], q[1], q[2], q[3] = turned(c, s, ax, ay, az, q[0], q[1], q[2], q[3])


def quat_from_rotvec(rv):
    """Quaternion [4] of the rotation vector ``rv`` [3] (axis times angle, radians). NumPy, setup only."""
    rv = np.asarray(rv, dtype=np.float64)
    ang = float(np.linalg.norm(rv))
    if ang == 0.0:
        return np.array([1.0, 0.0, 0.0, 0.0])
    axis = rv / ang
    return np.concatenate([[np.cos(ang / 2)], np.sin(ang / 2) * axis])


def quat_to_matrix(q):
    """Rotation matrix [3, 3] of the unit quaternion ``q`` (NumPy convenience)."""
    m = np.empty((3, 3))
    quat_to_matrix_into(np.asarray(q, dtype=np.float64), m)
    return m
