/* Compiled twin of estimator/eskf_timeline.py's Timeline (issue 19): the ESKF's samples on a buffer sorted
by sample time, the filter state after each, rollback and replay. Included by estimator/_eskf_kernels.c (one
extension module: it runs on that file's kernels) and exported there as estimator._eskf_kernels.Timeline.

Takes in: a TimelineConfig (read once, attribute by attribute); estimator.eskf_timeline's F_INDEX,
MOCAP_STATES, TRIM_CHUNK and COUNTERS (read when a timeline is made: one source of truth); and the twin's
calls with the same arguments: link.messages.ImuSample and MocapPose objects (add_imu_sample, add_mocap_pose),
or times (s) and vectors as sequences of floats, and the caller's (15, 15) float64 output arrays.
Gives out: what the twin's methods give, bit for bit: every step below is the twin's in the same order (the
kernels are the same C functions the twin calls), each node holding its nominal state, covariance and
transition (F, Q) in place of the twin's tuples and arrays. tests/estimator/test_eskf_timeline.py checks the
bits over whole filtered flights with late, reordered, lost, duplicate, stale, invalid and outlier samples.

Why: with the kernels compiled, the twin's bookkeeping in Python was most of the estimator's time: 57.4 us of
CPU per 100 Hz tick (five IMU samples, one frame) against 19.9 us with this file (`benchmarks/estimator_bench.py
--seconds 4 --repeats 3`, frames in order, one run). Nodes are allocated one by one (5.7 kB each, P, F and Q
most of it) and recycled through a free list; the buffer holds pointers, so an insertion moves pointers. */

enum { KIND_IMU = 0, KIND_MOCAP = 1 };
enum { ST_NEW, ST_ACCEPTED, ST_REJECTED, ST_REINIT, ST_INIT };
/* estimator.eskf_timeline.COUNTERS, in its order (its length is checked when a timeline is made; its names are
   health_values' keys, which the tests compare between the twins) */
enum {
    C_ACCEPTED_MOCAP, C_REJECTED_OUTLIERS, C_REINITIALISATIONS, C_DUPLICATE_MOCAP, C_STALE_MOCAP, C_INVALID_MOCAP,
    C_IMU_GAPS, C_LOST_IMU, C_REORDERED_IMU, C_STALE_IMU, C_DUPLICATE_IMU, C_INVALID_IMU, N_COUNTERS
};

typedef struct Node {
    double t, start_s;
    int kind, status;
    int has_signal, has_P, has_start, has_transition; /* the twin's None checks */
    double f[3], w[3];   /* IMU signal: specific force FLU m/s^2, rate FLU rad/s */
    double pos[3], att[4]; /* mocap only */
    double x[N_STATE];
    double P[SQUARE], F[SQUARE], Q[SQUARE];
    struct Node *next_free;
} Node;

typedef struct {
    PyObject_HEAD
    double g, imu_period, max_step, buffer_length, gap_factor, gate_d2, reinit_blackout, reinit_velocity_var;
    long reinit_rejections;
    double r[N_MEAS], p0[N_ERR];
    double accel_psd, gyro_psd, accel_bias_psd, gyro_bias_psd;
    int f_index[N_TRANSITION];
    int mocap_sel[N_MEAS]; /* the states a mocap frame measures (H), estimator.eskf_timeline.MOCAP_STATES */
    Py_ssize_t trim_chunk;
    Node **nodes;
    Py_ssize_t n, cap;
    Node **pending; /* mocap frames newer than the newest IMU sample, sorted by time */
    Py_ssize_t n_pending, cap_pending;
    Node *free_nodes;
    double last_accepted_s, last_trimmed_imu_s;
    int has_last_trimmed;
    long consecutive_rejections;
    long long counts[N_COUNTERS];
    double post_dx[N_ERR], post_P[SQUARE]; /* the last innovation's posterior, for inject */
    PyObject *counter_names; /* estimator.eskf_timeline.COUNTERS (a tuple of str), the health_values dict's keys */
} TimelineObject;

static PyObject *lin_alg_error; /* numpy.linalg.LinAlgError, as the twin raises */

/* ------------------------------------------------------------------ nodes and lists */

static Node *node_new(TimelineObject *tl, double t, int kind) {
    Node *node = tl->free_nodes;
    if (node != NULL)
        tl->free_nodes = node->next_free;
    else if ((node = PyMem_Malloc(sizeof(Node))) == NULL) {
        PyErr_NoMemory();
        return NULL;
    }
    node->t = t;
    node->kind = kind;
    node->status = ST_NEW;
    node->has_signal = node->has_P = node->has_start = node->has_transition = 0;
    return node;
}

static void node_free(TimelineObject *tl, Node *node) {
    node->next_free = tl->free_nodes;
    tl->free_nodes = node;
}

/* room for one more pointer in *list (capacity *cap); -1 with MemoryError */
static int reserve(Node ***list, Py_ssize_t n, Py_ssize_t *cap) {
    if (n < *cap) return 0;
    Py_ssize_t grown = *cap ? 2 * *cap : 64;
    Node **bigger = PyMem_Realloc(*list, grown * sizeof(Node *));
    if (bigger == NULL) {
        PyErr_NoMemory();
        return -1;
    }
    *list = bigger;
    *cap = grown;
    return 0;
}

static int insert_node(TimelineObject *tl, Py_ssize_t i, Node *node) {
    if (reserve(&tl->nodes, tl->n, &tl->cap) < 0) return -1;
    memmove(&tl->nodes[i + 1], &tl->nodes[i], (tl->n - i) * sizeof(Node *));
    tl->nodes[i] = node;
    tl->n++;
    return 0;
}

/* bisect.bisect_left / bisect_right over the nodes' times */
static Py_ssize_t bisect_left(const TimelineObject *tl, double t) {
    Py_ssize_t lo = 0, hi = tl->n;
    while (lo < hi) {
        Py_ssize_t mid = (lo + hi) / 2;
        if (tl->nodes[mid]->t < t) lo = mid + 1; else hi = mid;
    }
    return lo;
}

