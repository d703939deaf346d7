/* Compiled twin of estimator/eskf_kernels.py: the ESKF's per-sample propagation and its covariance algebra
(issue 19).

Takes in: for propagate, the nominal state x (16 floats: p, v, q wxyz, b_a, b_g), the IMU signal at both
ends of an interval (f0, w0, f1, w1: specific force FLU m/s^2, rate FLU rad/s, 3 floats each), its length
dt (s), g (m/s^2), and optionally F - a writable C-contiguous float64 array holding the identity - with the
flat indices (int64) its 48 other entries go to. For predict_covariance, update_covariance,
reset_covariance and multiply: C-contiguous float64 15x15 matrices (P, F, Q), the mocap residual z, R's
diagonal r and the six measured state indices, an attitude correction dtheta (rad), and writable outputs.
Gives out: propagate -> the nominal state after dt (a tuple of 16 floats), and F's entries written in
place; the covariance kernels write F P F' + Q, the Joseph-form posterior with dx (returning d^2, NaN if
S is not positive definite), G P G', and A B into their outputs.
quat_exp's small-angle threshold is model.frames.SMALL_ANGLE_RAD, read once when the module loads.

Same result as the Python twin, bit for bit: every expression below is the Python one in the same order,
one IEEE double operation at a time (setup.py builds this file with -ffp-contract=off, so no multiply-add
is fused), and sqrt, sin and cos are the C library's, which CPython's math module calls too.
tests/estimator/test_eskf_kernels.py checks the bits against the twin. */

#include "../model/_kernels.h" /* includes Python.h; read_floats, read_module_float, float_tuple, check_nargs */
#include <math.h>
#include <stdint.h>
#include <string.h>

#define N_STATE 16
#define N_TRANSITION 48
#define F_SIZE (15 * 15)

/* model.frames.rotate */
static void rotate(const double r[9], double vx, double vy, double vz, double out[3]) {
    out[0] = r[0] * vx + r[1] * vy + r[2] * vz;
    out[1] = r[3] * vx + r[4] * vy + r[5] * vz;
    out[2] = r[6] * vx + r[7] * vy + r[8] * vz;
}

static double small_angle_rad; /* model.frames.SMALL_ANGLE_RAD */

/* model.frames.quat_exp */
static void quat_exp(double rx, double ry, double rz, double q[4]) {
    double angle = sqrt(rx * rx + ry * ry + rz * rz);
    if (angle < small_angle_rad) {
        double s = 0.5 - angle * angle / 48.0;
        q[0] = 1.0 - angle * angle / 8.0; q[1] = s * rx; q[2] = s * ry; q[3] = s * rz;
        return;
    }
    double s = sin(0.5 * angle) / angle;
    q[0] = cos(0.5 * angle); q[1] = s * rx; q[2] = s * ry; q[3] = s * rz;
}

/* model.frames.quat_multiply */
static void quat_multiply(const double a[4], const double b[4], double out[4]) {
    double aw = a[0], ax = a[1], ay = a[2], az = a[3];
    double bw = b[0], bx = b[1], by = b[2], bz = b[3];
    out[0] = aw * bw - ax * bx - ay * by - az * bz;
    out[1] = aw * bx + ax * bw + ay * bz - az * by;
    out[2] = aw * by - ax * bz + ay * bw + az * bx;
    out[3] = aw * bz + ax * by - ay * bx + az * bw;
}

/* F's 48 entries in eskf_kernels.transition_values' order, from R(q0) row-major, the mean bias-corrected
   specific force f and rate w, over dt */
