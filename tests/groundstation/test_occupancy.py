"""Occupancy grid and exact segment-box distances, against the geometric definitions."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from groundstation.planning.occupancy import OccupancyGrid, segment_box_distance, segments_clearance
from model.world import World


def world_with(blocks, bounds=(0.0, 4.0, 0.0, 3.0, 0.0, 2.0)) -> World:
    return World(bounds=np.array(bounds, float), blocks=np.array(blocks, float).reshape(-1, 6))


def sampled_box_distance(world: World, lo: np.ndarray, hi: np.ndarray, n: int = 9) -> float:
    """Smallest block distance over an n^3 lattice of points filling the box [lo, hi] (>= the true one)."""
    axes = [np.linspace(lo[a], hi[a], n) for a in range(3)]
    points = np.stack(np.meshgrid(*axes, indexing="ij"), axis=-1).reshape(-1, 3)
    return float(world.distance_to_blocks(points).min())


def test_grid_shape_is_ceil_of_extent_over_resolution_without_rounding_up_exact_multiples():
    world = World(bounds=np.array([-2.2, 3.5, -2.25, 2.1, 0.0, 1.9]), blocks=np.zeros((0, 6)))
    grid = OccupancyGrid.from_world(world, 0.05, 0.25)
    # 5.7/0.05 = 114, 4.35/0.05 = 87, 1.9/0.05 = 38 exactly, though 5.7/0.05 is 114.00000000000001 in floats
    assert grid.shape == (114, 87, 38)
    grid = OccupancyGrid.from_world(world, [0.4, 1.0, 0.5], 0.1)
    assert grid.shape == (math.ceil(5.7 / 0.4), math.ceil(4.35 / 1.0), math.ceil(1.9 / 0.5))


def test_voxel_is_occupied_exactly_when_its_box_is_within_the_margin_of_a_block_or_its_centre_of_a_wall():
    rng = np.random.default_rng(3)
    blocks = []
    for _ in range(4):
        lo = rng.uniform([0, 0, 0], [3.5, 2.5, 1.5])
        blocks.append(np.ravel(np.column_stack([lo, lo + rng.uniform(0.05, 0.6, 3)])))
    world = world_with(blocks)
    res, margin = np.array([0.2, 0.25, 0.3]), 0.15
    grid = OccupancyGrid.from_world(world, res, margin)
    for index in np.ndindex(grid.shape):
        centre = grid.index_to_metric_center(index)
        if np.any(centre > world.bounds[1::2] - margin) or np.any(centre < world.bounds[0::2] + margin):
            assert grid.occupied[index]  # centre within the margin of a wall, or beyond it
            continue
        lo, hi = centre - res / 2, centre + res / 2
        sampled = sampled_box_distance(world, lo, hi)
        if grid.occupied[index]:
            # true box distance <= margin; the lattice overestimates it by at most half a lattice diagonal
            assert sampled <= margin + np.linalg.norm(res / 8) / 2 + 1e-12
        else:
            assert sampled > margin


def test_every_point_of_a_free_voxel_clears_the_margin():
    world = world_with([[1.0, 1.3, 0.5, 2.5, 0.0, 1.2], [2.5, 3.0, 0.0, 1.0, 0.5, 2.0]])
    grid = OccupancyGrid.from_world(world, 0.1, 0.2)
    free = np.argwhere(~grid.occupied)
    rng = np.random.default_rng(0)
    centres = grid.index_to_metric_center(free)
    points = centres + rng.uniform(-0.05, 0.05, centres.shape)
    assert np.all(world.distance_to_blocks(points) > 0.2)


def test_path_points_stay_inside_the_bounds_minus_the_margin_at_a_coarse_resolution():
    """Issue 14: with a 1 m voxel the course-style grid put a path point exactly on the bounds (y = ymax)."""
    from groundstation.planning.astar import plan_path

    world = World(bounds=np.array([0.0, 4.5, 0.0, 6.5, 0.0, 3.0]), blocks=np.zeros((0, 6)))
    margin = 0.1
    result = plan_path(world, 1.0, margin, [1.0, 1.0, 1.0], [3.0, 6.0, 2.0])
    inner = result.path_m[1:-1]  # the voxel centres between the exact start and goal
    assert result.found and len(inner)
    assert np.all(inner >= world.bounds[0::2] + margin) and np.all(inner <= world.bounds[1::2] - margin)


def test_voxel_centre_outside_the_upper_bound_is_occupied():
    world = World(bounds=np.array([0.0, 1.0, 0.0, 1.0, 0.0, 1.0]), blocks=np.zeros((0, 6)))
    grid = OccupancyGrid.from_world(world, 0.3, 0.0)  # 4 voxels per axis, the last centred at 1.05
    assert grid.shape == (4, 4, 4)
    assert grid.occupied[3].all() and grid.occupied[:, 3].all() and grid.occupied[:, :, 3].all()
    assert not grid.occupied[:3, :3, :3].any()


def test_index_and_metric_conversions_are_inverse_and_the_upper_bound_maps_to_the_last_voxel():
    world = World(bounds=np.array([-1.0, 2.0, 0.5, 1.5, 0.0, 1.0]), blocks=np.zeros((0, 6)))
    grid = OccupancyGrid.from_world(world, [0.1, 0.25, 0.2], 0.1)
    index = np.array(list(np.ndindex(grid.shape)))
    centres = grid.index_to_metric_center(index)
    assert np.allclose(centres[0], [-0.95, 0.625, 0.1])
    assert np.array_equal(grid.metric_to_index(centres), index)
    assert np.array_equal(grid.metric_to_index(world.bounds[1::2]), np.array(grid.shape) - 1)
    assert grid.is_occupied_index([-1, 0, 0]) and grid.is_occupied_index(list(grid.shape))


def test_segment_distance_known_geometry():
    box = np.array([[0.0, 1.0, 0.0, 1.0, 0.0, 1.0]])
    cases = [
        ([-1.0, 1.3, 0.5], [2.0, 1.3, 0.5], 0.3),  # parallel to a face
        ([-1.0, 0.5, 0.5], [2.0, 0.5, 0.5], 0.0),  # through the box
        ([3.0, 0.0, 0.5], [0.0, 3.0, 0.5], 1.0 / math.sqrt(2.0)),  # passing a vertical edge at x = y = 1
        ([3.0, 0.0, 2.0], [0.0, 3.0, 2.0], math.sqrt(1.5)),  # passing the top edge at (1, 1, 1)
        ([2.0, 2.0, 2.0], [3.0, 3.0, 3.0], math.sqrt(3.0)),  # moving away: nearest at its start
        ([1.5, 0.5, 0.5], [1.5, 0.5, 0.5], 0.5),  # a point
    ]
    for p0, p1, expected in cases:
        assert segment_box_distance(np.array([p0]), np.array([p1]), box)[0, 0] == pytest.approx(
            expected, abs=1e-12
        )


def test_segment_distance_matches_dense_sampling_of_the_segment():
    rng = np.random.default_rng(11)
    boxes = np.sort(rng.uniform(-1, 1, (20, 3, 2)), axis=-1).reshape(20, 6)
    p0 = rng.uniform(-2, 2, (60, 3))
    p1 = rng.uniform(-2, 2, (60, 3))
    p1[:5, 1:] = p0[:5, 1:]  # axis-parallel segments: divisions by zero direction components
    exact = segment_box_distance(p0, p1, boxes)
    world = World(bounds=np.array([-3, 3, -3, 3, -3, 3.0]), blocks=boxes)
    s = np.linspace(0, 1, 4001)
    for i in range(len(p0)):
        points = p0[i] + s[:, None] * (p1[i] - p0[i])
        step = np.linalg.norm(p1[i] - p0[i]) / (len(s) - 1)
        lo, hi = boxes[:, 0::2], boxes[:, 1::2]
        gap = np.maximum(np.maximum(lo - points[:, None], points[:, None] - hi), 0.0)
        sampled = np.sqrt((gap**2).sum(-1)).min(0)
        assert np.all(exact[i] <= sampled + 1e-12)  # never above a distance actually reached
        assert np.all(exact[i] >= sampled - step / 2 - 1e-12)  # distance is 1-Lipschitz along the segment
    # the pruned variant (lower bounds beyond the cutoff) agrees on every segment within the cutoff
    clearance = segments_clearance(world, p0, p1, cutoff_m=0.3)
    near = exact.min(1) <= 0.3
    assert np.allclose(clearance[near], exact.min(1)[near])
    assert np.all(clearance[~near] > 0.3)


coordinate = st.floats(-2.0, 2.0, allow_nan=False)
point = st.tuples(coordinate, coordinate, coordinate)


@settings(max_examples=150, deadline=None, derandomize=True)
@given(
    p0=point, p1=point, corner=point, size=st.tuples(*[st.floats(0.01, 1.0)] * 3), margin=st.floats(0.0, 0.5)
)
def test_segment_is_never_free_when_some_point_of_it_is_within_the_margin(p0, p1, corner, size, margin):
    lo = np.array(corner)
    block = np.ravel(np.column_stack([lo, lo + np.array(size)]))
    world = World(bounds=np.array([-4, 4, -4, 4, -4, 4.0]), blocks=block[None])
    grid = OccupancyGrid(
        world=world,
        resolution_m=np.full(3, 0.1),
        margin_m=margin,
        origin_m=np.full(3, -4.0),
        occupied=np.zeros((1, 1, 1), bool),
    )
    s = np.linspace(0, 1, 2001)
    points = np.array(p0) + s[:, None] * (np.array(p1) - np.array(p0))
    if world.distance_to_blocks(points).min() <= margin:
        assert not grid.segment_is_free(p0, p1)


def test_segment_leaving_the_bounds_is_not_free():
    world = world_with([])
    grid = OccupancyGrid.from_world(world, 0.1, 0.1)
    assert grid.segment_is_free([0.5, 0.5, 0.5], [3.5, 2.5, 1.5])
    assert not grid.segment_is_free([0.5, 0.5, 0.5], [4.5, 2.5, 1.5])
