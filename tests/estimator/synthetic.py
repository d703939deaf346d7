"""Synthetic ground truth and sensor streams for the estimator tests.

Takes in: a flight (hover, or a circle of radius r at 1 m altitude flown at up to `speed_mps` after a
hover and a smooth speed ramp), the vehicle's IMU noise, the mocap room, link faults (`LinkFaults`) and
a seeded numpy Generator.
Gives out: `SensorRun` - truth sampled at the IMU sample times (position, velocity, attitude, body rate,
specific force, biases) and the messages (link.messages.ImuSample / MocapPose) in ARRIVAL order.

Truth from differential flatness (yaw 0), exact, no numerical differentiation:
    u = a + g e3,  b3 = u/|u|,  b2 = (b3 x e1)/|b3 x e1|,  b1 = b2 x b3,  R = [b1 b2 b3]
    time derivatives with d/dt (u/|u|) = (u' - b (b . u'))/|u|, u' = jerk;
    body rate [w]x = R' dR/dt;  specific force f = R' u = (0, 0, |u|).
Sensors: f_m = f + b_a + n_a, w_m = w + b_g + n_g with n ~ N(0, density^2 * rate) per sample (a white
noise of density s averaged over one sample period 1/rate); biases start at N(0, initial sigma^2) and
random-walk with increments N(0, rw^2 / rate). Mocap: p_m = p + N(0, s_p^2), q_m = q (x) Exp(N(0, s_t^2))
sampled at the room rate (its own clock phase), arriving `latency` later.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from scipy.spatial.transform import Rotation

from link.messages import ImuSample, MocapPose
from model.vehicle import GRAVITY_MPS2, ImuNoise, MocapRoom

E1 = np.array([1.0, 0.0, 0.0])
E3 = np.array([0.0, 0.0, 1.0])


@dataclass(frozen=True)
class Flight:
    """A circle about (0, 0) at `altitude_m`: hover for hover_s, ramp the speed up over ramp_s, cruise."""

    duration_s: float = 12.0
    radius_m: float = 1.0
    speed_mps: float = 1.0  # 0 = hover
    altitude_m: float = 1.0
    hover_s: float = 1.0
    ramp_s: float = 2.0


@dataclass(frozen=True)
class LinkFaults:
    """What the link does to the sensor streams. None = the mocap room's own figure."""

    mocap_latency_s: float | None = None
    mocap_jitter_s: float = 0.0  # extra latency, uniform in [0, jitter): > 1 period reorders frames
    mocap_dropout_probability: float | None = None
    mocap_outlier_probability: float | None = None
    mocap_outlier_magnitude_m: float | None = None
    mocap_outlier_times_s: tuple[float, ...] = ()  # extra outliers at the first frame after each time
    mocap_blackouts_s: tuple[tuple[float, float], ...] = ()  # (start, end): no frames sampled inside
    mocap_duplicate_probability: float = 0.0
    mocap_phase_s: float = 0.0037  # mocap clock phase against the IMU's sample times
    imu_loss_probability: float = 0.0
    imu_loss_bursts: int = 0  # bursts of imu_burst_length lost samples at random times
    imu_burst_length: int = 10
    imu_swap_probability: float = 0.0  # an adjacent pair swapped in arrival order
    imu_latency_s: float = 0.0


@dataclass
class Truth:
    time_s: np.ndarray  # (N,)
    position_enu_m: np.ndarray  # (N, 3)
    velocity_enu_mps: np.ndarray
    attitude_wxyz: np.ndarray  # (N, 4)
    rate_flu_radps: np.ndarray
    specific_force_flu_mps2: np.ndarray
    accel_bias_flu_mps2: np.ndarray
    gyro_bias_flu_radps: np.ndarray
    imu_rate_hz: float

    def index(self, t_s: float) -> int:
        return int(round((t_s - self.time_s[0]) * self.imu_rate_hz))


@dataclass
class SensorRun:
    truth: Truth
    events: list  # (arrival_s, ImuSample | MocapPose) in arrival order
    outlier_times_s: set = field(default_factory=set)  # sample times of the mocap frames made outliers
    mocap_count: int = 0


