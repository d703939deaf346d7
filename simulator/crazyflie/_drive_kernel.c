/* Compiled twins of the faithful firmware's power stage, once per 500 Hz stabilizer cycle (issue 19):
drive, of the drive chain CrazyflieFirmware._drive_python (simulator/crazyflie/stabilizer.py), and
force_torque_pwm, of power_distribution.ForceTorqueMixer.pwm.

drive takes in: the four uncapped motor commands (a tuple of 4 ints, PWM units), the filtered supply voltage
the firmware measures (V), the battery's terminal voltage (V) and charge drawn (A s), and the constants of
drive_kernel.drive_constants (N_CONSTANTS floats: the thrust curve, the PWM and idle limits, the supply
filter, the battery, the step, k_T).
It gives out: (motor PWM: a tuple of 4 ints; motor forces N: a tuple of 4 floats; rotor speeds rad/s: a tuple
of 4 floats, or None for motors off; the new supply voltage V; the battery's new terminal voltage V, current A
and charge drawn A s).
force_torque_pwm takes in: the collective thrust (N), the torques (3 floats, N m, body FLU) and the mixer's
constants (0.25 / arm m, thrust-to-torque m, PWM per N); gives out the four uncapped commands (a tuple of 4
ints, PWM units).
Both give None where they would not do alike with the Python (a command that is not a tuple of 4 ints within
2^53, a value Python would refuse: the square root of a negative, a negative number to a fractional power, a
division by zero, an overflow, a result that is not an int within 2^53): the caller then runs the Python,
which gives what Python gives, errors included.

Same result as the Python, bit for bit: every expression below is the Python's in the same order, one IEEE
double operation at a time (setup.py builds this file with -ffp-contract=off, so no multiply-add is fused);
`**` is CPython's float_pow (py_pow below: its special cases, then the C library's pow, the one Python
calls), sqrt and int() truncation are exact in both, and the ints stay below 2^53 (exact as doubles).
tests/simulator/test_drive_kernel.py checks the bits against the Python. */

#include "../../model/_kernels.h" /* includes Python.h; read_floats, float_tuple, check_nargs */
#include <math.h>

#define N_MOTORS 4
#define N_CONSTANTS 19
#define EXACT_INT_LIMIT 9007199254740992.0 /* 2^53: every integer below it is a double */

/* The constants' order (drive_kernel.drive_constants) */
enum {
    V0, V1, V2, V3, THRUST_MIN_N, THRUST_MAX_N, PWM_MAX, MIN_SUPPLY_V, IDLE_PWM, SUPPLY_B,
    EMPTY_V, FULL_V, CAPACITY_AS, R_OHM, MOTOR_HOVER_W, MOTOR_HOVER_N, POWER_EXPONENT, DT_S, K_THRUST,
};

/* Python's a / b: -1 where Python raises ZeroDivisionError */
static int py_div(double a, double b, double *out) {
    if (b == 0.0) return -1;
    *out = a / b;
    return 0;
}

static int is_odd_integer(double y) { return fmod(fabs(y), 2.0) == 1.0; }

/* CPython's float ** float for finite y (Objects/floatobject.c float_pow): 0 with *out set, or -1 where Python
   raises (ZeroDivisionError, OverflowError) or answers with a complex number */
static int py_pow(double x, double y, double *out) {
    if (!isfinite(y)) return -1; /* not a case the drive chain meets: left to Python */
    if (y == 0.0) {
        *out = 1.0;
        return 0;
    }
    if (isnan(x)) {
        *out = x;
        return 0;
    }
    if (isinf(x)) {
        int odd = is_odd_integer(y);
        *out = y > 0.0 ? (odd ? x : fabs(x)) : (odd ? copysign(0.0, x) : 0.0);
        return 0;
    }
    if (x == 0.0) {
        if (y < 0.0) return -1;
        *out = is_odd_integer(y) ? x : 0.0;
        return 0;
    }
    int negate = 0;
    if (x < 0.0) {
        if (y != floor(y)) return -1;
        x = -x;
        negate = is_odd_integer(y);
    }
    if (x == 1.0) {
        *out = negate ? -1.0 : 1.0;
        return 0;
    }
    double r = pow(x, y);
    if (isinf(r)) return -1;
    *out = negate ? -r : r;
    return 0;
}

/* motors._cbrt: copysign(|x| ** (1/3), x) */
static int cbrt_signed(double x, double *out) {
    double root;
    if (py_pow(fabs(x), 1.0 / 3.0, &root) < 0) return -1;
    *out = copysign(root, x);
    return 0;
}

/* ThrustCurve.motor_voltage_v */
static int motor_voltage_v(const double *c, double thrust_n, double *out) {
    double p, q_tail, r, cube, a, b;
    if (py_div(-c[V2], 3.0 * c[V3], &p) < 0
        || py_div(c[V2] * c[V1] - 3.0 * c[V3] * (c[V0] - thrust_n), 6.0 * c[V3] * c[V3], &q_tail) < 0
        || py_div(c[V1], 3.0 * c[V3], &r) < 0 || py_pow(r - p * p, 3.0, &cube) < 0)
        return -1;
    double q = p * p * p + q_tail;
    double radicand = q * q + cube;
    if (radicand < 0.0) return -1; /* math.sqrt: ValueError */
    double qrp = sqrt(radicand);
    if (cbrt_signed(q + qrp, &a) < 0 || cbrt_signed(q - qrp, &b) < 0) return -1;
    *out = a + b + p;
    return 0;
}

