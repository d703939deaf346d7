"""The rigid body's RK4 step (simulator.dynamics' module docstring has the equations) and the rotors' lag, in
Python and compiled.

Takes in: the state x (13 floats: position ENU m, velocity ENU m/s, attitude wxyz body FLU -> world ENU,
body rates FLU rad/s), the wrench terms u = (T/m m/s^2, Mx/Ixx, My/Iyy, Mz/Izz rad/s^2, drag/m 1/s) at the
step's start, middle and end (u0, um, u1), the step's constants steps = (h, h/2, h/4, h/6, h/12, h^2/6) (s, s^2)
and gyro = ((Izz - Iyy)/Ixx, (Ixx - Izz)/Iyy, (Iyy - Ixx)/Izz); gravity is model.vehicle.GRAVITY_MPS2.
Gives out: rk4 -> the state after the step, a new list of 13 floats (the quaternion renormalised).
For the rotors: rotor speeds w (4 floats, rad/s), and the body's coefficients `coeffs` (ROTOR_COEFFS floats:
the allocation matrix's 16 entries row by row (N and N m per (rad/s)^2), mass kg, Ixx, Iyy, Izz kg m^2, the
rotor drag per rad/s of summed rotor speed, kg/s per rad/s). rotor_inputs -> (T N, the wrench terms u);
rotor_lag -> None when a step of the first-order lag leaves w as it is, else (w at the step's end, a new
list; T there; u at the step's middle and end).

`rk4`, `rotor_inputs` and `rotor_lag` are the compiled twins (simulator/_dynamics_kernels.c, built by `pip
install`) when they were built, else the `*_python` functions below. They give the same bits
(tests/simulator/test_dynamics_kernels.py): the C file repeats each expression in the same order, one IEEE
operation at a time. Why compiled: they run once per physics step (1 kHz of simulated time, per vehicle).
The RK4 twin took 4.5 us per call (one throwaway timing, warm) of a faithful vehicle's 21-25 us step, and
the lag's Python took 3-4 us per step more than a vehicle without lag (README: Lockstep speed).
"""

from __future__ import annotations

import math

from model.frames import Vec3
from model.vehicle import GRAVITY_MPS2


