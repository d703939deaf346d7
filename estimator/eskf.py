"""Error-state (multiplicative) Kalman filter fusing a ~500 Hz IMU with ~100 Hz motion capture.

Takes in: link.messages.ImuSample (sample time on the vehicle clock; specific force FLU m/s^2, reading
+g on z at rest; angular rate FLU rad/s) and link.messages.MocapPose (SAMPLE time; position ENU m;
attitude wxyz body FLU -> world ENU), in any arrival order. What it assumes of its sensors from
estimator.sensor_spec.SensorSpec (their data sheets, not the simulator's settings); the IMU's nominal rate;
tuning from estimator/params/eskf.toml (`EskfParams`).
Gives out: `Estimate` (position ENU m, velocity ENU m/s, attitude wxyz, bias-corrected body rate FLU
rad/s, accelerometer and gyro biases, 15x15 error covariance and its standard deviations, health).

State. Nominal x = (p, v, q, b_a, b_g); error dx = (dp, dv, dtheta, db_a, db_g) (15 states, this order,
see ERROR_STATE_LABELS) with the local attitude error q_true = q (x) Exp(dtheta) (body frame).
Nominal propagation over an IMU interval [t0, t1], dt = t1 - t0, trapezoidal in the two samples:
    w = (w0 + w1)/2 - b_g,                  q1 = q0 (x) Exp(w dt)
    a_k = R(q_k) (f_k - b_a) - g e3,       a = (a_0 + a_1)/2       (g = model.vehicle.GRAVITY_MPS2)
    p1 = p0 + v0 dt + a dt^2/2,             v1 = v0 + a dt,         biases constant.
Error transition, first order (Sola 2017 eq. 269), f = (f0 + f1)/2 - b_a, R = R(q0):
    F = I + dt A + dt^2/2 (dp rows):  dp <- dv: I;  dv <- dtheta: -R[f]x;  dv <- db_a: -R;
    dtheta <- dtheta: -[w]x;  dtheta <- db_g: -I;  and dp <- dtheta, db_a: -R[f]x dt^2/2, -R dt^2/2.
Process noise from the continuous densities (s_a, s_g, s_ba, s_bg) of the sensor spec, per axis:
    Q_pp = s_a^2 dt^3/3, Q_pv = s_a^2 dt^2/2, Q_vv = s_a^2 dt, Q_tt = s_g^2 dt, Q_ba = s_ba^2 dt,
    Q_bg = s_bg^2 dt (times noise.process_noise_variance_scale).
Mocap measurement: z = [p_m - p ; Log(q^* (x) q_m)] = H dx + n, H = [I 0 0 0 0; 0 0 I 0 0],
    R = diag(s_p^2 I3, s_theta^2 I3) of the sensor spec (times noise.mocap_noise_variance_scale).

The Kalman steps are filterpy's (filterpy.kalman.KalmanFilter, dim_x = 15, dim_z = 6, x = the error state):
predict P = F P F' + Q; update y = z - H x (x = 0: y = z), S = H P H' + R, K = P H' S^-1, x = x + K y and the
Joseph form P = (I - K H) P (I - K H)' + K R K'. They run in estimator.eskf_kernels' fixed-order kernels
(compiled when built, else their Python twins: the same bits), not numpy's matrix products: those go to
BLAS, which picks its kernel by CPU at run time and with it the order and fusing of every sum, so the
filter's last bits - and a lockstep flight's log - depended on the machine (issue 19 documents the change;
tests/estimator/test_eskf_kernels.py checks the kernels against filterpy to rounding and a filtered flight
under three OpenBLAS kernels bit for bit). Every covariance the kernels give is exactly symmetric (computed
on and above the diagonal, copied below); S^-1 comes from S's Cholesky factor L (S is positive definite;
the gate's d^2 = |L^-1 y|^2 is never negative).
What this module does around them: the nominal propagation above and F (the identity, its 48 other entries
written by estimator.eskf_kernels.propagate), Q (depends on dt alone: cached per interval length), forming
z from the nominal state, the Mahalanobis gate d^2 = y' S^-1 y (a rejected frame keeps the prior P: the
update is discarded), injecting dx into the nominal state (q <- q (x) Exp(dtheta)), the ESKF reset
P <- G P G' with G_theta = I - [dtheta/2]x (Sola eq. 287), the error state back to 0, and the time
bookkeeping below.

Time bookkeeping (latency compensation). Every sample is a node on a timeline sorted by sample time,
holding the nominal state and P just after it; the last `buffer.length_s` seconds are kept. A mocap
frame is inserted at its SAMPLE time: the filter rolls back to the node before it, propagates to the
frame's time (the IMU signal there interpolated between the neighbouring samples), updates, and
re-propagates through the buffered IMU samples, re-applying later mocap frames, to the newest sample.
Late, reordered and out-of-order frames of either kind take that same path; during a replay earlier
decisions (accept / reject / re-initialise) are kept, not re-gated, and the (F, Q) of intervals that did
not change are reused (linearised before the replay's corrections: a second-order difference, below
1e-3 of the estimate's own sigma in the tests): a replayed IMU sample costs its nominal step and one
predict, not a new F.
Covariances are propagated lazily: an IMU node gets its nominal state and (F, Q) when processed, its
P = F P_before F' + Q (the predict) only when something needs it - a mocap frame after it,
estimate(), predict_to(), or its becoming the buffer's base - so when several samples and a late frame
arrive between two estimate() calls (attitude mode: 5 IMU samples and 1 frame per tick) each interval is
predicted once, not once per replay. Same (F, Q) in the same order: bit for bit the eager result.
Frames older than the buffer are dropped and counted; a frame with the same sample time as one already
held is a duplicate and ignored.
A mocap frame from the future (sample time after the newest IMU sample) is held, then gated and applied
when the IMU stream reaches its sample time. Lost IMU frames: the interval is integrated between
the samples either side of the gap (signal interpolated linearly, sub-steps of at most imu.max_step_s),
and Q grows with its length; gaps are counted when their nodes leave the buffer, i.e. once final.
predict_to(t) makes one step from the newest sample holding it (nominal step and predict into new
values), so the filter itself is untouched. estimate() is cached until the next input.

Outliers and re-initialisation. A frame with d^2 > chi2.ppf(gating.chi2_probability, 6) is rejected and
counted. A frame failing the gate instead re-initialises the filter - position and attitude := the
frame, velocity and biases kept, P reset to the initial one with velocity sigma
initial.reinit_velocity_sigma_mps and the bias blocks kept - when no frame was accepted for
gating.reinit_after_blackout_s, or after gating.reinit_after_rejections rejections in a row: by then the
estimate, not the frame, is the likelier to be wrong. (Re-initialising on an outlier is undone the same
way by the following good frames.)
"""