static Py_ssize_t bisect_right(const TimelineObject *tl, double t) {
    Py_ssize_t lo = 0, hi = tl->n;
    while (lo < hi) {
        Py_ssize_t mid = (lo + hi) / 2;
        if (t < tl->nodes[mid]->t) hi = mid; else lo = mid + 1;
    }
    return lo;
}

static void reset_bookkeeping(TimelineObject *tl) {
    for (Py_ssize_t i = 0; i < tl->n; i++) node_free(tl, tl->nodes[i]);
    for (Py_ssize_t i = 0; i < tl->n_pending; i++) node_free(tl, tl->pending[i]);
    tl->n = tl->n_pending = 0;
    tl->last_accepted_s = -INFINITY;
    tl->consecutive_rejections = 0;
    tl->has_last_trimmed = 0;
    memset(tl->counts, 0, sizeof(tl->counts));
}

/* ------------------------------------------------------------------ propagation (the twin's _propagate) */

static void lerp3(const double a[3], const double b[3], double s, double out[3]) {
    out[0] = a[0] + s * (b[0] - a[0]);
    out[1] = a[1] + s * (b[1] - a[1]);
    out[2] = a[2] + s * (b[2] - a[2]);
}

static void process_noise(const TimelineObject *tl, double dt, double *Q) {
    double qv = tl->accel_psd * dt;
    double qp = qv * dt * dt / 3.0, qpv = qv * dt * 0.5;
    double qt = tl->gyro_psd * dt, qba = tl->accel_bias_psd * dt, qbg = tl->gyro_bias_psd * dt;
    memset(Q, 0, SQUARE * sizeof(double));
    for (int i = 0; i < 3; i++) {
        Q[i * N_ERR + i] = qp;
        Q[i * N_ERR + 3 + i] = qpv;
        Q[(3 + i) * N_ERR + i] = qpv;
        Q[(3 + i) * N_ERR + 3 + i] = qv;
        Q[(6 + i) * N_ERR + 6 + i] = qt;
        Q[(9 + i) * N_ERR + 9 + i] = qba;
        Q[(12 + i) * N_ERR + 12 + i] = qbg;
    }
}

/* the twin's _step: x1, and F (the identity with its transition entries) and Q over dt */
static int step(const TimelineObject *tl, const double *x, const double *f0, const double *w0, const double *f1,
                const double *w1, double dt, double *x1, double *F, double *Q) {
    double v[N_TRANSITION];
    if (propagate_core(x, f0, w0, f1, w1, dt, tl->g, x1, v) < 0) return -1;
    memset(F, 0, SQUARE * sizeof(double));
    for (int i = 0; i < N_ERR; i++) F[i * N_ERR + i] = 1.0;
    for (int i = 0; i < N_TRANSITION; i++) F[tl->f_index[i]] = v[i];
    process_noise(tl, dt, Q);
    return 0;
}

/* the twin's _advance: node's nominal state and (unless `keep`: an earlier pass's stored one) its (F, Q) from
   prev; its P left pending */
static int advance(const TimelineObject *tl, Node *node, const Node *prev, int keep) {
    double dt = node->t - prev->t;
    node->start_s = prev->t;
    node->has_start = 1;
    node->has_P = 0;
    if (!prev->has_signal || !node->has_signal) {
        PyErr_SetString(PyExc_RuntimeError, "timeline: a node without an IMU signal");
        return -1;
    }
    if (dt <= 0.0) {
        memcpy(node->x, prev->x, sizeof(node->x));
        node->has_transition = keep;
        return 0;
    }
    double n_real = ceil(dt / tl->max_step - 1e-9);
    if (n_real <= 1.0) {
        if (keep) return propagate_core(prev->x, prev->f, prev->w, node->f, node->w, dt, tl->g, node->x, NULL);
        node->has_transition = 1;
        return step(tl, prev->x, prev->f, prev->w, node->f, node->w, dt, node->x, node->F, node->Q);
    }
    long n = (long)n_real;
    double h = dt / n_real;
    double x[N_STATE], fa[3], wa[3], fb[3], wb[3];
    memcpy(x, prev->x, sizeof(x));
    memcpy(fa, prev->f, sizeof(fa));
    memcpy(wa, prev->w, sizeof(wa));
    double F[SQUARE], Q[SQUARE], scratch[SQUARE];
    for (long k = 1; k <= n; k++) {
        double s = (double)k / n_real;
        lerp3(prev->f, node->f, s, fb);
        lerp3(prev->w, node->w, s, wb);
        if (keep) {
            if (propagate_core(x, fa, wa, fb, wb, h, tl->g, x, NULL) < 0) return -1;
        } else if (k == 1) {
            if (step(tl, x, fa, wa, fb, wb, h, x, node->F, node->Q) < 0) return -1;
        } else {
            if (step(tl, x, fa, wa, fb, wb, h, x, F, Q) < 0) return -1;
            predict_kernel(node->Q, F, Q, scratch); /* Q_total = F Q_total F' + Q */
            memcpy(node->Q, scratch, sizeof(scratch));
            multiply_core(F, node->F, node->F); /* F_total = F F_total */
        }
        memcpy(fa, fb, sizeof(fa));
        memcpy(wa, wb, sizeof(wa));
    }
    memcpy(node->x, x, sizeof(x));
    node->has_transition = 1;
    return 0;
}

/* the twin's _covariance_at: P of node j, predicting over the intervals still pending */
static double *covariance_at(TimelineObject *tl, Py_ssize_t j) {
    Node **nodes = tl->nodes;
    Py_ssize_t k = j;
    while (!nodes[k]->has_P) k--; /* nodes[0] always has its P */
    for (Py_ssize_t m = k + 1; m <= j; m++) {
        Node *node = nodes[m];
        if (node->has_transition)
            predict_kernel(nodes[m - 1]->P, node->F, node->Q, node->P);
        else
            memcpy(node->P, nodes[m - 1]->P, sizeof(node->P));
        node->has_P = 1;
    }
    return nodes[j]->P;
}

/* ------------------------------------------------------------------ mocap decisions */

