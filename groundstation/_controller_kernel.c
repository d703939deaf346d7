/* Compiled twin of the SE(3) controller's "report" law (groundstation.controller, issue 19):
SE3Controller._update_python, once per control tick on the ground station's critical path.

se3_update takes in: the state (position ENU m, velocity ENU m/s, attitude wxyz body FLU -> world ENU, rate FLU
rad/s: float64 arrays or sequences of floats, 3, 3, 4 and 3 of them), the reference (position ENU m, velocity
ENU m/s, acceleration ENU m/s^2: 3 floats each; yaw rad), the constants of controller_kernel.report_constants (the
model mass kg, K_p, K_d, K_R, K_w, the diagonal inertia kg m^2, the thrust limit N, the moment limits N m,
gravity m/s^2, the degenerate norm) and the ControlOutput class.
It gives out the ControlOutput the Python gives, or None where it would not do alike with the Python: an
attitude to normalise of zero norm, a cos or sin of an infinite yaw, a desired attitude Shepperd's method
cannot take (the square root of a negative, a division by zero), or vectors that are not floats of the right
count (ints, say, whose arithmetic Python keeps exact). The caller then runs the Python, which gives what
Python gives, errors included.

Same bits as the Python: every expression below is the Python's, in the same order, one IEEE double operation
at a time (setup.py builds this file with -ffp-contract=off, so no multiply-add is fused); sqrt, sin and cos
are the C library's, the ones Python's math module calls. tests/groundstation/test_controller_kernel.py checks
the bits against the Python. */

/* includes Python.h and math.h; read_floats, float_tuple, check_nargs, quat_to_rows, quat_normalize_positive_w */
#include "../model/_kernels.h"
#include <math.h>
#include <string.h>

#define N_CONSTANTS 24

/* The constants' order (controller_kernel.report_constants) */
enum {
    MASS_KG, KPX, KPY, KPZ, KDX, KDY, KDZ, KRX, KRY, KRZ, KWX, KWY, KWZ, IXX, IYY, IZZ, MAX_THRUST_N,
    MAX_MX, MAX_MY, MAX_MZ, GRAVITY, DEGENERATE_NORM, N_USED,
};

/* Python's _clip(value, low, high) */
static double clip(double value, double low, double high) {
    return value > high ? high : value < low ? low : value;
}

/* model.frames.rows_to_quat (Shepperd's method, then quat_normalize_positive_w); -1 where the Python raises */
static int rows_to_quat(double r00, double r01, double r02, double r10, double r11, double r12, double r20,
                        double r21, double r22, double *q) {
    double trace = r00 + r11 + r22, radicand;
    int largest; /* 0: the trace, 1-3: r00, r11, r22 (the branch keeps the divisor away from zero) */
    if (trace >= r00 && trace >= r11 && trace >= r22)
        largest = 0, radicand = 1.0 + trace;
    else if (r00 >= r11 && r00 >= r22)
        largest = 1, radicand = 1.0 + r00 - r11 - r22;
    else if (r11 >= r22)
        largest = 2, radicand = 1.0 + r11 - r00 - r22;
    else
        largest = 3, radicand = 1.0 + r22 - r00 - r11;
    if (radicand < 0.0) return -1; /* math.sqrt: ValueError */
    double s = 2.0 * sqrt(radicand); /* 4 w, 4 x, 4 y or 4 z */
    if (s == 0.0) return -1; /* ZeroDivisionError */
    switch (largest) {
    case 0: q[0] = 0.25 * s, q[1] = (r21 - r12) / s, q[2] = (r02 - r20) / s, q[3] = (r10 - r01) / s; break;
    case 1: q[0] = (r21 - r12) / s, q[1] = 0.25 * s, q[2] = (r01 + r10) / s, q[3] = (r02 + r20) / s; break;
    case 2: q[0] = (r02 - r20) / s, q[1] = (r01 + r10) / s, q[2] = 0.25 * s, q[3] = (r12 + r21) / s; break;
    default: q[0] = (r10 - r01) / s, q[1] = (r02 + r20) / s, q[2] = (r12 + r21) / s, q[3] = 0.25 * s;
    }
    return quat_normalize_positive_w(q); /* -1 with ValueError for the zero quaternion */
}

/* The outputs, in ControlOutput's field order: thrust, moment, attitude_des, rate_des, thrust_saturated,
   moment_saturated, force_des, position_error, velocity_error, e_R, e_w */
typedef struct {
    double thrust, moment[3], q_des[4], force[3], ep[3], ev[3], er[3], ew[3];
    int thrust_sat, moment_sat[3];
} Output;

