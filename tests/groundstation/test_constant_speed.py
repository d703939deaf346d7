"""The report's constant-speed trajectory (lab report III.B, eq. (1)) against its definition."""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import pytest

from groundstation.planning import load_planning_params
from groundstation.trajectories.constant_speed import (
    ConstantSpeedSettings,
    ConstantSpeedTrajectory,
    downsample_path,
)
from model.errors import UserError

sys.path.insert(0, str(Path(__file__).resolve().parent))

from trajectory_checks import assert_samples_are_fresh_arrays  # noqa: E402

WAYPOINTS = np.array([[0.0, 0.0, 1.0], [0.4, 0.0, 1.0], [0.4, 0.3, 1.0], [0.4, 0.3, 1.6], [1.0, 1.1, 1.6]])


def test_settings_are_the_reports():
    s = ConstantSpeedSettings.from_params(load_planning_params())
    assert (s.speed_mps, s.keep_every, s.end_segment_time_factor) == (1.0, 3, 1.5)


def test_downsampling_keeps_every_third_point_and_the_goal():
    path = np.arange(11 * 3, dtype=float).reshape(11, 3)
    assert np.array_equal(downsample_path(path, 3), path[[0, 3, 6, 9, 10]])
    assert np.array_equal(downsample_path(path[:10], 3), path[[0, 3, 6, 9]])


def test_segment_times_follow_equation_1():
    v = 0.8
    traj = ConstantSpeedTrajectory(WAYPOINTS, speed_mps=v, end_segment_time_factor=1.5)
    lengths = np.linalg.norm(np.diff(WAYPOINTS, axis=0), axis=1)
    expected = lengths / v
    expected[0] *= 1.5
    expected[-1] *= 1.5
    assert np.allclose(traj.segment_times_s, expected)
    assert traj.duration_s == pytest.approx(expected.sum())
    for t, p in zip(traj.knot_times_s, WAYPOINTS, strict=True):
        assert np.allclose(traj.sample(t).position_m, p, atol=1e-12)


def test_middle_segments_move_at_v_along_the_segment_direction():
    v = 0.8
    traj = ConstantSpeedTrajectory(WAYPOINTS, speed_mps=v, end_segment_time_factor=1.5)
    for i in range(1, len(WAYPOINTS) - 2):
        t_start = traj.knot_times_s[i]
        direction = (WAYPOINTS[i + 1] - WAYPOINTS[i]) / np.linalg.norm(WAYPOINTS[i + 1] - WAYPOINTS[i])
        for t in np.linspace(t_start, traj.knot_times_s[i + 1], 7)[1:-1]:
            out = traj.sample(t)
            assert np.allclose(out.velocity_mps, v * direction)
            assert np.allclose(out.position_m, WAYPOINTS[i] + v * direction * (t - t_start))  # r_T of III.B


def test_first_and_last_segments_ramp_speed_linearly_and_cover_their_segment():
    v = 1.0
    traj = ConstantSpeedTrajectory(WAYPOINTS, speed_mps=v, end_segment_time_factor=1.5)
    t0, t1 = traj.knot_times_s[0], traj.knot_times_s[1]
    times = np.linspace(t0, t1, 301)
    speed = np.array([np.linalg.norm(traj.sample(t).velocity_mps) for t in times])
    ramp = times < t0 + (t1 - t0) * 2 / 3
    assert np.allclose(speed[ramp], v * (times[ramp] - t0) / ((t1 - t0) * 2 / 3))  # linear from 0
    assert np.allclose(speed[~ramp], v)
    # position is the integral of the reported velocity (trapezoid rule on a fine grid)
    t_fine = np.linspace(0, traj.duration_s, 20001)
    velocity = np.array([traj.sample(t).velocity_mps for t in t_fine])
    position = np.array([traj.sample(t).position_m for t in t_fine])
    integral = WAYPOINTS[0] + np.concatenate(
        [np.zeros((1, 3)), np.cumsum((velocity[1:] + velocity[:-1]) / 2 * np.diff(t_fine)[:, None], axis=0)]
    )
    assert np.abs(integral - position).max() < 1e-3
    tn1, tn = traj.knot_times_s[-2], traj.knot_times_s[-1]
    late = np.linspace(tn1 + (tn - tn1) / 3, tn, 50)
    speed = np.array([np.linalg.norm(traj.sample(t).velocity_mps) for t in late])
    assert np.allclose(speed, v * (tn - late) / ((tn - tn1) * 2 / 3))  # linear down to 0 at the goal


def test_position_is_continuous_and_never_faster_than_v():
    v = 1.0
    traj = ConstantSpeedTrajectory(WAYPOINTS, speed_mps=v, end_segment_time_factor=1.5)
    t = np.linspace(-0.5, traj.duration_s + 0.5, 40001)
    p = np.array([traj.sample(x).position_m for x in t])
    steps = np.linalg.norm(np.diff(p, axis=0), axis=1)
    assert steps.max() <= v * (t[1] - t[0]) * (1 + 1e-9)


def test_starts_and_ends_at_rest_and_holds_outside_its_duration():
    traj = ConstantSpeedTrajectory(WAYPOINTS, 1.0, 1.5)
    for t in (-1.0, 0.0):
        out = traj.sample(t)
        assert np.array_equal(out.position_m, WAYPOINTS[0]) and not out.velocity_mps.any()
    for t in (traj.duration_s, traj.duration_s + 5.0):
        out = traj.sample(t)
        assert np.array_equal(out.position_m, WAYPOINTS[-1]) and not out.velocity_mps.any()
    assert np.linalg.norm(traj.sample(1e-6).velocity_mps) < 1e-5


def test_higher_derivatives_are_reported_as_zero():
    traj = ConstantSpeedTrajectory(WAYPOINTS, 1.0, 1.5)
    for t in np.linspace(0, traj.duration_s, 23):
        out = traj.sample(t)
        assert not out.acceleration_mps2.any() and not out.jerk_mps3.any() and not out.snap_mps4.any()
        assert out.yaw_rad == 0.0


def test_single_segment_ramps_up_and_down_within_one_factor_of_its_time():
    a, b = np.array([0.0, 0.0, 1.0]), np.array([1.2, 0.0, 1.0])
    traj = ConstantSpeedTrajectory(np.array([a, b]), speed_mps=1.0, end_segment_time_factor=1.5)
    assert traj.duration_s == pytest.approx(1.5 * 1.2)
    assert np.allclose(traj.sample(traj.duration_s - 1e-12).position_m, b)
    assert np.linalg.norm(traj.sample(traj.duration_s / 2).velocity_mps) == pytest.approx(1.0)


def test_from_path_downsamples_then_times():
    path = np.column_stack([np.linspace(0, 2.0, 21), np.zeros(21), np.ones(21)])
    traj = ConstantSpeedTrajectory.from_path(path)
    assert np.allclose(traj.waypoints_m, path[[0, 3, 6, 9, 12, 15, 18, 20]])


@pytest.mark.parametrize("speed, factor", [(0.0, 1.5), (1.0, 2.5), (1.0, 0.9)])
def test_bad_settings_are_user_errors(speed, factor):
    with pytest.raises(UserError):
        ConstantSpeedTrajectory(WAYPOINTS, speed, factor)


def test_samples_are_fresh_arrays_the_caller_may_modify():
    traj = ConstantSpeedTrajectory(WAYPOINTS, 1.0, 1.5)
    assert_samples_are_fresh_arrays(traj, (-1.0, 0.5, traj.duration_s / 2, traj.duration_s + 1.0))
