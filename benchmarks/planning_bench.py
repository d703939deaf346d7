"""Planning benchmark: our batched A* against a straightforward heapq-and-dict A*, and minimum snap.

Takes in: the course world files in ../shared/worlds (lab mazes test_lab_* and maze_20* at 0.05 m
resolution and 0.25 m margin; p12_test_window at its own resolution and margin); --repeats N.
Gives out: a table on stdout - per world the occupancy-map time, our search time (min and median of N
runs), the baseline's search time (one run, same grid, same start/goal connections), the ratio
baseline/ours, both path lengths (they must agree: both are optimal), both expansion counts and the
time of scipy.sparse.csgraph.dijkstra on the same graph (graph construction included); then
the time of minimum snap through 30 waypoints (time allocation, optimisation, limit scaling) and of the
full maze pipeline (pruning, minimum snap, clearance repair).

Run: python benchmarks/planning_bench.py [--repeats 5]
"""

from __future__ import annotations

import argparse
import heapq
import itertools
import math
import statistics
import sys
import time
from pathlib import Path

import numpy as np

from groundstation.planning import load_planning_params
from groundstation.planning.astar import _connections, astar
from groundstation.planning.occupancy import OccupancyGrid
from groundstation.trajectories.minsnap import MinSnapSettings, min_snap_through, plan_min_snap
from model.vehicle import load_vehicle
from model.world import load_world

# the library alternative (scipy Dijkstra) lives with the tests, which use it as the oracle
sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests" / "groundstation"))

from bench_paths import SHARED_WORLDS  # noqa: E402
from reference_paths import dijkstra_length  # noqa: E402

LAB_RESOLUTION_M, LAB_MARGIN_M = 0.05, 0.25


def baseline_astar(grid: OccupancyGrid, start: np.ndarray, goal: np.ndarray) -> tuple[float, int]:
    """Textbook A*: heapq open list, dicts for g and parents, a closed set, 26 neighbours in Python.

    Same graph as ours (same start/goal connections), so the lengths must agree. Returns (length, expansions).
    """
    res = grid.resolution_m
    shape = grid.shape
    occupied = grid.occupied
    steps = [d for d in itertools.product((-1, 0, 1), repeat=3) if any(d)]
    step_cost = [math.sqrt(sum((d[a] * res[a]) ** 2 for a in range(3))) for d in steps]
    origin = grid.origin_m

    def h(v):
        return math.sqrt(sum((origin[a] + (v[a] + 0.5) * res[a] - goal[a]) ** 2 for a in range(3)))

    src_vox, src_cost = _connections(grid, start)
    tgt_vox, tgt_cost = _connections(grid, goal)
    targets = {tuple(int(x) for x in v): float(c) for v, c in zip(tgt_vox, tgt_cost, strict=True)}
    g: dict[tuple, float] = {}
    parent: dict[tuple, tuple | None] = {}
    heap = []
    for v, c in zip(src_vox, src_cost, strict=True):
        key = tuple(int(x) for x in v)
        g[key] = float(c)
        parent[key] = None
        heapq.heappush(heap, (float(c) + h(key), key))
    closed = set()
    expanded = 0
    best = math.inf
    while heap:
        f, v = heapq.heappop(heap)
        if f >= best:
            break
        if v in closed:
            continue
        closed.add(v)
        expanded += 1
        gv = g[v]
        if v in targets:
            best = min(best, gv + targets[v])
        for d, c in zip(steps, step_cost, strict=True):
            n = (v[0] + d[0], v[1] + d[1], v[2] + d[2])
            if not (0 <= n[0] < shape[0] and 0 <= n[1] < shape[1] and 0 <= n[2] < shape[2]):
                continue
            if occupied[n] or n in closed:
                continue
            ng = gv + c
            if ng < g.get(n, math.inf):
                g[n] = ng
                parent[n] = v
                heapq.heappush(heap, (ng + h(n), n))
    return best, expanded


def cases() -> list[tuple[str, np.ndarray, float]]:
    names = sorted(p.name for p in SHARED_WORLDS.glob("test_lab_*.json")) + sorted(
        p.name for p in SHARED_WORLDS.glob("maze_20*.json")
    )
    out = [(n, np.full(3, LAB_RESOLUTION_M), LAB_MARGIN_M) for n in names]
    window = load_world(SHARED_WORLDS / "p12_test_window.json")
    out.append(("p12_test_window.json", window.resolution, window.margin))
    return out


def timed(fn, repeats: int) -> tuple[list[float], object]:
    times, result = [], None
    for _ in range(repeats):
        t0 = time.perf_counter()
        result = fn()
        times.append(time.perf_counter() - t0)
    return times, result


