"""The ESKF's per-sample propagation and its covariance algebra (estimator.eskf's module docstring has the
equations), in Python and compiled.

Takes in: for propagate, the nominal state x (16 floats: p ENU m, v ENU m/s, q wxyz body FLU -> world ENU,
b_a FLU m/s^2, b_g FLU rad/s), the IMU signal at both ends of an interval (f0, w0, f1, w1: specific force
FLU m/s^2 and rate FLU rad/s, 3 floats each), its length dt (s), gravity g (m/s^2), and optionally F - a
writable C-contiguous (15, 15) float64 array holding the identity - with the flat indices (int64,
TRANSITION_ENTRIES of them) its other entries go to. For the covariance kernels, C-contiguous float64
arrays: the 15x15 error covariance P (error state order of estimator.eskf.ERROR_STATE_LABELS), the
transition F and process noise Q; the mocap residual z (6: position ENU m, attitude error rad), R's
diagonal r (m^2, rad^2) and the 6 states the frame measures; an attitude correction dtheta (rad).
Gives out: propagate -> the nominal state after dt (16 floats), and the first-order error transition over
dt written into F; predict_covariance -> F P F' + Q; update_covariance -> the Joseph-form posterior P,
the posterior error state dx and the gate's d^2 (NaN when S is not positive definite);
reset_covariance -> G P G'; multiply -> A B. Each writes into the `out` arrays it is given.

Each function is the compiled twin (estimator/_eskf_kernels.c, built by `pip install`) when it was built,
else its `*_python` twin below. They give the same bits (tests/estimator/test_eskf_kernels.py): the C file
repeats each expression in the same order, one IEEE operation at a time. The covariance kernels sum in
index order and use no BLAS, so their bits are the same on every CPU (see the section below). Why
compiled: this is the estimator's hot path, once per IMU sample and again for every sample a late mocap
frame replays (issue 19). The Python twin of propagate costs 6.5 us per sample with F, the compiled one
1.0 us, the identity's copy included (medians of 5 x 20000 calls, one throwaway timing). The covariance
twins cost 42 (predict), 103 (update) and 21 us (reset) per call, the compiled ones 1.4, 1.8 and 0.3 us
(one throwaway timing, 20000 calls each), where numpy's BLAS predict took 2.4 us. Why C and not numba:
importing numba took 0.22-0.33 s and loading one tiny cached function 0.30-0.64 s per process here
(README: Lockstep speed), more than a flight's propagation costs in all; this module loads in 0.2 ms.
"""

from __future__ import annotations

import math

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


# ------------------------------------------------------------------ covariance algebra
# The Kalman steps on the 15x15 error covariance, written as fixed-order sums so that they give the same bits
# on every machine: numpy's matrix products go to BLAS, whose kernel (chosen per CPU at run time) sets the
# order of each sum and whether it fuses multiply-adds, and with it the last bits of every estimate. Each
# sum below runs in index order from its first term; each symmetric result is computed on and above the
# diagonal and copied below it (exactly symmetric). The twins use elementwise numpy operations only
# (one IEEE rounding per element, the same on every CPU) and np.add.accumulate, which adds in order.

_UPPER = np.triu(np.ones((15, 15), dtype=bool))


def _ordered_product(A: np.ndarray, B: np.ndarray) -> np.ndarray:
    """A B with each entry summed over k = 0, 1, ... in order: A[i,0] B[0,j] + A[i,1] B[1,j] + ..."""
    return np.add.accumulate(A[:, :, None] * B[None, :, :], axis=1)[:, -1, :]


def _mirror_upper(M: np.ndarray) -> np.ndarray:
    return np.where(_UPPER, M, M.T)


def predict_covariance_python(P: np.ndarray, F: np.ndarray, Q: np.ndarray, out: np.ndarray) -> None:
    """out = F P F' + Q (the predict): M = F P, then (M F')[i, j] + Q[i, j] for j >= i, mirrored."""
    M = _ordered_product(F, P)
    out[...] = _mirror_upper(_ordered_product(M, F.T) + Q)


def cholesky_python(S: list) -> list | None:
    """Lower Cholesky factor of a symmetric n x n S (lists of rows); None if S is not positive definite."""
    n = len(S)
    L = [[0.0] * n for _ in range(n)]
    for j in range(n):
        d = S[j][j]
        for k in range(j):
            d = d - L[j][k] * L[j][k]
        if not d > 0.0:
            return None
        ljj = math.sqrt(d)
        L[j][j] = ljj
        for i in range(j + 1, n):
            acc = S[i][j]
            for k in range(j):
                acc = acc - L[i][k] * L[j][k]
            L[i][j] = acc / ljj
    return L


