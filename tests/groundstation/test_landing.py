"""groundstation.landing: the landing spot after the goal. Straight down when that descent is clear; else the
nearest spot whose descent keeps collision radius + safety from every block and whose footprint lies inside
a pad's top face; None when nothing is clear within the search radius."""

import math

import numpy as np

from groundstation.landing import LandingSettings, find_landing_spot
from groundstation.mission import load_mission_params
from model.world import World

RADIUS_M = 0.069
SETTINGS = load_mission_params().landing


def clearance(settings: LandingSettings = SETTINGS) -> float:
    return RADIUS_M + settings.safety_m


def room(*blocks) -> World:
    return World(bounds=np.array([0.0, 6.0, 0.0, 8.0, 0.0, 3.0]), blocks=np.array(blocks, float).reshape(-1, 6))


def test_clear_floor_lands_straight_down():
    spot = find_landing_spot(room([4.0, 5.0, 4.0, 5.0, 0.0, 1.0]), [1.0, 1.0, 1.0], RADIUS_M, SETTINGS)
    assert spot.moved_m == 0.0 and spot.on_pad == -1 and np.allclose(spot.touchdown_m, [1.0, 1.0, 0.0])


def test_the_middle_of_a_pad_lands_on_the_pad():
    spot = find_landing_spot(room([1.0, 3.0, 1.0, 3.0, 0.0, 0.5]), [2.0, 2.0, 1.0], RADIUS_M, SETTINGS)
    assert spot.on_pad == 0 and spot.moved_m == 0.0 and math.isclose(spot.touchdown_m[2], 0.5)


def test_a_goal_over_a_pads_edge_moves_onto_the_pad_or_off_it_far_enough():
    # The student map of issue 14: a block spanning y 4..6, the goal at y = 6.0 right above its edge.
    block = [0.0, 6.0, 4.0, 6.0, 0.0, 0.5]
    w = room(block)
    spot = find_landing_spot(w, [3.0, 6.0, 1.0], RADIUS_M, SETTINGS)
    assert spot is not None and 0.0 < spot.moved_m <= SETTINGS.search_radius_m
    x, y, z = spot.touchdown_m
    if spot.on_pad == 0:  # the footprint lies inside the top face
        assert 4.0 + clearance() <= y <= 6.0 - clearance() and math.isclose(z, 0.5)
    else:  # on the floor, and the whole descent column keeps the clearance to the block
        column = np.column_stack([np.full(50, x), np.full(50, y), np.linspace(0.0, 1.0, 50)])
        assert w.distance_to_blocks(column).min() >= clearance() - 1e-12
    # the nearest clear spot: nothing on a ring closer than this one is clear, so it is within one step of
    # the 0.1 m the vehicle must move off the edge (onto the floor side: y >= 6 + clearance)
    assert spot.moved_m <= clearance() + SETTINGS.search_step_m


def test_no_clear_spot_within_the_search_radius_gives_none():
    # a narrow shaft of floor between two tall blocks, narrower than two clearances
    gap = clearance()  # half of what the vehicle needs
    w = room([0.0, 3.0 - gap / 2, 0.0, 8.0, 0.0, 3.0], [3.0 + gap / 2, 6.0, 0.0, 8.0, 0.0, 3.0])
    assert find_landing_spot(w, [3.0, 4.0, 1.0], RADIUS_M, SETTINGS) is None


def test_the_move_to_the_spot_keeps_clear_of_blocks():
    # straight below is a pillar top too small for the footprint; the path sideways must not cut a wall
    pillar = [2.95, 3.05, 3.95, 4.05, 0.0, 0.9]
    w = room(pillar)
    spot = find_landing_spot(w, [3.0, 4.0, 1.0], RADIUS_M, SETTINGS)
    assert spot is not None and spot.on_pad == -1 and spot.moved_m > 0.0
    column = np.column_stack([np.full(20, spot.touchdown_m[0]), np.full(20, spot.touchdown_m[1]),
                              np.linspace(0.0, 1.0, 20)])
    assert w.distance_to_blocks(column).min() >= clearance() - 1e-12
