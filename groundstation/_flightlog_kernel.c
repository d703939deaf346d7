/* Compiled twin of states.csv's row formatting (groundstation.flightlog, issue 19): FlightLog's Python row line,
once per control tick, after the tick's ack.

format_row takes in FlightLog.row's 19 arguments, in its order: t_s, phase (text), the blocks truth (10), estimate
(10), sigma (9), reference (6), moment_cmd (4) and attitude_cmd (4) (each None or a tuple or list of that many
floats), saturated and healthy (None or a bool), mocap_age_s (None or a float), uplink_sent, downlink_received
and downlink_lost (ints), rtt_ms, tick_time_ms, est_time_s, truth_time_s and battery_v (None or a float).
It gives out the row's line (text, newline included), or None where it would not do alike with the Python: any
value of another type (an int where a float goes, a numpy bool, a generator for a block), a block of the wrong
length, non-ASCII phase text. The caller then runs the Python, which gives what Python gives, errors included.
format_number(x) -> the text of one float, for the tests.

Same text as the Python, whose numbers are "%.12g" % x (PyOS_double_to_string(x, 'g', 12, 0): the value correctly
rounded to 12 significant digits, ties to even; no trailing zeros; exponent form when the decimal exponent is
below -4 or above 11, with a sign and at least two digits). The fast path finds the 12 digits with one long
double operation: x times (or over) an exact power of ten (10^k, |k| <= 27, has at most 63 significant bits, so
it is exact in x86's 64-bit significand), giving s in [1e11, 1e12) with an error below 2^-64 of s, under 6e-8.
Rounding s to an integer then gives the correctly rounded digits unless s's fraction lies within that error of
1/2; within TIE_MARGIN of 1/2 (ties included), and for zero's sign, infinities, NaN, numbers whose power of ten
is out of the table, and wherever long double has less than 64 significant bits, the kernel asks Python's own
PyOS_double_to_string. tests/groundstation/test_flightlog_kernel.py compares the two on millions of numbers
(every magnitude, the rounding boundaries and their neighbours) and rows. */

#include "../model/_kernels.h" /* includes Python.h */
#include <float.h>
#include <stdint.h>

#define SIG_DIGITS 12
#define MAX_POW10 27
#define TIE_MARGIN 1e-6L         /* |fraction - 1/2| below this: Python's dtoa decides (the error is < 6e-8) */
#define LINE_CAPACITY 4096       /* 55 cells of at most 25 characters, the phase's text and the commas */
#define MAX_PHASE 256            /* longer phase text: the Python's */
#define NUMBER_CAPACITY 32       /* "-1.23456789012e-308" and the like */
#define N_ARGS 19

#if LDBL_MANT_DIG >= 64
#define FAST_PATH 1
static const long double POW10[MAX_POW10 + 1] = {
    1e0L,  1e1L,  1e2L,  1e3L,  1e4L,  1e5L,  1e6L,  1e7L,  1e8L,  1e9L,  1e10L, 1e11L, 1e12L, 1e13L,
    1e14L, 1e15L, 1e16L, 1e17L, 1e18L, 1e19L, 1e20L, 1e21L, 1e22L, 1e23L, 1e24L, 1e25L, 1e26L, 1e27L,
};
#else
#define FAST_PATH 0
#endif

/* Python's text of x, written at out; its length, or -1 with MemoryError set */
static int python_number(double x, char *out) {
    char *text = PyOS_double_to_string(x, 'g', SIG_DIGITS, 0, NULL);
    if (text == NULL) return -1;
    size_t n = strlen(text);
    if (n >= NUMBER_CAPACITY) { /* cannot happen for 12 digits; the Python's turn if it did */
        PyMem_Free(text);
        PyErr_SetString(PyExc_OverflowError, "format_number: text too long");
        return -1;
    }
    memcpy(out, text, n);
    PyMem_Free(text);
    return (int)n;
}

#if FAST_PATH
/* a * 10^(11 - e) for a > 0: s in [1e11, 1e12) when e is a's decimal exponent; 0 when 10^|11 - e| is not exact */
static long double scaled(double a, int e) {
    int k = SIG_DIGITS - 1 - e;
    if (k > MAX_POW10 || k < -MAX_POW10) return 0.0L;
    return k >= 0 ? (long double)a * POW10[k] : (long double)a / POW10[-k];
}

/* The 12 digits of a > 0 (finite) into *digits (in [1e11, 1e12)) and its decimal exponent into *e; 0, or 1
   where the fast path cannot decide (the caller asks Python) */
