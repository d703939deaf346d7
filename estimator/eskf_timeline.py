"""The ESKF's timeline: every sample on a buffer sorted by sample time, the filter state after each, the
rollback and replay a late sample needs (estimator.eskf's module docstring, "Time bookkeeping" on, has the
equations and the rules). In Python here; estimator/_eskf_timeline.h (built into estimator._eskf_kernels) is
its compiled twin.

Takes in: a TimelineConfig (the filter's numbers: gravity, IMU period, sub-step and buffer lengths, gate,
re-initialisation rules, R's diagonal, the initial covariance's diagonal, the process noise densities), and
samples: link.messages.ImuSample and MocapPose as they arrive (add_imu_sample, add_mocap_pose: checked here,
an invalid one counted and dropped), or already checked as plain floats (time s on the vehicle clock;
specific force FLU m/s^2 and rate FLU rad/s; position ENU m and unit attitude wxyz with w >= 0).
Gives out: the newest node's time, nominal state (16 floats: p ENU m, v ENU m/s, q wxyz, b_a FLU m/s^2,
b_g FLU rad/s) and IMU rate, its covariance written into a caller's (15, 15) float64 array; the same one
step ahead (predict); whether a frame was accepted; the counters of COUNTERS. newest_state gives what an
estimate needs in one call, into the caller's arrays: the covariance, the state with the bias-corrected rate
(N_VALUES floats) and the standard deviations, with the health values.

Why a class of its own with a compiled twin (issue 19): in attitude mode the ground station adds five IMU
samples and a mocap frame per tick on the lockstep's critical path, and with the kernels compiled this
bookkeeping was most of the estimator's time: 57.4 us of CPU per 100 Hz tick here, 19.9 us with the compiled
twin (`benchmarks/estimator_bench.py --seconds 4 --repeats 3`, frames in order, one run). The twins give the
same bits (tests/estimator/test_eskf_timeline.py checks them over whole filtered flights, faults included).
"""

from __future__ import annotations

import bisect
import math
from dataclasses import dataclass

import numpy as np

from estimator.eskf_kernels import (
    TRANSITION_ENTRIES,
    multiply,
    predict_covariance,
    propagate,
    reset_covariance,
    update_covariance,
)
from link.messages import ImuSample, MocapPose
from model.frames import attitude_error, quat_exp, quat_multiply, quat_normalize_positive_w

N_ERROR = 15
N_STATE = 16
N_VALUES = N_STATE + 3  # an estimate's numbers in one array: the nominal state, then the bias-corrected rate
MOCAP_STATES = (0, 1, 2, 6, 7, 8)  # the error states a mocap frame measures (position, attitude): H
# The timeline's counters, in this order in both twins (EstimatorHealth's fields of the same names).
COUNTERS = ("accepted_mocap", "rejected_outliers", "reinitialisations", "duplicate_mocap", "stale_mocap",
            "invalid_mocap", "imu_gaps", "lost_imu", "reordered_imu", "stale_imu", "duplicate_imu", "invalid_imu")
(ACCEPTED_MOCAP, REJECTED_OUTLIERS, REINITIALISATIONS, DUPLICATE_MOCAP, STALE_MOCAP, INVALID_MOCAP, IMU_GAPS,
 LOST_IMU, REORDERED_IMU, STALE_IMU, DUPLICATE_IMU, INVALID_IMU) = range(len(COUNTERS))
# What add_imu_sample did with a sample (the compiled twin returns the same numbers).
TAKEN, INVALID, NOT_STARTED = range(3)


def fill_state(x: tuple, w: tuple | None, P: np.ndarray, values_out: np.ndarray, std_out: np.ndarray) -> None:
    """values_out (N_VALUES) <- the nominal state x, then the rate w - b_g (-b_g before the first IMU sample,
    w None); std_out (N_ERROR) <- the square roots of P's diagonal. The compiled twin's newest_state does the
    same operations (one IEEE subtraction per rate component, a correctly rounded square root)."""
    bgx, bgy, bgz = x[13], x[14], x[15]
    values_out[:N_STATE] = x
    values_out[N_STATE:] = (w[0] - bgx, w[1] - bgy, w[2] - bgz) if w is not None else (-bgx, -bgy, -bgz)
    np.sqrt(P.diagonal(), out=std_out)


