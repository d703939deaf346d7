"""The compiled RK4 step and rotor lag (simulator/_dynamics_kernels.c) give their Python twins' bits
(simulator/dynamics_kernels.py), call by call on random inputs and over whole flights (issue 19: behaviour
unchanged). The twin's physics is tests/simulator/test_dynamics.py's (fourth order against an independent
solution, with and without rotor drag)."""

from __future__ import annotations

import struct

import numpy as np
import pytest
from faithful_flight import fly_faithful

from model.frames import quat_from_euler_zyx
from model.vehicle import load_vehicle
from simulator import dynamics, dynamics_kernels

needs_compiled = pytest.mark.skipif(
    not dynamics_kernels.COMPILED,
    reason="simulator/_dynamics_kernels.c was not built (no C compiler at pip install): the Python twin runs")


def _bits(values) -> bytes:
    return struct.pack(f"{len(values)}d", *values)


def _random_step(rng: np.random.Generator):
    """A state, three wrenches (sometimes the same object, as the vehicle passes them), the step constants and
    gyroscopic coefficients, drawn wide: tumbling, fast, with and without rotor drag."""
    q = quat_from_euler_zyx(*rng.uniform(-np.pi, np.pi, 3))
    x = [*rng.normal(scale=5.0, size=3), *rng.normal(scale=3.0, size=3), *q, *rng.normal(scale=10.0, size=3)]
    x = [float(v) for v in x]

    def wrench():
        drag = float(rng.uniform(0.0, 0.5)) if rng.random() < 0.5 else 0.0
        return (float(rng.uniform(0.0, 30.0)), *(float(v) for v in rng.normal(scale=50.0, size=3)), drag)

    u0 = wrench()
    um = u0 if rng.random() < 0.5 else wrench()
    u1 = um if rng.random() < 0.5 else wrench()
    h = float(rng.choice([0.001, 0.002, 0.0005]))
    steps = (h, 0.5 * h, 0.25 * h, h / 6.0, h / 12.0, h * h / 6.0)
    gyro = tuple(float(v) for v in rng.normal(scale=0.5, size=3))
    return x, u0, um, u1, steps, gyro


@needs_compiled
def test_compiled_step_is_the_python_twins_bit_for_bit():
    rng = np.random.default_rng(11)
    dragged = 0
    for _ in range(20000):
        args = _random_step(rng)
        compiled = dynamics_kernels.rk4_compiled(*args)
        twin = dynamics_kernels.rk4_python(*args)
        assert type(compiled) is list and len(compiled) == 13
        assert _bits(compiled) == _bits(twin), args
        dragged += any(u[4] != 0.0 for u in args[1:4])
    assert dragged > 5000  # the drag branches ran too


@needs_compiled
def test_compiled_step_refuses_bad_arguments_with_one_error():
    x = [0.0] * 6 + [1.0, 0.0, 0.0, 0.0] + [0.0] * 3
    u = (9.81, 0.0, 0.0, 0.0, 0.0)
    steps, gyro = (0.001, 0.0005, 0.00025, 0.001 / 6, 0.001 / 12, 1e-6 / 6), (0.1, -0.1, 0.0)
    rk4 = dynamics_kernels.rk4_compiled
    with pytest.raises(ValueError, match="x: expected 13"):
        rk4(x[:12], u, u, u, steps, gyro)
    with pytest.raises(ValueError, match="u1: expected 5"):
        rk4(x, u, u, u[:4], steps, gyro)
    with pytest.raises(TypeError):
        rk4(x, u, u, ("a", 0.0, 0.0, 0.0, 0.0), steps, gyro)
    with pytest.raises(TypeError):
        rk4(x, u, u, u, steps)
    assert rk4(x, u, u, u, steps, gyro) == dynamics_kernels.rk4_python(x, u, u, u, steps, gyro)


def _random_rotors(rng: np.random.Generator):
    """Rotor speeds, commands (sometimes reached: the lag then changes nothing) and coefficients, drawn wide."""
    w = [float(v) for v in rng.uniform(0.0, 3000.0, 4)]
    cmd = list(w) if rng.random() < 0.1 else [float(v) for v in rng.uniform(0.0, 3000.0, 4)]
    decay_full = float(rng.uniform(0.5, 1.0))
    decay_half = float(np.sqrt(decay_full))
    alloc = rng.normal(scale=1e-8, size=(4, 4))
    drag = float(rng.uniform(0.0, 1e-4)) if rng.random() < 0.5 else 0.0
    coeffs = dynamics_kernels.rotor_coeffs(alloc, rng.uniform(0.02, 0.05), rng.uniform(1e-5, 3e-5, 3), drag)
    return w, cmd, decay_half, decay_full, coeffs