from __future__ import annotations

import bisect
import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from scipy.special import gammaincinv

from estimator.eskf_kernels import (
    TRANSITION_ENTRIES,
    multiply,
    predict_covariance,
    propagate,
    reset_covariance,
    update_covariance,
)
from estimator.sensor_spec import SensorSpec
from link.messages import ImuSample, MocapPose
from model.config import Params, resolve
from model.errors import UserError
from model.frames import (
    attitude_error,
    quat_exp,
    quat_multiply,
    quat_normalize_positive_w,
)
from model.vehicle import GRAVITY_MPS2

ERROR_STATE_LABELS = (
    "position_e_m", "position_n_m", "position_u_m",
    "velocity_e_mps", "velocity_n_mps", "velocity_u_mps",
    "attitude_x_rad", "attitude_y_rad", "attitude_z_rad",
    "accel_bias_x_mps2", "accel_bias_y_mps2", "accel_bias_z_mps2",
    "gyro_bias_x_radps", "gyro_bias_y_radps", "gyro_bias_z_radps",
)
POSITION, VELOCITY, ATTITUDE, ACCEL_BIAS, GYRO_BIAS = (slice(i, i + 3) for i in range(0, 15, 3))
N_ERROR = 15
N_MOCAP = 6
_IDENTITY_ERROR = np.eye(N_ERROR)
MOCAP_STATES = (*range(N_ERROR)[POSITION], *range(N_ERROR)[ATTITUDE])  # the states a mocap frame measures: H