def _flat(cells) -> np.ndarray:
    return np.array([r * N_ERROR + c for r, c in cells], dtype=np.int64)


# Flat indices of the entries of F other than its unit diagonal, in eskf_kernels.transition_values' order:
# dp <- dv, the 6x6 block of rows dp, dv by columns dtheta, db_a, dtheta <- dtheta off the diagonal,
# dtheta <- db_g. The compiled twin is given this same array.
F_INDEX = _flat([(i, 3 + i) for i in range(3)] + [(r, c) for r in range(6) for c in range(6, 12)]
                + [(6, 7), (6, 8), (7, 6), (7, 8), (8, 6), (8, 7)] + [(6 + i, 12 + i) for i in range(3)])
assert len(F_INDEX) == TRANSITION_ENTRIES
# Q's non-zero entries in _process_noise's order: pp, pv and vp (per axis), then the diagonal from vv on.
_Q_INDEX = _flat([(i, i) for i in range(3)] + [(i, 3 + i) for i in range(3)] + [(3 + i, i) for i in range(3)]
                 + [(i, i) for i in range(3, N_ERROR)])
_IDENTITY_ERROR = np.eye(N_ERROR)
# Interval lengths whose Q is kept: IMU intervals take a handful of values, mocap frames split them at
# arbitrary times, so the cache is cleared when full.
_Q_CACHE_SIZE = 64

_IMU, _MOCAP = 0, 1
_NEW, _ACCEPTED, _REJECTED, _REINIT, _INIT = range(5)
# Trim the buffer in chunks: deleting the head of a list costs the same for 1 or 16 nodes.
TRIM_CHUNK = 16


@dataclass(frozen=True)
class TimelineConfig:
    """The numbers a timeline works with (estimator.eskf.ErrorStateKF derives them from its parameters)."""

    gravity_mps2: float
    imu_period_s: float  # the IMU's nominal period: what counts as a gap
    max_step_s: float  # longest single integration step (imu.max_step_s)
    buffer_length_s: float
    gap_factor: float  # an interval longer than this many periods is a gap
    gate_d2: float  # the chi-square gate on the squared Mahalanobis distance
    reinit_after_blackout_s: float
    reinit_after_rejections: int
    r_diag: tuple  # R's diagonal: 3 position variances (m^2), 3 attitude variances (rad^2)
    p0_diag: tuple  # the initial covariance's diagonal (15, error-state order)
    reinit_velocity_var: float  # (m/s)^2, the velocity variance after a re-initialisation
    accel_psd: float  # continuous noise densities squared, times the process-noise scale
    gyro_psd: float
    accel_bias_psd: float
    gyro_bias_psd: float


class _Node:
    """One sample on the timeline and the filter state just after it."""

    __slots__ = ("time_s", "kind", "f", "w", "position", "attitude", "status", "x", "P", "start_s",
                 "transition")

    def __init__(self, time_s: float, kind: int, f=None, w=None, position=None, attitude=None,
                 status: int = _NEW):
        self.time_s = time_s
        self.kind = kind
        self.f = f  # specific force FLU at time_s (interpolated for mocap nodes)
        self.w = w  # angular rate FLU at time_s
        self.position = position  # mocap only
        self.attitude = attitude  # mocap only
        self.status = status  # mocap only: _NEW until gated
        self.x = None  # nominal state, 16 floats: p, v, q(wxyz), b_a, b_g
        self.P = None  # (15, 15) error covariance
        self.start_s = None  # time of the node before, when `transition` was computed
        self.transition = None  # (F, Q) from the node before to this one


