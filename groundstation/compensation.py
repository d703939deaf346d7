"""Latency compensation: predict the vehicle's state to the moment the command being computed will act.

Takes in: the newest estimate (on the vehicle's clock, so already a downlink latency old), the clock
offset and round-trip time from TIMESYNC, one-way frame ages, and the commands this ground station sent.
Gives out: a ControllerState at t_act = now + uplink latency, integrated on the vehicle model with the
commands that will be acting in between held as sent (they are in flight and cannot be changed).

Model (body FLU, world ENU; Lee et al. 2010 notation): m v' = T R e3 - m g e3, p' = v,
R' = R [w]x, I w' = M - w x I w. In attitude mode the vehicle's onboard loop is taken to hold the
commanded attitude as soon as a command acts (its bandwidth, ~20 rad/s, is far above the position loop's).
"""

from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass

from groundstation.controller import ControllerState
from link.vehicle import GRAVITY_MPS2, Vehicle

HISTORY_S = 1.0  # commands kept: longer than any round trip a flyable link has


@dataclass(frozen=True)
class SentCommand:
    sent_s: float  # ground-station clock
    thrust_n: float
    moment_flu_nm: tuple[float, float, float]
    attitude_wxyz: tuple[float, float, float, float]


class LatencyCompensator:
    def __init__(self, vehicle: Vehicle, mode: str, step_s: float):
        self.mode = mode
        self.step_s = step_s
        self.m = vehicle.mass_kg
        self.inertia = (vehicle.inertia_kgm2[0, 0], vehicle.inertia_kgm2[1, 1], vehicle.inertia_kgm2[2, 2])
        self.sent: deque[SentCommand] = deque()

    def record(self, sent_s: float, thrust_n: float, moment_flu_nm, attitude_wxyz) -> None:
        self.sent.append(SentCommand(sent_s, float(thrust_n), tuple(map(float, moment_flu_nm)),
                                     tuple(map(float, attitude_wxyz))))
        while self.sent and self.sent[0].sent_s < sent_s - HISTORY_S:
            self.sent.popleft()

    def predict(self, est, now_s: float, vehicle_minus_ground_s: float, uplink_latency_s: float) -> ControllerState:
        """State at now + uplink latency, from the estimate at est.time_s (vehicle clock)."""
        t = est.time_s - vehicle_minus_ground_s  # the estimate's time on our clock
        t_act = now_s + uplink_latency_s
        p = [float(v) for v in est.position_enu_m]
        v = [float(x) for x in est.velocity_enu_mps]
        q = [float(x) for x in est.attitude_wxyz]
        w = [float(x) for x in est.rate_flu_radps]
        while t < t_act - 1e-12:
            dt = min(self.step_s, t_act - t)
            command = self._acting_at(t, uplink_latency_s)
            if command is not None:
                p, v, q, w = self._step(p, v, q, w, command, dt)
            else:  # nothing of ours acts yet: coast
                p = [p[i] + v[i] * dt for i in range(3)]
            t += dt
        return ControllerState(position_enu_m=tuple(p), velocity_enu_mps=tuple(v), attitude_wxyz=tuple(q),
                               rate_flu_radps=tuple(w))

    def _acting_at(self, t: float, uplink_latency_s: float) -> SentCommand | None:
        """The newest command that has reached the vehicle by time t (our clock)."""
        acting = None
        for command in reversed(self.sent):
            if command.sent_s + uplink_latency_s <= t + 1e-12:
                acting = command
                break
        return acting

    def _step(self, p, v, q, w, c: SentCommand, dt: float):
        if self.mode == "attitude":
            q = list(c.attitude_wxyz)
            w = [0.0, 0.0, 0.0]
        else:
            ix, iy, iz = self.inertia
            mx, my, mz = c.moment_flu_nm
            wx, wy, wz = w
            w = [wx + dt * (mx - (iz - iy) * wy * wz) / ix,
                 wy + dt * (my - (ix - iz) * wz * wx) / iy,
                 wz + dt * (mz - (iy - ix) * wx * wy) / iz]
            q = _integrate_quat(q, w, dt)
        qw, qx, qy, qz = q
        b3 = (2.0 * (qx * qz + qw * qy), 2.0 * (qy * qz - qw * qx), 1.0 - 2.0 * (qx * qx + qy * qy))
        a = [c.thrust_n / self.m * b3[0], c.thrust_n / self.m * b3[1], c.thrust_n / self.m * b3[2] - GRAVITY_MPS2]
        p = [p[i] + dt * v[i] + 0.5 * dt * dt * a[i] for i in range(3)]
        v = [v[i] + dt * a[i] for i in range(3)]
        return p, v, q, w


def _integrate_quat(q, w, dt: float):
    """q (x) exp(w dt / 2): the exact rotation for a rate held over dt."""
    wx, wy, wz = w
    angle = math.sqrt(wx * wx + wy * wy + wz * wz) * dt
    if angle < 1e-12:
        return q
    s = math.sin(angle / 2.0) / (angle / dt)
    dw, dx, dy, dz = math.cos(angle / 2.0), wx * s, wy * s, wz * s
    qw, qx, qy, qz = q
    out = [qw * dw - qx * dx - qy * dy - qz * dz, qw * dx + qx * dw + qy * dz - qz * dy,
           qw * dy - qx * dz + qy * dw + qz * dx, qw * dz + qx * dy - qy * dx + qz * dw]
    n = math.sqrt(sum(c * c for c in out))
    return [c / n for c in out]