def rk4_python(x: list, u0: tuple, um: tuple, u1: tuple, steps: tuple, gyro: tuple) -> list:
    """One classical RK4 step of the module docstring's equations, written out on local floats.

    Stage i evaluates the derivatives at its attitude q_i, rates w_i and velocity v_i, with the
    inputs u = (T/m, M/I, drag/m) at the start (stage 1), middle (2, 3) or end (4) of the step:
        a_i = T/m R(q_i) e3 - g e3 (+ drag)                        (v')
        p_i = Omega(w_i) q_i = (0, w_i) (x) q_i... as q (x) (0, w_i), q' = p / 2
        e_i = M/I - c * (w_y w_z, w_z w_x, w_x w_y),  c = ((Izz - Iyy)/Ixx, (Ixx - Izz)/Iyy, (Iyy - Ixx)/Izz)
    then x_{n+1} = x_n + h/6 (k1 + 2 k2 + 2 k3 + k4). Position's stage derivatives are the stage
    velocities v, v + h/2 a1, v + h/2 a2, v + h a3, so its update folds to h v + h^2/6 (a1 + a2 + a3).
    The quaternion is renormalised after the step (RK4 keeps |q| = 1 only to O(h^5)).
    The scalar part of p is carried negated (n = -p_w) to save a negation per stage.
    """
    h, h2, hq, h6, h12, hh6 = steps
    cx, cy, cz = gyro
    px, py, pz, vx, vy, vz, qw, qx, qy, qz, wx, wy, wz = x
    # stage 1 at the start
    tm, ex, ey, ez, dm = u0
    t2, tg = 2.0 * tm, tm - GRAVITY_MPS2  # T/m R e3 - g e3 = (t2 (xz + wy), t2 (yz - wx), tg - t2 (x^2 + y^2))
    a1x = t2 * (qx * qz + qw * qy)
    a1y = t2 * (qy * qz - qw * qx)
    a1z = tg - t2 * (qx * qx + qy * qy)
    if dm != 0.0:
        dx, dy, dz = drag_world(qw, qx, qy, qz, vx, vy, vz, dm)
        a1x, a1y, a1z = a1x + dx, a1y + dy, a1z + dz
    n1 = qx * wx + qy * wy + qz * wz
    p1x = qw * wx + qy * wz - qz * wy
    p1y = qw * wy - qx * wz + qz * wx
    p1z = qw * wz + qx * wy - qy * wx
    e1x = ex - cx * wy * wz
    e1y = ey - cy * wz * wx
    e1z = ez - cz * wx * wy
    # stage 2 at the middle, from stage 1's slopes
    if um is not u0:
        tm, ex, ey, ez, dm = um
        t2, tg = 2.0 * tm, tm - GRAVITY_MPS2
    sw, sx, sy, sz = qw - hq * n1, qx + hq * p1x, qy + hq * p1y, qz + hq * p1z
    rx, ry, rz = wx + h2 * e1x, wy + h2 * e1y, wz + h2 * e1z
    a2x = t2 * (sx * sz + sw * sy)
    a2y = t2 * (sy * sz - sw * sx)
    a2z = tg - t2 * (sx * sx + sy * sy)
    if dm != 0.0:
        dx, dy, dz = drag_world(sw, sx, sy, sz, vx + h2 * a1x, vy + h2 * a1y, vz + h2 * a1z, dm)
        a2x, a2y, a2z = a2x + dx, a2y + dy, a2z + dz
    n2 = sx * rx + sy * ry + sz * rz
    p2x = sw * rx + sy * rz - sz * ry
    p2y = sw * ry - sx * rz + sz * rx
    p2z = sw * rz + sx * ry - sy * rx
    e2x = ex - cx * ry * rz
    e2y = ey - cy * rz * rx
    e2z = ez - cz * rx * ry
    # stage 3 at the middle, from stage 2's slopes
    sw, sx, sy, sz = qw - hq * n2, qx + hq * p2x, qy + hq * p2y, qz + hq * p2z
    rx, ry, rz = wx + h2 * e2x, wy + h2 * e2y, wz + h2 * e2z
    a3x = t2 * (sx * sz + sw * sy)
    a3y = t2 * (sy * sz - sw * sx)
    a3z = tg - t2 * (sx * sx + sy * sy)
    if dm != 0.0:
        dx, dy, dz = drag_world(sw, sx, sy, sz, vx + h2 * a2x, vy + h2 * a2y, vz + h2 * a2z, dm)
        a3x, a3y, a3z = a3x + dx, a3y + dy, a3z + dz
    n3 = sx * rx + sy * ry + sz * rz
    p3x = sw * rx + sy * rz - sz * ry
    p3y = sw * ry - sx * rz + sz * rx
    p3z = sw * rz + sx * ry - sy * rx
    e3x = ex - cx * ry * rz
    e3y = ey - cy * rz * rx
    e3z = ez - cz * rx * ry
    # stage 4 at the end, from stage 3's slopes (q + h q' = q + h/2 p)
    if u1 is not um:
        tm, ex, ey, ez, dm = u1
        t2, tg = 2.0 * tm, tm - GRAVITY_MPS2
    sw, sx, sy, sz = qw - h2 * n3, qx + h2 * p3x, qy + h2 * p3y, qz + h2 * p3z
    rx, ry, rz = wx + h * e3x, wy + h * e3y, wz + h * e3z
    a4x = t2 * (sx * sz + sw * sy)
    a4y = t2 * (sy * sz - sw * sx)
    a4z = tg - t2 * (sx * sx + sy * sy)
    if dm != 0.0:
        dx, dy, dz = drag_world(sw, sx, sy, sz, vx + h * a3x, vy + h * a3y, vz + h * a3z, dm)
        a4x, a4y, a4z = a4x + dx, a4y + dy, a4z + dz
    n4 = sx * rx + sy * ry + sz * rz
    p4x = sw * rx + sy * rz - sz * ry
    p4y = sw * ry - sx * rz + sz * rx
    p4z = sw * rz + sx * ry - sy * rx
    e4x = ex - cx * ry * rz
    e4y = ey - cy * rz * rx
    e4z = ez - cz * rx * ry
    # combine; q' = p / 2, so q takes h/12 of the p's
    qw -= h12 * (n1 + 2.0 * (n2 + n3) + n4)
    qx += h12 * (p1x + 2.0 * (p2x + p3x) + p4x)
    qy += h12 * (p1y + 2.0 * (p2y + p3y) + p4y)
    qz += h12 * (p1z + 2.0 * (p2z + p3z) + p4z)
    k = 1.0 / math.sqrt(qw * qw + qx * qx + qy * qy + qz * qz)
    sx, sy, sz = a1x + a2x + a3x, a1y + a2y + a3y, a1z + a2z + a3z  # a1 + 2 a2 + 2 a3 + a4 = s + a2 + a3 + a4
    return [
        px + h * vx + hh6 * sx,
        py + h * vy + hh6 * sy,
        pz + h * vz + hh6 * sz,
        vx + h6 * (sx + a2x + a3x + a4x),
        vy + h6 * (sy + a2y + a3y + a4y),
        vz + h6 * (sz + a2z + a3z + a4z),
        qw * k, qx * k, qy * k, qz * k,
        wx + h6 * (e1x + 2.0 * (e2x + e3x) + e4x),
        wy + h6 * (e1y + 2.0 * (e2y + e3y) + e4y),
        wz + h6 * (e1z + 2.0 * (e2z + e3z) + e4z),
    ]


