"""Rotation helpers for the ground station: quaternion <-> rotation matrix, hat/vee, elementary rotations.

Takes in: quaternions (w, x, y, z) rotating body FLU vectors into world ENU, 3x3 rotation matrices,
3-vectors, angles in rad.
Gives out: the same objects converted. Two flavours of each conversion:
  - numpy: `quat_to_matrix`, `matrix_to_quat`, `hat`, `vee`, `rot_x/y/z` (for analysis and tests);
  - plain floats: `quat_to_rows` / `rows_to_quat` on 9-tuples (row-major), for the 500 Hz controller,
    where building small numpy arrays costs more than the arithmetic itself.
The numpy versions are built on the float ones so there is one implementation of each formula.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np

from link.rotation import quat_to_matrix as rows_of_unit_quat

Rows = tuple[float, float, float, float, float, float, float, float, float]


def quat_to_rows(w: float, x: float, y: float, z: float) -> Rows:
    """Row-major entries of R(q) for a quaternion q = (w, x, y, z); q is normalised first."""
    n = math.sqrt(w * w + x * x + y * y + z * z)
    return rows_of_unit_quat((w / n, x / n, y / n, z / n))


def rows_to_quat(r00: float, r01: float, r02: float, r10: float, r11: float, r12: float,
                 r20: float, r21: float, r22: float) -> tuple[float, float, float, float]:
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
    w, x, y, z = q
    n = math.sqrt(w * w + x * x + y * y + z * z)
    if w < 0.0:  # q and -q are the same rotation; report the w >= 0 one
        n = -n
    return (w / n, x / n, y / n, z / n)


def quat_to_matrix(q_wxyz: Sequence[float]) -> np.ndarray:
    """R (3, 3) rotating body FLU vectors into world ENU, from q = (w, x, y, z)."""
    w, x, y, z = (float(v) for v in q_wxyz)
    return np.array(quat_to_rows(w, x, y, z)).reshape(3, 3)


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
