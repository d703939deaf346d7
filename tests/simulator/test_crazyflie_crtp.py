"""The faithful firmware's CRTP commanders (crtp_commander_rpyt.c, crtp_commander_high_level.c, the
commander's watchdog): thrust lock, the 1000 / 60000 clamps, auto-arming, the watchdog re-locking the
thrust, non-finite setpoints refused, the high-level commander's plans and its enable parameter."""

from __future__ import annotations

import math

import numpy as np
import pytest

from link.crtp.setpoints import HighLevel, NotifySetpointsStop, PositionSetpoint, Rpyt, StopSetpoint
from model.vehicle import load_vehicle
from simulator.crazyflie.high_level_commander import smooth_step
from simulator.firmware import load_firmware_params
from simulator.vehicle_sim import SimVehicle

CF21 = load_vehicle("cf21")
PARAMS = load_firmware_params()


def _sim() -> SimVehicle:
    return SimVehicle(CF21, np.random.default_rng(5), initial_position_enu_m=(0.0, 0.0, 0.0), firmware="crazyflie")


def _stream(sim: SimVehicle, record, seconds: float, period_s: float = 0.01) -> None:
    """Send `record` every period_s for `seconds` (a cflib script's loop), stepping the vehicle."""
    for _ in range(round(seconds / period_s)):
        sim.handle_uplink(record, sim.t_s)
        sim.run(period_s)


def test_thrust_is_locked_until_a_zero_thrust_packet_then_clamped():
    sim = _sim()
    fw = sim.firmware
    _stream(sim, Rpyt(0.0, 0.0, 0.0, 45000), 0.2)
    assert fw.armed  # the default build arms itself on a setpoint (no CONFIG_MOTORS_REQUIRE_ARMING)
    assert fw._sp_pid.thrust_pwm == 0.0 and sim.truth.position_enu_m[2] == 0.0  # locked: still on the floor
    _stream(sim, Rpyt(0.0, 0.0, 0.0, 0), 0.02)
    _stream(sim, Rpyt(0.0, 0.0, 0.0, 999), 0.02)
    assert fw._sp_pid.thrust_pwm == 0.0  # below MIN_THRUST (1000): 0
    _stream(sim, Rpyt(0.0, 0.0, 0.0, 65000), 0.02)
    assert fw._sp_pid.thrust_pwm == 60000.0  # capped at MAX_THRUST
    _stream(sim, Rpyt(0.0, 0.0, 0.0, 45000), 1.0)
    assert sim.truth.position_enu_m[2] > 0.1 and all(fw.motor_pwm)  # unlocked: it climbs


def test_non_finite_setpoints_are_refused_and_counted():
    sim = _sim()
    fw = sim.firmware
    before = fw.rejected_commands
    _stream(sim, Rpyt(math.nan, 0.0, 0.0, 0), 0.02)
    _stream(sim, PositionSetpoint(0.0, math.inf, 1.0, 0.0), 0.02)
    assert fw.rejected_commands - before == 4 and not fw.armed


def test_the_watchdog_levels_then_stops_and_locks_the_thrust_again():
    sim = _sim()
    fw = sim.firmware
    _stream(sim, Rpyt(0.0, 0.0, 0.0, 0), 0.02)
    _stream(sim, Rpyt(0.0, 0.0, 0.0, 40000), 0.5)
    sim.run(PARAMS.watchdog_shutdown_timeout_s + 0.1)  # silence: level at 0.5 s, motors off at 2 s
    assert not fw.armed and not any(fw.motor_pwm)
    _stream(sim, Rpyt(0.0, 0.0, 0.0, 40000), 0.1)  # priority fell to DISABLE: the lock is on again
    assert fw.armed and fw._sp_pid.thrust_pwm == 0.0


def test_stop_setpoint_stops_the_motors():
    sim = _sim()
    fw = sim.firmware
    _stream(sim, Rpyt(0.0, 0.0, 0.0, 0), 0.02)
    _stream(sim, Rpyt(0.0, 0.0, 0.0, 40000), 0.2)
    assert any(fw.motor_pwm)
    _stream(sim, StopSetpoint(), 0.02)
    assert not any(fw.motor_pwm)