static void transition_values(const double r[9], const double f[3], const double w[3], double dt,
                              double v[N_TRANSITION]) {
    double fx = f[0], fy = f[1], fz = f[2];
    double r0 = r[0], r1 = r[1], r2 = r[2], r3 = r[3], r4 = r[4], r5 = r[5], r6 = r[6], r7 = r[7], r8 = r[8];
    double m0 = r1 * fz - r2 * fy, m1 = r2 * fx - r0 * fz, m2 = r0 * fy - r1 * fx;
    double m3 = r4 * fz - r5 * fy, m4 = r5 * fx - r3 * fz, m5 = r3 * fy - r4 * fx;
    double m6 = r7 * fz - r8 * fy, m7 = r8 * fx - r6 * fz, m8 = r6 * fy - r7 * fx;
    double h = -0.5 * dt * dt, k = -dt;
    double wx = w[0] * dt, wy = w[1] * dt, wz = w[2] * dt;
    double values[N_TRANSITION] = {
        dt, dt, dt,
        h * m0, h * m1, h * m2, h * r0, h * r1, h * r2,
        h * m3, h * m4, h * m5, h * r3, h * r4, h * r5,
        h * m6, h * m7, h * m8, h * r6, h * r7, h * r8,
        k * m0, k * m1, k * m2, k * r0, k * r1, k * r2,
        k * m3, k * m4, k * m5, k * r3, k * r4, k * r5,
        k * m6, k * m7, k * m8, k * r6, k * r7, k * r8,
        wz, -wy, -wz, wx, wy, -wx,
        k, k, k,
    };
    memcpy(v, values, sizeof(values));
}

/* Write the transition values into F at `index` (both checked: float64 15x15 writable, 48 int64). */
static int put_transition(PyObject *F_obj, PyObject *index_obj, const double v[N_TRANSITION]) {
    Py_buffer F, index;
    if (PyObject_GetBuffer(F_obj, &F, PyBUF_WRITABLE | PyBUF_C_CONTIGUOUS | PyBUF_FORMAT) < 0) return -1;
    if (PyObject_GetBuffer(index_obj, &index, PyBUF_C_CONTIGUOUS | PyBUF_FORMAT) < 0) {
        PyBuffer_Release(&F);
        return -1;
    }
    int ok = F.itemsize == 8 && F.len == F_SIZE * 8 && strcmp(F.format, "d") == 0
             && index.itemsize == 8 && index.len == N_TRANSITION * 8
             && (strcmp(index.format, "l") == 0 || strcmp(index.format, "q") == 0);
    if (!ok) {
        PyErr_SetString(PyExc_ValueError, "F must be a writable C-contiguous 15x15 float64 array and index "
                                          "48 int64 flat indices");
    } else {
        double *out = (double *)F.buf;
        const int64_t *at = (const int64_t *)index.buf;
        for (int i = 0; i < N_TRANSITION; i++) {
            if (at[i] < 0 || at[i] >= F_SIZE) {
                PyErr_SetString(PyExc_ValueError, "transition index out of range");
                ok = 0;
                break;
            }
            out[at[i]] = v[i];
        }
    }
    PyBuffer_Release(&index);
    PyBuffer_Release(&F);
    return ok ? 0 : -1;
}

/* The nominal step over dt into x1 and, given v (else NULL), F's 48 transition values: eskf_kernels.propagate.
   -1 (ValueError set) if the attitude became the zero quaternion. */
static int propagate_core(const double x[N_STATE], const double f0[3], const double w0[3], const double f1[3],
                          const double w1[3], double dt, double g, double x1[N_STATE], double v[N_TRANSITION]) {
    double px = x[0], py = x[1], pz = x[2], vx = x[3], vy = x[4], vz = x[5];
    double bax = x[10], bay = x[11], baz = x[12], bgx = x[13], bgy = x[14], bgz = x[15];
    double w[3] = {0.5 * (w0[0] + w1[0]) - bgx, 0.5 * (w0[1] + w1[1]) - bgy, 0.5 * (w0[2] + w1[2]) - bgz};
    double q0[4] = {x[6], x[7], x[8], x[9]};
    double r0[9], r1[9], dq[4], q1[4], a0[3], a1[3];
    quat_to_rows(q0, r0);
    quat_exp(w[0] * dt, w[1] * dt, w[2] * dt, dq);
    quat_multiply(q0, dq, q1);
    if (quat_normalize_positive_w(q1) < 0) return -1;
    rotate(r0, f0[0] - bax, f0[1] - bay, f0[2] - baz, a0);
    quat_to_rows(q1, r1);
    rotate(r1, f1[0] - bax, f1[1] - bay, f1[2] - baz, a1);
    double ax = 0.5 * (a0[0] + a1[0]);
    double ay = 0.5 * (a0[1] + a1[1]);
    double az = 0.5 * (a0[2] + a1[2]) - g;
    double half_dt2 = 0.5 * dt * dt;
    double out[N_STATE] = {
        px + vx * dt + ax * half_dt2, py + vy * dt + ay * half_dt2, pz + vz * dt + az * half_dt2,
        vx + ax * dt, vy + ay * dt, vz + az * dt, q1[0], q1[1], q1[2], q1[3], bax, bay, baz, bgx, bgy, bgz,
    };
    memcpy(x1, out, sizeof(out));
    if (v != NULL) {
        double f[3] = {0.5 * (f0[0] + f1[0]) - bax, 0.5 * (f0[1] + f1[1]) - bay, 0.5 * (f0[2] + f1[2]) - baz};
        transition_values(r0, f, w, dt, v);
    }
    return 0;
}

