"""The whole-flight check the compiled kernels' tests share: the faithful vehicle flown by setpoints that tilt and
turn it, step by step, so a kernel and its Python twin can be compared over every step of a flight.

Takes in: the vehicle's name, the mode (attitude: AttitudeTarget; moments: ThrustMoment), the physics steps, what
to record after each step (`record(sim)` -> bytes), the random seed, the desired yaw as a function of time (rad),
and whether the mocap pose is streamed as extpose in moments mode too (it always is in attitude mode).
Gives out: the list of what `record` returned, one entry per step.
Importable from every test module (pyproject.toml: pytest pythonpath = ["tests"]).
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from link.messages import AttitudeTarget, ExternalPose, ThrustMoment
from model.frames import quat_from_euler_zyx
from model.vehicle import load_mocap_room, load_vehicle
from simulator.vehicle_sim import SimVehicle

SETPOINT_EVERY = 10  # physics steps between setpoints: 100 Hz at 1 kHz


def fly_faithful(vehicle_name: str, mode: str, steps: int, record: Callable[[SimVehicle], bytes], *, seed: int,
                 yaw_rad: Callable[[float], float] = lambda t: 0.1, extpose_in_moments: bool = False) -> list[bytes]:
    """Airborne at 1 m in the vicon room; every SETPOINT_EVERY steps the mocap pose as extpose (attitude mode, or
    moments mode with extpose_in_moments), then in attitude mode roll 0.3 sin t, pitch 0.2 cos 2t (rad) and
    yaw_rad(t) at 1.1 x the weight, in moments mode a sway of a few 1e-5 N m at 1.05 x the weight (never a
    tumble)."""
    vehicle = load_vehicle(vehicle_name)
    sim = SimVehicle(vehicle, np.random.default_rng(seed), mocap_room=load_mocap_room("vicon"),
                     initial_position_enu_m=(0.0, 0.0, 1.0), airborne=True, firmware="crazyflie")
    out = []
    for k in range(steps):
        t = sim.t_s
        if k % SETPOINT_EVERY == 0:
            truth = sim.truth
            if mode == "attitude" or extpose_in_moments:
                sim.handle_uplink(ExternalPose(t, truth.position_enu_m, truth.attitude_wxyz), t)
            if mode == "attitude":
                tilt = quat_from_euler_zyx(0.3 * np.sin(t), 0.2 * np.cos(2.0 * t), yaw_rad(t))
                sim.handle_uplink(AttitudeTarget(t, 1.1 * vehicle.weight_n, tuple(tilt)), t)
            else:
                wobble = (2e-5 * np.sin(5.0 * t), -2e-5 * np.cos(3.0 * t), 1e-5)
                sim.handle_uplink(ThrustMoment(t, 1.05 * vehicle.weight_n, wobble), t)
        sim.step()
        sim.pop_outputs()
        out.append(record(sim))
    return out
