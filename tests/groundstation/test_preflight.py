"""groundstation.preflight: a start or goal on the bounds is moved inward by the collision radius (with a
warning naming the file and the move); inside or too close to a block is refused with one line."""

import numpy as np
import pytest

from groundstation.preflight import checked_point, checked_world
from model.errors import WorldError
from model.world import World

RADIUS_M = 0.07


def world(start, goal) -> World:
    return World(bounds=np.array([0.0, 5.0, 0.0, 5.0, 0.0, 3.0]), blocks=np.array([[2.0, 3.0, 2.0, 3.0, 0.0, 3.0]]),
                 start=np.array(start, float), goal=np.array(goal, float), source="maps/room.json")


def test_a_point_on_the_bounds_is_moved_inward_by_the_radius_with_a_warning():
    checked, warnings = checked_world(world([0.0, 1.0, 1.0], [4.0, 4.0, 1.0]), RADIUS_M)
    assert np.allclose(checked.start, [RADIUS_M, 1.0, 1.0])
    assert np.array_equal(checked.goal, [4.0, 4.0, 1.0])
    assert len(warnings) == 1 and "maps/room.json" in warnings[0] and "start" in warnings[0]
    assert "0.070 m inward" in warnings[0]


def test_a_point_clear_of_everything_is_unchanged_without_warning():
    checked, warnings = checked_world(world([1.0, 1.0, 1.0], [4.0, 4.0, 1.0]), RADIUS_M)
    assert warnings == [] and np.array_equal(checked.start, [1.0, 1.0, 1.0])


@pytest.mark.parametrize("goal, reason", [
    ([2.5, 2.5, 1.0], "inside a block"),
    ([3.05, 2.5, 1.0], "0.050 m from block 0"),
    ([6.0, 2.5, 1.0], "outside the bounds"),
])
def test_a_point_that_cannot_be_flown_is_refused_in_one_line(goal, reason):
    with pytest.raises(WorldError) as err:
        checked_world(world([1.0, 1.0, 1.0], goal), RADIUS_M)
    message = str(err.value)
    assert "\n" not in message and "maps/room.json" in message and "goal" in message and reason in message


def test_a_point_resting_on_a_pad_is_allowed():
    w = World(bounds=np.array([0.0, 5.0, 0.0, 5.0, 0.0, 3.0]), blocks=np.array([[2.0, 3.0, 2.0, 3.0, 0.0, 0.5]]))
    warnings: list[str] = []
    assert np.array_equal(checked_point(w, [2.5, 2.5, 0.5], "start", RADIUS_M, warnings), [2.5, 2.5, 0.5])
    assert warnings == []