static int decide(TimelineObject *tl, double d2, double t) {
    int status;
    if (d2 <= tl->gate_d2)
        status = ST_ACCEPTED;
    else if (t - tl->last_accepted_s > tl->reinit_blackout || tl->consecutive_rejections >= tl->reinit_rejections)
        status = ST_REINIT;
    else {
        tl->counts[C_REJECTED_OUTLIERS]++;
        tl->consecutive_rejections++;
        return ST_REJECTED;
    }
    tl->counts[status == ST_REINIT ? C_REINITIALISATIONS : C_ACCEPTED_MOCAP]++;
    tl->consecutive_rejections = 0;
    tl->last_accepted_s = t > tl->last_accepted_s ? t : tl->last_accepted_s; /* max(last, t) */
    return status;
}

/* model.frames.attitude_error(q_from, q_to) = quat_log(quat_conjugate(q_from) (x) q_to) */
static void attitude_error(const double q_from[4], const double q_to[4], double out[3]) {
    double conj[4] = {q_from[0], -q_from[1], -q_from[2], -q_from[3]}, q[4];
    quat_multiply(conj, q_to, q);
    double w = q[0], x = q[1], y = q[2], z = q[3];
    if (w < 0.0) {
        w = -w; x = -x; y = -y; z = -z;
    }
    double n = sqrt(x * x + y * y + z * z);
    double k = n < small_angle_rad ? 2.0 / w : 2.0 * atan2(n, w) / n;
    out[0] = k * x; out[1] = k * y; out[2] = k * z;
}

/* the twin's _innovate: d^2, the posterior kept in post_dx / post_P; NaN (LinAlgError set) if S is not
   positive definite */
static double innovate(TimelineObject *tl, const double *x, const double *P, const Node *node) {
    double dtheta[3];
    attitude_error(&x[6], node->att, dtheta);
    double z[N_MEAS] = {node->pos[0] - x[0], node->pos[1] - x[1], node->pos[2] - x[2], dtheta[0], dtheta[1], dtheta[2]};
    double d2 = update_core(P, z, tl->r, tl->mocap_sel, tl->post_P, tl->post_dx);
    if (isnan(d2))
        PyErr_SetString(lin_alg_error, "mocap update: innovation covariance H P H' + R not positive definite");
    return d2;
}

/* the twin's _inject, into the node's x and P */
static int inject(TimelineObject *tl, Node *node) {
    const double *dx = tl->post_dx, *x = node->x;
    double dq[4], q[4];
    quat_exp(dx[6], dx[7], dx[8], dq);
    quat_multiply(&x[6], dq, q);
    if (quat_normalize_positive_w(q) < 0) return -1;
    double x_new[N_STATE] = {
        x[0] + dx[0], x[1] + dx[1], x[2] + dx[2], x[3] + dx[3], x[4] + dx[4], x[5] + dx[5], q[0], q[1], q[2], q[3],
        x[10] + dx[9], x[11] + dx[10], x[12] + dx[11], x[13] + dx[12], x[14] + dx[13], x[15] + dx[14],
    };
    memcpy(node->x, x_new, sizeof(x_new));
    double dtheta[3] = {dx[6], dx[7], dx[8]};
    reset_core(tl->post_P, dtheta, node->P);
    return 0;
}

/* P = diag(p0), the initial covariance (the twin's np.diag(p0_diag)) */
static void initial_covariance(const TimelineObject *tl, double *P) {
    memset(P, 0, SQUARE * sizeof(double));
    for (int i = 0; i < N_ERR; i++) P[i * N_ERR + i] = tl->p0[i];
}

/* the twin's _reinitialised, into the node's x and P (P holds the prior: its bias blocks are kept) */
static void reinitialise_at(const TimelineObject *tl, Node *node) {
    double *x = node->x, *P = node->P;
    memcpy(&x[0], node->pos, sizeof(node->pos));
    memcpy(&x[6], node->att, sizeof(node->att));
    double bias[6][6];
    for (int i = 0; i < 6; i++)
        for (int j = 0; j < 6; j++) bias[i][j] = P[(9 + i) * N_ERR + 9 + j];
    initial_covariance(tl, P);
    for (int i = 3; i < 6; i++) P[i * N_ERR + i] = 1.0 * tl->reinit_velocity_var; /* np.eye(3) * var */
    for (int i = 0; i < 6; i++)
        for (int j = 0; j < 6; j++) P[(9 + i) * N_ERR + 9 + j] = bias[i][j];
}

/* the twin's _signal_at: the IMU signal at mocap node j */
static void signal_at(TimelineObject *tl, Py_ssize_t j, double f[3], double w[3]) {
    const Node *prev = tl->nodes[j - 1];
    for (Py_ssize_t k = j + 1; k < tl->n; k++) {
        const Node *next = tl->nodes[k];
        if (next->kind == KIND_IMU) {
            double span = next->t - prev->t;
            double s = span > 0.0 ? (tl->nodes[j]->t - prev->t) / span : 0.0;
            lerp3(prev->f, next->f, s, f);
            lerp3(prev->w, next->w, s, w);
            return;
        }
    }
    memcpy(f, prev->f, 3 * sizeof(double));
    memcpy(w, prev->w, 3 * sizeof(double));
}

/* the twin's _process_mocap: 1, or 0 after a re-initialisation; -1 with the error set */
static int process_mocap(TimelineObject *tl, Py_ssize_t j, int keep) {
    Node *node = tl->nodes[j];
    signal_at(tl, j, node->f, node->w);
    node->has_signal = 1;
    if (advance(tl, node, tl->nodes[j - 1], keep) < 0) return -1;
    const double *P = covariance_at(tl, j);
    if (node->status == ST_NEW) {
        double d2 = innovate(tl, node->x, P, node);
        if (isnan(d2)) return -1;
        node->status = decide(tl, d2, node->t);
        if (node->status == ST_ACCEPTED && inject(tl, node) < 0) return -1;
    } else if (node->status == ST_ACCEPTED) {
        if (isnan(innovate(tl, node->x, P, node)) || inject(tl, node) < 0) return -1;
    }
    if (node->status == ST_REINIT) reinitialise_at(tl, node);
    return node->status != ST_REINIT;
}

