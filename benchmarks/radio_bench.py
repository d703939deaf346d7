"""What the one-dongle radio model costs: CRTP moments traffic through `crazyradio` (the half-duplex EsbAir) against
`esb-duplex` (each direction on its own air), in the same run, alternating.

The traffic is cflib's in moments mode: 500 Hz commands (20 bytes) and 100 Hz extpose (30 bytes) up, the 100 Hz
IMU log block (29 bytes) down, pushed and popped every 1 ms of simulated time, as the emulator's vehicle node does.
Prints the wall time per simulated second for each model and their ratio.

Usage: python benchmarks/radio_bench.py [--seconds 120] [--repeats 3]
"""

from __future__ import annotations

import argparse
import statistics
import sys
import time

import numpy as np

from model.radio import load_radio_profile
from simulator.radio import DOWNLINK, UPLINK, EsbAir, RadioChannel

STEP_S = 0.001
COMMAND_EVERY, EXTPOSE_EVERY = 2, 10  # steps between pushes: 500 Hz and 100 Hz


def wall_per_simulated_s(profile_name: str, seconds: float) -> float:
    profile = load_radio_profile(profile_name)
    air = EsbAir(profile.crazyradio, np.random.default_rng(5)) if profile.model == "crazyradio" else None
    up = RadioChannel(profile, np.random.default_rng(2), keep_ledger=False, air=air, direction=UPLINK)
    down = RadioChannel(profile, np.random.default_rng(3), keep_ledger=False, air=air, direction=DOWNLINK)
    command, extpose, imu = bytes(20), bytes(30), bytes(29)
    start = time.perf_counter()
    for step in range(round(seconds / STEP_S)):
        t = step * STEP_S
        if step % COMMAND_EVERY == 0:
            up.push(command, t)
        if step % EXTPOSE_EVERY == 0:
            up.push(extpose, t)
            down.push(imu, t)
        up.pop_due(t)
        down.pop_due(t)
    return (time.perf_counter() - start) / seconds


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--seconds", type=float, default=120.0, help="simulated seconds per run")
    p.add_argument("--repeats", type=int, default=3, help="alternating runs per model")
    args = p.parse_args()
    runs: dict[str, list[float]] = {"crazyradio": [], "esb-duplex": []}
    for _ in range(args.repeats):
        for name in runs:
            runs[name].append(wall_per_simulated_s(name, args.seconds))
    medians = {name: statistics.median(values) for name, values in runs.items()}
    for name, value in medians.items():
        print(f"{name:<11} {value * 1e3:6.3f} ms of wall time per simulated second (median of {args.repeats})")
    extra = medians["crazyradio"] - medians["esb-duplex"]
    print(f"ratio crazyradio / esb-duplex {medians['crazyradio'] / medians['esb-duplex']:.2f}; the shared air adds "
          f"{extra * 1e3:.3f} ms per simulated second")
    return 0


if __name__ == "__main__":
    sys.exit(main())
