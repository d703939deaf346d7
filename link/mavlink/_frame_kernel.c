/* Compiled twins of the MAVLink codec's per-frame work (link.mavlink.codec, issue 19), in both directions.

Encoding: Codec.encode of ImuSample, TruthState, MocapPose, ExternalPose, ThrustMoment and AttitudeTarget, unsigned.
The emulator encodes about eleven such frames per 100 Hz tick (five IMU samples, five truths, the mocap pose),
the ground station one or two per tick on its critical path.
encode_frame takes in: the kind (link.mavlink.frame_kernel's KINDS order), the message, the frame's sequence
number, source system id, component id and target system, and the codec's limits (max moments N m about x, y, z
and max thrust N, as floats; None without limits). It gives out the whole frame (bytes): payload packed as the
wire's struct packs it, zero-truncated, header, CRC-16/MCRF4XX over header, payload and CRC_EXTRA. It gives
None where the Python might not do alike, and changes nothing then: a field that is not a float (an int,
whose arithmetic Python keeps exact, a numpy float32, text), a vector of the wrong length, a time the wire
cannot hold (negative, non-finite, too large for its integer), a value too large for a float32 (struct raises),
a target system outside 0..255, no limits for a normalised message. The caller then runs the Python, which
gives what Python gives, errors included.

Parsing: FrameParser._scan for a parser without signing (every ground station and emulator parser unless MAVLink
signing is on). parse_frames takes in the parser, the bytes to scan and whether they end a datagram; it gives
out (the fields of each frame, as _scan's tuples; the position scanned to), adds to the parser's counters what
_scan adds (on every exit, errors included), and calls its _undelivered where _scan does. HIGHRES_IMU, ATT_POS_MOCAP
and ODOMETRY are decoded here (codec._dec_imu, _dec_mocap, _dec_truth: the same arithmetic, the same messages);
every other message through its Python decoder, whose errors count as _scan counts them.

configure and configure_parser (called once by link.mavlink.codec at import) take the constants from the Python
twin: sqrt(1/2) of the quaternion conversion, per wire the message id, CRC_EXTRA and the fixed tail (IMU:
fields_updated; mocap and truth: the packed bytes after the state); the decoders done natively, the messages
they make, the ground station's system id and MAV_FRAME_LOCAL_NED, and per message its field names where its
__init__ only sets them (codec.direct_fields): the kernel then makes it as that __init__ would, object.__new__ and
object.__setattr__ of each field in order, without running the Python function (a frozen dataclass's __init__ was
most of a decoded IMU sample's cost: 0.42 us of `ImuSample(t, v, v)`, timeit, warm), else it calls the class.

Same bytes and bits as the Python: every number is the Python expression's, one IEEE double operation at a time
(setup.py builds with -ffp-contract=off), converted to float32 by a C cast as struct's PyFloat_Pack4 does and back
as PyFloat_Unpack4 does, times rounded as Python's round() rounds (half to even) and divided as Python divides an
int by a float. tests/link/test_frame_kernel.py compares the twins. */

/* includes Python.h and math.h; check_nargs, read_float_vector, intern_names, add_to_attr */
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

/* The first n numbers of the vector attribute attr into out (read_float_vector, `at_least` where the Python
   indexes it): 0, or 1 where the Python might not do alike; -1 on error */
