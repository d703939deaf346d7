/* Compiled twin of the MAVLink encoder for the messages a lockstep tick sends (link.mavlink.codec, issue 19):
Codec.encode of ImuSample, TruthState, MocapPose, ExternalPose, ThrustMoment and AttitudeTarget, unsigned.
The emulator encodes about eleven such frames per 100 Hz tick (five IMU samples, five truths, the mocap pose),
the ground station one or two per tick on its critical path.

encode_frame takes in: the kind (link.mavlink.frame_kernel's KIND_* order), the message, the frame's sequence
number, source system id, component id and target system, and the codec's limits (max moments N m about x, y, z
and max thrust N, as floats; None without limits). It gives out the whole frame (bytes): payload packed as the
wire's struct packs it, zero-truncated, header, CRC-16/MCRF4XX over header, payload and CRC_EXTRA. It gives
None where the Python might not do alike, and changes nothing then: a field that is not a float (an int,
whose arithmetic Python keeps exact, a numpy float32, text), a vector of the wrong length, a time the wire
cannot hold (negative, non-finite, too large for its integer), a value too large for a float32 (struct raises),
a target system outside 0..255, no limits for a normalised message. The caller then runs the Python, which
gives what Python gives, errors included.

configure (called once by frame_kernel at import) takes the constants from the Python twin: sqrt(1/2) of the
quaternion conversion, and per kind the message id, CRC_EXTRA and the fixed tail (IMU: fields_updated;
mocap and truth: the packed bytes after the state).

Same bytes as the Python: every number is the Python expression's, one IEEE double operation at a time (setup.py
builds with -ffp-contract=off), converted to float32 by a C cast as struct's PyFloat_Pack4 does, and times are
rounded as Python's round() rounds (half to even). tests/link/test_frame_kernel.py compares the two. */

/* includes Python.h and math.h; check_nargs */
#include "../../model/_kernels.h"
#include <stdint.h>
#include <string.h>

#define MAGIC_V2 0xFD
#define HEADER_LEN 10 /* magic, len, incompat, compat, seq, sysid, compid, msgid (3) */
#define MAX_PAYLOAD 255
#define N_TAIL 256

/* The kinds, in link.mavlink.frame_kernel's KINDS order */
enum { KIND_IMU, KIND_MOCAP, KIND_EXTERNAL_POSE, KIND_TRUTH, KIND_THRUST_MOMENT, KIND_ATTITUDE_TARGET, N_KINDS };
/* Which wire each kind goes out on (an external pose is a mocap frame) */
enum { WIRE_IMU, WIRE_MOCAP, WIRE_TRUTH, WIRE_ACTUATOR, WIRE_ATTITUDE, N_WIRES };
static const int WIRE_OF_KIND[N_KINDS] = {WIRE_IMU, WIRE_MOCAP, WIRE_MOCAP, WIRE_TRUTH, WIRE_ACTUATOR,
                                          WIRE_ATTITUDE};

typedef struct {
    uint32_t msgid;
    uint8_t crc_extra;
    unsigned char tail[N_TAIL];
    Py_ssize_t tail_len;
    unsigned long fields_updated; /* IMU only */
} Wire;

static Wire wires[N_WIRES];
static double sqrt_half = 0.0;
static int configured = 0;

enum { A_TIME, A_FORCE, A_RATE, A_POSITION, A_ATTITUDE, A_VELOCITY, A_THRUST, A_MOMENT, A_RATES, N_ATTRS };
static const char *ATTR_NAMES[N_ATTRS] = {"time_s", "specific_force_flu_mps2", "rate_flu_radps", "position_enu_m",
                                          "attitude_wxyz", "velocity_enu_mps", "thrust_n", "moment_flu_nm",
                                          "rates_flu_radps"};
static PyObject *attr_names[N_ATTRS];

/* ------------------------------------------------------------------------ reading the message */

/* The float attribute attr of msg into out: 0, or 1 (nothing set) where it is not a float, -1 on error */
static int read_float_attr(PyObject *msg, int attr, double *out) {
    PyObject *value = PyObject_GetAttr(msg, attr_names[attr]);
    if (value == NULL) return -1;
    int ok = PyFloat_Check(value);
    if (ok) *out = PyFloat_AS_DOUBLE(value);
    Py_DECREF(value);
    return ok ? 0 : 1;
}

