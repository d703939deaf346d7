"""Pre-flight checks: what must hold before anything starts (no emulator, no link, no planning yet).

Takes in: a world (model.world) with its start and goal, and the vehicle (its collision radius).
Gives out: the start and goal to fly, and one warning line per point it moved; a WorldError (one line,
exit code 2) for a point it cannot fly.

Rule (the same in `fly`, `step`, `sweep` and `plan`): a start or goal must lie at least the vehicle's
collision radius inside the bounds and at least that far from every block (a landing pad right below
it excepted). The course accepts a point ON the bounds (it flags only points strictly outside), while
the emulator ends a flight whose centre leaves the bounds: such a point, or one within the radius of a
wall, the floor or the ceiling, is moved inward by the radius, with a warning saying so. A point inside a
block, or within the radius of one, is refused with the reason: moving it would change the mission.
"""

from __future__ import annotations

import dataclasses

import numpy as np

from model.errors import WorldError
from model.world import World


def checked_point(world: World, point, name: str, radius_m: float, warnings: list[str]) -> np.ndarray:
    """The point to fly to (nudged inside the bounds when needed); WorldError when it cannot be flown."""
    given = np.asarray(point, float)
    where = given.round(6).tolist()
    if not world.contains(given):
        raise WorldError(f"{world.source}: {name} {where} is outside the bounds {world.bounds.tolist()}")
    # strictly inside: a point on a surface is judged by its distance below (a pad's top is allowed)
    if len(world.blocks) and np.any(np.all((world.blocks[:, 0::2] < given) & (given < world.blocks[:, 1::2]), axis=1)):
        raise WorldError(f"{world.source}: {name} {where} is inside a block")
    nudged = world.nudged_inside(given, radius_m)
    moved = float(np.linalg.norm(nudged - given))
    if moved > 0.0:
        warnings.append(f"{world.source}: {name} {where} is within the vehicle's collision radius "
                        f"{radius_m:.3f} m of the world bounds: moved {moved:.3f} m inward, to "
                        f"{nudged.round(6).tolist()}")
    distance, obstacle = world.obstacle_clearance(nudged, pads_allowed=True)
    if distance[0] < radius_m and obstacle[0] >= 0:
        block = int(obstacle[0])
        raise WorldError(f"{world.source}: {name} {where} is {distance[0]:.3f} m from block {block} "
                         f"{world.blocks[block].tolist()}, inside the vehicle's collision radius "
                         f"{radius_m:.3f} m")
    return nudged


def checked_world(world: World, radius_m: float) -> tuple[World, list[str]]:
    """The world with its start and goal checked (and nudged, see the module docstring), and the warnings."""
    warnings: list[str] = []
    start = None if world.start is None else checked_point(world, world.start, "start", radius_m, warnings)
    goal = None if world.goal is None else checked_point(world, world.goal, "goal", radius_m, warnings)
    return dataclasses.replace(world, start=start, goal=goal), warnings
