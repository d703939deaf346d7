/* Compiled twin of link.endpoint.deliver_fields (issue 19): what Endpoint.deliver does per frame after the parser.
The ground station runs it for every frame it receives (about six per 100 Hz tick on its critical path, and the
truth's five after it); in Python it took about as long as the parser itself.

deliver_fields takes in: the fields of each frame (FrameParser.feed_fields' tuples: message, system id, component id,
sequence, msgid, signed, frame bytes, target system, and one more), the endpoint's LinkStats, its TlogWriter or
None, the receive time (the endpoint's clock) and the list to append to. Per frame, in the Python's order, it:
- records the frame as LinkStats.record_frame does: rx_frames and rx_frame_bytes, the one-way age when the message
  has a time_s and the clocks give an offset (the same double arithmetic), the sequence verdict of
  SequenceTracker.observe. The usual frame (the next sequence number of a known stream with no gap waiting) is
  done here; every other one by calling the tracker's own observe;
- writes the frame to the tlog as TlogWriter.write does for a buffered writer that is open and a frame that is
  bytes (stamped by the writer's clock); every other case calls the writer's write;
- appends Received(message, system id, sequence, receive time, signed, extra) with the extra dict of the Python.
Gives out: None, having appended to the list. An error raises as the Python raises, with the frames before it done.

configure (called once by link.endpoint at import) takes the Received class, link.stats' SEQUENCE_MODULUS and
REORDER_WINDOW, and link.mavlink.tlog's RECORD_HEADER_LEN. tests/link/test_deliver_kernel.py compares the twins. */

/* includes Python.h and math.h; check_nargs, intern_names, add_to_attr */
#include "../model/_kernels.h"
#include <limits.h>

enum { F_MESSAGE, F_SYSTEM, F_COMPONENT, F_SEQUENCE, F_MSGID, F_SIGNED, F_FRAME, F_TARGET, N_FIELDS = 9 };

enum {
    S_RX_FRAMES, S_RX_FRAME_BYTES, S_OFFSET, S_SHARED, S_AGE, S_SEQUENCES, S_STREAMS, S_UNIQUE, S_OBSERVE,
    S_TIME, S_FD, S_BUFFER, S_CLOCK, S_FRAMES_WRITTEN, S_BYTES_WRITTEN, S_WRITE, S_APPEND, S_COMPONENT_ID,
    S_TARGET_SYSTEM, S_MSGID, S_SEQUENCE, S_NEW, N_NAMES
};
static const char *NAME_TEXTS[N_NAMES] = {
    "rx_frames", "rx_frame_bytes", "_offset_estimate", "shared_clock", "age_s", "sequences", "_streams", "unique",
    "observe", "time_s", "_fd", "_buffer", "clock", "frames_written", "bytes_written", "write", "append",
    "component_id", "target_system", "msgid", "sequence", "new"};
static PyObject *names[N_NAMES];

static PyObject *received_type = NULL;
static long long sequence_modulus = 0, reorder_window = 0, record_header_len = 0;

/* getattr(message, "time_s", None): a new reference, None included; NULL on an error other than AttributeError */
static PyObject *sample_time(PyObject *message) {
    PyObject *value = PyObject_GetAttr(message, names[S_TIME]);
    if (value == NULL && PyErr_ExceptionMatches(PyExc_AttributeError)) {
        PyErr_Clear();
        Py_RETURN_NONE;
    }
    return value;
}

/* received - sample - offset, left to right: the doubles' arithmetic when all three are floats */
static PyObject *frame_age(PyObject *received_s, PyObject *sample_s, PyObject *offset_s) {
    if (PyFloat_CheckExact(received_s) && PyFloat_CheckExact(sample_s) && PyFloat_CheckExact(offset_s))
        return PyFloat_FromDouble(PyFloat_AS_DOUBLE(received_s) - PyFloat_AS_DOUBLE(sample_s) -
                                  PyFloat_AS_DOUBLE(offset_s));
    PyObject *partial = PyNumber_Subtract(received_s, sample_s);
    if (partial == NULL) return NULL;
    PyObject *age = PyNumber_Subtract(partial, offset_s);
    Py_DECREF(partial);
    return age;
}