/* The first n numbers of the vector attribute attr into out: 0, or 1 where the Python might not do alike (fewer
   than n items; with `exact`, as a tuple unpacking asks, other than n; an item that is not a float); -1 on error.
   A 1-D float64 array is read through the buffer protocol, anything else as a sequence of floats. */
static int read_vector_attr(PyObject *msg, int attr, double *out, Py_ssize_t n, int exact) {
    PyObject *obj = PyObject_GetAttr(msg, attr_names[attr]);
    if (obj == NULL) return -1;
    int result = 1;
    if (PyObject_CheckBuffer(obj) && !PyBytes_Check(obj) && !PyByteArray_Check(obj)) {
        Py_buffer view;
        if (PyObject_GetBuffer(obj, &view, PyBUF_FORMAT | PyBUF_C_CONTIGUOUS) == 0) {
            Py_ssize_t count = view.len / (Py_ssize_t)sizeof(double);
            if (view.format != NULL && strcmp(view.format, "d") == 0 && view.ndim == 1 &&
                (exact ? count == n : count >= n)) {
                memcpy(out, view.buf, (size_t)n * sizeof(double));
                result = 0;
            }
            PyBuffer_Release(&view);
        } else {
            PyErr_Clear(); /* not a contiguous buffer: not ours to read */
        }
        Py_DECREF(obj);
        return result;
    }
    if (PyTuple_Check(obj) || PyList_Check(obj)) {
        Py_ssize_t count = PySequence_Fast_GET_SIZE(obj);
        if (exact ? count == n : count >= n) {
            PyObject **items = PySequence_Fast_ITEMS(obj);
            result = 0;
            for (Py_ssize_t i = 0; i < n && result == 0; i++) {
                if (PyFloat_Check(items[i]))
                    out[i] = PyFloat_AS_DOUBLE(items[i]);
                else
                    result = 1;
            }
        }
    }
    Py_DECREF(obj);
    return result;
}

/* ------------------------------------------------------------------------ packing, as struct packs */

typedef struct {
    unsigned char bytes[MAX_PAYLOAD];
    Py_ssize_t len;
    int ok; /* 0 once a value is not one the Python packs alike */
} Payload;

static void put_u8(Payload *p, unsigned long v) { p->bytes[p->len++] = (unsigned char)(v & 0xFF); }

static void put_u16(Payload *p, unsigned long v) {
    put_u8(p, v);
    put_u8(p, v >> 8);
}

static void put_u32(Payload *p, uint32_t v) {
    for (int i = 0; i < 4; i++) put_u8(p, (v >> (8 * i)) & 0xFF);
}

/* struct's 'f': the C cast PyFloat_Pack4 makes; a finite value that overflows float32 raises in Python */
static void put_f32(Payload *p, double x) {
    float y = (float)x;
    if (isinf(y) && !isinf(x)) {
        p->ok = 0;
        return;
    }
    uint32_t bits;
    memcpy(&bits, &y, sizeof bits);
    put_u32(p, bits);
}

/* int(round(t * scale)) as struct packs it into an unsigned integer below `limit` (2^64 'Q', 2^32 'I'): Python's
   round() is half to even; a non-finite or out-of-range result raises in Python */
static void put_time(Payload *p, double t, double scale, double limit, int bytes) {
    double x = t * scale;
    double r = round(x);
    if (fabs(x - r) == 0.5) r = 2.0 * round(x / 2.0);
    if (!isfinite(r) || r < 0.0 || r >= limit) {
        p->ok = 0;
        return;
    }
    uint64_t v = (uint64_t)r;
    for (int i = 0; i < bytes; i++) put_u8(p, (unsigned long)((v >> (8 * i)) & 0xFF));
}

static void put_zeros_f32(Payload *p, int n) {
    for (int i = 0; i < n; i++) put_f32(p, 0.0);
}

static void put_tail(Payload *p, const Wire *w) {
    memcpy(p->bytes + p->len, w->tail, (size_t)w->tail_len);
    p->len += w->tail_len;
}

