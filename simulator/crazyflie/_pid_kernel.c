/* Compiled twin of three firmware PIDs updated together (issue 19): AttitudeController's
correct_attitude_python and correct_rate_python (simulator/crazyflie/attitude_controller.py), each three
simulator.crazyflie.pid.Pid.update calls, at 500 Hz in attitude, position and level flight.

update3 takes in: a tuple of three Pid objects (their gains and state are read from them and their state is
written back to them, as Pid.update does), the desired and the measured values (sequences of 3 floats: deg
or deg/s), whether the third PID's error and measurement step wrap to +-180 deg (the yaw angle PID), and
whether the outputs are saturated to int16 (the rate PIDs: attitude_controller.saturate_int16).
It gives out: a tuple of the three outputs (floats; ints when saturated), or None, having changed nothing,
where it would not do alike with the Python: an argument or attribute that is not a float (an int, a numpy
number), a zero dt (Python raises ZeroDivisionError), a saturated output that is NaN (int() raises
ValueError). The caller then runs the Python, which gives what Python gives, errors included.

Same result as the Python, bit for bit: every expression below is Pid.update's in the same order, one IEEE
double operation at a time (setup.py builds this file with -ffp-contract=off, so no multiply-add is fused);
min and max are Python's (the first argument unless the second compares beyond it, so NaN passes as
Python's does), and int() of a finite double within +-32767 truncates toward zero in both.
tests/simulator/test_pid_kernel.py checks the bits against the Python. */

#include "../../model/_kernels.h" /* includes Python.h; check_nargs, intern_names */

#define N_AXES 3
#define INT16_LIMIT 32767.0 /* attitude_controller.INT16_MAX: saturateSignedInt16's bound */
#define HALF_TURN_DEG 180.0 /* pid._wrap_deg */
#define TURN_DEG 360.0

/* Pid's fields, in the order read below (interned once at module load) */
enum { KP, KI, KD, KFF, DT_S, I_LIMIT, OUTPUT_LIMIT, INTEG, PREV_MEASURED, N_READ };
enum { OUT_P = N_READ, OUT_I, OUT_D, N_FIELDS };
static const char *FIELD_NAMES[N_FIELDS] = {"kp", "ki", "kd", "kff", "dt_s", "i_limit", "output_limit",
                                            "integ", "prev_measured", "out_p", "out_i", "out_d"};
static PyObject *field_names[N_FIELDS];

/* pid._wrap_deg */
static double wrap_deg(double angle) {
    if (angle > HALF_TURN_DEG) return angle - TURN_DEG;
    if (angle < -HALF_TURN_DEG) return angle + TURN_DEG;
    return angle;
}

/* Python's max(a, b) and min(a, b) on floats: a unless b compares beyond it */
static double py_max(double a, double b) { return b > a ? b : a; }
static double py_min(double a, double b) { return b < a ? b : a; }

/* 1 with the pid's fields read into f, 0 where one is not a float, -1 with an error set */
static int read_pid(PyObject *pid, double f[N_READ]) {
    for (int i = 0; i < N_READ; i++) {
        PyObject *value = PyObject_GetAttr(pid, field_names[i]);
        if (value == NULL) return -1;
        int is_float = PyFloat_CheckExact(value);
        if (is_float) f[i] = PyFloat_AS_DOUBLE(value);
        Py_DECREF(value);
        if (!is_float) return 0;
    }
    return 1;
}

/* 1 with seq's 3 items read into out, 0 where it is not a tuple or list of 3 floats */
static int read_exact_floats(PyObject *seq, double out[N_AXES]) {
    if (!(PyTuple_CheckExact(seq) || PyList_CheckExact(seq)) || PySequence_Fast_GET_SIZE(seq) != N_AXES) return 0;
    PyObject **items = PySequence_Fast_ITEMS(seq);
    for (int i = 0; i < N_AXES; i++) {
        if (!PyFloat_CheckExact(items[i])) return 0;
        out[i] = PyFloat_AS_DOUBLE(items[i]);
    }
    return 1;
}

