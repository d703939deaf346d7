"""A user's course-style controller, trajectory and planner behind cfstack's own interfaces.

Takes in: the user's objects (groundstation.usercode.loader), the vehicle in use, the command mode and
the controller output choice, usercode.toml.
Gives out:
- UserController.update(state, reference, t_s) -> ControlOutput, like SE3Controller: the user's
  update(t, state, flat_output) with state {'x','v','q' [i,j,k,w],'w' body} from our estimate (never
  truth), outputs ravelled as the course's sanitize step does; moments mode flies cmd_thrust + cmd_moment,
  attitude mode cmd_thrust + cmd_q, `motor_speeds` output flies cmd_motor_speeds through the course's '+'
  mixer. Each command is logged to user_commands.csv (flushed per line) with cmd_motor_speeds beside it.
- UserTrajectory: the Trajectory protocol (sample(t) -> FlatOutput, duration_s) over the user's
  update(t) dict; its end is where update(t) comes to rest at update(inf)'s point.
- user_planner(graph_search): a planner for groundstation.planned (path, nodes expanded) that takes any of
  the course's return conventions: path (2020), (path, nodes_expanded), (sparse_path, dense_path).
After the first failure (an exception, a non-finite or missing output, a hang) user code is not called
again: the controller falls back to cfstack's SE3Controller and the mission holds, then lands.
"""

from __future__ import annotations

import csv
import logging
import math
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from groundstation.controller import ControllerState, ControlOutput, SE3Controller
from groundstation.trajectory import FlatOutput
from groundstation.usercode.guard import CallFailed, CallTimes, Fault, Guard
from groundstation.usercode.quad_params import quad_params_of
from model.config import Params, resolve
from model.errors import UserError
from model.frames import quat_normalize, quat_to_rows
from model.vehicle import Vehicle

log = logging.getLogger("cfstack.usercode")
CONTROLLER_OUTPUTS = ("commands", "motor_speeds")  # commands: cmd_thrust with cmd_moment / cmd_q
FLAT_KEYS = ("x", "x_dot", "x_ddot", "x_dddot", "x_ddddot")
USER_COMMAND_COLUMNS = ("t_s", "flown", "cmd_thrust_n", "cmd_moment_x_nm", "cmd_moment_y_nm", "cmd_moment_z_nm",
                        "cmd_q_w", "cmd_q_x", "cmd_q_y", "cmd_q_z", "cmd_motor_speed_1_radps",
                        "cmd_motor_speed_2_radps", "cmd_motor_speed_3_radps", "cmd_motor_speed_4_radps")
_NAN3 = (math.nan, math.nan, math.nan)


@dataclass(frozen=True)
class UserCodeSettings:
    call_timeout_s: float
    t_final_s: float
    end_scan_step_s: float
    end_resolution_s: float
    end_position_tolerance_m: float
    end_speed_tolerance_mps: float
    disagree_thrust_fraction_of_weight: float
    disagree_moment_fraction_of_max: float
    build_progress_period_s: float


def load_usercode_settings(name_or_path: str = "usercode") -> UserCodeSettings:
    p = Params.load(resolve(name_or_path, "groundstation", "params", "user-code settings"))
    return UserCodeSettings(**{f: p.number(f, minimum=0.0) for f in UserCodeSettings.__dataclass_fields__})


def _vector(u: dict, key: str, sizes: tuple[int, ...]) -> np.ndarray:
    """u[key] ravelled to float64 (course code returns (n,), (n,1) or (1,n) arrays); CallFailed otherwise."""
    if not isinstance(u, dict):
        raise CallFailed(f"returned {type(u).__name__}, not a dict")
    if key not in u:
        raise CallFailed(f"returned no '{key}' (keys: {', '.join(map(str, u)) or 'none'})")
    try:
        value = np.asarray(u[key], dtype=float).ravel()
    except (TypeError, ValueError):
        raise CallFailed(f"'{key}' is not numeric ({u[key]!r:.60})") from None
    if value.size not in sizes:
        raise CallFailed(f"'{key}' has {value.size} values, expected {' or '.join(map(str, sizes))}")
    if not np.all(np.isfinite(value)):
        raise CallFailed(f"'{key}' is not finite ({value.tolist()})")
    return value