/* codec.quat_enu_flu_to_ned_frd */
static void put_quat_ned_frd(Payload *p, const double q[4]) {
    double w = q[0], x = q[1], y = q[2], z = q[3];
    put_f32(p, sqrt_half * (w + z));
    put_f32(p, sqrt_half * (x + y));
    put_f32(p, sqrt_half * (x - y));
    put_f32(p, sqrt_half * (w - z));
}

/* ------------------------------------------------------------------------ the payloads (codec._enc_*) */

#define READ(call)                  \
    do {                            \
        int status_ = (call);       \
        if (status_ != 0) return status_; \
    } while (0)

static int pack_imu(PyObject *msg, Payload *p) { /* _enc_imu */
    double t, f[3], w[3];
    READ(read_float_attr(msg, A_TIME, &t));
    READ(read_vector_attr(msg, A_FORCE, f, 3, 1));
    READ(read_vector_attr(msg, A_RATE, w, 3, 1));
    put_time(p, t, 1e6, 18446744073709551616.0, 8);
    put_f32(p, f[0]);
    put_f32(p, -f[1]);
    put_f32(p, -f[2]);
    put_f32(p, w[0]);
    put_f32(p, -w[1]);
    put_f32(p, -w[2]);
    put_zeros_f32(p, 7);
    put_u16(p, wires[WIRE_IMU].fields_updated);
    put_u8(p, 0);
    return 0;
}

static int pack_mocap(PyObject *msg, Payload *p) { /* _enc_mocap (and _enc_external_pose through it) */
    double t, pos[3], q[4];
    READ(read_float_attr(msg, A_TIME, &t));
    READ(read_vector_attr(msg, A_POSITION, pos, 3, 0));
    READ(read_vector_attr(msg, A_ATTITUDE, q, 4, 1));
    put_time(p, t, 1e6, 18446744073709551616.0, 8);
    put_quat_ned_frd(p, q);
    put_f32(p, pos[1]);
    put_f32(p, pos[0]);
    put_f32(p, -pos[2]);
    put_tail(p, &wires[WIRE_MOCAP]);
    return 0;
}

static int pack_truth(PyObject *msg, Payload *p) { /* _enc_truth */
    double t, pos[3], vel[3], q[4], w[3];
    READ(read_float_attr(msg, A_TIME, &t));
    READ(read_vector_attr(msg, A_POSITION, pos, 3, 0));
    READ(read_vector_attr(msg, A_VELOCITY, vel, 3, 0));
    READ(read_vector_attr(msg, A_RATE, w, 3, 0));
    READ(read_vector_attr(msg, A_ATTITUDE, q, 4, 1));
    put_time(p, t, 1e6, 18446744073709551616.0, 8);
    put_f32(p, pos[1]);
    put_f32(p, pos[0]);
    put_f32(p, -pos[2]);
    put_quat_ned_frd(p, q);
    put_f32(p, vel[1]);
    put_f32(p, vel[0]);
    put_f32(p, -vel[2]);
    put_f32(p, w[0]);
    put_f32(p, -w[1]);
    put_f32(p, -w[2]);
    put_tail(p, &wires[WIRE_TRUTH]);
    return 0;
}

static int pack_thrust_moment(PyObject *msg, const double *limits, long target, Payload *p) { /* _enc_thrust_moment */
    double t, thrust, m[3];
    READ(read_float_attr(msg, A_TIME, &t));
    READ(read_float_attr(msg, A_THRUST, &thrust));
    READ(read_vector_attr(msg, A_MOMENT, m, 3, 1));
    put_time(p, t, 1e6, 18446744073709551616.0, 8);
    put_f32(p, m[0] / limits[0]);
    put_f32(p, -m[1] / limits[1]);
    put_f32(p, -m[2] / limits[2]);
    put_f32(p, thrust / limits[3]);
    put_zeros_f32(p, 4);
    put_u8(p, 0);
    put_u8(p, (unsigned long)target);
    put_u8(p, 0);
    return 0;
}