/* int(ThrustCurve.compensate(pwm, supply_v)): the battery-compensated command, truncated */
static int compensate(const double *c, long long pwm, double supply_v, long long *out) {
    double ratio = 0.0;
    if (!(supply_v < c[MIN_SUPPLY_V])) {
        double share, volts;
        if (py_div((double)pwm, c[PWM_MAX], &share) < 0) return -1;
        double thrust = share * c[THRUST_MAX_N];
        if (!(thrust < c[THRUST_MIN_N])) {
            if (motor_voltage_v(c, thrust, &volts) < 0 || py_div(c[PWM_MAX] * volts, supply_v, &ratio) < 0)
                return -1;
        }
    }
    if (!isfinite(ratio) || !(fabs(ratio) < EXACT_INT_LIMIT)) return -1;
    *out = (long long)ratio; /* truncation toward zero, as int() */
    return 0;
}

/* ThrustCurve.thrust_n: max(0.0, V0 + v (V1 + v (V2 + v V3))), v = battery_v pwm / pwm_max */
static int thrust_n(const double *c, long long pwm, double battery_v, double *out) {
    double v;
    if (py_div(battery_v * (double)pwm, c[PWM_MAX], &v) < 0) return -1;
    double f = c[V0] + v * (c[V1] + v * (c[V2] + v * c[V3]));
    *out = f > 0.0 ? f : 0.0;
    return 0;
}

/* Battery.step: the terminal voltage, current and charge drawn after drawing the motors' power for dt */
static int battery_step(const double *c, const double forces[N_MOTORS], double drawn_as, double out[3]) {
    double used, per_n, total = 0.0;
    if (py_div(drawn_as, c[CAPACITY_AS], &used) < 0 || py_div(1.0, c[MOTOR_HOVER_N], &per_n) < 0) return -1;
    double left = 1.0 - used;
    double v_oc = c[EMPTY_V] + (c[FULL_V] - c[EMPTY_V]) * (left > 0.0 ? left : 0.0);
    for (int i = 0; i < N_MOTORS; i++) {
        double term;
        if (py_pow((0.0 > forces[i] ? 0.0 : forces[i]) * per_n, c[POWER_EXPONENT], &term) < 0) return -1;
        total += term;
    }
    double power = c[MOTOR_HOVER_W] * total;
    double disc = v_oc * v_oc - 4.0 * c[R_OHM] * power;
    double v = disc > 0.0 ? 0.5 * (v_oc + sqrt(disc)) : 0.5 * v_oc;
    double current = v > 0.0 ? power / v : 0.0;
    out[0] = v;
    out[1] = current;
    out[2] = drawn_as + current * c[DT_S];
    return 0;
}

/* the uncapped commands as C integers: -1 (no error set) unless a tuple of 4 ints within 2^53 */
static int read_commands(PyObject *uncapped, long long out[N_MOTORS]) {
    if (!PyTuple_CheckExact(uncapped) || PyTuple_GET_SIZE(uncapped) != N_MOTORS) return -1;
    for (int i = 0; i < N_MOTORS; i++) {
        PyObject *item = PyTuple_GET_ITEM(uncapped, i);
        if (!PyLong_CheckExact(item)) return -1;
        int overflow;
        out[i] = PyLong_AsLongLongAndOverflow(item, &overflow);
        if (overflow || (out[i] == -1 && PyErr_Occurred())) {
            PyErr_Clear();
            return -1;
        }
        if (!((double)llabs(out[i]) < EXACT_INT_LIMIT)) return -1;
    }
    return 0;
}

static PyObject *int_tuple(const long long values[N_MOTORS]) {
    return Py_BuildValue("(LLLL)", values[0], values[1], values[2], values[3]);
}

/* drive(uncapped, supply_v, battery_v, drawn_as, constants) -> (pwm, forces, speeds | None, supply_v,
   battery_v, current_a, drawn_as) | None: CrazyflieFirmware._drive_python */