def test_the_no_jerk_blend_is_rest_to_rest():
    h = 1e-4
    assert smooth_step(0.0) == 0.0 and smooth_step(1.0) == 1.0 and smooth_step(0.5) == 0.5  # odd symmetry
    for u in (0.0, 1.0):  # velocity, acceleration and jerk vanish at both ends (finite differences)
        values = [smooth_step(u + k * h) for k in (-2, -1, 0, 1, 2)]
        assert abs(values[3] - values[1]) / (2 * h) < 1e-6
        assert abs(values[3] - 2 * values[2] + values[1]) / h**2 < 1e-4
    assert all(smooth_step(a) < smooth_step(b) for a, b in zip(np.linspace(0.01, 0.99, 50),
                                                               np.linspace(0.02, 1.0, 50), strict=True))


def _with_position_fixes(sim: SimVehicle, seconds: float, record=None) -> None:
    """Run with the vehicle's true position as its external fixes (what the positioning deck gives)."""
    from link.messages import ExternalPose

    for _ in range(round(seconds / 0.01)):
        truth = sim.truth
        sim.firmware.take_position_fix(ExternalPose(sim.t_s, truth.position_enu_m, truth.attitude_wxyz), sim.t_s)
        if record is not None:
            sim.handle_uplink(record, sim.t_s)
        sim.run(0.01)


def test_high_level_takeoff_needs_the_enable_parameter_and_a_position_then_reaches_its_height():
    sim = _sim()
    fw = sim.firmware
    takeoff = HighLevel("takeoff", 0, z_m=0.6, duration_s=2.0)
    _stream(sim, takeoff, 0.01)
    assert fw.crtp_ignored == 1 and fw.high_level.plan is None  # no position estimate yet: nothing to plan from
    _with_position_fixes(sim, 0.5)
    fw.high_level_enabled = False
    _stream(sim, takeoff, 0.01)
    assert fw.crtp_ignored == 2
    fw.high_level_enabled = True
    _with_position_fixes(sim, 0.01, takeoff)
    _with_position_fixes(sim, 3.0)
    assert abs(sim.truth.position_enu_m[2] - 0.6) < 0.1
    _with_position_fixes(sim, 1.0, PositionSetpoint(0.2, 0.0, 0.6, 0.0))  # a low-level setpoint has priority
    assert fw.low_level_active and fw._sp_position == (0.2, 0.0, 0.6)
    _with_position_fixes(sim, 0.01, NotifySetpointsStop())
    _with_position_fixes(sim, 0.5)
    # the plan flies again: its end, above where the takeoff started (the estimate then)
    assert fw.mode.name == "POSITION" and fw._sp_position[2] == 0.6 and math.hypot(*fw._sp_position[:2]) < 0.01


def test_full_state_flies_its_position_and_the_quaternions_yaw_and_z_distance_its_height():
    from link.crtp.setpoints import FullState, Hover, ZDistance
    from model.frames import yaw_of

    sim = _sim()
    _with_position_fixes(sim, 0.3)
    yaw = 0.5
    state = FullState((0.2, -0.1, 0.5), (0.0,) * 3, (0.0,) * 3, (math.cos(yaw / 2), 0.0, 0.0, math.sin(yaw / 2)),
                      (0.0,) * 3)
    _with_position_fixes(sim, 4.0, state)
    truth = sim.truth
    assert math.dist(truth.position_enu_m, (0.2, -0.1, 0.5)) < 0.1, truth.position_enu_m
    assert abs(yaw_of(truth.attitude_wxyz) - yaw) < 0.05
    _with_position_fixes(sim, 3.0, ZDistance(0.0, 0.0, 0.0, 0.8))
    assert abs(sim.truth.position_enu_m[2] - 0.8) < 0.1
    _with_position_fixes(sim, 2.0, Hover(0.3, 0.0, 0.0, 0.8))  # 0.3 m/s forward in the yaw frame
    v = sim.truth.velocity_enu_mps
    assert math.hypot(v[0] - 0.3 * math.cos(yaw), v[1] - 0.3 * math.sin(yaw)) < 0.1, v