@needs_compiled
def test_compiled_rotor_lag_and_inputs_are_the_python_twins_bit_for_bit():
    rng = np.random.default_rng(12)
    unchanged = 0
    for _ in range(20000):
        w, cmd, dh, df, coeffs = _random_rotors(rng)
        thrust, u = dynamics_kernels.rotor_inputs_compiled(w, coeffs)
        twin_thrust, twin_u = dynamics_kernels.rotor_inputs_python(w, coeffs)
        assert type(u) is tuple and _bits([thrust, *u]) == _bits([twin_thrust, *twin_u])
        compiled = dynamics_kernels.rotor_lag_compiled(w, cmd, dh, df, coeffs)
        twin = dynamics_kernels.rotor_lag_python(w, cmd, dh, df, coeffs)
        if twin is None:
            assert compiled is None
            unchanged += 1
            continue
        w_end, thrust, um, u1 = compiled
        assert type(w_end) is list and type(um) is tuple and type(u1) is tuple
        assert _bits([*w_end, thrust, *um, *u1]) == _bits([*twin[0], twin[1], *twin[2], *twin[3]])
    assert 1000 < unchanged < 5000  # both branches ran


@needs_compiled
def test_compiled_rotor_kernels_refuse_bad_arguments_with_one_error():
    w, coeffs = [1.0, 2.0, 3.0, 4.0], tuple(float(k + 1) for k in range(dynamics_kernels.ROTOR_COEFFS))
    with pytest.raises(ValueError, match="w: expected 4"):
        dynamics_kernels.rotor_inputs_compiled(w[:3], coeffs)
    with pytest.raises(ValueError, match="coeffs: expected 21"):
        dynamics_kernels.rotor_lag_compiled(w, w, 0.9, 0.8, coeffs[:20])
    with pytest.raises(TypeError):
        dynamics_kernels.rotor_lag_compiled(w, w, "0.9", 0.8, coeffs)
    with pytest.raises(TypeError):
        dynamics_kernels.rotor_lag_compiled(w, w, 0.9, 0.8)
    nan = [float("nan")] * 4  # a NaN speed never equals itself: a change, as the twin's list comparison says
    assert dynamics_kernels.rotor_lag_compiled(nan, nan, 0.9, 0.8, coeffs) is not None
    assert dynamics_kernels.rotor_lag_python(nan, nan, 0.9, 0.8, coeffs) is not None


def _fly(vehicle_name: str, mode: str, steps: int) -> list[bytes]:
    """Every physics step's truth of a faithful vehicle flown by fixed setpoints that tilt and turn it
    (faithful_flight)."""
    def record(sim) -> bytes:
        truth = sim.truth
        return _bits([*truth.position_enu_m, *truth.velocity_enu_mps, *truth.attitude_wxyz, *truth.rate_flu_radps])
    return fly_faithful(vehicle_name, mode, steps, record, seed=3)


@needs_compiled
@pytest.mark.parametrize(("vehicle", "mode"), [("cf21", "attitude"), ("cf2x", "moments")])  # cf2x: rotor drag
def test_a_flight_on_the_compiled_kernels_is_the_flight_on_the_twins(monkeypatch, vehicle, mode):
    assert load_vehicle("cf2x").rotor_drag_coefficient > 0.0
    assert load_vehicle(vehicle).motor_time_constant_s > 0.0  # the lag runs
    compiled = _fly(vehicle, mode, 3000)
    monkeypatch.setattr(dynamics, "rk4", dynamics_kernels.rk4_python)
    monkeypatch.setattr(dynamics, "rotor_lag", dynamics_kernels.rotor_lag_python)
    monkeypatch.setattr(dynamics, "rotor_inputs", dynamics_kernels.rotor_inputs_python)
    twin = _fly(vehicle, mode, 3000)
    assert compiled == twin
    assert len(set(compiled)) == len(compiled)  # airborne and moving every step: no two states compared alike
