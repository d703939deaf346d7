"""The ESKF's per-sample propagation (estimator.eskf's module docstring has the equations), in Python and
compiled.

Takes in: the nominal state x (16 floats: p ENU m, v ENU m/s, q wxyz body FLU -> world ENU, b_a FLU m/s^2,
b_g FLU rad/s), the IMU signal at both ends of an interval (f0, w0, f1, w1: specific force FLU m/s^2 and
rate FLU rad/s, 3 floats each), its length dt (s), gravity g (m/s^2), and optionally F - a writable
C-contiguous (15, 15) float64 array holding the identity - with the flat indices (int64,
TRANSITION_ENTRIES of them) its other entries go to.
Gives out: propagate -> the nominal state after dt (16 floats), and the first-order error transition over
dt written into F.

`propagate` is the compiled twin (estimator/_eskf_kernels.c, built by `pip install`) when it was built, else
`propagate_python` below. They give the same bits (tests/estimator/test_eskf_kernels.py): the C file repeats
each expression in the same order, one IEEE operation at a time. Why compiled: this is the estimator's
hot path, once per IMU sample and again for every sample a late mocap frame replays (issue 19); the
Python twin costs 6.5 us per sample with F, the compiled one 1.0 us, the identity's copy included (medians
of 5 x 20000 calls, one throwaway timing). Why C and not numba: importing numba took 0.22-0.33 s and
loading one tiny cached function 0.30-0.64 s per process here (README: Lockstep speed), more than a flight's
propagation costs in all; this module loads in 0.2 ms.
"""

from __future__ import annotations

import numpy as np

from model.frames import quat_exp, quat_multiply, quat_normalize_positive_w, quat_to_rows, rotate

TRANSITION_ENTRIES = 48  # entries of F other than its unit diagonal


def propagate_python(x: tuple, f0, w0, f1, w1, dt: float, g: float, F: np.ndarray | None,
                     index: np.ndarray | None) -> tuple:
    """Trapezoidal nominal step over dt, and (given F) F's entries at `index`; the reference twin."""
    px, py, pz, vx, vy, vz, qw, qx, qy, qz, bax, bay, baz, bgx, bgy, bgz = x
    wx = 0.5 * (w0[0] + w1[0]) - bgx
    wy = 0.5 * (w0[1] + w1[1]) - bgy
    wz = 0.5 * (w0[2] + w1[2]) - bgz
    q0 = (qw, qx, qy, qz)
    r0 = quat_to_rows(q0)
    q1 = quat_normalize_positive_w(quat_multiply(q0, quat_exp(wx * dt, wy * dt, wz * dt)))
    a0 = rotate(r0, f0[0] - bax, f0[1] - bay, f0[2] - baz)
    a1 = rotate(quat_to_rows(q1), f1[0] - bax, f1[1] - bay, f1[2] - baz)
    ax = 0.5 * (a0[0] + a1[0])
    ay = 0.5 * (a0[1] + a1[1])
    az = 0.5 * (a0[2] + a1[2]) - g
    half_dt2 = 0.5 * dt * dt
    x1 = (px + vx * dt + ax * half_dt2, py + vy * dt + ay * half_dt2, pz + vz * dt + az * half_dt2,
          vx + ax * dt, vy + ay * dt, vz + az * dt, *q1, bax, bay, baz, bgx, bgy, bgz)
    if F is not None:
        f = (0.5 * (f0[0] + f1[0]) - bax, 0.5 * (f0[1] + f1[1]) - bay, 0.5 * (f0[2] + f1[2]) - baz)
        F.put(index, transition_values(r0, f, (wx, wy, wz), dt))
    return x1


def transition_values(r: tuple, f: tuple, w: tuple, dt: float) -> tuple:
    """F's entries other than its unit diagonal, in estimator.eskf._F_INDEX's order.

    r: R(q0) row-major; f: bias-corrected specific force FLU; w: bias-corrected rate FLU.
    """
    fx, fy, fz = f
    r0, r1, r2, r3, r4, r5, r6, r7, r8 = r
    # M = R [f]x, row by row
    m0, m1, m2 = r1 * fz - r2 * fy, r2 * fx - r0 * fz, r0 * fy - r1 * fx
    m3, m4, m5 = r4 * fz - r5 * fy, r5 * fx - r3 * fz, r3 * fy - r4 * fx
    m6, m7, m8 = r7 * fz - r8 * fy, r8 * fx - r6 * fz, r6 * fy - r7 * fx
    h, k = -0.5 * dt * dt, -dt
    wx, wy, wz = w[0] * dt, w[1] * dt, w[2] * dt
    return (
        dt, dt, dt,  # dp <- dv: I dt
        h * m0, h * m1, h * m2, h * r0, h * r1, h * r2,  # dp <- dtheta: -R[f]x dt^2/2, db_a: -R dt^2/2
        h * m3, h * m4, h * m5, h * r3, h * r4, h * r5,
        h * m6, h * m7, h * m8, h * r6, h * r7, h * r8,
        k * m0, k * m1, k * m2, k * r0, k * r1, k * r2,  # dv <- dtheta: -R[f]x dt, db_a: -R dt
        k * m3, k * m4, k * m5, k * r3, k * r4, k * r5,
        k * m6, k * m7, k * m8, k * r6, k * r7, k * r8,
        wz, -wy, -wz, wx, wy, -wx,  # dtheta <- dtheta off the diagonal: -[w dt]x
        k, k, k,  # dtheta <- db_g: -I dt
    )


try:
    from estimator._eskf_kernels import propagate as propagate_compiled
except ImportError:  # not built (no C compiler at install): the Python twin, same results, slower
    propagate_compiled = None

propagate = propagate_compiled if propagate_compiled is not None else propagate_python
COMPILED = propagate_compiled is not None
