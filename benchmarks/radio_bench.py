"""What the one-dongle radio model costs: CRTP moments traffic through `crazyradio` (the half-duplex EsbAir) against
`esb-duplex` (each direction on its own air), in the same run, alternating.

The traffic is cfstack's own CRTP moments traffic as radio_budget.py accounts it (frame sizes from its encoders,
rates from its parameter files), pushed and popped on a 1 ms grid of simulated time (radio_budget.run_traffic).
Prints the wall time per simulated second for each model and their ratio.

Usage: python benchmarks/radio_bench.py [--seconds 120] [--repeats 3]
"""

from __future__ import annotations

import argparse
import statistics
import sys
import time

from radio_budget import crtp_traffic, run_traffic

from model.radio import load_radio_profile

MODELS = ("crazyradio", "esb-duplex")
COMMAND_HZ = 500.0  # moments mode's command rate


def wall_per_simulated_s(profile_name: str, seconds: float) -> float:
    profile = load_radio_profile(profile_name)
    traffic = crtp_traffic("moments", COMMAND_HZ)
    start = time.perf_counter()
    run_traffic(profile, *traffic, seconds=seconds)
    return (time.perf_counter() - start) / seconds


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--seconds", type=float, default=120.0, help="simulated seconds per run")
    p.add_argument("--repeats", type=int, default=3, help="alternating runs per model")
    args = p.parse_args()
    runs: dict[str, list[float]] = {name: [] for name in MODELS}
    for _ in range(args.repeats):
        for name in MODELS:
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
