"""Grading a flown session: what the summary (`--json`, summary.json) says, and on what evidence.

Takes in: the flight loop's record (per tick: time, phase, reference, estimate, and simulation truth when
the link provides it), the mission's outcome, the crash report (simulation only), the link's statistics,
the world and the course grading rules (groundstation/params/course_grading.toml).
Gives out: the summary dict. Its parts, kept apart:
- the mission: `result` (reached_goal, timeout, failsafe, aborted, crashed), `reached_goal`,
  `time_to_goal_s` (None for a trajectory that goes nowhere, e.g. a hover), `collided` (a collision in
  flight, before the mission's result was decided); the exit code follows these;
- `landing`: what happened after: landed, crashed, not attempted; where and how far it moved first;
- `failure`: for a crash or a failsafe, the phase, time, position, speed and what was touched (block index
  and extents, floor, bounds), with the same one line the command prints on stderr;
- `min_clearance_m` over the whole flight (take-off and landing included), with `min_clearance_phase`
  and `min_clearance_to` (a block's index, or "bounds"); pads are not obstacles while taking off or landing;
- `course_grade`: the course's own rules beside ours (stopped at the goal, no collision within its robot
  radius during the flight, flight time), from the truth.
Grading uses simulator truth when the link provides it (simulation only); control never does.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from link.messages import CrashReport, Touched
from model.config import Params, resolve
from model.world import World

# Phases in which touching a landing pad is intended (its clearance does not count as an obstacle's).
GROUND_PHASES = ("connect", "reset", "arm", "takeoff", "land", "vehicle_land", "disarm", "done",
                 "failsafe_descent")
AIRBORNE_PHASES = ("takeoff", "settle", "track", "hover", "land", "failsafe_hold", "failsafe_descent",
                   "vehicle_land")
TRACKING_PHASES = ("track", "hover")
_TOUCHED_NAMES = {Touched.FLOOR: "floor", Touched.BLOCK: "block", Touched.BLOCK_TOP: "block_top",
                  Touched.BOUNDS: "bounds"}


@dataclass(frozen=True)
class CourseRules:
    """MEAM 620 flightsim's grading (course_grading.toml has the sources)."""

    robot_radius_m: float
    stop_position_tolerance_m: float
    stop_speed_tolerance_mps: float
    stop_attitude_tolerance_rad: float
    min_time_when_start_is_goal_s: float
    source: str


def load_course_rules(name_or_path: str = "course_grading") -> CourseRules:
    p = Params.load(resolve(name_or_path, "groundstation", "params", "course grading rules"))
    positive = {"minimum": 1e-9}
    return CourseRules(
        robot_radius_m=p.number("robot_radius_m", **positive),
        stop_position_tolerance_m=p.number("stop_position_tolerance_m", **positive),
        stop_speed_tolerance_mps=p.number("stop_speed_tolerance_mps", **positive),
        stop_attitude_tolerance_rad=p.number("stop_attitude_tolerance_rad", **positive),
        min_time_when_start_is_goal_s=p.number("min_time_when_start_is_goal_s", minimum=0.0),
        source=p.string("source"),
    )


def stack3(rows: list, width: int = 3) -> np.ndarray:
    """Per-tick tuples (or None) as an (N, width) array, NaN where None."""
    return np.array([r if r is not None else [np.nan] * width for r in rows], float).reshape(-1, width)


def rms(values) -> float | None:
    values = np.asarray(values, float)
    return float(math.sqrt(np.mean(values**2))) if values.size else None


def min_clearance(world: World | None, t: np.ndarray, phase: np.ndarray, truth: np.ndarray) -> dict:
    """The smallest truth clearance to an obstacle over the whole flight, where and when it happened."""
    none = {"min_clearance_m": None, "min_clearance_phase": None, "min_clearance_to": None,
            "min_clearance_time_s": None}
    if world is None:
        return none
    rows = np.flatnonzero(np.isfinite(truth).all(axis=1) & np.isin(phase, AIRBORNE_PHASES + GROUND_PHASES))
    if not rows.size:
        return none
    distance, obstacle = world.obstacle_clearance(truth[rows], pads_allowed=np.isin(phase[rows], GROUND_PHASES))
    i = int(np.argmin(distance))
    return {"min_clearance_m": float(distance[i]), "min_clearance_phase": str(phase[rows[i]]),
            "min_clearance_to": "bounds" if obstacle[i] < 0 else f"block {int(obstacle[i])}",
            "min_clearance_time_s": float(t[rows[i]])}


