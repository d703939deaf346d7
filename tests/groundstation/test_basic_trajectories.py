"""Built-in trajectories: derivatives vs finite differences, rest at both ends, geometry as configured."""

from __future__ import annotations

import math
import sys
from pathlib import Path

import numpy as np
import pytest
from numpy.polynomial import polynomial

from groundstation.trajectories.basic import (
    Circle,
    Hover,
    Line,
    Step,
    load_trajectory_params,
    make_builtin,
)
from groundstation.trajectories.flat import polyval
from model.errors import ConfigError, UserError

sys.path.insert(0, str(Path(__file__).resolve().parent))

from trajectory_checks import FIELDS, assert_samples_are_fresh_arrays, derivatives  # noqa: E402

START = np.array([0.3, -0.2, 0.9])
def assert_derivatives_consistent(trajectory, times, h=1e-4):
    """Each derivative equals the central difference of the one below it (error O(h^2))."""
    for t in times:
        below, above = derivatives(trajectory, t - h), derivatives(trajectory, t + h)
        here = derivatives(trajectory, t)
        for k in range(1, 5):
            fd = (above[k - 1] - below[k - 1]) / (2 * h)
            scale = max(1.0, float(np.max(np.abs(here[k]))))
            np.testing.assert_allclose(here[k], fd, atol=1e-5 * scale, err_msg=f"{FIELDS[k]} at t={t}")


def assert_rest(trajectory, t, position):
    out = derivatives(trajectory, t)
    np.testing.assert_allclose(out[0], position, atol=1e-12)
    for k in range(1, 4):  # velocity, acceleration and jerk vanish at the ends (snap may jump)
        np.testing.assert_allclose(out[k], 0.0, atol=1e-9)


def test_line_derivatives_rest_and_peak_speed():
    end = START + [2.0, 1.0, -0.5]
    line = Line(START, end, speed_mps=0.8, hold_s=1.0)
    assert_derivatives_consistent(line, np.linspace(0.05, line.move_s - 0.05, 13))
    for t in (-1.0, 0.0):
        assert_rest(line, t, START)
    for t in (line.move_s, line.duration_s, line.duration_s + 5.0):
        assert_rest(line, t, end)
    assert line.duration_s == pytest.approx(line.move_s + 1.0)
    # Speed is largest mid-way and equals the configured peak; the path stays on the segment.
    speeds = [np.linalg.norm(line.sample(t).velocity_mps) for t in np.linspace(0, line.move_s, 2001)]
    assert max(speeds) == pytest.approx(0.8, rel=1e-6)
    mid = line.sample(line.move_s / 2).position_m
    np.testing.assert_allclose(mid, (START + end) / 2, atol=1e-12)
    for t in np.linspace(0, line.move_s, 7):
        offset = line.sample(t).position_m - START
        assert np.linalg.norm(np.cross(offset, end - START)) < 1e-12


def test_line_velocity_integrates_to_the_displacement():
    end = START + [1.0, 0.0, 0.0]
    line = Line(START, end, speed_mps=0.5)
    t = np.linspace(0.0, line.move_s, 4001)
    vx = [line.sample(ti).velocity_mps[0] for ti in t]
    assert np.trapezoid(vx, t) == pytest.approx(1.0, rel=1e-6)


def test_zero_length_line_is_a_hover():
    line = Line(START, START, speed_mps=0.5, hold_s=2.0)
    assert line.duration_s == 2.0
    assert_rest(line, 1.0, START)


def test_circle_derivatives_radius_speed_and_rest():
    center, radius, speed = np.array([1.0, 2.0, 1.2]), 0.6, 0.9
    circle = Circle(center, radius, speed, laps=2, spin_up_s=1.5, start_angle_rad=0.7)
    start = center + radius * np.array([math.cos(0.7), math.sin(0.7), 0.0])
    assert_derivatives_consistent(circle, np.linspace(0.05, circle.duration_s - 0.05, 23))
    assert_rest(circle, 0.0, start)
    assert_rest(circle, -1.0, start)
    assert_rest(circle, circle.duration_s, start)  # whole laps bring it back
    samples = [circle.sample(t) for t in np.linspace(0.0, circle.duration_s, 3001)]
    distances = [np.linalg.norm(s.position_m[:2] - center[:2]) for s in samples]
    np.testing.assert_allclose(distances, radius, atol=1e-12)
    assert all(s.position_m[2] == center[2] for s in samples)
    speeds = np.array([np.linalg.norm(s.velocity_mps) for s in samples])
    assert speeds.max() == pytest.approx(speed, rel=1e-12)
    # Cruise: speed as configured, centripetal acceleration v^2 / R pointing at the centre.
    cruise = circle.sample(circle.duration_s / 2)
    assert np.linalg.norm(cruise.velocity_mps) == pytest.approx(speed, rel=1e-12)
    inward = (center - cruise.position_m) / radius
    np.testing.assert_allclose(cruise.acceleration_mps2, speed**2 / radius * inward, atol=1e-12)
    # Angle covered is 2 pi laps: the path length is 2 pi R laps.
    t = np.linspace(0.0, circle.duration_s, 20001)
    length = np.trapezoid([np.linalg.norm(circle.sample(ti).velocity_mps) for ti in t], t)
    assert length == pytest.approx(2 * math.pi * radius * 2, rel=1e-6)