/* ------------------------------------------------------------------ timeline bookkeeping */

static int replay_from(TimelineObject *tl, Py_ssize_t i) {
    int reuse = 1;
    for (Py_ssize_t j = i; j < tl->n; j++) {
        Node *node = tl->nodes[j], *prev = tl->nodes[j - 1];
        int keep = reuse && node->has_start && node->start_s == prev->t && node->has_transition;
        if (node->kind == KIND_IMU) {
            if (advance(tl, node, prev, keep) < 0) return -1;
        } else {
            int r = process_mocap(tl, j, keep);
            if (r < 0) return -1;
            if (r == 0) reuse = 0;
        }
    }
    return 0;
}

static void count_gap(TimelineObject *tl, double t) {
    int had = tl->has_last_trimmed;
    double last = tl->last_trimmed_imu_s;
    tl->last_trimmed_imu_s = t;
    tl->has_last_trimmed = 1;
    if (had && t - last > tl->gap_factor * tl->imu_period) {
        tl->counts[C_IMU_GAPS]++;
        long long lost = (long long)nearbyint((t - last) / tl->imu_period) - 1; /* round(): half to even */
        tl->counts[C_LOST_IMU] += lost > 1 ? lost : 1;
    }
}

static void trim(TimelineObject *tl) {
    double cut = tl->nodes[tl->n - 1]->t - tl->buffer_length;
    if (tl->n <= tl->trim_chunk || tl->nodes[tl->trim_chunk]->t >= cut) return;
    Py_ssize_t k = bisect_left(tl, cut) - 1;
    covariance_at(tl, k); /* the new base holds its P */
    for (Py_ssize_t i = 0; i < k; i++) {
        if (tl->nodes[i]->kind == KIND_IMU) count_gap(tl, tl->nodes[i]->t);
        node_free(tl, tl->nodes[i]);
    }
    memmove(tl->nodes, &tl->nodes[k], (tl->n - k) * sizeof(Node *));
    tl->n -= k;
}

static int append_imu(TimelineObject *tl, Node *node) {
    Node *base = tl->nodes[0];
    if (!base->has_signal) { /* the initial pose gets the first sample as its IMU signal */
        memcpy(base->f, node->f, sizeof(base->f));
        memcpy(base->w, node->w, sizeof(base->w));
        base->has_signal = 1;
    }
    Py_ssize_t start = tl->n;
    double t = node->t;
    if (tl->n_pending == 0 || tl->pending[0]->t > t) { /* nothing released (sorted by time) */
        if (advance(tl, node, tl->nodes[tl->n - 1], 0) < 0 || insert_node(tl, tl->n, node) < 0) {
            node_free(tl, node);
            return -1;
        }
        return 0;
    }
    Py_ssize_t released = 0;
    while (released < tl->n_pending && tl->pending[released]->t <= t) released++;
    Py_ssize_t before = 0; /* released frames older than the sample: they go before it, the rest after */
    while (before < released && tl->pending[before]->t < t) before++;
    for (Py_ssize_t m = 0; m <= released; m++) {
        Node *next = m < before ? tl->pending[m] : m == before ? node : tl->pending[m - 1];
        if (insert_node(tl, tl->n, next) < 0) return -1;
    }
    memmove(tl->pending, &tl->pending[released], (tl->n_pending - released) * sizeof(Node *));
    tl->n_pending -= released;
    return replay_from(tl, start);
}

static int insert_imu(TimelineObject *tl, Node *node) {
    double t = node->t;
    if (t < tl->nodes[0]->t) {
        tl->counts[C_STALE_IMU]++;
        node_free(tl, node);
        return 0;
    }
    Py_ssize_t i = bisect_left(tl, t);
    for (Py_ssize_t k = i; k < tl->n && tl->nodes[k]->t == t; k++)
        if (tl->nodes[k]->kind == KIND_IMU) {
            tl->counts[C_DUPLICATE_IMU]++;
            node_free(tl, node);
            return 0;
        }
    if (i == 0) { /* same time as the base node (a pose): nothing before it to replay from */
        tl->counts[C_STALE_IMU]++;
        node_free(tl, node);
        return 0;
    }
    if (insert_node(tl, i, node) < 0) {
        node_free(tl, node);
        return -1;
    }
    tl->counts[C_REORDERED_IMU]++;
    Py_ssize_t start = i; /* mocap nodes just before the new sample interpolated their signal past it */
    while (start > 1 && tl->nodes[start - 1]->kind == KIND_MOCAP) {
        start--;
        tl->nodes[start]->has_transition = 0;
    }
    return replay_from(tl, start);
}

static int holds_mocap_at(const TimelineObject *tl, double t) {
    for (Py_ssize_t i = bisect_left(tl, t); i < tl->n && tl->nodes[i]->t == t; i++)
        if (tl->nodes[i]->kind == KIND_MOCAP) return 1;
    for (Py_ssize_t i = 0; i < tl->n_pending; i++)
        if (tl->pending[i]->t == t) return 1;
    return 0;
}

/* a new mocap node at t; NULL with MemoryError */
static Node *mocap_node(TimelineObject *tl, double t, const double pos[3], const double att[4]) {
    Node *node = node_new(tl, t, KIND_MOCAP);
    if (node == NULL) return NULL;
    memcpy(node->pos, pos, 3 * sizeof(double));
    memcpy(node->att, att, 4 * sizeof(double));
    return node;
}

/* (t, position, attitude) arguments, as add_mocap and queue_mocap take them; -1 with the error set */
static int read_frame_args(PyObject *const *args, double *t, double pos[3], double att[4]) {
    *t = PyFloat_AsDouble(args[0]);
    if (*t == -1.0 && PyErr_Occurred()) return -1;
    return read_floats(args[1], pos, 3, "position") < 0 || read_floats(args[2], att, 4, "attitude") < 0 ? -1 : 0;
}

static int queue_node(TimelineObject *tl, Node *node) {
    if (reserve(&tl->pending, tl->n_pending, &tl->cap_pending) < 0) return -1;
    Py_ssize_t i = tl->n_pending; /* bisect.insort: after frames of the same time */
    while (i > 0 && tl->pending[i - 1]->t > node->t) i--;
    memmove(&tl->pending[i + 1], &tl->pending[i], (tl->n_pending - i) * sizeof(Node *));
    tl->pending[i] = node;
    tl->n_pending++;
    return 0;
}

