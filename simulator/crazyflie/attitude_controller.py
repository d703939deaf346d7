"""The attitude and rate PIDs (crazyflie-firmware controller/attitude_pid_controller.c), at ATTITUDE_RATE.

Takes in: the gains (simulator/params/crazyflie.toml [pid_attitude], [pid_rate]) and the update period
(1 / 500 Hz); per update the actual and desired roll, pitch, yaw (deg, legacy frame: pitch positive nose
up), then the actual and desired body rates (deg/s, the same legacy signs).
Gives out: the desired rates (deg/s) from the attitude PIDs, and the roll, pitch, yaw actuator outputs
(int16 "PWM delta", saturated to +-32767 and truncated toward zero as saturateSignedInt16 does) from the
rate PIDs. Each three PIDs run compiled (pid_kernel) where the kernel was built, with the same bits.
"""

from __future__ import annotations

from collections.abc import Sequence

from simulator.crazyflie.pid import Pid
from simulator.crazyflie.pid_kernel import update3

INT16_MAX = 32767


def saturate_int16(value: float) -> int:
    """saturateSignedInt16: +-INT16_MAX (not INT16_MIN, which a later negation would overflow), then the C
    cast, which truncates toward zero."""
    if value > INT16_MAX:
        return INT16_MAX
    if value < -INT16_MAX:
        return -INT16_MAX
    return int(value)


class AttitudeController:
    def __init__(self, attitude_gains: dict, rate_gains: dict, dt_s: float):
        self.attitude = _pids(attitude_gains, dt_s)  # roll, pitch, yaw: deg -> deg/s
        self.rate = _pids(rate_gains, dt_s)  # roll, pitch, yaw: deg/s -> int16

    def correct_attitude(self, actual_deg: Sequence[float], desired_deg: Sequence[float]) -> tuple[float, ...]:
        """The desired rates (deg/s): compiled (pid_kernel) where it was built, else correct_attitude_python."""
        if update3 is not None:
            rates = update3(self.attitude, desired_deg, actual_deg, True, False)
            if rates is not None:
                return rates
        return self.correct_attitude_python(actual_deg, desired_deg)

    def correct_rate(self, actual_dps: Sequence[float], desired_dps: Sequence[float]) -> tuple[int, int, int]:
        """The roll, pitch, yaw outputs (int16): compiled (pid_kernel) where it was built, else correct_rate_python."""
        if update3 is not None:
            outputs = update3(self.rate, desired_dps, actual_dps, False, True)
            if outputs is not None:
                return outputs
        return self.correct_rate_python(actual_dps, desired_dps)

    def correct_attitude_python(self, actual_deg: Sequence[float], desired_deg: Sequence[float]) -> tuple[float, ...]:
        """correct_attitude in Python (the compiled kernel's twin, and what runs where it was not built)."""
        roll, pitch, yaw = self.attitude
        return (roll.update(desired_deg[0], actual_deg[0]), pitch.update(desired_deg[1], actual_deg[1]),
                yaw.update(desired_deg[2], actual_deg[2], is_yaw_angle=True))

    def correct_rate_python(self, actual_dps: Sequence[float], desired_dps: Sequence[float]) -> tuple[int, int, int]:
        """correct_rate in Python (the compiled kernel's twin, and what runs where it was not built)."""
        roll, pitch, yaw = self.rate
        return (saturate_int16(roll.update(desired_dps[0], actual_dps[0])),
                saturate_int16(pitch.update(desired_dps[1], actual_dps[1])),
                saturate_int16(yaw.update(desired_dps[2], actual_dps[2])))

    def reset_all(self, roll_deg: float, pitch_deg: float, yaw_deg: float) -> None:
        """attitudeControllerResetAllPID: the angle PIDs from the actual angles, the rate PIDs from 0."""
        for pid, actual in zip(self.attitude, (roll_deg, pitch_deg, yaw_deg), strict=True):
            pid.reset(actual)
        for pid in self.rate:
            pid.reset(0.0)


def _pids(gains: dict, dt_s: float) -> tuple[Pid, Pid, Pid]:
    return tuple(Pid(gains["kp"][i], gains["ki"][i], gains["kd"][i], dt_s, gains["integration_limit"][i])
                 for i in range(3))
