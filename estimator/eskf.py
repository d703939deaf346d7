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
What the timeline (estimator.eskf_timeline.Timeline, or its compiled twin in estimator._eskf_kernels when it
was built: the same bits) does around them: the nominal propagation above and F (the identity, its 48 other
entries written by estimator.eskf_kernels.propagate), Q (depends on dt alone), forming z from the nominal
state, the Mahalanobis gate d^2 = y' S^-1 y (a rejected frame keeps the prior P: the update is discarded),
injecting dx into the nominal state (q <- q (x) Exp(dtheta)), the ESKF reset P <- G P G' with
G_theta = I - [dtheta/2]x (Sola eq. 287), the error state back to 0, and the time bookkeeping below.
This module checks each sample, holds the poses seen before the first IMU sample, and builds the Estimate.

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

from estimator import eskf_timeline
from estimator.eskf_timeline import (
    MOCAP_STATES,
    N_ERROR,
    N_VALUES,
    NOT_STARTED,
    STALE_IMU,
    TimelineConfig,
    fill_state,
    pose_valid,
    pose_values,
)
from estimator.sensor_spec import SensorSpec
from link.messages import ImuSample, MocapPose
from model.config import Params, resolve
from model.errors import UserError
from model.vehicle import GRAVITY_MPS2

try:
    from estimator._eskf_kernels import Timeline as CompiledTimeline
except ImportError:  # not built (no C compiler at install): the Python twin, same results, slower
    CompiledTimeline = None

ERROR_STATE_LABELS = (
    "position_e_m", "position_n_m", "position_u_m",
    "velocity_e_mps", "velocity_n_mps", "velocity_u_mps",
    "attitude_x_rad", "attitude_y_rad", "attitude_z_rad",
    "accel_bias_x_mps2", "accel_bias_y_mps2", "accel_bias_z_mps2",
    "gyro_bias_x_radps", "gyro_bias_y_radps", "gyro_bias_z_radps",
)
POSITION, VELOCITY, ATTITUDE, ACCEL_BIAS, GYRO_BIAS = (slice(i, i + 3) for i in range(0, 15, 3))
N_MOCAP = 6
assert MOCAP_STATES == (*range(N_ERROR)[POSITION], *range(N_ERROR)[ATTITUDE])  # H: position and attitude


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