/* propagate(x, f0, w0, f1, w1, dt, g, F, index) -> x1: eskf_kernels.propagate */
static PyObject *propagate(PyObject *self, PyObject *const *args, Py_ssize_t nargs) {
    (void)self;
    if (check_nargs("propagate", nargs, 9) < 0) return NULL;
    double x[N_STATE], f0[3], w0[3], f1[3], w1[3];
    if (read_floats(args[0], x, N_STATE, "x") < 0 || read_floats(args[1], f0, 3, "f0") < 0
        || read_floats(args[2], w0, 3, "w0") < 0 || read_floats(args[3], f1, 3, "f1") < 0
        || read_floats(args[4], w1, 3, "w1") < 0)
        return NULL;
    double dt = PyFloat_AsDouble(args[5]);
    double g = PyFloat_AsDouble(args[6]);
    if (PyErr_Occurred()) return NULL;
    double x1[N_STATE], v[N_TRANSITION];
    int with_F = args[7] != Py_None;
    if (propagate_core(x, f0, w0, f1, w1, dt, g, x1, with_F ? v : NULL) < 0) return NULL;
    if (with_F && put_transition(args[7], args[8], v) < 0) return NULL;
    return float_tuple(x1, N_STATE);
}

/* ------------------------------------------------------------------ covariance algebra (eskf_kernels'
   predict_covariance, update_covariance, reset_covariance, multiply): dense loops, every sum taken in
   index order from its first term, every symmetric result computed on and above the diagonal and copied
   below it. No BLAS: the same bits on every CPU. */

#define N_ERR 15
#define N_MEAS 6

/* A C-contiguous float64 buffer of n doubles; -1 with ValueError naming it otherwise */
static int get_matrix(PyObject *obj, Py_buffer *view, Py_ssize_t n, int writable, const char *name) {
    if (PyObject_GetBuffer(obj, view, (writable ? PyBUF_WRITABLE : 0) | PyBUF_C_CONTIGUOUS | PyBUF_FORMAT) < 0)
        return -1;
    if (view->itemsize != 8 || view->len != n * 8 || strcmp(view->format, "d") != 0) {
        PyErr_Format(PyExc_ValueError, "%s must be a C-contiguous float64 array of %zd numbers", name, n);
        PyBuffer_Release(view);
        return -1;
    }
    return 0;
}

static void release_all(Py_buffer *views, int n) {
    for (int i = 0; i < n; i++) PyBuffer_Release(&views[i]);
}

/* A kernel's array argument: its position, size in doubles, whether it is written, its name in errors */
typedef struct {
    int arg;
    Py_ssize_t n;
    int writable;
    const char *name;
} MatrixArg;

#define SQUARE (N_ERR * N_ERR)

/* views[i] = get_matrix of args[spec[i].arg] for i < count; -1 (error set, none held) if one fails */
static int get_matrices(PyObject *const *args, const MatrixArg *spec, int count, Py_buffer *views) {
    for (int i = 0; i < count; i++)
        if (get_matrix(args[spec[i].arg], &views[i], spec[i].n, spec[i].writable, spec[i].name) < 0) {
            release_all(views, i);
            return -1;
        }
    return 0;
}

/* Copy the upper triangle of a 15x15 matrix onto its lower one */
static void mirror_upper(double *m) {
    for (int i = 0; i < N_ERR; i++)
        for (int j = i + 1; j < N_ERR; j++) m[j * N_ERR + i] = m[i * N_ERR + j];
}