static int started(const TimelineObject *tl) { return tl->n > 0 && tl->nodes[0]->has_signal; }

static int require_started(const TimelineObject *tl, const char *method) {
    if (started(tl)) return 0;
    PyErr_Format(PyExc_RuntimeError, "Timeline.%s: the timeline has not started (no IMU sample yet)", method);
    return -1;
}

/* ------------------------------------------------------------------ the methods (the twin's public ones) */

static int require_nodes(const TimelineObject *tl, const char *method) {
    if (tl->n > 0) return 0;
    PyErr_Format(PyExc_RuntimeError, "Timeline.%s: the timeline is empty", method);
    return -1;
}

static PyObject *tl_initialise(TimelineObject *tl, PyObject *const *args, Py_ssize_t nargs) {
    if (check_nargs("initialise", nargs, 2) < 0) return NULL;
    double t = PyFloat_AsDouble(args[0]), x[N_STATE];
    if ((t == -1.0 && PyErr_Occurred()) || read_floats(args[1], x, N_STATE, "x") < 0) return NULL;
    reset_bookkeeping(tl);
    Node *node = node_new(tl, t, KIND_MOCAP);
    if (node == NULL) return NULL;
    node->status = ST_INIT;
    memcpy(node->x, x, sizeof(x));
    initial_covariance(tl, node->P);
    node->has_P = 1;
    if (insert_node(tl, 0, node) < 0) {
        node_free(tl, node);
        return NULL;
    }
    tl->last_accepted_s = t;
    Py_RETURN_NONE;
}

static PyObject *tl_count(TimelineObject *tl, PyObject *counter) {
    long i = PyLong_AsLong(counter);
    if (i == -1 && PyErr_Occurred()) return NULL;
    if (i < 0 || i >= N_COUNTERS) {
        PyErr_SetString(PyExc_IndexError, "Timeline.count: no such counter");
        return NULL;
    }
    tl->counts[i]++;
    Py_RETURN_NONE;
}

/* the twin's add_imu on a started timeline: -1 with the error set */
static int add_imu_values(TimelineObject *tl, double t, const double f[3], const double w[3]) {
    Node *node = node_new(tl, t, KIND_IMU);
    if (node == NULL) return -1;
    memcpy(node->f, f, 3 * sizeof(double));
    memcpy(node->w, w, 3 * sizeof(double));
    node->has_signal = 1;
    if ((t > tl->nodes[tl->n - 1]->t ? append_imu(tl, node) : insert_imu(tl, node)) < 0) return -1;
    trim(tl);
    return 0;
}

/* the twin's add_mocap on a started timeline: 1 accepted (or held), 0 not, -1 with the error set */
static int add_mocap_values(TimelineObject *tl, double t, const double pos[3], const double att[4]) {
    if (t < tl->nodes[0]->t || holds_mocap_at(tl, t)) {
        tl->counts[t < tl->nodes[0]->t ? C_STALE_MOCAP : C_DUPLICATE_MOCAP]++;
        return 0;
    }
    Node *node = mocap_node(tl, t, pos, att);
    if (node == NULL) return -1;
    if (t > tl->nodes[tl->n - 1]->t) { /* queued: decided when the IMU stream reaches its sample time */
        if (queue_node(tl, node) < 0) {
            node_free(tl, node);
            return -1;
        }
        return 1;
    }
    Py_ssize_t i = bisect_right(tl, t);
    if (insert_node(tl, i, node) < 0) {
        node_free(tl, node);
        return -1;
    }
    if (replay_from(tl, i) < 0) return -1;
    return node->status == ST_ACCEPTED || node->status == ST_REINIT;
}

static PyObject *tl_add_imu(TimelineObject *tl, PyObject *const *args, Py_ssize_t nargs) {
    if (check_nargs("add_imu", nargs, 3) < 0 || require_nodes(tl, "add_imu") < 0) return NULL;
    double t = PyFloat_AsDouble(args[0]), f[3], w[3];
    if ((t == -1.0 && PyErr_Occurred()) || read_floats(args[1], f, 3, "f") < 0 || read_floats(args[2], w, 3, "w") < 0)
        return NULL;
    if (add_imu_values(tl, t, f, w) < 0) return NULL;
    Py_RETURN_NONE;
}

static PyObject *tl_add_mocap(TimelineObject *tl, PyObject *const *args, Py_ssize_t nargs) {
    double t, pos[3], att[4];
    if (check_nargs("add_mocap", nargs, 3) < 0 || require_started(tl, "add_mocap") < 0
        || read_frame_args(args, &t, pos, att) < 0)
        return NULL;
    int accepted = add_mocap_values(tl, t, pos, att);
    return accepted < 0 ? NULL : PyBool_FromLong(accepted);
}

/* ------------------------------------------------------------------ samples as they arrive (the twin's
   add_imu_sample, add_mocap_pose): their checks, then the above */

enum { ADD_TAKEN, ADD_INVALID, ADD_NOT_STARTED }; /* estimator.eskf_timeline.TAKEN, INVALID, NOT_STARTED */
static PyObject *name_time_s, *name_force, *name_rate, *name_position, *name_attitude; /* interned */

/* obj.name as a list or tuple (PySequence_Fast: a new reference); NULL with the error set */
static PyObject *attr_sequence(PyObject *obj, PyObject *name) {
    PyObject *value = PyObject_GetAttr(obj, name);
    if (value == NULL) return NULL;
    PyObject *fast = PySequence_Fast(value, "a sample's vector");
    Py_DECREF(value);
    return fast;
}

/* the items of a PySequence_Fast as doubles (float() of each: a non-number raises); -1 with the error set */
static int sequence_floats(PyObject *fast, double *out) {
    Py_ssize_t n = PySequence_Fast_GET_SIZE(fast);
    PyObject **items = PySequence_Fast_ITEMS(fast);
    for (Py_ssize_t i = 0; i < n; i++) {
        out[i] = PyFloat_AsDouble(items[i]);
        if (out[i] == -1.0 && PyErr_Occurred()) return -1;
    }
    return 0;
}

