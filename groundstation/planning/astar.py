"""A* shortest paths on an occupancy grid, from the exact start point to the exact goal point.

Takes in: an `OccupancyGrid` (or a `World`, a resolution (m) and a margin (m)), a start and a goal
point (3,) m, ENU.
Gives out: a `PathResult` - found, the path (M, 3) m starting exactly at the start and ending exactly
at the goal, its length (m), the number of node expansions and the planning time (s).

Graph: free voxels, 26-connected, step cost = Euclidean distance between voxel centres; heuristic
h = Euclidean distance from the voxel centre to the goal point (admissible and consistent). The result
is optimal on this graph.

Search (batched label-correcting A*, exact): every iteration expands, at once and vectorised with
numpy, all open voxels whose f = g + h lies within `batch_width_m` of the smallest open f. A voxel whose
g improves again after expansion is re-opened and expanded again (label correcting), and the search
stops when the best goal cost found is <= the smallest open f; since f is a lower bound on any path
through an open voxel, the path returned is optimal whatever the batch width. With a width below the
smallest step cost almost no voxel is expanded twice (as in delta-stepping). `nodes_expanded` counts
every expansion, re-expansions included. This replaces ~26 Python operations per expansion of a
heapq-and-dict A* by a few numpy operations per batch of many voxels (see benchmarks/planning_bench.py).

Start and goal: the start point connects to the centre of its own voxel (cost = the distance between
them). When that voxel is occupied - the start lies within the margin plus a voxel diagonal of a block,
or its voxel centre is outside the bounds - the start instead connects to the nearest free voxel
centres it can see along a straight segment that keeps at least min(margin, start clearance) from the
blocks (the vehicle is already there, so the planner leads it out of the margin along the shortest
such segment rather than giving up). The goal is handled the same way. A start and goal in one free
voxel are joined directly. A start or goal outside the bounds or inside a block is a UserError.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field, replace
from itertools import product

import numpy as np

from groundstation.planning.occupancy import OccupancyGrid, segments_are_free
from model.errors import UserError
from model.world import World

# Candidate voxels for leaving an occupied start/goal voxel are tested in chunks of this many,
# nearest first (each test is an exact segment-box distance against every block).
_ESCAPE_CHUNK = 64
# Relative shrink of the clearance an escape segment must keep, so that a segment leaving the start
# exactly at the start's own clearance is accepted despite rounding.
_ESCAPE_CLEARANCE_TOLERANCE = 1e-9


@dataclass(frozen=True)
class PathResult:
    found: bool
    path_m: np.ndarray  # (M, 3) start, voxel centres, goal; (0, 3) when not found
    length_m: float  # inf when not found
    nodes_expanded: int
    planning_time_s: float
    message: str = ""
    voxel_indices: np.ndarray = field(default_factory=lambda: np.zeros((0, 3), int))  # of the centres

    @property
    def path(self) -> np.ndarray:
        return self.path_m


def plan_path(
    world: World, resolution_m, margin_m: float, start_m=None, goal_m=None, batch_width_voxels: float = 1.0
) -> PathResult:
    """Build the occupancy grid and search it; planning_time_s covers both."""
    t0 = time.perf_counter()
    grid = OccupancyGrid.from_world(world, resolution_m, margin_m)
    result = astar(
        grid,
        world.start if start_m is None else start_m,
        world.goal if goal_m is None else goal_m,
        batch_width_voxels=batch_width_voxels,
    )
    return replace(result, planning_time_s=time.perf_counter() - t0)


def astar(grid: OccupancyGrid, start_m, goal_m, batch_width_voxels: float = 1.0) -> PathResult:
    """Optimal 26-connected path on `grid` from the exact `start_m` to the exact `goal_m`.

    batch_width_voxels: width of each expansion batch in f, as a multiple of the smallest voxel size;
    it changes the speed only, never the path length.
    """
    t0 = time.perf_counter()
    if start_m is None or goal_m is None:
        raise UserError(f"{grid.world.source}: no start or goal to plan between")
    start = _checked_endpoint(grid, start_m, "start")
    goal = _checked_endpoint(grid, goal_m, "goal")
    own = grid.metric_to_index(start)
    if np.array_equal(own, grid.metric_to_index(goal)) and not grid.is_occupied_index(own):
        # Both in one free voxel: the straight segment stays inside its box, clear of the margin.
        points = start[None] if np.array_equal(start, goal) else np.vstack([start, goal])
        return PathResult(
            True, points, float(np.linalg.norm(goal - start)), 0, time.perf_counter() - t0, "", own[None]
        )
    sources = _connections(grid, start)
    targets = _connections(grid, goal)
    if len(sources[0]) == 0 or len(targets[0]) == 0:
        which = "start" if len(sources[0]) == 0 else "goal"
        return PathResult(
            False,
            np.zeros((0, 3)),
            np.inf,
            0,
            time.perf_counter() - t0,
            f"no free voxel can be reached in a straight line from the {which}",
        )
    search = _Search(grid, goal, batch_width_voxels * float(grid.resolution_m.min()))
    end_voxel = search.run(sources, targets)
    if end_voxel < 0:
        return PathResult(
            False,
            np.zeros((0, 3)),
            np.inf,
            search.expanded,
            time.perf_counter() - t0,
            "no path: the goal cannot be reached from the start at this resolution and margin",
        )
    voxels = search.voxel_chain(end_voxel)
    points = np.vstack([start, grid.index_to_metric_center(voxels), goal])
    # Drop zero-length steps (a point exactly on a voxel centre); the kept copy is bitwise equal.
    points = points[np.r_[True, np.any(np.diff(points, axis=0) != 0, axis=1)]]
    length = float(np.linalg.norm(np.diff(points, axis=0), axis=1).sum())
    return PathResult(True, points, length, search.expanded, time.perf_counter() - t0, "", voxels)


def _checked_endpoint(grid: OccupancyGrid, point, name: str) -> np.ndarray:
    p = np.asarray(point, float).reshape(-1)
    if p.shape != (3,) or not np.all(np.isfinite(p)):
        raise UserError(f"{name} must be 3 finite numbers, got {np.asarray(point).tolist()}")
    if not grid.world.contains(p):
        raise UserError(f"{grid.world.source}: {name} {p.tolist()} is outside the bounds")
    if grid.world.inside_block(p):
        raise UserError(f"{grid.world.source}: {name} {p.tolist()} is inside a block")
    return p


def _connections(grid: OccupancyGrid, point: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Voxels (K, 3) the exact point connects to, and the straight-line cost (K,) of each connection."""
    own = grid.metric_to_index(point)
    if not grid.is_occupied_index(own):
        return own[None], np.array([np.linalg.norm(grid.index_to_metric_center(own) - point)])
    clearance = min(grid.margin_m, float(grid.world.distance_to_blocks(point)))
    required = clearance * (1 - _ESCAPE_CLEARANCE_TOLERANCE)
    reach = int(np.ceil((grid.margin_m + 2 * np.linalg.norm(grid.resolution_m)) / grid.resolution_m.min()))
    lo = np.maximum(own - reach, 0)
    hi = np.minimum(own + reach + 1, np.array(grid.shape))
    box = grid.occupied[lo[0] : hi[0], lo[1] : hi[1], lo[2] : hi[2]]
    candidates = np.argwhere(~box) + lo
    if len(candidates) == 0:
        return np.zeros((0, 3), int), np.zeros(0)
    cost = np.linalg.norm(grid.index_to_metric_center(candidates) - point, axis=1)
    order = np.argsort(cost, kind="stable")
    for chunk in range(0, len(order), _ESCAPE_CHUNK):
        pick = order[chunk : chunk + _ESCAPE_CHUNK]
        centres = grid.index_to_metric_center(candidates[pick])
        visible = segments_are_free(grid.world, np.broadcast_to(point, centres.shape), centres, required)
        if visible.any():
            return candidates[pick[visible]], cost[pick[visible]]
    return np.zeros((0, 3), int), np.zeros(0)