/* out = A B (15x15), each entry summed in index order; out must be neither A nor B */
static void product(const double *A, const double *B, double *out) {
    for (int i = 0; i < N_ERR; i++)
        for (int j = 0; j < N_ERR; j++) {
            double acc = A[i * N_ERR] * B[j];
            for (int k = 1; k < N_ERR; k++) acc = acc + A[i * N_ERR + k] * B[k * N_ERR + j];
            out[i * N_ERR + j] = acc;
        }
}

/* out = F P F' + Q */
static void predict_kernel(const double *P, const double *F, const double *Q, double *out) {
    double M[N_ERR * N_ERR];
    product(F, P, M);
    for (int i = 0; i < N_ERR; i++)
        for (int j = i; j < N_ERR; j++) {
            double acc = M[i * N_ERR] * F[j * N_ERR];
            for (int k = 1; k < N_ERR; k++) acc = acc + M[i * N_ERR + k] * F[j * N_ERR + k];
            out[i * N_ERR + j] = acc + Q[i * N_ERR + j];
        }
    mirror_upper(out);
}

/* predict_covariance(P, F, Q, out) -> None */
static PyObject *predict_covariance(PyObject *self, PyObject *const *args, Py_ssize_t nargs) {
    (void)self;
    if (check_nargs("predict_covariance", nargs, 4) < 0) return NULL;
    static const MatrixArg spec[4] = {{0, SQUARE, 0, "P"}, {1, SQUARE, 0, "F"}, {2, SQUARE, 0, "Q"}, {3, SQUARE, 1, "out"}};
    Py_buffer v[4];
    if (get_matrices(args, spec, 4, v) < 0) return NULL;
    predict_kernel(v[0].buf, v[1].buf, v[2].buf, v[3].buf);
    release_all(v, 4);
    Py_RETURN_NONE;
}

/* Lower Cholesky factor L of the 6x6 S (row-major); 0 if S is not positive definite */
static int cholesky(const double *S, double *L) {
    memset(L, 0, sizeof(double) * N_MEAS * N_MEAS);
    for (int j = 0; j < N_MEAS; j++) {
        double d = S[j * N_MEAS + j];
        for (int k = 0; k < j; k++) d = d - L[j * N_MEAS + k] * L[j * N_MEAS + k];
        if (!(d > 0.0)) return 0; /* also catches NaN */
        double ljj = sqrt(d);
        L[j * N_MEAS + j] = ljj;
        for (int i = j + 1; i < N_MEAS; i++) {
            double acc = S[i * N_MEAS + j];
            for (int k = 0; k < j; k++) acc = acc - L[i * N_MEAS + k] * L[j * N_MEAS + k];
            L[i * N_MEAS + j] = acc / ljj;
        }
    }
    return 1;
}

/* The Joseph-form update: P_out, dx and d^2 (returned; NaN when S is not positive definite, outputs
   untouched). sel: the six measured states (H). */