static int pack_attitude_target(PyObject *msg, const double *limits, long target, Payload *p) { /* _enc_attitude_target */
    double t, thrust, q[4], rates[3];
    READ(read_float_attr(msg, A_TIME, &t));
    READ(read_float_attr(msg, A_THRUST, &thrust));
    READ(read_vector_attr(msg, A_ATTITUDE, q, 4, 1));
    READ(read_vector_attr(msg, A_RATES, rates, 3, 0));
    put_time(p, t, 1e3, 4294967296.0, 4);
    put_quat_ned_frd(p, q);
    put_f32(p, rates[0]); /* flu_to_frd */
    put_f32(p, -rates[1]);
    put_f32(p, -rates[2]);
    put_f32(p, thrust / limits[3]);
    put_u8(p, (unsigned long)target);
    put_u8(p, 0);
    put_u8(p, 0);
    return 0;
}

/* ------------------------------------------------------------------------ the frame (Codec._wrap) */

/* MAVLink's CRC-16/MCRF4XX (x25) accumulation */
static uint16_t crc_accumulate(uint16_t crc, const unsigned char *data, Py_ssize_t n) {
    for (Py_ssize_t i = 0; i < n; i++) {
        uint8_t tmp = (uint8_t)(data[i] ^ (uint8_t)(crc & 0xFF));
        tmp ^= (uint8_t)(tmp << 4);
        crc = (uint16_t)((crc >> 8) ^ ((uint16_t)tmp << 8) ^ ((uint16_t)tmp << 3) ^ (tmp >> 4));
    }
    return crc;
}

static PyObject *wrap(const Wire *w, const Payload *p, unsigned long seq, unsigned long source,
                      unsigned long component) {
    Py_ssize_t len = p->len;
    while (len > 1 && p->bytes[len - 1] == 0) len--; /* zero truncation; MAVLink 2 keeps the first byte */
    unsigned char frame[HEADER_LEN + MAX_PAYLOAD + 2];
    frame[0] = MAGIC_V2;
    frame[1] = (unsigned char)len;
    frame[2] = 0; /* incompat flags: unsigned */
    frame[3] = 0;
    frame[4] = (unsigned char)seq;
    frame[5] = (unsigned char)source;
    frame[6] = (unsigned char)component;
    frame[7] = (unsigned char)(w->msgid & 0xFF);
    frame[8] = (unsigned char)((w->msgid >> 8) & 0xFF);
    frame[9] = (unsigned char)((w->msgid >> 16) & 0xFF);
    memcpy(frame + HEADER_LEN, p->bytes, (size_t)len);
    uint16_t crc = crc_accumulate(0xFFFF, frame + 1, HEADER_LEN - 1 + len);
    crc = crc_accumulate(crc, &w->crc_extra, 1);
    frame[HEADER_LEN + len] = (unsigned char)(crc & 0xFF);
    frame[HEADER_LEN + len + 1] = (unsigned char)(crc >> 8);
    return PyBytes_FromStringAndSize((const char *)frame, HEADER_LEN + len + 2);
}

/* An int argument in [low, high] into out: 0, 1 where it is not an int in range, -1 on error */
static int read_int_arg(PyObject *obj, long low, long high, long *out) {
    if (!PyLong_CheckExact(obj)) return 1;
    int overflow = 0;
    long v = PyLong_AsLongAndOverflow(obj, &overflow);
    if (v == -1 && PyErr_Occurred()) return -1;
    if (overflow || v < low || v > high) return 1;
    *out = v;
    return 0;
}