class Timeline:
    """The Python twin. It checks the samples given as messages (add_imu_sample, add_mocap_pose); its caller
    (ErrorStateKF) holds the poses seen before the first IMU sample."""

    def __init__(self, config: TimelineConfig):
        self.c = config
        self._q_cache: dict[float, np.ndarray] = {}
        self._posterior: tuple[np.ndarray, np.ndarray] | None = None  # (dx, P) of the last _innovate
        self._reset_bookkeeping()

    # ------------------------------------------------------------------ what ErrorStateKF calls

    @property
    def empty(self) -> bool:
        """No node yet (never initialised)."""
        return not self._nodes

    @property
    def started(self) -> bool:
        """Initialised and the first IMU sample taken (the base node has its IMU signal)."""
        return bool(self._nodes) and self._nodes[0].f is not None

    def initialise(self, t: float, x: tuple) -> None:
        """Restart at time t with nominal state x (16 floats) and the initial covariance; counters to 0."""
        self._reset_bookkeeping()
        node = _Node(t, _MOCAP, status=_INIT)
        node.x = x
        node.P = np.diag(self.c.p0_diag)
        self._nodes = [node]
        self._times = [t]
        self._last_accepted_s = t

    def count(self, counter: int) -> None:
        """Add one to COUNTERS[counter] (for what the caller drops before the timeline sees it)."""
        self._count[counter] += 1

    def add_imu_sample(self, sample: ImuSample) -> int:
        """Check and add an IMU sample: INVALID (counted) if a number is not finite or a vector not of 3,
        NOT_STARTED (nothing done) before the first sample has a pose to start from (the caller's to
        find), else TAKEN (added by add_imu)."""
        f, w = sample.specific_force_flu_mps2, sample.rate_flu_radps
        if len(f) != 3 or len(w) != 3 or not _finite((sample.time_s, *f, *w)):  # a non-number raises TypeError
            self._count[INVALID_IMU] += 1
            return INVALID
        t, f, w = float(sample.time_s), tuple(map(float, f)), tuple(map(float, w))
        if not self.started:
            return NOT_STARTED
        self.add_imu(t, f, w)
        return TAKEN

    def add_mocap_pose(self, pose: MocapPose) -> bool | None:
        """Check and add a mocap frame: False if invalid (counted: see pose_valid), None (nothing done) when
        the timeline has not started, else add_mocap's answer."""
        if not pose_valid(pose):
            self._count[INVALID_MOCAP] += 1
            return False
        if not self.started:
            return None
        return self.add_mocap(float(pose.time_s), *pose_values(pose))

    def add_imu(self, t: float, f: tuple, w: tuple) -> None:
        """A sample (started timelines only): appended, or inserted and replayed when late, or dropped."""
        node = _Node(t, _IMU, f, w)
        if t > self._times[-1]:
            self._append_imu(node)
        else:
            self._insert_imu(node)
        self._trim()

    def add_mocap(self, t: float, position: tuple, attitude: tuple) -> bool:
        """A frame (started timelines only); True if accepted or used to re-initialise, or held for later
        (newer than the newest IMU sample)."""
        if t < self._times[0]:
            self._count[STALE_MOCAP] += 1
            return False
        if self._holds_mocap_at(t):
            self._count[DUPLICATE_MOCAP] += 1
            return False
        if t > self._times[-1]:
            self.queue_mocap(t, position, attitude)
            return True  # queued: decided when the IMU stream reaches its sample time
        node = _Node(t, _MOCAP, position=position, attitude=attitude)
        i = bisect.bisect_right(self._times, t)
        self._nodes.insert(i, node)
        self._times.insert(i, t)
        self._replay_from(i)
        return node.status in (_ACCEPTED, _REINIT)

    def queue_mocap(self, t: float, position: tuple, attitude: tuple) -> None:
        """Hold a frame newer than the newest IMU sample until the IMU stream reaches its time.

        It is gated then, against the state propagated on the real IMU samples up to its sample time:
        when the downlink's latency exceeds the mocap's (a radio of 20+ ms against a 5 ms Vicon), a
        gate decided now on a held-IMU prediction over that gap rejects good frames during manoeuvres.
        """
        node = _Node(t, _MOCAP, position=position, attitude=attitude)
        bisect.insort(self._pending, node, key=lambda m: m.time_s)

    def newest(self, P_out: np.ndarray) -> tuple[float, tuple, tuple | None]:
        """(time, nominal state, IMU rate or None before the first sample) of the newest node; its
        covariance into P_out."""
        last = len(self._nodes) - 1
        node = self._nodes[last]
        P_out[...] = self._covariance_at(last)
        return node.time_s, node.x, node.w

    def newest_state(self, P_out: np.ndarray, values_out: np.ndarray,
                     std_out: np.ndarray) -> tuple[float, float, int, dict]:
        """What an estimate of the newest node needs, in one call: its covariance into P_out, fill_state's
        values and standard deviations into values_out and std_out; returns (its time, then health_values'
        last three: newest accepted frame's time, rejections in a row, the counters by name)."""
        t, x, w = self.newest(P_out)
        fill_state(x, w, P_out, values_out, std_out)
        _, last_accepted_s, in_a_row, counts = self.health_values()
        return t, last_accepted_s, in_a_row, counts

    def predict(self, t: float, P_out: np.ndarray) -> tuple[tuple, tuple] | None:
        """(state, IMU rate) one step from the newest node to t holding its IMU signal, the covariance
        into P_out; None when there is no signal yet or t is not after the newest node."""
        last = len(self._nodes) - 1
        node = self._nodes[last]
        dt = t - node.time_s
        if node.f is None or not dt > 0.0:
            return None
        x, transition = self._step(node.x, node.f, node.w, node.f, node.w, dt)
        P_out[...] = self._predict(self._covariance_at(last), transition)
        return x, node.w

    def health_values(self) -> tuple[float | None, float, int, dict]:
        """(newest node's time or None when empty, newest accepted frame's time, rejections in a row, a new
        dict of COUNTERS' values by name)."""
        newest_s = self._times[-1] if self._times else None
        counts = dict(zip(COUNTERS, self._count, strict=True))
        return newest_s, self._last_accepted_s, self._consecutive_rejections, counts

    # ------------------------------------------------------------------ timeline bookkeeping

    def _reset_bookkeeping(self) -> None:
        self._nodes: list[_Node] = []
        self._times: list[float] = []
        self._pending: list[_Node] = []  # mocap frames newer than the newest IMU sample, not yet gated
        self._last_accepted_s = -math.inf
        self._consecutive_rejections = 0
        self._last_trimmed_imu_s: float | None = None
        self._count = [0] * len(COUNTERS)

    def _append_imu(self, node: _Node) -> None:
        """The usual case: a sample newer than everything held. Releases queued future mocap frames."""
        base = self._nodes[0]
        if base.f is None:  # the initial pose gets the first sample as its IMU signal
            base.f, base.w = node.f, node.w
        start = len(self._nodes)
        t = node.time_s
        if not self._pending or self._pending[0].time_s > t:  # nothing released (sorted by time)
            self._advance(node, self._nodes[-1], None)
            self._nodes.append(node)
            self._times.append(t)
            return
        released = [m for m in self._pending if m.time_s <= t]
        self._pending = [m for m in self._pending if m.time_s > t]
        for m in [m for m in released if m.time_s < t] + [node] + [m for m in released if m.time_s == t]:
            self._nodes.append(m)
            self._times.append(m.time_s)
        self._replay_from(start)

    def _insert_imu(self, node: _Node) -> None:
        """A sample older than the newest: insert it by time and replay, or drop it if too old / repeated."""
        t = node.time_s
        if t < self._times[0]:
            self._count[STALE_IMU] += 1
            return
        i = bisect.bisect_left(self._times, t)
        k = i
        while k < len(self._times) and self._times[k] == t:
            if self._nodes[k].kind == _IMU:
                self._count[DUPLICATE_IMU] += 1
                return
            k += 1
        if i == 0:  # same time as the base node (a pose): nothing before it to replay from
            self._count[STALE_IMU] += 1
            return
        self._nodes.insert(i, node)
        self._times.insert(i, t)
        self._count[REORDERED_IMU] += 1
        # Mocap nodes just before the new sample interpolated their IMU signal past it: redo them too.
        start = i
        while start > 1 and self._nodes[start - 1].kind == _MOCAP:
            start -= 1
            self._nodes[start].transition = None  # its signal changes: F and Q too
        self._replay_from(start)

    def _holds_mocap_at(self, t: float) -> bool:
        i = bisect.bisect_left(self._times, t)
        while i < len(self._times) and self._times[i] == t:
            if self._nodes[i].kind == _MOCAP:
                return True
            i += 1
        return any(m.time_s == t for m in self._pending)

    def _replay_from(self, i: int) -> None:
        """Recompute the state of nodes i..end from node i-1 (rollback + re-propagation).

        Covariance transitions stored by an earlier pass over an unchanged interval are reused: they were
        linearised at the nominal state before this replay's corrections, a second-order difference for
        gated corrections, but not after a re-initialisation, which may move the attitude far.
        IMU nodes get their nominal state and (F, Q) here; their P waits for _covariance_at.
        """
        nodes = self._nodes
        reuse = True
        for j in range(i, len(nodes)):
            node, prev = nodes[j], nodes[j - 1]
            stored = node.transition if reuse and node.start_s == prev.time_s else None
            if node.kind == _IMU:
                self._advance(node, prev, stored)
            elif not self._process_mocap(j, stored):
                reuse = False

    def _advance(self, node: _Node, prev: _Node, stored: tuple | None) -> None:
        """Nominal state and (F, Q) of `node` from `prev` (stored: an earlier pass's (F, Q) over the same
        interval, or None); its P is left pending (_covariance_at)."""
        node.x, node.transition = self._propagate(prev.x, prev.f, prev.w, node.f, node.w,
                                                  node.time_s - prev.time_s, stored)
        node.start_s = prev.time_s
        node.P = None

    def _process_mocap(self, j: int, stored: tuple | None) -> bool:
        """Propagate to mocap node j (as _advance), then gate / update / inject / re-initialise; False
        after a re-initialisation (later transitions must not be reused)."""
        node = self._nodes[j]
        node.f, node.w = self._signal_at(j)
        self._advance(node, self._nodes[j - 1], stored)
        x, P = node.x, self._covariance_at(j)
        if node.status == _NEW:
            node.status = self._decide(self._innovate(x, P, node), node.time_s)
            if node.status == _ACCEPTED:
                x, P = self._inject(x)
        elif node.status == _ACCEPTED:
            self._innovate(x, P, node)
            x, P = self._inject(x)
        if node.status == _REINIT:
            x, P = self._reinitialised(x, P, node)
        node.x, node.P = x, P
        return node.status != _REINIT

    def _covariance_at(self, j: int) -> np.ndarray:
        """P of node j, running the predict over the intervals whose P is still pending.

        Lazy on purpose: a replay after a late mocap frame changes every later node, and when nothing asks
        for their P in between (several samples per flight-loop tick) each interval is predicted once
        instead of once per pass. Same (F, Q), same order: the same bits as predicting eagerly.
        """
        nodes = self._nodes
        k = j
        while nodes[k].P is None:  # nodes[0].P is always set
            k -= 1
        P = nodes[k].P
        for m in range(k + 1, j + 1):
            node = nodes[m]
            if node.transition is not None:  # None: zero-length interval, P unchanged
                P = self._predict(P, node.transition)
            node.P = P
        return P

    @staticmethod
    def _predict(P: np.ndarray, transition: tuple[np.ndarray, np.ndarray]) -> np.ndarray:
        """The predict's covariance step over one stored (F, Q): P' = F P F' + Q, into a new array
        (estimator.eskf_kernels.predict_covariance)."""
        F, Q = transition
        out = np.empty((N_ERROR, N_ERROR))
        predict_covariance(P, F, Q, out)
        return out

    def _signal_at(self, j: int) -> tuple[tuple, tuple]:
        """IMU signal at a mocap node: linear between the node before and the next IMU sample."""
        prev = self._nodes[j - 1]
        for k in range(j + 1, len(self._nodes)):
            nxt = self._nodes[k]
            if nxt.kind == _IMU:
                span = nxt.time_s - prev.time_s
                s = (self._nodes[j].time_s - prev.time_s) / span if span > 0.0 else 0.0
                return _lerp(prev.f, nxt.f, s), _lerp(prev.w, nxt.w, s)
        return prev.f, prev.w

    def _trim(self) -> None:
        """Forget nodes older than the buffer, keeping one before the cut as the rollback base."""
        times = self._times
        cut_s = times[-1] - self.c.buffer_length_s
        if len(times) <= TRIM_CHUNK or times[TRIM_CHUNK] >= cut_s:
            return  # fewer than TRIM_CHUNK + 1 nodes before the cut (the bisect below would say k < chunk)
        k = bisect.bisect_left(times, cut_s) - 1
        self._covariance_at(k)  # the new base holds its P
        for node in self._nodes[:k]:
            if node.kind == _IMU:
                self._count_gap(node.time_s)
        del self._nodes[:k]
        del self._times[:k]

    def _count_gap(self, t: float) -> None:
        last, self._last_trimmed_imu_s = self._last_trimmed_imu_s, t
        period = self.c.imu_period_s
        if last is not None and t - last > self.c.gap_factor * period:
            self._count[IMU_GAPS] += 1
            self._count[LOST_IMU] += max(1, round((t - last) / period) - 1)

    # ------------------------------------------------------------------ mocap decisions

    def _decide(self, d2: float, t: float) -> int:
        """Accept, reject or re-initialise on a frame with squared Mahalanobis distance d2."""
        c = self.c
        if d2 <= c.gate_d2:
            status = _ACCEPTED
        elif (t - self._last_accepted_s > c.reinit_after_blackout_s
              or self._consecutive_rejections >= c.reinit_after_rejections):
            status = _REINIT
        else:
            self._count[REJECTED_OUTLIERS] += 1
            self._consecutive_rejections += 1
            return _REJECTED
        self._count[REINITIALISATIONS if status == _REINIT else ACCEPTED_MOCAP] += 1
        self._consecutive_rejections = 0
        self._last_accepted_s = max(self._last_accepted_s, t)
        return status

    def _innovate(self, x: tuple, P: np.ndarray, node: _Node) -> float:
        """The update with the mocap residual z (estimator.eskf_kernels.update_covariance); returns
        d^2 = z' S^-1 z (posterior kept for _inject)."""
        dtheta = attitude_error(x[6:10], node.attitude)
        px, py, pz = node.position
        z = (px - x[0], py - x[1], pz - x[2], *dtheta)
        P_post = np.empty((N_ERROR, N_ERROR))
        dx = np.empty(N_ERROR)
        d2 = update_covariance(P, z, self.c.r_diag, MOCAP_STATES, P_post, dx)
        if math.isnan(d2):
            raise np.linalg.LinAlgError("mocap update: innovation covariance H P H' + R not positive definite")
        self._posterior = dx, P_post
        return d2

    def _inject(self, x: tuple) -> tuple[tuple, np.ndarray]:
        """Fold the update's posterior dx into the nominal state and reset the error (Sola sec. 6.2-6.3)."""
        dx_array, P_post = self._posterior
        dx = dx_array.tolist()
        q = quat_normalize_positive_w(quat_multiply(x[6:10], quat_exp(dx[6], dx[7], dx[8])))
        x_new = (x[0] + dx[0], x[1] + dx[1], x[2] + dx[2], x[3] + dx[3], x[4] + dx[4], x[5] + dx[5], *q,
                 x[10] + dx[9], x[11] + dx[10], x[12] + dx[11], x[13] + dx[12], x[14] + dx[13], x[15] + dx[14])
        P = np.empty((N_ERROR, N_ERROR))
        reset_covariance(P_post, (dx[6], dx[7], dx[8]), P)  # G P G', G_theta = I - [dtheta/2]x
        return x_new, P

    def _reinitialised(self, x: tuple, P: np.ndarray, node: _Node) -> tuple[tuple, np.ndarray]:
        x_new = (*node.position, *x[3:6], *node.attitude, *x[10:16])
        P_new = np.diag(self.c.p0_diag)
        P_new[3:6, 3:6] = np.eye(3) * self.c.reinit_velocity_var
        P_new[9:15, 9:15] = P[9:15, 9:15]
        return x_new, P_new

    # ------------------------------------------------------------------ propagation

    def _propagate(self, x: tuple, f0, w0, f1, w1, dt: float,
                   transition: tuple | None = None) -> tuple[tuple, tuple | None]:
        """Nominal state after dt with signals (f0, w0) at the start and (f1, w1) at the end, and (F, Q).

        Intervals longer than max_step_s are integrated in equal sub-steps (signals interpolated); their
        F and Q are chained into one F = F_n..F_1, Q = F_n(..)F_n' + Q_n for a single predict.
        Given `transition` (F, Q) - stored from an earlier pass over this same interval - only the nominal
        state is recomputed. Returns (x, (F, Q)), (x, None) for dt <= 0 (P unchanged).
        """
        if dt <= 0.0:
            return x, transition
        g = self.c.gravity_mps2
        n = math.ceil(dt / self.c.max_step_s - 1e-9)  # slack: 2.0000000001 steps are 2
        if n <= 1:
            if transition is not None:
                return propagate(x, f0, w0, f1, w1, dt, g, None, None), transition
            return self._step(x, f0, w0, f1, w1, dt)
        h = dt / n
        fa, wa = f0, w0
        F_total = Q_total = None
        for k in range(1, n + 1):
            fb, wb = _lerp(f0, f1, k / n), _lerp(w0, w1, k / n)
            if transition is not None:
                x = propagate(x, fa, wa, fb, wb, h, g, None, None)
            else:
                x, (F, Q) = self._step(x, fa, wa, fb, wb, h)
                if F_total is None:
                    F_total, Q_total = F, Q
                else:
                    Q_total = self._predict(Q_total, (F, Q))  # F Q_total F' + Q
                    multiply(F, F_total, F_total)  # F_total = F F_total, in place: it is this call's own
            fa, wa = fb, wb
        return x, transition if transition is not None else (F_total, Q_total)

    def _step(self, x: tuple, f0, w0, f1, w1, dt: float) -> tuple[tuple, tuple[np.ndarray, np.ndarray]]:
        """One trapezoidal nominal step (estimator.eskf's docstring; estimator.eskf_kernels.propagate) and
        its (F, Q): F a new array, the identity with its 48 other entries written by the kernel; Q shared,
        read only (_process_noise)."""
        F = _IDENTITY_ERROR.copy()
        x1 = propagate(x, f0, w0, f1, w1, dt, self.c.gravity_mps2, F, F_INDEX)
        return x1, (F, self._process_noise(dt))

    def _process_noise(self, dt: float) -> np.ndarray:
        """Q over dt (estimator.eskf's docstring), read-only, cached by dt: IMU intervals take a few lengths."""
        Q = self._q_cache.get(dt)
        if Q is not None:
            return Q
        if len(self._q_cache) >= _Q_CACHE_SIZE:
            self._q_cache.clear()  # mocap frames split intervals at arbitrary times
        c = self.c
        qv = c.accel_psd * dt
        qp, qpv = qv * dt * dt / 3.0, qv * dt * 0.5
        qt, qba, qbg = c.gyro_psd * dt, c.accel_bias_psd * dt, c.gyro_bias_psd * dt
        Q = np.zeros((N_ERROR, N_ERROR))
        Q.put(_Q_INDEX, (qp, qp, qp, qpv, qpv, qpv, qpv, qpv, qpv, qv, qv, qv, qt, qt, qt,
                         qba, qba, qba, qbg, qbg, qbg))
        Q.flags.writeable = False  # shared by every interval of this length
        self._q_cache[dt] = Q
        return Q


def _finite(values) -> bool:
    """All finite; math.isfinite reads each as a C double does (PyFloat_AsDouble): as the compiled twin."""
    return all(map(math.isfinite, values))


def pose_valid(pose: MocapPose) -> bool:
    """A position of 3 and an attitude of 4 finite numbers, the attitude not all zero."""
    return (len(pose.position_enu_m) == 3 and len(pose.attitude_wxyz) == 4
            and _finite((pose.time_s, *pose.position_enu_m, *pose.attitude_wxyz)) and any(pose.attitude_wxyz))


def pose_values(pose: MocapPose) -> tuple[tuple, tuple]:
    """A valid pose's position and attitude as floats, the attitude normalised with w >= 0."""
    return (tuple(map(float, pose.position_enu_m)),
            quat_normalize_positive_w(tuple(map(float, pose.attitude_wxyz))))


def _lerp(a: tuple, b: tuple, s: float) -> tuple:
    return (a[0] + s * (b[0] - a[0]), a[1] + s * (b[1] - a[1]), a[2] + s * (b[2] - a[2]))
