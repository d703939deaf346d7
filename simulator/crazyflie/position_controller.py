"""The position and velocity PIDs (crazyflie-firmware controller/position_controller_pid.c), at 100 Hz.

Takes in: the [position_controller] gains of simulator/params/crazyflie.toml; per update the desired
position (m, world) or, per axis in velocity mode, the desired velocity (m/s, world or yaw frame), the
estimated position and velocity (m, m/s, world) and the estimated yaw (deg).
Gives out: the desired roll and pitch (deg, legacy frame: pitch positive nose up) and the thrust (PWM units).

As in the firmware: positions and velocities are turned into the yaw frame (body x forward, y left, level);
the position PIDs give a velocity setpoint (limited to the max speed x 1.10); the velocity PIDs give
pitch = -PID(vx), roll = -PID(vy) (limited to 20 deg x 1.10, then to 20 deg) and
thrust = PID(vz) thrustScale + thrustBase, at least thrustMin, within 0..65535.
"""

from __future__ import annotations

import math

from simulator.crazyflie.pid import Pid

MODE_ABS = 1  # controller_pid.MODE_ABS (stabilizer_types.h modeAbs)


class PositionController:
    def __init__(self, gains: dict, dt_s: float):
        g = gains
        over = g["limit_overhead"]
        limit = g["integration_limit"]
        vmax = g["velocity_max_mps"]
        self.position = [Pid(g["position_kp"][i], g["position_ki"][i], 0.0, dt_s, limit,
                             output_limit=max(vmax[i], 0.5 if i == 2 else 0.0) * over) for i in range(3)]
        self.rp_max = g["roll_pitch_max_deg"]
        self.velocity = [Pid(g["velocity_kp"][i], g["velocity_ki"][i], 0.0, dt_s, limit,
                             output_limit=self.rp_max * over) for i in range(2)]
        self.velocity.append(Pid(g["velocity_kp"][2], g["velocity_ki"][2], 0.0, dt_s, limit,
                                 output_limit=65535 / 2 / g["thrust_scale"]))
        self.thrust_base, self.thrust_min, self.thrust_scale = (g["thrust_base_pwm"], g["thrust_min_pwm"],
                                                                g["thrust_scale"])

    def reset(self, position, velocity) -> None:
        for pid, actual in zip(self.position, position, strict=True):
            pid.reset(actual)
        for pid, actual in zip(self.velocity, velocity, strict=True):
            pid.reset(actual)

    def update(self, desired_m, position_m, velocity_mps, yaw_deg: float, modes=(1, 1, 1),
               desired_velocity_mps=(0.0, 0.0, 0.0), velocity_body: bool = False) -> tuple[float, float, float]:
        """(roll deg, pitch deg legacy, thrust PWM). Per axis (modes x, y, z: 1 absolute, else velocity) the
        position PID gives the velocity setpoint, or the setpoint's own velocity is flown: world x, y turned
        into the yaw frame unless velocity_body (positionController)."""
        c, s = math.cos(math.radians(yaw_deg)), math.sin(math.radians(yaw_deg))
        body = _to_yaw_frame
        sp_x, sp_y = body(desired_m, c, s)
        st_x, st_y = body(position_m, c, s)
        yaw_frame_vx, yaw_frame_vy = (desired_velocity_mps[0], desired_velocity_mps[1]) if velocity_body else \
            body(desired_velocity_mps, c, s)
        vx_sp = self.position[0].update(sp_x, st_x) if modes[0] == MODE_ABS else yaw_frame_vx
        vy_sp = self.position[1].update(sp_y, st_y) if modes[1] == MODE_ABS else yaw_frame_vy
        vz_sp = self.position[2].update(desired_m[2], position_m[2]) if modes[2] == MODE_ABS \
            else desired_velocity_mps[2]
        vx, vy = body(velocity_mps, c, s)
        pitch = -self.velocity[0].update(vx_sp, vx)
        roll = -self.velocity[1].update(vy_sp, vy)
        roll = min(max(roll, -self.rp_max), self.rp_max)
        pitch = min(max(pitch, -self.rp_max), self.rp_max)
        thrust = self.velocity[2].update(vz_sp, velocity_mps[2]) * self.thrust_scale + self.thrust_base
        thrust = min(max(max(thrust, self.thrust_min), 0.0), 65535.0)
        return roll, pitch, thrust


def _to_yaw_frame(v, c: float, s: float) -> tuple[float, float]:
    return v[0] * c + v[1] * s, -v[0] * s + v[1] * c