static int twelve_digits(double a, uint64_t *digits, int *e) {
    int exp10 = (int)floor(log10(a));
    long double s = scaled(a, exp10);
    if (s != 0.0L && s < 1e11L) s = scaled(a, --exp10); /* log10 rounded up across a power of ten */
    else if (s >= 1e12L) s = scaled(a, ++exp10);         /* or down */
    if (s < 1e11L || s >= 1e12L) return 1;               /* out of the table (or still not found) */
    long double whole = floorl(s);
    long double fraction = s - whole; /* exact: s < 2^40 */
    if (fabsl(fraction - 0.5L) < TIE_MARGIN) return 1;
    uint64_t n = (uint64_t)whole + (fraction > 0.5L);
    if (n == 1000000000000ULL) { /* rounded up to the next power of ten */
        n = 100000000000ULL;
        exp10++;
    }
    *digits = n;
    *e = exp10;
    return 0;
}
#endif

/* "%.12g" % x written at out (no terminator); its length, or -1 with an error set */
static int format_number(double x, char *out) {
#if FAST_PATH
    uint64_t n;
    int e;
    if (x == 0.0 || !isfinite(x) || twelve_digits(fabs(x), &n, &e)) return python_number(x, out);
    char digits[SIG_DIGITS];
    for (int i = SIG_DIGITS - 1; i >= 0; i--) {
        digits[i] = (char)('0' + n % 10);
        n /= 10;
    }
    int nd = SIG_DIGITS;
    while (nd > 1 && digits[nd - 1] == '0') nd--; /* no trailing zeros */
    char *p = out;
    if (x < 0) *p++ = '-';
    int decpt = e + 1; /* the value is 0.d1d2... x 10^decpt */
    if (decpt <= -4 || decpt > SIG_DIGITS) {
        *p++ = digits[0];
        if (nd > 1) {
            *p++ = '.';
            memcpy(p, digits + 1, (size_t)(nd - 1));
            p += nd - 1;
        }
        *p++ = 'e';
        *p++ = e < 0 ? '-' : '+';
        int mag = e < 0 ? -e : e; /* two digits: the table's powers keep |e| under 40 */
        *p++ = (char)('0' + mag / 10);
        *p++ = (char)('0' + mag % 10);
    } else if (decpt <= 0) {
        *p++ = '0';
        *p++ = '.';
        memset(p, '0', (size_t)(-decpt));
        p += -decpt;
        memcpy(p, digits, (size_t)nd);
        p += nd;
    } else if (decpt < nd) {
        memcpy(p, digits, (size_t)decpt);
        p += decpt;
        *p++ = '.';
        memcpy(p, digits + decpt, (size_t)(nd - decpt));
        p += nd - decpt;
    } else {
        memcpy(p, digits, (size_t)nd);
        p += nd;
        memset(p, '0', (size_t)(decpt - nd));
        p += decpt - nd;
    }
    return (int)(p - out);
#else
    return python_number(x, out);
#endif
}

typedef struct {
    char *p, *end;
} Line;

/* Return what a put_ gave unless it is 0 (go on) */
#define PUT(call)             \
    do {                      \
        int put_ = (call);    \
        if (put_) return put_; \
    } while (0)

/* 0; 1 where the row is not the kernel's (no error set); -1 with an error set */
static int put_number(Line *line, PyObject *obj) {
    if (!PyFloat_Check(obj)) return 1; /* an int, text, ...: "%.12g" % obj is the Python's */
    if (line->end - line->p < NUMBER_CAPACITY) return 1;
    int n = format_number(PyFloat_AS_DOUBLE(obj), line->p);
    if (n < 0) return -1;
    line->p += n;
    return 0;
}

static int put_text(Line *line, const char *text, Py_ssize_t n) {
    if (line->end - line->p < n) return 1;
    memcpy(line->p, text, (size_t)n);
    line->p += n;
    return 0;
}

static int put_comma(Line *line) { return put_text(line, ",", 1); }

/* _cells: `count` cells, empty for None */
static int put_block(Line *line, PyObject *values, Py_ssize_t count) {
    if (values == Py_None) {
        for (Py_ssize_t i = 0; i < count - 1; i++)
            if (put_comma(line)) return 1;
        return 0;
    }
    if (!PyTuple_CheckExact(values) && !PyList_CheckExact(values)) return 1;
    if (PySequence_Fast_GET_SIZE(values) != count) return 1; /* the Python raises its ValueError */
    PyObject **items = PySequence_Fast_ITEMS(values);
    for (Py_ssize_t i = 0; i < count; i++) {
        if (i) PUT(put_comma(line));
        PUT(put_number(line, items[i]));
    }
    return 0;
}

