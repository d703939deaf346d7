/* Compiled twin of simulator/dynamics_kernels.py: the rigid body's RK4 step and the rotors' lag (issue 19).

rk4 takes in: the state x (13 floats: position ENU m, velocity ENU m/s, attitude wxyz, body rates FLU rad/s), the
wrench terms u = (T/m, Mx/Ixx, My/Iyy, Mz/Izz, drag/m) at the step's start, middle and end (u0, um, u1: 5
floats each), the step's constants (h, h/2, h/4, h/6, h/12, h^2/6) and the gyroscopic coefficients (3 floats).
Gives out: the state after the step, a new list of 13 floats.
rotor_inputs takes in: rotor speeds w (4 floats, rad/s) and the body's coefficients (ROTOR_COEFFS floats:
the allocation matrix row by row, mass kg, Ixx, Iyy, Izz kg m^2, drag per rad/s); gives out (T N, (T/m,
Mx/Ixx, My/Iyy, Mz/Izz, drag/m)). rotor_lag takes in: the rotor speeds w and commanded speeds (4 floats each,
rad/s), the decays over half a step and a whole one, the coefficients; gives out None when the step leaves
the speeds as they are, else (the speeds at the step's end, a new list; T there; the wrench terms at the
step's middle and end).
Gravity is model.vehicle.GRAVITY_MPS2, read once when the module loads.

Same result as the Python twin, bit for bit: every expression below is the Python one in the same order,
one IEEE double operation at a time (C and Python group + - * / alike, left to right; setup.py builds this
file with -ffp-contract=off, so no multiply-add is fused), and sqrt is correctly rounded in both.
The twin reads a middle or end wrench only when it is another object than the one before; the values are
the same either way, so this file always reads them. tests/simulator/test_dynamics_kernels.py checks the
bits against the twin. */

#include "../model/_kernels.h" /* includes Python.h; read_floats, read_module_float, float_tuple, float_list,
                                  check_nargs */
#include <math.h>

#define N_STATE 13
#define N_WRENCH 5
#define N_ROTORS 4
#define ROTOR_COEFFS 21 /* 16 allocation entries, mass, Ixx, Iyy, Izz, drag per rad/s */

static double gravity_mps2; /* model.vehicle.GRAVITY_MPS2 */

/* dynamics_kernels.drag_world: R(q) (-d v_body_x, -d v_body_y, 0), v_body = world_to_body(q, v) */
static void drag_world(double qw, double qx, double qy, double qz, double vx, double vy, double vz,
                       double drag_m, double out[3]) {
    double vbx = (1.0 - 2.0 * (qy * qy + qz * qz)) * vx + 2.0 * (qx * qy + qw * qz) * vy
                 + 2.0 * (qx * qz - qw * qy) * vz;
    double vby = 2.0 * (qx * qy - qw * qz) * vx + (1.0 - 2.0 * (qx * qx + qz * qz)) * vy
                 + 2.0 * (qy * qz + qw * qx) * vz;
    double fx = -drag_m * vbx, fy = -drag_m * vby;
    out[0] = (1.0 - 2.0 * (qy * qy + qz * qz)) * fx + 2.0 * (qx * qy - qw * qz) * fy;
    out[1] = 2.0 * (qx * qy + qw * qz) * fx + (1.0 - 2.0 * (qx * qx + qz * qz)) * fy;
    out[2] = 2.0 * (qx * qz - qw * qy) * fx + 2.0 * (qy * qz + qw * qx) * fy;
}

