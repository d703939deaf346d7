"""Benchmark: what the faithful firmware (--firmware crazyflie) costs against the ideal one, in the same run.

Takes in: --seconds of simulated hover per in-process run, --repeats (interleaved), --skip-flights,
--baseline REV (a git revision whose vehicle is timed in the same runs).
Gives out (printed):
1. in-process, no radio: microseconds per physics step (1 kHz) of one cf21 vehicle hovering, ideal and
   faithful firmware interleaved, in moments mode (ThrustMoment setpoints at 500 Hz) and attitude mode
   (AttitudeTarget at 100 Hz plus the mocap pose as ExternalPose at 100 Hz), with the faithful/ideal ratio
   (median of the repeats); with --baseline, each run is a child process, the baseline's (its tree
   extracted, its kernels built) interleaved with this tree's, and the table adds the baseline's us/step
   and new/baseline per firmware;
2. lockstep flights through the link (`cfstack fly`, esb-duplex profile, MAVLink's default: the built-in circle, and the
   test_lab_1 maze from ../shared/worlds when present): real-time factor of the flight loop per mode and
   firmware, and the ratio. Issue 15's floor: moments mode at 500 Hz at least 5x real time with the faithful firmware.

The setpoints come from the truth, the thrust holding the height on it (emulator_bench.HeightHold), a
stand-in for the ground station: this measures the vehicle, airborne throughout, not a controller.
Run: python benchmarks/firmware_bench.py [--seconds 10] [--repeats 3] [--skip-flights] [--baseline REV]
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
from bench_paths import NEUTRAL_CWD, SHARED_WORLDS
from emulator_bench import LEVEL_WXYZ, HeightHold
from git_baseline import REPO, baseline_tree

from link.messages import AttitudeTarget, ExternalPose, MocapPose, ThrustMoment
from model.firmwares import FIRMWARE_VEHICLES
from model.vehicle import load_mocap_room, load_vehicle
from simulator.vehicle_sim import SimVehicle

VEHICLE = "cf21"
FIRMWARES = tuple(FIRMWARE_VEHICLES)
MAZE = SHARED_WORLDS / "test_lab_1.json"
TARGET_MOMENTS_RTF = 5.0


def hover_in_process(firmware: str, mode: str, seconds: float, seed: int) -> float:
    """Microseconds per physics step of `seconds` of hover (setpoints and poses from the truth)."""
    vehicle = load_vehicle(VEHICLE)
    sim = SimVehicle(vehicle, np.random.default_rng(seed), mocap_room=load_mocap_room("vicon"),
                     initial_position_enu_m=(0.0, 0.0, 1.0), airborne=True, firmware=firmware)
    steps_per_setpoint = 2 if mode == "moments" else 10
    hold = HeightHold(vehicle)  # a fixed thrust would let the faithful vehicle sink to the floor mid-run
    total_steps = round(seconds * 1000.0)
    start = time.perf_counter()
    for k in range(total_steps):
        if k % steps_per_setpoint == 0:
            t = sim.t_s
            truth = sim.truth
            hold.see(MocapPose(t, 1, truth.position_enu_m, truth.attitude_wxyz))
            if mode == "moments":
                sim.handle_uplink(ThrustMoment(t, hold.thrust_n, (0.0, 0.0, 0.0)), t)
            else:
                sim.handle_uplink(ExternalPose(t, truth.position_enu_m, truth.attitude_wxyz), t)
                sim.handle_uplink(AttitudeTarget(t, hold.thrust_n, LEVEL_WXYZ), t)
        sim.step()
        sim.pop_outputs()
    return (time.perf_counter() - start) / total_steps * 1e6


# One hover_in_process run in a child process from a tree (its own firmware_bench, its own kernels)
HOVER_SCRIPT = """
import sys
sys.path.insert(0, {benchmarks!r})
import firmware_bench
print(firmware_bench.hover_in_process({firmware!r}, {mode!r}, {seconds!r}, {seed!r}))
"""


def hover_in_tree(tree: Path, firmware: str, mode: str, seconds: float, seed: int) -> float:
    """hover_in_process as the code of `tree` runs it, in a fresh process (us per physics step)."""
    script = HOVER_SCRIPT.format(benchmarks=str(tree / "benchmarks"), firmware=firmware, mode=mode, seconds=seconds,
                                 seed=seed)
    run = subprocess.run([sys.executable, "-c", script], cwd=NEUTRAL_CWD, env={**os.environ, "PYTHONPATH": str(tree)},
                         capture_output=True, text=True, timeout=600, stdin=subprocess.DEVNULL)
    if run.returncode != 0:
        raise SystemExit(f"firmware_bench: the hover in {tree} failed: {run.stderr.strip()[-300:]}")
    return float(run.stdout.strip().splitlines()[-1])


def baseline_table(seconds: float, repeats: int, rev: str) -> None:
    """Section 1 against a git baseline: every run a child process, the baseline's and this tree's interleaved."""
    print(f"1. In-process hover, one {VEHICLE} vehicle, {seconds:g} s simulated per run, {repeats} interleaved "
          f"repeats (median), git {rev} against this tree, each run a child process")
    print(f"{'mode':<10} {'firmware':<10} {'git ' + rev + ' us/step':>18} {'new us/step':>12} {'new/base':>9}")
    with tempfile.TemporaryDirectory() as tmp:
        base = baseline_tree(rev, Path(tmp))
        for mode in ("moments", "attitude"):
            times = {(name, f): [] for name in ("base", "new") for f in FIRMWARES}
            for r in range(repeats):
                for firmware in FIRMWARES:
                    for name, tree in (("base", base), ("new", REPO)):
                        times[name, firmware].append(hover_in_tree(tree, firmware, mode, seconds, seed=r))
                print(f"   [{mode}] repeat {r + 1}/{repeats}", file=sys.stderr, flush=True)  # progress
            for firmware in FIRMWARES:
                b, n = (statistics.median(times[name, firmware]) for name in ("base", "new"))
                print(f"{mode:<10} {firmware:<10} {b:>18.1f} {n:>12.1f} {n / b:>9.2f}")


def in_process_table(seconds: float, repeats: int) -> None:
    print(f"1. In-process hover, one {VEHICLE} vehicle, {seconds:g} s simulated per run, {repeats} interleaved "
          "repeats (median)")
    print(f"{'mode':<10} {'ideal us/step':>14} {'faithful us/step':>17} {'faithful/ideal':>15}")
    for mode in ("moments", "attitude"):
        times = {f: [] for f in FIRMWARES}
        for r in range(repeats):
            for firmware in FIRMWARES:
                times[firmware].append(hover_in_process(firmware, mode, seconds, seed=r))
        ideal, faithful = statistics.median(times["ideal"]), statistics.median(times["crazyflie"])
        print(f"{mode:<10} {ideal:>14.1f} {faithful:>17.1f} {faithful / ideal:>15.2f}")


def flight(folder: Path, what: str, mode: str, firmware: str) -> dict:
    world = [str(MAZE)] if what == "maze" else ["--trajectory", "circle"]
    log = folder / f"{what}_{mode}_{firmware}"
    run = subprocess.run([sys.executable, "-m", "cfstack", "fly", *world, "--mode", mode, "--firmware", firmware,
                          "--vehicle-model", VEHICLE, "--clock", "lockstep", "--seed", "1", "--json", "--log",
                          str(log)], capture_output=True, text=True, timeout=900, stdin=subprocess.DEVNULL)
    if not run.stdout.strip():
        raise SystemExit(f"firmware_bench: the {mode}/{firmware} flight printed no summary: "
                         f"{run.stderr.strip().splitlines()[-1:]}")
    return json.loads(run.stdout)


def flights_table() -> None:
    flights = ["circle"] + (["maze"] if MAZE.is_file() else [])
    absent = "" if MAZE.is_file() else f" ({MAZE} absent: no maze flights)"
    print(f"\n2. Lockstep flights through the link (esb-duplex, {VEHICLE}): flight-loop real-time factor "
          f"(simulated s per wall s of the loop){absent}")
    print(f"{'flight':<8} {'mode':<10} {'ideal x':>9} {'faithful x':>11} {'faithful/ideal':>15} "
          f"{'faithful result':>16}")
    with tempfile.TemporaryDirectory() as tmp:
        for what in flights:
            for mode in ("moments", "attitude"):
                rtf, results = {}, {}
                for firmware in FIRMWARES:
                    s = flight(Path(tmp), what, mode, firmware)
                    rtf[firmware] = s["timing"]["real_time_factor"]
                    results[firmware] = s["result"]
                    print(f"  [{what} {mode} {firmware}] {results[firmware]}, {rtf[firmware]:.1f}x", file=sys.stderr,
                          flush=True)
                ratio = rtf["crazyflie"] / rtf["ideal"]
                print(f"{what:<8} {mode:<10} {rtf['ideal']:>9.1f} {rtf['crazyflie']:>11.1f} {ratio:>15.2f} "
                      f"{results['crazyflie']:>16}")
                if mode == "moments":
                    verdict = "meets" if rtf["crazyflie"] >= TARGET_MOMENTS_RTF else "MISSES"
                    print(f"{'':<19} faithful moments mode {verdict} the {TARGET_MOMENTS_RTF:g}x floor")


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--seconds", type=float, default=10.0)
    p.add_argument("--repeats", type=int, default=3)
    p.add_argument("--skip-flights", action="store_true")
    p.add_argument("--baseline", metavar="REV", help="git revision whose vehicle section 1 times in the same runs")
    args = p.parse_args()
    if args.baseline:
        baseline_table(args.seconds, args.repeats, args.baseline)
    else:
        in_process_table(args.seconds, args.repeats)
    if not args.skip_flights:
        flights_table()
    return 0


if __name__ == "__main__":
    sys.exit(main())