def plus_mixer(quad_params: dict, motor_speeds_radps: np.ndarray) -> tuple[float, np.ndarray]:
    """Collective thrust (N) and body moment (N m) of rotor speeds, as the course's Quadrotor.step makes
    them: speeds clipped to [rotor_speed_min, rotor_speed_max], thrust_i = k_thrust w_i^2, and its '+'
    geometry (rotor 1 on +x, 2 on +y, 3 on -x, 4 on -y; spins +,-,+,-):
    [T, Mx, My, Mz] = [[1,1,1,1],[0,L,0,-L],[-L,0,L,0],[k,-k,k,-k]] @ thrusts, k = k_drag/k_thrust."""
    w = np.clip(motor_speeds_radps, quad_params["rotor_speed_min"], quad_params["rotor_speed_max"])
    f = quad_params["k_thrust"] * w**2
    arm, k = quad_params["arm_length"], quad_params["k_drag"] / quad_params["k_thrust"]
    moment = np.array([arm * (f[1] - f[3]), arm * (f[2] - f[0]), k * (f[0] - f[1] + f[2] - f[3])])
    return float(f.sum()), moment


class UserController:
    """The user's SE3Control behind SE3Controller's interface (module docstring)."""

    def __init__(self, instance, where: str, vehicle: Vehicle, fallback: SE3Controller, mode: str, output: str,
                 guard: Guard, settings: UserCodeSettings, log_path: Path | None):
        self.instance = instance
        self.name = where  # "se3_control.py SE3Control"
        self.where = f"{where}.update"
        self.vehicle = vehicle
        self.quad_params = quad_params_of(vehicle)
        self.fallback = fallback
        self.mode = mode
        self.output = output
        self.guard = guard
        self.times = CallTimes(self.where)
        self.max_thrust_n = vehicle.max_thrust_n
        self.max_moment_nm = np.asarray(vehicle.max_moment_nm, float)
        self.thrust_tolerance_n = settings.disagree_thrust_fraction_of_weight * vehicle.weight_n
        self.moment_tolerance_nm = settings.disagree_moment_fraction_of_max * float(self.max_moment_nm[:2].max())
        self.on_fault: Callable[[Fault], None] = lambda fault: None
        self.notes: list[str] = []
        self.disagreement: str | None = None
        self._summed_thrust_noted = False
        self._file = open(log_path, "w", buffering=1, newline="") if log_path else None  # noqa: SIM115
        self._csv = csv.writer(self._file) if self._file else None
        if self._csv:
            self._csv.writerow(USER_COMMAND_COLUMNS)

    def close(self) -> None:
        if self._file is not None:
            self._file.close()

    def update(self, state: ControllerState, ref: FlatOutput, t_s: float = 0.0) -> ControlOutput:
        if self.guard.fault is None:
            try:
                u = self.guard.call(self.times, t_s, self.instance.update, t_s, _state_dict(state), _flat_dict(ref))
                return self._flown(u, state, ref, t_s)
            except CallFailed as failed:
                self.on_fault(self.guard.record(self.where, t_s, str(failed)))
        return self.fallback.update(state, ref)

    def _flown(self, u, state: ControllerState, ref: FlatOutput, t_s: float) -> ControlOutput:
        speeds = _vector(u, "cmd_motor_speeds", (4,)) if self.output == "motor_speeds" or \
            (isinstance(u, dict) and "cmd_motor_speeds" in u) else None
        if self.output == "motor_speeds":
            thrust, moment = plus_mixer(self.quad_params, speeds)
            attitude = None
        else:
            thrust = self._thrust(_vector(u, "cmd_thrust", (1, 4)), t_s)
            if self.mode == "moments":
                moment, attitude = _vector(u, "cmd_moment", (3,)), None
            else:
                moment = _vector(u, "cmd_moment", (3,)) if "cmd_moment" in u else np.array(_NAN3)
                attitude = _unit_quaternion(_vector(u, "cmd_q", (4,)))
            if speeds is not None:
                self._compare(speeds, thrust, moment, t_s)
        rate = _vector(u, "cmd_w", (3,)) if self.mode == "attitude" and "cmd_w" in u else np.zeros(3)
        out = self._output(thrust, moment, attitude, rate, state, ref)
        if self._csv:
            self._csv.writerow(_row(t_s, self.output if self.output == "motor_speeds" else self.mode, out,
                                    attitude, speeds))
        return out

    def _thrust(self, cmd_thrust: np.ndarray, t_s: float) -> float:
        if cmd_thrust.size == 4:
            if not self._summed_thrust_noted:
                self._summed_thrust_noted = True
                self.notes.append(f"cmd_thrust has four values (first at t={t_s:.3f} s): taken as the rotors' "
                                  "thrusts, N, and summed")
                log.warning("user code %s: %s", self.where, self.notes[-1])
            return float(cmd_thrust.sum())
        return float(cmd_thrust[0])

    def _compare(self, speeds: np.ndarray, thrust: float, moment: np.ndarray, t_s: float) -> None:
        """Warn once when cmd_thrust/cmd_moment are not what cmd_motor_speeds make through the '+' mixer."""
        if self.disagreement is not None:
            return
        t_ms, m_ms = plus_mixer(self.quad_params, speeds)
        moment_gap = np.abs(m_ms[:2] - moment[:2]).max() if np.all(np.isfinite(moment)) else 0.0
        if abs(t_ms - thrust) > self.thrust_tolerance_n or moment_gap > self.moment_tolerance_nm:
            self.disagreement = (f"at t={t_s:.3f} s cmd_motor_speeds give {t_ms:.4f} N and roll/pitch moment "
                                 f"{m_ms[0]:.2e}, {m_ms[1]:.2e} N m through the course's '+' mixer, but cmd_thrust is "
                                 f"{thrust:.4f} N and cmd_moment {moment[0]:.2e}, {moment[1]:.2e} N m; cfstack flies "
                                 "cmd_thrust/cmd_moment (--controller-output motor_speeds flies the speeds)")
            log.warning("user code %s: %s", self.where, self.disagreement)

    def _output(self, thrust: float, moment: np.ndarray, attitude, rate: np.ndarray, state: ControllerState,
                ref: FlatOutput) -> ControlOutput:
        clipped_thrust = min(max(thrust, 0.0), self.max_thrust_n)
        clipped_moment = np.clip(moment, -self.max_moment_nm, self.max_moment_nm)
        q_now = tuple(float(v) for v in state.attitude_wxyz)
        rows = quat_to_rows(attitude if attitude is not None else q_now)
        b3 = (rows[2], rows[5], rows[8])
        position = np.asarray(state.position_enu_m, float)
        velocity = np.asarray(state.velocity_enu_mps, float)
        return ControlOutput(
            clipped_thrust, tuple(clipped_moment.tolist()), attitude if attitude is not None else q_now,
            tuple(rate.tolist()), clipped_thrust != thrust,
            tuple(bool(abs(m) > limit) for m, limit in zip(moment, self.max_moment_nm, strict=True)),
            tuple(thrust * c for c in b3), tuple((position - ref.position_m).tolist()),
            tuple((velocity - ref.velocity_mps).tolist()), _NAN3, _NAN3)

    def summary(self) -> dict:
        out = {"controller": self.name, "controller_output": self.output,
               "controller_update": self.times.summary()}
        if self.disagreement:
            out["motor_speeds_disagree"] = self.disagreement
        if self.notes:
            out["notes"] = list(self.notes)
        return out


