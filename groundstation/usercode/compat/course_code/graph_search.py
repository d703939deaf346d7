"""The course's `graph_search(world, resolution, margin, start, goal, astar)`, backed by cfstack's A*.

Takes in: a flightsim-compatible World, voxel size (m), margin (m), start and goal (m, world ENU).
Gives out: (path, nodes_expanded) as the course defines it since 2021: path (N, 3) from start to goal
through voxel centres, or None when there is none. cfstack's search is A* with an admissible heuristic,
so astar=False (Dijkstra in the course) returns a path of the same, shortest, length.
"""

from __future__ import annotations

import numpy as np

from groundstation.planning.astar import astar as astar_search
from groundstation.planning.occupancy import OccupancyGrid
from groundstation.usercode.compat.course_code.occupancy_map import model_world


def graph_search(world, resolution, margin, start, goal, astar=True):  # noqa: ARG001 (see above)
    grid = OccupancyGrid.from_world(model_world(world), resolution, float(margin))
    result = astar_search(grid, np.asarray(start, float), np.asarray(goal, float))
    return (result.path_m if result.found else None), int(result.nodes_expanded)
