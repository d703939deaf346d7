/* Compiled twin of the latency compensator's model steps (groundstation.compensation, issue 19):
LatencyCompensator._steps_python, once per control tick on the ground station's critical path.

predict_steps takes in: t and t_act (s, the ground station's clock: the estimate's time and the time the
command being computed will act); the state at t (13 floats: position ENU m, velocity ENU m/s, attitude
wxyz body FLU -> world ENU, rate FLU rad/s); the command acting at t (a SentCommand, or None) and those sent
after it, in sending order (a list of SentCommand: sent_s s, thrust_n N, moment_flu_nm N m, attitude_wxyz);
the one-way uplink latency (s); the constants of compensation_kernel.step_constants (the step s, the mass
kg, the diagonal inertia kg m^2, gravity m/s^2, the angle below which a rotation is none, rad) and whether
the vehicle flies attitude setpoints (1) or moments (0).
It gives out the state at t_act (the same 13 floats), or None where it would not do alike with the Python:
a step whose attitude would raise there (sin or cos of an infinite angle, a zero quaternion to normalise),
or commands whose fields are not numbers of the right count. The caller then runs the Python, which gives
what Python gives, errors included.

Same bits as the Python: every expression below is the Python's, in the same order, one IEEE double
operation at a time (setup.py builds this file with -ffp-contract=off, so no multiply-add is fused); sqrt,
sin and cos are the C library's, the ones Python's math module calls. tests/groundstation/test_compensation_kernel.py
checks the bits against the Python. */

#include "../model/_kernels.h" /* includes Python.h; read_floats, float_tuple, check_nargs */
#include <math.h>

#define N_STATE 13
#define N_CONSTANTS 7
#define TIME_SLACK_S 1e-12 /* compensation.py's: a step or an arrival within it of t counts as at t */

/* The constants' order (compensation_kernel.step_constants) */
enum { STEP_S, MASS_KG, IXX, IYY, IZZ, GRAVITY, NEGLIGIBLE_ANGLE };

typedef struct {
    double sent_s, thrust_n, moment[3], attitude[4];
} Command;

/* A SentCommand's fields into c; -1 with the error set */
static int read_command(PyObject *obj, Command *c) {
    PyObject *v = PyObject_GetAttrString(obj, "sent_s");
    if (v == NULL) return -1;
    c->sent_s = PyFloat_AsDouble(v);
    Py_DECREF(v);
    if (c->sent_s == -1.0 && PyErr_Occurred()) return -1;
    v = PyObject_GetAttrString(obj, "thrust_n");
    if (v == NULL) return -1;
    c->thrust_n = PyFloat_AsDouble(v);
    Py_DECREF(v);
    if (c->thrust_n == -1.0 && PyErr_Occurred()) return -1;
    v = PyObject_GetAttrString(obj, "moment_flu_nm");
    if (v == NULL) return -1;
    int bad = read_floats(v, c->moment, 3, "moment_flu_nm");
    Py_DECREF(v);
    if (bad) return -1;
    v = PyObject_GetAttrString(obj, "attitude_wxyz");
    if (v == NULL) return -1;
    bad = read_floats(v, c->attitude, 4, "attitude_wxyz");
    Py_DECREF(v);
    return bad;
}

/* model.frames.quat_integrate: q (x) Exp(w dt), normalised; -1 where the Python would raise */
static int quat_integrate(double *q, const double *w, double dt, double negligible) {
    double wx = w[0], wy = w[1], wz = w[2];
    double angle = sqrt(wx * wx + wy * wy + wz * wz) * dt;
    if (angle < negligible) return 0;
    double half = angle / 2.0;
    if (isinf(half)) return -1; /* math.sin / math.cos raise ValueError on an infinite argument */
    double s = sin(half) / (angle / dt);
    double dw = cos(half), dx = wx * s, dy = wy * s, dz = wz * s;
    double qw = q[0], qx = q[1], qy = q[2], qz = q[3];
    double ow = qw * dw - qx * dx - qy * dy - qz * dz;
    double ox = qw * dx + qx * dw + qy * dz - qz * dy;
    double oy = qw * dy - qx * dz + qy * dw + qz * dx;
    double oz = qw * dz + qx * dy - qy * dx + qz * dw;
    double n = sqrt(ow * ow + ox * ox + oy * oy + oz * oz);
    if (n == 0.0) return -1; /* ZeroDivisionError */
    q[0] = ow / n;
    q[1] = ox / n;
    q[2] = oy / n;
    q[3] = oz / n;
    return 0;
}