static int read_vector_attr(PyObject *msg, int attr, double *out, Py_ssize_t n, int at_least) {
    PyObject *obj = PyObject_GetAttr(msg, attr_names[attr]);
    if (obj == NULL) return -1;
    int result = read_float_vector(obj, out, n, at_least);
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
    READ(read_vector_attr(msg, A_FORCE, f, 3, 0));
    READ(read_vector_attr(msg, A_RATE, w, 3, 0));
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
    READ(read_vector_attr(msg, A_POSITION, pos, 3, 1));
    READ(read_vector_attr(msg, A_ATTITUDE, q, 4, 0));
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
    READ(read_vector_attr(msg, A_POSITION, pos, 3, 1));
    READ(read_vector_attr(msg, A_VELOCITY, vel, 3, 1));
    READ(read_vector_attr(msg, A_RATE, w, 3, 1));
    READ(read_vector_attr(msg, A_ATTITUDE, q, 4, 0));
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

/* _enc_thrust_moment */
static int pack_thrust_moment(PyObject *msg, const double *limits, long target, Payload *p) {
    double t, thrust, m[3];
    READ(read_float_attr(msg, A_TIME, &t));
    READ(read_float_attr(msg, A_THRUST, &thrust));
    READ(read_vector_attr(msg, A_MOMENT, m, 3, 0));
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

/* _enc_attitude_target */
static int pack_attitude_target(PyObject *msg, const double *limits, long target, Payload *p) {
    double t, thrust, q[4], rates[3];
    READ(read_float_attr(msg, A_TIME, &t));
    READ(read_float_attr(msg, A_THRUST, &thrust));
    READ(read_vector_attr(msg, A_ATTITUDE, q, 4, 0));
    READ(read_vector_attr(msg, A_RATES, rates, 3, 1));
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

/* ======================================================================== parsing (FrameParser._scan) */

#define MIN_FRAME_LEN (HEADER_LEN + 2)
#define SIGNATURE_BLOCK_LEN 13 /* link id, timestamp, signature */
#define IFLAG_SIGNED 0x01

/* Counters the scan adds to as it goes (FrameParser.counters), flushed into the Python object on every exit */
enum { C_GARBAGE, C_TRUNCATED, C_UNKNOWN, C_CRC, C_VALID_BYTES, C_BAD_HEADERS, C_FRAMES_OK, N_COUNTS };
static const char *COUNT_NAMES[N_COUNTS] = {"garbage_bytes", "truncated_frames", "unknown_messages", "crc_failures",
                                            "valid_frame_bytes", "bad_headers", "frames_ok"};
static PyObject *count_names[N_COUNTS];

/* The Python decoders the kernel decodes natively (codec._dec_imu, _dec_mocap, _dec_truth), the messages they
   make, and their constants; each native layout is used only while its wire's struct has the size it assumes */
enum { NATIVE_IMU, NATIVE_MOCAP, NATIVE_TRUTH, N_NATIVE };
static const Py_ssize_t NATIVE_SIZE[N_NATIVE] = {63, 120, 233}; /* HIGHRES_IMU, ATT_POS_MOCAP, ODOMETRY */
static PyObject *native_decoder[N_NATIVE];
/* The messages they make (ImuSample, MocapPose, ExternalPose, TruthState) and, per message, its fields' names where
   the kernel may make it itself (codec.direct_fields), else NULL: the class is called */
enum { M_IMU, M_MOCAP, M_EXTERNAL_POSE, M_TRUTH, N_MESSAGES };
static const Py_ssize_t MESSAGE_FIELDS[N_MESSAGES] = {3, 4, 3, 5};
static PyObject *message_type[N_MESSAGES], *message_fields[N_MESSAGES];
static PyObject *no_args; /* () for object.__new__ */
static long ground_station_id, frame_local_ned;
static int parser_configured = 0;
/* The parser's attributes and methods, and the counters it names to _undelivered */
enum { S_COUNTERS, S_WIRES, S_UNDELIVERED, S_UNPACK_FROM, S_UNSUPPORTED, S_BAD_LENGTHS, S_DECODE_ERRORS, N_NAMES };
static const char *NAME_TEXTS[N_NAMES] = {"counters", "_wires", "_undelivered", "unpack_from",
                                          "unsupported_messages", "bad_lengths", "decode_errors"};
static PyObject *names[N_NAMES];

static int flush_counts(PyObject *counters, const long long counts[N_COUNTS]) {
    for (int k = 0; k < N_COUNTS; k++)
        if (counts[k] != 0 && add_to_attr(counters, count_names[k], counts[k]) < 0) return -1;
    return 0;
}

static double f32_at(const unsigned char *b, int offset) {
    uint32_t bits = (uint32_t)b[offset] | (uint32_t)b[offset + 1] << 8 | (uint32_t)b[offset + 2] << 16 |
                    (uint32_t)b[offset + 3] << 24;
    float f;
    memcpy(&f, &bits, sizeof f);
    return (double)f;
}

static double usec_to_s(const unsigned char *b) { /* v[0] / 1e6 of a 'Q' field at offset 0 */
    uint64_t v = 0;
    for (int k = 7; k >= 0; k--) v = v << 8 | b[k];
    return (double)v / 1e6;
}

/* codec.quat_ned_frd_to_enu_flu of the four float32 at offset */
static PyObject *quat_enu_flu_at(const unsigned char *b, int offset) {
    double w = f32_at(b, offset), x = f32_at(b, offset + 4), y = f32_at(b, offset + 8), z = f32_at(b, offset + 12);
    double q[4] = {sqrt_half * (w + z), sqrt_half * (x + y), sqrt_half * (x - y), sqrt_half * (w - z)};
    return float_tuple(q, 4);
}

static PyObject *vec3(double a, double b, double c) {
    double v[3] = {a, b, c};
    return float_tuple(v, 3);
}

/* What the frozen dataclass's generated __init__ does, without running it: object.__new__(cls), then
   object.__setattr__ of each field in order; NULL with the error set */
static PyObject *set_fields(PyObject *cls, PyObject *fields, PyObject *const *values) {
    PyObject *obj = PyBaseObject_Type.tp_new((PyTypeObject *)cls, no_args, NULL);
    if (obj == NULL) return NULL;
    for (Py_ssize_t k = 0; k < PyTuple_GET_SIZE(fields); k++) {
        if (PyObject_GenericSetAttr(obj, PyTuple_GET_ITEM(fields, k), values[k]) < 0) {
            Py_DECREF(obj);
            return NULL;
        }
    }
    return obj;
}

/* Message `which` (M_*) of (time, then the other arguments, stolen); NULL with the error set */
static PyObject *make(int which, double t, int n, PyObject **args) {
    PyObject *call[6];
    int ok = 1;
    call[0] = PyFloat_FromDouble(t);
    for (int k = 0; k < n; k++) {
        call[k + 1] = args[k];
        ok = ok && args[k] != NULL;
    }
    PyObject *out = NULL, *cls = message_type[which], *fields = message_fields[which];
    if (ok && call[0] != NULL)
        out = fields != NULL ? set_fields(cls, fields, call) : PyObject_Vectorcall(cls, call, (size_t)(n + 1), NULL);
    for (int k = 0; k <= n; k++) Py_XDECREF(call[k]);
    return out;
}

/* The message the Python decoder would give for a native kind (b: the payload, zero-extended to its size);
   Py_None (new reference) where it gives None; NULL with the error set */
static PyObject *decode_native(int kind, const unsigned char *b, long system_id) {
    PyObject *args[4];
    switch (kind) {
    case NATIVE_IMU: /* _dec_imu */
        args[0] = vec3(f32_at(b, 8), -f32_at(b, 12), -f32_at(b, 16));
        args[1] = vec3(f32_at(b, 20), -f32_at(b, 24), -f32_at(b, 28));
        return make(M_IMU, usec_to_s(b), 2, args);
    case NATIVE_MOCAP: { /* _dec_mocap: from the ground station, the receiving vehicle's own pose */
        PyObject *position = vec3(f32_at(b, 28), f32_at(b, 24), -f32_at(b, 32));
        PyObject *attitude = quat_enu_flu_at(b, 8);
        if (system_id == ground_station_id) {
            args[0] = position, args[1] = attitude;
            return make(M_EXTERNAL_POSE, usec_to_s(b), 2, args);
        }
        args[0] = PyLong_FromLong(system_id), args[1] = position, args[2] = attitude;
        return make(M_MOCAP, usec_to_s(b), 3, args);
    }
    default: /* _dec_truth */
        if (b[228] != frame_local_ned || b[229] != frame_local_ned) Py_RETURN_NONE;
        args[0] = vec3(f32_at(b, 12), f32_at(b, 8), -f32_at(b, 16));
        args[1] = vec3(f32_at(b, 40), f32_at(b, 36), -f32_at(b, 44));
        args[2] = quat_enu_flu_at(b, 20);
        args[3] = vec3(f32_at(b, 48), -f32_at(b, 52), -f32_at(b, 56));
        return make(M_TRUTH, usec_to_s(b), 4, args);
    }
}

/* parser._undelivered(counter, system id, component id, sequence); -1 with the error set */
static int undelivered(PyObject *parser, PyObject *counter, long system_id, long component_id, long sequence) {
    PyObject *sid = PyLong_FromLong(system_id), *cid = PyLong_FromLong(component_id), *seq = PyLong_FromLong(sequence);
    PyObject *out = sid && cid && seq
                        ? PyObject_CallMethodObjArgs(parser, names[S_UNDELIVERED], counter, sid, cid, seq, NULL)
                        : NULL;
    Py_XDECREF(sid);
    Py_XDECREF(cid);
    Py_XDECREF(seq);
    Py_XDECREF(out);
    return out == NULL ? -1 : 0;
}

/* The Python decoder's answer, as _scan's try block has it: the (message, target) result, Py_None for None,
   or `decode_error` set where it raised ValueError, TypeError or OverflowError; NULL for any other error */
static PyObject *decode_python(PyObject *unpacker, PyObject *decoder, PyObject *source, Py_ssize_t offset,
                               long system_id, int *decode_error) {
    PyObject *off = PyLong_FromSsize_t(offset), *sid = PyLong_FromLong(system_id), *values = NULL, *result = NULL;
    if (off != NULL && sid != NULL) {
        PyObject *unpack_args[3] = {unpacker, source, off};
        values = PyObject_VectorcallMethod(names[S_UNPACK_FROM], unpack_args, 3 | PY_VECTORCALL_ARGUMENTS_OFFSET, NULL);
    }
    if (values != NULL) {
        PyObject *decode_args[2] = {values, sid};
        result = PyObject_Vectorcall(decoder, decode_args, 2, NULL);
    }
    Py_XDECREF(off);
    Py_XDECREF(sid);
    Py_XDECREF(values);
    if (result == NULL && (PyErr_ExceptionMatches(PyExc_ValueError) || PyErr_ExceptionMatches(PyExc_TypeError) ||
                           PyErr_ExceptionMatches(PyExc_OverflowError))) {
        PyErr_Clear();
        *decode_error = 1;
    }
    return result;
}

/* One frame's (message, system id, component id, sequence, msgid, signed, frame, target, link id), as _scan
   appends it for a parser without signing; NULL with the error set */
static PyObject *frame_fields(PyObject *message, long sid, long cid, long seq, long msgid, PyObject *frame,
                              PyObject *target) {
    PyObject *t = PyTuple_New(9);
    if (t == NULL) return NULL;
    long ints[4] = {sid, cid, seq, msgid};
    for (int k = 0; k < 4; k++) {
        PyObject *v = PyLong_FromLong(ints[k]);
        if (v == NULL) {
            Py_DECREF(t);
            return NULL;
        }
        PyTuple_SET_ITEM(t, 1 + k, v);
    }
    Py_INCREF(message);
    PyTuple_SET_ITEM(t, 0, message);
    Py_INCREF(Py_False);
    PyTuple_SET_ITEM(t, 5, Py_False);
    Py_INCREF(frame);
    PyTuple_SET_ITEM(t, 6, frame);
    Py_INCREF(target);
    PyTuple_SET_ITEM(t, 7, target);
    Py_INCREF(Py_None);
    PyTuple_SET_ITEM(t, 8, Py_None);
    return t;
}

/* Decode one genuine frame whose wire has a decoder (b + start: the payload, plen bytes) into out; 0, or -1
   with the error set. Counts and hands back what _scan's Python would. */
static int decode_frame(PyObject *parser, PyObject *buf, const unsigned char *b, Py_ssize_t i, Py_ssize_t end,
                        Py_ssize_t n, PyObject *wire, long plen, long sid, long cid, long seq, long msgid,
                        long long counts[N_COUNTS], PyObject *out) {
    PyObject *unpacker = PyTuple_GET_ITEM(wire, 1), *decoder = PyTuple_GET_ITEM(wire, 3);
    Py_ssize_t size = PyLong_AsSsize_t(PyTuple_GET_ITEM(wire, 2));
    if (size < 0 || size > MAX_PAYLOAD) {
        if (!PyErr_Occurred()) PyErr_SetString(PyExc_ValueError, "parse_frames: a wire's size is out of range");
        return -1;
    }
    int native = -1;
    for (int k = 0; k < N_NATIVE; k++)
        if (decoder == native_decoder[k] && size == NATIVE_SIZE[k]) native = k;
    /* a zero-truncated payload reads as zero-extended (MAVLink 2); a whole one goes to unpack_from as it is */
    unsigned char extended[MAX_PAYLOAD];
    if (native >= 0 || plen < size) {
        memset(extended, 0, (size_t)size);
        memcpy(extended, b + i + HEADER_LEN, (size_t)(plen < size ? plen : size));
    }
    PyObject *message, *target, *result = NULL;
    int decode_error = 0;
    if (native >= 0) {
        message = decode_native(native, extended, sid);
        if (message == NULL) return -1;
        if (message == Py_None) {
            Py_DECREF(message);
            return undelivered(parser, names[S_UNSUPPORTED], sid, cid, seq);
        }
        target = PyLong_FromLong(0);
        if (target == NULL) {
            Py_DECREF(message);
            return -1;
        }
    } else {
        PyObject *source = plen >= size ? (Py_INCREF(buf), buf)
                                        : PyBytes_FromStringAndSize((const char *)extended, size);
        if (source == NULL) return -1;
        result = decode_python(unpacker, decoder, source, plen >= size ? i + HEADER_LEN : 0, sid, &decode_error);
        Py_DECREF(source);
        if (result == NULL) return decode_error ? undelivered(parser, names[S_DECODE_ERRORS], sid, cid, seq) : -1;
        if (result == Py_None) {
            Py_DECREF(result);
            return undelivered(parser, names[S_UNSUPPORTED], sid, cid, seq);
        }
        PyObject *pair = PySequence_Fast(result, "a decoder returns (message, target)");
        Py_DECREF(result);
        if (pair == NULL) return -1;
        if (PySequence_Fast_GET_SIZE(pair) != 2) {
            Py_DECREF(pair);
            PyErr_SetString(PyExc_ValueError, "a decoder returns (message, target)");
            return -1;
        }
        message = PySequence_Fast_GET_ITEM(pair, 0);
        target = PySequence_Fast_GET_ITEM(pair, 1);
        Py_INCREF(message);
        Py_INCREF(target);
        Py_DECREF(pair);
    }
    counts[C_FRAMES_OK]++;
    PyObject *frame = end == n && i == 0 ? (Py_INCREF(buf), buf)
                                         : PyBytes_FromStringAndSize((const char *)b + i, end - i);
    PyObject *fields = frame == NULL ? NULL : frame_fields(message, sid, cid, seq, msgid, frame, target);
    Py_XDECREF(frame);
    Py_DECREF(message);
    Py_DECREF(target);
    if (fields == NULL) return -1;
    int status = PyList_Append(out, fields);
    Py_DECREF(fields);
    return status;
}

/* FrameParser._scan for a parser without signing: (the frames' fields, the position scanned to) */
static PyObject *parse_frames(PyObject *self, PyObject *const *args, Py_ssize_t nargs) {
    (void)self;
    if (check_nargs("parse_frames", nargs, 3) < 0) return NULL;
    if (!configured || !parser_configured) {
        PyErr_SetString(PyExc_RuntimeError, "parse_frames: configure() and configure_parser() were not called");
        return NULL;
    }
    PyObject *parser = args[0], *buf = args[1];
    if (!PyBytes_CheckExact(buf)) {
        PyErr_SetString(PyExc_TypeError, "parse_frames: the buffer must be bytes");
        return NULL;
    }
    int final = PyObject_IsTrue(args[2]);
    if (final < 0) return NULL;
    PyObject *counters = PyObject_GetAttr(parser, names[S_COUNTERS]);
    PyObject *wires = counters == NULL ? NULL : PyObject_GetAttr(parser, names[S_WIRES]);
    PyObject *out = wires == NULL ? NULL : PyList_New(0);
    if (out == NULL || !PyDict_Check(wires)) {
        if (wires != NULL && !PyDict_Check(wires))
            PyErr_SetString(PyExc_TypeError, "parse_frames: _wires is not a dict");
        Py_XDECREF(counters);
        Py_XDECREF(wires);
        Py_XDECREF(out);
        return NULL;
    }
    const unsigned char *b = (const unsigned char *)PyBytes_AS_STRING(buf);
    Py_ssize_t n = PyBytes_GET_SIZE(buf), pos = 0;
    long long counts[N_COUNTS] = {0};
    int failed = 0;
    while (pos < n && !failed) {
        Py_ssize_t i = pos;
        if (b[pos] != MAGIC_V2) {
            const unsigned char *hit = memchr(b + pos, MAGIC_V2, (size_t)(n - pos));
            if (hit == NULL) {
                counts[C_GARBAGE] += n - pos;
                pos = n;
                break;
            }
            i = hit - b;
            counts[C_GARBAGE] += i - pos;
            pos = i;
        }
        long plen = 0, flags = 0, seq = 0, sid = 0, cid = 0, msgid = 0;
        Py_ssize_t end = n + 1; /* unknown until the length byte has arrived */
        if (n - i >= MIN_FRAME_LEN) {
            plen = b[i + 1], flags = b[i + 2], seq = b[i + 4], sid = b[i + 5], cid = b[i + 6];
            msgid = (long)b[i + 7] | (long)b[i + 8] << 8 | (long)b[i + 9] << 16;
            end = i + MIN_FRAME_LEN + plen + (flags & IFLAG_SIGNED ? SIGNATURE_BLOCK_LEN : 0);
        }
        if (end > n) { /* incomplete: wait for more bytes, unless this was a whole datagram */
            if (!final) break;
            counts[C_TRUNCATED]++, counts[C_GARBAGE]++, pos = i + 1;
            continue;
        }
        PyObject *key = PyLong_FromLong(msgid);
        PyObject *wire = key == NULL ? NULL : PyDict_GetItemWithError(wires, key); /* borrowed */
        Py_XDECREF(key);
        if (wire == NULL) {
            if (PyErr_Occurred()) {
                failed = 1;
                break;
            }
            counts[C_UNKNOWN]++, counts[C_GARBAGE]++, pos = i + 1; /* outside the dialect: cannot be verified */
            continue;
        }
        PyObject *extra = PyTuple_Check(wire) && PyTuple_GET_SIZE(wire) == 4 ? PyTuple_GET_ITEM(wire, 0) : NULL;
        if (extra == NULL || !PyBytes_Check(extra) || PyBytes_GET_SIZE(extra) != 1) {
            PyErr_SetString(PyExc_TypeError, "parse_frames: a wire is not (crc_extra, struct, size, decoder)");
            failed = 1;
            break;
        }
        Py_ssize_t crc_at = i + HEADER_LEN + plen;
        uint16_t crc = crc_accumulate(0xFFFF, b + i + 1, crc_at - (i + 1));
        crc = crc_accumulate(crc, (const unsigned char *)PyBytes_AS_STRING(extra), 1);
        if (crc != (uint16_t)(b[crc_at] | b[crc_at + 1] << 8)) {
            counts[C_CRC]++, counts[C_GARBAGE]++, pos = i + 1;
            continue;
        }
        pos = end; /* a genuine frame: whatever happens next, skip it whole */
        counts[C_VALID_BYTES] += end - i;
        if (flags & ~IFLAG_SIGNED) {
            counts[C_BAD_HEADERS]++;
            continue;
        }
        if (PyTuple_GET_ITEM(wire, 3) == Py_None) {
            failed = undelivered(parser, names[S_UNSUPPORTED], sid, cid, seq) < 0;
            continue;
        }
        if (plen == 0) {
            failed = undelivered(parser, names[S_BAD_LENGTHS], sid, cid, seq) < 0;
            continue;
        }
        failed = decode_frame(parser, buf, b, i, end, n, wire, plen, sid, cid, seq, msgid, counts, out) < 0;
    }
    /* the counts so far go into the Python object on every exit, as the Python's += would have left them */
    PyObject *type, *value, *traceback;
    PyErr_Fetch(&type, &value, &traceback);
    int flushed = flush_counts(counters, counts);
    if (failed || flushed < 0) {
        if (failed) {
            if (flushed < 0) PyErr_Clear();
            PyErr_Restore(type, value, traceback);
        } else {
            Py_XDECREF(type);
            Py_XDECREF(value);
            Py_XDECREF(traceback);
        }
        Py_DECREF(counters);
        Py_DECREF(wires);
        Py_DECREF(out);
        return NULL;
    }
    Py_DECREF(counters);
    Py_DECREF(wires);
    PyObject *result = Py_BuildValue("(Nn)", out, pos);
    return result;
}

/* The parser's constants: the Python decoders decoded natively (codec._dec_imu, _dec_mocap, _dec_truth), the
   messages they make (ImuSample, MocapPose, ExternalPose, TruthState), the ground station's system id,
   MAV_FRAME_LOCAL_NED, then per message its codec.direct_fields or None. The field tuples are checked before
   anything is taken, so one that is refused leaves the configuration as it was */
static PyObject *configure_parser(PyObject *self, PyObject *const *args, Py_ssize_t nargs) {
    (void)self;
    if (check_nargs("configure_parser", nargs, 13) < 0) return NULL;
    for (int m = 0; m < N_MESSAGES; m++) { /* checked before anything is taken */
        PyObject *fields = args[9 + m], *cls = args[3 + m];
        int ok = fields == Py_None || (PyTuple_Check(fields) && PyTuple_GET_SIZE(fields) == MESSAGE_FIELDS[m]);
        for (Py_ssize_t k = 0; ok && fields != Py_None && k < MESSAGE_FIELDS[m]; k++)
            ok = PyUnicode_Check(PyTuple_GET_ITEM(fields, k));
        if (!ok) {
            PyErr_Format(PyExc_ValueError, "configure_parser: message %d's fields must be None or a tuple of %zd "
                         "names", m, MESSAGE_FIELDS[m]);
            return NULL;
        }
        /* made with object.__new__: only a class that takes object's own __new__ */
        if (fields != Py_None && (!PyType_Check(cls) || ((PyTypeObject *)cls)->tp_new != PyBaseObject_Type.tp_new)) {
            PyErr_Format(PyExc_ValueError, "configure_parser: message %d has fields but is not a class made by "
                         "object.__new__", m);
            return NULL;
        }
    }
    PyObject **slots[7] = {&native_decoder[NATIVE_IMU], &native_decoder[NATIVE_MOCAP], &native_decoder[NATIVE_TRUTH],
                           &message_type[M_IMU], &message_type[M_MOCAP], &message_type[M_EXTERNAL_POSE],
                           &message_type[M_TRUTH]};
    for (int k = 0; k < 7; k++) {
        if (!PyCallable_Check(args[k])) {
            PyErr_SetString(PyExc_TypeError, "configure_parser: the decoders and messages must be callables");
            return NULL;
        }
        Py_INCREF(args[k]);
        Py_XSETREF(*slots[k], args[k]);
    }
    ground_station_id = PyLong_AsLong(args[7]);
    frame_local_ned = PyLong_AsLong(args[8]);
    if (PyErr_Occurred()) return NULL;
    if (no_args == NULL && (no_args = PyTuple_New(0)) == NULL) return NULL;
    for (int m = 0; m < N_MESSAGES; m++) {
        PyObject *fields = args[9 + m];
        Py_XSETREF(message_fields[m], fields == Py_None ? NULL : Py_NewRef(fields));
    }
    parser_configured = 1;
    Py_RETURN_NONE;
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
    {"parse_frames", (PyCFunction)(void (*)(void))parse_frames, METH_FASTCALL,
     "parse_frames(parser, buf, final) -> (fields of each frame, position scanned to) (FrameParser._scan, "
     "without signing)"},
    {"configure_parser", (PyCFunction)(void (*)(void))configure_parser, METH_FASTCALL,
     "configure_parser(dec_imu, dec_mocap, dec_truth, ImuSample, MocapPose, ExternalPose, TruthState, "
     "ground_station_id, MAV_FRAME_LOCAL_NED, then per message its direct_fields or None)"},
    {"configure", (PyCFunction)(void (*)(void))configure, METH_FASTCALL,
     "configure(sqrt_half, imu, mocap, truth, actuator, attitude): the Python twin's constants, each wire "
     "(msgid, crc_extra, tail bytes, fields_updated)"},
    {NULL, NULL, 0, NULL},
};

static struct PyModuleDef module = {
    PyModuleDef_HEAD_INIT, "_frame_kernel",
    "Compiled twins of the MAVLink encoder of a tick's messages and of the parser (link.mavlink.frame_kernel).", -1,
    methods,
};

PyMODINIT_FUNC PyInit__frame_kernel(void) {
    if (intern_names(ATTR_NAMES, attr_names, N_ATTRS) < 0 || intern_names(COUNT_NAMES, count_names, N_COUNTS) < 0 ||
        intern_names(NAME_TEXTS, names, N_NAMES) < 0)
        return NULL;
    return PyModule_Create(&module);
}
