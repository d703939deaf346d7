"""Speed of the estimator per call: add_imu, add_mocap and estimate(), baseline against candidate, one run.

Takes in: nothing (seeded synthetic 1 m/s circles from tests/estimator/synthetic.py, crazyflie + vicon).
Gives out: a table on stdout: median over interleaved repeats of the mean thread CPU microseconds per add_imu,
per add_mocap, per estimate() and per flight-loop tick, for the baseline, the candidate's Python twin, the
candidate on its Python timeline and the candidate, their ratios, how far the baseline's final estimates
differ from the candidate's (in units of the candidate's own sigma), and whether the twins' final estimates
and the candidate's have the same bits.

Baseline: estimator/eskf.py (and those of BASELINE_MODULES the commit has) as of commit BASELINE_COMMIT
(before the per-sample speed work; --baseline-commit), read with `git show` and loaded as package
`bench_baseline`; candidate: the working tree's estimator.eskf with its propagation as the ground station
runs it (compiled kernels and timeline when estimator/_eskf_kernels.c was built); py twin: the same filter all
in Python (estimator/eskf_timeline.py on estimator/eskf_kernels.py's twins), i.e. what compiling saves;
py tl: the Python timeline on the compiled kernels (the candidate before the timeline was compiled). All
get the same messages in the same order, fed as the ground station's lockstep loop does:
  moments  - 2 ms ticks: the tick's messages, then one estimate() (one IMU sample per tick);
  attitude - 10 ms ticks: the tick's messages (5 IMU samples, 1 mocap frame), then one estimate().
Link cases: frames in order (Vicon 5 ms: each lands 2-3 IMU samples after its sample time, a short
rollback), late and reordered (20 ms + 15 ms jitter: long rollbacks), and from the future (the IMU
downlink 23 ms behind: frames wait, and are fused inside add_imu).
Per-call figures move between columns when work moves (the candidate's covariance is propagated when
something asks for it: estimate() or a mocap frame), so the per-tick column (add_imu + add_mocap +
estimate) is the one to compare. est.build: estimate() once more after re-sending the tick's last IMU
sample (a duplicate: ignored, but new input for the cache), i.e. the cost of building an Estimate alone.
Budget (issue "The ground station"): <= 60 us per IMU propagation, <= 150 us per mocap update.

Run: python benchmarks/estimator_bench.py [--seconds 6] [--repeats 5] [--baseline-commit HASH]
"""

from __future__ import annotations

import argparse
import contextlib
import gc
import inspect
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "tests" / "estimator"))

from git_baseline import baseline_modules  # noqa: E402 (benchmarks/, beside this script)
from synthetic import Flight, LinkFaults, simulate  # noqa: E402

import estimator.eskf as eskf  # noqa: E402
from estimator import eskf_kernels, eskf_timeline  # noqa: E402
from estimator.eskf import ErrorStateKF  # noqa: E402
from estimator.sensor_spec import SensorSpec  # noqa: E402
from link.messages import ImuSample  # noqa: E402
from model.vehicle import load_mocap_room, load_vehicle  # noqa: E402

BASELINE_COMMIT = "cab9f57c13bfa3d422a11a3579d289f2ea03d9ed"
CASES = (
    ("in order (5 ms)", LinkFaults()),
    ("late (20 ms + 15 ms jitter)", LinkFaults(mocap_latency_s=0.020, mocap_jitter_s=0.015)),
    ("future (IMU 23 ms behind)", LinkFaults(imu_latency_s=0.023)),
)
IMU_SAMPLES_PER_TICK = {"moments": 1, "attitude": 5}
WARMUP_S = 1.0  # not timed: the filter's start and first buffer fill
CALLS = ("add_imu", "add_mocap", "estimate")
BUILD = "est.build"  # estimate() right after a repeated (ignored) IMU sample: building the Estimate only
COLUMNS = (*CALLS, "tick", BUILD)


# the baseline's eskf.py and the modules it imports that have since moved (they come from the same commit)
BASELINE_MODULES = {"eskf": "estimator/eskf.py", "eskf_kernels": "estimator/eskf_kernels.py",
                    "rotation": "estimator/rotation.py",
                    "link_rotation": "link/rotation.py", "config": "link/config.py", "errors": "link/errors.py",
                    "vehicle": "link/vehicle.py"}


