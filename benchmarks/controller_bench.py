"""Benchmark of one SE3Controller.update against a straightforward numpy version of the same law.

Takes in: nothing (the crazyflie vehicle, the shipped gains and a fixed set of seeded random states).
Gives out: microseconds per update for the numpy baseline and the float candidate ("report" and "full"
variants), their ratio, and a check that baseline and candidate agree. Budget: <= 40 us per update
(500 Hz loop). Run: python benchmarks/controller_bench.py
"""

from __future__ import annotations

import timeit

import numpy as np
from scipy.spatial.transform import Rotation

from groundstation.controller import ControllerState, SE3Controller, load_gains
from groundstation.trajectory import FlatOutput
from link.vehicle import GRAVITY_MPS2, load_vehicle

BUDGET_US = 40.0


class NumpyReportController:
    """The report's law written the obvious way with numpy arrays: the baseline. Constants precomputed."""

    def __init__(self, vehicle, gains):
        self.m = vehicle.mass_kg + gains.mass_offset_kg
        self.kp, self.kd = np.diag(gains.kp), np.diag(gains.kd)
        self.k_r, self.k_w = np.diag(gains.k_r), np.diag(gains.k_w)
        self.inertia = vehicle.inertia_kgm2
        self.max_thrust, self.max_moment = vehicle.max_thrust_n, vehicle.max_moment_nm
        self.weight = np.array([0.0, 0.0, self.m * GRAVITY_MPS2])

    def update(self, state: ControllerState, ref: FlatOutput):
        r, v = np.asarray(state.position_enu_m), np.asarray(state.velocity_enu_mps)
        q = np.asarray(state.attitude_wxyz)
        w, x, y, z = q / np.linalg.norm(q)
        rot = np.array([
            [1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
            [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
            [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)],
        ])
        acc_des = ref.acceleration_mps2 - self.kd @ (v - ref.velocity_mps) - self.kp @ (r - ref.position_m)
        f_des = self.m * acc_des + self.weight
        u1 = rot[:, 2] @ f_des
        b3 = f_des / np.linalg.norm(f_des)
        a_psi = np.array([np.cos(ref.yaw_rad), np.sin(ref.yaw_rad), 0.0])
        b2 = np.cross(b3, a_psi)
        b2 /= np.linalg.norm(b2)
        r_des = np.column_stack([np.cross(b2, b3), b2, b3])
        skew = r_des.T @ rot - rot.T @ r_des
        e_r = 0.5 * np.array([skew[2, 1], skew[0, 2], skew[1, 0]])
        u2 = self.inertia @ (-self.k_r @ e_r - self.k_w @ np.asarray(state.rate_flu_radps))
        return np.clip(u1, 0.0, self.max_thrust), np.clip(u2, -self.max_moment, self.max_moment)


def random_cases(rng: np.random.Generator, n: int):
    cases = []
    for _ in range(n):
        q_xyzw = Rotation.from_rotvec(rng.normal(0.0, 0.2, 3)).as_quat()
        state = ControllerState(rng.normal(0, 1, 3), rng.normal(0, 0.5, 3), np.roll(q_xyzw, 1),
                                rng.normal(0, 0.5, 3))
        ref = FlatOutput(*(rng.normal(0, s, 3) for s in (1.0, 0.5, 1.0, 2.0, 4.0)),
                         yaw_rad=float(rng.uniform(-np.pi, np.pi)), yaw_rate_radps=float(rng.normal(0, 0.3)))
        cases.append((state, ref))
    return cases


def per_call_us(fn, cases, repeat: int = 5) -> float:
    def run():
        for state, ref in cases:
            fn(state, ref)

    return min(timeit.repeat(run, number=20, repeat=repeat)) / (20 * len(cases)) * 1e6


def main() -> None:
    vehicle, gains = load_vehicle("crazyflie"), load_gains()
    cases = random_cases(np.random.default_rng(0), 200)
    report = SE3Controller(vehicle, gains, "report")
    full = SE3Controller(vehicle, gains, "full")

    baseline_controller = NumpyReportController(vehicle, gains)
    worst = 0.0
    for state, ref in cases:
        u1, u2 = baseline_controller.update(state, ref)
        out = report.update(state, ref)
        worst = max(worst, abs(out.thrust_n - u1), float(np.max(np.abs(np.array(out.moment_flu_nm) - u2))))
    print(f"agreement baseline vs candidate (report variant): max |difference| = {worst:.2e}")

    baseline = per_call_us(baseline_controller.update, cases)
    candidate = per_call_us(report.update, cases)
    candidate_full = per_call_us(full.update, cases)
    print(f"numpy baseline (report law):   {baseline:7.2f} us/update")
    print(f"SE3Controller report variant:  {candidate:7.2f} us/update  (baseline/candidate = "
          f"{baseline / candidate:.1f}x)")
    print(f"SE3Controller full variant:    {candidate_full:7.2f} us/update  (baseline/candidate = "
          f"{baseline / candidate_full:.1f}x)")
    verdict = "met" if max(candidate, candidate_full) <= BUDGET_US else "MISSED"
    print(f"budget {BUDGET_US:.0f} us/update: {verdict}")


if __name__ == "__main__":
    main()
