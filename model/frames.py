"""Frames and rotations: the one module every package uses for attitude arithmetic.

Conventions (everywhere inside cfstack): world ENU (x east, y north, z up), body FLU (x forward, y left,
z up), quaternions (w, x, y, z) Hamilton, unit, rotating body FLU vectors into world ENU, so that
R(q_a (x) q_b) = R(q_a) R(q_b) (Sola, "Quaternion kinematics for the error-state Kalman filter", 2017).
NED/FRD and the Crazyflie's legacy pitch sign exist only at the protocol edge (link/).

Takes in / gives out, in two flavours:
- plain floats, for the 100 Hz-1 kHz loops, where a numpy call on a 4-vector costs more than the
  arithmetic (and scipy's Rotation costs ~10 us to build): quaternions as 4-tuples, vectors as 3-tuples,
  rotation matrices as row-major 9-tuples ("rows");
- numpy arrays, for analysis, plots and tests: (3, 3) matrices, (N, 4) quaternion rows.
tests/model/test_frames.py checks every function against scipy.spatial.transform.Rotation.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np

Quat = tuple[float, float, float, float]
Vec3 = tuple[float, float, float]
Mat9 = tuple[float, float, float, float, float, float, float, float, float]

IDENTITY: Quat = (1.0, 0.0, 0.0, 0.0)

# Below this angle (rad) quat_exp/quat_log use their Taylor series: sin(a/2)/a = 1/2 - a^2/48 + ...,
# whose truncation error a^4/3840 is below double precision for a < 1e-4 (and well below at 1e-6).
SMALL_ANGLE_RAD = 1e-6
# Below this rotation angle (rad) over a step, quat_integrate returns q unchanged (exact to rounding).
_NEGLIGIBLE_ANGLE_RAD = 1e-12


# ------------------------------------------------------------------------------------------------
# Quaternion algebra (plain floats)
# ------------------------------------------------------------------------------------------------


def quat_multiply(a: Quat, b: Quat) -> Quat:
    """Hamilton product a (x) b: rotate by b first, then by a."""
    aw, ax, ay, az = a
    bw, bx, by, bz = b
    return (
        aw * bw - ax * bx - ay * by - az * bz,
        aw * bx + ax * bw + ay * bz - az * by,
        aw * by - ax * bz + ay * bw + az * bx,
        aw * bz + ax * by - ay * bx + az * bw,
    )


def quat_conjugate(q: Quat) -> Quat:
    """The inverse rotation of a unit quaternion."""
    return (q[0], -q[1], -q[2], -q[3])


def quat_norm(q: Quat) -> float:
    return math.sqrt(q[0] * q[0] + q[1] * q[1] + q[2] * q[2] + q[3] * q[3])


def quat_normalize(q: Quat) -> Quat:
    """q / |q| (the sign of q is kept)."""
    n = quat_norm(q)
    return (q[0] / n, q[1] / n, q[2] / n, q[3] / n)


def quat_normalize_positive_w(q: Quat) -> Quat:
    """The unit quaternion with w >= 0 of the rotation q (q and -q are the same rotation).

    Raises ValueError for the zero quaternion, which is no rotation.
    """
    n = math.sqrt(q[0] * q[0] + q[1] * q[1] + q[2] * q[2] + q[3] * q[3])
    if n == 0.0:
        raise ValueError("zero quaternion")
    if q[0] < 0.0:
        n = -n
    return (q[0] / n, q[1] / n, q[2] / n, q[3] / n)


def quat_exp(rx: float, ry: float, rz: float) -> Quat:
    """Unit quaternion of the rotation vector (rx, ry, rz) rad: [cos(a/2), sin(a/2) r/a], a = |r|.

    estimator/_eskf_kernels.c repeats this (reading SMALL_ANGLE_RAD when it loads): change both together."""
    angle = math.sqrt(rx * rx + ry * ry + rz * rz)
    if angle < SMALL_ANGLE_RAD:
        s = 0.5 - angle * angle / 48.0
        return (1.0 - angle * angle / 8.0, s * rx, s * ry, s * rz)
    s = math.sin(0.5 * angle) / angle
    return (math.cos(0.5 * angle), s * rx, s * ry, s * rz)


def quat_log(q: Quat) -> Vec3:
    """Rotation vector (rad, |.| <= pi) of the unit quaternion q: the inverse of quat_exp."""
    w, x, y, z = q
    if w < 0.0:  # the short way round
        w, x, y, z = -w, -x, -y, -z
    n = math.sqrt(x * x + y * y + z * z)
    if n < SMALL_ANGLE_RAD:
        k = 2.0 / w  # 2 atan2(n, w) / n -> 2 / w as n -> 0
        return (k * x, k * y, k * z)
    k = 2.0 * math.atan2(n, w) / n
    return (k * x, k * y, k * z)


def attitude_error(q_from: Quat, q_to: Quat) -> Vec3:
    """Body-frame rotation vector d_theta (rad) with q_to = q_from (x) Exp(d_theta)."""
    return quat_log(quat_multiply(quat_conjugate(q_from), q_to))


def rotation_angle_between(a: Quat, b: Quat) -> float:
    """Angle (rad, 0..pi) of the rotation taking attitude a to attitude b."""
    dw = abs(a[0] * b[0] + a[1] * b[1] + a[2] * b[2] + a[3] * b[3]) / (quat_norm(a) * quat_norm(b))
    return 2.0 * math.acos(min(1.0, dw))


def quat_integrate(q: Quat, w_flu_radps: Vec3, dt_s: float) -> Quat:
    """q (x) Exp(w dt), normalised: the exact attitude after holding body rate w (rad/s) for dt_s."""
    wx, wy, wz = w_flu_radps
    angle = math.sqrt(wx * wx + wy * wy + wz * wz) * dt_s
    if angle < _NEGLIGIBLE_ANGLE_RAD:
        return q
    s = math.sin(angle / 2.0) / (angle / dt_s)
    dw, dx, dy, dz = math.cos(angle / 2.0), wx * s, wy * s, wz * s
    qw, qx, qy, qz = q
    ow = qw * dw - qx * dx - qy * dy - qz * dz
    ox = qw * dx + qx * dw + qy * dz - qz * dy
    oy = qw * dy - qx * dz + qy * dw + qz * dx
    oz = qw * dz + qx * dy - qy * dx + qz * dw
    n = math.sqrt(ow * ow + ox * ox + oy * oy + oz * oz)
    return (ow / n, ox / n, oy / n, oz / n)


# ------------------------------------------------------------------------------------------------
# Euler angles and heading (plain floats); ZYX = yaw about world z, then pitch, then roll
# ------------------------------------------------------------------------------------------------


def quat_from_yaw(yaw_rad: float) -> Quat:
    """Level attitude heading yaw_rad (rotation about world +z, counter-clockwise from +x east)."""
    return (math.cos(0.5 * yaw_rad), 0.0, 0.0, math.sin(0.5 * yaw_rad))


def yaw_of(q: Quat) -> float:
    """Heading (rad) of the body x axis projected on the horizontal plane (ZYX Euler yaw)."""
    w, x, y, z = q
    return math.atan2(2.0 * (w * z + x * y), 1.0 - 2.0 * (y * y + z * z))


def level_with_yaw(q: Quat) -> Quat:
    """The level attitude (roll = pitch = 0) with the same heading as q."""
    return quat_from_yaw(yaw_of(q))


def quat_from_euler_zyx(roll_rad: float, pitch_rad: float, yaw_rad: float) -> Quat:
    """q = Rz(yaw) Ry(pitch) Rx(roll), the aerospace ZYX convention (body FLU, world ENU).

    In FLU a positive pitch turns the nose down (thrust tips towards +x)."""
    cr, sr = math.cos(0.5 * roll_rad), math.sin(0.5 * roll_rad)
    cp, sp = math.cos(0.5 * pitch_rad), math.sin(0.5 * pitch_rad)
    cy, sy = math.cos(0.5 * yaw_rad), math.sin(0.5 * yaw_rad)
    return (
        cr * cp * cy + sr * sp * sy,
        sr * cp * cy - cr * sp * sy,
        cr * sp * cy + sr * cp * sy,
        cr * cp * sy - sr * sp * cy,
    )


def euler_zyx_of(q: Quat) -> Vec3:
    """(roll, pitch, yaw) rad of a unit quaternion, the inverse of quat_from_euler_zyx (pitch in
    [-pi/2, pi/2])."""
    w, x, y, z = q
    roll = math.atan2(2.0 * (w * x + y * z), 1.0 - 2.0 * (x * x + y * y))
    pitch = math.asin(max(-1.0, min(1.0, 2.0 * (w * y - z * x))))
    return roll, pitch, yaw_of(q)


# ------------------------------------------------------------------------------------------------
# Rotation matrices as row-major 9-tuples (plain floats)
# ------------------------------------------------------------------------------------------------


def quat_to_rows(q: Quat) -> Mat9:
    """Row-major rotation matrix R(q) (body -> world) of a unit quaternion."""
    w, x, y, z = q
    xx, yy, zz = x * x, y * y, z * z
    xy, xz, yz = x * y, x * z, y * z
    wx, wy, wz = w * x, w * y, w * z
    return (
        1.0 - 2.0 * (yy + zz), 2.0 * (xy - wz), 2.0 * (xz + wy),
        2.0 * (xy + wz), 1.0 - 2.0 * (xx + zz), 2.0 * (yz - wx),
        2.0 * (xz - wy), 2.0 * (yz + wx), 1.0 - 2.0 * (xx + yy),
    )


def rows_to_quat(r00: float, r01: float, r02: float, r10: float, r11: float, r12: float,
                 r20: float, r21: float, r22: float) -> Quat:
    """Unit quaternion (w, x, y, z), w >= 0, of a rotation matrix given row-major (Shepperd's method).

    The branch on the largest of (trace, r00, r11, r22) keeps the divisor away from zero.
    """
    trace = r00 + r11 + r22
    if trace >= r00 and trace >= r11 and trace >= r22:
        s = 2.0 * math.sqrt(1.0 + trace)  # s = 4 w
        q = (0.25 * s, (r21 - r12) / s, (r02 - r20) / s, (r10 - r01) / s)
    elif r00 >= r11 and r00 >= r22:
        s = 2.0 * math.sqrt(1.0 + r00 - r11 - r22)  # s = 4 x
        q = ((r21 - r12) / s, 0.25 * s, (r01 + r10) / s, (r02 + r20) / s)
    elif r11 >= r22:
        s = 2.0 * math.sqrt(1.0 + r11 - r00 - r22)  # s = 4 y
        q = ((r02 - r20) / s, (r01 + r10) / s, 0.25 * s, (r12 + r21) / s)
    else:
        s = 2.0 * math.sqrt(1.0 + r22 - r00 - r11)  # s = 4 z
        q = ((r10 - r01) / s, (r02 + r20) / s, (r12 + r21) / s, 0.25 * s)
    return quat_normalize_positive_w(q)


def rotate(r: Mat9, vx: float, vy: float, vz: float) -> Vec3:
    """R v for a row-major 9-tuple R."""
    return (
        r[0] * vx + r[1] * vy + r[2] * vz,
        r[3] * vx + r[4] * vy + r[5] * vz,
        r[6] * vx + r[7] * vy + r[8] * vz,
    )


# ------------------------------------------------------------------------------------------------
# numpy flavour (analysis, plots, tests)
# ------------------------------------------------------------------------------------------------


def quat_to_matrix(q_wxyz: Sequence[float]) -> np.ndarray:
    """R (3, 3) rotating body FLU vectors into world ENU, from q = (w, x, y, z); q is normalised first."""
    return np.array(quat_to_rows(quat_normalize(tuple(float(v) for v in q_wxyz)))).reshape(3, 3)


def matrix_to_quat(rotation: np.ndarray) -> np.ndarray:
    """Unit quaternion (w, x, y, z) with w >= 0 of a 3x3 rotation matrix."""
    return np.array(rows_to_quat(*np.asarray(rotation, dtype=float).reshape(9).tolist()))


def hat(v: Sequence[float]) -> np.ndarray:
    """The skew-symmetric matrix with hat(v) @ u = v x u."""
    x, y, z = (float(c) for c in v)
    return np.array([[0.0, -z, y], [z, 0.0, -x], [-y, x, 0.0]])


def vee(m: np.ndarray) -> np.ndarray:
    """Inverse of hat: the vector of a skew-symmetric 3x3 matrix (reads the lower triangle)."""
    return np.array([m[2, 1], m[0, 2], m[1, 0]], dtype=float)


def rot_x(angle_rad: float) -> np.ndarray:
    """Rotation by angle_rad about +x (right-handed)."""
    c, s = math.cos(angle_rad), math.sin(angle_rad)
    return np.array([[1.0, 0.0, 0.0], [0.0, c, -s], [0.0, s, c]])


def rot_y(angle_rad: float) -> np.ndarray:
    """Rotation by angle_rad about +y (right-handed). In FLU, positive = nose down."""
    c, s = math.cos(angle_rad), math.sin(angle_rad)
    return np.array([[c, 0.0, s], [0.0, 1.0, 0.0], [-s, 0.0, c]])


def rot_z(angle_rad: float) -> np.ndarray:
    """Rotation by angle_rad about +z (right-handed): yaw, counter-clockwise seen from above."""
    c, s = math.cos(angle_rad), math.sin(angle_rad)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def quat_exp_rows(rotvec: np.ndarray) -> np.ndarray:
    """(N, 4) rows (w, x, y, z) = Exp of (N, 3) rotation vectors (rad); first order below 1e-12 rad."""
    angle = np.linalg.norm(rotvec, axis=1, keepdims=True)
    small = angle < _NEGLIGIBLE_ANGLE_RAD
    safe = np.where(small, 1.0, angle)
    scale = np.where(small, 0.5, np.sin(0.5 * safe) / safe)
    return np.hstack([np.where(small, 1.0, np.cos(0.5 * safe)), rotvec * scale])


def roll_pitch_yaw_deg(q_wxyz: np.ndarray) -> np.ndarray:
    """(N, 4) quaternions (w, x, y, z) -> (N, 3) roll, pitch, yaw (deg, ZYX); NaN or zero rows give NaN."""
    q_wxyz = np.asarray(q_wxyz, dtype=float).reshape(-1, 4)
    out = np.full((len(q_wxyz), 3), np.nan)
    norm = np.linalg.norm(q_wxyz, axis=1)
    ok = np.isfinite(norm) & (norm > 0)
    if ok.any():
        q = q_wxyz[ok] / norm[ok, None]
        w, x, y, z = q[:, 0], q[:, 1], q[:, 2], q[:, 3]
        roll = np.arctan2(2.0 * (w * x + y * z), 1.0 - 2.0 * (x * x + y * y))
        pitch = np.arcsin(np.clip(2.0 * (w * y - z * x), -1.0, 1.0))
        yaw = np.arctan2(2.0 * (w * z + x * y), 1.0 - 2.0 * (y * y + z * z))
        out[ok] = np.degrees(np.column_stack([roll, pitch, yaw]))
    return out
