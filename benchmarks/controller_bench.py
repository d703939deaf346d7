"""Benchmark of the ground station's per-tick control path: baseline (a git revision) against the working tree.

Takes in: nothing (the crazyflie vehicle, the shipped gains, mission and trajectory parameters, and
seeded random states); optionally --baseline REV (default HEAD), the git revision whose versions of
the modules under test are the baseline (read with `git show REV:path`, loaded under another name).
Gives out, from one run: microseconds per call of the baseline and of the candidate (the working tree),
their ratio, and the largest relative difference of their results (must be floating-point rounding,
~1e-12), for
  - SE3Controller.update ("report" and "full" variants),
  - LatencyCompensator.predict (moments and attitude mode) and record,
  - Mission.update in the TRACK phase and Mission.reference_at,
  - sample() of Circle, Line, Hover, ConstantSpeedTrajectory and MinSnapTrajectory,
  - the whole control path of one tick (mission, prediction, look-ahead reference, controller, record);
and the controller against a straightforward numpy version of the report's law (budget: <= 40 us per
update at 500 Hz). Run: python benchmarks/controller_bench.py [--baseline REV] [--quick]
"""

from __future__ import annotations

import argparse
import importlib
import tempfile
import timeit
from dataclasses import dataclass, fields
from pathlib import Path

import numpy as np
from git_baseline import baseline_modules  # benchmarks/, beside this script
from scipy.spatial.transform import Rotation

from groundstation.controller import ControllerState, SE3Controller, load_gains
from groundstation.trajectory import FlatOutput
from model.vehicle import GRAVITY_MPS2, load_vehicle

BUDGET_US = 40.0
# The modules under test: loaded from the working tree (candidate) and from the baseline revision.
MODULES = {
    "controller": "groundstation/controller.py",
    "compensation": "groundstation/compensation.py",
    "mission": "groundstation/mission.py",
    "basic": "groundstation/trajectories/basic.py",
    "constant_speed": "groundstation/trajectories/constant_speed.py",
    "minsnap": "groundstation/trajectories/minsnap.py",
}
CONTROL_PERIOD_S = 0.002  # 500 Hz, moments mode
UPLINK_LATENCY_S = 0.003  # one way; with the estimate one downlink latency old, 3 prediction steps


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


# --- loading the two versions ---------------------------------------------------------------------------

def candidate_modules() -> dict:
    return {name: importlib.import_module(path[:-3].replace("/", ".")) for name, path in MODULES.items()}


# --- comparing results ----------------------------------------------------------------------------------

def flatten(value) -> list[float]:
    """Every number in a result (dataclass, tuple, array, float, bool) as one flat list, in order."""
    if value is None:
        return []
    if hasattr(value, "__dataclass_fields__"):
        return [x for f in fields(value) for x in flatten(getattr(value, f.name))]
    if isinstance(value, np.ndarray | tuple | list):
        return [x for v in value for x in flatten(v)]
    if hasattr(value, "value") and not isinstance(value, bool | float | int):  # an Enum
        return [float(hash(value.value) % 1000)]
    return [float(value)]


def relative_difference(baseline_results: list, candidate_results: list) -> float:
    """max |candidate - baseline| / max |baseline| over all results (inf if their shapes differ)."""
    a = np.array([flatten(r) for r in baseline_results], dtype=float)
    b = np.array([flatten(r) for r in candidate_results], dtype=float)
    if a.shape != b.shape:
        return float("inf")
    scale = np.maximum(np.abs(a).max(axis=0), 1e-300)
    return float((np.abs(a - b) / scale).max()) if a.size else 0.0


def per_call_us(fn, args: list[tuple], repeat: int, number: int) -> float:
    def run():
        for a in args:
            fn(*a)

    return min(timeit.repeat(run, number=number, repeat=repeat)) / (number * len(args)) * 1e6


# --- the cases ------------------------------------------------------------------------------------------

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


@dataclass
class FakeEstimate:
    """The fields of an estimator.Estimate the compensator reads (numpy arrays, as the filter gives)."""

    time_s: float
    position_enu_m: np.ndarray
    velocity_enu_mps: np.ndarray
    attitude_wxyz: np.ndarray
    rate_flu_radps: np.ndarray


def sent_history(rng: np.random.Generator, n: int) -> list[tuple]:
    """(sent_s, thrust, moment, attitude) of n commands at the control rate (one second at 500 Hz)."""
    history = []
    for k in range(n):
        q = np.roll(Rotation.from_rotvec(rng.normal(0.0, 0.1, 3)).as_quat(), 1)
        history.append((k * CONTROL_PERIOD_S, float(rng.uniform(0.2, 0.5)), tuple(rng.normal(0, 1e-3, 3)),
                        tuple(q.tolist())))
    return history