class ErrorStateKF:
    """The estimator. Feed add_imu / add_mocap in arrival order; read estimate() / predict_to().

    `timeline`: the class keeping the samples and the state (estimator.eskf_timeline.Timeline or its
    compiled twin, the default when it was built: the same bits)."""

    def __init__(self, sensors: SensorSpec, imu_rate_hz: float, params: EskfParams | None = None,
                 timeline: type | None = None):
        self.params = params if params is not None else load_eskf_params()
        self.sensors = sensors
        prm = self.params
        scale = prm.process_noise_variance_scale
        var_p = prm.mocap_noise_variance_scale * sensors.mocap_position_sigma_m**2
        var_t = prm.mocap_noise_variance_scale * sensors.mocap_attitude_sigma_rad**2
        if var_p <= 0.0 or var_t <= 0.0:
            raise UserError(f"sensor spec '{sensors.name}': the mocap sigmas must be positive for the estimator")
        bias_var = [sensors.accel_bias_initial_sigma**2] * 3 + [sensors.gyro_bias_initial_sigma**2] * 3
        velocity_var = [prm.initial_velocity_sigma_mps**2] * 3
        self.config = TimelineConfig(
            gravity_mps2=GRAVITY_MPS2, imu_period_s=1.0 / imu_rate_hz, max_step_s=prm.imu_max_step_s,
            buffer_length_s=prm.buffer_length_s, gap_factor=prm.imu_gap_factor,
            gate_d2=chi2_quantile(prm.gate_chi2_probability, N_MOCAP),
            reinit_after_blackout_s=prm.reinit_after_blackout_s,
            reinit_after_rejections=prm.reinit_after_rejections, r_diag=(var_p,) * 3 + (var_t,) * 3,
            p0_diag=tuple([var_p] * 3 + velocity_var + [var_t] * 3 + bias_var),
            reinit_velocity_var=prm.reinit_velocity_sigma_mps**2,
            accel_psd=scale * sensors.accel_noise_density**2, gyro_psd=scale * sensors.gyro_noise_density**2,
            accel_bias_psd=scale * sensors.accel_bias_random_walk**2,
            gyro_bias_psd=scale * sensors.gyro_bias_random_walk**2)
        if timeline is None:
            timeline = CompiledTimeline if CompiledTimeline is not None else eskf_timeline.Timeline
        self._timeline = timeline(self.config)
        self._estimate: Estimate | None = None  # estimate()'s cache, cleared by every input
        self._waiting_poses: list[MocapPose] = []  # poses seen before the first IMU sample

    # ------------------------------------------------------------------ public API

    @property
    def initialised(self) -> bool:
        return not self._timeline.empty

    def initialise(self, pose: MocapPose) -> None:
        """Start (or restart) the filter at `pose`, assuming the vehicle is at rest with zero biases."""
        if not pose_valid(pose):
            raise UserError(f"MocapPose at t={pose.time_s!r}: position/attitude must be finite and the "
                            "quaternion non-zero to initialise the estimator")
        self._estimate = None
        position, attitude = pose_values(pose)  # at rest, zero biases
        self._timeline.initialise(float(pose.time_s), (*position, 0.0, 0.0, 0.0, *attitude, *(0.0,) * 6))

    def add_imu(self, sample: ImuSample) -> None:
        """Propagate to the sample's time (or insert it in the buffer and replay if it is late)."""
        self._estimate = None
        if self._timeline.add_imu_sample(sample) == NOT_STARTED:  # checked: valid, the first to place
            t = float(sample.time_s)
            if self._start_at_imu(t):
                self._timeline.add_imu(t, tuple(map(float, sample.specific_force_flu_mps2)),
                                       tuple(map(float, sample.rate_flu_radps)))

    def add_mocap(self, pose: MocapPose) -> bool:
        """Fuse a pose at its sample time. True if accepted (or used to re-initialise)."""
        self._estimate = None
        accepted = self._timeline.add_mocap_pose(pose)
        if accepted is not None:
            return accepted
        # No IMU yet: keep the poses; the first IMU sample starts the filter at the newest pose no later
        # than itself (the downlink may lag the mocap by more than a mocap period).
        bisect.insort(self._waiting_poses, pose, key=lambda p: p.time_s)
        horizon = self._waiting_poses[-1].time_s - self.params.buffer_length_s
        self._waiting_poses = [p for p in self._waiting_poses if p.time_s >= horizon]
        if self._timeline.empty:
            self.initialise(pose)
            self._waiting_poses = [pose]
        return True

    def estimate(self) -> Estimate:
        """The state after the newest sample (all NaN and healthy=False before the first pose).

        Cached: calls with no add_imu / add_mocap / initialise in between return the same Estimate.
        """
        if self._estimate is None:
            if self._timeline.empty:
                self._estimate = self._nan_estimate()
            else:
                P, values, std = np.empty((N_ERROR, N_ERROR)), np.empty(N_VALUES), np.empty(N_ERROR)
                t, last_accepted_s, in_a_row, counts = self._timeline.newest_state(P, values, std)
                self._estimate = self._make_estimate(t, values, P, std,
                                                     self._health(t, last_accepted_s, in_a_row, counts))
        return self._estimate

    def predict_to(self, t_s: float) -> Estimate:
        """The state propagated to t_s (vehicle clock) holding the newest IMU sample; the filter is unchanged.

        One integration step whatever the horizon (meant for the few tens of ms of link latency: with a
        held signal the rotation is exact and the trapezoid's velocity error ~ g (w dt)^2 / 12).
        For t_s at or before the newest sample this is estimate() (no backward prediction).
        """
        if self._timeline.empty:
            return self._nan_estimate()
        P = np.empty((N_ERROR, N_ERROR))
        predicted = self._timeline.predict(float(t_s), P)
        if predicted is None:
            return self.estimate()
        x, w = predicted
        values, std = np.empty(N_VALUES), np.empty(N_ERROR)
        fill_state(x, w, P, values, std)
        return self._make_estimate(float(t_s), values, P, std, self.health())

    def health(self) -> EstimatorHealth:
        """Counters and flags (see EstimatorHealth); also inside every Estimate."""
        return self._health(*self._timeline.health_values())

    def _health(self, newest_s: float | None, last_accepted_s: float, in_a_row: int, counts: dict) -> EstimatorHealth:
        """EstimatorHealth from the timeline's health values (health_values' four; counts is filled in)."""
        # A frame from the future (queued until the IMU catches up) must not make the age negative.
        age = math.inf if newest_s is None else max(0.0, newest_s - last_accepted_s)
        counts["initialised"] = newest_s is not None
        counts["mocap_age_s"] = age
        counts["blackout"] = age > self.params.blackout_s
        counts["consecutive_rejections"] = in_a_row
        return _frozen(EstimatorHealth, counts)

    # ------------------------------------------------------------------ before the first IMU sample

    def _start_at_imu(self, t: float) -> bool:
        """Before the first IMU sample: (re)start at the newest waiting pose at or before t, and queue the
        newer ones as future frames. False when every waiting pose is newer than t."""
        earlier = [p for p in self._waiting_poses if p.time_s < t]
        if not earlier:
            self._timeline.count(STALE_IMU)
            return False
        later = [p for p in self._waiting_poses if p.time_s > t]
        self.initialise(earlier[-1])
        self._waiting_poses = []
        for pose in later:
            self._timeline.queue_mocap(float(pose.time_s), *pose_values(pose))
        return True

    # ------------------------------------------------------------------ output

    def _make_estimate(self, t: float, values: np.ndarray, P: np.ndarray, std: np.ndarray,
                       health: EstimatorHealth) -> Estimate:
        """The Estimate of fill_state's arrays (values: the 16 state numbers and the rate, sliced into the
        fields; std: P's standard deviations). They are the caller's new arrays: the Estimate keeps them."""
        sx, sy, sz = std[0:3].tolist()
        limit = self.params.max_position_sigma_m
        healthy = (not health.blackout) and sx <= limit and sy <= limit and sz <= limit
        return _frozen(Estimate, {
            "time_s": t, "position_enu_m": values[0:3], "velocity_enu_mps": values[3:6],
            "attitude_wxyz": values[6:10], "rate_flu_radps": values[16:19], "accel_bias_flu_mps2": values[10:13],
            "gyro_bias_flu_radps": values[13:16], "covariance": P, "std_dev": std, "healthy": healthy,
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
