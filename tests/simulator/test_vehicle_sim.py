"""SimVehicle as a whole: determinism, output channels and rates, TIMESYNC, delivery times, crashes in a
course world, and one-line errors for bad vehicle/firmware files and start positions."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
from testsupport import shared_world

from link.messages import (
    AttitudeTarget,
    BatteryStatus,
    Heartbeat,
    ImuSample,
    MocapPose,
    MotorOutputs,
    MotorOutputsRequest,
    ThrustMoment,
    TimeSync,
    TruthState,
    VehicleMode,
)
from model.config import builtin_path
from model.errors import ConfigError, UserError, WorldError
from model.frames import quat_from_euler_zyx
from model.vehicle import load_mocap_room, load_vehicle
from model.world import World, load_world
from simulator.firmware import load_firmware_params
from simulator.vehicle_sim import SimVehicle

CF = load_vehicle("crazyflie")
ROOM = load_mocap_room("vicon")


def _scripted_run(seed: int, seconds: float = 1.0):
    sim = SimVehicle(CF, np.random.default_rng(seed), mocap_room=ROOM, initial_position_enu_m=(0.0, 0.0, 1.0),
                     airborne=True)
    outputs = []
    tilt = quat_from_euler_zyx(0.05, 0.0, 0.0)
    while sim.t_s < seconds:
        sim.handle_uplink(AttitudeTarget(sim.t_s, CF.weight_n, tilt), sim.t_s)
        sim.handle_uplink(TimeSync(0, 42), sim.t_s)
        sim.run(0.01)
        outputs.extend(sim.pop_outputs())
    return outputs


def test_same_seed_gives_identical_outputs_and_another_seed_does_not():
    first, second, other = _scripted_run(7), _scripted_run(7), _scripted_run(8)
    assert first == second
    assert first != other


def test_channels_rates_and_release_order():
    sim = SimVehicle(CF, np.random.default_rng(1), mocap_room=ROOM)
    sim.run(2.0)
    outputs = sim.pop_outputs()
    releases = [o.release_time_s for o in outputs]
    assert releases == sorted(releases) and releases[-1] <= sim.t_s
    params = load_firmware_params()

    def count(kind, channel):
        return sum(1 for o in outputs if isinstance(o.message, kind) and o.channel == channel)

    assert count(ImuSample, "downlink") == pytest.approx(2.0 * CF.imu.rate_hz, abs=1)
    assert count(Heartbeat, "downlink") == pytest.approx(2.0 * params.heartbeat_rate_hz, abs=1)
    assert count(BatteryStatus, "downlink") == pytest.approx(2.0 * params.battery_rate_hz, abs=1)
    assert count(TruthState, "truth") == pytest.approx(2.0 * params.truth_rate_hz, abs=1)
    assert count(MocapPose, "mocap") == pytest.approx(2.0 * ROOM.rate_hz, abs=4)
    assert len(outputs) == sum(count(k, c) for k, c in ((ImuSample, "downlink"), (Heartbeat, "downlink"),
                                                         (BatteryStatus, "downlink"), (TruthState, "truth"),
                                                         (MocapPose, "mocap")))
    imu_times = [o.message.time_s for o in outputs if isinstance(o.message, ImuSample)]
    assert np.diff(imu_times) == pytest.approx(1.0 / CF.imu.rate_hz)


def test_timesync_reply_carries_the_vehicle_clock_of_the_firmware_cycle_and_echoes_the_origin():
    """Delivered at 0.251 s (between two 2 ms firmware cycles), answered by the cycle at 0.252 s."""
    sim = SimVehicle(CF, np.random.default_rng(1))
    sim.run(0.251)
    sim.handle_uplink(TimeSync(remote_ns=0, origin_ns=123_456), sim.t_s)
    sim.handle_uplink(TimeSync(remote_ns=5, origin_ns=9), sim.t_s)  # a reply sent to us: not answered
    sim.step()  # the step at 0.251 s: no firmware cycle, nothing answered yet
    assert not [o for o in sim.pop_outputs() if isinstance(o.message, TimeSync)]
    sim.step()  # the cycle at 0.252 s
    replies = [o for o in sim.pop_outputs() if isinstance(o.message, TimeSync)]
    assert len(replies) == 1
    assert replies[0].message == TimeSync(remote_ns=252_000_000, origin_ns=123_456)
    assert replies[0].channel == "downlink" and replies[0].release_time_s == pytest.approx(0.252)


def test_an_uplink_acts_at_the_first_firmware_cycle_at_or_after_its_delivery():
    """first_effect_s is a true bound: a setpoint delivered at 0.3005 s changes the rotors from the
    0.302 s cycle on (500 Hz cycles on a 1 kHz physics grid), never before."""
    sim = SimVehicle(CF, np.random.default_rng(1), initial_position_enu_m=(0.0, 0.0, 1.0), airborne=True)
    hover = CF.hover_rotor_speed_radps
    assert sim.first_effect_s(0.3005) == pytest.approx(0.302)
    assert sim.first_effect_s(0.302) == pytest.approx(0.302)  # on a cycle: handled in it
    sim.run(0.301)
    sim.handle_uplink(ThrustMoment(0.0, 1.1 * CF.weight_n, (0.0, 0.0, 0.0)), 0.3005)
    sim.step()  # 0.301 -> 0.302: not a cycle
    assert sim.dynamics.rotor_speeds_radps == pytest.approx([hover] * 4)
    sim.step()  # the cycle at 0.302
    assert sim.dynamics.rotor_speeds_radps == pytest.approx([hover * math.sqrt(1.1)] * 4)
    off_grid = SimVehicle(CF, np.random.default_rng(1), physics_rate_hz=300.0)
    assert off_grid.first_effect_s(0.3005) == 0.3005  # cycles between steps: only the delivery bounds it


def test_an_uplink_delivered_later_waits_for_its_time():
    sim = SimVehicle(CF, np.random.default_rng(1), initial_position_enu_m=(0.0, 0.0, 1.0), airborne=True)
    hover = CF.hover_rotor_speed_radps
    sim.handle_uplink(ThrustMoment(0.0, 1.1 * CF.weight_n, (0.0, 0.0, 0.0)), 0.3)
    sim.run(0.29)
    assert sim.dynamics.rotor_speeds_radps == pytest.approx([hover] * 4)  # not applied yet
    sim.run(0.02)
    assert sim.dynamics.rotor_speeds_radps == pytest.approx([hover * math.sqrt(1.1)] * 4)
    sim.run(0.47)  # t = 0.78 s: had the watchdog counted from the t = 0 start, LEVEL would have begun
    assert sim.firmware.mode == VehicleMode.MOMENTS
    sim.run(0.03)
    assert sim.firmware.mode == VehicleMode.LEVEL


def test_crash_into_a_course_wall_is_reported_with_time_and_place():
    path = shared_world("test_lab_1")
    world = load_world(path)
    sim = SimVehicle(CF, np.random.default_rng(3), world=world, initial_position_enu_m=tuple(world.start),
                     airborne=True)
    nose_down = quat_from_euler_zyx(0.0, math.radians(10.0), 0.0)  # FLU: +pitch tips the nose down, thrust +x
    while sim.crash is None and sim.t_s < 3.0:
        thrust = CF.weight_n / math.cos(math.radians(10.0))
        sim.handle_uplink(AttitudeTarget(sim.t_s, thrust, nose_down), sim.t_s)
        sim.run(0.01)
    crash = sim.crash
    assert crash is not None and "block" in crash.reason
    wall_x = -1.02  # the wall [-1.02, -0.98] x [-2, -1] across the path from the start (-1.5, -1.5)
    radius = sim.dynamics.collision_radius_m
    assert crash.position_enu_m[0] == pytest.approx(wall_x - radius, abs=0.01)
    assert crash.position_enu_m[1:] == pytest.approx(tuple(world.start[1:]), abs=0.05)
    assert 0.0 < crash.time_s <= sim.t_s
    sim.run(0.6)
    beats = [o.message for o in sim.pop_outputs() if isinstance(o.message, Heartbeat)]
    assert beats[-1] == Heartbeat(armed=False, mode=VehicleMode.CRASHED, failsafe=True)
    assert sim.truth.position_enu_m == pytest.approx(crash.position_enu_m)


def test_bad_start_positions_give_one_line_errors():
    world = World(bounds=np.array([-1.0, 1.0, -1.0, 1.0, 0.0, 2.0]),
                  blocks=np.array([[0.2, 0.4, -1.0, 1.0, 0.0, 2.0]]), source="box.json")
    with pytest.raises(WorldError, match="box.json: start position .* outside the bounds"):
        SimVehicle(CF, np.random.default_rng(0), world=world, initial_position_enu_m=(3.0, 0.0, 1.0))
    with pytest.raises(WorldError, match="box.json: start position .* collision radius"):
        SimVehicle(CF, np.random.default_rng(0), world=world, initial_position_enu_m=(0.15, 0.0, 1.0))
    with pytest.raises(UserError, match="below the floor"):
        SimVehicle(CF, np.random.default_rng(0), initial_position_enu_m=(0.0, 0.0, -0.1))
    with pytest.raises(UserError, match="3 finite numbers"):
        SimVehicle(CF, np.random.default_rng(0), initial_position_enu_m=(0.0, float("nan"), 0.0))
    with pytest.raises(UserError, match="physics rate"):
        SimVehicle(CF, np.random.default_rng(0), physics_rate_hz=0.0)


def _edited_copy(tmp_path, source: Path, old: str, new: str) -> Path:
    text = source.read_text()
    assert old in text
    path = tmp_path / source.name
    path.write_text(text.replace(old, new, 1))
    return path


@pytest.mark.parametrize("old, new, field", [
    ("mass_kg = 0.030\n", "", "inertia.mass_kg: missing"),
    ("thrust_coefficient_n_per_radps2 = 2.3e-8", 'thrust_coefficient_n_per_radps2 = "2.3e-8"',
     "rotors.thrust_coefficient_n_per_radps2: expected a finite number"),
    ("rate_hz = 500.0", "rate_hz = true", "imu.rate_hz: expected a finite number"),
])
def test_bad_vehicle_files_name_the_file_and_field(tmp_path, old, new, field):
    path = _edited_copy(tmp_path, builtin_path("model", "params/vehicles", "crazyflie"), old, new)
    with pytest.raises(ConfigError) as err:
        load_vehicle(path)
    assert str(err.value).startswith(str(path)) and field in str(err.value)
    assert "\n" not in str(err.value)


@pytest.mark.parametrize("old, new, field", [
    ("k_w_per_s = [70.0, 70.0, 50.0]\n", "", "attitude.k_w_per_s: missing"),
    ("heartbeat_rate_hz = 2.0", 'heartbeat_rate_hz = "often"',
     "telemetry.heartbeat_rate_hz: expected a finite"),
    ("watchdog_shutdown_timeout_s = 2.0", "watchdog_shutdown_timeout_s = 0.4",
     "commander.watchdog_shutdown_timeout_s: must exceed"),
])
def test_bad_firmware_files_name_the_file_and_field(tmp_path, old, new, field):
    path = _edited_copy(tmp_path, builtin_path("simulator", "params", "firmware"), old, new)
    with pytest.raises(ConfigError) as err:
        SimVehicle(CF, np.random.default_rng(0), firmware_params=path)
    assert str(err.value).startswith(str(path)) and field in str(err.value)


def test_motor_outputs_come_only_on_request_at_its_rate_as_the_firmwares_pwm_duty():
    """MAV_CMD_SET_MESSAGE_INTERVAL semantics: nothing before the request; then one MotorOutputs per 1 / rate s of
    vehicle time, each the faithful firmware's motor.m1..m4 / pwm_max at that cycle; rate 0 stops them."""
    cf21 = load_vehicle("cf21")
    sim = SimVehicle(cf21, np.random.default_rng(2), initial_position_enu_m=(0.0, 0.0, 1.0), airborne=True,
                     firmware="crazyflie")
    hover = ThrustMoment(0.0, cf21.weight_n, (0.0, 0.0, 0.0))
    sim.handle_uplink(hover, 0.0)
    sim.run(0.2)
    assert not [o for o in sim.pop_outputs() if isinstance(o.message, MotorOutputs)]
    sim.handle_uplink(MotorOutputsRequest(10.0), sim.t_s)
    reports = []
    while sim.t_s < 1.2:
        sim.handle_uplink(ThrustMoment(sim.t_s, cf21.weight_n, (0.0, 0.0, 0.0)), sim.t_s)
        sim.step()
        for out in sim.pop_outputs():
            if isinstance(out.message, MotorOutputs):
                reports.append(out.message)
                pwm_max = sim.firmware.cf.curve.pwm_max
                assert out.message.duty == tuple(p / pwm_max for p in sim.firmware.motor_pwm)  # this cycle's PWM
    times = np.array([r.time_s for r in reports])
    assert len(reports) == 10 and np.allclose(np.diff(times), 0.1)
    assert all(0.0 < d < 1.0 for r in reports for d in r.duty)  # hovering: every motor driven, none saturated
    sim.handle_uplink(MotorOutputsRequest(0.0), sim.t_s)
    sim.run(0.5)
    late = [o.message for o in sim.pop_outputs() if isinstance(o.message, MotorOutputs)]
    assert all(m.time_s <= times[-1] + 0.1 + 1e-9 for m in late) and len(late) <= 1  # stopped at the next cycle
