"""Benchmark: the emulated vehicle in-process (physics 1 kHz, firmware 500 Hz, IMU, mocap, truth), no radio.

Takes in: --seconds of simulated flight per run, --vehicles for the fleet run, --seed.
Gives out (printed): real-time factor and microseconds per physics step for one vehicle and for a fleet,
where a step's time goes (uplink, firmware, sensors + telemetry, physics; time.perf_counter accounting
inside SimVehicle.step), the ratio of the float RK4 step to a numpy-on-3-vectors RK4 baseline, and of
an IMU sample drawn from blocks (simulator.sensors) to one Generator call per sample (baseline).

Each vehicle hovers at 1 m on ThrustMoment setpoints from a tiny PD hover law (standing in for the ground
station, 100 Hz, reading the truth); the PD law's own time is reported apart from the vehicle's.
Target (issue "The emulator"): >= 20x real time for one vehicle, i.e. < 50 us per physics step.

Run: python benchmarks/emulator_inprocess_bench.py [--seconds 20] [--vehicles 10]
"""

from __future__ import annotations

import argparse
import time

import numpy as np

from link.messages import ImuSample, ThrustMoment
from model.vehicle import GRAVITY_MPS2, load_mocap_room, load_vehicle
from simulator.dynamics import QuadrotorDynamics
from simulator.firmware import load_firmware_params
from simulator.sensors import DRAW_BLOCK, ImuModel
from simulator.vehicle_sim import SimVehicle

PHYSICS_RATE_HZ = 1000.0
SETPOINT_EVERY_STEPS = 10  # 100 Hz setpoints
TARGET_RTF = 20.0
# the bench's PD hover law (per unit mass / inertia), not a tuned controller
KP_Z, KD_Z = 8.0, 7.0
KR, KW = 480.0, 70.0


def hover_setpoint(sim: SimVehicle, z_ref: float) -> ThrustMoment:
    v = sim.vehicle
    truth = sim.truth
    w, x, y, z = truth.attitude_wxyz
    r33 = max(1.0 - 2.0 * (x * x + y * y), 0.5)
    accel = GRAVITY_MPS2 + KP_Z * (z_ref - truth.position_enu_m[2]) - KD_Z * truth.velocity_enu_mps[2]
    thrust = min(max(v.mass_kg * accel / r33, 0.0), 0.95 * v.max_thrust_n)
    # level: e_R = 2 q_w q_xyz for q_des = identity
    rates = truth.rate_flu_radps
    inertia = np.diag(v.inertia_kgm2)
    limits = 0.95 * v.max_moment_nm
    wanted = inertia * (-KR * 2.0 * w * np.array([x, y, z]) - KW * np.array(rates))
    moment = tuple(np.clip(wanted, -limits, limits).tolist())
    return ThrustMoment(truth.time_s, thrust, moment)


def fly(count: int, seconds: float, seed: int, profile: bool) -> dict:
    vehicle, room = load_vehicle("crazyflie"), load_mocap_room("vicon")
    params = load_firmware_params()
    seeds = np.random.SeedSequence(seed).spawn(count)
    sims = [SimVehicle(vehicle, np.random.default_rng(s), mocap_room=room, vehicle_id=i + 1,
                       physics_rate_hz=PHYSICS_RATE_HZ, initial_position_enu_m=(0.5 * i, 0.0, 1.0),
                       firmware_params=params, airborne=True, profile=profile) for i, s in enumerate(seeds)]
    steps = round(seconds * PHYSICS_RATE_HZ)
    clock = time.perf_counter
    pd_s = pop_s = 0.0
    outputs = 0
    start, cpu_start = clock(), time.process_time()
    for n in range(steps):
        for sim in sims:
            if n % SETPOINT_EVERY_STEPS == 0:
                t0 = clock()
                sp = hover_setpoint(sim, 1.0)
                pd_s += clock() - t0
                sim.handle_uplink(sp, sim.t_s)
            sim.step()
            t0 = clock()
            outputs += len(sim.pop_outputs())
            pop_s += clock() - t0
    wall = clock() - start
    cpu = time.process_time() - cpu_start
    vehicle_wall = wall - pd_s
    vehicle_cpu = cpu - pd_s  # the PD law's wall time stands in for its CPU time (it never sleeps)
    heights = [s.truth.position_enu_m[2] for s in sims]
    parts = {k: sum(s.timing_s[k] for s in sims) for k in sims[0].timing_s}
    parts["pop_outputs"] = pop_s
    return {
        "steps": steps * count, "sim_steps": steps, "wall_s": wall, "vehicle_wall_s": vehicle_wall,
        "pd_s": pd_s,
        "rtf": seconds / vehicle_wall, "us_per_step": vehicle_wall / (steps * count) * 1e6,
        "cpu_rtf": seconds / vehicle_cpu, "cpu_us_per_step": vehicle_cpu / (steps * count) * 1e6,
        "parts": parts, "outputs": outputs, "crashes": sum(s.crash is not None for s in sims),
        "height_error_m": max(abs(h - 1.0) for h in heights),
    }


