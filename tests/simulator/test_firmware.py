"""Onboard commander and mixer: saturation keeps roll/pitch, arming, watchdog timings, command rejection,
the attitude loop, landing, and the battery."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from link.messages import (
    AttitudeTarget,
    BatteryStatus,
    CommandKind,
    Heartbeat,
    ThrustMoment,
    VehicleCommand,
    VehicleMode,
)
from model.frames import quat_from_euler_zyx, rotation_angle_between
from model.vehicle import load_vehicle
from simulator.firmware import load_firmware_params
from simulator.mixer import Mixer
from simulator.vehicle_sim import SimVehicle

CF = load_vehicle("crazyflie")
PARAMS = load_firmware_params()
TICK_S = 1.0 / PARAMS.commander_rate_hz


def _sim(z=1.0, airborne=True, vehicle=CF, seed=0):
    return SimVehicle(vehicle, np.random.default_rng(seed), initial_position_enu_m=(0.0, 0.0, z),
                      airborne=airborne)


def _send(sim, message):
    sim.handle_uplink(message, sim.t_s)


def _hover(sim):
    _send(sim, ThrustMoment(sim.t_s, CF.weight_n, (0.0, 0.0, 0.0)))


# --- mixer --------------------------------------------------------------------------------------------
@pytest.mark.parametrize("name", ["crazyflie", "cf2x"])
def test_mixer_is_exact_inside_the_limits(name):
    vehicle = load_vehicle(name)
    mixer = Mixer(vehicle)
    request = np.array([vehicle.weight_n, 1e-3, -2e-3, 2e-4])
    assert mixer.wrench(mixer.mix(request[0], request[1:])) == pytest.approx(request, rel=1e-9, abs=1e-15)


def test_mixer_keeps_roll_pitch_when_thrust_is_too_high():
    mixer = Mixer(CF)
    request = (0.98 * CF.max_thrust_n, (0.5 * CF.max_moment_nm[0], -0.3 * CF.max_moment_nm[1], 0.0))
    got = mixer.wrench(mixer.mix(*request))
    assert got[1:3] == pytest.approx(request[1][:2], rel=1e-9)
    assert got[0] < request[0]  # thrust gave way


def test_mixer_keeps_roll_pitch_when_thrust_is_too_low():
    mixer = Mixer(CF)
    got = mixer.wrench(mixer.mix(0.0, (0.4 * CF.max_moment_nm[0], 0.0, 0.0)))
    assert got[1] == pytest.approx(0.4 * CF.max_moment_nm[0], rel=1e-9)
    assert got[0] > 0.0  # the collective rose to make the moment


def test_mixer_drops_yaw_before_roll_pitch():
    mixer = Mixer(CF)
    request_mx = 0.8 * CF.max_moment_nm[0]
    got = mixer.wrench(mixer.mix(CF.weight_n, (request_mx, 0.0, CF.max_moment_nm[2])))
    assert got[1] == pytest.approx(request_mx, rel=1e-9)
    assert 0.0 <= got[3] < CF.max_moment_nm[2]


def test_mixer_scales_an_impossible_roll_pitch_keeping_its_direction():
    cf2x = load_vehicle("cf2x")
    mixer = Mixer(cf2x)
    mx, my = cf2x.max_moment_nm[0], cf2x.max_moment_nm[1]  # both at once exceed an X frame's rotors
    got = mixer.wrench(mixer.mix(cf2x.weight_n, (mx, my, 1e-4)))
    assert got[1] / got[2] == pytest.approx(mx / my, rel=1e-9)
    assert got[1] < mx
    assert got[3] == pytest.approx(0.0, abs=1e-15)


@settings(max_examples=200, deadline=None)
@given(thrust=st.floats(0.0, 1.0), mx=st.floats(-1.0, 1.0), my=st.floats(-1.0, 1.0), mz=st.floats(-1.0, 1.0))
def test_mixer_stays_in_limits_and_meets_any_plus_frame_roll_pitch(thrust, mx, my, mz):
    # In the "+" frame roll and pitch use disjoint rotor pairs, so every |M| <= max_moment is reachable.
    mixer = Mixer(CF)
    moment = np.array([mx, my, mz]) * CF.max_moment_nm
    speeds = np.array(mixer.mix(thrust * CF.max_thrust_n, moment))
    assert np.all(speeds >= CF.rotor_speed_min_radps - 1e-9)
    assert np.all(speeds <= CF.rotor_speed_max_radps + 1e-9)
    got = mixer.wrench(speeds)
    assert got[1:3] == pytest.approx(moment[:2], rel=1e-6, abs=1e-12)


# --- arming -------------------------------------------------------------------------------------------
def test_motors_stay_off_until_armed_and_stop_on_disarm():
    sim = _sim(z=0.0, airborne=False)
    _hover(sim)
    sim.run(0.1)
    assert sim.dynamics.rotor_speeds_radps == (0.0,) * 4 and not sim.firmware.armed
    _send(sim, VehicleCommand(sim.t_s, CommandKind.ARM))
    sim.run(TICK_S)  # the next firmware cycle takes it
    assert sim.firmware.armed and sim.firmware.mode == VehicleMode.IDLE
    _hover(sim)
    sim.run(0.1)
    assert sim.dynamics.rotor_speeds_radps == pytest.approx([CF.hover_rotor_speed_radps] * 4)
    assert sim.firmware.mode == VehicleMode.MOMENTS
    _send(sim, VehicleCommand(sim.t_s, CommandKind.DISARM))
    sim.run(0.01)
    assert sim.dynamics.rotor_speeds_radps == (0.0,) * 4 and not sim.firmware.armed


def test_land_descends_slowly_to_the_floor_then_disarms():
    sim = _sim(z=1.0)
    _hover(sim)
    sim.step()
    _send(sim, VehicleCommand(sim.t_s, CommandKind.LAND))
    sim.run(TICK_S)  # the next firmware cycle takes it
    lowest_vz = 0.0
    while sim.firmware.armed and sim.t_s < 10.0:
        _hover(sim)  # setpoints are ignored while landing
        sim.step()
        lowest_vz = min(lowest_vz, sim.truth.velocity_enu_mps[2])
        if sim.firmware.armed:
            assert sim.firmware.mode == VehicleMode.LANDING
    assert sim.crash is None and sim.dynamics.on_ground and not sim.firmware.armed
    assert -lowest_vz == pytest.approx(PARAMS.landing_descent_speed_mps, rel=0.05)
    assert -lowest_vz <= PARAMS.contact.landing_speed_max_mps
    assert sim.t_s == pytest.approx(1.0 / PARAMS.landing_descent_speed_mps, rel=0.15)


# --- watchdog -----------------------------------------------------------------------------------------
def test_watchdog_levels_at_500_ms_then_cuts_motors_at_2000_ms():
    sim = _sim(z=2.0)
    tilt = quat_from_euler_zyx(math.radians(10.0), 0.0, math.radians(40.0))
    thrust = CF.weight_n / math.cos(math.radians(10.0))
    last_arrival = 0.0
    while sim.t_s < 0.5:
        last_arrival = sim.t_s
        _send(sim, AttitudeTarget(sim.t_s, thrust, tilt))
        sim.run(0.01)
    level_at = off_at = None
    while sim.t_s < last_arrival + 2.1:
        sim.step()
        if level_at is None and sim.firmware.mode == VehicleMode.LEVEL:
            level_at = sim.t_s - sim.dynamics.dt_s  # the tick ran at the start of this step
            assert sim.firmware.heartbeat().failsafe
        if off_at is None and sim.dynamics.rotor_speeds_radps == (0.0,) * 4:
            off_at = sim.t_s - sim.dynamics.dt_s
        if level_at is not None and sim.t_s < last_arrival + 1.9:
            # LEVEL: commanded to roll = pitch = 0 with the heading of its entry, last thrust kept
            commanded = sim.firmware.mixer.wrench(sim.dynamics.rotor_speeds_radps)[0]
            if sim.t_s > level_at + 0.8:
                level = quat_from_euler_zyx(0.0, 0.0, math.radians(40.0))
                assert rotation_angle_between(sim.truth.attitude_wxyz, level) < math.radians(0.5)
                assert commanded == pytest.approx(thrust, rel=1e-6)
    assert 0.5 < level_at - last_arrival <= 0.5 + TICK_S + 1e-9
    assert 2.0 < off_at - last_arrival <= 2.0 + TICK_S + 1e-9
    assert not sim.firmware.armed and sim.firmware.heartbeat().failsafe


def test_setpoints_time_out_by_arrival_not_by_their_own_stamp():
    sim = _sim(z=2.0)
    sim.run(0.3)
    stale = ThrustMoment(time_s=-100.0, thrust_n=CF.weight_n, moment_flu_nm=(0.0, 0.0, 0.0))
    arrival = sim.t_s
    sim.handle_uplink(stale, arrival)
    sim.run(0.45)
    assert sim.firmware.mode == VehicleMode.MOMENTS  # 0.45 s after arrival: still fresh
    sim.run(0.1)
    assert sim.firmware.mode == VehicleMode.LEVEL


# --- rejection ----------------------------------------------------------------------------------------
BAD_SETPOINTS = [
    ThrustMoment(0.0, float("nan"), (0.0, 0.0, 0.0)),
    ThrustMoment(0.0, 0.2, (0.0, float("inf"), 0.0)),
    ThrustMoment(float("nan"), 0.2, (0.0, 0.0, 0.0)),
    ThrustMoment(0.0, -0.01, (0.0, 0.0, 0.0)),
    ThrustMoment(0.0, CF.max_thrust_n * 1.01, (0.0, 0.0, 0.0)),
    ThrustMoment(0.0, 0.2, (CF.max_moment_nm[0] * 1.01, 0.0, 0.0)),
    ThrustMoment(0.0, 0.2, (0.0, 0.0, -CF.max_moment_nm[2] * 1.01)),
    AttitudeTarget(0.0, 0.2, (0.9, 0.0, 0.0, 0.0)),
    AttitudeTarget(0.0, 0.2, (float("nan"), 0.0, 0.0, 0.0)),
    AttitudeTarget(0.0, 0.2, (1.0, 0.0, 0.0, 0.0), (0.0, float("-inf"), 0.0)),
    AttitudeTarget(0.0, 0.2, (1.0, 0.0, 0.0, 0.0), (0.0, 0.0, PARAMS.max_rate_radps * 1.1)),
    AttitudeTarget(0.0, float("inf"), (1.0, 0.0, 0.0, 0.0)),
    VehicleCommand(0.0, 99),
    VehicleCommand(float("nan"), CommandKind.DISARM),
]


def test_bad_commands_are_rejected_counted_and_never_applied():
    sim = _sim(z=2.0)
    _hover(sim)
    sim.run(0.01)
    before = sim.dynamics.rotor_speeds_radps
    for i, bad in enumerate(BAD_SETPOINTS, start=1):
        _send(sim, bad)
        sim.run(0.004)
        assert sim.firmware.rejected_commands == i, bad
        assert sim.dynamics.rotor_speeds_radps == pytest.approx(before, rel=1e-6), bad
    assert sim.firmware.armed and sim.firmware.mode == VehicleMode.MOMENTS
    sim.run(0.5)
    statuses = [o.message for o in sim.pop_outputs() if isinstance(o.message, BatteryStatus)]
    assert statuses[-1].rejected_commands == len(BAD_SETPOINTS)


def test_limits_allow_float32_rounding_of_the_maximum():
    sim = _sim(z=2.0)
    at_max = float(np.float32(CF.max_thrust_n))
    _send(sim, ThrustMoment(0.0, at_max, (0.0, 0.0, float(np.float32(CF.max_moment_nm[2])))))
    assert sim.firmware.rejected_commands == 0


# --- attitude loop ------------------------------------------------------------------------------------
@pytest.mark.parametrize("name", ["crazyflie", "cf2x"])
def test_attitude_loop_converges_to_the_commanded_attitude(name):
    vehicle = load_vehicle(name)
    sim = _sim(z=2.0, vehicle=vehicle)
    target = quat_from_euler_zyx(math.radians(15.0), math.radians(-10.0), math.radians(30.0))
    thrust = vehicle.weight_n / (math.cos(math.radians(15.0)) * math.cos(math.radians(10.0)))
    while sim.t_s < 1.5:
        _send(sim, AttitudeTarget(sim.t_s, thrust, target))
        sim.run(0.01)
    assert sim.crash is None and sim.firmware.mode == VehicleMode.ATTITUDE
    assert rotation_angle_between(sim.truth.attitude_wxyz, target) < math.radians(0.2)
    assert np.linalg.norm(sim.truth.rate_flu_radps) < 0.01


def test_attitude_law_matches_the_matrix_formula():
    # e_R = 1/2 vee(R_d^T R - R^T R_d), M = I(-K_R e_R - K_w (w - w_d)) + w x I w, written with matrices
    sim = _sim(z=2.0)
    rng = np.random.default_rng(5)
    for _ in range(20):
        q = quat_from_euler_zyx(*rng.uniform(-1.0, 1.0, 3))
        qd = quat_from_euler_zyx(*rng.uniform(-1.0, 1.0, 3))
        w, wd = rng.normal(size=3), rng.normal(size=3)
        sim.dynamics.set_state(attitude_wxyz=q, rate_flu_radps=w)
        got = sim.firmware.attitude_moments(qd, tuple(wd), sim.dynamics)
        r, rd = _matrix(q), _matrix(qd)
        skew = rd.T @ r - r.T @ rd
        e_r = 0.5 * np.array([skew[2, 1], skew[0, 2], skew[1, 0]])
        inertia = CF.inertia_kgm2
        expected = inertia @ (-np.array(PARAMS.k_r_per_s2) * e_r - np.array(PARAMS.k_w_per_s) * (w - wd)) \
            + np.cross(w, inertia @ w)
        assert got == pytest.approx(expected, rel=1e-9, abs=1e-15)


def _matrix(q):
    w, x, y, z = q
    return np.array([
        [1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
        [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
        [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)],
    ])


# --- reports ------------------------------------------------------------------------------------------
def test_heartbeat_reports_and_battery_drains_with_rotor_power():
    sim = _sim(z=2.0)
    for _ in range(500):
        _hover(sim)
        sim.run(0.01)
    outputs = sim.pop_outputs()
    beats = [o.message for o in outputs if isinstance(o.message, Heartbeat)]
    statuses = [o for o in outputs if isinstance(o.message, BatteryStatus)]
    assert len(beats) == pytest.approx(5.0 * PARAMS.heartbeat_rate_hz, abs=1)
    assert all(b.armed and b.mode == VehicleMode.MOMENTS and not b.failsafe for b in beats)
    assert statuses[0].message.voltage_v == pytest.approx(CF.battery_full_v, abs=1e-3)
    # Hover power from the rotor model: each rotor's aerodynamic power is torque * speed = k_D w^3.
    w = CF.hover_rotor_speed_radps
    power_w = 4.0 * CF.k_drag_torque * w**3 / PARAMS.motor_efficiency + PARAMS.avionics_power_w
    energy_j = CF.battery_capacity_mah * 3.6 * 0.5 * (CF.battery_full_v + CF.battery_empty_v)
    last = statuses[-1]
    drop_v = (CF.battery_full_v - CF.battery_empty_v) * power_w * last.release_time_s / energy_j
    assert CF.battery_full_v - last.message.voltage_v == pytest.approx(drop_v, rel=0.02)
    assert last.message.remaining_pct < 100