/* LinkStats.record_frame's age: appended to stats.age_s when the sample has a time and the clocks an offset */
static int record_age(PyObject *stats, PyObject *sample_s, PyObject *received_s) {
    if (sample_s == Py_None) return 0;
    PyObject *offset = PyObject_GetAttr(stats, names[S_OFFSET]);
    if (offset == NULL) return -1;
    if (offset == Py_None) {
        PyObject *shared = PyObject_GetAttr(stats, names[S_SHARED]);
        int is_shared = shared == NULL ? -1 : PyObject_IsTrue(shared);
        Py_XDECREF(shared);
        if (is_shared < 0) {
            Py_DECREF(offset);
            return -1;
        }
        if (is_shared) Py_SETREF(offset, PyFloat_FromDouble(0.0));
        if (offset == NULL) return -1;
    }
    if (offset == Py_None) {
        Py_DECREF(offset);
        return 0;
    }
    PyObject *age = frame_age(received_s, sample_s, offset);
    Py_DECREF(offset);
    if (age == NULL) return -1;
    PyObject *ages = PyObject_GetAttr(stats, names[S_AGE]);
    PyObject *done = ages == NULL ? NULL : PyObject_CallMethodOneArg(ages, names[S_APPEND], age);
    Py_XDECREF(ages);
    Py_DECREF(age);
    Py_XDECREF(done);
    return done == NULL ? -1 : 0;
}

/* Python's x % m for m > 0 (never negative) */
static long long floor_mod(long long x, long long m) { return ((x % m) + m) % m; }

/* SequenceTracker.observe's usual case done here: the stream is known, the frame is the next one after its newest
   (delta 1) and no gap waits in its order deque. Returns 1 (done: newest and unique advanced), 0 (not the usual
   case: nothing changed) or -1 (error). */
static int observe_next(PyObject *tracker, PyObject *system_id, PyObject *component_id, PyObject *sequence) {
    if (!PyLong_CheckExact(system_id) || !PyLong_CheckExact(component_id) || !PyLong_CheckExact(sequence)) return 0;
    int overflow = 0;
    long long sid = PyLong_AsLongLongAndOverflow(system_id, &overflow);
    long long cid = overflow ? 0 : PyLong_AsLongLongAndOverflow(component_id, &overflow);
    long long seq = overflow ? 0 : PyLong_AsLongLongAndOverflow(sequence, &overflow);
    if (overflow || sid < 0 || sid > 0xFFFF || cid < 0 || cid > 0xFF || seq < 0 || seq > 0xFFFF) return 0;
    PyObject *streams = PyObject_GetAttr(tracker, names[S_STREAMS]);
    if (streams == NULL) return -1;
    PyObject *key = PyDict_CheckExact(streams) ? PyLong_FromLongLong((sid << 8) | cid) : NULL;
    PyObject *stream = key == NULL ? NULL : PyDict_GetItemWithError(streams, key); /* borrowed */
    Py_XDECREF(key);
    int result = PyErr_Occurred() ? -1 : 0;
    if (stream != NULL && PyList_CheckExact(stream) && PyList_GET_SIZE(stream) == 3 &&
        PyLong_CheckExact(PyList_GET_ITEM(stream, 0))) {
        long long newest = PyLong_AsLongLongAndOverflow(PyList_GET_ITEM(stream, 0), &overflow);
        Py_ssize_t waiting = overflow ? -1 : PyObject_Length(PyList_GET_ITEM(stream, 2));
        if (waiting < 0 && PyErr_Occurred()) result = -1;
        else if (!overflow && waiting == 0 && newest < LLONG_MAX - sequence_modulus &&
                 floor_mod(seq - newest + reorder_window, sequence_modulus) - reorder_window == 1) {
            PyObject *next = PyLong_FromLongLong(newest + 1);
            Py_INCREF(stream); /* kept alive while it is written */
            result = next == NULL || PyList_SetItem(stream, 0, next) < 0 ? -1 : 1; /* SetItem steals next */
            Py_DECREF(stream);
            if (result == 1 && add_to_attr(tracker, names[S_UNIQUE], 1) < 0) result = -1;
        }
    }
    Py_DECREF(streams);
    return result;
}

