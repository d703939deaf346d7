"""Minimum-snap trajectories: optimality, smoothness, rest, limits and clearance after repair."""

from __future__ import annotations

import sys
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
import scipy.linalg
from numpy.polynomial import Polynomial

from groundstation.planning import load_planning_params
from groundstation.planning.astar import plan_path
from groundstation.trajectories.minsnap import (
    MinSnapSettings,
    min_snap,
    min_snap_through,
    optimise_times,
    plan_min_snap,
    snap_cost_and_gradient,
    solve_coefficients,
    trapezoid_times,
)
from model.errors import UserError
from model.vehicle import GRAVITY_MPS2, load_vehicle
from model.world import load_world

sys.path.insert(0, str(Path(__file__).resolve().parent))

from testsupport import shared_world  # noqa: E402
from trajectory_checks import assert_samples_are_fresh_arrays  # noqa: E402

WAYPOINTS = np.array(
    [[0.0, 0.0, 1.0], [1.0, 0.2, 1.2], [1.5, 1.2, 1.0], [0.8, 2.0, 1.5], [1.6, 2.6, 1.5], [2.5, 2.4, 0.8]]
)


def settings() -> MinSnapSettings:
    return MinSnapSettings.from_params(load_planning_params(), load_vehicle("crazyflie"))


def segment_derivative(coefficients: np.ndarray, times: np.ndarray, i: int, r: int, tau: float) -> np.ndarray:
    """r-th time derivative (3,) of segment i at normalised time tau, from its coefficients."""
    return np.array([Polynomial(coefficients[i, :, a]).deriv(r)(tau) for a in range(3)]) / times[i] ** r


def reference_min_snap(waypoints: np.ndarray, times: np.ndarray) -> list[np.ndarray]:
    """The textbook QP (Mellinger & Kumar): min sum int |x''''|^2 in local time t in [0, T_i], subject to the
    waypoints, v/a/j continuity only, rest at the ends; solved through its KKT system. Per-segment
    coefficient arrays (8, 3) in local time."""
    n = len(times)
    size = 8 * n
    hessian = np.zeros((size, size))
    for i, duration in enumerate(times):
        for k in range(4, 8):
            for m in range(4, 8):
                f = np.prod(range(k - 3, k + 1)) * np.prod(range(m - 3, m + 1))
                hessian[8 * i + k, 8 * i + m] = f * duration ** (k + m - 7) / (k + m - 7)

    def row(i, r, t):  # r-th derivative of segment i at local time t
        out = np.zeros(size)
        for k in range(r, 8):
            out[8 * i + k] = np.prod(range(k - r + 1, k + 1)) * t ** (k - r)
        return out

    rows, rhs = [], []
    for i in range(n):
        rows += [row(i, 0, 0.0), row(i, 0, times[i])]
        rhs += [waypoints[i], waypoints[i + 1]]
    for r in (1, 2, 3):
        rows += [row(0, r, 0.0), row(n - 1, r, times[-1])]
        rhs += [np.zeros(3), np.zeros(3)]
        for i in range(n - 1):
            rows.append(row(i, r, times[i]) - row(i + 1, r, 0.0))
            rhs.append(np.zeros(3))
    a = np.array(rows)
    kkt = np.block([[2 * hessian, a.T], [a, np.zeros((len(a), len(a)))]])
    solution = scipy.linalg.solve(kkt, np.vstack([np.zeros((size, 3)), np.array(rhs)]))
    return [solution[8 * i : 8 * i + 8] for i in range(n)]


def test_fixed_time_solution_equals_the_constrained_qp_optimum():
    times = np.array([1.2, 0.9, 1.5, 1.0, 1.3])
    traj = min_snap(WAYPOINTS, times)
    reference = reference_min_snap(WAYPOINTS, times)
    for i in range(len(times)):
        t = np.linspace(0, times[i], 9)
        expected = np.array([[Polynomial(reference[i][:, a])(x) for a in range(3)] for x in t])
        assert np.allclose(traj.evaluate(traj.knot_times_s[i] + t)[0], expected, atol=1e-8)


