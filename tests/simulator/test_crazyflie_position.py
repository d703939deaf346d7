"""Position setpoints flown by the faithful firmware's onboard PID position controller (position_controller_pid.c)
on its own position estimate (external poses + accelerometer), and refused where they cannot be flown."""

import math

import numpy as np
import pytest
from testsupport import cfstack

from link.mavlink.codec import Codec, FrameParser
from link.messages import ExternalPose, PositionTarget
from model.vehicle import load_vehicle
from simulator.crazyflie.position_controller import PositionController
from simulator.crazyflie.stabilizer import load_crazyflie_params
from simulator.vehicle_sim import SimVehicle

CF = load_crazyflie_params()
CF21 = load_vehicle("cf21")


def test_a_position_target_crosses_the_link_in_ned_and_comes_back():
    sp = PositionTarget(2.5, (1.0, 2.0, 0.5), (0.1, -0.2, 0.3), 0.25)
    frame = Codec(255).encode(sp, target_system=3)
    decoded = FrameParser(Codec(3)).feed(frame, True)[0]
    assert decoded.target_system == 3
    m = decoded.message
    assert m.position_enu_m == pytest.approx(sp.position_enu_m) and m.velocity_enu_mps == pytest.approx(
        sp.velocity_enu_mps, abs=1e-6)
    assert m.yaw_enu_rad == pytest.approx(0.25, abs=1e-6) and m.time_s == 2.5


def test_the_position_pids_follow_the_firmware():
    pc = PositionController(CF.position_gains, 0.01)
    pc.reset((0.0, 0.0, 1.0), (0.0, 0.0, 0.0))
    roll, pitch, thrust = pc.update((0.1, 0.0, 1.0), (0.0, 0.0, 1.0), (0.0, 0.0, 0.0), 0.0)
    # x: position PID kp 2 -> 0.2 m/s; velocity PID kp 25 ki 1 -> 25 * 0.2 + 1 * 0.2 * 0.01; pitch = -that
    assert pitch == pytest.approx(-(25.0 * 0.2 + 1.0 * 0.2 * 0.01)) and roll == pytest.approx(0.0)
    # z at its setpoint, at rest: thrust is the base
    assert thrust == pytest.approx(36000.0)
    # limits: a far setpoint saturates the speed at 1.0 x 1.10 m/s and the tilt at 20 deg; the vz PID then
    # gives 25 x 1.1 + 15 x 1.1 x 0.01 (its first integral step), times thrustScale 1000, on the 36000 base
    roll, pitch, thrust = pc.update((0.0, -50.0, 30.0), (0.0, 0.0, 1.0), (0.0, 0.0, 0.0), 0.0)
    assert roll == pytest.approx(20.0)
    assert thrust == pytest.approx(36000.0 + 1000.0 * (25.0 * 1.1 + 15.0 * 1.1 * 0.01))


def _sim(firmware="crazyflie"):
    return SimVehicle(CF21, np.random.default_rng(2), initial_position_enu_m=(0.0, 0.0, 1.0), airborne=True,
                      firmware=firmware)


def test_without_a_position_source_or_a_position_controller_the_setpoint_is_refused():
    sim = _sim()
    sim.handle_uplink(PositionTarget(0.0, (0.0, 0.0, 1.0)), 0.0)
    sim.run(0.01)
    assert sim.firmware.rejected_commands == 1  # no external pose yet: no position estimate
    ideal = _sim("ideal")
    ideal.handle_uplink(ExternalPose(0.0, (0.0, 0.0, 1.0), (1.0, 0.0, 0.0, 0.0)), 0.0)
    ideal.handle_uplink(PositionTarget(0.0, (0.0, 0.0, 1.0)), 0.0)
    ideal.run(0.01)
    assert ideal.firmware.rejected_commands == 1


def test_the_onboard_controller_flies_a_step_on_its_own_estimate():
    sim = _sim()
    for _ in range(600):  # 6 s: hold, then 0.5 m along x at t = 1 s
        truth = sim.truth
        sim.handle_uplink(ExternalPose(sim.t_s, truth.position_enu_m, truth.attitude_wxyz), sim.t_s)
        target = (0.5, 0.0, 1.0) if sim.t_s >= 1.0 else (0.0, 0.0, 1.0)
        sim.handle_uplink(PositionTarget(sim.t_s, target), sim.t_s)
        sim.run(0.01)
        sim.pop_outputs()
    x, y, z = sim.truth.position_enu_m
    # the firmware's x/y position PIDs have no integral: within a few cm, not exactly
    assert abs(x - 0.5) < 0.05 and abs(y) < 0.05 and abs(z - 1.0) < 0.05
    assert sim.firmware.rejected_commands == 0
    est = sim.firmware.position.p
    assert math.dist(est, sim.truth.position_enu_m) < 0.03


def test_fly_in_position_mode_and_refusals(tmp_path):
    run = cfstack("fly", "--trajectory", "hover", "--mode", "position", "--firmware", "crazyflie",
                  "--vehicle-model", "cf21", "--json", "--log", str(tmp_path / "log"))
    assert run.returncode == 0, run.stderr
    bad = cfstack("fly", "--trajectory", "hover", "--mode", "position", "--firmware", "ideal", timeout=30)
    assert bad.returncode == 2 and "needs --firmware crazyflie" in bad.stderr and len(bad.stderr.splitlines()) == 1