def prediction_cases(rng: np.random.Generator, n: int, end_s: float) -> list[tuple]:
    """(est, now, vehicle_minus_ground, uplink latency): the estimate one downlink latency old."""
    cases = []
    for _ in range(n):
        now = end_s - float(rng.uniform(0.0, 0.5)) * CONTROL_PERIOD_S
        q = np.roll(Rotation.from_rotvec(rng.normal(0.0, 0.2, 3)).as_quat(), 1)
        est = FakeEstimate(now - UPLINK_LATENCY_S + 0.05, rng.normal(0, 1, 3), rng.normal(0, 0.5, 3), q,
                           rng.normal(0, 0.5, 3))
        cases.append((est, now, 0.05, UPLINK_LATENCY_S))
    return cases


def compensator(mod, vehicle, mode: str, history: list[tuple]):
    c = mod.LatencyCompensator(vehicle, mode, CONTROL_PERIOD_S)
    for command in history:
        c.record(*command)
    return c


def mission_in_track(mods):
    """A Mission of module set `mods` flying the built-in circle, driven by views through arm and settle
    into its TRACK phase."""
    params = mods["mission"].load_mission_params()
    track = circle_track(mods)
    start = track.sample(0.0).position_m
    m = mods["mission"].Mission(params, track, lambda p: 0.0, track.sample(track.duration_s).position_m)
    t = 0.0
    m.update(t, view_at(mods, t, start, armed=False))
    while m.phase != mods["mission"].Phase.TRACK:
        t += CONTROL_PERIOD_S
        m.update(t, view_at(mods, t, start, armed=True))
    return m


def view_at(mods, t: float, position, armed: bool = True):
    return mods["mission"].VehicleView(t_s=t, position_enu_m=np.asarray(position, float) + [0.2, 0.0, 0.0],
                                       velocity_enu_mps=np.zeros(3), armed=armed, crashed=False,
                                       mocap_age_s=0.004, estimator_healthy=True, downlink_age_s=0.002)


def circle_track(mods):
    return mods["basic"].make_builtin("circle", [0.0, 0.0, 1.0])


def maze_path(rng: np.random.Generator, n: int) -> np.ndarray:
    """A dense grid-like path (0.1 m steps along one axis at a time), as A* gives."""
    steps = np.eye(3)[rng.integers(0, 3, n)] * rng.choice([-0.1, 0.1], (n, 1))
    return np.cumsum(np.vstack([[0.0, 0.0, 1.0], steps]), axis=0)


@dataclass
class Row:
    name: str
    baseline_us: float
    candidate_us: float
    rel_diff: float


def compare(name: str, base_fn, cand_fn, args: list[tuple], repeat: int, number: int,
            cand_args: list[tuple] | None = None) -> Row:
    cand_args = args if cand_args is None else cand_args
    diff = relative_difference([base_fn(*a) for a in args], [cand_fn(*a) for a in cand_args])
    base_us = cand_us = float("inf")
    for _ in range(repeat):  # interleaved, so load changes on a shared machine hit both alike
        base_us = min(base_us, per_call_us(base_fn, args, 1, number))
        cand_us = min(cand_us, per_call_us(cand_fn, cand_args, 1, number))
    return Row(name, base_us, cand_us, diff)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--baseline", default="HEAD", help="git revision of the baseline (default HEAD)")
    parser.add_argument("--quick", action="store_true", help="fewer repeats")
    args = parser.parse_args()
    repeat, number = (3, 3) if args.quick else (15, 4)

    vehicle, gains = load_vehicle("crazyflie"), load_gains()
    cand = candidate_modules()
    with tempfile.TemporaryDirectory() as tmp:
        base = baseline_modules(args.baseline, MODULES, Path(tmp))
        rows = run_comparisons(base, cand, vehicle, gains, repeat, number)

    print(f"baseline: git {args.baseline}; candidate: working tree; us per call (min of {repeat} runs)")
    print(f"{'function':44s} {'baseline':>9s} {'candidate':>9s} {'ratio':>6s} {'max rel diff':>13s}")
    for r in rows:
        print(f"{r.name:44s} {r.baseline_us:9.2f} {r.candidate_us:9.2f} {r.baseline_us / r.candidate_us:5.1f}x "
              f"{r.rel_diff:13.1e}")
    numpy_against_float(vehicle, gains, repeat)


def run_comparisons(base: dict, cand: dict, vehicle, gains, repeat: int, number: int) -> list[Row]:
    rng = np.random.default_rng(0)
    rows = []
    cases = random_cases(rng, 200)
    for variant in ("report", "full"):
        b = base["controller"].SE3Controller(vehicle, gains, variant)
        c = cand["controller"].SE3Controller(vehicle, gains, variant)
        rows.append(compare(f"SE3Controller.update ({variant})", b.update, c.update, cases, repeat, number))

    history = sent_history(rng, 500)
    end_s = history[-1][0]
    predictions = prediction_cases(rng, 100, end_s)
    for mode in ("moments", "attitude"):
        b, c = (compensator(m, vehicle, mode, history) for m in (base["compensation"], cand["compensation"]))
        rows.append(compare(f"LatencyCompensator.predict ({mode})", b.predict, c.predict, predictions, repeat,
                            number))
    b, c = (compensator(m, vehicle, "moments", history[:1]) for m in (base["compensation"], cand["compensation"]))
    rows.append(compare("LatencyCompensator.record", b.record, c.record, history, repeat, number))

    b, c = (mission_in_track(m) for m in (base, cand))
    start = b.phase_start_s
    times = [start + x for x in np.linspace(0.0, b.track.duration_s - 0.01, 200).tolist()]
    rows.append(compare("Mission.update (TRACK, circle)", b.update, c.update,
                        [(t, view_at(base, t, [0.0, 0.0, 1.0])) for t in times], repeat, number,
                        [(t, view_at(cand, t, [0.0, 0.0, 1.0])) for t in times]))
    rows.append(compare("Mission.reference_at (circle)", b.reference_at, c.reference_at,
                        [(t + UPLINK_LATENCY_S,) for t in times], repeat, number))

    rows += trajectory_rows(base, cand, rng, repeat, number)
    rows.append(tick_row(base, cand, vehicle, gains, history, predictions, times, repeat, number))
    return rows