def _unit_quaternion(q_ijkw: np.ndarray) -> tuple[float, float, float, float]:
    """cmd_q [i, j, k, w] (scalar last, the course's) as a unit (w, x, y, z)."""
    norm = float(np.linalg.norm(q_ijkw))
    if norm < 1e-6:
        raise CallFailed(f"'cmd_q' is not a rotation (norm {norm:.2e})")
    return quat_normalize((float(q_ijkw[3]), float(q_ijkw[0]), float(q_ijkw[1]), float(q_ijkw[2])))


def _row(t_s: float, flown: str, out: ControlOutput, attitude, speeds) -> list:
    q = attitude if attitude is not None else (math.nan,) * 4
    w = speeds if speeds is not None else (math.nan,) * 4
    return [f"{t_s:.6f}", flown, f"{out.thrust_n:.9g}", *(f"{v:.9g}" for v in out.moment_flu_nm),
            *(f"{v:.9g}" for v in q), *(f"{float(v):.9g}" for v in w)]


def _state_dict(state: ControllerState) -> dict:
    """The course's state dict: float64 arrays, q as [i, j, k, w] (body -> world), w body rates."""
    w, x, y, z = (float(v) for v in state.attitude_wxyz)
    return {"x": np.array(state.position_enu_m, float), "v": np.array(state.velocity_enu_mps, float),
            "q": np.array([x, y, z, w]), "w": np.array(state.rate_flu_radps, float)}


def _flat_dict(ref: FlatOutput) -> dict:
    return {"x": np.array(ref.position_m, float), "x_dot": np.array(ref.velocity_mps, float),
            "x_ddot": np.array(ref.acceleration_mps2, float), "x_dddot": np.array(ref.jerk_mps3, float),
            "x_ddddot": np.array(ref.snap_mps4, float), "yaw": float(ref.yaw_rad),
            "yaw_dot": float(ref.yaw_rate_radps)}


def flat_from_dict(d) -> FlatOutput:
    """A course flat-output dict as a FlatOutput; CallFailed on a missing, misshapen or non-finite value."""
    vectors = [_vector(d, key, (3,)) for key in FLAT_KEYS]
    yaw = _vector(d, "yaw", (1,))[0]
    yaw_rate = _vector(d, "yaw_dot", (1,))[0]
    return FlatOutput(*vectors, yaw_rad=float(yaw), yaw_rate_radps=float(yaw_rate))


