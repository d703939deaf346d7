"""`cfstack plan WORLD`: plan a grid path through a world file and report it.

Takes in: a world JSON file and options [--resolution R | --resolution RX RY RZ] [--margin M]
[--start X Y Z] [--goal X Y Z] [--vehicle-model NAME] [--json] [--plot FILE] [--params TOML].
The start and goal pass the same pre-flight check as in `fly` (groundstation.preflight): on the bounds
they are moved inward by the vehicle's collision radius, with a warning; inside a block they are refused.
Resolution and margin default to the world file's own values, else to planning.toml [grid].
Gives out: on stdout the path length, nodes expanded and planning time (human), or with --json exactly
one JSON object {found, path, length_m, nodes_expanded, planning_time_s} (path: list of [x, y, z] m,
the exact start first and the exact goal last); with --plot a PNG 3D view (blocks, path, pruned
waypoints). World warnings go to stderr, one line each. Exit code 0 when a path is found, 1 when none
exists (with a message on stderr), 2 for bad input (a one-line UserError printed by the dispatcher).
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np

from groundstation.planning import load_planning_params
from groundstation.planning.astar import PathResult, plan_path
from groundstation.planning.pruning import prune_path
from groundstation.preflight import checked_point
from model.errors import OneLineParser, UserError
from model.options import finite_float, non_negative_float, positive_float
from model.vehicle import load_vehicle
from model.world import World, load_world


def _parser() -> argparse.ArgumentParser:
    p = OneLineParser(prog="cfstack plan", description="Plan an A* path through a world file.")
    p.add_argument("world", help="world JSON file")
    p.add_argument("--resolution", type=positive_float, nargs="+", metavar="R",
                   help="voxel size in m: one value, or three (x y z); default: the world's, else planning.toml")
    p.add_argument("--margin", type=non_negative_float, metavar="M",
                   help="clearance to blocks and walls in m; default: the world's, else planning.toml")
    p.add_argument("--start", type=finite_float, nargs=3, metavar=("X", "Y", "Z"),
                   help="start point, m (default: the world's)")
    p.add_argument("--goal", type=finite_float, nargs=3, metavar=("X", "Y", "Z"),
                   help="goal point, m (default: the world's)")
    p.add_argument("--vehicle-model", default="crazyflie",
                   help="vehicle parameters (its collision radius for the pre-flight check): name or TOML file")
    p.add_argument("--json", action="store_true", help="print exactly one JSON object on stdout")
    p.add_argument("--plot", metavar="FILE", help="write a PNG 3D view of blocks, path and pruned waypoints")
    p.add_argument("--params", default="planning", help="planning parameters: name or TOML file")
    return p


def command(argv: list[str]) -> int:
    args = _parser().parse_args(argv)
    params = load_planning_params(args.params)
    grid = params.table("grid")
    world = load_world(args.world)
    radius_m = load_vehicle(args.vehicle_model).collision_radius_m
    # The same pre-flight rule as `fly` (groundstation.preflight): a point on the bounds is moved inward.
    nudges: list[str] = []
    start = checked_point(world, _endpoint(args.start, world.start, "start", world), "start", radius_m, nudges)
    goal = checked_point(world, _endpoint(args.goal, world.goal, "goal", world), "goal", radius_m, nudges)
    for warning in (*world.warnings, *nudges):
        print(f"warning: {warning}", file=sys.stderr)
    resolution = _resolution(args.resolution, world, grid.number("resolution_m", minimum=1e-6))
    margin = _margin(args.margin, world, grid.number("margin_m", minimum=0.0))
    result = plan_path(
        world,
        resolution,
        margin,
        start,
        goal,
        batch_width_voxels=grid.number("batch_width_voxels", minimum=1e-3),
    )
    if args.plot:
        _plot(Path(args.plot), world, result, margin, start, goal)
    if args.json:
        print(json.dumps(_json_summary(result)))
    else:
        print(_human_summary(world, resolution, margin, result))
    if not result.found:
        print(f"cfstack plan: {result.message}", file=sys.stderr)
        return 1
    return 0


def _resolution(given: list[float] | None, world: World, default: float) -> np.ndarray:
    if given is None:
        return world.resolution if world.resolution is not None else np.full(3, default)
    if len(given) not in (1, 3):
        raise UserError(f"argument --resolution: give one value or three, not {len(given)} "
                        "(see 'cfstack plan --help')")
    return np.broadcast_to(np.array(given, float), (3,)).copy()


def _margin(given: float | None, world: World, default: float) -> float:
    if given is None:
        return world.margin if world.margin is not None else default
    return float(given)


def _endpoint(
    given: list[float] | None, from_world: np.ndarray | None, name: str, world: World
) -> np.ndarray:
    if given is not None:
        return np.array(given, float)
    if from_world is None:
        raise UserError(f"{world.source}: no {name} in the world file; give --{name} X Y Z")
    return from_world


def _json_summary(result: PathResult) -> dict:
    return {
        "found": result.found,
        "path": result.path_m.tolist(),
        "length_m": result.length_m if result.found else None,
        "nodes_expanded": result.nodes_expanded,
        "planning_time_s": result.planning_time_s,
    }


def _human_summary(world: World, resolution: np.ndarray, margin: float, result: PathResult) -> str:
    res = " x ".join(f"{r:g}" for r in resolution)
    head = f"{world.source}: resolution {res} m, margin {margin:g} m"
    if not result.found:
        return (
            f"{head}\nno path found ({result.nodes_expanded} nodes expanded, "
            f"planning time {result.planning_time_s:.3f} s)"
        )
    return (
        f"{head}\npath length {result.length_m:.3f} m, {len(result.path_m)} points, "
        f"{result.nodes_expanded} nodes expanded, planning time {result.planning_time_s:.3f} s"
    )


def _plot(
    path: Path, world: World, result: PathResult, margin: float, start: np.ndarray, goal: np.ndarray
) -> None:
    """PNG 3D view: blocks (translucent boxes), A* path, pruned waypoints, start and goal."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure
    from mpl_toolkits.mplot3d.art3d import Poly3DCollection

    fig = Figure(figsize=(8, 7))
    FigureCanvasAgg(fig)
    ax = fig.add_subplot(projection="3d")
    faces = [face for block in world.blocks for face in _box_faces(block)]
    if faces:
        ax.add_collection3d(
            Poly3DCollection(faces, facecolor="tab:gray", edgecolor="k", linewidth=0.2, alpha=0.25)
        )
    if result.found:
        p = result.path_m
        ax.plot(p[:, 0], p[:, 1], p[:, 2], color="tab:blue", linewidth=1.0, label="A* path")
        w = prune_path(p, world, margin)
        ax.plot(
            w[:, 0],
            w[:, 1],
            w[:, 2],
            "o--",
            color="tab:orange",
            markersize=4,
            linewidth=0.8,
            label=f"pruned waypoints ({len(w)})",
        )
    ax.scatter(*start, color="tab:green", s=40, label="start")
    ax.scatter(*goal, color="tab:red", s=40, label="goal")
    b = world.bounds
    ax.set_xlim(b[0], b[1])
    ax.set_ylim(b[2], b[3])
    ax.set_zlim(b[4], b[5])
    ax.set_box_aspect(b[1::2] - b[0::2])
    ax.set_xlabel("x east (m)")
    ax.set_ylabel("y north (m)")
    ax.set_zlabel("z up (m)")
    title = f"{Path(world.source).name}: " + (f"{result.length_m:.2f} m path" if result.found else "no path")
    ax.set_title(title)
    ax.legend(loc="upper left", fontsize=8)
    try:
        fig.savefig(path, dpi=120)
    except OSError as err:
        raise UserError(f"--plot {path}: cannot write ({err.strerror})") from None


def _box_faces(block: np.ndarray) -> list[np.ndarray]:
    x0, x1, y0, y1, z0, z1 = block
    c = np.array(
        [[x, y, z] for x in (x0, x1) for y in (y0, y1) for z in (z0, z1)]
    )  # corner (i, j, k) = 4i+2j+k
    quads = [(0, 1, 3, 2), (4, 5, 7, 6), (0, 1, 5, 4), (2, 3, 7, 6), (0, 2, 6, 4), (1, 3, 7, 5)]
    return [c[list(q)] for q in quads]
