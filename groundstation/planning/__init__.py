"""Path planning on the course's world maps: occupancy grid, A* search, waypoint pruning.

Takes in: a `model.world.World`, a voxel resolution (m, per axis) and a safety margin (m), and the
planning parameter file (groundstation/params/planning.toml, or a path to another TOML file).
Gives out: an `OccupancyGrid` (occupancy.py), a `PathResult` from A* (astar.py) and the indices of the
waypoints that survive line-of-sight pruning (pruning.py).
"""

from __future__ import annotations

from pathlib import Path

from model.config import Params, resolve


def load_planning_params(name_or_path: str | Path = "planning") -> Params:
    """The planning parameter file: built-in name ("planning") or a path to a TOML file."""
    return Params.load(resolve(name_or_path, "groundstation", "params", "planning parameters"))
