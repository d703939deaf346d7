"""A* on the course's graph-search test worlds, and optimality against scipy's Dijkstra."""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import pytest

from groundstation.planning.astar import astar, plan_path
from groundstation.planning.occupancy import OccupancyGrid
from groundstation.planning.pruning import prune_waypoints
from model.errors import UserError
from model.world import World, load_world

sys.path.insert(0, str(Path(__file__).resolve().parent))

from reference_paths import dijkstra_length  # noqa: E402
from testsupport import shared_world  # noqa: E402


def course_world(name: str) -> World:
    return load_world(shared_world(name.removesuffix(".json")))


def densify(path: np.ndarray, spacing_m: float = 1e-3) -> np.ndarray:
    """Points along the polyline at most `spacing_m` apart (vertices included)."""
    pieces = [path[:1]]
    for a, b in zip(path[:-1], path[1:], strict=True):
        n = max(1, int(np.ceil(np.linalg.norm(b - a) / spacing_m)))
        s = np.arange(1, n + 1) / n
        pieces.append(a + s[:, None] * (b - a))
    return np.vstack(pieces)


@pytest.mark.parametrize(
    "name", ["test_empty.json", "test_saw.json", "test_forest.json", "p12_test_window.json"]
)
def test_course_graph_search_cases(name):
    world = course_world(name)
    result = plan_path(world, world.resolution, world.margin)
    assert result.found
    path = result.path_m
    assert np.linalg.norm(path[0] - world.start) <= 1e-3
    assert np.linalg.norm(path[-1] - world.goal) <= 1e-3
    assert np.all(world.distance_to_blocks(densify(path)) >= world.margin - 1e-9)
    assert np.all(world.contains(path))
    assert result.length_m == pytest.approx(np.linalg.norm(np.diff(path, axis=0), axis=1).sum())
    assert result.length_m <= world.expected_path_length + 2 * np.linalg.norm(world.resolution)
    assert result.nodes_expanded > 0 and result.planning_time_s > 0


def test_impossible_world_has_no_path():
    world = course_world("test_impossible.json")
    result = plan_path(world, world.resolution, world.margin)
    assert not result.found
    assert result.path_m.shape == (0, 3) and result.length_m == np.inf
    assert "no path" in result.message


def test_lab_maze_at_fine_resolution_clears_the_margin():
    world = course_world("maze_2022_1.json")
    result = plan_path(world, 0.05, 0.25)
    assert result.found
    assert np.array_equal(result.path_m[0], world.start) and np.array_equal(result.path_m[-1], world.goal)
    assert np.all(world.distance_to_blocks(densify(result.path_m)) >= 0.25 - 1e-9)


@pytest.mark.parametrize("seed", range(6))
def test_path_length_is_optimal_on_the_grid(seed):
    rng = np.random.default_rng(seed)
    bounds = np.array([0.0, 3.0, 0.0, 2.0, 0.0, 1.5])
    lo = rng.uniform(bounds[0::2], bounds[1::2] - 0.2, (8, 3))
    blocks = np.stack([lo, lo + rng.uniform(0.1, 0.8, (8, 3))], axis=-1).reshape(8, 6)
    world = World(bounds=bounds, blocks=blocks)
    res = rng.choice([0.1, 0.15, 0.2], 3)
    grid = OccupancyGrid.from_world(world, res, 0.1)
    free = np.argwhere(~grid.occupied)
    i, j = rng.choice(len(free), 2, replace=False)
    start = grid.index_to_metric_center(free[i]) + rng.uniform(-0.4, 0.4, 3) * res
    goal = grid.index_to_metric_center(free[j]) + rng.uniform(-0.4, 0.4, 3) * res
    reference = dijkstra_length(grid, start, goal)
    for width in (0.25, 1.0, 4.0):  # the batch width changes the speed, never the optimum
        result = astar(grid, start, goal, batch_width_voxels=width)
        assert result.found == np.isfinite(reference)
        if result.found:
            assert result.length_m == pytest.approx(reference, rel=1e-12)


