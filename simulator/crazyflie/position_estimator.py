"""The onboard position and velocity estimate from the accelerometer and external positions (the firmware
fuses extpos in its Kalman filter; this is a complementary filter with that filter's steady-state gains).

Takes in: per estimator update (250 Hz) the attitude estimate (w, x, y, z), the specific force (m/s^2, body)
and dt; per external fix its position (ENU, m) and sample time, and the time since the previous fix.
Gives out: position (m) and velocity (m/s), world ENU; `valid` once a fix has arrived; the position
variance per axis (m^2: the Kalman filter's initial one before a fix, then the posterior P = K R of the
steady-state filter whose gain K each fix applies); `reset()` (kalman.resetEstimation).

Predict: a = R(q) f - g e_z; v += a dt; p += v dt. Correct, for a fix z at sample time t_z against the
estimate then (its history): e = z - p(t_z); p += L_p dt_fix e; v += L_v dt_fix e, with w = sqrt(s_a / (s_p
sqrt(dt_fix))), L_p = sqrt(2) w, L_v = w^2 per axis, s_a the firmware Kalman filter's acceleration process
noise as a density (simulator/params/crazyflie.toml [position_estimator]).
"""

from __future__ import annotations

import math

from model.frames import quat_to_rows, rotate
from simulator.crazyflie.history import TimeHistory


class PositionEstimator:
    def __init__(self, accel_density, pos_std_m: float, gravity_mps2: float,
                 initial_std_m: tuple[float, float, float] = (0.0, 0.0, 0.0)):
        """accel_density: s_a (m/s^2/sqrt(Hz)), one for all axes or one per axis."""
        self.accel_density = tuple(accel_density) if hasattr(accel_density, "__len__") else (accel_density,) * 3
        self.pos_std_m = pos_std_m
        self.gravity = gravity_mps2
        self.initial_variance_m2 = tuple(s * s for s in initial_std_m)
        self.reset()

    def reset(self) -> None:
        """Forget the position (kalman.resetEstimation): the next fix sets it again."""
        self.p = [0.0, 0.0, 0.0]
        self.v = [0.0, 0.0, 0.0]
        self.valid = False
        self.variance_m2 = self.initial_variance_m2  # per axis: the initial, then the fixes' posterior
        self._history = TimeHistory()  # (sample time, position) per update

    def predict(self, t_s: float, q, f_body, dt: float) -> None:
        if not self.valid:
            return
        ax, ay, az = rotate(quat_to_rows(q), *f_body)  # the specific force in the world frame
        az -= self.gravity
        p, v = self.p, self.v
        p[0] += v[0] * dt
        p[1] += v[1] * dt
        p[2] += v[2] * dt
        v[0] += ax * dt
        v[1] += ay * dt
        v[2] += az * dt
        self._history.append(t_s, (p[0], p[1], p[2]))

    def fuse(self, position_enu_m, time_s: float, dt_fix: float) -> None:
        if not self.valid:  # the first fix sets the position, at rest
            self.p = [float(c) for c in position_enu_m]
            self.v = [0.0, 0.0, 0.0]
            self.valid = True
            return
        if dt_fix <= 0.0:
            return
        then = self._history.at(time_s) or tuple(self.p)
        variances = []
        for k in range(3):
            w = math.sqrt(self.accel_density[k] / (self.pos_std_m * math.sqrt(dt_fix)))
            gain_p, gain_v = math.sqrt(2.0) * w * dt_fix, w * w * dt_fix
            variances.append(gain_p * self.pos_std_m**2)  # the posterior P = K R of the filter of that gain
            e = position_enu_m[k] - then[k]
            self.p[k] += gain_p * e
            self.v[k] += gain_v * e
        self.variance_m2 = tuple(variances)