/* _cell: empty for None */
static int put_optional_number(Line *line, PyObject *obj) { return obj == Py_None ? 0 : put_number(line, obj); }

/* "" for None, else str(int(flag)) for a bool */
static int put_flag(Line *line, PyObject *obj) {
    if (obj == Py_None) return 0;
    if (!PyBool_Check(obj)) return 1;
    return put_text(line, obj == Py_True ? "1" : "0", 1);
}

/* str(count) for an int (not a bool: str(True) is "True") */
static int put_count(Line *line, PyObject *obj) {
    if (!PyLong_CheckExact(obj)) return 1;
    int overflow;
    long long v = PyLong_AsLongLongAndOverflow(obj, &overflow);
    if (overflow) return 1; /* beyond 64 bits: the Python's */
    char text[24];
    int n = snprintf(text, sizeof text, "%lld", v);
    return put_text(line, text, n);
}

static int put_phase(Line *line, PyObject *obj) {
    if (!PyUnicode_CheckExact(obj) || !PyUnicode_IS_ASCII(obj)) return 1;
    Py_ssize_t n = PyUnicode_GET_LENGTH(obj);
    if (n > MAX_PHASE) return 1;
    return put_text(line, (const char *)PyUnicode_DATA(obj), n);
}

static const Py_ssize_t BLOCK_SIZES[6] = {10, 10, 9, 6, 4, 4}; /* flightlog._BLOCKS, in the row's order */

/* The row of FlightLog.row's arguments; 0, 1 (the Python's) or -1 */
static int put_row(Line *line, PyObject *const *a) {
    PUT(put_number(line, a[0]));
    PUT(put_comma(line));
    PUT(put_phase(line, a[1]));
    for (int b = 0; b < 6; b++) {
        PUT(put_comma(line));
        PUT(put_block(line, a[2 + b], BLOCK_SIZES[b]));
    }
    PUT(put_comma(line));
    PUT(put_flag(line, a[8]));
    PUT(put_comma(line));
    PUT(put_optional_number(line, a[9]));
    PUT(put_comma(line));
    PUT(put_flag(line, a[10]));
    for (int i = 11; i < 14; i++) {
        PUT(put_comma(line));
        PUT(put_count(line, a[i]));
    }
    for (int i = 14; i < N_ARGS; i++) {
        PUT(put_comma(line));
        PUT(put_optional_number(line, a[i]));
    }
    return put_text(line, "\n", 1);
}

/* format_row(19 arguments of FlightLog.row) -> str | None */
static PyObject *format_row(PyObject *self, PyObject *const *args, Py_ssize_t nargs) {
    (void)self;
    if (check_nargs("format_row", nargs, N_ARGS)) return NULL;
    char buffer[LINE_CAPACITY];
    Line line = {buffer, buffer + LINE_CAPACITY};
    int r = put_row(&line, args);
    if (r < 0) return NULL;
    if (r) Py_RETURN_NONE;
    Py_ssize_t n = line.p - buffer;
    PyObject *text = PyUnicode_New(n, 127);
    if (text != NULL) memcpy(PyUnicode_DATA(text), buffer, (size_t)n);
    return text;
}

/* format_number(x) -> str */
static PyObject *format_number_py(PyObject *self, PyObject *arg) {
    (void)self;
    double x = PyFloat_AsDouble(arg);
    if (x == -1.0 && PyErr_Occurred()) return NULL;
    char text[NUMBER_CAPACITY];
    int n = format_number(x, text);
    if (n < 0) return NULL;
    return PyUnicode_FromStringAndSize(text, n);
}

static PyMethodDef methods[] = {
    {"format_row", (PyCFunction)(void (*)(void))format_row, METH_FASTCALL,
     "format_row(t_s, phase, truth, estimate, sigma, reference, moment_cmd, attitude_cmd, saturated, mocap_age_s, "
     "healthy, uplink_sent, downlink_received, downlink_lost, rtt_ms, tick_time_ms, est_time_s, truth_time_s, "
     "battery_v) -> str | None (groundstation.flightlog_kernel)"},
    {"format_number", format_number_py, METH_O, "format_number(x) -> '%.12g' % x"},
    {NULL, NULL, 0, NULL},
};

static struct PyModuleDef module = {
    PyModuleDef_HEAD_INIT, "_flightlog_kernel",
    "Compiled twin of states.csv's row formatting (groundstation.flightlog_kernel).", -1, methods,
};

PyMODINIT_FUNC PyInit__flightlog_kernel(void) { return PyModule_Create(&module); }