/* LinkStats.record_frame: the counters, the age, the sequence verdict (a new reference) */
static PyObject *record_frame(PyObject *stats, PyObject *const *f, Py_ssize_t frame_len, PyObject *received_s) {
    PyObject *sample_s = sample_time(f[F_MESSAGE]); /* the Python evaluates it as the call's argument, first */
    if (sample_s == NULL) return NULL;
    int failed = add_to_attr(stats, names[S_RX_FRAMES], 1) < 0 ||
                 add_to_attr(stats, names[S_RX_FRAME_BYTES], frame_len) < 0 ||
                 record_age(stats, sample_s, received_s) < 0;
    Py_DECREF(sample_s);
    if (failed) return NULL;
    PyObject *tracker = PyObject_GetAttr(stats, names[S_SEQUENCES]);
    if (tracker == NULL) return NULL;
    PyObject *verdict = NULL;
    int usual = observe_next(tracker, f[F_SYSTEM], f[F_COMPONENT], f[F_SEQUENCE]);
    if (usual == 1) {
        verdict = names[S_NEW];
        Py_INCREF(verdict);
    } else if (usual == 0) {
        verdict = PyObject_CallMethodObjArgs(tracker, names[S_OBSERVE], f[F_SYSTEM], f[F_COMPONENT], f[F_SEQUENCE],
                                             NULL);
    }
    Py_DECREF(tracker);
    return verdict;
}

/* TlogWriter.write(frame): a buffered, open writer and a bytes frame here, anything else through its write */
static int write_tlog(PyObject *tlog, PyObject *frame) {
    PyObject *fd = PyObject_GetAttr(tlog, names[S_FD]);
    PyObject *buffer = fd == NULL ? NULL : PyObject_GetAttr(tlog, names[S_BUFFER]);
    if (buffer == NULL) {
        Py_XDECREF(fd);
        return -1;
    }
    int here = fd != Py_None && PyList_CheckExact(buffer) && PyBytes_CheckExact(frame);
    Py_DECREF(fd);
    if (!here) {
        Py_DECREF(buffer);
        PyObject *done = PyObject_CallMethodOneArg(tlog, names[S_WRITE], frame);
        Py_XDECREF(done);
        return done == NULL ? -1 : 0;
    }
    PyObject *stamp_s = PyObject_CallMethodNoArgs(tlog, names[S_CLOCK]);
    int failed = stamp_s == NULL || add_to_attr(tlog, names[S_FRAMES_WRITTEN], 1) < 0 ||
                 add_to_attr(tlog, names[S_BYTES_WRITTEN], record_header_len + PyBytes_GET_SIZE(frame)) < 0;
    PyObject *record = failed ? NULL : PyTuple_Pack(2, stamp_s, frame);
    failed = record == NULL || PyList_Append(buffer, record) < 0;
    Py_XDECREF(record);
    Py_XDECREF(stamp_s);
    Py_DECREF(buffer);
    return failed ? -1 : 0;
}

/* The Received of one frame, with the Python's extra dict */
static PyObject *make_received(PyObject *const *f, PyObject *verdict, PyObject *received_s) {
    PyObject *extra = PyDict_New();
    if (extra == NULL) return NULL;
    int is_new = PyObject_RichCompareBool(verdict, names[S_NEW], Py_EQ);
    if (is_new < 0 || PyDict_SetItem(extra, names[S_COMPONENT_ID], f[F_COMPONENT]) < 0 ||
        PyDict_SetItem(extra, names[S_TARGET_SYSTEM], f[F_TARGET]) < 0 ||
        PyDict_SetItem(extra, names[S_MSGID], f[F_MSGID]) < 0 ||
        (!is_new && PyDict_SetItem(extra, names[S_SEQUENCE], verdict) < 0)) {
        Py_DECREF(extra);
        return NULL;
    }
    PyObject *args[6] = {f[F_MESSAGE], f[F_SYSTEM], f[F_SEQUENCE], received_s, f[F_SIGNED], extra};
    PyObject *received = PyObject_Vectorcall(received_type, args, 6, NULL);
    Py_DECREF(extra);
    return received;
}

