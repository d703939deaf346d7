"""The faithful firmware's drive chain, compiled: battery compensation, the cap, the motor forces on the
battery's voltage, the battery's draw and the rotor speeds, once per 500 Hz stabilizer cycle (issue 19); and
the force-torque mixer's commands before it (moments mode).

Takes in: the firmware's thrust curve, PWM limits, supply filter, battery, cycle and k_T (drive_constants
packs them in the compiled kernel's order); per cycle the uncapped motor commands (4 ints, PWM units), the
filtered supply voltage (V), the battery's terminal voltage (V) and charge drawn (A s).
Gives out: `drive`, the compiled kernel (simulator/crazyflie/_drive_kernel.c, built by `pip install`), or
None where it was not built; it returns (PWM, forces N, rotor speeds rad/s or None for motors off, supply
V, battery V, current A, charge drawn A s), or None for a cycle it leaves to the Python.
`force_torque_pwm` (thrust N, torques N m FLU, the mixer's constants) -> the four uncapped commands, or None
likewise.

The Python is CrazyflieFirmware._drive_python (stabilizer.py, through motors.ThrustCurve,
power_distribution.cap and battery.Battery) and ForceTorqueMixer.pwm_python; the kernels give their bits
(tests/simulator/test_drive_kernel.py). Why compiled: the drive chain's Python took 15.5 us per cycle (1.6
compiled), the largest part of the faithful firmware's extra work over the ideal firmware's (README:
Lockstep speed).
"""

from __future__ import annotations

from simulator.crazyflie.battery import Battery
from simulator.crazyflie.motors import ThrustCurve

try:
    from simulator.crazyflie._drive_kernel import drive, force_torque_pwm
except ImportError:  # not built (no C compiler at install): the firmware runs its Python, same results, slower
    drive = force_torque_pwm = None

COMPILED = drive is not None


def drive_constants(curve: ThrustCurve, idle_pwm: int, supply_b: float, battery: Battery, cycle_s: float,
                    k_thrust: float) -> tuple[float, ...]:
    """The kernel's constants, in _drive_kernel.c's order (its enum)."""
    return tuple(float(v) for v in (
        curve.v0, curve.v1, curve.v2, curve.v3, curve.thrust_min_n, curve.thrust_max_n, curve.pwm_max,
        curve.min_supply_v, idle_pwm, supply_b,
        battery.empty_v, battery.full_v, battery.capacity_as, battery.r_ohm, battery.motor_hover_w,
        battery.motor_hover_n, battery.k, cycle_s, k_thrust))