/* rk4(x, u0, um, u1, steps, gyro) -> list: dynamics_kernels.rk4 */
static PyObject *rk4(PyObject *self, PyObject *const *args, Py_ssize_t nargs) {
    (void)self;
    if (check_nargs("rk4", nargs, 6) < 0) return NULL;
    double x[N_STATE], u0[N_WRENCH], um[N_WRENCH], u1[N_WRENCH], steps[6], gyro[3];
    if (read_floats(args[0], x, N_STATE, "x") < 0 || read_floats(args[1], u0, N_WRENCH, "u0") < 0
        || read_floats(args[2], um, N_WRENCH, "um") < 0 || read_floats(args[3], u1, N_WRENCH, "u1") < 0
        || read_floats(args[4], steps, 6, "steps") < 0 || read_floats(args[5], gyro, 3, "gyro") < 0)
        return NULL;
    double h = steps[0], h2 = steps[1], hq = steps[2], h6 = steps[3], h12 = steps[4], hh6 = steps[5];
    double cx = gyro[0], cy = gyro[1], cz = gyro[2];
    double px = x[0], py = x[1], pz = x[2], vx = x[3], vy = x[4], vz = x[5];
    double qw = x[6], qx = x[7], qy = x[8], qz = x[9], wx = x[10], wy = x[11], wz = x[12];
    double d[3];

    /* stage 1 at the start */
    double tm = u0[0], ex = u0[1], ey = u0[2], ez = u0[3], dm = u0[4];
    double t2 = 2.0 * tm, tg = tm - gravity_mps2;
    double a1x = t2 * (qx * qz + qw * qy);
    double a1y = t2 * (qy * qz - qw * qx);
    double a1z = tg - t2 * (qx * qx + qy * qy);
    if (dm != 0.0) {
        drag_world(qw, qx, qy, qz, vx, vy, vz, dm, d);
        a1x = a1x + d[0]; a1y = a1y + d[1]; a1z = a1z + d[2];
    }
    double n1 = qx * wx + qy * wy + qz * wz;
    double p1x = qw * wx + qy * wz - qz * wy;
    double p1y = qw * wy - qx * wz + qz * wx;
    double p1z = qw * wz + qx * wy - qy * wx;
    double e1x = ex - cx * wy * wz;
    double e1y = ey - cy * wz * wx;
    double e1z = ez - cz * wx * wy;

    /* stage 2 at the middle, from stage 1's slopes */
    tm = um[0]; ex = um[1]; ey = um[2]; ez = um[3]; dm = um[4];
    t2 = 2.0 * tm; tg = tm - gravity_mps2;
    double sw = qw - hq * n1, sx = qx + hq * p1x, sy = qy + hq * p1y, sz = qz + hq * p1z;
    double rx = wx + h2 * e1x, ry = wy + h2 * e1y, rz = wz + h2 * e1z;
    double a2x = t2 * (sx * sz + sw * sy);
    double a2y = t2 * (sy * sz - sw * sx);
    double a2z = tg - t2 * (sx * sx + sy * sy);
    if (dm != 0.0) {
        drag_world(sw, sx, sy, sz, vx + h2 * a1x, vy + h2 * a1y, vz + h2 * a1z, dm, d);
        a2x = a2x + d[0]; a2y = a2y + d[1]; a2z = a2z + d[2];
    }
    double n2 = sx * rx + sy * ry + sz * rz;
    double p2x = sw * rx + sy * rz - sz * ry;
    double p2y = sw * ry - sx * rz + sz * rx;
    double p2z = sw * rz + sx * ry - sy * rx;
    double e2x = ex - cx * ry * rz;
    double e2y = ey - cy * rz * rx;
    double e2z = ez - cz * rx * ry;

    /* stage 3 at the middle, from stage 2's slopes */
    sw = qw - hq * n2; sx = qx + hq * p2x; sy = qy + hq * p2y; sz = qz + hq * p2z;
    rx = wx + h2 * e2x; ry = wy + h2 * e2y; rz = wz + h2 * e2z;
    double a3x = t2 * (sx * sz + sw * sy);
    double a3y = t2 * (sy * sz - sw * sx);
    double a3z = tg - t2 * (sx * sx + sy * sy);
    if (dm != 0.0) {
        drag_world(sw, sx, sy, sz, vx + h2 * a2x, vy + h2 * a2y, vz + h2 * a2z, dm, d);
        a3x = a3x + d[0]; a3y = a3y + d[1]; a3z = a3z + d[2];
    }
    double n3 = sx * rx + sy * ry + sz * rz;
    double p3x = sw * rx + sy * rz - sz * ry;
    double p3y = sw * ry - sx * rz + sz * rx;
    double p3z = sw * rz + sx * ry - sy * rx;
    double e3x = ex - cx * ry * rz;
    double e3y = ey - cy * rz * rx;
    double e3z = ez - cz * rx * ry;

    /* stage 4 at the end, from stage 3's slopes (q + h q' = q + h/2 p) */
    tm = u1[0]; ex = u1[1]; ey = u1[2]; ez = u1[3]; dm = u1[4];
    t2 = 2.0 * tm; tg = tm - gravity_mps2;
    sw = qw - h2 * n3; sx = qx + h2 * p3x; sy = qy + h2 * p3y; sz = qz + h2 * p3z;
    rx = wx + h * e3x; ry = wy + h * e3y; rz = wz + h * e3z;
    double a4x = t2 * (sx * sz + sw * sy);
    double a4y = t2 * (sy * sz - sw * sx);
    double a4z = tg - t2 * (sx * sx + sy * sy);
    if (dm != 0.0) {
        drag_world(sw, sx, sy, sz, vx + h * a3x, vy + h * a3y, vz + h * a3z, dm, d);
        a4x = a4x + d[0]; a4y = a4y + d[1]; a4z = a4z + d[2];
    }
    double n4 = sx * rx + sy * ry + sz * rz;
    double p4x = sw * rx + sy * rz - sz * ry;
    double p4y = sw * ry - sx * rz + sz * rx;
    double p4z = sw * rz + sx * ry - sy * rx;
    double e4x = ex - cx * ry * rz;
    double e4y = ey - cy * rz * rx;
    double e4z = ez - cz * rx * ry;

    /* combine; q' = p / 2, so q takes h/12 of the p's */
    qw -= h12 * (n1 + 2.0 * (n2 + n3) + n4);
    qx += h12 * (p1x + 2.0 * (p2x + p3x) + p4x);
    qy += h12 * (p1y + 2.0 * (p2y + p3y) + p4y);
    qz += h12 * (p1z + 2.0 * (p2z + p3z) + p4z);
    double k = 1.0 / sqrt(qw * qw + qx * qx + qy * qy + qz * qz);
    sx = a1x + a2x + a3x; sy = a1y + a2y + a3y; sz = a1z + a2z + a3z;
    double out[N_STATE] = {
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
    };
    return float_list(out, N_STATE);
}

