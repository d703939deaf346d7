/* What the compiled kernels (estimator/_eskf_kernels.c, simulator/_dynamics_kernels.c,
   simulator/crazyflie/_drive_kernel.c, groundstation/_compensation_kernel.c, groundstation/_controller_kernel.c,
   groundstation/_flightlog_kernel.c, link/mavlink/_frame_kernel.c, link/_deliver_kernel.c) share: reading Python
   numbers into C doubles, building tuples and lists of floats, checking a call's argument count, interning
   attribute names, adding to an int attribute, and model.frames' quat_to_rows and quat_normalize_positive_w.
   Included by each; setup.py lists it in every extension's depends. */

#ifndef CFSTACK_KERNELS_H
#define CFSTACK_KERNELS_H

#define PY_SSIZE_T_CLEAN
#include <Python.h>
#include <math.h>
#include <string.h>

/* n numbers of a sequence into out; -1 with ValueError (wrong length) or TypeError (not a number) set */
static inline int read_floats(PyObject *seq, double *out, Py_ssize_t n, const char *name) {
    PyObject *fast = PySequence_Fast(seq, name);
    if (fast == NULL) return -1;
    if (PySequence_Fast_GET_SIZE(fast) != n) {
        PyErr_Format(PyExc_ValueError, "%s: expected %zd numbers, got %zd", name, n,
                     PySequence_Fast_GET_SIZE(fast));
        Py_DECREF(fast);
        return -1;
    }
    PyObject **items = PySequence_Fast_ITEMS(fast);
    for (Py_ssize_t i = 0; i < n; i++) {
        out[i] = PyFloat_AsDouble(items[i]);
        if (out[i] == -1.0 && PyErr_Occurred()) {
            Py_DECREF(fast);
            return -1;
        }
    }
    Py_DECREF(fast);
    return 0;
}

/* The first n numbers of a vector into out, where they are floats as they stand: a 1-D float64 buffer (a numpy
   array, read without conversion) or a sequence of floats (numpy's float64 is one). 0, or 1 with no error set
   where the vector is anything else (ints, say, whose arithmetic Python keeps exact; text; a set, a generator):
   the caller leaves it to its Python twin. `at_least`: n or more items, as the Python's indexing reads them;
   else exactly n, as its unpacking asks. */
static inline int read_float_vector(PyObject *obj, double *out, Py_ssize_t n, int at_least) {
    if (PyObject_CheckBuffer(obj)) {
        Py_buffer view;
        if (PyObject_GetBuffer(obj, &view, PyBUF_FORMAT | PyBUF_C_CONTIGUOUS) == 0) {
            Py_ssize_t count = view.len / (Py_ssize_t)sizeof(double);
            int ok = view.format != NULL && strcmp(view.format, "d") == 0 && view.ndim == 1 &&
                     (at_least ? count >= n : count == n);
            if (ok) memcpy(out, view.buf, (size_t)n * sizeof(double));
            PyBuffer_Release(&view);
            if (ok) return 0;
        } else {
            PyErr_Clear(); /* not a contiguous buffer: read as a sequence */
        }
    }
    if (!PySequence_Check(obj)) return 1; /* iterating a set or a generator would differ from (or spend) it */
    PyObject *fast = PySequence_Fast(obj, "a vector");
    if (fast == NULL) {
        PyErr_Clear();
        return 1;
    }
    Py_ssize_t count = PySequence_Fast_GET_SIZE(fast);
    int ok = at_least ? count >= n : count == n;
    for (Py_ssize_t i = 0; ok && i < n; i++) {
        PyObject *item = PySequence_Fast_GET_ITEM(fast, i);
        ok = PyFloat_Check(item);
        if (ok) out[i] = PyFloat_AS_DOUBLE(item);
    }
    Py_DECREF(fast);
    return ok ? 0 : 1;
}

/* module.name as a double, read once when a kernel module loads (a constant it shares with its twin);
   -1 with the import or attribute error set */