def load_baseline(commit: str, workdir: Path) -> type | None:
    """ErrorStateKF of estimator/eskf.py at `commit`, or None (with the reason printed) without git. Of
    BASELINE_MODULES, those the commit has; the rest come from the working tree."""
    try:
        held = {name: path for name, path in BASELINE_MODULES.items()
                if subprocess.run(["git", "cat-file", "-e", f"{commit}:{path}"], cwd=ROOT,
                                  capture_output=True).returncode == 0}
        return baseline_modules(commit, held, workdir)["eskf"].ErrorStateKF
    except (OSError, subprocess.CalledProcessError) as err:
        print(f"baseline {commit[:9]} not readable with git ({err}): candidate only")
        return None


def clock_overhead_ns() -> float:
    """What two back-to-back readings of the thread CPU clock cost (subtracted from every call)."""
    clock = time.thread_time_ns
    samples = []
    for _ in range(2000):
        t0 = clock()
        samples.append(clock() - t0)
    return statistics.median(samples)


def fly_ticks(kf, events: list, tick_s: float, overhead_ns: float) -> tuple[dict[str, float], object]:
    """Feed `events` tick by tick (estimate() at each tick's end). Mean thread CPU microseconds per call
    kind and per tick after WARMUP_S, and the final estimate.

    CPU time of this thread, not wall time: on the shared machine a wall clock also counts the time
    other processes hold the core."""
    spent = dict.fromkeys((*CALLS, BUILD), 0.0)
    calls = dict.fromkeys((*CALLS, BUILD), 0)
    ticks = 0
    clock = time.thread_time_ns
    tick_end = tick_s

    def timed(kind: str, fn, *args):
        t0 = clock()
        result = fn(*args)
        if tick_end > WARMUP_S:
            spent[kind] += clock() - t0 - overhead_ns
            calls[kind] += 1
        return result

    last_imu = None
    for arrival_s, msg in events:
        while arrival_s >= tick_end:
            if kf.initialised:
                timed("estimate", kf.estimate)
                if last_imu is not None:  # a duplicate changes nothing but the counters (untimed)
                    kf.add_imu(last_imu)
                    timed(BUILD, kf.estimate)
            ticks += tick_end > WARMUP_S
            tick_end += tick_s
        if isinstance(msg, ImuSample):
            timed("add_imu", kf.add_imu, msg)
            last_imu = msg
        else:
            timed("add_mocap", kf.add_mocap, msg)
    per_call = {k: 1e-3 * spent[k] / max(calls[k], 1) for k in (*CALLS, BUILD)}
    per_call["tick"] = 1e-3 * sum(spent[k] for k in CALLS) / max(ticks, 1)
    return per_call, kf.estimate()


KERNELS = ("propagate", "predict_covariance", "update_covariance", "reset_covariance", "multiply")


@contextlib.contextmanager
def python_twins():
    """The Python timeline (estimator/eskf_timeline.py) on the Python twins of all its kernels
    (estimator/eskf_kernels.py), for the calls inside the block."""
    saved = {name: getattr(eskf_timeline, name) for name in KERNELS}
    for name in KERNELS:
        setattr(eskf_timeline, name, getattr(eskf_kernels, f"{name}_python"))
    try:
        yield
    finally:
        for name, kernel in saved.items():
            setattr(eskf_timeline, name, kernel)


def difference_in_sigma(a, b) -> float:
    """Largest |a - b| of position and velocity over b's own standard deviations."""
    diffs = np.concatenate([a.position_enu_m - b.position_enu_m, a.velocity_enu_mps - b.velocity_enu_mps])
    return float(np.max(np.abs(diffs) / b.std_dev[0:6]))


def _estimate_bytes(e) -> bytes:
    return b"".join(np.asarray(v).tobytes() for v in (e.time_s, e.position_enu_m, e.velocity_enu_mps,
                                                      e.attitude_wxyz, e.covariance))


