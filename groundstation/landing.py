"""Where to land: a spot whose descent never passes an edge, the nearest one to where the vehicle hovers.

Takes in: the world, the vehicle's position (ENU, m), its collision radius (m, model.vehicle) and the
landing search settings (groundstation/params/mission.toml [landing]).
Gives out: a LandingSpot (where to descend, the surface it lands on, how far it moves first), or None
when no clear spot lies within the search radius.

A spot (x, y) is clear when, with r = collision radius + safety:
- it lies at least r inside the bounds' walls;
- the vertical column from the hover height down to the surface below (the floor, or the top of the
  highest block under (x, y) and below the vehicle: a landing pad) stays at least r from every other
  block, measured in 3-D, so the descent meets no block's side or edge;
- on a pad, the footprint (the square of half-width r around (x, y)) lies inside the pad's top face,
  so the vehicle does not settle on its edge;
- the horizontal move from the hover point to above the spot keeps r from every block.
The emulator calls a crash what comes within the collision radius of a block other than a pad right
below (simulator.dynamics), so such a descent cannot end in one. Candidates are tried straight below
first, then on rings of growing radius (step `search_step_m`), nearest first.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from model.world import World


@dataclass(frozen=True)
class LandingSettings:
    search_radius_m: float  # farthest horizontal move to a clear spot
    search_step_m: float  # spacing of the candidate rings and of the points along a ring
    safety_m: float  # clearance added to the collision radius
    path_check_step_m: float  # spacing of the points checked along the horizontal move


@dataclass(frozen=True)
class LandingSpot:
    above_m: np.ndarray  # (3,) the point above the spot at the hover height
    touchdown_m: np.ndarray  # (3,) the spot on its surface
    on_pad: int  # index of the block landed on, -1 for the floor
    moved_m: float  # horizontal distance from the hover point


def find_landing_spot(world: World, position_m, collision_radius_m: float,
                      settings: LandingSettings) -> LandingSpot | None:
    """The nearest clear spot (see the module docstring), or None."""
    p = np.asarray(position_m, float)
    r = collision_radius_m + settings.safety_m
    # Along the move, keep r, or the clearance the vehicle already has where it hovers if that is less
    # (it hovers between r and the collision radius of a block: moving away must still be allowed).
    move_clearance = min(r, float(world.distance_to_blocks(p)))
    for x, y in _candidates(p[0], p[1], settings):
        spot = _clear_spot(world, x, y, p[2], r)
        if spot is None:
            continue
        above = np.array([x, y, p[2]])
        if _move_is_clear(world, p, above, move_clearance, settings.path_check_step_m):
            surface, pad = spot
            return LandingSpot(above, np.array([x, y, surface]), pad, float(math.hypot(x - p[0], y - p[1])))
    return None


def _candidates(x0: float, y0: float, settings: LandingSettings):
    """(x0, y0), then rings of radius k step (k = 1, 2, ...), each at points about `step` apart."""
    yield x0, y0
    step = settings.search_step_m
    rings = int(settings.search_radius_m / step)
    for k in range(1, rings + 1):
        radius = k * step
        count = max(8, math.ceil(2.0 * math.pi * radius / step))
        for i in range(count):
            angle = 2.0 * math.pi * i / count
            yield x0 + radius * math.cos(angle), y0 + radius * math.sin(angle)


def _clear_spot(world: World, x: float, y: float, z_hover: float, r: float) -> tuple[float, int] | None:
    """(surface height, pad index or -1) when the column at (x, y) is clear, else None."""
    b = world.bounds
    if not (b[0] + r <= x <= b[1] - r and b[2] + r <= y <= b[3] - r):
        return None
    blocks = world.blocks
    floor = float(b[4])
    if len(blocks) == 0:
        return floor, -1
    lo, hi = blocks[:, 0::2], blocks[:, 1::2]
    under = (lo[:, 0] <= x) & (x <= hi[:, 0]) & (lo[:, 1] <= y) & (y <= hi[:, 1]) & (hi[:, 2] <= z_hover)
    pad = int(np.flatnonzero(under)[np.argmax(hi[under, 2])]) if under.any() else -1
    surface = float(hi[pad, 2]) if pad >= 0 else floor
    if pad >= 0 and not (lo[pad, 0] + r <= x <= hi[pad, 0] - r and lo[pad, 1] + r <= y <= hi[pad, 1] - r):
        return None  # the footprint would hang over the pad's edge
    # distance from the column segment (x, y, surface..z_hover) to each other block (3-D box distance)
    dx = np.maximum(np.maximum(lo[:, 0] - x, x - hi[:, 0]), 0.0)
    dy = np.maximum(np.maximum(lo[:, 1] - y, y - hi[:, 1]), 0.0)
    dz = np.maximum(np.maximum(lo[:, 2] - z_hover, surface - hi[:, 2]), 0.0)
    distance = np.sqrt(dx * dx + dy * dy + dz * dz)
    if pad >= 0:
        distance[pad] = np.inf
    return (surface, pad) if distance.min() >= r else None


def _move_is_clear(world: World, start: np.ndarray, end: np.ndarray, clearance_m: float, step_m: float) -> bool:
    """Every point of the straight move start -> end, `step_m` apart (ends included), keeps clearance_m."""
    length = float(np.linalg.norm(end - start))
    if length == 0.0 or len(world.blocks) == 0:
        return True
    fractions = np.linspace(0.0, 1.0, max(2, math.ceil(length / step_m) + 1))
    points = start + fractions[:, None] * (end - start)
    return bool(world.distance_to_blocks(points).min() >= clearance_m)
