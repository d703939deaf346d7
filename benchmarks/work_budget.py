"""How much work per tick a lockstep ground station may add and still keep a share of the floor (issue 19).

Takes in: --modes (default: moments attitude), --rounds N (default 3), --seconds simulated per floor run,
--work "BEFORE,AFTER ..." (microseconds per tick; default per mode, WORK_POINTS_US), --no-flight.
Gives out (printed), per mode: the matched floor of loop_bench (the emulator with the crazyflie firmware against
emulator_bench's responder flying the mode's own command on the height hold, each pose forwarded), flown with the
responder busy for BEFORE us per tick before its commands and AFTER us after its ack; each point's real-time
factor as a ratio to its round's zero-work floor (median and range over the rounds; below); and beside them
`cfstack fly --trajectory circle` in that mode, flown in the same rounds, with its critical path P (tick record
taken -> ack sent) and its loop thread's CPU per tick, as its summary gives them.

Why: the ground station's own work per tick sits in two places. Before its ack it is on the lockstep's
critical path (the emulator may not step past the next tick until the ack is in); after it, it overlaps the
emulator's next step, but the loop's thread is serial, so it still bounds the tick. A busy wait holds the CPU
and the GIL as Python work does, without that work's other costs (its caches, its allocations), so the share at
a point is an upper bound on what real work of that size reaches: what a change must cut to reach a share can
be read off here, measured on the machine at hand rather than predicted by a model.

Each round flies the zero-work floor first and last and every other point in between, in an order shuffled with
the round's number as seed; each point's share is to the mean of its round's two zero-work floors (these machines
drift within a run, and a single floor run varies by more than 10 %: the ratio to its own round cancels most of
the drift). The zero-work floor's row gives those two runs' shares, so its range shows the spread within a round.
Benchmarks measure, they do not assert.

Usage: python benchmarks/work_budget.py [--modes moments] [--rounds 3] [--work "0,0 50,0 0,50"] [--no-flight]
"""

from __future__ import annotations

import argparse
import math
import random
import statistics
import sys
from tempfile import TemporaryDirectory

# this folder (python puts it on sys.path)
from loop_bench import FLOOR_SECONDS, FLOOR_SHARE_TARGET, cfstack, matched_floor_run

from groundstation.clocks import DEFAULT_RATE_HZ

MODES = ("moments", "attitude")
FLIGHT = "flight"  # the point that is `cfstack fly`, not the responder
ZERO_WORK = (0.0, 0.0)  # the zero-work floor every ratio is to: always a point, the first
# Busy waits (before the commands, after the ack) in us per tick besides ZERO_WORK: they span what the ground
# station's tick costs now (loop_bench's P and loop CPU) down to a few tens of us.
WORK_POINTS_US = {
    "moments": ((25.0, 0.0), (0.0, 25.0), (25.0, 25.0), (50.0, 0.0), (0.0, 50.0), (50.0, 50.0), (100.0, 100.0)),
    "attitude": ((50.0, 50.0), (100.0, 0.0), (0.0, 100.0), (100.0, 100.0), (200.0, 200.0)),
}


def parse_work(text: str) -> tuple[tuple[float, float], ...]:
    """'B,A B,A ...' -> ((B, A), ...); one clear line for anything else."""
    points = []
    for item in text.split():
        try:
            before, after = (float(v) for v in item.split(","))
        except ValueError:
            raise SystemExit(f"--work: {item!r} is not BEFORE,AFTER in microseconds (e.g. 50,25)") from None
        if not (0 <= before < math.inf and 0 <= after < math.inf):  # NaN fails too
            raise SystemExit(f"--work: {item!r}: a busy wait is a finite number of microseconds, not negative")
        points.append((before, after))
    return tuple(points)


def flight_point(mode: str) -> dict:
    """`cfstack fly --trajectory circle` in `mode`, as loop_bench flies it: real-time factor, P, loop CPU."""
    with TemporaryDirectory(prefix="work-budget-") as log:  # its logs are not kept
        timing = cfstack("fly", "--trajectory", "circle", "--mode", mode, "--seed", "1", "--log", log)["timing"]
    return {"rtf": timing["real_time_factor"], "p_us": timing["ack_after_tick_us_mean"],
            "loop_cpu_us": timing["loop_thread_cpu_us_per_tick"]}