/* dynamics_kernels.rotor_inputs_python on C doubles: T (returned) and the wrench terms u */
static double inputs_for(const double w[N_ROTORS], const double c[ROTOR_COEFFS], double u[N_WRENCH]) {
    double s0 = w[0] * w[0], s1 = w[1] * w[1], s2 = w[2] * w[2], s3 = w[3] * w[3];
    double mass = c[16];
    double thrust = c[0] * s0 + c[1] * s1 + c[2] * s2 + c[3] * s3;
    u[0] = thrust / mass;
    u[1] = (c[4] * s0 + c[5] * s1 + c[6] * s2 + c[7] * s3) / c[17];
    u[2] = (c[8] * s0 + c[9] * s1 + c[10] * s2 + c[11] * s3) / c[18];
    u[3] = (c[12] * s0 + c[13] * s1 + c[14] * s2 + c[15] * s3) / c[19];
    u[4] = c[20] * (w[0] + w[1] + w[2] + w[3]) / mass;
    return thrust;
}

/* rotor_inputs(w, coeffs) -> (T, u): dynamics_kernels.rotor_inputs */
static PyObject *rotor_inputs(PyObject *self, PyObject *const *args, Py_ssize_t nargs) {
    (void)self;
    if (check_nargs("rotor_inputs", nargs, 2) < 0) return NULL;
    double w[N_ROTORS], c[ROTOR_COEFFS], u[N_WRENCH];
    if (read_floats(args[0], w, N_ROTORS, "w") < 0 || read_floats(args[1], c, ROTOR_COEFFS, "coeffs") < 0)
        return NULL;
    double thrust = inputs_for(w, c, u);
    PyObject *wrench = float_tuple(u, N_WRENCH);
    if (wrench == NULL) return NULL;
    return Py_BuildValue("(dN)", thrust, wrench);
}