def numpy_rk4_step_us(repeats: int) -> float:
    """Baseline: the same RK4 written on numpy 3-vectors (what the float version avoids)."""
    v = load_vehicle("crazyflie")
    inertia = np.asarray(v.inertia_kgm2, float)
    inv_inertia = np.linalg.inv(inertia)
    g = np.array([0.0, 0.0, GRAVITY_MPS2])
    thrust, moment, h = v.weight_n, np.array([1e-5, 0.0, 0.0]), 1e-3

    def deriv(state):
        vel, q, w = state[3:6], state[6:10], state[10:13]
        qw, qx, qy, qz = q
        r3 = np.array([2 * (qx * qz + qw * qy), 2 * (qy * qz - qw * qx), 1 - 2 * (qx * qx + qy * qy)])
        acc = thrust / v.mass_kg * r3 - g
        omega = np.array([[0, -w[0], -w[1], -w[2]], [w[0], 0, w[2], -w[1]],
                          [w[1], -w[2], 0, w[0]], [w[2], w[1], -w[0], 0]])
        dq = 0.5 * omega @ q
        dw = inv_inertia @ (moment - np.cross(w, inertia @ w))
        return np.concatenate([vel, acc, dq, dw])

    state = np.array([0, 0, 1.0, 0, 0, 0, 1.0, 0, 0, 0, 0, 0, 0])
    start = time.perf_counter()
    for _ in range(repeats):
        k1 = deriv(state)
        k2 = deriv(state + 0.5 * h * k1)
        k3 = deriv(state + 0.5 * h * k2)
        k4 = deriv(state + h * k3)
        state = state + h / 6.0 * (k1 + 2 * k2 + 2 * k3 + k4)
        state[6:10] /= np.linalg.norm(state[6:10])
    return (time.perf_counter() - start) / repeats * 1e6


def float_rk4_step_us(repeats: int) -> float:
    v = load_vehicle("crazyflie")
    dyn = QuadrotorDynamics(v, load_firmware_params().contact, position_enu_m=(0.0, 0.0, 1.0))
    dyn.command_rotor_speeds([v.hover_rotor_speed_radps] * 4)
    start = time.perf_counter()
    for _ in range(repeats):
        dyn.step()
    return (time.perf_counter() - start) / repeats * 1e6


def per_sample_imu_us(repeats: int) -> float:
    """Baseline: the same IMU model (white noise + bias random walk) with one Generator call per sample."""
    noise = load_vehicle("crazyflie").imu
    rng = np.random.default_rng(0)
    white = [noise.accel_noise_density * noise.rate_hz ** 0.5] * 3 + [noise.gyro_noise_density
                                                                      * noise.rate_hz ** 0.5] * 3
    walk = [noise.accel_bias_random_walk / noise.rate_hz ** 0.5] * 3 + [noise.gyro_bias_random_walk
                                                                        / noise.rate_hz ** 0.5] * 3
    bias = [0.0] * 6
    f, w = (0.0, 0.0, GRAVITY_MPS2), (0.0, 0.0, 0.0)
    start = time.perf_counter()
    for k in range(repeats):
        n = rng.standard_normal(12).tolist()
        e = [bias[i] + white[i] * n[i] for i in range(6)]
        ImuSample(k * 0.002, (f[0] + e[0], f[1] + e[1], f[2] + e[2]), (w[0] + e[3], w[1] + e[4], w[2] + e[5]))
        bias = [bias[i] + walk[i] * n[6 + i] for i in range(6)]
    return (time.perf_counter() - start) / repeats * 1e6


def block_imu_us(repeats: int) -> float:
    imu = ImuModel(load_vehicle("crazyflie").imu, np.random.default_rng(0))
    f, w = (0.0, 0.0, GRAVITY_MPS2), (0.0, 0.0, 0.0)
    start = time.perf_counter()
    for k in range(repeats):
        imu.sample(k * 0.002, f, w)
    return (time.perf_counter() - start) / repeats * 1e6


def report(title: str, r: dict, profiled: dict) -> None:
    print(f"{title}: {r['steps']} vehicle-steps, {r['outputs']} outputs, crashes {r['crashes']}, "
          f"max |z - 1 m| {r['height_error_m']:.4f} m")
    print(f"  real-time factor {r['rtf']:.1f}x wall ({r['us_per_step']:.1f} us per vehicle physics step), "
          f"{r['cpu_rtf']:.1f}x process CPU ({r['cpu_us_per_step']:.1f} us)")
    if r["steps"] == r["sim_steps"]:
        print(f"  ratio to the {TARGET_RTF:.0f}x target: {r['rtf'] / TARGET_RTF:.2f} wall, "
              f"{r['cpu_rtf'] / TARGET_RTF:.2f} CPU")
    pd_us = r["pd_s"] / r["steps"] * 1e6
    print(f"  bench PD hover law (ground-station stand-in, excluded): {pd_us:.1f} us/step")
    total = sum(profiled["parts"].values())
    steps = profiled["steps"]
    print(f"  where a step goes (profiled run, {total / steps * 1e6:.1f} us/step with accounting):")
    for name, seconds in profiled["parts"].items():
        print(f"    {name:<12} {seconds / steps * 1e6:6.2f} us/step  {100 * seconds / total:5.1f} %")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seconds", type=float, default=20.0, help="simulated seconds per run")
    parser.add_argument("--vehicles", type=int, default=10, help="fleet size for the fleet run")
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args()

    baseline = numpy_rk4_step_us(5000)
    candidate = float_rk4_step_us(5000)
    print(f"RK4 step alone: numpy 3-vectors (baseline) {baseline:.1f} us, plain floats (candidate) "
          f"{candidate:.1f} us, speed-up {baseline / candidate:.1f}x")
    baseline, candidate = per_sample_imu_us(20000), block_imu_us(20000)
    print(f"IMU sample alone: a Generator call per sample (baseline) {baseline:.2f} us, blocks of "
          f"{DRAW_BLOCK} (candidate) {candidate:.2f} us, speed-up {baseline / candidate:.1f}x")
    for count in (1, args.vehicles):
        seconds = args.seconds if count == 1 else max(args.seconds / count, 1.0)
        timed = fly(count, seconds, args.seed, profile=False)
        profiled = fly(count, seconds, args.seed, profile=True)
        report(f"{count} vehicle(s), {seconds:g} s simulated", timed, profiled)


if __name__ == "__main__":
    main()
