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

from collections import deque
from dataclasses import dataclass

from groundstation.compensation_kernel import predict_steps, step_constants
from groundstation.controller import ControllerState, as_floats
from model.frames import quat_integrate
from model.vehicle import GRAVITY_MPS2, Vehicle

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
        self.m = float(vehicle.mass_kg)
        # Python floats: arithmetic on numpy scalars is several times slower.
        self.inertia = tuple(float(vehicle.inertia_kgm2[k, k]) for k in range(3))
        self.sent: deque[SentCommand] = deque()
        self._constants = step_constants(step_s, self.m, self.inertia)  # the compiled steps' (compensation_kernel)

    def record(self, sent_s: float, thrust_n: float, moment_flu_nm, attitude_wxyz) -> None:
        self.sent.append(SentCommand(sent_s, float(thrust_n), tuple(map(float, moment_flu_nm)),
                                     tuple(map(float, attitude_wxyz))))
        while self.sent and self.sent[0].sent_s < sent_s - HISTORY_S:
            self.sent.popleft()

    def predict(self, est, now_s: float, vehicle_minus_ground_s: float, uplink_latency_s: float) -> ControllerState:
        """State at now + uplink latency, from the estimate at est.time_s (vehicle clock).

        Runs every control tick, a few model steps each: the steps are compiled (compensation_kernel), with
        _steps_python as their twin.
        """
        t = est.time_s - vehicle_minus_ground_s  # the estimate's time on our clock
        t_act = now_s + uplink_latency_s
        state = (*as_floats(est.position_enu_m), *as_floats(est.velocity_enu_mps), *as_floats(est.attitude_wxyz),
                 *as_floats(est.rate_flu_radps))
        acting, pending = self._acting_and_pending(t, uplink_latency_s)
        x = None
        if predict_steps is not None:
            x = predict_steps(t, t_act, state, acting, pending, uplink_latency_s, self._constants,
                              self.mode == "attitude")
        if x is None:  # not built, or a prediction the kernel leaves to the Python (its errors included)
            x = self._steps_python(t, t_act, state, acting, pending, uplink_latency_s)
        return ControllerState(position_enu_m=x[0:3], velocity_enu_mps=x[3:6], attitude_wxyz=x[6:10],
                               rate_flu_radps=x[10:13])

    def _steps_python(self, t: float, t_act: float, state: tuple, acting: SentCommand | None,
                      pending: list[SentCommand], uplink_latency_s: float) -> tuple:
        """The state at t_act from `state` at t (13 floats: position, velocity, attitude wxyz, rate), the
        commands acting in between held as sent; the compiled kernel's twin. Written on local floats (a
        numpy call on a 3-vector costs more than the step's arithmetic)."""
        px, py, pz, vx, vy, vz = state[0:6]
        q, w = state[6:10], state[10:13]
        attitude_mode = self.mode == "attitude"
        step_s, m = self.step_s, self.m
        arrived, count = 0, len(pending)  # pending is in sending order, and t only grows: one forward pass
        while t < t_act - 1e-12:
            dt = min(step_s, t_act - t)
            while arrived < count and pending[arrived].sent_s + uplink_latency_s <= t + 1e-12:
                acting = pending[arrived]  # the newest command that has reached the vehicle by t
                arrived += 1
            if acting is None:  # nothing of ours acts yet: coast
                px, py, pz = px + vx * dt, py + vy * dt, pz + vz * dt
                t += dt
                continue
            if attitude_mode:
                q = acting.attitude_wxyz
                w = (0.0, 0.0, 0.0)
            else:
                w = self._rate_step(w, acting.moment_flu_nm, dt)
                q = quat_integrate(q, w, dt)
            qw, qx, qy, qz = q
            f = acting.thrust_n / m  # thrust acceleration along b3 = R e3
            ax = f * (2.0 * (qx * qz + qw * qy))
            ay = f * (2.0 * (qy * qz - qw * qx))
            az = f * (1.0 - 2.0 * (qx * qx + qy * qy)) - GRAVITY_MPS2
            half_dt2 = 0.5 * dt * dt
            px, py, pz = px + dt * vx + half_dt2 * ax, py + dt * vy + half_dt2 * ay, pz + dt * vz + half_dt2 * az
            vx, vy, vz = vx + dt * ax, vy + dt * ay, vz + dt * az
            t += dt
        return (px, py, pz, vx, vy, vz, *q, *w)

    def _acting_and_pending(self, t: float, uplink_latency_s: float) -> tuple[SentCommand | None, list[SentCommand]]:
        """The newest command that has reached the vehicle by time t (our clock), and those sent after it.

        A later time's acting command is the newest of the pending ones that has arrived by then, or else
        still this one: so a prediction scans the history once, not once per step.
        """
        pending = []
        for command in reversed(self.sent):
            if command.sent_s + uplink_latency_s <= t + 1e-12:
                pending.reverse()
                return command, pending
            pending.append(command)
        pending.reverse()
        return None, pending

    def _rate_step(self, w, moment_flu_nm, dt: float) -> tuple[float, float, float]:
        """Euler step of I w' = M - w x I w (diagonal I)."""
        ix, iy, iz = self.inertia
        mx, my, mz = moment_flu_nm
        wx, wy, wz = w
        return (wx + dt * (mx - (iz - iy) * wy * wz) / ix,
                wy + dt * (my - (ix - iz) * wz * wx) / iy,
                wz + dt * (mz - (iy - ix) * wx * wy) / iz)