def bench_astar(repeats: int) -> None:
    print(
        "A*: ours (batched, numpy) vs baseline (heapq + dict), same grid; "
        f"times in ms, ours min/median of {repeats}"
    )
    header = (
        f"{'world':22s} {'res m':>5s} {'marg':>5s} {'map':>6s} {'ours min':>8s} {'ours med':>8s} "
        f"{'ours+map':>8s} {'baseline':>9s} {'ratio':>6s} {'len ours':>9s} {'len base':>9s} "
        f"{'exp ours':>8s} {'exp base':>8s} {'scipy':>7s}"
    )
    print(header)
    print("-" * len(header))
    ratios = []
    for name, res, margin in cases():
        world = load_world(SHARED_WORLDS / name)
        map_times, grid = timed(lambda: OccupancyGrid.from_world(world, res, margin), repeats)  # noqa: B023
        ours_times, ours = timed(lambda: astar(grid, world.start, world.goal), repeats)  # noqa: B023
        t0 = time.perf_counter()
        base_len, base_expanded = baseline_astar(grid, world.start, world.goal)
        base_time = time.perf_counter() - t0
        t0 = time.perf_counter()
        scipy_len = dijkstra_length(grid, world.start, world.goal)
        scipy_time = time.perf_counter() - t0
        best = min(ours_times)
        ratios.append(base_time / best)
        print(
            f"{name:22s} {res[0]:5.2f} {margin:5.2f} {1e3 * min(map_times):6.1f} {1e3 * best:8.1f} "
            f"{1e3 * statistics.median(ours_times):8.1f} {1e3 * (best + min(map_times)):8.1f} "
            f"{1e3 * base_time:9.1f} {base_time / best:6.1f} {ours.length_m:9.4f} {base_len:9.4f} "
            f"{ours.nodes_expanded:8d} {base_expanded:8d} {1e3 * scipy_time:7.1f}"
        )
        if not all(math.isclose(ours.length_m, x, rel_tol=1e-9, abs_tol=1e-9) for x in (base_len, scipy_len)):
            print(f"  !! path lengths differ on {name}", file=sys.stderr)
    print(
        f"speed-up baseline/ours: min {min(ratios):.1f}x, median {statistics.median(ratios):.1f}x, "
        f"max {max(ratios):.1f}x"
    )


def bench_minsnap(repeats: int) -> None:
    settings = MinSnapSettings.from_params(load_planning_params(), load_vehicle("crazyflie"))
    rng = np.random.default_rng(620)
    waypoints = np.cumsum(rng.uniform(-0.6, 0.6, (30, 3)), axis=0)
    times, traj = timed(lambda: min_snap_through(waypoints, settings), repeats)
    print(
        f"\nminimum snap through 30 waypoints (29 segments; allocation + time optimisation + limit scaling): "
        f"min {1e3 * min(times):.1f} ms, median {1e3 * statistics.median(times):.1f} ms "
        f"(duration {traj.duration_s:.2f} s)"
    )
    sample_times, _ = timed(lambda: [traj.sample(t) for t in np.linspace(0, traj.duration_s, 1000)], repeats)
    print(f"sample(): {1e3 * min(sample_times):.1f} us per call (min of {repeats} x 1000 calls)")
    print("\nmaze pipeline (pruning + minimum snap + clearance repair, A* at 0.05 m / 0.25 m):")
    print(
        f"{'world':22s} {'ms min':>7s} {'ms med':>7s} {'waypts':>6s} {'repairs':>7s} "
        f"{'clear m':>7s} {'T s':>6s}"
    )
    for name, res, margin in cases():
        world = load_world(SHARED_WORLDS / name)
        path = astar(OccupancyGrid.from_world(world, res, margin), world.start, world.goal).path_m
        t, plan = timed(lambda: plan_min_snap(path, world, margin, settings), max(1, repeats // 2))  # noqa: B023
        print(
            f"{name:22s} {1e3 * min(t):7.1f} {1e3 * statistics.median(t):7.1f} {len(plan.path_positions):6d} "
            f"{plan.repairs:7d} {plan.min_clearance_m:7.3f} {plan.trajectory.duration_s:6.2f}"
        )


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=5)
    args = parser.parse_args()
    if not SHARED_WORLDS.is_dir():
        print(f"world files not found at {SHARED_WORLDS}", file=sys.stderr)
        return 2
    bench_astar(args.repeats)
    bench_minsnap(args.repeats)
    return 0


if __name__ == "__main__":
    sys.exit(main())