class UserTrajectory:
    """The user's WorldTraj as a Trajectory: t = 0 is the start of tracking (the course's t = 0)."""

    def __init__(self, instance, where: str, settings: UserCodeSettings, guard: Guard):
        self.instance = instance
        self.name = where  # "world_traj.py WorldTraj"
        self.where = f"{where}.update"
        self.guard = guard
        self.times = CallTimes(self.where)
        self.on_fault: Callable[[Fault], None] = lambda fault: None
        self._last: FlatOutput | None = None
        self.final = self._call(math.inf)  # the course's traj_end_exit reads update(inf)
        self.duration_s = self._end_time(settings)
        self.note = None if self.duration_s < settings.t_final_s else (
            f"update(t) does not come to rest at update(inf)'s point within the course's t_final "
            f"({settings.t_final_s:g} s): flown for that long")

    def _call(self, t_s: float) -> FlatOutput:
        """update(t) as a FlatOutput; before the flight (construction) a failure is a UserError."""
        try:
            return flat_from_dict(self.guard.call(self.times, t_s, self.instance.update, t_s))
        except CallFailed as failed:
            raise UserError(f"user code {self.where}({t_s:g}): {failed}") from None

    def _end_time(self, s: UserCodeSettings) -> float:
        """The first time (to end_resolution_s) from which update(t) rests at the final point."""
        def at_rest(t: float) -> bool:
            out = self._call(t)
            return bool(np.linalg.norm(out.position_m - self.final.position_m) <= s.end_position_tolerance_m
                        and np.linalg.norm(out.velocity_mps) <= s.end_speed_tolerance_mps)

        grid = np.arange(0.0, s.t_final_s + s.end_scan_step_s / 2, s.end_scan_step_s)
        hit = next((float(t) for t in grid if at_rest(float(t))), None)
        if hit is None:
            return s.t_final_s
        low, high = max(0.0, hit - s.end_scan_step_s), hit
        if low == high:
            return 0.0
        while high - low > s.end_resolution_s:
            mid = (low + high) / 2
            low, high = (low, mid) if at_rest(mid) else (mid, high)
        return high

    def sample(self, t_s: float) -> FlatOutput:
        if self.guard.fault is None:
            try:
                self._last = flat_from_dict(self.guard.call(self.times, t_s, self.instance.update, t_s))
                return self._last
            except CallFailed as failed:
                self.on_fault(self.guard.record(self.where, t_s, str(failed)))
        held = self._last.position_m if self._last is not None else self.final.position_m
        return FlatOutput(np.array(held, float))  # at rest where it last was, until the mission lands

    def summary(self) -> dict:
        out = {"trajectory": self.name, "trajectory_update": self.times.summary(),
               "trajectory_duration_s": self.duration_s}
        if self.note:
            out["trajectory_note"] = self.note
        return out


def user_planner(function, where: str, guard: Guard):
    """graph_search(world, resolution, margin, start, goal, astar=True) as (path (N, 3) or None, nodes)."""
    from groundstation.usercode.compat.flightsim.world import World as CourseWorld

    times = CallTimes(where)

    def plan(world, resolution, margin: float, start, goal) -> tuple[np.ndarray | None, int | None]:
        try:
            result = guard.call(times, 0.0, function, CourseWorld.from_model(world), np.asarray(resolution, float),
                                float(margin), np.asarray(start, float), np.asarray(goal, float), True)
        except CallFailed as failed:
            raise UserError(f"user code {where}: {failed}") from None
        return _path_and_nodes(result, where)

    plan.where = where
    return plan


def _path_and_nodes(result, where: str) -> tuple[np.ndarray | None, int | None]:
    """Any of the course's return conventions: path; (path, nodes_expanded); (sparse_path, dense_path)."""
    nodes = None
    if isinstance(result, tuple):
        if len(result) != 2:
            raise UserError(f"user code {where}: returned a tuple of {len(result)}, expected path, "
                            "(path, nodes_expanded) or (sparse_path, dense_path)")
        first, second = result
        if second is None or np.ndim(second) == 0:
            result, nodes = first, None if second is None else int(second)
        else:
            result = second  # (sparse, dense): fly the dense path, as the course's harness plots it
    if result is None:
        return None, nodes
    path = np.asarray(result, float)
    if path.ndim != 2 or path.shape[1] != 3 or len(path) < 2 or not np.all(np.isfinite(path)):
        raise UserError(f"user code {where}: the path is not an (N, 3) array of finite points (shape "
                        f"{path.shape})")
    return path, nodes