/* SE3Controller._update_python's "report" branch, expression for expression; -1 where the Python raises */
static int report_law(const double *p, const double *v, const double *q_in, const double *w, const double *rp,
                      const double *rv, const double *ra, double psi, const double *k, Output *o) {
    double m = k[MASS_KG], deg = k[DEGENERATE_NORM];
    double epx = p[0] - rp[0], epy = p[1] - rp[1], epz = p[2] - rp[2];
    double evx = v[0] - rv[0], evy = v[1] - rv[1], evz = v[2] - rv[2];
    double fx = m * (ra[0] - k[KDX] * evx - k[KPX] * epx);
    double fy = m * (ra[1] - k[KDY] * evy - k[KPY] * epy);
    double fz = m * (ra[2] - k[KDZ] * evz - k[KPZ] * epz + k[GRAVITY]);

    /* model.frames.quat_normalize (the sign kept), then quat_to_rows */
    double qn = sqrt(q_in[0] * q_in[0] + q_in[1] * q_in[1] + q_in[2] * q_in[2] + q_in[3] * q_in[3]), r[9];
    if (qn == 0.0) return -1; /* ZeroDivisionError */
    double q_unit[4] = {q_in[0] / qn, q_in[1] / qn, q_in[2] / qn, q_in[3] / qn};
    quat_to_rows(q_unit, r);
    double r00 = r[0], r01 = r[1], r02 = r[2], r10 = r[3], r11 = r[4], r12 = r[5], r20 = r[6], r21 = r[7], r22 = r[8];
    double thrust = r02 * fx + r12 * fy + r22 * fz;

    double f_norm = sqrt(fx * fx + fy * fy + fz * fz), b3x, b3y, b3z;
    if (f_norm > deg) {
        b3x = fx / f_norm, b3y = fy / f_norm, b3z = fz / f_norm;
    } else {
        b3x = r02, b3y = r12, b3z = r22;
    }
    if (isinf(psi)) return -1; /* math.cos / math.sin: ValueError */
    double ax = cos(psi), ay = sin(psi);
    double cx = -b3z * ay, cy = b3z * ax, cz = b3x * ay - b3y * ax;
    double c_norm = sqrt(cx * cx + cy * cy + cz * cz);
    if (c_norm <= deg) {
        cx = b3y * r20 - b3z * r10, cy = b3z * r00 - b3x * r20, cz = b3x * r10 - b3y * r00;
        c_norm = sqrt(cx * cx + cy * cy + cz * cz);
        if (c_norm <= deg) cx = r01, cy = r11, cz = r21, c_norm = 1.0;
    }
    double b2x = cx / c_norm, b2y = cy / c_norm, b2z = cz / c_norm;
    double b1x = b2y * b3z - b2z * b3y, b1y = b2z * b3x - b2x * b3z, b1z = b2x * b3y - b2y * b3x;

    double m01 = b1x * r01 + b1y * r11 + b1z * r21;
    double m02 = b1x * r02 + b1y * r12 + b1z * r22;
    double m10 = b2x * r00 + b2y * r10 + b2z * r20;
    double m12 = b2x * r02 + b2y * r12 + b2z * r22;
    double m20 = b3x * r00 + b3y * r10 + b3z * r20;
    double m21 = b3x * r01 + b3y * r11 + b3z * r21;
    double erx = 0.5 * (m21 - m12), ery = 0.5 * (m02 - m20), erz = 0.5 * (m10 - m01);

    /* model.attitude_law.attitude_moment without feed-forward or gyroscopic term; e_w = w (w_des = 0) */
    double ewx = w[0], ewy = w[1], ewz = w[2];
    double aax = -k[KRX] * erx - k[KWX] * ewx;
    double aay = -k[KRY] * ery - k[KWY] * ewy;
    double aaz = -k[KRZ] * erz - k[KWZ] * ewz;
    double mx = k[IXX] * aax, my = k[IYY] * aay, mz = k[IZZ] * aaz;

    if (rows_to_quat(b1x, b2x, b3x, b1y, b2y, b3y, b1z, b2z, b3z, o->q_des)) return -1;
    o->thrust = clip(thrust, 0.0, k[MAX_THRUST_N]);
    o->moment[0] = clip(mx, -k[MAX_MX], k[MAX_MX]);
    o->moment[1] = clip(my, -k[MAX_MY], k[MAX_MY]);
    o->moment[2] = clip(mz, -k[MAX_MZ], k[MAX_MZ]);
    o->thrust_sat = o->thrust != thrust;
    o->moment_sat[0] = o->moment[0] != mx, o->moment_sat[1] = o->moment[1] != my, o->moment_sat[2] = o->moment[2] != mz;
    o->force[0] = fx, o->force[1] = fy, o->force[2] = fz;
    o->ep[0] = epx, o->ep[1] = epy, o->ep[2] = epz;
    o->ev[0] = evx, o->ev[1] = evy, o->ev[2] = evz;
    o->er[0] = erx, o->er[1] = ery, o->er[2] = erz;
    o->ew[0] = ewx, o->ew[1] = ewy, o->ew[2] = ewz;
    return 0;
}

