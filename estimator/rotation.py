"""Quaternion helpers on plain Python floats for the estimator's 500 Hz inner loop.

Takes in: quaternions as 4-tuples (w, x, y, z) rotating body FLU vectors into world ENU, rotation
vectors as 3 floats (rad).
Gives out: products, exponential/logarithm maps and 3x3 rotation matrices as row-major 9-tuples.

Why not scipy.spatial.transform.Rotation: building one Rotation object costs ~10 us, which alone
would spend a sixth of the per-IMU-sample budget (issue: <= 60 us); these are checked against scipy
in tests/estimator/test_eskf.py.

Conventions (Sola, "Quaternion kinematics for the error-state Kalman filter", 2017, Hamilton):
  q_a (x) q_b is the Hamilton product, R(q_a (x) q_b) = R(q_a) R(q_b);
  Exp(theta) = [cos(|theta|/2), sin(|theta|/2) theta/|theta|];  Log is its inverse with |angle| <= pi.
"""

from __future__ import annotations

import math

from link.rotation import Mat9, quat_conjugate, quat_multiply, quat_to_matrix  # noqa: F401 (re-exported)

Quat4 = tuple[float, float, float, float]

# Below this angle (rad) Exp/Log use their Taylor series: sin(a/2)/a = 1/2 - a^2/48 + ..., whose
# truncation error a^4/3840 is below double precision for a < 1e-4 (and well below at 1e-6).
_SMALL_ANGLE_RAD = 1e-6


def quat_normalise(q: Quat4) -> Quat4:
    """Unit quaternion with non-negative w (q and -q are the same rotation)."""
    n = math.sqrt(q[0] * q[0] + q[1] * q[1] + q[2] * q[2] + q[3] * q[3])
    if n == 0.0:
        raise ValueError("zero quaternion")
    if q[0] < 0.0:
        n = -n
    return (q[0] / n, q[1] / n, q[2] / n, q[3] / n)


def quat_exp(rx: float, ry: float, rz: float) -> Quat4:
    """Unit quaternion of the rotation vector (rx, ry, rz) rad."""
    angle = math.sqrt(rx * rx + ry * ry + rz * rz)
    if angle < _SMALL_ANGLE_RAD:
        s = 0.5 - angle * angle / 48.0
        return (1.0 - angle * angle / 8.0, s * rx, s * ry, s * rz)
    s = math.sin(0.5 * angle) / angle
    return (math.cos(0.5 * angle), s * rx, s * ry, s * rz)


def quat_log(q: Quat4) -> tuple[float, float, float]:
    """Rotation vector (rad, |.| <= pi) of the unit quaternion q."""
    w, x, y, z = q
    if w < 0.0:  # the short way round
        w, x, y, z = -w, -x, -y, -z
    n = math.sqrt(x * x + y * y + z * z)
    if n < _SMALL_ANGLE_RAD:
        k = 2.0 / w  # 2 atan2(n, w) / n -> 2 / w as n -> 0
        return (k * x, k * y, k * z)
    k = 2.0 * math.atan2(n, w) / n
    return (k * x, k * y, k * z)


def rotate(r: Mat9, vx: float, vy: float, vz: float) -> tuple[float, float, float]:
    """R v for a row-major 9-tuple R."""
    return (
        r[0] * vx + r[1] * vy + r[2] * vz,
        r[3] * vx + r[4] * vy + r[5] * vz,
        r[6] * vx + r[7] * vy + r[8] * vz,
    )


def attitude_error(q_from: Quat4, q_to: Quat4) -> tuple[float, float, float]:
    """Body-frame rotation vector d_theta with q_to = q_from (x) Exp(d_theta), rad."""
    return quat_log(quat_multiply(quat_conjugate(q_from), q_to))