class _Search:
    """Batched label-correcting A* over a padded flat copy of the grid (a wall of occupied voxels
    around it, so neighbour indices never need a bounds check)."""

    def __init__(self, grid: OccupancyGrid, goal: np.ndarray, batch_width_m: float):
        nx, ny, nz = grid.shape
        self.padded_shape = (nx + 2, ny + 2, nz + 2)
        padded = np.ones(self.padded_shape, bool)
        padded[1:-1, 1:-1, 1:-1] = grid.occupied
        self.free = ~padded.ravel()
        self.strides = np.array([(ny + 2) * (nz + 2), nz + 2, 1])
        steps = np.array([d for d in product((-1, 0, 1), repeat=3) if any(d)])
        self.offsets = steps @ self.strides
        self.step_costs = np.linalg.norm(steps * grid.resolution_m, axis=1)
        self.grid = grid
        self.batch_width_m = batch_width_m
        self.heuristic = self._heuristic(goal)
        size = padded.size
        self.cost = np.full(size, np.inf)
        self.parent = np.full(size, -1, np.int64)
        self.is_open = np.zeros(size, bool)
        self.goal_extra = np.full(size, np.inf)  # cost of the final straight segment, at goal voxels
        self.expanded = 0

    def _heuristic(self, goal: np.ndarray) -> np.ndarray:
        res, origin = self.grid.resolution_m, self.grid.origin_m
        axes = [origin[a] + (np.arange(self.padded_shape[a]) - 0.5) * res[a] - goal[a] for a in range(3)]
        h2 = axes[0][:, None, None] ** 2 + axes[1][None, :, None] ** 2 + axes[2][None, None, :] ** 2
        return np.sqrt(h2).ravel()

    def flat(self, index: np.ndarray) -> np.ndarray:
        return (np.asarray(index) + 1) @ self.strides

    def run(self, sources: tuple[np.ndarray, np.ndarray], targets: tuple[np.ndarray, np.ndarray]) -> int:
        """Search from the source voxels to the target voxels; the flat index of the best target or -1."""
        src, src_cost = self.flat(sources[0]), sources[1]
        tgt, tgt_cost = self.flat(targets[0]), targets[1]
        np.minimum.at(self.goal_extra, tgt, tgt_cost)
        np.minimum.at(self.cost, src, src_cost)
        open_nodes = np.unique(src)
        self.is_open[open_nodes] = True
        totals = self.cost[open_nodes] + self.goal_extra[open_nodes]
        best_cost = totals.min()
        best = int(open_nodes[totals.argmin()]) if np.isfinite(best_cost) else -1
        cost, heuristic, free = self.cost, self.heuristic, self.free
        while open_nodes.size:
            f = cost[open_nodes] + heuristic[open_nodes]
            f_min = f.min()
            if best_cost <= f_min:
                break
            in_batch = f < f_min + self.batch_width_m
            batch = open_nodes[in_batch]
            open_nodes = open_nodes[~in_batch]
            self.is_open[batch] = False
            self.expanded += batch.size
            neighbours = (batch[:, None] + self.offsets).ravel()
            new_cost = (cost[batch][:, None] + self.step_costs).ravel()
            better = free[neighbours] & (new_cost < cost[neighbours])
            if not better.any():
                continue
            neighbours, new_cost = neighbours[better], new_cost[better]
            parents = np.repeat(batch, len(self.offsets))[better]
            order = np.lexsort((new_cost, neighbours))  # cheapest offer per neighbour first
            neighbours = neighbours[order]
            first = np.r_[True, neighbours[1:] != neighbours[:-1]]
            neighbours, new_cost, parents = neighbours[first], new_cost[order][first], parents[order][first]
            cost[neighbours] = new_cost
            self.parent[neighbours] = parents
            totals = new_cost + self.goal_extra[neighbours]
            k = totals.argmin()
            if totals[k] < best_cost:
                best_cost, best = totals[k], int(neighbours[k])
            reopened = neighbours[~self.is_open[neighbours]]
            self.is_open[reopened] = True
            open_nodes = np.concatenate([open_nodes, reopened])
        return best

    def voxel_chain(self, end: int) -> np.ndarray:
        """Grid indices (K, 3) from a source voxel to `end`."""
        chain = [end]
        while self.parent[chain[-1]] >= 0:
            chain.append(int(self.parent[chain[-1]]))
        flat = np.array(chain[::-1])
        return np.stack(np.unravel_index(flat, self.padded_shape), axis=-1) - 1