/* rotor_lag(w, cmd, decay_half, decay_full, coeffs) -> None | (w_end, T, um, u1): dynamics_kernels.rotor_lag */
static PyObject *rotor_lag(PyObject *self, PyObject *const *args, Py_ssize_t nargs) {
    (void)self;
    if (check_nargs("rotor_lag", nargs, 5) < 0) return NULL;
    double w[N_ROTORS], cmd[N_ROTORS], c[ROTOR_COEFFS];
    if (read_floats(args[0], w, N_ROTORS, "w") < 0 || read_floats(args[1], cmd, N_ROTORS, "cmd") < 0
        || read_floats(args[4], c, ROTOR_COEFFS, "coeffs") < 0)
        return NULL;
    double dh = PyFloat_AsDouble(args[2]);
    if (dh == -1.0 && PyErr_Occurred()) return NULL;
    double df = PyFloat_AsDouble(args[3]);
    if (df == -1.0 && PyErr_Occurred()) return NULL;
    double w_end[N_ROTORS], w_half[N_ROTORS], um[N_WRENCH], u1[N_WRENCH];
    int changed = 0;
    for (int i = 0; i < N_ROTORS; i++) {
        w_end[i] = cmd[i] + (w[i] - cmd[i]) * df;
        changed |= w_end[i] != w[i]; /* as the twin's list comparison: a NaN counts as a change */
    }
    if (!changed) Py_RETURN_NONE;
    for (int i = 0; i < N_ROTORS; i++) w_half[i] = cmd[i] + (w[i] - cmd[i]) * dh;
    inputs_for(w_half, c, um);
    double thrust = inputs_for(w_end, c, u1);
    PyObject *speeds = float_list(w_end, N_ROTORS);
    if (speeds == NULL) return NULL;
    PyObject *middle = float_tuple(um, N_WRENCH);
    if (middle == NULL) {
        Py_DECREF(speeds);
        return NULL;
    }
    PyObject *end = float_tuple(u1, N_WRENCH);
    if (end == NULL) {
        Py_DECREF(speeds);
        Py_DECREF(middle);
        return NULL;
    }
    return Py_BuildValue("(NdNN)", speeds, thrust, middle, end);
}

static PyMethodDef methods[] = {
    {"rk4", (PyCFunction)(void (*)(void))rk4, METH_FASTCALL,
     "rk4(x, u0, um, u1, steps, gyro) -> x1 (simulator.dynamics_kernels.rk4)"},
    {"rotor_inputs", (PyCFunction)(void (*)(void))rotor_inputs, METH_FASTCALL,
     "rotor_inputs(w, coeffs) -> (T, u) (simulator.dynamics_kernels.rotor_inputs)"},
    {"rotor_lag", (PyCFunction)(void (*)(void))rotor_lag, METH_FASTCALL,
     "rotor_lag(w, cmd, decay_half, decay_full, coeffs) -> None | (w_end, T, um, u1) "
     "(simulator.dynamics_kernels.rotor_lag)"},
    {NULL, NULL, 0, NULL},
};

static struct PyModuleDef module = {
    PyModuleDef_HEAD_INIT, "_dynamics_kernels",
    "Compiled twin of simulator.dynamics_kernels (the rigid body's RK4 step, the rotors' lag).", -1, methods,
};

PyMODINIT_FUNC PyInit__dynamics_kernels(void) {
    if (read_module_float("model.vehicle", "GRAVITY_MPS2", &gravity_mps2) < 0) return NULL;
    return PyModule_Create(&module);
}