static int all_finite(const double *v, int n) {
    for (int i = 0; i < n; i++)
        if (!isfinite(v[i])) return 0;
    return 1;
}

/* A sample's time and two vectors of sizes n1, n2 (n1 + n2 <= 7) into v (t first), read as the twin reads
   them: both lengths checked first (1: wrong, nothing converted), then the numbers converted, time first
   (-1 with the error set: not a number, or no such attribute), then 0 */
static int read_sample(PyObject *obj, PyObject *name1, Py_ssize_t n1, PyObject *name2, Py_ssize_t n2, double *v) {
    PyObject *first = attr_sequence(obj, name1);
    PyObject *second = first == NULL ? NULL : attr_sequence(obj, name2);
    int status = -1;
    if (second != NULL) {
        if (PySequence_Fast_GET_SIZE(first) != n1 || PySequence_Fast_GET_SIZE(second) != n2) {
            status = 1;
        } else {
            PyObject *t = PyObject_GetAttr(obj, name_time_s);
            if (t != NULL) {
                v[0] = PyFloat_AsDouble(t);
                Py_DECREF(t);
                if (!(v[0] == -1.0 && PyErr_Occurred()) && sequence_floats(first, &v[1]) == 0
                    && sequence_floats(second, &v[1 + n1]) == 0)
                    status = 0;
            }
        }
    }
    Py_XDECREF(first);
    Py_XDECREF(second);
    return status;
}

static PyObject *tl_add_imu_sample(TimelineObject *tl, PyObject *sample) {
    double v[7]; /* t, f, w */
    int status = read_sample(sample, name_force, 3, name_rate, 3, v);
    if (status < 0) return NULL;
    if (status == 1 || !all_finite(v, 7)) {
        tl->counts[C_INVALID_IMU]++;
        return PyLong_FromLong(ADD_INVALID);
    }
    if (!started(tl)) return PyLong_FromLong(ADD_NOT_STARTED);
    if (add_imu_values(tl, v[0], &v[1], &v[4]) < 0) return NULL;
    return PyLong_FromLong(ADD_TAKEN);
}

static PyObject *tl_add_mocap_pose(TimelineObject *tl, PyObject *pose) {
    double v[8]; /* t, position, attitude */
    int status = read_sample(pose, name_position, 3, name_attitude, 4, v);
    if (status < 0) return NULL;
    if (status == 1 || !all_finite(v, 8) || !(v[4] != 0.0 || v[5] != 0.0 || v[6] != 0.0 || v[7] != 0.0)) {
        tl->counts[C_INVALID_MOCAP]++;
        Py_RETURN_FALSE;
    }
    if (!started(tl)) Py_RETURN_NONE;
    if (quat_normalize_positive_w(&v[4]) < 0) return NULL;
    int accepted = add_mocap_values(tl, v[0], &v[1], &v[4]);
    return accepted < 0 ? NULL : PyBool_FromLong(accepted);
}

static PyObject *tl_queue_mocap(TimelineObject *tl, PyObject *const *args, Py_ssize_t nargs) {
    double t, pos[3], att[4];
    if (check_nargs("queue_mocap", nargs, 3) < 0 || read_frame_args(args, &t, pos, att) < 0) return NULL;
    Node *node = mocap_node(tl, t, pos, att);
    if (node == NULL) return NULL;
    if (queue_node(tl, node) < 0) {
        node_free(tl, node);
        return NULL;
    }
    Py_RETURN_NONE;
}

static PyObject *tl_newest(TimelineObject *tl, PyObject *P_obj) {
    if (require_nodes(tl, "newest") < 0) return NULL;
    Py_buffer view;
    if (get_matrix(P_obj, &view, SQUARE, 1, "P_out") < 0) return NULL;
    const double *P = covariance_at(tl, tl->n - 1);
    memcpy(view.buf, P, SQUARE * sizeof(double));
    PyBuffer_Release(&view);
    const Node *node = tl->nodes[tl->n - 1];
    PyObject *x = float_tuple(node->x, N_STATE);
    PyObject *w = node->has_signal ? float_tuple(node->w, 3) : Py_NewRef(Py_None);
    if (x == NULL || w == NULL) {
        Py_XDECREF(x);
        Py_XDECREF(w);
        return NULL;
    }
    return Py_BuildValue("(dNN)", node->t, x, w);
}

static PyObject *tl_predict(TimelineObject *tl, PyObject *const *args, Py_ssize_t nargs) {
    if (check_nargs("predict", nargs, 2) < 0 || require_nodes(tl, "predict") < 0) return NULL;
    double t = PyFloat_AsDouble(args[0]);
    if (t == -1.0 && PyErr_Occurred()) return NULL;
    const Node *node = tl->nodes[tl->n - 1];
    double dt = t - node->t;
    if (!node->has_signal || !(dt > 0.0)) Py_RETURN_NONE;
    Py_buffer view;
    if (get_matrix(args[1], &view, SQUARE, 1, "P_out") < 0) return NULL;
    double x[N_STATE], F[SQUARE], Q[SQUARE];
    if (step(tl, node->x, node->f, node->w, node->f, node->w, dt, x, F, Q) < 0) {
        PyBuffer_Release(&view);
        return NULL;
    }
    predict_kernel(covariance_at(tl, tl->n - 1), F, Q, view.buf);
    PyBuffer_Release(&view);
    PyObject *xs = float_tuple(x, N_STATE), *ws = float_tuple(node->w, 3);
    if (xs == NULL || ws == NULL) {
        Py_XDECREF(xs);
        Py_XDECREF(ws);
        return NULL;
    }
    return Py_BuildValue("(NN)", xs, ws);
}