static PyObject *drive(PyObject *self, PyObject *const *args, Py_ssize_t nargs) {
    (void)self;
    if (check_nargs("drive", nargs, 5) < 0) return NULL;
    double c[N_CONSTANTS], state[3];
    for (int i = 0; i < 3; i++) {
        state[i] = PyFloat_AsDouble(args[1 + i]);
        if (state[i] == -1.0 && PyErr_Occurred()) return NULL;
    }
    if (read_floats(args[4], c, N_CONSTANTS, "constants") < 0) return NULL;
    long long uncapped[N_MOTORS], compensated[N_MOTORS], pwm[N_MOTORS];
    if (read_commands(args[0], uncapped) < 0) Py_RETURN_NONE;
    double battery_v = state[1];
    double supply_v = state[0] + c[SUPPLY_B] * (battery_v - state[0]);
    for (int i = 0; i < N_MOTORS; i++)
        if (compensate(c, uncapped[i], supply_v, &compensated[i]) < 0) Py_RETURN_NONE;
    /* power_distribution.cap: shift all down by the excess of the highest over pwm_max, floor at idle */
    long long highest = compensated[0], pwm_max = (long long)c[PWM_MAX], idle = (long long)c[IDLE_PWM];
    for (int i = 1; i < N_MOTORS; i++) highest = compensated[i] > highest ? compensated[i] : highest;
    long long reduction = highest - pwm_max > 0 ? highest - pwm_max : 0;
    double forces[N_MOTORS], speeds[N_MOTORS], battery[3];
    int any = 0;
    for (int i = 0; i < N_MOTORS; i++) {
        long long shifted = compensated[i] - reduction;
        pwm[i] = shifted > idle ? shifted : idle;
        if (thrust_n(c, pwm[i], battery_v, &forces[i]) < 0) Py_RETURN_NONE;
        any |= forces[i] != 0.0;
    }
    if (battery_step(c, forces, state[2], battery) < 0) Py_RETURN_NONE;
    for (int i = 0; i < N_MOTORS && any; i++) {
        double ratio;
        if (py_div(forces[i], c[K_THRUST], &ratio) < 0 || ratio < 0.0) Py_RETURN_NONE; /* sqrt: ValueError */
        speeds[i] = sqrt(ratio);
    }
    PyObject *pwm_out = int_tuple(pwm), *forces_out = float_tuple(forces, N_MOTORS);
    PyObject *speeds_out = any ? float_tuple(speeds, N_MOTORS) : Py_NewRef(Py_None);
    if (pwm_out == NULL || forces_out == NULL || speeds_out == NULL) {
        Py_XDECREF(pwm_out);
        Py_XDECREF(forces_out);
        Py_XDECREF(speeds_out);
        return NULL;
    }
    return Py_BuildValue("(NNNdddd)", pwm_out, forces_out, speeds_out, supply_v, battery[0], battery[1],
                         battery[2]);
}

/* force_torque_pwm(thrust_n, torque_flu_nm, (0.25 / arm, thrust_to_torque, pwm per N)) -> (4 ints) | None:
   ForceTorqueMixer.pwm, the per-motor forces of the force-torque command as PWM, truncated (a force that is not
   finite gives 0, as _int32) */
static PyObject *force_torque_pwm(PyObject *self, PyObject *const *args, Py_ssize_t nargs) {
    (void)self;
    if (check_nargs("force_torque_pwm", nargs, 3) < 0) return NULL;
    double thrust = PyFloat_AsDouble(args[0]);
    if (thrust == -1.0 && PyErr_Occurred()) return NULL;
    double torque[3], c[3];
    if (read_floats(args[1], torque, 3, "torque_flu_nm") < 0 || read_floats(args[2], c, 3, "mixer") < 0) return NULL;
    double quarter_per_arm = c[0], roll = quarter_per_arm * torque[0], pitch = quarter_per_arm * torque[1];
    double yaw, t = 0.25 * thrust;
    if (py_div(0.25 * torque[2], c[1], &yaw) < 0) Py_RETURN_NONE;
    double forces[N_MOTORS] = {t - roll - pitch - yaw, t - roll + pitch + yaw, t + roll + pitch - yaw,
                               t + roll - pitch + yaw};
    long long pwm[N_MOTORS];
    for (int i = 0; i < N_MOTORS; i++) {
        double scaled = (0.0 > forces[i] ? 0.0 : forces[i]) * c[2];
        if (!isfinite(scaled)) {
            pwm[i] = 0;
            continue;
        }
        if (!(fabs(scaled) < EXACT_INT_LIMIT)) Py_RETURN_NONE;
        pwm[i] = (long long)scaled;
    }
    return int_tuple(pwm);
}

static PyMethodDef methods[] = {
    {"drive", (PyCFunction)(void (*)(void))drive, METH_FASTCALL,
     "drive(uncapped, supply_v, battery_v, drawn_as, constants) -> (pwm, forces, speeds | None, supply_v, "
     "battery_v, current_a, drawn_as) | None (simulator.crazyflie.drive_kernel)"},
    {"force_torque_pwm", (PyCFunction)(void (*)(void))force_torque_pwm, METH_FASTCALL,
     "force_torque_pwm(thrust_n, torque_flu_nm, mixer) -> (4 ints) | None (simulator.crazyflie.drive_kernel)"},
    {NULL, NULL, 0, NULL},
};

static struct PyModuleDef module = {
    PyModuleDef_HEAD_INIT, "_drive_kernel",
    "Compiled twin of the faithful firmware's drive chain (simulator.crazyflie.drive_kernel).", -1, methods,
};

PyMODINIT_FUNC PyInit__drive_kernel(void) { return PyModule_Create(&module); }
