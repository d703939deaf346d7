"""groundstation.grading on synthetic flights whose answers follow from the definitions: the course's
COMPLETE exit (position, speed and attitude tolerances), its robot-radius collision check, our minimum
clearance over the whole flight, and the failure line for a crash after a failsafe."""

import math
from types import SimpleNamespace

import numpy as np

from groundstation.grading import course_grade, failure, load_course_rules, min_clearance
from link.messages import CrashReport, Touched
from model.world import World

RULES = load_course_rules()
DT = 0.01


def straight_flight(speed_mps: float = 1.0, length_m: float = 2.0, hold_s: float = 2.0):
    """x from 0 to length at constant speed, then at rest at the goal; level, yaw 0."""
    t = np.arange(0.0, length_m / speed_mps + hold_s, DT)
    x = np.minimum(t * speed_mps, length_m)
    truth = np.column_stack([x, np.full_like(t, 1.0), np.full_like(t, 1.0)])
    vel = np.column_stack([np.where(x < length_m, speed_mps, 0.0), np.zeros_like(t), np.zeros_like(t)])
    att = np.tile([1.0, 0.0, 0.0, 0.0], (len(t), 1))
    return t, truth, vel, att


def room(*blocks) -> World:
    return World(bounds=np.array([-1.0, 5.0, -1.0, 3.0, 0.0, 3.0]), blocks=np.array(blocks, float).reshape(-1, 6))


def test_complete_at_the_first_sample_within_every_tolerance():
    t, truth, vel, att = straight_flight()
    grade = course_grade(RULES, room(), t, truth, vel, att, np.array([2.0, 1.0, 1.0]), 0.0, 0.0, False, t[-1])
    assert grade["stopped_at_goal"] and grade["no_collision"] and grade["passed"]
    # at x = 2 - 0.02 m the speed is still 1 m/s > 0.03 m/s: COMPLETE waits for the stop at t = 2 s
    assert math.isclose(grade["flight_time_s"], 2.0, abs_tol=DT)


def test_a_tilted_stop_is_not_complete():
    t, truth, vel, att = straight_flight()
    tilt = RULES.stop_attitude_tolerance_rad * 2.0
    att[:] = [math.cos(tilt / 2), math.sin(tilt / 2), 0.0, 0.0]
    grade = course_grade(RULES, room(), t, truth, vel, att, np.array([2.0, 1.0, 1.0]), 0.0, 0.0, False, t[-1])
    assert not grade["stopped_at_goal"] and grade["flight_time_s"] is None and not grade["passed"]


def test_a_start_that_is_the_goal_is_not_complete_before_the_minimum_time():
    t = np.arange(0.0, 3.0, DT)
    truth = np.tile([1.0, 1.0, 1.0], (len(t), 1))
    grade = course_grade(RULES, room(), t, truth, np.zeros_like(truth), np.tile([1.0, 0, 0, 0], (len(t), 1)),
                         np.array([1.0, 1.0, 1.0]), 0.0, 0.5, True, t[-1])
    assert math.isclose(grade["flight_time_s"], RULES.min_time_when_start_is_goal_s, abs_tol=DT)


def test_passing_within_the_robot_radius_of_a_block_is_a_course_collision():
    # the path runs at y = 1; a block whose face is at y = 1.2 is 0.2 m away, inside the course's 0.25 m
    t, truth, vel, att = straight_flight()
    block = [0.9, 1.1, 1.2, 2.0, 0.0, 3.0]
    grade = course_grade(RULES, room(block), t, truth, vel, att, np.array([2.0, 1.0, 1.0]), 0.0, 0.0, False, t[-1])
    assert grade["stopped_at_goal"] and not grade["no_collision"] and not grade["passed"]
    x, y, z = grade["collision_point_enu_m"]
    assert 0.9 - 0.25 <= x <= 1.1 + 0.25 and y == 1.0


def test_min_clearance_covers_landing_and_ignores_the_pad_only_on_the_ground():
    t = np.arange(5) * 1.0
    truth = np.array([[0.0, 0.0, 1.0], [0.0, 0.0, 2.0], [2.0, 0.0, 2.0], [2.0, 0.0, 1.05], [2.0, 0.0, 1.0]])
    phase = np.array(["takeoff", "track", "track", "land", "land"])
    pad = [1.5, 2.5, -0.5, 0.5, 0.0, 1.0]
    result = min_clearance(room([-0.5, 0.5, -0.5, 0.5, 0.0, 1.0], pad), t, phase, truth)
    # Resting on a pad while taking off or landing is not a collision: the other points are 1 m from a wall
    # (y = -1), from the ceiling or from a pad below them, so the whole flight's minimum is 1 m.
    assert math.isclose(result["min_clearance_m"], 1.0)
    assert result["min_clearance_to"] == "bounds"
    # the same points flown while tracking: the pad is an obstacle, 0.05 m below
    result = min_clearance(room(pad), t, np.array(["track"] * 5), truth)
    assert math.isclose(result["min_clearance_m"], 0.0) and result["min_clearance_to"] == "block 0"
    assert result["min_clearance_phase"] == "track" and result["min_clearance_time_s"] == 4.0


def test_a_crash_after_a_failsafe_says_both_in_one_line():
    t = np.arange(0.0, 10.0, 1.0)
    phase = np.array(["track"] * 4 + ["failsafe_hold"] * 2 + ["done"] * 4)
    est = np.tile([1.0, 1.0, 1.0], (10, 1))
    mission = SimpleNamespace(failsafe_reason="link lost: no downlink for 0.5 s", result="failsafe",
                              failsafe_at=(4.0, "track"), crash_seen=None)
    crash = CrashReport(time_s=7.5, position_enu_m=(1.0, 1.0, 0.0), velocity_enu_mps=(0.0, 3.0, -4.0),
                        touched=Touched.FLOOR, limit=1.0)
    report = failure(mission, crash, t, phase, est)
    assert report["kind"] == "crash" and report["phase"] == "done" and report["speed_mps"] == 5.0
    assert report["after_failsafe"]["time_s"] == 4.0
    line = report["reason"]
    assert "\n" not in line and line.startswith("failsafe while tracking at t=4.000 s: link lost")
    assert "after the ground station stopped commanding: hit the floor" in line and "5.00 m/s" in line