def test_derivatives_are_continuous_at_the_knots_and_waypoints_are_met():
    traj = min_snap_through(WAYPOINTS, settings())
    c, times = traj.coefficients, traj.segment_times_s
    for i in range(len(times) - 1):
        for r in range(7):  # position through pop (6th derivative): snap continuity and more
            left = segment_derivative(c, times, i, r, 1.0)
            right = segment_derivative(c, times, i + 1, r, 0.0)
            assert np.allclose(left, right, rtol=1e-7, atol=1e-7 * max(1.0, np.abs(left).max()))
    for t, w in zip(traj.knot_times_s, WAYPOINTS, strict=True):
        assert np.allclose(traj.sample(t).position_m, w, atol=1e-9)


def test_rest_at_both_ends_and_hold_outside_the_duration():
    traj = min_snap_through(WAYPOINTS, settings())
    c, times = traj.coefficients, traj.segment_times_s
    for r in (1, 2, 3):
        assert np.allclose(segment_derivative(c, times, 0, r, 0.0), 0.0, atol=1e-9)
        assert np.allclose(segment_derivative(c, times, len(times) - 1, r, 1.0), 0.0, atol=1e-9)
    before, after = traj.sample(-1.0), traj.sample(traj.duration_s + 1.0)
    assert np.array_equal(before.position_m, WAYPOINTS[0]) and not before.velocity_mps.any()
    assert np.array_equal(after.position_m, WAYPOINTS[-1]) and not after.acceleration_mps2.any()
    assert traj.sample(3.0).yaw_rad == 0.0


def test_sample_agrees_with_vectorised_evaluation_and_finite_differences():
    traj = min_snap_through(WAYPOINTS, settings())
    t = np.linspace(0.01, traj.duration_s - 0.01, 37)
    table = traj.evaluate(t)
    h = 1e-5
    for k, x in enumerate(t):
        out = traj.sample(x)
        derivs = [out.position_m, out.velocity_mps, out.acceleration_mps2, out.jerk_mps3, out.snap_mps4]
        assert np.allclose(np.array(derivs), table[:, k])
        for r in range(4):  # each derivative is the time derivative of the one before
            numeric = (traj.evaluate([x + h])[r, 0] - traj.evaluate([x - h])[r, 0]) / (2 * h)
            assert np.allclose(
                numeric, derivs[r + 1], rtol=1e-4, atol=1e-4 * max(1.0, np.abs(derivs[r + 1]).max())
            )


def test_samples_are_fresh_arrays_the_caller_may_modify():
    traj = min_snap_through(WAYPOINTS, settings())
    assert_samples_are_fresh_arrays(traj, (-1.0, 0.7, traj.duration_s / 2, traj.duration_s + 1.0))

def test_gradient_of_the_snap_cost_matches_finite_differences():
    times = np.array([1.2, 0.9, 1.5, 1.0, 1.3])
    _, gradient = snap_cost_and_gradient(solve_coefficients(WAYPOINTS, times), times)
    for i in range(len(times)):
        step = np.zeros(len(times))
        step[i] = 1e-6
        plus, _ = snap_cost_and_gradient(solve_coefficients(WAYPOINTS, times + step), times + step)
        minus, _ = snap_cost_and_gradient(solve_coefficients(WAYPOINTS, times - step), times - step)
        assert gradient[i] == pytest.approx((plus - minus) / 2e-6, rel=1e-5)


def test_snap_cost_is_the_integral_of_squared_snap():
    times = np.array([1.2, 0.9, 1.5, 1.0, 1.3])
    traj = min_snap(WAYPOINTS, times)
    cost, _ = snap_cost_and_gradient(traj.coefficients, times)
    t = np.linspace(0, traj.duration_s, 100001)
    snap2 = (traj.evaluate(t)[4] ** 2).sum(1)
    assert cost == pytest.approx(np.sum((snap2[1:] + snap2[:-1]) / 2 * np.diff(t)), rel=1e-3)


