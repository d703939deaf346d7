"""From a world file to a trajectory: plan (A*), then constant-speed or minimum-snap timing.

Takes in: a World with start and goal, resolution and margin (or their defaults: the world's own, else
planning.toml), the trajectory kind and speed, the vehicle (its thrust-to-weight ratio limits minimum snap).
Gives out: a PlannedTrack: the trajectory to track, the goal, the plan record for plan.json, and the
summary fields (planning_time_s, trajectory).
"""

from __future__ import annotations

import dataclasses
import time
from dataclasses import dataclass

import numpy as np

from groundstation.planning import load_planning_params
from groundstation.planning.astar import PathResult, plan_path
from groundstation.trajectories.constant_speed import ConstantSpeedSettings, ConstantSpeedTrajectory, downsample_path
from groundstation.trajectories.minsnap import MinSnapSettings, plan_min_snap
from groundstation.trajectory import Trajectory
from model.errors import UserError
from model.vehicle import Vehicle
from model.world import World

KINDS = ("constant-speed", "minsnap")


@dataclass
class PlannedTrack:
    trajectory: Trajectory
    goal_enu_m: np.ndarray
    plan: dict
    summary: dict


class NoPathError(UserError):
    """No path between start and goal: a normal outcome, reported with exit code 1."""

    exit_code = 1


def grid_settings(world: World, resolution: list[float] | None, margin: float | None,
                  params=None) -> tuple[np.ndarray, float]:
    grid = (params or load_planning_params()).table("grid")
    if resolution is not None:
        res = np.broadcast_to(np.asarray(resolution, float), (3,)).copy()
        if len(resolution) not in (1, 3) or not np.all(res > 0):
            raise UserError(f"--resolution: expected 1 or 3 positive numbers, got {resolution}")
    elif world.resolution is not None:
        res = world.resolution
    else:
        res = np.full(3, grid.number("resolution_m", minimum=1e-6))
    if margin is not None:
        if not margin >= 0:
            raise UserError(f"--margin: must be >= 0, got {margin}")
        m = float(margin)
    else:
        m = world.margin if world.margin is not None else grid.number("margin_m", minimum=0.0)
    return res, m


def plan_track(world: World, kind: str, vehicle: Vehicle, speed_mps: float | None = None,
               resolution: list[float] | None = None, margin: float | None = None,
               accel_mps2: float | None = None, planning: str = "planning", planner=None) -> PlannedTrack:
    """planner: a user's graph_search (groundstation.usercode.adapters.user_planner) instead of our A*."""
    if world.start is None or world.goal is None:
        raise UserError(f"{world.source}: the world has no start and goal to plan between")
    if kind not in KINDS:
        raise UserError(f"--trajectory {kind}: with a world, one of {', '.join(KINDS)}")
    if speed_mps is not None and not speed_mps > 0:
        raise UserError(f"--speed: must be positive, got {speed_mps}")
    params = load_planning_params(planning)
    res, m = grid_settings(world, resolution, margin, params)
    t0 = time.perf_counter()
    if planner is None:
        result = plan_path(world, res, m, batch_width_voxels=params.table("grid").number("batch_width_voxels"))
    else:
        result = _user_path(planner, world, res, m)
    if not result.found:
        raise NoPathError(f"{world.source}: no path from start to goal at resolution "
                          f"{res.tolist()} m and margin {m} m ({result.message})")
    if kind == "constant-speed":
        settings = ConstantSpeedSettings.from_params(params)
        if speed_mps is not None:
            settings = dataclasses.replace(settings, speed_mps=speed_mps)
        trajectory = ConstantSpeedTrajectory.from_path(result.path_m, settings)
        waypoints = downsample_path(result.path_m, settings.keep_every)
        speed = settings.speed_mps
    else:
        settings = MinSnapSettings.from_params(params, vehicle)
        if speed_mps is not None:
            settings = dataclasses.replace(settings, max_speed_mps=speed_mps)
        if accel_mps2 is not None:
            if not accel_mps2 > 0:
                raise UserError(f"--accel: must be positive, got {accel_mps2}")
            settings = dataclasses.replace(settings, max_accel_mps2=accel_mps2)
        plan = plan_min_snap(result.path_m, world, m, settings)
        trajectory = plan.trajectory
        waypoints = trajectory.waypoints_m
        speed = settings.max_speed_mps
    planning_time = time.perf_counter() - t0
    record = {
        "world": str(world.source), "resolution": res.tolist(), "margin": m, "trajectory": kind,
        "speed_mps": speed, "path": result.path_m.tolist(), "waypoints": np.asarray(waypoints).tolist(),
        "astar_length_m": result.length_m, "nodes_expanded": result.nodes_expanded,
    }
    if planner is not None:
        record["planner"] = planner.where
    summary = {"planning_time_s": planning_time, "trajectory": kind, "planned_duration_s": trajectory.duration_s}
    return PlannedTrack(trajectory, np.array(world.goal, float), record, summary)


def _user_path(planner, world: World, res: np.ndarray, margin_m: float) -> PathResult:
    """The user's graph_search result as a PathResult (nodes_expanded -1 when it does not say)."""
    t0 = time.perf_counter()
    path, nodes = planner(world, res, margin_m, world.start, world.goal)
    elapsed = time.perf_counter() - t0
    nodes = -1 if nodes is None else nodes
    if path is None:
        return PathResult(False, np.zeros((0, 3)), np.inf, nodes, elapsed, "the user's graph_search returned no path")
    return PathResult(True, path, float(np.linalg.norm(np.diff(path, axis=0), axis=1).sum()), nodes, elapsed)