def _airborne_sim() -> SimVehicle:
    return SimVehicle(CF21, np.random.default_rng(5), initial_position_enu_m=(0.0, 0.0, 1.0), firmware="crazyflie",
                      airborne=True)


def _hover_pwm(sim: SimVehicle) -> int:
    """The PWM whose battery-compensated force holds the vehicle up: THRUST_MAX per motor at PWM 65535."""
    curve = sim.firmware.cf.curve
    return round(CF21.mass_kg * 9.81 / 4 / curve.thrust_max_n * curve.pwm_max)


def test_manual_setpoints_fly_angles_or_rates_with_their_own_thrust():
    from link.crtp.setpoints import Manual
    from model.frames import euler_zyx_of

    sim = _airborne_sim()
    hover = _hover_pwm(sim)
    _stream(sim, Manual(10.0, 0.0, 0.0, hover, False), 0.5)  # levelled: roll 10 deg, held
    roll, pitch, _ = (math.degrees(a) for a in euler_zyx_of(sim.truth.attitude_wxyz))
    assert abs(roll - 10.0) < 1.5 and abs(pitch) < 1.5, (roll, pitch)
    assert sim.firmware.mode.name == "ATTITUDE" and sim.firmware._sp_pid.thrust_pwm == hover  # no lock, no clamp
    _stream(sim, Manual(0.0, 0.0, 0.0, hover, False), 0.5)
    _stream(sim, Manual(-40.0, 0.0, 0.0, hover, True), 0.25)  # a roll rate of -40 deg/s for 0.25 s
    roll = math.degrees(euler_zyx_of(sim.truth.attitude_wxyz)[0])
    assert -12.0 < roll < -6.0, roll  # -10 deg less the rate loop's rise


def test_cppm_channels_scale_to_the_firmwares_angles_and_turn_to_rates_with_aux_0_low():
    from link.crtp.setpoints import CppmEmulation

    sim = _airborne_sim()
    fw = sim.firmware
    thrust_us = 1000 + round(_hover_pwm(sim) / fw.cf.curve.pwm_max * 1000)
    _stream(sim, CppmEmulation(1600, 1400, 1550, thrust_us, ()), 0.05)
    sp = fw._sp_pid
    # (1500 - channel) / 500 of cppm.angRoll / angPitch (50 deg) and cppm.rateYaw (400 deg/s): each inverted
    assert sp.attitude_deg[:2] == (-10.0, 10.0) and sp.attitude_rate_dps[2] == -40.0
    assert abs(sp.thrust_pwm - _hover_pwm(sim)) < fw.cf.curve.pwm_max / 1000
    _stream(sim, CppmEmulation(1600, 1500, 1500, thrust_us, (1000,)), 0.05)  # self-levelling off
    assert fw._sp_pid.attitude_rate_dps[:2] == (-144.0, 0.0)  # cppm.rateRoll 720 deg/s
    _stream(sim, CppmEmulation(1500, 1500, 1500, 900, ()), 0.05)
    assert fw._sp_pid.thrust_pwm == 0.0  # below 1000 us: never negative


def test_altitude_hold_climbs_at_its_vertical_velocity():
    from link.crtp.setpoints import AltitudeHold

    sim = _airborne_sim()
    _with_position_fixes(sim, 1.0, PositionSetpoint(0.0, 0.0, 1.0, 0.0))
    z0 = sim.truth.position_enu_m[2]
    _with_position_fixes(sim, 2.0, AltitudeHold(0.0, 0.0, 0.0, 0.25))
    vz = sim.truth.velocity_enu_mps[2]
    assert abs(vz - 0.25) < 0.05 and sim.truth.position_enu_m[2] - z0 > 0.3, (vz, sim.truth.position_enu_m)