/* a new dict of the counters by name (the twin's dict(zip(COUNTERS, counts))); NULL with the error set */
static PyObject *counts_dict(TimelineObject *tl, const char *method) {
    if (tl->counter_names == NULL) {
        PyErr_Format(PyExc_RuntimeError, "Timeline.%s: the timeline was not made (__init__ failed)", method);
        return NULL;
    }
    PyObject *counts = PyDict_New();
    if (counts == NULL) return NULL;
    for (int i = 0; i < N_COUNTERS; i++) {
        PyObject *value = PyLong_FromLongLong(tl->counts[i]);
        int failed = value == NULL || PyDict_SetItem(counts, PyTuple_GET_ITEM(tl->counter_names, i), value) < 0;
        Py_XDECREF(value);
        if (failed) {
            Py_DECREF(counts);
            return NULL;
        }
    }
    return counts;
}

static PyObject *tl_health_values(TimelineObject *tl, PyObject *Py_UNUSED(ignored)) {
    PyObject *counts = counts_dict(tl, "health_values");
    if (counts == NULL) return NULL;
    PyObject *newest = tl->n ? PyFloat_FromDouble(tl->nodes[tl->n - 1]->t) : Py_NewRef(Py_None);
    if (newest == NULL) {
        Py_DECREF(counts);
        return NULL;
    }
    return Py_BuildValue("(NdlN)", newest, tl->last_accepted_s, tl->consecutive_rejections, counts);
}

/* The twin's newest_state: newest(P_out), then fill_state(x, w, P, values_out, std_out) - values = x, then
   w - b_g (-b_g without a signal), std = sqrt(diag P) - then health_values' last three. */
#define N_VALUES (N_STATE + 3) /* estimator.eskf_timeline.N_VALUES: x, then the rate */
#define GYRO_BIAS 13            /* b_g's first index in x (p, v, q wxyz, b_a, b_g) */
static PyObject *tl_newest_state(TimelineObject *tl, PyObject *const *args, Py_ssize_t nargs) {
    static const MatrixArg outputs[] = {
        {0, SQUARE, 1, "P_out"}, {1, N_VALUES, 1, "values_out"}, {2, N_ERR, 1, "std_out"}};
    if (check_nargs("newest_state", nargs, 3) < 0 || require_nodes(tl, "newest_state") < 0) return NULL;
    Py_buffer views[3];
    if (get_matrices(args, outputs, 3, views) < 0) return NULL;
    const Node *node = tl->nodes[tl->n - 1];
    double *P = views[0].buf, *values = views[1].buf, *std = views[2].buf;
    memcpy(P, covariance_at(tl, tl->n - 1), SQUARE * sizeof(double));
    memcpy(values, node->x, N_STATE * sizeof(double));
    for (int i = 0; i < 3; i++) {
        double bias = node->x[GYRO_BIAS + i];
        values[N_STATE + i] = node->has_signal ? node->w[i] - bias : -bias;
    }
    for (int i = 0; i < N_ERR; i++) std[i] = sqrt(P[i * N_ERR + i]);
    release_all(views, 3);
    PyObject *counts = counts_dict(tl, "newest_state");
    if (counts == NULL) return NULL;
    return Py_BuildValue("(ddlN)", node->t, tl->last_accepted_s, tl->consecutive_rejections, counts);
}

static PyObject *tl_get_empty(TimelineObject *tl, void *Py_UNUSED(closure)) { return PyBool_FromLong(tl->n == 0); }

static PyObject *tl_get_started(TimelineObject *tl, void *Py_UNUSED(closure)) { return PyBool_FromLong(started(tl)); }

/* ------------------------------------------------------------------ making one */

static int config_float(PyObject *config, const char *name, double *out) {
    PyObject *value = PyObject_GetAttrString(config, name);
    if (value == NULL) return -1;
    *out = PyFloat_AsDouble(value);
    Py_DECREF(value);
    return (*out == -1.0 && PyErr_Occurred()) ? -1 : 0;
}

static int config_floats(PyObject *config, const char *name, double *out, Py_ssize_t n) {
    PyObject *value = PyObject_GetAttrString(config, name);
    if (value == NULL) return -1;
    int status = read_floats(value, out, n, name);
    Py_DECREF(value);
    return status;
}

/* n indices in [0, limit) from module.name into out; -1 with the error set */
static int read_indices(PyObject *mod, const char *name, int *out, int n, int limit) {
    PyObject *value = PyObject_GetAttrString(mod, name);
    if (value == NULL) return -1;
    double values[N_TRANSITION]; /* the longest: F_INDEX */
    int status = n <= N_TRANSITION ? read_floats(value, values, n, name) : -1;
    Py_DECREF(value);
    for (int i = 0; status == 0 && i < n; i++) {
        out[i] = (int)values[i];
        if (out[i] < 0 || out[i] >= limit || values[i] != out[i]) {
            PyErr_Format(PyExc_ValueError, "estimator.eskf_timeline.%s: index %d out of range", name, i);
            status = -1;
        }
    }
    return status;
}

/* F_INDEX, MOCAP_STATES, TRIM_CHUNK and COUNTERS (its length checked: its names are health_values' keys)
   from estimator.eskf_timeline */
static int read_twin_constants(TimelineObject *tl) {
    PyObject *mod = PyImport_ImportModule("estimator.eskf_timeline");
    if (mod == NULL) return -1;
    int status = -1;
    PyObject *chunk = NULL, *counters = NULL;
    if (read_indices(mod, "F_INDEX", tl->f_index, N_TRANSITION, SQUARE) == 0
        && read_indices(mod, "MOCAP_STATES", tl->mocap_sel, N_MEAS, N_ERR) == 0
        && (chunk = PyObject_GetAttrString(mod, "TRIM_CHUNK")) != NULL
        && (counters = PyObject_GetAttrString(mod, "COUNTERS")) != NULL) {
        tl->trim_chunk = PyLong_AsSsize_t(chunk);
        if (PyErr_Occurred()) {
            status = -1;
        } else if (tl->trim_chunk < 1 || !PyTuple_Check(counters) || PyTuple_GET_SIZE(counters) != N_COUNTERS) {
            PyErr_SetString(PyExc_ValueError, "estimator.eskf_timeline's TRIM_CHUNK or COUNTERS do not match the "
                                              "compiled timeline");
        } else {
            Py_XSETREF(tl->counter_names, Py_NewRef(counters));
            status = 0;
        }
    }
    Py_DECREF(mod);
    Py_XDECREF(chunk);
    Py_XDECREF(counters);
    return status;
}

