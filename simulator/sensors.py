"""Sensor models: the onboard IMU and the motion-capture room.

Takes in: the true specific force (body FLU, m/s^2) and body rates (FLU, rad/s) for the IMU; the true
position (ENU, m) and attitude (w, x, y, z) for mocap; sample times (sim s); noise parameters
(model.vehicle.ImuNoise, model.vehicle.MocapRoom); a numpy Generator each (all randomness comes from it).
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
whatever happens to it, so one fault does not reshuffle the noise of every later frame.

Speed: the random parts are computed DRAW_BLOCK samples at a time with numpy (one Generator call per
block; the IMU's b_k + n_k as a cumulative sum, mocap's error quaternions by a vectorised exp map), so a
sample costs a few float additions. Blocks are drawn when needed, in sample order: the outputs are still
a pure function of the seed and the samples asked for.
"""

from __future__ import annotations

import math

import numpy as np

from link.messages import ImuSample, MocapPose
from model.frames import Quat, Vec3, quat_exp_rows
from model.vehicle import ImuNoise, MocapRoom

DRAW_BLOCK = 256  # samples of random numbers drawn per Generator call


class ImuModel:
    def __init__(self, noise: ImuNoise, rng: np.random.Generator):
        self.rng = rng
        self.rate_hz = noise.rate_hz
        self.period_s = 1.0 / noise.rate_hz
        root_rate = math.sqrt(noise.rate_hz)
        root_dt = math.sqrt(self.period_s)
        accel_white_sigma = noise.accel_noise_density * root_rate  # m/s^2 per sample
        gyro_white_sigma = noise.gyro_noise_density * root_rate  # rad/s per sample
        accel_walk_sigma = noise.accel_bias_random_walk * root_dt  # m/s^2 per sample step
        gyro_walk_sigma = noise.gyro_bias_random_walk * root_dt  # rad/s per sample step
        self._white = np.array([accel_white_sigma] * 3 + [gyro_white_sigma] * 3)
        self._walk = np.array([accel_walk_sigma] * 3 + [gyro_walk_sigma] * 3)
        # b_0: accel then gyro; later, the bias of the first sample after the drawn rows
        self._bias_next = np.concatenate([rng.standard_normal(3) * noise.accel_bias_initial_sigma,
                                          rng.standard_normal(3) * noise.gyro_bias_initial_sigma])
        self._rows: list[list[float]] = []  # per sample: b_k + n_k (accel, gyro)
        self._biases = np.empty((0, 6))  # per sample: b_k (accel, gyro)
        self._next = 0

    @property
    def accel_bias(self) -> list[float]:
        """The accelerometer bias b_k (m/s^2, FLU) of the next sample."""
        return self._peek()[0:3]

    def sample(self, t_s: float, specific_force_flu_mps2: Vec3, rate_flu_radps: Vec3) -> ImuSample:
        """One reading at sample time t_s; then the biases take one random-walk step."""
        i = self._next
        if i == len(self._rows):
            self._draw_block()
            i = 0
        self._next = i + 1
        e = self._rows[i]
        f, w = specific_force_flu_mps2, rate_flu_radps
        # positional: a keyword call costs a third more (time_s, specific_force_flu_mps2, rate_flu_radps)
        return ImuSample(t_s, (f[0] + e[0], f[1] + e[1], f[2] + e[2]), (w[0] + e[3], w[1] + e[4], w[2] + e[5]))

    def _peek(self) -> list[float]:
        """b_k (accel, gyro) of the next sample (the first of the next block once this one is used up)."""
        if self._next == len(self._rows):
            return self._bias_next.tolist()
        return self._biases[self._next].tolist()

    def _draw_block(self) -> None:
        """DRAW_BLOCK samples' errors: per sample 6 white draws, then 6 walk draws (its bias step)."""
        normals = self.rng.standard_normal((DRAW_BLOCK, 12))
        walked = np.cumsum(normals[:, 6:] * self._walk, axis=0)  # b_{k+1} - b_start
        start = self._bias_next
        biases = np.empty_like(walked)  # b_k
        biases[0] = start
        biases[1:] = start + walked[:-1]
        self._bias_next = start + walked[-1]
        self._biases = biases
        self._rows = (biases + normals[:, :6] * self._white).tolist()
        self._next = 0


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
        self._rows: list[list[float]] = []
        self._next = 0

    def sample(self, t_s: float, position_enu_m: Vec3, attitude_wxyz: Quat) -> MocapPose | None:
        """The pose seen at sample time t_s, or None when the frame is lost."""
        i = self._next
        if i == len(self._rows):
            self._draw_block()
            i = 0
        self._next = i + 1
        u_drop, u_out, nx, ny, nz, ew, ex, ey, ez, jx, jy, jz = self._rows[i]
        self.frames += 1
        room = self.room
        if u_drop < room.dropout_probability:
            self.dropouts += 1
            return None
        p = position_enu_m
        x, y, z = p[0] + nx, p[1] + ny, p[2] + nz
        if u_out < room.outlier_probability:
            self.outliers += 1
            x, y, z = x + jx, y + jy, z + jz
        # q (x) e: the error is a body-frame perturbation; renormalised against rounding
        qw, qx, qy, qz = attitude_wxyz
        aw = qw * ew - qx * ex - qy * ey - qz * ez
        ax = qw * ex + qx * ew + qy * ez - qz * ey
        ay = qw * ey - qx * ez + qy * ew + qz * ex
        az = qw * ez + qx * ey - qy * ex + qz * ew
        k = 1.0 / math.sqrt(aw * aw + ax * ax + ay * ay + az * az)
        return MocapPose(t_s, self.body_id, (x, y, z), (aw * k, ax * k, ay * k, az * k))

    def _draw_block(self) -> None:
        """DRAW_BLOCK frames: per frame U(0,1) for dropout and outlier, then 9 normals - position noise,
        attitude rotation vector, outlier direction - turned into the errors sample() adds."""
        room = self.room
        u = self.rng.random((DRAW_BLOCK, 2))
        n = self.rng.standard_normal((DRAW_BLOCK, 9))
        position = n[:, 0:3] * room.position_noise_m
        error = quat_exp_rows(n[:, 3:6] * room.attitude_noise_rad)
        norm = np.linalg.norm(n[:, 6:9], axis=1, keepdims=True)
        jump = n[:, 6:9] * (room.outlier_magnitude_m / np.where(norm > 0.0, norm, 1.0))
        self._rows = np.hstack([u, position, error, jump]).tolist()
        self._next = 0
