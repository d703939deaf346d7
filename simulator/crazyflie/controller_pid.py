"""The PID controller's flow (crazyflie-firmware controller/controller_pid.c, controllerPid), at 500 Hz.

Takes in: per tick (ATTITUDE_RATE) a Setpoint (per-axis modes; roll/pitch/yaw in deg with the legacy pitch
sign; rates in deg/s; thrust in PWM units 0-65535), the onboard estimate's roll, pitch, yaw (deg, legacy)
and the gyro (deg/s, body x forward, y left, z up: the sensor's own signs).
Gives out: a legacy Control: thrust (PWM units) and roll, pitch, yaw (int16) for the legacy mixer.

As in controller_pid.c:
- a change of any axis' mode resets every PID and sets the desired roll and pitch to the actual ones
  ("to prevent control bump");
- yaw in velocity mode integrates the desired yaw: yaw_des += yaw_rate dt, wrapped to +-180 deg; yaw in
  absolute mode takes the setpoint's yaw;
- with x, y disabled the desired roll and pitch are the setpoint's; with z disabled the thrust is;
- roll or pitch in velocity mode overwrite the attitude PID's rate with the setpoint's rate;
- the rate PIDs read (gyro.x, -gyro.y, gyro.z) (the legacy pitch sign) and the yaw output is negated;
- a thrust of 0 zeroes the outputs, resets the PIDs and sets the desired yaw to the actual yaw.
- with x, y or z absolute or in velocity mode, the position and velocity PIDs (position_controller.py) run
  on every fifth tick (POSITION_RATE 100 Hz) and give the desired roll and pitch and the thrust, from the
  onboard position estimate.
"""

from __future__ import annotations

from dataclasses import dataclass

from simulator.crazyflie.attitude_controller import AttitudeController
from simulator.crazyflie.position_controller import PositionController

MODE_DISABLE, MODE_ABS, MODE_VELOCITY = 0, 1, 2


@dataclass(frozen=True)
class Setpoint:
    """setpoint_t, the part the attitude controller reads. Modes per axis: x, y, z, roll, pitch, yaw."""

    modes: tuple[int, int, int, int, int, int]
    attitude_deg: tuple[float, float, float] = (0.0, 0.0, 0.0)  # roll, pitch (legacy), yaw
    attitude_rate_dps: tuple[float, float, float] = (0.0, 0.0, 0.0)
    thrust_pwm: float = 0.0
    position_m: tuple[float, float, float] = (0.0, 0.0, 0.0)  # world ENU, for x, y, z in absolute mode
    velocity_mps: tuple[float, float, float] = (0.0, 0.0, 0.0)  # for x, y, z in velocity mode
    velocity_body: bool = False  # velocity x, y in the yaw frame (the hover setpoint), else world ENU


@dataclass(frozen=True)
class LegacyControl:
    thrust_pwm: float
    roll: int
    pitch: int
    yaw: int


ZERO_CONTROL = LegacyControl(0.0, 0, 0, 0)


def _cap_angle(angle_deg: float) -> float:
    while angle_deg > 180.0:
        angle_deg -= 360.0
    while angle_deg < -180.0:
        angle_deg += 360.0
    return angle_deg


class ControllerPid:
    def __init__(self, attitude: AttitudeController, dt_s: float, position: PositionController | None = None,
                 position_every: int = 5):
        self.attitude = attitude
        self.position = position
        self.position_every = position_every  # ATTITUDE_RATE / POSITION_RATE
        self.dt_s = dt_s
        self.desired_deg = [0.0, 0.0, 0.0]
        self._previous_modes: tuple[int, ...] | None = None  # None: the first tick resets, as the zero-init does
        self._tick = 0
        self._position_output = (0.0, 0.0, 0.0)  # roll deg, pitch deg, thrust PWM from the position loop

    def reinitialize(self, state_deg, position_state=None) -> None:
        """controllerPidReinitialize: the position PIDs from the estimate, the attitude PIDs from the angles."""
        if self.position is not None and position_state is not None:
            self.position.reset(*position_state)
        self.attitude.reset_all(*state_deg)
        self.desired_deg[0], self.desired_deg[1] = state_deg[0], state_deg[1]

    def update(self, sp: Setpoint, state_deg, gyro_dps, position_state=None) -> LegacyControl:
        """One 500 Hz tick; position_state = (position m, velocity m/s), world ENU, for absolute x, y, z."""
        if sp.modes != self._previous_modes:
            self._previous_modes = sp.modes
            self.reinitialize(state_deg, position_state)
        desired = self.desired_deg
        yaw_mode = sp.modes[5]
        if yaw_mode == MODE_VELOCITY:
            desired[2] = _cap_angle(desired[2] + sp.attitude_rate_dps[2] * self.dt_s)
        elif yaw_mode == MODE_ABS:
            desired[2] = sp.attitude_deg[2]
        desired[2] = _cap_angle(desired[2])
        x_mode, y_mode, z_mode = sp.modes[0], sp.modes[1], sp.modes[2]
        position_loop = (x_mode, y_mode, z_mode) != (MODE_DISABLE,) * 3 and self.position is not None
        if position_loop and self._tick % self.position_every == 0:
            self._position_output = self.position.update(sp.position_m, position_state[0], position_state[1],
                                                         state_deg[2], (x_mode, y_mode, z_mode), sp.velocity_mps,
                                                         sp.velocity_body)
        self._tick += 1
        roll_pos, pitch_pos, thrust_pos = self._position_output
        thrust = sp.thrust_pwm if z_mode == MODE_DISABLE or not position_loop else thrust_pos
        if x_mode == MODE_DISABLE or y_mode == MODE_DISABLE or not position_loop:
            desired[0], desired[1] = sp.attitude_deg[0], sp.attitude_deg[1]
        else:
            desired[0], desired[1] = roll_pos, pitch_pos
        rates = list(self.attitude.correct_attitude(state_deg, desired))
        if sp.modes[3] == MODE_VELOCITY:
            rates[0] = sp.attitude_rate_dps[0]
        if sp.modes[4] == MODE_VELOCITY:
            rates[1] = sp.attitude_rate_dps[1]
        roll, pitch, yaw = self.attitude.correct_rate((gyro_dps[0], -gyro_dps[1], gyro_dps[2]), rates)
        if thrust == 0.0:
            self.reinitialize(state_deg, position_state)
            desired[2] = state_deg[2]
            return ZERO_CONTROL
        return LegacyControl(thrust, roll, pitch, -yaw)