def run_mode(mode: str, points: tuple, rounds: int, seconds: float, with_flight: bool) -> dict:
    """{point: [run, ...]} over the rounds (ZERO_WORK first), each run with its 'share' of its round's zero-work
    floor: the mean of that floor's real-time factor flown first and last in the round (`points` and the flight in
    between, shuffled). Each point but the flight is loop_bench's matched floor with the responder busy."""
    zero = ZERO_WORK
    others = [*(p for p in dict.fromkeys(points) if p != zero), *([FLIGHT] if with_flight else [])]
    runs: dict = {key: [] for key in (zero, *others)}
    for r in range(rounds):
        order = others[:]
        random.Random(r).shuffle(order)
        this_round, floors = {}, []
        for i, key in enumerate([zero, *order, zero]):
            run = (flight_point(mode) if key == FLIGHT
                   else matched_floor_run(mode, work_us=key, seconds=seconds))
            if key == zero:
                floors.append(run)
            else:
                this_round[key] = run
            print(f"  {mode} round {r + 1}/{rounds} run {i + 1}/{len(order) + 2}, {_label(key)}: {run['rtf']:.2f}x "
                  "real time", file=sys.stderr, flush=True)
        floor_rtf = statistics.fmean(run["rtf"] for run in floors)
        for key, run in [*((zero, run) for run in floors), *this_round.items()]:
            runs[key].append({**run, "share": run["rtf"] / floor_rtf})
    return runs


def _label(key) -> str:
    return "cfstack fly" if key == FLIGHT else f"busy {key[0]:g} us before, {key[1]:g} us after"


def report(mode: str, runs: dict) -> None:
    period_us = 1e6 / DEFAULT_RATE_HZ[mode]
    rounds = len(runs[ZERO_WORK]) // 2
    print(f"\n{mode} ({DEFAULT_RATE_HZ[mode]:g} Hz ticks, {period_us:g} us simulated each), {rounds} round(s); "
          f"share = real-time factor / the mean of its round's two zero-work floors' (target {FLOOR_SHARE_TARGET:.0%})")
    print(f"{'before us':>9} {'after us':>8} {'RTF':>6} {'share':>6} {'range':>11} {'wall us/tick':>12} "
          f"{'emu main CPU':>12} {'responder work':>14}")
    for key, values in runs.items():
        share = statistics.median(v["share"] for v in values)
        low, high = min(v["share"] for v in values), max(v["share"] for v in values)
        rtf = statistics.median(v["rtf"] for v in values)
        mark = "*" if share >= FLOOR_SHARE_TARGET else " "
        if key == FLIGHT:
            p = statistics.median(v["p_us"] for v in values)
            cpu = statistics.median(v["loop_cpu_us"] for v in values)
            print(f"cfstack fly --trajectory circle {rtf:6.2f} {share:6.1%}{mark}{low:5.0%}-{high:4.0%}  "
                  f"P {p:.0f} us, loop thread CPU {cpu:.0f} us per tick")
            continue
        wall = statistics.median(v["us_per_tick"] for v in values)
        emu = statistics.median(v["main_cpu_us_per_tick"] for v in values)
        work = statistics.median(v["responder"]["work_s"] / v["responder"]["ticks"] * 1e6 for v in values)
        print(f"{key[0]:9g} {key[1]:8g} {rtf:6.2f} {share:6.1%}{mark}{low:5.0%}-{high:4.0%} {wall:12.0f} {emu:12.0f} "
              f"{work:14.0f}")
    print("(* at or above the target; 'responder work': its busy waits plus sending its commands and ack, us per "
          "tick;\n 'emu main CPU': the emulator's main thread, us per tick)")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--modes", nargs="+", choices=MODES, default=list(MODES))
    parser.add_argument("--rounds", type=int, default=3, help="rounds; every point is flown once per round")
    parser.add_argument("--seconds", type=float, default=FLOOR_SECONDS, help="simulated seconds per floor run")
    parser.add_argument("--work", help="busy waits 'BEFORE,AFTER ...' in us per tick (default: per mode)")
    parser.add_argument("--no-flight", dest="flight", action="store_false", help="skip the cfstack fly circles")
    args = parser.parse_args()
    if args.rounds < 1 or args.seconds <= 0:
        raise SystemExit("--rounds must be at least 1 and --seconds positive")
    chosen = parse_work(args.work) if args.work else None  # an empty --work: the defaults, as before
    points = {mode: WORK_POINTS_US[mode] if chosen is None else chosen for mode in args.modes}
    for mode in args.modes:
        report(mode, run_mode(mode, points[mode], args.rounds, args.seconds, args.flight))


if __name__ == "__main__":
    main()
