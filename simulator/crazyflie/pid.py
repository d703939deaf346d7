"""The firmware's PID object (crazyflie-firmware src/utils/src/pid.c, pidUpdate and pidReset).

Takes in: the gains, the update period dt (s), the integral limit and output limit (0 = none), then per
update the desired and the measured value (in the caller's units: deg or deg/s here).
Gives out: kp e + kd (-(measured - previous measured) / dt) + ki clamp(sum e dt) + kff desired, clamped to
the output limit when it is nonzero.

As in pid.c: the derivative acts on the measurement, not the error (no kick when the setpoint jumps); a yaw
angle wraps the error and the measurement step to +-180 deg; the integral is clamped to +-iLimit (unless 0);
the derivative low-pass filter is off for the attitude and rate PIDs (ATTITUDE_LPF_ENABLE and
ATTITUDE_RATE_LPF_ENABLE are false in platform_defaults.h), so it is not modelled.
"""

from __future__ import annotations


def _wrap_deg(angle: float) -> float:
    if angle > 180.0:
        return angle - 360.0
    if angle < -180.0:
        return angle + 360.0
    return angle


class Pid:
    __slots__ = ("kp", "ki", "kd", "kff", "dt_s", "i_limit", "output_limit", "integ", "prev_measured",
                 "out_p", "out_i", "out_d")

    def __init__(self, kp: float, ki: float, kd: float, dt_s: float, i_limit: float,
                 output_limit: float = 0.0, kff: float = 0.0):
        self.kp, self.ki, self.kd, self.kff = kp, ki, kd, kff
        self.dt_s = dt_s
        self.i_limit = i_limit
        self.output_limit = output_limit
        self.integ = 0.0
        self.prev_measured = 0.0
        self.out_p = self.out_i = self.out_d = 0.0

    def update(self, desired: float, measured: float, is_yaw_angle: bool = False) -> float:
        error = desired - measured
        delta = -(measured - self.prev_measured)
        if is_yaw_angle:
            error = _wrap_deg(error)
            delta = _wrap_deg(delta)
        self.out_p = self.kp * error
        self.out_d = self.kd * delta / self.dt_s
        integ = self.integ + error * self.dt_s
        if self.i_limit != 0.0:
            integ = min(max(integ, -self.i_limit), self.i_limit)
        self.integ = integ
        self.out_i = self.ki * integ
        output = self.out_p + self.out_d + self.out_i + self.kff * desired
        if self.output_limit != 0.0:
            output = min(max(output, -self.output_limit), self.output_limit)
        self.prev_measured = measured
        return output

    def reset(self, actual: float) -> None:
        """pidReset: zero integral and derivative history, the next derivative measured from `actual`."""
        self.integ = 0.0
        self.prev_measured = actual
