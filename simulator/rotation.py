"""Small quaternion helpers on plain floats for the emulator's 1 kHz inner loops.

Takes in: quaternions (w, x, y, z) rotating body FLU vectors into world ENU, 3-vectors, angles in rad.
Gives out: norms, yaw and Euler conversions, rotation angles, as tuples of floats.

Why not scipy.spatial.transform.Rotation: it costs tens of microseconds per call on one rotation,
and the emulator's budget is < 50 us for a whole physics step; the tests check these helpers against
scipy. The basics shared with every package (product, conjugate, R(q)) are in link.rotation.
"""

from __future__ import annotations

import math

from link.rotation import Quat

Vec3 = tuple[float, float, float]

IDENTITY: Quat = (1.0, 0.0, 0.0, 0.0)


def quat_norm(q: Quat) -> float:
    return math.sqrt(q[0] * q[0] + q[1] * q[1] + q[2] * q[2] + q[3] * q[3])


def quat_normalize(q: Quat) -> Quat:
    n = quat_norm(q)
    return (q[0] / n, q[1] / n, q[2] / n, q[3] / n)


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
    """q = Rz(yaw) Ry(pitch) Rx(roll), the aerospace ZYX convention (body FLU, world ENU)."""
    cr, sr = math.cos(0.5 * roll_rad), math.sin(0.5 * roll_rad)
    cp, sp = math.cos(0.5 * pitch_rad), math.sin(0.5 * pitch_rad)
    cy, sy = math.cos(0.5 * yaw_rad), math.sin(0.5 * yaw_rad)
    return (
        cr * cp * cy + sr * sp * sy,
        sr * cp * cy - cr * sp * sy,
        cr * sp * cy + sr * cp * sy,
        cr * cp * sy - sr * sp * cy,
    )


def rotation_angle_between(a: Quat, b: Quat) -> float:
    """Angle (rad, 0..pi) of the rotation taking attitude a to attitude b."""
    dw = abs(a[0] * b[0] + a[1] * b[1] + a[2] * b[2] + a[3] * b[3]) / (quat_norm(a) * quat_norm(b))
    return 2.0 * math.acos(min(1.0, dw))
