"""The complementary attitude filter (crazyflie-firmware src/modules/src/sensfusion6.c, Mahony's filter, the
default without CONFIG_IMU_MADGWICK_QUATERNION), run by estimator_complementary.c at 250 Hz.

Takes in: gyro (deg/s) and accelerometer (g) in the body frame (x forward, y left, z up), and dt (s).
Gives out: the attitude quaternion (w, x, y, z; body to world, not adjusted for the legacy frame) and the
Euler angles roll, pitch, yaw (deg) in the legacy frame (pitch = asin(gravity_x): positive nose up, the
opposite of the FLU pitch), as sensfusion6GetEulerRPY gives them.

The accelerometer pulls the estimated gravity direction toward the measured one (proportional twoKp,
integral twoKi on the error); yaw has no absolute reference here and drifts with the residual gyro bias, as
on a Crazyflie flying the complementary estimator without a position system.
"""

from __future__ import annotations

import math

from model.frames import quat_integrate

DEG = math.pi / 180.0


class Sensfusion6:
    def __init__(self, two_kp: float, two_ki: float):
        self.two_kp, self.two_ki = two_kp, two_ki
        self.q = [1.0, 0.0, 0.0, 0.0]
        self.integral = [0.0, 0.0, 0.0]

    def set_yaw_deg(self, yaw_deg: float) -> None:
        """Start level at a given heading (the firmware starts at identity; the emulator's vehicle may not)."""
        half = 0.5 * yaw_deg * DEG
        self.q = [math.cos(half), 0.0, 0.0, math.sin(half)]

    def update(self, gyro_dps, acc_g, dt_s: float, use_accelerometer: bool = True) -> None:
        gx, gy, gz = gyro_dps[0] * DEG, gyro_dps[1] * DEG, gyro_dps[2] * DEG
        ax, ay, az = acc_g
        qw, qx, qy, qz = self.q
        if use_accelerometer and not (ax == 0.0 and ay == 0.0 and az == 0.0):
            norm = 1.0 / math.sqrt(ax * ax + ay * ay + az * az)
            ax, ay, az = ax * norm, ay * norm, az * norm
            halfvx = qx * qz - qw * qy
            halfvy = qw * qx + qy * qz
            halfvz = qw * qw - 0.5 + qz * qz
            halfex = ay * halfvz - az * halfvy
            halfey = az * halfvx - ax * halfvz
            halfez = ax * halfvy - ay * halfvx
            if self.two_ki > 0.0:
                i = self.integral
                i[0] += self.two_ki * halfex * dt_s
                i[1] += self.two_ki * halfey * dt_s
                i[2] += self.two_ki * halfez * dt_s
                gx, gy, gz = gx + i[0], gy + i[1], gz + i[2]
            else:
                self.integral = [0.0, 0.0, 0.0]
            gx += self.two_kp * halfex
            gy += self.two_kp * halfey
            gz += self.two_kp * halfez
        gx, gy, gz = gx * 0.5 * dt_s, gy * 0.5 * dt_s, gz * 0.5 * dt_s
        qa, qb, qc = qw, qx, qy
        qw += -qb * gx - qc * gy - qz * gz
        qx += qa * gx + qc * gz - qz * gy
        qy += qa * gy - qb * gz + qz * gx
        qz += qa * gz + qb * gy - qc * gx
        norm = 1.0 / math.sqrt(qw * qw + qx * qx + qy * qy + qz * qz)
        self.q = [qw * norm, qx * norm, qy * norm, qz * norm]

    def rotate_body(self, rx: float, ry: float, rz: float) -> None:
        """q <- q (x) Exp((rx, ry, rz)): a small correction (rad) about the body axes."""
        self.q = list(quat_integrate(tuple(self.q), (rx, ry, rz), 1.0))

    def euler_rpy_deg(self) -> tuple[float, float, float]:
        """sensfusion6GetEulerRPY: roll, pitch (legacy sign), yaw in degrees."""
        qw, qx, qy, qz = self.q
        gx = 2.0 * (qx * qz - qw * qy)
        gy = 2.0 * (qw * qx + qy * qz)
        gz = qw * qw - qx * qx - qy * qy + qz * qz
        gx = min(max(gx, -1.0), 1.0)
        yaw = math.atan2(2.0 * (qw * qz + qx * qy), qw * qw + qx * qx - qy * qy - qz * qz) / DEG
        return math.atan2(gy, gz) / DEG, math.asin(gx) / DEG, yaw