def circle_kinematics(flight: Flight, t: np.ndarray) -> tuple[np.ndarray, ...]:
    """Position, velocity, acceleration, jerk (N, 3) of the flight at times t (s)."""
    omega = flight.speed_mps / flight.radius_m
    tau = np.clip((t - flight.hover_s) / flight.ramp_s, 0.0, 1.0)
    # Phase rate follows a quintic smoothstep s(tau) = 10 tau^3 - 15 tau^4 + 6 tau^5 from 0 to omega.
    s = tau**3 * (10 - 15 * tau + 6 * tau**2)
    ds = 30 * tau**2 * (1 - tau) ** 2 / flight.ramp_s
    dds = 60 * tau * (1 - tau) * (1 - 2 * tau) / flight.ramp_s**2
    ramping = (tau > 0) & (tau < 1)
    ds, dds = np.where(ramping, ds, 0.0), np.where(ramping, dds, 0.0)
    integral_s = flight.ramp_s * tau**4 * (2.5 - 3 * tau + tau**2)  # int_0^t s dt, up to the end of the ramp
    phase = omega * (integral_s + np.maximum(t - flight.hover_s - flight.ramp_s, 0.0))
    phi1, phi2, phi3 = omega * s, omega * ds, omega * dds
    r = flight.radius_m
    c, sn = np.cos(phase), np.sin(phase)
    radial, tangent = np.stack([c, sn, 0 * c], -1), np.stack([-sn, c, 0 * c], -1)
    col = np.newaxis
    pos = r * radial + flight.altitude_m * E3
    vel = r * phi1[:, col] * tangent
    acc = r * phi2[:, col] * tangent - r * (phi1**2)[:, col] * radial
    jerk = r * (phi3 - phi1**3)[:, col] * tangent - 3 * r * (phi1 * phi2)[:, col] * radial
    return pos, vel, acc, jerk