static PyObject *encode_frame(PyObject *self, PyObject *const *args, Py_ssize_t nargs) {
    (void)self;
    if (check_nargs("encode_frame", nargs, 7) < 0) return NULL;
    if (!configured) {
        PyErr_SetString(PyExc_RuntimeError, "encode_frame: configure() was not called");
        return NULL;
    }
    long kind, seq, source, component, target;
    int status = read_int_arg(args[0], 0, N_KINDS - 1, &kind);
    if (status == 0) status = read_int_arg(args[2], 0, 255, &seq);
    if (status == 0) status = read_int_arg(args[3], 0, 255, &source);
    if (status == 0) status = read_int_arg(args[4], 0, 255, &component);
    if (status == 0) status = read_int_arg(args[5], 0, 255, &target);
    if (status < 0) return NULL;
    if (status > 0) Py_RETURN_NONE;
    double limits[4];
    int have_limits = args[6] != Py_None;
    if (have_limits) {
        if (!PyTuple_CheckExact(args[6]) || PyTuple_GET_SIZE(args[6]) != 4) Py_RETURN_NONE;
        for (int i = 0; i < 4; i++) {
            PyObject *item = PyTuple_GET_ITEM(args[6], i);
            if (!PyFloat_CheckExact(item)) Py_RETURN_NONE;
            limits[i] = PyFloat_AS_DOUBLE(item);
        }
    }
    PyObject *msg = args[1];
    Payload payload = {.len = 0, .ok = 1};
    switch (kind) {
    case KIND_IMU: status = pack_imu(msg, &payload); break;
    case KIND_MOCAP:
    case KIND_EXTERNAL_POSE: status = pack_mocap(msg, &payload); break;
    case KIND_TRUTH: status = pack_truth(msg, &payload); break;
    case KIND_THRUST_MOMENT:
        status = have_limits ? pack_thrust_moment(msg, limits, target, &payload) : 1;
        break;
    default: status = have_limits ? pack_attitude_target(msg, limits, target, &payload) : 1; break;
    }
    if (status < 0) return NULL;
    if (status > 0 || !payload.ok) Py_RETURN_NONE;
    return wrap(&wires[WIRE_OF_KIND[kind]], &payload, (unsigned long)seq, (unsigned long)source,
                (unsigned long)component);
}

/* ------------------------------------------------------------------------ configure */

/* One wire's constants: (msgid, crc_extra, tail bytes, fields_updated) */
static int read_wire(PyObject *spec, Wire *w, const char *name) {
    unsigned long msgid, crc_extra, fields_updated;
    const char *tail;
    Py_ssize_t tail_len;
    if (!PyArg_ParseTuple(spec, "kky#k", &msgid, &crc_extra, &tail, &tail_len, &fields_updated)) return -1;
    if (msgid > 0xFFFFFF || crc_extra > 0xFF || tail_len > N_TAIL || fields_updated > 0xFFFF) {
        PyErr_Format(PyExc_ValueError, "configure: the %s wire's constants are out of range", name);
        return -1;
    }
    w->msgid = (uint32_t)msgid;
    w->crc_extra = (uint8_t)crc_extra;
    memcpy(w->tail, tail, (size_t)tail_len);
    w->tail_len = tail_len;
    w->fields_updated = fields_updated;
    return 0;
}

static PyObject *configure(PyObject *self, PyObject *const *args, Py_ssize_t nargs) {
    (void)self;
    static const char *WIRE_NAMES[N_WIRES] = {"imu", "mocap", "truth", "actuator", "attitude"};
    if (check_nargs("configure", nargs, 1 + N_WIRES) < 0) return NULL;
    sqrt_half = PyFloat_AsDouble(args[0]);
    if (sqrt_half == -1.0 && PyErr_Occurred()) return NULL;
    for (int i = 0; i < N_WIRES; i++)
        if (read_wire(args[1 + i], &wires[i], WIRE_NAMES[i]) < 0) return NULL;
    configured = 1;
    Py_RETURN_NONE;
}

static PyMethodDef methods[] = {
    {"encode_frame", (PyCFunction)(void (*)(void))encode_frame, METH_FASTCALL,
     "encode_frame(kind, message, sequence, source, component, target, limits) -> bytes | None "
     "(link.mavlink.frame_kernel)"},
    {"configure", (PyCFunction)(void (*)(void))configure, METH_FASTCALL,
     "configure(sqrt_half, imu, mocap, truth, actuator, attitude): the Python twin's constants, each wire "
     "(msgid, crc_extra, tail bytes, fields_updated)"},
    {NULL, NULL, 0, NULL},
};

static struct PyModuleDef module = {
    PyModuleDef_HEAD_INIT, "_frame_kernel",
    "Compiled twin of the MAVLink encoder of a tick's messages (link.mavlink.frame_kernel).", -1, methods,
};

PyMODINIT_FUNC PyInit__frame_kernel(void) {
    for (int i = 0; i < N_ATTRS; i++) {
        attr_names[i] = PyUnicode_InternFromString(ATTR_NAMES[i]);
        if (attr_names[i] == NULL) return NULL;
    }
    return PyModule_Create(&module);
}
