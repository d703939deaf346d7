"""The battery: open-circuit voltage from the charge drawn, and the sag under load.

Takes in: capacity (mAh), full and empty open-circuit voltages (V) from the vehicle TOML; the internal
resistance (ohm) and the per-motor power law from simulator/params/crazyflie.toml [battery]; per step the
four motor forces (N) and the step (s).
Gives out: the terminal voltage V (what pm.vbat measures and what drives the motors), the current (A) and
the charge left (0..1).

Electrical power of motor i: P_i = (V_nominal I_hover / 4) (f_i / (T_hover / 4))^k (momentum theory,
k = 1.5), so the hover draw is the datasheet's 250 mAh in 7 min. The current I = P / V, with the terminal
voltage V = V_oc - R I: V = (V_oc + sqrt(V_oc^2 - 4 R P)) / 2. The open-circuit voltage falls linearly from
full to empty with the charge drawn.
"""

from __future__ import annotations

import math

SECONDS_PER_HOUR = 3600.0
MA_PER_A = 1000.0


class Battery:
    def __init__(self, capacity_mah: float, full_v: float, empty_v: float, internal_resistance_ohm: float,
                 hover_current_a: float, hover_thrust_n: float, nominal_voltage_v: float, power_exponent: float):
        self.capacity_as = capacity_mah / MA_PER_A * SECONDS_PER_HOUR
        self.full_v, self.empty_v = full_v, empty_v
        self.r_ohm = internal_resistance_ohm
        self.motor_hover_w = nominal_voltage_v * hover_current_a / 4.0
        self.motor_hover_n = hover_thrust_n / 4.0
        self.k = power_exponent
        self.drawn_as = 0.0
        self.current_a = 0.0
        self.voltage_v = full_v

    @property
    def charge_left(self) -> float:
        return max(0.0, 1.0 - self.drawn_as / self.capacity_as)

    @property
    def open_circuit_v(self) -> float:
        return self.empty_v + (self.full_v - self.empty_v) * self.charge_left

    def power_w(self, forces_n) -> float:
        per_n, k = 1.0 / self.motor_hover_n, self.k
        total = 0.0  # summed in motor order, one addition at a time (the compiled drive kernel does the same)
        for f in forces_n:
            total += (max(f, 0.0) * per_n) ** k
        return self.motor_hover_w * total

    def step(self, forces_n, dt_s: float) -> float:
        """Draw the motors' power for dt_s; the terminal voltage (V) under that load."""
        v_oc = self.open_circuit_v
        power = self.power_w(forces_n)
        disc = v_oc * v_oc - 4.0 * self.r_ohm * power
        v = 0.5 * (v_oc + math.sqrt(disc)) if disc > 0.0 else 0.5 * v_oc  # beyond the maximum power point
        self.voltage_v = v
        self.current_a = power / v if v > 0.0 else 0.0
        self.drawn_as += self.current_a * dt_s
        return v
