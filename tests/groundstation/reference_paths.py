"""A reference shortest path through an occupancy grid, by a library: the free-voxel graph (26-connected,
edge cost = metric step length) as a scipy sparse matrix and scipy.sparse.csgraph.dijkstra (C, no
heuristic, no early exit). The oracle A* is tested against (test_astar.py) and the library
alternative it is timed against (benchmarks/planning_bench.py)."""

from __future__ import annotations

from itertools import product

import numpy as np
import scipy.sparse
import scipy.sparse.csgraph

from groundstation.planning.occupancy import OccupancyGrid


def dijkstra_length(grid: OccupancyGrid, start: np.ndarray, goal: np.ndarray) -> float:
    """Shortest start -> start voxel centre -> ... -> goal voxel centre -> goal length (m)."""
    shape = grid.shape
    free = ~grid.occupied
    ids = np.full(shape, -1)
    ids[free] = np.arange(free.sum())
    rows, cols, costs = [], [], []
    for d in product((-1, 0, 1), repeat=3):
        if not any(d):
            continue
        src = tuple(slice(max(0, -k), shape[a] - max(0, k)) for a, k in enumerate(d))
        dst = tuple(slice(max(0, k), shape[a] - max(0, -k)) for a, k in enumerate(d))
        both = free[src] & free[dst]
        rows.append(ids[src][both])
        cols.append(ids[dst][both])
        costs.append(np.full(both.sum(), np.linalg.norm(np.array(d) * grid.resolution_m)))
    n = int(free.sum())
    graph = scipy.sparse.csr_matrix(
        (np.concatenate(costs), (np.concatenate(rows), np.concatenate(cols))), (n, n)
    )
    s_vox, g_vox = grid.metric_to_index(start), grid.metric_to_index(goal)
    dist = scipy.sparse.csgraph.dijkstra(graph, indices=ids[tuple(s_vox)])
    return float(
        np.linalg.norm(start - grid.index_to_metric_center(s_vox))
        + dist[ids[tuple(g_vox)]]
        + np.linalg.norm(goal - grid.index_to_metric_center(g_vox))
    )