def _unit_and_rate(u: np.ndarray, du: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    n = np.linalg.norm(u, axis=-1, keepdims=True)
    b = u / n
    return b, (du - b * np.sum(b * du, axis=-1, keepdims=True)) / n


def flat_attitude(acc: np.ndarray, jerk: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Rotation matrices (N, 3, 3), body rates FLU (N, 3) and specific force FLU (N, 3), yaw 0."""
    u = acc + GRAVITY_MPS2 * E3
    b3, db3 = _unit_and_rate(u, jerk)
    b2, db2 = _unit_and_rate(np.cross(b3, E1), np.cross(db3, E1))
    b1 = np.cross(b2, b3)
    db1 = np.cross(db2, b3) + np.cross(b2, db3)
    rot = np.stack([b1, b2, b3], axis=-1)
    drot = np.stack([db1, db2, db3], axis=-1)
    omega_hat = np.einsum("nji,njk->nik", rot, drot)  # R' dR/dt
    rates = np.stack([omega_hat[:, 2, 1], omega_hat[:, 0, 2], omega_hat[:, 1, 0]], -1)
    force = np.einsum("nji,nj->ni", rot, u)
    return rot, rates, force


def truth_pose(flight: Flight, t: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    pos, _, acc, jerk = circle_kinematics(flight, t)
    rot, _, _ = flat_attitude(acc, jerk)
    return pos, Rotation.from_matrix(rot).as_quat(scalar_first=True)


def make_truth(flight: Flight, imu: ImuNoise, rng: np.random.Generator) -> Truth:
    t = np.arange(0.0, flight.duration_s, 1.0 / imu.rate_hz)
    pos, vel, acc, jerk = circle_kinematics(flight, t)
    rot, rates, force = flat_attitude(acc, jerk)
    quat = Rotation.from_matrix(rot).as_quat(scalar_first=True)
    step_sd = np.sqrt(1.0 / imu.rate_hz)
    ba = imu.accel_bias_initial_sigma * rng.standard_normal(3) + np.cumsum(
        imu.accel_bias_random_walk * step_sd * rng.standard_normal((t.size, 3)), axis=0)
    bg = imu.gyro_bias_initial_sigma * rng.standard_normal(3) + np.cumsum(
        imu.gyro_bias_random_walk * step_sd * rng.standard_normal((t.size, 3)), axis=0)
    return Truth(t, pos, vel, quat, rates, force, ba, bg, imu.rate_hz)


def imu_messages(truth: Truth, imu: ImuNoise, rng: np.random.Generator) -> list[ImuSample]:
    sd_a = imu.accel_noise_density * np.sqrt(imu.rate_hz)
    sd_g = imu.gyro_noise_density * np.sqrt(imu.rate_hz)
    shape = truth.time_s.shape + (3,)
    f = truth.specific_force_flu_mps2 + truth.accel_bias_flu_mps2 + sd_a * rng.standard_normal(shape)
    w = truth.rate_flu_radps + truth.gyro_bias_flu_radps + sd_g * rng.standard_normal(shape)
    return [ImuSample(float(t), tuple(fi.tolist()), tuple(wi.tolist()))
            for t, fi, wi in zip(truth.time_s, f, w, strict=True)]


def simulate(flight: Flight, imu: ImuNoise, room: MocapRoom, rng: np.random.Generator,
             faults: LinkFaults = LinkFaults()) -> SensorRun:
    """Truth plus both sensor streams through the faulty link, sorted by arrival time."""
    truth = make_truth(flight, imu, rng)
    events = _imu_arrivals(imu_messages(truth, imu, rng), faults, rng)
    mocap_events, outliers, count = _mocap_arrivals(flight, room, faults, rng)
    events += mocap_events
    events.sort(key=lambda e: e[0])  # stable: ties keep IMU first
    return SensorRun(truth, events, outliers, count)


def _imu_arrivals(samples: list[ImuSample], faults: LinkFaults, rng: np.random.Generator) -> list:
    n = len(samples)
    keep = rng.random(n) >= faults.imu_loss_probability
    keep[0] = True
    for start in rng.integers(n // 10, n - faults.imu_burst_length, size=faults.imu_loss_bursts):
        keep[start:start + faults.imu_burst_length] = False
    kept = [s for s, k in zip(samples, keep, strict=True) if k]
    order = list(range(len(kept)))
    i = 1
    while i < len(order) - 1:
        if rng.random() < faults.imu_swap_probability:
            order[i], order[i + 1] = order[i + 1], order[i]
            i += 2
        else:
            i += 1
    # Arrival times are monotone in arrival order: a swapped pair arrives together.
    events = []
    latest = -np.inf
    for k in order:
        latest = max(latest, kept[k].time_s + faults.imu_latency_s)
        events.append((latest, kept[k]))
    return events


def _mocap_arrivals(flight: Flight, room: MocapRoom, faults: LinkFaults, rng: np.random.Generator):
    t = np.arange(faults.mocap_phase_s, flight.duration_s - 0.05, 1.0 / room.rate_hz)
    for start, end in faults.mocap_blackouts_s:
        t = t[(t < start) | (t >= end)]
    pos, quat = truth_pose(flight, t)
    pos = pos + room.position_noise_m * rng.standard_normal(pos.shape)
    noise_rot = Rotation.from_rotvec(room.attitude_noise_rad * rng.standard_normal(pos.shape))
    quat = (Rotation.from_quat(quat, scalar_first=True) * noise_rot).as_quat(scalar_first=True)
    dropout = faults.mocap_dropout_probability
    dropout = room.dropout_probability if dropout is None else dropout
    outlier_p = faults.mocap_outlier_probability
    outlier_p = room.outlier_probability if outlier_p is None else outlier_p
    magnitude = faults.mocap_outlier_magnitude_m
    magnitude = room.outlier_magnitude_m if magnitude is None else magnitude
    is_outlier = rng.random(t.size) < outlier_p
    for ts in faults.mocap_outlier_times_s:
        is_outlier[min(np.searchsorted(t, ts), t.size - 1)] = True
    is_outlier[0] = False  # the first pose initialises the filter
    direction = rng.standard_normal(pos.shape)
    direction /= np.linalg.norm(direction, axis=1, keepdims=True)
    pos[is_outlier] += magnitude * direction[is_outlier]
    kept = rng.random(t.size) >= dropout
    kept[0] = True
    latency = room.latency_s if faults.mocap_latency_s is None else faults.mocap_latency_s
    arrival = t + latency + faults.mocap_jitter_s * rng.random(t.size)
    duplicate = rng.random(t.size) < faults.mocap_duplicate_probability
    events, outliers = [], set()
    for i in np.flatnonzero(kept):
        msg = MocapPose(float(t[i]), 1, tuple(pos[i].tolist()), tuple(quat[i].tolist()))
        events.append((float(arrival[i]), msg))
        if duplicate[i]:
            events.append((float(arrival[i]) + 1.0 / room.rate_hz, msg))
        if is_outlier[i]:
            outliers.add(float(t[i]))
    return events, outliers, int(kept.sum())