def _flat(cells) -> np.ndarray:
    return np.array([r * N_ERROR + c for r, c in cells], dtype=np.int64)


# Flat indices of the entries of F other than its unit diagonal, in eskf_kernels.transition_values' order:
# dp <- dv, the 6x6 block of rows dp, dv by columns dtheta, db_a, dtheta <- dtheta off the diagonal,
# dtheta <- db_g.
_F_INDEX = _flat([(i, 3 + i) for i in range(3)] + [(r, c) for r in range(6) for c in range(6, 12)]
                 + [(6, 7), (6, 8), (7, 6), (7, 8), (8, 6), (8, 7)] + [(6 + i, 12 + i) for i in range(3)])
assert len(_F_INDEX) == TRANSITION_ENTRIES
# Q's non-zero entries in _process_noise's order: pp, pv and vp (per axis), then the diagonal from vv on.
_Q_INDEX = _flat([(i, i) for i in range(3)] + [(i, 3 + i) for i in range(3)] + [(3 + i, i) for i in range(3)]
                 + [(i, i) for i in range(3, N_ERROR)])
# Interval lengths whose Q is kept: IMU intervals take a handful of values, mocap frames split them at
# arbitrary times, so the cache is cleared when full.
_Q_CACHE_SIZE = 64

_IMU, _MOCAP = 0, 1
_NEW, _ACCEPTED, _REJECTED, _REINIT, _INIT = range(5)
# Trim the buffer in chunks: deleting the head of a list costs the same for 1 or 16 nodes.
_TRIM_CHUNK = 16


@dataclass(frozen=True)
class EskfParams:
    """The filter's own tuning (estimator/params/eskf.toml); sensor noise comes from the SensorSpec."""

    process_noise_variance_scale: float
    mocap_noise_variance_scale: float
    initial_velocity_sigma_mps: float
    reinit_velocity_sigma_mps: float
    gate_chi2_probability: float
    reinit_after_blackout_s: float
    reinit_after_rejections: int
    blackout_s: float
    max_position_sigma_m: float
    buffer_length_s: float
    imu_gap_factor: float
    imu_max_step_s: float
    source: str = "<memory>"


def load_eskf_params(name_or_path: str | Path = "eskf") -> EskfParams:
    """Read filter tuning from a TOML file (built-in name: eskf); one-line ConfigError on a bad field."""
    p = Params.load(resolve(name_or_path, "estimator", "params", "estimator parameters"))
    noise, initial, gating = p.table("noise"), p.table("initial"), p.table("gating")
    health, buffer, imu = p.table("health"), p.table("buffer"), p.table("imu")
    return EskfParams(
        process_noise_variance_scale=noise.number("process_noise_variance_scale", minimum=1e-6),
        mocap_noise_variance_scale=noise.number("mocap_noise_variance_scale", minimum=1e-6),
        initial_velocity_sigma_mps=initial.number("velocity_sigma_mps", minimum=1e-6),
        reinit_velocity_sigma_mps=initial.number("reinit_velocity_sigma_mps", minimum=1e-6),
        gate_chi2_probability=gating.number("chi2_probability", minimum=0.5, maximum=1.0 - 1e-15),
        reinit_after_blackout_s=gating.number("reinit_after_blackout_s", minimum=0.0),
        reinit_after_rejections=gating.integer("reinit_after_rejections", minimum=1),
        blackout_s=health.number("blackout_s", minimum=0.0),
        max_position_sigma_m=health.number("max_position_sigma_m", minimum=0.0),
        buffer_length_s=buffer.number("length_s", minimum=0.0),
        imu_gap_factor=imu.number("gap_factor", minimum=1.0),
        imu_max_step_s=imu.number("max_step_s", minimum=1e-5),
        source=p.source,
    )