def drag_world(qw: float, qx: float, qy: float, qz: float, vx: float, vy: float, vz: float,
                drag_m: float) -> Vec3:
    """Rotor drag acceleration in world ENU: R(q) (-d v_body_x, -d v_body_y, 0) for drag d = c sum(w) / m."""
    vbx, vby, _ = world_to_body(qw, qx, qy, qz, vx, vy, vz)
    fx, fy = -drag_m * vbx, -drag_m * vby
    return ((1.0 - 2.0 * (qy * qy + qz * qz)) * fx + 2.0 * (qx * qy - qw * qz) * fy,
            2.0 * (qx * qy + qw * qz) * fx + (1.0 - 2.0 * (qx * qx + qz * qz)) * fy,
            2.0 * (qx * qz - qw * qy) * fx + 2.0 * (qy * qz + qw * qx) * fy)


def world_to_body(qw: float, qx: float, qy: float, qz: float, vx: float, vy: float, vz: float) -> Vec3:
    """R(q)^T v for a unit quaternion, written out (the rows of R^T are the columns of R)."""
    return (
        (1.0 - 2.0 * (qy * qy + qz * qz)) * vx + 2.0 * (qx * qy + qw * qz) * vy
        + 2.0 * (qx * qz - qw * qy) * vz,
        2.0 * (qx * qy - qw * qz) * vx + (1.0 - 2.0 * (qx * qx + qz * qz)) * vy
        + 2.0 * (qy * qz + qw * qx) * vz,
        2.0 * (qx * qz + qw * qy) * vx + 2.0 * (qy * qz - qw * qx) * vy
        + (1.0 - 2.0 * (qx * qx + qy * qy)) * vz,
    )


ROTOR_COEFFS = 21  # 16 allocation entries, mass, Ixx, Iyy, Izz, drag per rad/s


def rotor_coeffs(allocation, mass_kg: float, inertia_diag_kgm2, drag_per_radps: float) -> tuple[float, ...]:
    """The coefficients rotor_inputs and rotor_lag take, as floats in their order."""
    return (*(float(v) for row in allocation for v in row), float(mass_kg),
            *(float(v) for v in inertia_diag_kgm2), float(drag_per_radps))


def rotor_inputs_python(w, coeffs: tuple) -> tuple[float, tuple[float, float, float, float, float]]:
    """T (N), and (T/m, Mx/Ixx, My/Iyy, Mz/Izz, drag/m) for rotor speeds w: what the integrator takes.
    Each force or moment is its allocation row times the squared speeds, summed in rotor order."""
    s0, s1, s2, s3 = w[0] * w[0], w[1] * w[1], w[2] * w[2], w[3] * w[3]
    (a00, a01, a02, a03, a10, a11, a12, a13, a20, a21, a22, a23, a30, a31, a32, a33,
     mass, ixx, iyy, izz, drag) = coeffs
    thrust = a00 * s0 + a01 * s1 + a02 * s2 + a03 * s3
    return thrust, (thrust / mass,
                    (a10 * s0 + a11 * s1 + a12 * s2 + a13 * s3) / ixx,
                    (a20 * s0 + a21 * s1 + a22 * s2 + a23 * s3) / iyy,
                    (a30 * s0 + a31 * s1 + a32 * s2 + a33 * s3) / izz,
                    drag * (w[0] + w[1] + w[2] + w[3]) / mass)


def rotor_lag_python(w: list, cmd: list, decay_half: float, decay_full: float, coeffs: tuple):
    """One step of each rotor's first-order lag toward its command, w(t) = c + (w0 - c) exp(-t / tau) (the
    decays exp(-h / 2 tau) and exp(-h / tau) are given): None if the step leaves every speed as it is (the
    wrench is unchanged), else (w at the end, T there, u at the middle, u at the end)."""
    w_end = [c + (s - c) * decay_full for s, c in zip(w, cmd, strict=True)]
    if w_end == w:
        return None
    um = rotor_inputs_python([c + (s - c) * decay_half for s, c in zip(w, cmd, strict=True)], coeffs)[1]
    thrust, u1 = rotor_inputs_python(w_end, coeffs)
    return w_end, thrust, um, u1


try:
    from simulator._dynamics_kernels import rk4 as rk4_compiled
    from simulator._dynamics_kernels import rotor_inputs as rotor_inputs_compiled
    from simulator._dynamics_kernels import rotor_lag as rotor_lag_compiled
except ImportError:  # not built (no C compiler at install): the Python twins, same results, slower
    rk4_compiled = rotor_inputs_compiled = rotor_lag_compiled = None

COMPILED = rk4_compiled is not None
rk4 = rk4_compiled if COMPILED else rk4_python
rotor_inputs = rotor_inputs_compiled if COMPILED else rotor_inputs_python
rotor_lag = rotor_lag_compiled if COMPILED else rotor_lag_python
