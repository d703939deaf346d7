"""The legacy roll/pitch/yaw-rate/thrust setpoint (crazyflie-firmware src/modules/src/crtp_commander_rpyt.c,
crtpCommanderRpytDecodeSetpoint), as cflib's `commander.send_setpoint(roll, pitch, yawrate, thrust)` sends it.

Takes in: roll and pitch (deg, legacy frame: pitch positive nose up), yaw rate (deg/s) and thrust (uint16 PWM
units) of one packet, and whether the commander's priority is DISABLE (nothing commanding: the lock re-arms).
Gives out: the Setpoint the PID controller flies (controller_pid.py).

As in the firmware with its default flight modes (stabilizationModeRoll/Pitch ANGLE, Yaw RATE, X mode, no
altitude/position hold; the parameters flightmode.stabModeRoll/Pitch/Yaw, 0 rate, 1 angle, choose for each
axis, e.g. stabModeYaw 1 makes the yaw field an absolute heading in degrees):
- thrust lock: after start-up (and whenever the commander's priority fell back to DISABLE) thrust stays 0
  until a packet with thrust 0 arrives, so a stale joystick cannot spin the motors up;
- thrust below MIN_THRUST (1000) is 0; above MAX_THRUST (60000) it is capped;
- roll and pitch are absolute angles; the yaw rate is inverted ("legacy rate input is inverted");
- x, y and z are disabled (thrust comes from the packet).
"""

from __future__ import annotations

from simulator.crazyflie.controller_pid import MODE_ABS, MODE_DISABLE, MODE_VELOCITY, Setpoint

MIN_THRUST = 1000
MAX_THRUST = 60000
RPYT_MODES = (MODE_DISABLE, MODE_DISABLE, MODE_DISABLE, MODE_ABS, MODE_ABS, MODE_VELOCITY)


ANGLE, RATE = 1, 0  # flightmode.stabMode* values (crtp_commander_rpyt.c RPYType)


class RpytDecoder:
    def __init__(self):
        self.thrust_locked = True
        self.stab_mode = {"roll": ANGLE, "pitch": ANGLE, "yaw": RATE}  # flightmode.stabModeRoll/Pitch/Yaw

    def decode(self, roll_deg: float, pitch_deg: float, yaw: float, thrust: int,
               priority_disabled: bool = False) -> Setpoint:
        """`yaw` is a rate (deg/s, inverted) or, with stabModeYaw ANGLE, a heading (deg)."""
        if priority_disabled:
            self.thrust_locked = True
        if thrust == 0:
            self.thrust_locked = False
        if self.thrust_locked or thrust < MIN_THRUST:
            thrust_pwm = 0.0
        else:
            thrust_pwm = float(min(thrust, MAX_THRUST))
        modes = self.stab_mode
        if modes["roll"] == ANGLE and modes["pitch"] == ANGLE and modes["yaw"] == RATE:  # the default, fast
            return Setpoint(RPYT_MODES, (float(roll_deg), float(pitch_deg), 0.0), (0.0, 0.0, -float(yaw)),
                            thrust_pwm)
        angles, rates = [0.0, 0.0, 0.0], [0.0, 0.0, 0.0]
        axis_modes = []
        for i, (axis, value) in enumerate((("roll", roll_deg), ("pitch", pitch_deg), ("yaw", yaw))):
            if modes[axis] == ANGLE:
                angles[i] = float(value)
                axis_modes.append(MODE_ABS)
            else:
                rates[i] = -float(value) if axis == "yaw" else float(value)  # legacy yaw rate input is inverted
                axis_modes.append(MODE_VELOCITY)
        return Setpoint((MODE_DISABLE, MODE_DISABLE, MODE_DISABLE, *axis_modes), tuple(angles), tuple(rates),
                        thrust_pwm)
