"""model.world: obstacle clearance (blocks, walls, ceiling; pads while on the ground) and nudging a point
inside the bounds, and the support height under a point (the floor or a pad), checked against distances and
heights worked out by hand for boxes."""

import math

import numpy as np

from model.world import RESTING_TOLERANCE_M, World

BOUNDS = np.array([0.0, 10.0, 0.0, 8.0, 0.0, 4.0])
PAD = np.array([2.0, 4.0, 2.0, 4.0, 0.0, 1.0])  # a 2 m x 2 m block 1 m tall
WALL = np.array([6.0, 7.0, 0.0, 8.0, 0.0, 4.0])


def world() -> World:
    return World(bounds=BOUNDS, blocks=np.array([PAD, WALL]))


def test_clearance_to_a_block_is_the_euclidean_box_distance():
    # 0.3 m beyond the pad's x face and 0.4 m above its top: the nearest point is its top edge, 0.5 m away
    d, which = world().obstacle_clearance([[4.3, 3.0, 1.4]])
    assert math.isclose(d[0], 0.5, abs_tol=1e-12) and which[0] == 0


def test_walls_and_ceiling_are_obstacles_and_the_floor_is_not():
    d, which = world().obstacle_clearance([[9.9, 6.0, 2.0], [8.0, 6.0, 3.95], [8.0, 6.0, 0.01]])
    assert np.allclose(d[:2], [0.1, 0.05]) and list(which[:2]) == [-1, -1]
    # 1 cm above the floor, 1 m from the wall block, 2 m from the nearest wall: the floor does not count
    assert math.isclose(d[2], 1.0) and which[2] == 1


def test_a_pad_right_below_counts_only_where_pads_are_allowed():
    resting = [[3.0, 3.0, 1.0]]
    d_air, which_air = world().obstacle_clearance(resting, pads_allowed=False)
    assert d_air[0] == 0.0 and which_air[0] == 0
    d_ground, which_ground = world().obstacle_clearance(resting, pads_allowed=True)
    assert d_ground[0] > 1.0 and which_ground[0] != 0


def test_a_float32_position_resting_on_a_pad_still_rests_on_it():
    # 1.0 m read back through a float32 field is 0.99999994 m: inside the tolerance, so still on the pad
    z = float(np.float32(1.0 - 6e-8))
    assert 1.0 - z < RESTING_TOLERANCE_M
    d, which = world().obstacle_clearance([[3.0, 3.0, z]], pads_allowed=True)
    assert which[0] != 0


def test_pads_allowed_per_point():
    d, which = world().obstacle_clearance([[3.0, 3.0, 1.0], [3.0, 3.0, 1.0]], pads_allowed=[True, False])
    assert which[0] != 0 and which[1] == 0


def test_nudged_inside_moves_only_the_coordinates_within_the_radius():
    w = world()
    assert np.allclose(w.nudged_inside([0.0, 4.0, 2.0], 0.1), [0.1, 4.0, 2.0])
    assert np.allclose(w.nudged_inside([10.0, 8.0, 0.0], 0.1), [9.9, 7.9, 0.1])
    inside = np.array([5.0, 5.0, 2.0])
    assert np.array_equal(w.nudged_inside(inside, 0.1), inside)


def test_support_height_is_the_highest_pad_top_below_the_point_or_the_floor():
    # two stacked-footprint pads (tops 0.5 and 1.0 m) overlapping on x in [1, 2], and one far away
    world = World(bounds=np.array([-5.0, 5.0, -5.0, 5.0, -0.25, 4.0]),
                  blocks=np.array([[0.0, 2.0, 0.0, 1.0, 0.0, 0.5], [1.0, 3.0, 0.0, 1.0, 0.0, 1.0],
                                   [-4.0, -3.0, -4.0, -3.0, 0.0, 2.0]]))
    assert world.support_height((0.5, 0.5, 2.0)) == 0.5  # over the low pad only
    assert world.support_height((1.5, 0.5, 2.0)) == 1.0  # over both: the higher top
    assert world.support_height((1.5, 0.5, 0.7)) == 0.5  # below the higher top: it is no support
    assert world.support_height((1.5, 0.5, 1.0 - 0.5e-9)) == 1.0  # on the top, within the 1e-9 m allowance
    assert world.support_height((2.0, 1.0, 3.0)) == 1.0  # the footprint's edges are closed
    assert world.support_height((3.0 + 1e-12, 0.5, 3.0)) == -0.25  # just outside: the floor (bounds zmin)
    assert world.support_height(np.array([-3.5, -3.5, 2.5])) == 2.0  # a numpy point as well as a tuple
    assert world.support_height((math.nan, 0.5, 2.0)) == -0.25  # an unknown position holds on no pad
    assert World.empty().support_height((0.0, 0.0, 1.0)) == 0.0
