"""Quaternion basics shared by every package (the frame conventions of link.messages live here too).

Takes in / gives out: plain-float quaternions (w, x, y, z) rotating body FLU into world ENU, and
row-major 3x3 rotation matrices as 9-tuples. Plain floats, not numpy: these run in 500 Hz-1 kHz loops,
where a numpy call on a 4-vector costs more than the arithmetic.
"""

from __future__ import annotations

Quat = tuple[float, float, float, float]
Mat9 = tuple[float, float, float, float, float, float, float, float, float]


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


def quat_to_matrix(q: Quat) -> Mat9:
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