static int deliver_one(PyObject *fields, PyObject *stats, PyObject *tlog, PyObject *received_s, PyObject *out) {
    if (!PyTuple_Check(fields) || PyTuple_GET_SIZE(fields) != N_FIELDS) {
        PyErr_SetString(PyExc_TypeError, "deliver_fields: a frame's fields are not FrameParser's 9-tuple");
        return -1;
    }
    PyObject *const *f = &PyTuple_GET_ITEM(fields, 0);
    Py_ssize_t frame_len = PyObject_Length(f[F_FRAME]);
    if (frame_len < 0) return -1;
    PyObject *verdict = record_frame(stats, f, frame_len, received_s);
    if (verdict == NULL) return -1;
    PyObject *received = tlog != Py_None && write_tlog(tlog, f[F_FRAME]) < 0 ? NULL
                                                                            : make_received(f, verdict, received_s);
    Py_DECREF(verdict);
    int failed = received == NULL || PyList_Append(out, received) < 0;
    Py_XDECREF(received);
    return failed ? -1 : 0;
}

static PyObject *deliver_fields(PyObject *self, PyObject *const *args, Py_ssize_t nargs) {
    (void)self;
    if (check_nargs("deliver_fields", nargs, 5) < 0) return NULL;
    if (received_type == NULL) {
        PyErr_SetString(PyExc_RuntimeError, "deliver_fields: configure() first");
        return NULL;
    }
    PyObject *fields = args[0], *stats = args[1], *tlog = args[2], *received_s = args[3], *out = args[4];
    if (!PyList_Check(fields) || !PyList_Check(out)) {
        PyErr_SetString(PyExc_TypeError, "deliver_fields: the fields and the output must be lists");
        return NULL;
    }
    for (Py_ssize_t i = 0; i < PyList_GET_SIZE(fields); i++)
        if (deliver_one(PyList_GET_ITEM(fields, i), stats, tlog, received_s, out) < 0) return NULL;
    Py_RETURN_NONE;
}

/* The Python twin's constants: Received, SEQUENCE_MODULUS, REORDER_WINDOW, RECORD_HEADER_LEN */
static PyObject *configure(PyObject *self, PyObject *const *args, Py_ssize_t nargs) {
    (void)self;
    if (check_nargs("configure", nargs, 4) < 0) return NULL;
    if (!PyCallable_Check(args[0])) {
        PyErr_SetString(PyExc_TypeError, "configure: Received must be callable");
        return NULL;
    }
    long long modulus = PyLong_AsLongLong(args[1]), window = PyLong_AsLongLong(args[2]);
    long long header = PyLong_AsLongLong(args[3]);
    if (PyErr_Occurred()) return NULL;
    if (modulus <= 0 || window < 0 || window >= modulus || header < 0) {
        PyErr_SetString(PyExc_ValueError, "configure: the sequence modulus, window or record header is out of range");
        return NULL;
    }
    Py_INCREF(args[0]);
    Py_XSETREF(received_type, args[0]);
    sequence_modulus = modulus, reorder_window = window, record_header_len = header;
    Py_RETURN_NONE;
}

static PyMethodDef methods[] = {
    {"deliver_fields", (PyCFunction)(void (*)(void))deliver_fields, METH_FASTCALL,
     "deliver_fields(fields, stats, tlog, received_s, out) -> None (link.endpoint.deliver_fields)"},
    {"configure", (PyCFunction)(void (*)(void))configure, METH_FASTCALL,
     "configure(Received, SEQUENCE_MODULUS, REORDER_WINDOW, RECORD_HEADER_LEN)"},
    {NULL, NULL, 0, NULL},
};

static struct PyModuleDef module = {
    PyModuleDef_HEAD_INIT, "_deliver_kernel",
    "Compiled twin of Endpoint.deliver's per-frame work (link.deliver_kernel).", -1, methods,
};

PyMODINIT_FUNC PyInit__deliver_kernel(void) {
    if (intern_names(NAME_TEXTS, names, N_NAMES) < 0) return NULL;
    return PyModule_Create(&module);
}