def course_grade(rules: CourseRules, world: World | None, t: np.ndarray, truth: np.ndarray, truth_vel: np.ndarray,
                 truth_att: np.ndarray, goal: np.ndarray, final_yaw_rad: float, track_start_s: float | None,
                 starts_at_goal: bool, flight_over_s: float) -> dict | None:
    """The course's verdict from the truth: the flight starts when tracking starts; it is COMPLETE at the
    first sample within the stop tolerances of the goal (position, speed, attitude to level at the final
    yaw), not before min_time_when_start_is_goal_s for a trajectory that ends where it starts; no_collision
    looks at every sample from the start to that moment (or to the end of the flight when it never stops)
    with the course's robot radius."""
    if track_start_s is None or not np.isfinite(truth).any():
        return None
    span = (t >= track_start_s) & (t <= flight_over_s) & np.isfinite(truth).all(axis=1)
    earliest = track_start_s + (rules.min_time_when_start_is_goal_s if starts_at_goal else 0.0)
    level = np.array([math.cos(final_yaw_rad / 2), 0.0, 0.0, math.sin(final_yaw_rad / 2)])
    angle = 2.0 * np.arccos(np.clip(np.abs(truth_att @ level), 0.0, 1.0))
    stopped = (span & (t >= earliest) & (np.linalg.norm(truth - goal, axis=1) < rules.stop_position_tolerance_m)
               & (np.linalg.norm(truth_vel, axis=1) <= rules.stop_speed_tolerance_mps)
               & (angle <= rules.stop_attitude_tolerance_rad))
    hits = np.flatnonzero(stopped)
    end = t[hits[0]] if hits.size else flight_over_s
    flown = span & (t <= end)
    collision_point = None
    if world is not None and len(world.blocks) and flown.any():
        close = world.distance_to_blocks(truth[flown]) < rules.robot_radius_m
        if close.any():
            collision_point = truth[flown][int(np.argmax(close))].tolist()
    grade = {
        "stopped_at_goal": bool(hits.size),
        "no_collision": collision_point is None,
        "flight_time_s": float(end - track_start_s) if hits.size else None,
        "collision_point_enu_m": collision_point,
        "robot_radius_m": rules.robot_radius_m,
        "rules": rules.source,
    }
    grade["passed"] = grade["stopped_at_goal"] and grade["no_collision"]
    return grade


def failure(mission, crash: CrashReport | None, t: np.ndarray, phase: np.ndarray, est: np.ndarray) -> dict | None:
    """The crash (what the simulation reported, else what the vehicle said) or the failsafe, as data and as
    the one line the command prints; None when neither happened. A failsafe that came first (the ground
    station stopped commanding, then the vehicle's own watchdog let it fall) is kept in `after_failsafe`."""
    first = _failsafe(mission, t, phase, est)
    if crash is None and mission.crash_seen is None:
        return first
    if crash is not None:
        at = _phase_at(t, phase, crash.time_s)
        touched = {"what": _TOUCHED_NAMES[crash.touched]}
        if crash.block_index >= 0:
            touched |= {"block_index": crash.block_index, "block_extents_m": list(crash.block_extents_m)}
        report = {"kind": "crash", "phase": at, "time_s": crash.time_s, "position_enu_m": list(crash.position_enu_m),
                  "velocity_enu_mps": list(crash.velocity_enu_mps), "speed_mps": crash.speed_mps,
                  "touched": touched, "what": crash.describe()}
    else:
        seen_s, at = mission.crash_seen
        report = {"kind": "crash", "phase": at, "time_s": seen_s, "position_enu_m": _estimate_at(t, est, seen_s),
                  "velocity_enu_mps": None, "speed_mps": None, "touched": None,
                  "what": f"the vehicle reported CRASHED at t={seen_s:.3f} s"}
    if first is not None and first["time_s"] <= report["time_s"]:
        report["after_failsafe"] = first
        report["reason"] = f"{first['reason']}; then a crash {_while(at)}: {report['what']}"
    else:
        report["reason"] = f"crash {_while(at)}: {report['what']}"
    return report


def _failsafe(mission, t: np.ndarray, phase: np.ndarray, est: np.ndarray) -> dict | None:
    if mission.failsafe_reason is None or mission.result not in ("failsafe", "aborted", "crashed"):
        return None
    seen_s, at = mission.failsafe_at or (float(t[-1]) if t.size else 0.0, "connect")
    return {"kind": "failsafe", "phase": at, "time_s": seen_s, "position_enu_m": _estimate_at(t, est, seen_s),
            "velocity_enu_mps": None, "speed_mps": None, "touched": None,
            "reason": f"failsafe {_while(at)} at t={seen_s:.3f} s: {mission.failsafe_reason}"}


def _tick_at(t: np.ndarray, time_s: float) -> int:
    """Index of the last tick at or before time_s (the first tick's before the log starts)."""
    return max(0, int(np.searchsorted(t, time_s, side="right")) - 1)


def _phase_at(t: np.ndarray, phase: np.ndarray, time_s: float) -> str:
    return str(phase[_tick_at(t, time_s)]) if t.size else "connect"


def _estimate_at(t: np.ndarray, est: np.ndarray, time_s: float) -> list[float] | None:
    if not t.size:
        return None
    i = _tick_at(t, time_s)
    return est[i].tolist() if np.isfinite(est[i]).all() else None


def _while(phase: str) -> str:
    """'while tracking', 'after the ground station stopped commanding', ... for a phase name."""
    if phase == "done":
        return "after the ground station stopped commanding"
    doing = {"track": "tracking", "hover": "hovering at the goal", "land": "landing", "takeoff": "taking off",
             "settle": "settling", "arm": "arming", "connect": "connecting", "vehicle_land": "landing",
             "failsafe_hold": "holding (mocap lost)", "failsafe_descent": "descending (failsafe)",
             "disarm": "disarming", "reset": "resetting"}.get(phase, phase)
    return f"while {doing}"