def trajectory_rows(base: dict, cand: dict, rng: np.random.Generator, repeat: int, number: int) -> list[Row]:
    path = maze_path(rng, 120)
    waypoints = path[::12]
    seg_times = rng.uniform(0.5, 1.5, len(waypoints) - 1)
    builders = {
        "Circle.sample (built-in circle)": lambda m: m["basic"].make_builtin("circle", [0.0, 0.0, 1.0]),
        "Line.sample (built-in line)": lambda m: m["basic"].make_builtin("line", [0.0, 0.0, 1.0]),
        "Hover.sample": lambda m: m["basic"].Hover([0.0, 0.0, 1.0], 5.0),
        "ConstantSpeedTrajectory.sample (maze)": lambda m: m["constant_speed"].ConstantSpeedTrajectory.from_path(
            path, m["constant_speed"].ConstantSpeedSettings(1.0, 3, 1.5)),
        "MinSnapTrajectory.sample (maze)": lambda m: m["minsnap"].min_snap(waypoints, seg_times),
    }
    rows = []
    for name, build in builders.items():
        b, c = build(base), build(cand)
        times = [(t,) for t in np.linspace(-0.2, b.duration_s + 0.2, 400).tolist()]
        rows.append(compare(name, b.sample, c.sample, times, repeat, number))
    return rows


def tick_row(base, cand, vehicle, gains, history, predictions, times, repeat, number) -> Row:
    """One tick's control path as groundstation/flight.py runs it with latency compensation on.

    The clock keeps advancing across repeated runs (the command history must stay one second long, as in
    a flight); the mission's track time wraps around within its TRACK phase.
    """
    def path_of(mods):
        mission = mission_in_track(mods)
        comp = compensator(mods["compensation"], vehicle, "moments", history)
        controller = mods["controller"].SE3Controller(vehicle, gains, "full")
        view = view_at(mods, 0.0, [0.0, 0.0, 1.0])
        clock = {"tick": 0}
        end_s = history[-1][0]

        def tick():
            k = clock["tick"] = clock["tick"] + 1
            t = times[k % len(times)]
            step = mission.update(t, view)
            est, _, offset, latency = predictions[k % len(predictions)]
            now = end_s + k * CONTROL_PERIOD_S
            est.time_s = now - latency + offset
            state = comp.predict(est, now, offset, latency)
            reference = mission.reference_at(t + latency) or step.reference
            out = controller.update(state, reference)
            comp.record(now, out.thrust_n, out.moment_flu_nm, out.attitude_des_wxyz)
            return out

        return tick

    ticks = [()] * 200
    return compare("one tick's control path (full, moments)", path_of(base), path_of(cand), ticks, repeat,
                   number)


def numpy_against_float(vehicle, gains, repeat: int) -> None:
    """The controller against the obvious numpy version of the report's law."""
    cases = random_cases(np.random.default_rng(0), 200)
    report = SE3Controller(vehicle, gains, "report")
    full = SE3Controller(vehicle, gains, "full")
    numpy_controller = NumpyReportController(vehicle, gains)
    worst = 0.0
    for state, ref in cases:
        u1, u2 = numpy_controller.update(state, ref)
        out = report.update(state, ref)
        worst = max(worst, abs(out.thrust_n - u1), float(np.max(np.abs(np.array(out.moment_flu_nm) - u2))))
    print(f"\nnumpy version of the report's law vs SE3Controller (report): max |difference| = {worst:.2e}")
    numpy_us = per_call_us(numpy_controller.update, cases, repeat, 20)
    report_us = per_call_us(report.update, cases, repeat, 20)
    full_us = per_call_us(full.update, cases, repeat, 20)
    print(f"numpy version (report law):    {numpy_us:7.2f} us/update")
    print(f"SE3Controller report variant:  {report_us:7.2f} us/update  ({numpy_us / report_us:.1f}x faster)")
    print(f"SE3Controller full variant:    {full_us:7.2f} us/update  ({numpy_us / full_us:.1f}x faster)")
    verdict = "met" if max(report_us, full_us) <= BUDGET_US else "MISSED"
    print(f"budget {BUDGET_US:.0f} us/update: {verdict}")


if __name__ == "__main__":
    main()