static double update_core(const double *P, const double z[N_MEAS], const double r[N_MEAS], const int sel[N_MEAS],
                          double *P_out, double *dx) {
    double S[N_MEAS * N_MEAS], L[N_MEAS * N_MEAS];
    for (int m = 0; m < N_MEAS; m++)
        for (int n = 0; n < N_MEAS; n++) S[m * N_MEAS + n] = P[sel[m] * N_ERR + sel[n]] + (m == n ? r[m] : 0.0);
    if (!cholesky(S, L)) return NAN;
    /* Solve S X = B, B = [(P H')' | z] (6 x 16): forward W = L^-1 B, then back X = L'^-1 W */
    enum { NB = N_ERR + 1 };
    double W[N_MEAS][NB], X[N_MEAS][NB];
    for (int m = 0; m < N_MEAS; m++) {
        double lmm = L[m * N_MEAS + m];
        for (int c = 0; c < NB; c++) {
            double acc = c < N_ERR ? P[c * N_ERR + sel[m]] : z[m];
            for (int k = 0; k < m; k++) acc = acc - L[m * N_MEAS + k] * W[k][c];
            W[m][c] = acc / lmm;
        }
    }
    for (int m = N_MEAS - 1; m >= 0; m--) {
        double lmm = L[m * N_MEAS + m];
        for (int c = 0; c < NB; c++) {
            double acc = W[m][c];
            for (int k = m + 1; k < N_MEAS; k++) acc = acc - L[k * N_MEAS + m] * X[k][c];
            X[m][c] = acc / lmm;
        }
    }
    double d2 = W[0][N_ERR] * W[0][N_ERR];
    for (int m = 1; m < N_MEAS; m++) d2 = d2 + W[m][N_ERR] * W[m][N_ERR];
    /* K[i][m] = X[m][i]; dx = K z */
    for (int i = 0; i < N_ERR; i++) {
        double acc = X[0][i] * z[0];
        for (int m = 1; m < N_MEAS; m++) acc = acc + X[m][i] * z[m];
        dx[i] = acc;
    }
    /* Joseph form: A = (I - K H) P, P_out = A (I - K H)' + K R K' */
    double A[N_ERR * N_ERR];
    for (int i = 0; i < N_ERR; i++)
        for (int j = 0; j < N_ERR; j++) {
            double acc = P[i * N_ERR + j];
            for (int m = 0; m < N_MEAS; m++) acc = acc - X[m][i] * P[sel[m] * N_ERR + j];
            A[i * N_ERR + j] = acc;
        }
    for (int i = 0; i < N_ERR; i++)
        for (int j = i; j < N_ERR; j++) {
            double acc = A[i * N_ERR + j];
            for (int m = 0; m < N_MEAS; m++) acc = acc - A[i * N_ERR + sel[m]] * X[m][j];
            double krk = X[0][i] * r[0] * X[0][j];
            for (int m = 1; m < N_MEAS; m++) krk = krk + X[m][i] * r[m] * X[m][j];
            P_out[i * N_ERR + j] = acc + krk;
        }
    mirror_upper(P_out);
    return d2;
}

/* update_covariance(P, z, r, index, P_out, dx_out) -> d2 (NaN: S not positive definite, outputs untouched) */
static PyObject *update_covariance(PyObject *self, PyObject *const *args, Py_ssize_t nargs) {
    (void)self;
    if (check_nargs("update_covariance", nargs, 6) < 0) return NULL;
    double z[N_MEAS], r[N_MEAS], index_values[N_MEAS];
    int sel[N_MEAS];
    if (read_floats(args[1], z, N_MEAS, "z") < 0 || read_floats(args[2], r, N_MEAS, "r") < 0
        || read_floats(args[3], index_values, N_MEAS, "index") < 0)
        return NULL;
    for (int m = 0; m < N_MEAS; m++) {
        sel[m] = (int)index_values[m];
        if (sel[m] < 0 || sel[m] >= N_ERR || (double)sel[m] != index_values[m]) {
            PyErr_SetString(PyExc_ValueError, "index: six state indices in 0..14");
            return NULL;
        }
    }
    static const MatrixArg spec[3] = {{0, SQUARE, 0, "P"}, {4, SQUARE, 1, "P_out"}, {5, N_ERR, 1, "dx_out"}};
    Py_buffer v[3];
    if (get_matrices(args, spec, 3, v) < 0) return NULL;
    double d2 = update_core(v[0].buf, z, r, sel, v[1].buf, v[2].buf);
    release_all(v, 3);
    return PyFloat_FromDouble(d2);
}

/* out = G P G', G = I but G_theta = I - [dtheta/2]x (rows and columns 6..8) */
static void reset_core(const double *P, const double dtheta[3], double *out) {
    double hx = 0.5 * dtheta[0], hy = 0.5 * dtheta[1], hz = 0.5 * dtheta[2];
    double G[3][3] = {{1.0, hz, -hy}, {-hz, 1.0, hx}, {hy, -hx, 1.0}};
    double C[N_ERR * N_ERR]; /* G P: rows 6..8 mixed, the others P's */
    memcpy(C, P, sizeof(C));
    for (int a = 0; a < 3; a++)
        for (int j = 0; j < N_ERR; j++) {
            double acc = G[a][0] * P[6 * N_ERR + j];
            for (int b = 1; b < 3; b++) acc = acc + G[a][b] * P[(6 + b) * N_ERR + j];
            C[(6 + a) * N_ERR + j] = acc;
        }
    for (int i = 0; i < N_ERR; i++)
        for (int j = i; j < N_ERR; j++) {
            if (j < 6 || j > 8) {
                out[i * N_ERR + j] = C[i * N_ERR + j];
                continue;
            }
            int a = j - 6;
            double acc = C[i * N_ERR + 6] * G[a][0];
            for (int b = 1; b < 3; b++) acc = acc + C[i * N_ERR + 6 + b] * G[a][b];
            out[i * N_ERR + j] = acc;
        }
    mirror_upper(out);
}