def build_filter(cls, vehicle, room, timeline: type | None = None):
    """The filter told the simulated noise exactly, through whichever constructor its commit has (the
    sensor spec replaced the (vehicle, room) pair); on `timeline` if given (the working tree's alone)."""
    if timeline is not None:
        return cls(SensorSpec.matching_simulation(vehicle, room), vehicle.imu.rate_hz, timeline=timeline)
    if next(iter(inspect.signature(cls).parameters)) == "sensors":
        return cls(SensorSpec.matching_simulation(vehicle, room), vehicle.imu.rate_hz)
    return cls(vehicle, room)


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seconds", type=float, default=6.0, help="flight length per case (s)")
    parser.add_argument("--repeats", type=int, default=5, help="interleaved runs per filter; medians shown")
    parser.add_argument("--baseline-commit", default=BASELINE_COMMIT)
    args = parser.parse_args(argv)
    vehicle, room = load_vehicle("crazyflie"), load_mocap_room("vicon")
    scratch = tempfile.TemporaryDirectory()  # the baseline's sources, for as long as the run lasts
    baseline = load_baseline(args.baseline_commit, Path(scratch.name))
    # (class, on the Python twins, timeline): the module docstring says what each row is
    filters = {"candidate": (ErrorStateKF, False, None), "py twin": (ErrorStateKF, True, eskf_timeline.Timeline),
               "py tl": (ErrorStateKF, False, eskf_timeline.Timeline)}
    if baseline:
        filters["baseline"] = (baseline, False, None)
    overhead_ns = clock_overhead_ns()
    print(f"estimator bench: {args.seconds:.0f} s synthetic 1 m/s circle per case, IMU {vehicle.imu.rate_hz:.0f} Hz, "
          f"mocap {room.rate_hz:.0f} Hz; median of {args.repeats} interleaved runs, thread CPU us per call "
          f"(clock overhead {1e-3 * overhead_ns:.2f} us subtracted; baseline = {args.baseline_commit[:9]}; "
          f"candidate kernels and timeline: {'compiled' if eskf.CompiledTimeline else 'Python twins (not built)'})")
    header = f"{'mode / case':40s} {'filter':10s}" + "".join(f"{k:>11s}" for k in COLUMNS)
    print(header)
    flights = {label: simulate(Flight(duration_s=args.seconds), vehicle.imu, room, np.random.default_rng(7), faults)
            for label, faults in CASES}  # the same flights serve every mode
    for mode, imu_per_tick in IMU_SAMPLES_PER_TICK.items():
        tick_s = imu_per_tick / vehicle.imu.rate_hz
        for label, run in flights.items():
            results: dict[str, list[dict[str, float]]] = {name: [] for name in filters}
            finals = {}
            for _ in range(args.repeats):
                for name, (cls, twins, timeline) in filters.items():
                    gc.collect()
                    with python_twins() if twins else contextlib.nullcontext():
                        per_call, finals[name] = fly_ticks(build_filter(cls, vehicle, room, timeline), run.events,
                                                           tick_s, overhead_ns)
                    results[name].append(per_call)
            medians = {name: {k: statistics.median(r[k] for r in runs) for k in COLUMNS}
                       for name, runs in results.items()}
            for name in ("baseline", "py twin", "py tl", "candidate"):
                if name in medians:
                    print(f"{mode + ', ' + label:40s} {name:10s}"
                          + "".join(f"{medians[name][k]:11.1f}" for k in COLUMNS))
            if "baseline" in medians:
                ratio = "".join(f"{medians['baseline'][k] / medians['candidate'][k]:10.2f}x"
                                for k in COLUMNS)
                per_sim_s = {name: 1e-3 * m["tick"] / tick_s for name, m in medians.items()}  # ms per sim s
                print(f"{'':40s} {'speed-up':10s}{ratio}   CPU per simulated s {per_sim_s['baseline']:.1f} -> "
                      f"{per_sim_s['candidate']:.1f} ms; final estimates differ by "
                      f"{difference_in_sigma(finals['candidate'], finals['baseline']):.1e} sigma")
            for twin in ("py twin", "py tl"):
                ratios = "".join(f"{medians[twin][k] / medians['candidate'][k]:10.2f}x" for k in COLUMNS)
                same = "the same bits" if _estimate_bytes(finals[twin]) == _estimate_bytes(finals["candidate"]) \
                    else "DIFFERENT bits"
                print(f"{'':40s} {twin + '/cand':10s}{ratios}   final estimates of {twin} and the candidate: {same}")


if __name__ == "__main__":
    main()
