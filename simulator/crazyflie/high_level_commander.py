"""The high-level commander (crazyflie-firmware src/modules/src/crtp_commander_high_level.c, planner.c):
takeoff, land, go_to and stop, flown as a stream of position setpoints by the onboard position controller.

Takes in: a request (link.crtp.setpoints.HighLevel) with the time it arrived (s) and the vehicle's
position estimate (m, world) and yaw estimate (rad) then; per commander tick the time.
Gives out: per tick the position (m) and yaw (rad) to fly, or None when no plan is active (idle, or
stopped); `finished(t)` once the newest plan's end is reached.

Each plan is one 7th-order rest-to-rest polynomial segment per axis from where the vehicle is (or from the
previous plan's current point when one is flying) to the target in the requested duration, as the
firmware's planner builds takeoff, land and go_to (plan_takeoff / plan_land / plan_go_to ->
piecewise_plan_7th_order_no_jerk): zero velocity, acceleration and jerk at both ends,
s(u) = 35 u^4 - 84 u^5 + 70 u^6 - 20 u^7, u = t / duration. Yaw takes the short way round. After a land
the planner holds the landing point: the motors stop with a stop request (cflib examples send one).
"""

from __future__ import annotations

import math
from dataclasses import dataclass


def smooth_step(u: float) -> float:
    """The no-jerk 7th-order blend from 0 to 1 over u in [0, 1] (clamped outside)."""
    u = min(max(u, 0.0), 1.0)
    return u ** 4 * (35.0 - 84.0 * u + 70.0 * u * u - 20.0 * u ** 3)


@dataclass(frozen=True)
class Plan:
    start_s: float
    duration_s: float
    start_m: tuple[float, float, float]
    end_m: tuple[float, float, float]
    start_yaw_rad: float
    yaw_change_rad: float

    def at(self, t_s: float) -> tuple[tuple[float, float, float], float]:
        s = smooth_step((t_s - self.start_s) / self.duration_s) if self.duration_s > 0.0 else 1.0
        position = tuple(a + s * (b - a) for a, b in zip(self.start_m, self.end_m, strict=True))
        return position, self.start_yaw_rad + s * self.yaw_change_rad


class HighLevelCommander:
    def __init__(self):
        self.plan: Plan | None = None

    def request(self, kind: str, target_m: tuple[float, float, float], yaw_rad: float | None, duration_s: float,
                t_s: float, position_m, yaw_now_rad: float, relative: bool = False) -> bool:
        """Start a plan; False (nothing changes) for a duration that is not positive and finite."""
        if kind == "stop":
            self.plan = None
            return True
        if not (math.isfinite(duration_s) and duration_s > 0.0):
            return False
        start, start_yaw = (tuple(position_m), yaw_now_rad) if self.plan is None else self.plan.at(t_s)
        if kind in ("takeoff", "land"):
            end = (start[0], start[1], target_m[2])
        elif relative:
            end = tuple(a + b for a, b in zip(start, target_m, strict=True))
        else:
            end = tuple(target_m)
        end_yaw = start_yaw if yaw_rad is None else (start_yaw + yaw_rad if relative else yaw_rad)
        change = math.remainder(end_yaw - start_yaw, 2.0 * math.pi)
        if not all(math.isfinite(v) for v in (*end, change)):
            return False
        self.plan = Plan(t_s, duration_s, tuple(start), tuple(end), start_yaw, change)
        return True

    def setpoint(self, t_s: float) -> tuple[tuple[float, float, float], float] | None:
        return None if self.plan is None else self.plan.at(t_s)

    def finished(self, t_s: float) -> bool:
        return self.plan is None or t_s >= self.plan.start_s + self.plan.duration_s