static int tl_init(TimelineObject *tl, PyObject *args, PyObject *kwargs) {
    PyObject *config;
    static char *names[] = {"config", NULL};
    if (!PyArg_ParseTupleAndKeywords(args, kwargs, "O:Timeline", names, &config)) return -1;
    double rejections;
    if (config_float(config, "gravity_mps2", &tl->g) < 0 || config_float(config, "imu_period_s", &tl->imu_period) < 0
        || config_float(config, "max_step_s", &tl->max_step) < 0
        || config_float(config, "buffer_length_s", &tl->buffer_length) < 0
        || config_float(config, "gap_factor", &tl->gap_factor) < 0 || config_float(config, "gate_d2", &tl->gate_d2) < 0
        || config_float(config, "reinit_after_blackout_s", &tl->reinit_blackout) < 0
        || config_float(config, "reinit_after_rejections", &rejections) < 0
        || config_floats(config, "r_diag", tl->r, N_MEAS) < 0 || config_floats(config, "p0_diag", tl->p0, N_ERR) < 0
        || config_float(config, "reinit_velocity_var", &tl->reinit_velocity_var) < 0
        || config_float(config, "accel_psd", &tl->accel_psd) < 0 || config_float(config, "gyro_psd", &tl->gyro_psd) < 0
        || config_float(config, "accel_bias_psd", &tl->accel_bias_psd) < 0
        || config_float(config, "gyro_bias_psd", &tl->gyro_bias_psd) < 0 || read_twin_constants(tl) < 0)
        return -1;
    tl->reinit_rejections = (long)rejections;
    reset_bookkeeping(tl);
    return 0;
}

static void tl_dealloc(TimelineObject *tl) {
    reset_bookkeeping(tl);
    while (tl->free_nodes != NULL) {
        Node *next = tl->free_nodes->next_free;
        PyMem_Free(tl->free_nodes);
        tl->free_nodes = next;
    }
    PyMem_Free(tl->nodes);
    PyMem_Free(tl->pending);
    Py_XDECREF(tl->counter_names);
    Py_TYPE(tl)->tp_free((PyObject *)tl);
}

static PyMethodDef tl_methods[] = {
    {"initialise", (PyCFunction)(void (*)(void))tl_initialise, METH_FASTCALL, "initialise(t, x)"},
    {"count", (PyCFunction)tl_count, METH_O, "count(counter)"},
    {"add_imu", (PyCFunction)(void (*)(void))tl_add_imu, METH_FASTCALL, "add_imu(t, f, w)"},
    {"add_mocap", (PyCFunction)(void (*)(void))tl_add_mocap, METH_FASTCALL, "add_mocap(t, position, attitude) -> bool"},
    {"add_imu_sample", (PyCFunction)tl_add_imu_sample, METH_O, "add_imu_sample(sample) -> TAKEN, INVALID, NOT_STARTED"},
    {"add_mocap_pose", (PyCFunction)tl_add_mocap_pose, METH_O, "add_mocap_pose(pose) -> bool, None: not started"},
    {"queue_mocap", (PyCFunction)(void (*)(void))tl_queue_mocap, METH_FASTCALL, "queue_mocap(t, position, attitude)"},
    {"newest", (PyCFunction)tl_newest, METH_O, "newest(P_out) -> (t, x, w)"},
    {"newest_state", (PyCFunction)(void (*)(void))tl_newest_state, METH_FASTCALL,
     "newest_state(P_out, values_out, std_out) -> (t, last accepted, rejections in a row, counters)"},
    {"predict", (PyCFunction)(void (*)(void))tl_predict, METH_FASTCALL, "predict(t, P_out) -> (x, w) or None"},
    {"health_values", (PyCFunction)tl_health_values, METH_NOARGS, "health_values() -> (newest, last accepted, "
                                                                  "rejections in a row, counters)"},
    {NULL, NULL, 0, NULL},
};

static PyGetSetDef tl_getset[] = {
    {"empty", (getter)tl_get_empty, NULL, "no node yet", NULL},
    {"started", (getter)tl_get_started, NULL, "initialised and the first IMU sample taken", NULL},
    {NULL, NULL, NULL, NULL, NULL},
};

static PyTypeObject TimelineType = {
    PyVarObject_HEAD_INIT(NULL, 0)
    .tp_name = "estimator._eskf_kernels.Timeline",
    .tp_basicsize = sizeof(TimelineObject),
    .tp_flags = Py_TPFLAGS_DEFAULT,
    .tp_doc = "Compiled twin of estimator.eskf_timeline.Timeline (the same methods, the same bits).",
    .tp_new = PyType_GenericNew,
    .tp_init = (initproc)tl_init,
    .tp_dealloc = (destructor)tl_dealloc,
    .tp_methods = tl_methods,
    .tp_getset = tl_getset,
};

/* add Timeline to the module; -1 with the error set */
static int add_timeline_type(PyObject *module) {
    PyObject *linalg = PyImport_ImportModule("numpy.linalg");
    if (linalg == NULL) return -1;
    lin_alg_error = PyObject_GetAttrString(linalg, "LinAlgError");
    Py_DECREF(linalg);
    name_time_s = PyUnicode_InternFromString("time_s");
    name_force = PyUnicode_InternFromString("specific_force_flu_mps2");
    name_rate = PyUnicode_InternFromString("rate_flu_radps");
    name_position = PyUnicode_InternFromString("position_enu_m");
    name_attitude = PyUnicode_InternFromString("attitude_wxyz");
    if (lin_alg_error == NULL || name_time_s == NULL || name_force == NULL || name_rate == NULL
        || name_position == NULL || name_attitude == NULL || PyType_Ready(&TimelineType) < 0)
        return -1;
    Py_INCREF(&TimelineType);
    if (PyModule_AddObject(module, "Timeline", (PyObject *)&TimelineType) < 0) {
        Py_DECREF(&TimelineType);
        return -1;
    }
    return 0;
}
