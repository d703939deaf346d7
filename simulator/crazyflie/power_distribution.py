"""Power distribution (crazyflie-firmware src/modules/src/power_distribution_quadrotor.c), at 500 Hz.

Takes in: a legacy Control (thrust in PWM units, roll/pitch/yaw int16), or a force-torque command (collective
thrust N, body torques N m, FLU), and the [power] constants of simulator/params/crazyflie.toml.
Gives out: four uncapped motor commands (int32 PWM units, motors M1..M4 = front-right, back-right, back-left,
front-left), and `cap` turns battery-compensated ones into the four uint16 PWM ratios sent to the motors.

Legacy (X): r = roll/2, p = pitch/2 (int16, truncated), m1 = T - r + p + yaw, m2 = T - r - p - yaw,
m3 = T + r - p + yaw, m4 = T + r + p - yaw.
Force-torque: per motor f = T/4 -+ tau_x/(4 arm) -+ tau_y/(4 arm) -+ tau_z/(4 THRUST2TORQUE), arm = 0.707
ARM_LENGTH; a negative force becomes 0; PWM = f / THRUST_MAX * 65535.
Cap (powerDistributionCap): when the highest motor exceeds 65535, all four are shifted down by the excess
(the differences, hence the attitude torques, are kept; thrust gives way), then floored at the idle thrust.
"""

from __future__ import annotations

import math

from simulator.crazyflie import drive_kernel
from simulator.crazyflie.controller_pid import LegacyControl

SQRT_HALF = 0.707106781  # the firmware's literal (0.707106781f)


def _int32(value: float) -> int:
    """C float -> int32 conversion: truncation toward zero."""
    return int(value) if math.isfinite(value) else 0


def legacy(control: LegacyControl) -> tuple[int, int, int, int]:
    r = int(control.roll / 2.0)  # int16_t r = control->roll / 2.0f
    p = int(control.pitch / 2.0)
    t, y = control.thrust_pwm, control.yaw
    return (_int32(t - r + p + y), _int32(t - r - p - y), _int32(t + r - p + y), _int32(t + r + p - y))


class ForceTorqueMixer:
    def __init__(self, arm_length_m: float, thrust_to_torque_m: float, thrust_max_n: float, pwm_max: int):
        self.arm_m = SQRT_HALF * arm_length_m
        self.thrust_to_torque_m = thrust_to_torque_m
        self.pwm_per_n = pwm_max / thrust_max_n
        # pwm's compiled twin takes these (simulator/crazyflie/_drive_kernel.c); None: pwm_python runs
        self._compiled = (0.25 / self.arm_m, float(thrust_to_torque_m), self.pwm_per_n) if drive_kernel.COMPILED \
            else None

    def forces_n(self, thrust_n: float, torque_flu_nm) -> tuple[float, float, float, float]:
        """The per-motor forces before clipping (N)."""
        roll = 0.25 / self.arm_m * torque_flu_nm[0]
        pitch = 0.25 / self.arm_m * torque_flu_nm[1]
        yaw = 0.25 * torque_flu_nm[2] / self.thrust_to_torque_m
        t = 0.25 * thrust_n
        return (t - roll - pitch - yaw, t - roll + pitch + yaw, t + roll + pitch - yaw, t + roll - pitch + yaw)

    def pwm(self, thrust_n: float, torque_flu_nm) -> tuple[int, int, int, int]:
        """The uncapped motor commands (PWM units): compiled where it was built, else pwm_python (the same)."""
        if self._compiled is not None:
            out = drive_kernel.force_torque_pwm(thrust_n, torque_flu_nm, self._compiled)
            if out is not None:
                return out
        return self.pwm_python(thrust_n, torque_flu_nm)

    def pwm_python(self, thrust_n: float, torque_flu_nm) -> tuple[int, int, int, int]:
        scale = self.pwm_per_n
        f0, f1, f2, f3 = self.forces_n(thrust_n, torque_flu_nm)  # written out: 500 Hz, on the emulator's every tick
        return (_int32(max(f0, 0.0) * scale), _int32(max(f1, 0.0) * scale), _int32(max(f2, 0.0) * scale),
                _int32(max(f3, 0.0) * scale))


def cap(uncapped, pwm_max: int, idle_pwm: int) -> tuple[int, int, int, int]:
    """powerDistributionCap: shift all motors down by the excess of the highest over pwm_max, floor at idle."""
    reduction = max(0, max(uncapped) - pwm_max)
    return tuple(max(m - reduction, idle_pwm) for m in uncapped)