def test_circle_runs_counter_clockwise():
    circle = Circle([0, 0, 1], 1.0, 1.0)
    out = circle.sample(circle.duration_s / 2)
    assert np.cross(out.position_m - [0, 0, 1], out.velocity_mps)[2] > 0  # angular momentum along +z


def test_circle_too_short_for_its_spin_up_is_refused():
    with pytest.raises(UserError, match="too short"):
        Circle([0, 0, 1], 0.1, 2.0, laps=0.1, spin_up_s=1.0)


def test_hover_and_step():
    hover = Hover(START, 3.0, yaw_rad=0.2)
    assert hover.duration_s == 3.0 and hover.sample(1.0).yaw_rad == 0.2
    assert_rest(hover, 1.0, START)
    step = Step(START, "z", -0.4, hold_s=2.0, step_at_s=1.5)
    assert step.duration_s == 3.5
    assert_rest(step, 1.49, START)
    assert_rest(step, 1.5, START + [0, 0, -0.4])
    assert_rest(step, 10.0, START + [0, 0, -0.4])
    with pytest.raises(UserError, match="step axis"):
        Step(START, "w", 1.0, 1.0, 1.0)


def test_builtins_from_the_shipped_parameters():
    params = load_trajectory_params()
    hover = make_builtin("hover", START, params)
    top = np.array([START[0], START[1], params.hover.height_m])
    assert_rest(hover, hover.duration_s, top)
    assert max(np.linalg.norm(hover.sample(t).velocity_mps)
               for t in np.linspace(0, hover.duration_s, 999)) <= params.hover.climb_speed_mps + 1e-12

    line = make_builtin("line", START, params)
    assert_rest(line, 0.0, START)
    assert_rest(line, line.duration_s, START + params.line.length_m * np.array(params.line.direction_enu))

    circle = make_builtin("circle", START, params)
    assert_rest(circle, 0.0, START)
    assert_rest(circle, circle.duration_s, START)
    assert circle.radius_m == params.circle.radius_m and circle.speed_mps == params.circle.speed_mps
    center = START - params.circle.radius_m * np.array(params.circle.direction_to_start_enu)
    np.testing.assert_allclose(circle.center_m, center)

    step = make_builtin("step", START, params)
    assert step.step_at_s == params.step.step_at_s
    # The report's hardware flights stayed below 1 m/s.
    assert params.line.speed_mps < 1.0 and params.circle.speed_mps < 1.0

    with pytest.raises(UserError, match="unknown built-in trajectory 'spiral'"):
        make_builtin("spiral", START, params)


def test_bad_trajectory_file_gives_one_line_error(tmp_path):
    bad = tmp_path / "t.toml"
    bad.write_text('schema_version = 1\nname = "t"\nsource = "x"\n'
                   '[hover]\nheight_m = 1\n[line]\n[circle]\n[step]\n')
    with pytest.raises(ConfigError, match=r"t\.toml: hover\.climb_speed_mps: missing"):
        load_trajectory_params(bad)


def test_bad_arguments_are_refused():
    with pytest.raises(UserError, match="radius_m"):
        Circle([0, 0, 1], -1.0, 1.0)
    with pytest.raises(UserError, match="line start_m"):
        Line([0, 0], [1, 0, 0])
    with pytest.raises(UserError, match="speed_mps"):
        Line(START, START + 1, speed_mps=0.0)


def test_samples_are_fresh_arrays_the_caller_may_keep_or_modify():
    times = (-1.0, 0.3, 2.0, 50.0)
    for trajectory in (Hover(START, 3.0), Line(START, START + [1.0, 0.5, 0.0]),
                       Circle(START, 0.5, 0.5, spin_up_s=1.0), Step(START, "x", 0.5, 1.0, 1.0)):
        assert_samples_are_fresh_arrays(trajectory, times)


def test_polyval_is_the_polynomial_sum():
    rng = np.random.default_rng(3)
    for degree in (0, 1, 7):
        coefficients = rng.normal(size=degree + 1).tolist()
        for x in (-1.3, 0.0, 0.4, 2.0):
            expected = sum(c * x**k for k, c in enumerate(coefficients))
            assert polyval(coefficients, x) == pytest.approx(expected, rel=1e-12, abs=1e-12)
            assert polyval(coefficients, x) == polynomial.polyval(x, coefficients)  # same Horner steps
