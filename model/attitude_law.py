"""The geometric attitude law, written once for the ground station's SE(3) controller and the emulator's
ideal firmware (Lee, Leok & McClamroch, "Geometric tracking control of a quadrotor UAV on SE(3)", CDC 2010;
the MEAM 620 lab report, section II).

Takes in: attitudes as unit quaternions (w, x, y, z) body FLU -> world ENU, body rates (rad/s, FLU),
diagonal gains K_R (1/s^2) and K_w (1/s), already normalised by the inertia as the lab report's gains are,
and the diagonal inertia (kg m^2).
Gives out: the attitude error e_R (dimensionless: sin of the angle for a one-axis error) and the body
moment (N m, FLU)
    M = I (-K_R e_R - K_w e_w + alpha_ff) + w x I w,     e_R = 1/2 vee(R_des^T R - R^T R_des),
where the feed-forward alpha_ff and the gyroscopic term w x I w are optional (the lab report flew
without both).
Plain floats: these run at 500 Hz-1 kHz, where numpy on 3-vectors costs more than the arithmetic.
"""

from __future__ import annotations

from model.frames import Quat, Vec3


def attitude_error(q_des: Quat, q: Quat) -> Vec3:
    """e_R = 1/2 vee(R_des^T R - R^T R_des), computed as 2 q_e,w q_e,xyz with q_e = q_des^* (x) q
    (the same vector: for q_e = (cos a/2, sin a/2 n), 2 cos(a/2) sin(a/2) n = sin(a) n)."""
    a0, a1, a2, a3 = q_des
    q0, q1, q2, q3 = q
    s = 2.0 * (a0 * q0 + a1 * q1 + a2 * q2 + a3 * q3)
    return (
        s * (a0 * q1 - a1 * q0 - a2 * q3 + a3 * q2),
        s * (a0 * q2 + a1 * q3 - a2 * q0 - a3 * q1),
        s * (a0 * q3 - a1 * q2 + a2 * q1 - a3 * q0),
    )


def attitude_moment(e_r: Vec3, e_w: Vec3, k_r: Vec3, k_w: Vec3, inertia_diag_kgm2: Vec3,
                    w_flu_radps: Vec3 | None = None, alpha_ff_radps2: Vec3 | None = None) -> Vec3:
    """M = I (-K_R e_R - K_w e_w [+ alpha_ff]) [+ w x I w] in N m (body FLU, diagonal I).

    e_w = w - w_des in the body frame (rad/s). The gyroscopic term is added when w_flu_radps is given.
    """
    ex, ey, ez = e_r
    ewx, ewy, ewz = e_w
    krx, kry, krz = k_r
    kwx, kwy, kwz = k_w
    ax = -krx * ex - kwx * ewx
    ay = -kry * ey - kwy * ewy
    az = -krz * ez - kwz * ewz
    if alpha_ff_radps2 is not None:
        ax, ay, az = ax + alpha_ff_radps2[0], ay + alpha_ff_radps2[1], az + alpha_ff_radps2[2]
    ixx, iyy, izz = inertia_diag_kgm2
    if w_flu_radps is None:
        return (ixx * ax, iyy * ay, izz * az)
    wx, wy, wz = w_flu_radps
    return (
        ixx * ax + (izz - iyy) * wy * wz,
        iyy * ay + (ixx - izz) * wz * wx,
        izz * az + (iyy - ixx) * wx * wy,
    )
