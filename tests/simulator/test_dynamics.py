"""Rigid-body dynamics against closed-form physics: hover, free fall, moments, torque-free spin, floor,
blocks, bounds, motor lag and rotor drag; and the float quaternion helpers against scipy."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest
from scipy.integrate import solve_ivp
from scipy.spatial.transform import Rotation

from model.frames import quat_from_euler_zyx, quat_multiply, rotation_angle_between, yaw_of
from model.vehicle import GRAVITY_MPS2, load_vehicle
from model.world import World
from simulator.dynamics import QuadrotorDynamics
from simulator.firmware import load_firmware_params

CONTACT = load_firmware_params().contact


@pytest.fixture(scope="module")
def cf():
    return load_vehicle("crazyflie")


def _scipy(q):
    w, x, y, z = q
    return Rotation.from_quat([x, y, z, w])


def _rotor_speeds_for(vehicle, thrust_n, moment_flu_nm):
    """Invert A w^2 = [T, M] directly (independent of the mixer)."""
    w2 = np.linalg.solve(vehicle.allocation, np.array([thrust_n, *moment_flu_nm]))
    assert np.all(w2 >= 0.0)
    return np.sqrt(w2).tolist()


def _run(dyn, seconds):
    for _ in range(round(seconds / dyn.dt_s)):
        dyn.step()


# --- quaternion helpers ---------------------------------------------------------------------------
def test_quaternion_helpers_agree_with_scipy():
    rng = np.random.default_rng(3)
    for _ in range(50):
        a = tuple(Rotation.random(random_state=rng).as_quat(scalar_first=True).tolist())
        b = tuple(Rotation.random(random_state=rng).as_quat(scalar_first=True).tolist())
        assert np.allclose(_scipy(quat_multiply(a, b)).as_matrix(), (_scipy(a) * _scipy(b)).as_matrix())
        roll, pitch, yaw = rng.uniform(-1.2, 1.2, 3)
        expected = Rotation.from_euler("ZYX", [yaw, pitch, roll])
        assert np.allclose(_scipy(quat_from_euler_zyx(roll, pitch, yaw)).as_matrix(), expected.as_matrix())
        assert math.isclose(yaw_of(quat_from_euler_zyx(roll, pitch, yaw)), yaw, abs_tol=1e-9)
        angle = (_scipy(a).inv() * _scipy(b)).magnitude()
        assert math.isclose(rotation_angle_between(a, b), angle, abs_tol=1e-7)


# --- hover, free fall, moments ----------------------------------------------------------------------
def test_hover_rotor_speed_matches_weight_balance_and_holds_altitude(cf):
    hover = math.sqrt(cf.mass_kg * GRAVITY_MPS2 / (4.0 * cf.k_thrust))
    assert hover == pytest.approx(1789.0, abs=1.0)  # issue "The emulator": about 1789 rad/s
    dyn = QuadrotorDynamics(cf, CONTACT, position_enu_m=(0.0, 0.0, 1.0))
    dyn.command_rotor_speeds([hover] * 4)
    _run(dyn, 2.0)
    assert dyn.position_enu_m == pytest.approx((0.0, 0.0, 1.0), abs=1e-9)
    assert dyn.velocity_enu_mps == pytest.approx((0.0, 0.0, 0.0), abs=1e-9)


def test_free_fall_follows_z0_minus_half_g_t_squared(cf):
    z0 = 5.0
    dyn = QuadrotorDynamics(cf, CONTACT, position_enu_m=(0.3, -0.2, z0))
    for t in (0.1, 0.5, 0.9):
        _run(dyn, t - dyn.t_s)
        assert dyn.t_s == pytest.approx(t)
        assert dyn.position_enu_m[2] == pytest.approx(z0 - 0.5 * GRAVITY_MPS2 * t * t, abs=1e-9)
        assert dyn.velocity_enu_mps[2] == pytest.approx(-GRAVITY_MPS2 * t, abs=1e-9)
        assert dyn.position_enu_m[:2] == pytest.approx((0.3, -0.2), abs=1e-12)
        assert dyn.specific_force_flu() == pytest.approx((0.0, 0.0, 0.0))  # an accelerometer in free fall


@pytest.mark.parametrize("axis", [0, 1, 2])
def test_pure_moment_gives_angular_acceleration_moment_over_inertia(cf, axis):
    moment = [0.0, 0.0, 0.0]
    moment[axis] = 0.25 * cf.max_moment_nm[axis]
    dyn = QuadrotorDynamics(cf, CONTACT, position_enu_m=(0.0, 0.0, 10.0))
    dyn.command_rotor_speeds(_rotor_speeds_for(cf, cf.weight_n, moment))
    _run(dyn, 0.05)
    expected = moment[axis] / cf.inertia_kgm2[axis, axis]  # rad/s^2; w x I w = 0 about one principal axis
    rates = dyn.rate_flu_radps
    assert rates[axis] == pytest.approx(expected * 0.05, rel=1e-9)
    assert [r for i, r in enumerate(rates) if i != axis] == pytest.approx([0.0, 0.0], abs=1e-12)


def test_torque_free_spin_conserves_energy_and_angular_momentum(cf):
    body = dataclasses.replace(cf, inertia_kgm2=np.diag([1.4e-5, 2.1e-5, 2.9e-5]))  # all axes distinct
    dyn = QuadrotorDynamics(body, CONTACT, position_enu_m=(0.0, 0.0, 1000.0))
    dyn.set_state(rate_flu_radps=(0.4, 0.3, 6.0), attitude_wxyz=quat_from_euler_zyx(0.2, -0.1, 0.5))
    inertia = body.inertia_kgm2

    def energy_and_momentum():
        w = np.array(dyn.rate_flu_radps)
        r = _scipy(dyn.attitude_wxyz).as_matrix()
        return 0.5 * w @ inertia @ w, r @ inertia @ w  # J, world-frame N m s

    e0, h0 = energy_and_momentum()
    _run(dyn, 10.0)
    e1, h1 = energy_and_momentum()
    assert not np.allclose(dyn.rate_flu_radps, (0.4, 0.3, 6.0), atol=1e-3)  # it did precess
    assert e1 == pytest.approx(e0, rel=1e-7)
    assert np.linalg.norm(h1 - h0) < 1e-7 * np.linalg.norm(h0)


# --- floor --------------------------------------------------------------------------------------------
def test_resting_on_the_floor_neither_sinks_bounces_nor_slides(cf):
    dyn = QuadrotorDynamics(cf, CONTACT, position_enu_m=(0.5, 0.5, 0.0))
    assert dyn.on_ground
    below_weight = _rotor_speeds_for(cf, 0.9 * cf.weight_n, (1e-4, -1e-4, 1e-4))
    dyn.command_rotor_speeds(below_weight)
    _run(dyn, 1.0)
    assert dyn.on_ground and dyn.crash is None
    assert dyn.position_enu_m == (0.5, 0.5, 0.0)
    assert dyn.velocity_enu_mps == (0.0, 0.0, 0.0)
    assert rotation_angle_between(dyn.attitude_wxyz, (1.0, 0.0, 0.0, 0.0)) == 0.0
    assert dyn.specific_force_flu() == pytest.approx((0.0, 0.0, GRAVITY_MPS2))  # the floor holds it up


def test_takeoff_when_thrust_exceeds_weight(cf):
    dyn = QuadrotorDynamics(cf, CONTACT, position_enu_m=(0.0, 0.0, 0.0))
    dyn.command_rotor_speeds(_rotor_speeds_for(cf, 1.2 * cf.weight_n, (0.0, 0.0, 0.0)))
    _run(dyn, 0.5)
    accel = 0.2 * GRAVITY_MPS2
    assert not dyn.on_ground
    assert dyn.position_enu_m[2] == pytest.approx(0.5 * accel * 0.5**2, rel=1e-6)


def test_slow_touchdown_is_a_landing(cf):
    dyn = QuadrotorDynamics(cf, CONTACT, position_enu_m=(1.0, 2.0, 0.05))
    dyn.set_state(velocity_enu_mps=(0.1, 0.0, -0.3), attitude_wxyz=quat_from_euler_zyx(0.02, 0.0, 0.7))
    dyn.command_rotor_speeds([cf.hover_rotor_speed_radps * 0.999] * 4)
    _run(dyn, 0.5)
    assert dyn.crash is None and dyn.on_ground
    assert dyn.position_enu_m[2] == 0.0
    assert dyn.velocity_enu_mps == (0.0, 0.0, 0.0)
    assert yaw_of(dyn.attitude_wxyz) == pytest.approx(0.7, abs=0.01)  # levelled, heading kept
    level = quat_from_euler_zyx(0.0, 0.0, yaw_of(dyn.attitude_wxyz))
    assert rotation_angle_between(dyn.attitude_wxyz, level) < 1e-9


def test_hard_touchdown_is_a_crash_with_time_and_place(cf):
    z0, v0 = 0.2, -2.0
    dyn = QuadrotorDynamics(cf, CONTACT, position_enu_m=(1.0, 2.0, z0))
    dyn.set_state(velocity_enu_mps=(0.0, 0.0, v0))
    _run(dyn, 0.5)
    # z0 + v0 t - g t^2 / 2 = 0
    t_hit = (v0 + math.sqrt(v0 * v0 + 2.0 * GRAVITY_MPS2 * z0)) / GRAVITY_MPS2
    assert dyn.crash is not None and "floor" in dyn.crash.reason
    assert dyn.crash.time_s == pytest.approx(t_hit, abs=dyn.dt_s)
    assert dyn.crash.position_enu_m == pytest.approx((1.0, 2.0, 0.0))
    frozen = dyn.position_enu_m
    _run(dyn, 0.1)
    assert dyn.position_enu_m == frozen and dyn.rotor_speeds_radps == (0.0,) * 4


# --- blocks and bounds --------------------------------------------------------------------------------
def test_block_contact_is_a_crash_at_the_collision_radius(cf):
    block = [1.0, 1.2, -1.0, 1.0, 0.0, 2.0]
    world = World(bounds=np.array([-3.0, 3.0, -3.0, 3.0, 0.0, 3.0]), blocks=np.array([block]))
    speed = 1.0
    dyn = QuadrotorDynamics(cf, CONTACT, world=world, position_enu_m=(-1.0, 0.0, 1.0))
    dyn.set_state(velocity_enu_mps=(speed, 0.0, 0.0), rotor_speeds_radps=[cf.hover_rotor_speed_radps] * 4)
    radius = dyn.collision_radius_m
    arm = max(np.linalg.norm(p) for p in cf.rotor_positions_flu_m)
    assert radius == pytest.approx(arm + cf.prop_radius_m) == pytest.approx(0.046 + 0.0225)
    _run(dyn, 3.0)
    t_contact = (block[0] - radius - (-1.0)) / speed
    assert dyn.crash is not None and "block 0" in dyn.crash.reason
    assert dyn.crash.time_s == pytest.approx(t_contact, abs=1.5 * dyn.dt_s)
    expected = (block[0] - radius, 0.0, 1.0)
    assert dyn.crash.position_enu_m == pytest.approx(expected, abs=speed * 1.5 * dyn.dt_s)


def test_leaving_the_bounds_is_a_crash_at_the_ceiling(cf):
    world = World.empty(bounds=(-1.0, 1.0, -1.0, 1.0, 0.0, 1.5))
    dyn = QuadrotorDynamics(cf, CONTACT, world=world, position_enu_m=(0.0, 0.0, 1.0))
    dyn.command_rotor_speeds(_rotor_speeds_for(cf, 1.5 * cf.weight_n, (0.0, 0.0, 0.0)))
    _run(dyn, 2.0)
    t_out = math.sqrt(2.0 * 0.5 / (0.5 * GRAVITY_MPS2))  # 0.5 m at 0.5 g
    assert dyn.crash is not None and "bounds" in dyn.crash.reason
    assert dyn.crash.time_s == pytest.approx(t_out, abs=dyn.dt_s)
    assert dyn.crash.position_enu_m[2] == pytest.approx(1.5, abs=0.01)


# --- motor lag and rotor drag (cf2x) ------------------------------------------------------------------
def test_motor_lag_is_first_order():
    cf2x = load_vehicle("cf2x")
    tau = cf2x.motor_time_constant_s
    dyn = QuadrotorDynamics(cf2x, CONTACT, position_enu_m=(0.0, 0.0, 100.0))
    target = 2000.0
    dyn.command_rotor_speeds([target] * 4)
    _run(dyn, tau)
    assert dyn.rotor_speeds_radps == pytest.approx([target * (1.0 - math.exp(-1.0))] * 4, rel=1e-9)


def test_rotor_drag_decays_horizontal_speed_exponentially():
    cf2x = load_vehicle("cf2x")
    dyn = QuadrotorDynamics(cf2x, CONTACT, position_enu_m=(0.0, 0.0, 10.0))
    hover = cf2x.hover_rotor_speed_radps
    dyn.set_state(velocity_enu_mps=(2.0, 0.0, 0.0), rotor_speeds_radps=[hover] * 4)
    _run(dyn, 1.0)
    # m v' = -c * sum(w_i / w_hover) * v = -4 c v at hover
    decay = 4.0 * cf2x.rotor_drag_coefficient / cf2x.mass_kg
    assert dyn.velocity_enu_mps[0] == pytest.approx(2.0 * math.exp(-decay * 1.0), rel=1e-6)
    assert dyn.velocity_enu_mps[2] == pytest.approx(0.0, abs=1e-9)


# --- the integrator: fourth order, against an independent solution -------------------------------------
def _reference_state(vehicle, x0, rotors0, command, seconds):
    """The module docstring's equations written independently (numpy, scipy rotations, motor lag as a
    state) and solved by scipy's DOP853 to 1e-12: p, v, q, w after `seconds`."""
    m = vehicle.mass_kg
    inertia = np.asarray(vehicle.inertia_kgm2, float)
    allocation = np.asarray(vehicle.allocation, float)
    tau, c = vehicle.motor_time_constant_s, vehicle.rotor_drag_coefficient
    command = np.asarray(command, float)

    def derivative(_, s):
        v, q, w, rotors = s[3:6], s[6:10], s[10:13], s[13:17]
        thrust, *moment = allocation @ rotors**2
        r = _scipy(q).as_matrix()
        drag_xy = -c * (rotors.sum() / vehicle.hover_rotor_speed_radps) * (r.T @ v)[:2]
        acceleration = r @ np.array([*drag_xy, thrust]) / m - np.array([0.0, 0.0, GRAVITY_MPS2])
        dq = 0.5 * np.concatenate([[-q[1:] @ w], q[0] * w + np.cross(q[1:], w)])  # q (x) (0, w) / 2
        dw = np.linalg.solve(inertia, np.asarray(moment) - np.cross(w, inertia @ w))
        drotors = (command - rotors) / tau if tau > 0.0 else np.zeros(4)
        return np.concatenate([v, acceleration, dq, dw, drotors])

    start = np.concatenate([x0, rotors0 if tau > 0.0 else command])
    solution = solve_ivp(derivative, (0.0, seconds), start, method="DOP853", rtol=1e-12, atol=1e-14)
    return solution.y[:13, -1]