def test_time_optimisation_lowers_the_scale_free_snap_cost():
    initial = trapezoid_times(WAYPOINTS, 1.0, 3.0)
    optimised = optimise_times(WAYPOINTS, initial)

    def scale_free(times):  # J(a T) = a^-7 J(T): compare J (sum T)^7, which uniform scaling leaves alone
        return snap_cost_and_gradient(solve_coefficients(WAYPOINTS, times), times)[0] * times.sum() ** 7

    assert scale_free(optimised) < 0.99 * scale_free(initial)


def dense_limits(traj, gravity=GRAVITY_MPS2):
    out = traj.evaluate(np.linspace(0, traj.duration_s, 20001))
    speed = np.linalg.norm(out[1], axis=1).max()
    accel = np.linalg.norm(out[2], axis=1).max()
    thrust = np.linalg.norm(out[2] + [0.0, 0.0, gravity], axis=1).max()
    vertical = (out[2][:, 2] + gravity).min()
    return speed, accel, thrust, vertical


def test_speed_and_acceleration_limits_hold_and_one_binds():
    s = settings()
    assert s.max_thrust_accel_mps2 == pytest.approx(
        0.7 * load_vehicle("crazyflie").thrust_to_weight * GRAVITY_MPS2
    )
    traj = min_snap_through(WAYPOINTS, s)
    speed, accel, thrust, vertical = dense_limits(traj)
    assert speed <= s.max_speed_mps * 1.002 and accel <= s.max_accel_mps2 * 1.002
    assert thrust <= s.max_thrust_accel_mps2 * 1.002 and vertical >= s.min_vertical_thrust_accel_mps2 * 0.998
    assert max(speed / s.max_speed_mps, accel / s.max_accel_mps2) >= 0.99  # as fast as the limits allow


def test_thrust_to_weight_limit_binds_when_speed_and_acceleration_are_free():
    s = replace(settings(), max_speed_mps=100.0, max_accel_mps2=1000.0)
    climb = np.array([[0.0, 0.0, 0.5], [1.0, 0.0, 1.5], [2.0, 0.5, 0.5], [3.0, 0.0, 1.5]])
    traj = min_snap_through(climb, s)
    _, _, thrust, vertical = dense_limits(traj)
    assert thrust <= s.max_thrust_accel_mps2 * 1.002 and vertical >= s.min_vertical_thrust_accel_mps2 * 0.998
    binding = max(
        thrust / s.max_thrust_accel_mps2,
        (GRAVITY_MPS2 - vertical) / (GRAVITY_MPS2 - s.min_vertical_thrust_accel_mps2),
    )
    assert binding >= 0.99


def test_coincident_waypoints_are_a_user_error():
    with pytest.raises(UserError):
        min_snap_through(np.array([[0.0, 0.0, 1.0], [0.0, 0.0, 1.0], [1.0, 0.0, 1.0]]))


@pytest.mark.parametrize("name", ["test_lab_1.json", "maze_2024_3.json", "maze_2026_2.json"])
def test_lab_maze_trajectory_clears_the_margin_after_repair(name):
    world = load_world(shared_world(name.removesuffix(".json")))
    margin = 0.25
    result = plan_path(world, 0.05, margin)
    s = settings()
    plan = plan_min_snap(result.path_m, world, margin, s)
    traj = plan.trajectory
    assert np.array_equal(traj.waypoints_m[0], world.start) and np.array_equal(
        traj.waypoints_m[-1], world.goal
    )
    for point, position in zip(traj.waypoints_m, plan.path_positions, strict=True):  # waypoints on the path
        k = min(int(position), len(result.path_m) - 2)
        expected = result.path_m[k] + (position - k) * (result.path_m[k + 1] - result.path_m[k])
        assert np.allclose(point, expected, atol=1e-12)
    t = np.arange(0.0, traj.duration_s, 1e-3 / s.max_speed_mps)  # <= 1 mm apart at the speed limit
    points = traj.evaluate(t)[0]
    assert np.all(world.distance_to_blocks(points) >= margin - 1e-9)
    assert np.all(world.contains(points))
    speed, accel, thrust, _ = dense_limits(traj)
    assert speed <= s.max_speed_mps * 1.002 and accel <= s.max_accel_mps2 * 1.002