@dataclass(frozen=True)
class EstimatorHealth:
    """Counters and flags of the filter; counts are since initialise()."""

    initialised: bool
    mocap_age_s: float  # newest sample time minus the newest accepted mocap sample time
    blackout: bool  # mocap_age_s > health.blackout_s
    accepted_mocap: int
    rejected_outliers: int  # failed the chi-square gate
    consecutive_rejections: int
    reinitialisations: int  # in-flight re-initialisations (not counting the first pose)
    duplicate_mocap: int
    stale_mocap: int  # older than the buffer: dropped
    invalid_mocap: int  # non-finite numbers or a zero quaternion: dropped
    imu_gaps: int  # intervals longer than imu.gap_factor periods, counted once out of the buffer
    lost_imu: int  # frames missing in those gaps
    reordered_imu: int  # arrived after a newer one, inserted in the buffer
    stale_imu: int  # arrived older than the buffer: dropped
    duplicate_imu: int
    invalid_imu: int


@dataclass(frozen=True)
class Estimate:
    """The filter's state at `time_s` (vehicle clock). Arrays are copies the caller may keep (the vectors are
    views of one array per Estimate); estimate() returns the same Estimate until the filter gets new input."""

    time_s: float
    position_enu_m: np.ndarray  # (3,)
    velocity_enu_mps: np.ndarray  # (3,)
    attitude_wxyz: np.ndarray  # (4,) body FLU -> world ENU
    rate_flu_radps: np.ndarray  # (3,) newest gyro sample minus the gyro bias
    accel_bias_flu_mps2: np.ndarray  # (3,)
    gyro_bias_flu_radps: np.ndarray  # (3,)
    covariance: np.ndarray  # (15, 15) of the error state, order ERROR_STATE_LABELS
    std_dev: np.ndarray  # (15,) sqrt of the covariance diagonal
    healthy: bool  # initialised, no mocap blackout, position sigma within health.max_position_sigma_m
    health: EstimatorHealth


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


def _finite(values) -> bool:
    return all(map(math.isfinite, values))


def _pose_valid(pose: MocapPose) -> bool:
    values = (pose.time_s, *pose.position_enu_m, *pose.attitude_wxyz)
    return len(values) == 8 and _finite(values) and any(pose.attitude_wxyz)