@pytest.mark.parametrize("name", ["crazyflie", "cf2x"])  # cf2x: with motor lag and rotor drag
def test_rk4_is_fourth_order_and_converges_to_an_independent_solution(name):
    vehicle = load_vehicle(name)
    hover = vehicle.hover_rotor_speed_radps
    x0 = np.array([0.0, 0.0, 50.0, 1.5, -1.0, 0.5, *quat_from_euler_zyx(0.2, -0.3, 0.4), 4.0, -3.0, 6.0])
    rotors0 = [0.9 * hover] * 4
    command = [1.05 * hover, 0.97 * hover, 1.02 * hover, 0.99 * hover]  # moments on every axis
    seconds = 0.5
    expected = _reference_state(vehicle, x0, rotors0, command, seconds)
    errors = []
    for dt in (0.004, 0.002, 0.001):
        dyn = QuadrotorDynamics(vehicle, CONTACT, dt_s=dt, position_enu_m=tuple(x0[:3]))
        dyn.set_state(velocity_enu_mps=tuple(x0[3:6]), attitude_wxyz=tuple(x0[6:10]),
                      rate_flu_radps=tuple(x0[10:13]), rotor_speeds_radps=rotors0)
        dyn.command_rotor_speeds(command)
        _run(dyn, seconds)
        got = np.array([*dyn.position_enu_m, *dyn.velocity_enu_mps, *dyn.attitude_wxyz, *dyn.rate_flu_radps])
        errors.append(np.abs(got - expected).max())
    # global error ~ C dt^4: halving dt divides it by 16 (a third-order method would give 8)
    assert 12.0 < errors[0] / errors[1] < 20.0
    assert 12.0 < errors[1] / errors[2] < 20.0
    assert errors[2] < 1e-9  # at 1 kHz: rates within 1e-9 rad/s after 0.5 s of spinning at ~8 rad/s
