"""Motors: battery compensation and the motor-voltage thrust curve (crazyflie-firmware src/drivers/src/motors.c
motorsCompensateBatteryVoltage; the curve and limits of platform_defaults_cf2.h, CF 2.1+ propellers).

Takes in: a motor command in PWM units (0-65535, read as force: f = PWM / 65535 THRUST_MAX), the filtered
supply voltage the firmware measures (V), and for the physics the PWM ratio applied and the battery's
true terminal voltage (V).
Gives out: `compensate`: the PWM ratio (uncapped float) that gives force f at that supply voltage, 0 below
THRUST_MIN or a supply under 2 V; `thrust_n`: the force (N) a motor makes at PWM ratio r and battery
voltage V: v = V r / 65535, f = V0 + V1 v + V2 v^2 + V3 v^3 (never negative).

The inversion is the firmware's closed form of the cubic (Cardano: q, r, p as in motors.c), so that with
the measured voltage equal to the true one, thrust_n(compensate(PWM)) = PWM / 65535 THRUST_MAX: the command
is linear in force, the point of the compensation.
"""

from __future__ import annotations

import math
from dataclasses import dataclass


def _cbrt(x: float) -> float:
    return math.copysign(abs(x) ** (1.0 / 3.0), x)


@dataclass(frozen=True)
class ThrustCurve:
    v0: float
    v1: float
    v2: float
    v3: float
    thrust_min_n: float
    thrust_max_n: float
    pwm_max: int
    min_supply_v: float

    def thrust_n(self, pwm_ratio: float, battery_v: float) -> float:
        """Force (N) of one motor at PWM ratio pwm_ratio (0..pwm_max) on a battery at battery_v."""
        v = battery_v * pwm_ratio / self.pwm_max
        return max(0.0, self.v0 + v * (self.v1 + v * (self.v2 + v * self.v3)))

    def motor_voltage_v(self, thrust_n: float) -> float:
        """The motor voltage that makes thrust_n (the firmware's inversion of the cubic)."""
        p = -self.v2 / (3.0 * self.v3)
        q = p * p * p + (self.v2 * self.v1 - 3.0 * self.v3 * (self.v0 - thrust_n)) / (6.0 * self.v3 * self.v3)
        r = self.v1 / (3.0 * self.v3)
        qrp = math.sqrt(q * q + (r - p * p) ** 3)
        return _cbrt(q + qrp) + _cbrt(q - qrp) + p

    def compensate(self, pwm: float, supply_v: float) -> float:
        """motorsCompensateBatteryVoltage: the PWM ratio (uncapped) for command pwm at supply_v."""
        if supply_v < self.min_supply_v:
            return 0.0
        thrust = pwm / self.pwm_max * self.thrust_max_n
        if thrust < self.thrust_min_n:
            return 0.0
        return self.pwm_max * self.motor_voltage_v(thrust) / supply_v