def update_covariance_python(P: np.ndarray, z, r, index, P_out: np.ndarray, dx_out: np.ndarray) -> float:
    """The Kalman update with H selecting the states `index` (6 of the 15) and R = diag(r).

    S = H P H' + R by its Cholesky factor L; K = P H' S^-1 as the solution X = K' of S X = H P' (forward with
    L, back with L'); d^2 = y' S^-1 y as |L^-1 z|^2 (never negative); dx = K z (the prior error state is 0,
    so y = z); Joseph form P_out = (I - K H) P (I - K H)' + K R K'. Returns d^2, or NaN with the outputs
    untouched when S is not positive definite.
    """
    sel = [int(i) for i in index]
    z = [float(v) for v in z]
    r = [float(v) for v in r]
    S = [[float(P[a, b]) + (r[m] if m == n else 0.0) for n, b in enumerate(sel)] for m, a in enumerate(sel)]
    L = cholesky_python(S)
    if L is None:
        return math.nan
    B = np.concatenate((P[:, sel].T, np.array(z)[:, None]), axis=1)  # 6 x 16
    W = [None] * 6
    for m in range(6):
        acc = B[m]
        for k in range(m):
            acc = acc - L[m][k] * W[k]
        W[m] = acc / L[m][m]
    X = [None] * 6
    for m in range(5, -1, -1):
        acc = W[m]
        for k in range(m + 1, 6):
            acc = acc - L[k][m] * X[k]
        X[m] = acc / L[m][m]
    d2 = W[0][15] * W[0][15]
    for m in range(1, 6):
        d2 = d2 + W[m][15] * W[m][15]
    K = [X[m][:15] for m in range(6)]  # K's columns
    dx = K[0] * z[0]
    for m in range(1, 6):
        dx = dx + K[m] * z[m]
    A = P
    for m in range(6):
        A = A - K[m][:, None] * P[sel[m]][None, :]
    joseph = A
    for m in range(6):
        joseph = joseph - A[:, sel[m]][:, None] * K[m][None, :]
    krk = (K[0] * r[0])[:, None] * K[0][None, :]
    for m in range(1, 6):
        krk = krk + (K[m] * r[m])[:, None] * K[m][None, :]
    P_out[...] = _mirror_upper(joseph + krk)
    dx_out[...] = dx
    return float(d2)


def reset_covariance_python(P: np.ndarray, dtheta, out: np.ndarray) -> None:
    """out = G P G' with G the identity but G_theta = I - [dtheta/2]x on the attitude rows and columns 6..8
    (the ESKF reset, Sola 2017 eq. 287): only those rows and columns mix, each over its three terms."""
    hx, hy, hz = 0.5 * float(dtheta[0]), 0.5 * float(dtheta[1]), 0.5 * float(dtheta[2])
    G = ((1.0, hz, -hy), (-hz, 1.0, hx), (hy, -hx, 1.0))
    C = P.copy()
    for a in range(3):
        C[6 + a] = G[a][0] * P[6] + G[a][1] * P[7] + G[a][2] * P[8]
    result = C.copy()
    for a in range(3):
        result[:, 6 + a] = C[:, 6] * G[a][0] + C[:, 7] * G[a][1] + C[:, 8] * G[a][2]
    out[...] = _mirror_upper(result)


def multiply_python(A: np.ndarray, B: np.ndarray, out: np.ndarray) -> None:
    """out = A B, each entry summed in order (chains the sub-steps' transitions)."""
    out[...] = _ordered_product(A, B)


try:
    from estimator import _eskf_kernels as _compiled
except ImportError:  # not built (no C compiler at install): the Python twins, same results, slower
    _compiled = None

COMPILED = _compiled is not None
propagate = _compiled.propagate if COMPILED else propagate_python
predict_covariance = _compiled.predict_covariance if COMPILED else predict_covariance_python
update_covariance = _compiled.update_covariance if COMPILED else update_covariance_python
reset_covariance = _compiled.reset_covariance if COMPILED else reset_covariance_python
multiply = _compiled.multiply if COMPILED else multiply_python