def wall_world() -> World:
    """A floor-to-ceiling wall from y = 0 to 1.4 m; the gap to the far wall (y = 2.5) is passable with a 0.3 m
    margin at both the wall and the bounds (the planner keeps the margin from the bounds too)."""
    return World(
        bounds=np.array([0.0, 3.0, 0.0, 2.5, 0.0, 1.5]), blocks=np.array([[1.0, 1.1, 0.0, 1.4, 0.0, 1.5]])
    )


def test_start_inside_the_margin_leads_out_along_a_segment_no_closer_than_the_start():
    world = wall_world()
    start = np.array([0.95, 0.5, 0.5])  # 0.05 m from the wall, margin 0.3
    goal = np.array([2.5, 0.5, 0.5])
    result = plan_path(world, 0.1, 0.3, start, goal)
    assert result.found
    path = result.path_m
    assert np.array_equal(path[0], start) and np.array_equal(path[-1], goal)
    first_leg = densify(path[:2])
    assert world.distance_to_blocks(first_leg).min() >= 0.05 - 1e-9
    assert np.all(world.distance_to_blocks(densify(path[1:])) >= 0.3 - 1e-9)


def test_start_outside_the_margin_in_an_occupied_voxel_keeps_the_margin():
    world = wall_world()
    start = np.array([0.73, 0.35, 0.55])  # 0.27 m from the wall; its voxel [0.7, 0.8] is 0.2 m from it
    goal = np.array([2.5, 0.5, 0.5])
    grid = OccupancyGrid.from_world(world, 0.1, 0.25)
    assert grid.is_occupied_index(grid.metric_to_index(start))
    result = astar(grid, start, goal)
    assert result.found and np.array_equal(result.path_m[0], start)
    assert np.all(world.distance_to_blocks(densify(result.path_m)) >= 0.25 - 1e-9)


def test_goal_inside_the_margin_is_reached_exactly():
    world = wall_world()
    result = plan_path(world, 0.1, 0.3, [0.3, 0.5, 0.5], [1.15, 0.7, 0.5])  # goal 0.05 m beside the wall
    assert result.found and np.array_equal(result.path_m[-1], [1.15, 0.7, 0.5])


@pytest.mark.parametrize(
    "point, problem", [([1.05, 0.5, 0.5], "inside a block"), ([3.5, 0.5, 0.5], "outside")]
)
def test_start_in_a_block_or_outside_the_bounds_is_a_user_error(point, problem):
    with pytest.raises(UserError, match=problem):
        plan_path(wall_world(), 0.1, 0.1, point, [2.5, 0.5, 0.5])


def test_start_equal_to_goal_is_a_zero_length_path():
    result = plan_path(wall_world(), 0.1, 0.1, [0.5, 0.5, 0.5], [0.5, 0.5, 0.5])
    assert result.found and result.length_m == 0.0
    assert np.array_equal(result.path_m[0], [0.5, 0.5, 0.5]) and np.array_equal(
        result.path_m[-1], [0.5, 0.5, 0.5]
    )


def test_pruned_waypoints_keep_the_ends_see_each_other_and_are_greedy():
    world = course_world("test_lab_1.json")
    margin = 0.2
    path = plan_path(world, 0.1, margin).path_m
    kept = prune_waypoints(path, world, margin)
    assert kept[0] == 0 and kept[-1] == len(path) - 1 and np.all(np.diff(kept) > 0)
    assert len(kept) < len(path)
    for a, b in zip(kept[:-1], kept[1:], strict=True):
        assert np.all(
            world.distance_to_blocks(densify(path[[a, b]])) > margin
        )  # clear, on the continuous segment
        if b + 1 < len(path):  # greedy: the anchor could not see the point after the one kept
            beyond = densify(path[[a, b + 1]])
            # (1 mm samples: the exact minimum is at most 0.5 mm below the sampled one)
            assert world.distance_to_blocks(beyond).min() <= margin + 0.5e-3 or not np.all(
                world.contains(beyond)
            )