static PyObject *bool_tuple3(const int *values) {
    return PyTuple_Pack(3, values[0] ? Py_True : Py_False, values[1] ? Py_True : Py_False,
                        values[2] ? Py_True : Py_False);
}

/* ControlOutput's fields, in order (interned when the module loads) */
static const char *const FIELD_NAMES[11] = {
    "thrust_n", "moment_flu_nm", "attitude_des_wxyz", "rate_des_flu_radps", "thrust_saturated", "moment_saturated",
    "force_des_enu_n", "position_error_m", "velocity_error_mps", "e_R", "e_w",
};
static PyObject *field_names[11];

/* A ControlOutput holding o's values, built as its dataclass __init__ builds it - each slot set through
   object.__setattr__ - without the Python call (the class has slots, no defaults and no __post_init__:
   tests/groundstation/test_controller_kernel.py checks that it still has not); NULL with the error set */
static PyObject *control_output(PyObject *cls, const Output *o) {
    static const double zeros[3] = {0.0, 0.0, 0.0};
    if (!PyType_Check(cls)) {
        PyErr_SetString(PyExc_TypeError, "se3_update: ControlOutput must be a class");
        return NULL;
    }
    PyObject *fields[11] = {
        PyFloat_FromDouble(o->thrust), float_tuple(o->moment, 3), float_tuple(o->q_des, 4), float_tuple(zeros, 3),
        PyBool_FromLong(o->thrust_sat), bool_tuple3(o->moment_sat), float_tuple(o->force, 3), float_tuple(o->ep, 3),
        float_tuple(o->ev, 3), float_tuple(o->er, 3), float_tuple(o->ew, 3),
    };
    PyTypeObject *type = (PyTypeObject *)cls;
    PyObject *result = NULL;
    for (int i = 0; i < 11; i++)
        if (fields[i] == NULL) goto done;
    result = type->tp_alloc(type, 0);
    for (int i = 0; result != NULL && i < 11; i++) {
        if (PyObject_GenericSetAttr(result, field_names[i], fields[i]) < 0) Py_CLEAR(result);
    }
done:
    for (int i = 0; i < 11; i++) Py_XDECREF(fields[i]);
    return result;
}

/* se3_update(position, velocity, attitude, rate, ref_position, ref_velocity, ref_acceleration, yaw, constants,
   ControlOutput) -> ControlOutput | None */
static PyObject *se3_update(PyObject *self, PyObject *const *args, Py_ssize_t nargs) {
    (void)self;
    if (check_nargs("se3_update", nargs, 10)) return NULL;
    double p[3], v[3], q[4], w[3], rp[3], rv[3], ra[3], k[N_CONSTANTS];
    if (read_floats(args[8], k, N_USED, "constants")) return NULL;
    int bad = read_float_vector(args[0], p, 3, 0) || read_float_vector(args[1], v, 3, 0) ||
              read_float_vector(args[2], q, 4, 0) || read_float_vector(args[3], w, 3, 0) ||
              read_float_vector(args[4], rp, 3, 0) || read_float_vector(args[5], rv, 3, 0) ||
              read_float_vector(args[6], ra, 3, 0);
    double psi = bad ? 0.0 : PyFloat_AsDouble(args[7]);
    Output o;
    if (bad || (psi == -1.0 && PyErr_Occurred()) || report_law(p, v, q, w, rp, rv, ra, psi, k, &o)) {
        PyErr_Clear(); /* the Python's turn: it gives its result or its error */
        Py_RETURN_NONE;
    }
    return control_output(args[9], &o);
}

static PyMethodDef methods[] = {
    {"se3_update", (PyCFunction)(void (*)(void))se3_update, METH_FASTCALL,
     "se3_update(position, velocity, attitude, rate, ref_position, ref_velocity, ref_acceleration, yaw, "
     "constants, ControlOutput) -> ControlOutput | None (groundstation.controller_kernel)"},
    {NULL, NULL, 0, NULL},
};

static struct PyModuleDef module = {
    PyModuleDef_HEAD_INIT, "_controller_kernel",
    "Compiled twin of the SE(3) controller's report law (groundstation.controller_kernel).", -1, methods,
};

PyMODINIT_FUNC PyInit__controller_kernel(void) {
    if (intern_names(FIELD_NAMES, field_names, 11) < 0) return NULL;
    return PyModule_Create(&module);
}