def test_stab_mode_yaw_makes_the_rpyt_yaw_field_a_heading():
    from model.frames import yaw_of
    from simulator.crtp_service import CrtpService

    sim = _airborne_sim()
    service = CrtpService(sim)
    names = [f"{p.entry.group}.{p.entry.name}" for p in service.params]
    index = names.index("flightmode.stabModeYaw")
    assert service.params[index].get() == 0  # the firmware's default: a rate
    service.params[index].set(1)
    hover = _hover_pwm(sim)
    _stream(sim, Rpyt(0.0, 0.0, 0.0, 0), 0.02)
    _stream(sim, Rpyt(0.0, 0.0, 30.0, hover), 1.5)
    assert abs(math.degrees(yaw_of(sim.truth.attitude_wxyz)) - 30.0) < 2.0
    _stream(sim, Rpyt(0.0, 0.0, 30.0, hover), 0.5)  # held, not integrated as a rate would be
    assert abs(math.degrees(yaw_of(sim.truth.attitude_wxyz)) - 30.0) < 2.0


def test_the_app_channel_flies_thrust_and_moments_and_answers_time_sync_with_the_vehicle_clock():
    from link.crtp import appchannel
    from link.crtp.packet import CrtpPacket, Port, decode, encode
    from link.messages import ThrustMoment, TimeSync
    from simulator.crtp_service import CrtpService

    sim = _airborne_sim()
    service = CrtpService(sim)
    sim.run(0.5)
    request = appchannel.encode_time_sync(TimeSync(0, 42), reply=False)
    (reply,) = service.handle(encode(CrtpPacket(Port.PLATFORM, appchannel.APP_CHANNEL, request)), sim.t_s)
    answer = appchannel.decode(decode(reply).data, from_vehicle=True)
    assert answer.origin_ns == 42 and answer.remote_ns == round(sim.t_s * 1e9)
    # the app channel's thrust and moments fly exactly as MAVLink's ThrustMoment does (values exact in float32)
    direct = _airborne_sim()
    direct.run(0.5)
    for _ in range(20):
        command = ThrustMoment(sim.t_s, 0.28125, (0.0001220703125, 0.0, -0.0001220703125))
        packet = appchannel.encode_thrust_moment(command)
        assert service.handle(encode(CrtpPacket(Port.PLATFORM, appchannel.APP_CHANNEL, packet)), sim.t_s) == []
        direct.handle_uplink(command, direct.t_s)
        sim.run(0.01)
        direct.run(0.01)
    assert sim.truth == direct.truth and sim.truth.attitude_wxyz[1] > 0.05  # it rolled: the moment was flown
    nan = appchannel.encode_thrust_moment(ThrustMoment(sim.t_s, float("nan"), (0.0, 0.0, 0.0)))
    service.handle(encode(CrtpPacket(Port.PLATFORM, appchannel.APP_CHANNEL, nan)), sim.t_s)
    assert service.counters["non_finite"] == 1


def test_the_ground_stations_n_to_pwm_map_is_the_emulated_firmwares_compensated_thrust():
    """groundstation/params/crtp_link.toml's calibration against the emulated firmware's battery-compensated
    motors (motorsCompensateBatteryVoltage and the CF 2.1+ thrust curve): the PWM the ground station asks for a
    collective thrust makes that thrust on every motor, whatever the battery's voltage."""
    from groundstation.crtp_settings import load_crtp_link_settings

    settings = load_crtp_link_settings()
    curve = _airborne_sim().firmware.cf.curve
    for thrust_n in (0.1, CF21.mass_kg * 9.81, 0.4):
        pwm = settings.thrust_pwm(thrust_n)
        for supply_v in (4.2, 3.9, 3.6):
            ratio = curve.compensate(pwm, supply_v)
            assert 4 * curve.thrust_n(ratio, supply_v) == pytest.approx(thrust_n, rel=2e-4)