static inline int read_module_float(const char *module, const char *name, double *out) {
    PyObject *mod = PyImport_ImportModule(module);
    if (mod == NULL) return -1;
    PyObject *value = PyObject_GetAttrString(mod, name);
    Py_DECREF(mod);
    if (value == NULL) return -1;
    *out = PyFloat_AsDouble(value);
    Py_DECREF(value);
    return PyErr_Occurred() ? -1 : 0;
}

/* n doubles as a new tuple (list) of Python floats; NULL with the error set */
static inline PyObject *float_sequence(const double *values, Py_ssize_t n, int as_list) {
    PyObject *seq = as_list ? PyList_New(n) : PyTuple_New(n);
    if (seq == NULL) return NULL;
    for (Py_ssize_t i = 0; i < n; i++) {
        PyObject *item = PyFloat_FromDouble(values[i]);
        if (item == NULL) {
            Py_DECREF(seq);
            return NULL;
        }
        if (as_list)
            PyList_SET_ITEM(seq, i, item);
        else
            PyTuple_SET_ITEM(seq, i, item);
    }
    return seq;
}

static inline PyObject *float_tuple(const double *values, Py_ssize_t n) { return float_sequence(values, n, 0); }

static inline PyObject *float_list(const double *values, Py_ssize_t n) { return float_sequence(values, n, 1); }

/* -1 with TypeError unless a kernel got its `expected` number of arguments */
static inline int check_nargs(const char *kernel, Py_ssize_t nargs, Py_ssize_t expected) {
    if (nargs == expected) return 0;
    PyErr_Format(PyExc_TypeError, "%s takes %zd arguments (%zd given)", kernel, expected, nargs);
    return -1;
}

/* obj.name += delta, as Python's augmented assignment does it (get, add, set); -1 with the error set */
static inline int add_to_attr(PyObject *obj, PyObject *name, long long delta) {
    PyObject *value = PyObject_GetAttr(obj, name);
    if (value == NULL) return -1;
    PyObject *step = PyLong_FromLongLong(delta);
    PyObject *sum = step == NULL ? NULL : PyNumber_Add(value, step);
    Py_DECREF(value);
    Py_XDECREF(step);
    if (sum == NULL) return -1;
    int rc = PyObject_SetAttr(obj, name, sum);
    Py_DECREF(sum);
    return rc;
}

/* Intern each of n attribute names into out (a module's lookups by interned name); -1 with the error set. */
static inline int intern_names(const char *const *texts, PyObject **out, int n) {
    for (int i = 0; i < n; i++) {
        out[i] = PyUnicode_InternFromString(texts[i]);
        if (out[i] == NULL) return -1;
    }
    return 0;
}

/* model.frames.quat_to_rows */
static inline void quat_to_rows(const double q[4], double r[9]) {
    double w = q[0], x = q[1], y = q[2], z = q[3];
    double xx = x * x, yy = y * y, zz = z * z;
    double xy = x * y, xz = x * z, yz = y * z;
    double wx = w * x, wy = w * y, wz = w * z;
    r[0] = 1.0 - 2.0 * (yy + zz); r[1] = 2.0 * (xy - wz); r[2] = 2.0 * (xz + wy);
    r[3] = 2.0 * (xy + wz); r[4] = 1.0 - 2.0 * (xx + zz); r[5] = 2.0 * (yz - wx);
    r[6] = 2.0 * (xz - wy); r[7] = 2.0 * (yz + wx); r[8] = 1.0 - 2.0 * (xx + yy);
}

/* model.frames.quat_normalize_positive_w; -1 (ValueError set) for the zero quaternion */
static inline int quat_normalize_positive_w(double q[4]) {
    double n = sqrt(q[0] * q[0] + q[1] * q[1] + q[2] * q[2] + q[3] * q[3]);
    if (n == 0.0) {
        PyErr_SetString(PyExc_ValueError, "zero quaternion");
        return -1;
    }
    if (q[0] < 0.0) n = -n;
    q[0] = q[0] / n; q[1] = q[1] / n; q[2] = q[2] / n; q[3] = q[3] / n;
    return 0;
}

#endif