/* reset_covariance(P, dtheta, out) -> None: reset_core */
static PyObject *reset_covariance(PyObject *self, PyObject *const *args, Py_ssize_t nargs) {
    (void)self;
    if (check_nargs("reset_covariance", nargs, 3) < 0) return NULL;
    double dtheta[3];
    if (read_floats(args[1], dtheta, 3, "dtheta") < 0) return NULL;
    static const MatrixArg spec[2] = {{0, SQUARE, 0, "P"}, {2, SQUARE, 1, "out"}};
    Py_buffer v[2];
    if (get_matrices(args, spec, 2, v) < 0) return NULL;
    reset_core(v[0].buf, dtheta, v[1].buf);
    release_all(v, 2);
    Py_RETURN_NONE;
}

/* out = A B (15x15); out may be A or B */
static void multiply_core(const double *A, const double *B, double *out) {
    double result[N_ERR * N_ERR];
    product(A, B, result);
    memcpy(out, result, sizeof(result));
}

/* multiply(A, B, out) -> None: out = A B (15x15) */
static PyObject *multiply(PyObject *self, PyObject *const *args, Py_ssize_t nargs) {
    (void)self;
    if (check_nargs("multiply", nargs, 3) < 0) return NULL;
    static const MatrixArg spec[3] = {{0, SQUARE, 0, "A"}, {1, SQUARE, 0, "B"}, {2, SQUARE, 1, "out"}};
    Py_buffer v[3];
    if (get_matrices(args, spec, 3, v) < 0) return NULL;
    multiply_core(v[0].buf, v[1].buf, v[2].buf);
    release_all(v, 3);
    Py_RETURN_NONE;
}

#include "_eskf_timeline.h" /* the Timeline type (estimator.eskf_timeline's compiled twin), on the cores above */

static PyMethodDef methods[] = {
    {"propagate", (PyCFunction)(void (*)(void))propagate, METH_FASTCALL,
     "propagate(x, f0, w0, f1, w1, dt, g, F, index) -> x1 (estimator.eskf_kernels.propagate)"},
    {"predict_covariance", (PyCFunction)(void (*)(void))predict_covariance, METH_FASTCALL,
     "predict_covariance(P, F, Q, out): out = F P F' + Q (estimator.eskf_kernels)"},
    {"update_covariance", (PyCFunction)(void (*)(void))update_covariance, METH_FASTCALL,
     "update_covariance(P, z, r, index, P_out, dx_out) -> d2 (estimator.eskf_kernels)"},
    {"reset_covariance", (PyCFunction)(void (*)(void))reset_covariance, METH_FASTCALL,
     "reset_covariance(P, dtheta, out): out = G P G' (estimator.eskf_kernels)"},
    {"multiply", (PyCFunction)(void (*)(void))multiply, METH_FASTCALL,
     "multiply(A, B, out): out = A B (estimator.eskf_kernels)"},
    {NULL, NULL, 0, NULL},
};

static struct PyModuleDef module = {
    PyModuleDef_HEAD_INIT, "_eskf_kernels",
    "Compiled twin of estimator.eskf_kernels (the ESKF's per-sample propagation).", -1, methods,
};

PyMODINIT_FUNC PyInit__eskf_kernels(void) {
    if (read_module_float("model.frames", "SMALL_ANGLE_RAD", &small_angle_rad) < 0) return NULL;
    PyObject *created = PyModule_Create(&module);
    if (created == NULL) return NULL;
    if (add_timeline_type(created) < 0) {
        Py_DECREF(created);
        return NULL;
    }
    return created;
}
