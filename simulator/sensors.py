"""Sensor models: the onboard IMU and the motion-capture room.

Takes in: the true specific force (body FLU, m/s^2) and body rates (FLU, rad/s) for the IMU; the true
position (ENU, m) and attitude (w, x, y, z) for mocap; sample times (sim s); noise parameters
(link.vehicle.ImuNoise, link.vehicle.MocapRoom); a numpy Generator each (all randomness comes from it).
Gives out: ImuSample and MocapPose messages (time_s = the sample time) or None for a dropped mocap frame.

IMU (discrete-time equivalent of continuous-time densities, sample period dt = 1 / rate_hz):
    y_k = x_k + b_k + n_k,   n_k ~ N(0, (N / sqrt(dt))^2)      white noise, N = noise density
    b_{k+1} = b_k + w_k,     w_k ~ N(0, (K sqrt(dt))^2)        bias random walk, K = its density
    b_0 ~ N(0, sigma_b0^2)                                     turn-on bias
Mocap, per frame: with probability p_drop the frame is lost; otherwise position + N(0, sigma_p^2) per
axis and attitude (x) exp(N(0, sigma_a^2) per axis, body frame); with probability p_out the frame is an
outlier (a marker swap or ghost): its position jumps by outlier_magnitude_m in a uniformly random
direction. Latency: a frame carries its sample time and is released latency_s after it (the caller
schedules the release; see MocapModel.latency_s). Each frame draws the same count of random numbers
whatever happens to it, so one fault does not reshuffle the noise of every later frame. Normal draws
are taken from the Generator in blocks of DRAW_BLOCK samples (one numpy call per block instead of per
sample: ~1 us saved per sample), still a pure function of the seed.
"""

from __future__ import annotations

import math

import numpy as np

from link.messages import ImuSample, MocapPose
from link.vehicle import ImuNoise, MocapRoom
from simulator.rotation import Quat, Vec3, quat_from_rotvec, quat_multiply, quat_normalize

DRAW_BLOCK = 256  # samples of random numbers drawn per Generator call


class _Draws:
    """Rows of `uniforms` U(0, 1) numbers then `width` standard normals, drawn DRAW_BLOCK rows at a time."""

    def __init__(self, rng: np.random.Generator, width: int, uniforms: int = 0):
        self.rng, self.width, self.uniforms = rng, width, uniforms
        self.rows: list[list[float]] = []
        self.next = 0

    def row(self) -> list[float]:
        if self.next == len(self.rows):
            normals = self.rng.standard_normal((DRAW_BLOCK, self.width))
            if self.uniforms:
                normals = np.hstack([self.rng.random((DRAW_BLOCK, self.uniforms)), normals])
            self.rows = normals.tolist()
            self.next = 0
        self.next += 1
        return self.rows[self.next - 1]


class ImuModel:
    def __init__(self, noise: ImuNoise, rng: np.random.Generator):
        self.rng = rng
        self.rate_hz = noise.rate_hz
        self.period_s = 1.0 / noise.rate_hz
        root_rate = math.sqrt(noise.rate_hz)
        root_dt = math.sqrt(self.period_s)
        self.accel_white_sigma = noise.accel_noise_density * root_rate  # m/s^2 per sample
        self.gyro_white_sigma = noise.gyro_noise_density * root_rate  # rad/s per sample
        self.accel_walk_sigma = noise.accel_bias_random_walk * root_dt  # m/s^2 per sample step
        self.gyro_walk_sigma = noise.gyro_bias_random_walk * root_dt  # rad/s per sample step
        self.accel_bias = (rng.standard_normal(3) * noise.accel_bias_initial_sigma).tolist()
        self.gyro_bias = (rng.standard_normal(3) * noise.gyro_bias_initial_sigma).tolist()
        self._draws = _Draws(rng, 12)

    def sample(self, t_s: float, specific_force_flu_mps2: Vec3, rate_flu_radps: Vec3) -> ImuSample:
        """One reading at sample time t_s; then the biases take one random-walk step."""
        n = self._draws.row()
        sa, sg = self.accel_white_sigma, self.gyro_white_sigma
        ba, bg = self.accel_bias, self.gyro_bias
        f, w = specific_force_flu_mps2, rate_flu_radps
        out = ImuSample(
            time_s=t_s,
            specific_force_flu_mps2=(f[0] + ba[0] + sa * n[0], f[1] + ba[1] + sa * n[1],
                                     f[2] + ba[2] + sa * n[2]),
            rate_flu_radps=(w[0] + bg[0] + sg * n[3], w[1] + bg[1] + sg * n[4], w[2] + bg[2] + sg * n[5]),
        )
        wa, wg = self.accel_walk_sigma, self.gyro_walk_sigma
        self.accel_bias = [ba[0] + wa * n[6], ba[1] + wa * n[7], ba[2] + wa * n[8]]
        self.gyro_bias = [bg[0] + wg * n[9], bg[1] + wg * n[10], bg[2] + wg * n[11]]
        return out


class MocapModel:
    def __init__(self, room: MocapRoom, rng: np.random.Generator, body_id: int):
        self.rng = rng
        self.room = room
        self.body_id = body_id
        self.rate_hz = room.rate_hz
        self.period_s = 1.0 / room.rate_hz
        self.latency_s = room.latency_s
        self.frames = 0
        self.dropouts = 0
        self.outliers = 0
        self._draws = _Draws(rng, 9, uniforms=2)

    def sample(self, t_s: float, position_enu_m: Vec3, attitude_wxyz: Quat) -> MocapPose | None:
        """The pose seen at sample time t_s, or None when the frame is lost."""
        room = self.room
        u_drop, u_out, *n = self._draws.row()
        self.frames += 1
        if u_drop < room.dropout_probability:
            self.dropouts += 1
            return None
        sp, sa = room.position_noise_m, room.attitude_noise_rad
        p = position_enu_m
        x, y, z = p[0] + sp * n[0], p[1] + sp * n[1], p[2] + sp * n[2]
        if u_out < room.outlier_probability:
            self.outliers += 1
            norm = math.sqrt(n[6] * n[6] + n[7] * n[7] + n[8] * n[8]) or 1.0
            jump = room.outlier_magnitude_m / norm
            x, y, z = x + jump * n[6], y + jump * n[7], z + jump * n[8]
        error = quat_from_rotvec(sa * n[3], sa * n[4], sa * n[5])  # body-frame perturbation
        attitude = quat_normalize(quat_multiply(attitude_wxyz, error))
        return MocapPose(time_s=t_s, body_id=self.body_id, position_enu_m=(x, y, z), attitude_wxyz=attitude)