/* The state at t_act from the state at t: LatencyCompensator._steps_python, step for step */
static int steps(double t, double t_act, double *x, const Command *acting0, const Command *pending,
                 Py_ssize_t count, double latency, const double *k, int attitude_mode) {
    if (k[MASS_KG] == 0.0 || k[IXX] == 0.0 || k[IYY] == 0.0 || k[IZZ] == 0.0) return -1; /* ZeroDivisionError */
    double px = x[0], py = x[1], pz = x[2], vx = x[3], vy = x[4], vz = x[5];
    double *q = x + 6, *w = x + 10;
    const Command *acting = acting0;
    Py_ssize_t arrived = 0;
    while (t < t_act - TIME_SLACK_S) {
        double left = t_act - t;
        double dt = left < k[STEP_S] ? left : k[STEP_S]; /* Python's min(step_s, t_act - t) */
        while (arrived < count && pending[arrived].sent_s + latency <= t + TIME_SLACK_S) {
            acting = &pending[arrived];
            arrived += 1;
        }
        if (acting == NULL) { /* nothing of ours acts yet: coast */
            px = px + vx * dt;
            py = py + vy * dt;
            pz = pz + vz * dt;
            t += dt;
            continue;
        }
        if (attitude_mode) {
            for (int i = 0; i < 4; i++) q[i] = acting->attitude[i];
            w[0] = w[1] = w[2] = 0.0;
        } else { /* _rate_step: Euler step of I w' = M - w x I w, then the attitude */
            double ix = k[IXX], iy = k[IYY], iz = k[IZZ];
            double wx = w[0], wy = w[1], wz = w[2];
            w[0] = wx + dt * (acting->moment[0] - (iz - iy) * wy * wz) / ix;
            w[1] = wy + dt * (acting->moment[1] - (ix - iz) * wz * wx) / iy;
            w[2] = wz + dt * (acting->moment[2] - (iy - ix) * wx * wy) / iz;
            if (quat_integrate(q, w, dt, k[NEGLIGIBLE_ANGLE])) return -1;
        }
        double qw = q[0], qx = q[1], qy = q[2], qz = q[3];
        double f = acting->thrust_n / k[MASS_KG];
        double ax = f * (2.0 * (qx * qz + qw * qy));
        double ay = f * (2.0 * (qy * qz - qw * qx));
        double az = f * (1.0 - 2.0 * (qx * qx + qy * qy)) - k[GRAVITY];
        double half_dt2 = 0.5 * dt * dt;
        px = px + dt * vx + half_dt2 * ax;
        py = py + dt * vy + half_dt2 * ay;
        pz = pz + dt * vz + half_dt2 * az;
        vx = vx + dt * ax;
        vy = vy + dt * ay;
        vz = vz + dt * az;
        t += dt;
    }
    x[0] = px;
    x[1] = py;
    x[2] = pz;
    x[3] = vx;
    x[4] = vy;
    x[5] = vz;
    return 0;
}

/* predict_steps(t, t_act, state, acting, pending, latency, constants, attitude_mode) -> 13 floats | None */
static PyObject *predict_steps(PyObject *self, PyObject *const *args, Py_ssize_t nargs) {
    (void)self;
    if (check_nargs("predict_steps", nargs, 8)) return NULL;
    double t = PyFloat_AsDouble(args[0]), t_act = PyFloat_AsDouble(args[1]), latency = PyFloat_AsDouble(args[5]);
    if (PyErr_Occurred()) return NULL;
    double x[N_STATE], k[N_CONSTANTS];
    if (read_floats(args[2], x, N_STATE, "state") || read_floats(args[6], k, N_CONSTANTS, "constants")) return NULL;
    int attitude_mode = PyObject_IsTrue(args[7]);
    if (attitude_mode < 0) return NULL;
    if (!PyList_Check(args[4])) {
        PyErr_SetString(PyExc_TypeError, "predict_steps: pending must be a list");
        return NULL;
    }
    Py_ssize_t count = PyList_GET_SIZE(args[4]);
    Command acting, *pending = PyMem_Malloc((size_t)(count > 0 ? count : 1) * sizeof(Command));
    if (pending == NULL) return PyErr_NoMemory();
    int bad = args[3] != Py_None && read_command(args[3], &acting);
    for (Py_ssize_t i = 0; !bad && i < count; i++) bad = read_command(PyList_GET_ITEM(args[4], i), &pending[i]);
    if (bad || steps(t, t_act, x, args[3] == Py_None ? NULL : &acting, pending, count, latency, k, attitude_mode)) {
        PyMem_Free(pending);
        PyErr_Clear(); /* the Python's turn: it gives its result or its error */
        Py_RETURN_NONE;
    }
    PyMem_Free(pending);
    return float_tuple(x, N_STATE);
}

static PyMethodDef methods[] = {
    {"predict_steps", (PyCFunction)(void (*)(void))predict_steps, METH_FASTCALL,
     "predict_steps(t, t_act, state, acting, pending, latency, constants, attitude_mode) -> 13 floats | None "
     "(groundstation.compensation_kernel)"},
    {NULL, NULL, 0, NULL},
};

static struct PyModuleDef module = {
    PyModuleDef_HEAD_INIT, "_compensation_kernel",
    "Compiled twin of the latency compensator's model steps (groundstation.compensation_kernel).", -1, methods,
};

PyMODINIT_FUNC PyInit__compensation_kernel(void) { return PyModule_Create(&module); }