class ErrorStateKF:
    """The estimator. Feed add_imu / add_mocap in arrival order; read estimate() / predict_to()."""

    def __init__(self, sensors: SensorSpec, imu_rate_hz: float, params: EskfParams | None = None):
        self.params = params if params is not None else load_eskf_params()
        self.sensors = sensors
        prm = self.params
        self._g = GRAVITY_MPS2
        self._imu_period_s = 1.0 / imu_rate_hz
        scale = prm.process_noise_variance_scale
        self._accel_psd = scale * sensors.accel_noise_density**2
        self._gyro_psd = scale * sensors.gyro_noise_density**2
        self._accel_bias_psd = scale * sensors.accel_bias_random_walk**2
        self._gyro_bias_psd = scale * sensors.gyro_bias_random_walk**2
        var_p = prm.mocap_noise_variance_scale * sensors.mocap_position_sigma_m**2
        var_t = prm.mocap_noise_variance_scale * sensors.mocap_attitude_sigma_rad**2
        if var_p <= 0.0 or var_t <= 0.0:
            raise UserError(f"sensor spec '{sensors.name}': the mocap sigmas must be positive for the estimator")
        self._R = np.diag([var_p] * 3 + [var_t] * 3)
        self._r_diag = (var_p,) * 3 + (var_t,) * 3
        self._gate_d2 = chi2_quantile(prm.gate_chi2_probability, N_MOCAP)
        bias_var = [sensors.accel_bias_initial_sigma**2] * 3 + [sensors.gyro_bias_initial_sigma**2] * 3
        velocity_var = [prm.initial_velocity_sigma_mps**2] * 3
        self._P0_diag = np.array([var_p] * 3 + velocity_var + [var_t] * 3 + bias_var)
        self._posterior: tuple[np.ndarray, np.ndarray] | None = None  # (dx, P) of the last _innovate
        self._q_cache: dict[float, np.ndarray] = {}
        self._reset_bookkeeping()
        self._waiting_poses: list[MocapPose] = []  # poses seen before the first IMU sample

    # ------------------------------------------------------------------ public API

    @property
    def initialised(self) -> bool:
        return bool(self._nodes)

    def initialise(self, pose: MocapPose) -> None:
        """Start (or restart) the filter at `pose`, assuming the vehicle is at rest with zero biases."""
        if not _pose_valid(pose):
            raise UserError(f"MocapPose at t={pose.time_s!r}: position/attitude must be finite and the "
                            "quaternion non-zero to initialise the estimator")
        self._reset_bookkeeping()
        node = _Node(float(pose.time_s), _MOCAP, status=_INIT)
        node.x = (*map(float, pose.position_enu_m), 0.0, 0.0, 0.0,
                  *quat_normalize_positive_w(tuple(map(float, pose.attitude_wxyz))), 0.0, 0.0, 0.0, 0.0, 0.0, 0.0)
        node.P = np.diag(self._P0_diag)
        self._nodes = [node]
        self._times = [node.time_s]
        self._last_accepted_s = node.time_s

    def add_imu(self, sample: ImuSample) -> None:
        """Propagate to the sample's time (or insert it in the buffer and replay if it is late)."""
        self._estimate = None
        t = float(sample.time_s)
        f = tuple(map(float, sample.specific_force_flu_mps2))
        w = tuple(map(float, sample.rate_flu_radps))
        if not (len(f) == 3 and len(w) == 3 and _finite((t, *f, *w))):
            self._count["invalid_imu"] += 1
            return
        if not self._nodes or self._nodes[0].f is None:
            if not self._start_at_imu(t):
                return  # no pose at or before this sample yet: nothing to propagate from
        node = _Node(t, _IMU, f, w)
        if t > self._times[-1]:
            self._append_imu(node)
        else:
            self._insert_imu(node)
        self._trim()

    def add_mocap(self, pose: MocapPose) -> bool:
        """Fuse a pose at its sample time. True if accepted (or used to re-initialise)."""
        self._estimate = None
        if not _pose_valid(pose):
            self._count["invalid_mocap"] += 1
            return False
        t = float(pose.time_s)
        if not self._nodes or (len(self._nodes) == 1 and self._nodes[0].f is None):
            # No IMU yet: keep the poses; the first IMU sample starts the filter at the newest pose no
            # later than itself (the downlink may lag the mocap by more than a mocap period).
            bisect.insort(self._waiting_poses, pose, key=lambda p: p.time_s)
            horizon = self._waiting_poses[-1].time_s - self.params.buffer_length_s
            self._waiting_poses = [p for p in self._waiting_poses if p.time_s >= horizon]
            if not self._nodes:
                self.initialise(pose)
                self._waiting_poses = [pose]
            return True
        if t < self._times[0]:
            self._count["stale_mocap"] += 1
            return False
        if self._holds_mocap_at(t):
            self._count["duplicate_mocap"] += 1
            return False
        node = _Node(t, _MOCAP, position=tuple(map(float, pose.position_enu_m)),
                     attitude=quat_normalize_positive_w(tuple(map(float, pose.attitude_wxyz))))
        if t > self._times[-1]:
            self._queue_future_mocap(node)
            return True  # queued: decided when the IMU stream reaches its sample time
        else:
            i = bisect.bisect_right(self._times, t)
            self._nodes.insert(i, node)
            self._times.insert(i, t)
            self._replay_from(i)
        return node.status in (_ACCEPTED, _REINIT)

    def estimate(self) -> Estimate:
        """The state after the newest sample (all NaN and healthy=False before the first pose).

        Cached: calls with no add_imu / add_mocap / initialise in between return the same Estimate.
        """
        if self._estimate is None:
            if not self._nodes:
                self._estimate = self._nan_estimate()
            else:
                last = len(self._nodes) - 1
                node = self._nodes[last]
                self._estimate = self._make_estimate(node.time_s, node.x, self._covariance_at(last), node.w)
        return self._estimate

    def predict_to(self, t_s: float) -> Estimate:
        """The state propagated to t_s (vehicle clock) holding the newest IMU sample; the filter is unchanged.

        One integration step whatever the horizon (meant for the few tens of ms of link latency: with a
        held signal the rotation is exact and the trapezoid's velocity error ~ g (w dt)^2 / 12).
        For t_s at or before the newest sample this is estimate() (no backward prediction).
        """
        if not self._nodes:
            return self._nan_estimate()
        last = len(self._nodes) - 1
        node = self._nodes[last]
        dt = float(t_s) - node.time_s
        if node.f is None or not dt > 0.0:
            return self.estimate()
        x, (F, Q) = self._step(node.x, node.f, node.w, node.f, node.w, dt)
        P = self._predict(self._covariance_at(last), (F, Q))  # a new array: the filter keeps its own
        return self._make_estimate(float(t_s), x, P, node.w)

    def health(self) -> EstimatorHealth:
        """Counters and flags (see EstimatorHealth); also inside every Estimate."""
        # A frame from the future (queued until the IMU catches up) must not make the age negative.
        age = max(0.0, self._times[-1] - self._last_accepted_s) if self._nodes else math.inf
        c = self._count
        return _frozen(EstimatorHealth, {
            "initialised": bool(self._nodes), "mocap_age_s": age, "blackout": age > self.params.blackout_s,
            "accepted_mocap": c["accepted_mocap"], "rejected_outliers": c["rejected_outliers"],
            "consecutive_rejections": self._consecutive_rejections, "reinitialisations": c["reinitialisations"],
            "duplicate_mocap": c["duplicate_mocap"], "stale_mocap": c["stale_mocap"],
            "invalid_mocap": c["invalid_mocap"], "imu_gaps": c["imu_gaps"], "lost_imu": c["lost_imu"],
            "reordered_imu": c["reordered_imu"], "stale_imu": c["stale_imu"], "duplicate_imu": c["duplicate_imu"],
            "invalid_imu": c["invalid_imu"],
        })

    # ------------------------------------------------------------------ timeline bookkeeping

    def _start_at_imu(self, t: float) -> bool:
        """Before the first IMU sample: (re)start at the newest waiting pose at or before t, and queue the
        newer ones as future frames. False when every waiting pose is newer than t."""
        earlier = [p for p in self._waiting_poses if p.time_s < t]
        if not earlier:
            self._count["stale_imu"] += 1
            return False
        later = [p for p in self._waiting_poses if p.time_s > t]
        self.initialise(earlier[-1])
        self._waiting_poses = []
        for pose in later:
            self._queue_future_mocap(_Node(float(pose.time_s), _MOCAP, position=tuple(map(float, pose.position_enu_m)),
                                           attitude=quat_normalize_positive_w(tuple(map(float, pose.attitude_wxyz)))))
        return True

    def _reset_bookkeeping(self) -> None:
        self._nodes: list[_Node] = []
        self._times: list[float] = []
        self._pending: list[_Node] = []  # mocap frames newer than the newest IMU sample, not yet gated
        self._last_accepted_s = -math.inf
        self._consecutive_rejections = 0
        self._last_trimmed_imu_s: float | None = None
        self._estimate: Estimate | None = None  # estimate()'s cache, cleared by every input
        self._count = dict.fromkeys(
            ("accepted_mocap", "rejected_outliers", "reinitialisations", "duplicate_mocap", "stale_mocap",
             "invalid_mocap", "imu_gaps", "lost_imu", "reordered_imu", "stale_imu", "duplicate_imu",
             "invalid_imu"), 0)

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
            self._count["stale_imu"] += 1
            return
        i = bisect.bisect_left(self._times, t)
        k = i
        while k < len(self._times) and self._times[k] == t:
            if self._nodes[k].kind == _IMU:
                self._count["duplicate_imu"] += 1
                return
            k += 1
        if i == 0:  # same time as the base node (a pose): nothing before it to replay from
            self._count["stale_imu"] += 1
            return
        self._nodes.insert(i, node)
        self._times.insert(i, t)
        self._count["reordered_imu"] += 1
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

    def _queue_future_mocap(self, node: _Node) -> None:
        """Hold a frame newer than the newest IMU sample until the IMU stream reaches its time.

        It is gated then, against the state propagated on the real IMU samples up to its sample time:
        when the downlink's latency exceeds the mocap's (a radio of 20+ ms against a 5 ms Vicon), a
        gate decided now on a held-IMU prediction over that gap rejects good frames during manoeuvres.
        """
        bisect.insort(self._pending, node, key=lambda m: m.time_s)

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
        cut_s = times[-1] - self.params.buffer_length_s
        if len(times) <= _TRIM_CHUNK or times[_TRIM_CHUNK] >= cut_s:
            return  # fewer than _TRIM_CHUNK + 1 nodes before the cut (the bisect below would say k < chunk)
        k = bisect.bisect_left(times, cut_s) - 1
        self._covariance_at(k)  # the new base holds its P
        for node in self._nodes[:k]:
            if node.kind == _IMU:
                self._count_gap(node.time_s)
        del self._nodes[:k]
        del self._times[:k]

    def _count_gap(self, t: float) -> None:
        last, self._last_trimmed_imu_s = self._last_trimmed_imu_s, t
        if last is not None and t - last > self.params.imu_gap_factor * self._imu_period_s:
            self._count["imu_gaps"] += 1
            self._count["lost_imu"] += max(1, round((t - last) / self._imu_period_s) - 1)

    # ------------------------------------------------------------------ mocap decisions

    def _decide(self, d2: float, t: float) -> int:
        """Accept, reject or re-initialise on a frame with squared Mahalanobis distance d2."""
        if d2 <= self._gate_d2:
            status = _ACCEPTED
        elif (t - self._last_accepted_s > self.params.reinit_after_blackout_s
              or self._consecutive_rejections >= self.params.reinit_after_rejections):
            status = _REINIT
        else:
            self._count["rejected_outliers"] += 1
            self._consecutive_rejections += 1
            return _REJECTED
        self._count["reinitialisations" if status == _REINIT else "accepted_mocap"] += 1
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
        d2 = update_covariance(P, z, self._r_diag, MOCAP_STATES, P_post, dx)
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
        P_new = np.diag(self._P0_diag)
        P_new[VELOCITY, VELOCITY] = np.eye(3) * self.params.reinit_velocity_sigma_mps**2
        P_new[9:15, 9:15] = P[9:15, 9:15]
        return x_new, P_new

    # ------------------------------------------------------------------ propagation

    def _propagate(self, x: tuple, f0, w0, f1, w1, dt: float,
                   transition: tuple | None = None) -> tuple[tuple, tuple | None]:
        """Nominal state after dt with signals (f0, w0) at the start and (f1, w1) at the end, and (F, Q).

        Intervals longer than imu.max_step_s are integrated in equal sub-steps (signals interpolated);
        their F and Q are chained into one F = F_n..F_1, Q = F_n(..)F_n' + Q_n for a single predict.
        Given `transition` (F, Q) - stored from an earlier pass over this same interval - only the nominal
        state is recomputed. Returns (x, (F, Q)), (x, None) for dt <= 0 (P unchanged).
        """
        if dt <= 0.0:
            return x, transition
        n = math.ceil(dt / self.params.imu_max_step_s - 1e-9)  # slack: 2.0000000001 steps are 2
        if n <= 1:
            if transition is not None:
                return propagate(x, f0, w0, f1, w1, dt, self._g, None, None), transition
            return self._step(x, f0, w0, f1, w1, dt)
        h = dt / n
        fa, wa = f0, w0
        F_total = Q_total = None
        for k in range(1, n + 1):
            fb, wb = _lerp(f0, f1, k / n), _lerp(w0, w1, k / n)
            if transition is not None:
                x = propagate(x, fa, wa, fb, wb, h, self._g, None, None)
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
        """One trapezoidal nominal step (module docstring; estimator.eskf_kernels.propagate) and its (F, Q):
        F a new array, the identity with its 48 other entries written by the kernel; Q shared, read only
        (_process_noise)."""
        F = _IDENTITY_ERROR.copy()
        x1 = propagate(x, f0, w0, f1, w1, dt, self._g, F, _F_INDEX)
        return x1, (F, self._process_noise(dt))

    def _process_noise(self, dt: float) -> np.ndarray:
        """Q over dt (module docstring), read-only, cached by dt: IMU intervals take a few lengths."""
        Q = self._q_cache.get(dt)
        if Q is not None:
            return Q
        if len(self._q_cache) >= _Q_CACHE_SIZE:
            self._q_cache.clear()  # mocap frames split intervals at arbitrary times
        qv = self._accel_psd * dt
        qp, qpv = qv * dt * dt / 3.0, qv * dt * 0.5
        qt, qba, qbg = self._gyro_psd * dt, self._accel_bias_psd * dt, self._gyro_bias_psd * dt
        Q = np.zeros((N_ERROR, N_ERROR))
        Q.put(_Q_INDEX, (qp, qp, qp, qpv, qpv, qpv, qpv, qpv, qpv, qv, qv, qv, qt, qt, qt,
                         qba, qba, qba, qbg, qbg, qbg))
        Q.flags.writeable = False  # shared by every interval of this length
        self._q_cache[dt] = Q
        return Q

    # ------------------------------------------------------------------ output

    def _make_estimate(self, t: float, x: tuple, P: np.ndarray, w) -> Estimate:
        """One array for the 16 state numbers and the rate, sliced into the fields (one conversion)."""
        health = self.health()
        bgx, bgy, bgz = x[13], x[14], x[15]
        rate = (w[0] - bgx, w[1] - bgy, w[2] - bgz) if w is not None else (-bgx, -bgy, -bgz)
        values = np.array((*x, *rate))
        std = np.sqrt(P.diagonal())
        sx, sy, sz = std[0:3].tolist()
        limit = self.params.max_position_sigma_m
        healthy = (not health.blackout) and sx <= limit and sy <= limit and sz <= limit
        return _frozen(Estimate, {
            "time_s": t, "position_enu_m": values[0:3], "velocity_enu_mps": values[3:6],
            "attitude_wxyz": values[6:10], "rate_flu_radps": values[16:19], "accel_bias_flu_mps2": values[10:13],
            "gyro_bias_flu_radps": values[13:16], "covariance": P.copy(), "std_dev": std, "healthy": healthy,
            "health": health,
        })

    def _nan_estimate(self) -> Estimate:
        nan3 = np.full(3, np.nan)
        return Estimate(
            time_s=math.nan, position_enu_m=nan3, velocity_enu_mps=nan3.copy(),
            attitude_wxyz=np.full(4, np.nan),
            rate_flu_radps=nan3.copy(), accel_bias_flu_mps2=nan3.copy(), gyro_bias_flu_radps=nan3.copy(),
            covariance=np.full((N_ERROR, N_ERROR), np.nan), std_dev=np.full(N_ERROR, np.nan), healthy=False,
            health=self.health(),
        )


def _frozen(cls: type, fields: dict):
    """cls(**fields) for the frozen dataclasses above, without their generated __init__.

    That __init__ sets every field through object.__setattr__ (frozen): ~4 us for Estimate and its
    EstimatorHealth, half of estimate(). These classes have no __post_init__, defaults or slots, so
    filling the instance dict is the same object; tests/estimator checks every field is there.
    """
    instance = object.__new__(cls)
    instance.__dict__.update(fields)
    return instance


def chi2_quantile(probability: float, dof: int) -> float:
    """The chi-square distribution's quantile: 2 P^-1(dof/2, probability), P the regularized lower incomplete
    gamma function (scipy.stats.chi2.ppf computes this same expression; tests/estimator checks the bits).
    From scipy.special: importing scipy.stats costs ~0.4 s per process, in every ground station's start-up."""
    return float(2 * gammaincinv(dof / 2, probability))


def _lerp(a: tuple, b: tuple, s: float) -> tuple:
    return (a[0] + s * (b[0] - a[0]), a[1] + s * (b[1] - a[1]), a[2] + s * (b[2] - a[2]))