/* Pid.update on the fields f (updated in place: integ, prev_measured, out_p, out_i, out_d); the output */
static double pid_update(double f[N_FIELDS], double desired, double measured, int is_yaw_angle) {
    double error = desired - measured;
    double delta = -(measured - f[PREV_MEASURED]);
    if (is_yaw_angle) {
        error = wrap_deg(error);
        delta = wrap_deg(delta);
    }
    f[OUT_P] = f[KP] * error;
    f[OUT_D] = f[KD] * delta / f[DT_S];
    double integ = f[INTEG] + error * f[DT_S];
    if (f[I_LIMIT] != 0.0) integ = py_min(py_max(integ, -f[I_LIMIT]), f[I_LIMIT]);
    f[INTEG] = integ;
    f[OUT_I] = f[KI] * integ;
    double output = f[OUT_P] + f[OUT_D] + f[OUT_I] + f[KFF] * desired;
    if (f[OUTPUT_LIMIT] != 0.0) output = py_min(py_max(output, -f[OUTPUT_LIMIT]), f[OUTPUT_LIMIT]);
    f[PREV_MEASURED] = measured;
    return output;
}

/* attitude_controller.saturate_int16 on a non-NaN value */
static long saturate_int16(double value) {
    if (value > INT16_LIMIT) return (long)INT16_LIMIT;
    if (value < -INT16_LIMIT) return -(long)INT16_LIMIT;
    return (long)value;
}

/* The written fields back into the pid; -1 with an error set */
static int write_pid(PyObject *pid, const double f[N_FIELDS]) {
    static const int written[] = {INTEG, PREV_MEASURED, OUT_P, OUT_I, OUT_D};
    for (size_t i = 0; i < sizeof written / sizeof written[0]; i++) {
        PyObject *value = PyFloat_FromDouble(f[written[i]]);
        if (value == NULL) return -1;
        int failed = PyObject_SetAttr(pid, field_names[written[i]], value);
        Py_DECREF(value);
        if (failed) return -1;
    }
    return 0;
}

static PyObject *update3(PyObject *self, PyObject *const *args, Py_ssize_t nargs) {
    (void)self;
    if (check_nargs("update3", nargs, 5) < 0) return NULL;
    PyObject *pids = args[0];
    int wrap_last = PyObject_IsTrue(args[3]), saturate = PyObject_IsTrue(args[4]);
    if (wrap_last < 0 || saturate < 0) return NULL;
    double desired[N_AXES], measured[N_AXES], fields[N_AXES][N_FIELDS], out[N_AXES];
    if (!PyTuple_CheckExact(pids) || PyTuple_GET_SIZE(pids) != N_AXES || !read_exact_floats(args[1], desired) ||
        !read_exact_floats(args[2], measured))
        Py_RETURN_NONE;
    for (int i = 0; i < N_AXES; i++) {
        int read = read_pid(PyTuple_GET_ITEM(pids, i), fields[i]);
        if (read < 0) return NULL;
        if (read == 0 || fields[i][DT_S] == 0.0) Py_RETURN_NONE;
    }
    for (int i = 0; i < N_AXES; i++) {
        out[i] = pid_update(fields[i], desired[i], measured[i], wrap_last && i == N_AXES - 1);
        if (saturate && isnan(out[i])) Py_RETURN_NONE; /* int(nan) raises: nothing is written yet */
    }
    PyObject *result = PyTuple_New(N_AXES);
    if (result == NULL) return NULL;
    for (int i = 0; i < N_AXES; i++) {
        PyObject *item = saturate ? PyLong_FromLong(saturate_int16(out[i])) : PyFloat_FromDouble(out[i]);
        if (item == NULL || write_pid(PyTuple_GET_ITEM(pids, i), fields[i]) < 0) {
            Py_XDECREF(item);
            Py_DECREF(result);
            return NULL;
        }
        PyTuple_SET_ITEM(result, i, item);
    }
    return result;
}

static PyMethodDef methods[] = {
    {"update3", (PyCFunction)(void (*)(void))update3, METH_FASTCALL,
     "update3(pids, desired, measured, wrap_last, saturate) -> the three outputs, or None (see the file)"},
    {NULL, NULL, 0, NULL},
};

static struct PyModuleDef module = {PyModuleDef_HEAD_INIT, "_pid_kernel", NULL, -1, methods};

PyMODINIT_FUNC PyInit__pid_kernel(void) {
    if (intern_names(FIELD_NAMES, field_names, N_FIELDS) < 0) return NULL;
    return PyModule_Create(&module);
}
