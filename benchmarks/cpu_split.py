"""Where a lockstep tick's CPU goes, per process and thread, in a flight and in its matched floor (issue 19).

Takes in: --mode (moments or attitude; default moments), --rounds N (default 3), --seed.
Gives out (printed): per round and as medians, the CPU time per tick (us) of
- the matched floor (loop_bench.matched_floor_run: the emulator with the crazyflie firmware, in this process, against
  emulator_bench's responder flying the mode's own command, each pose forwarded): the emulator's main thread and
  its other threads (zenoh's), the responder's main thread and its other threads, all from tick 0 to the end;
- `cfstack fly --trajectory circle` in that mode: its emulator child's main thread and other threads, the ground
  station's main thread (the flight loop) and other threads, read from /proc/<pid>/task/<tid>/schedstat (time on
  a CPU, ns) every SAMPLE_S over the flight's middle rows (WINDOW of states.csv's rows: start-up and landing
  left out), the ticks in that window counted as states.csv's lines;
and for each the wall time per tick, the CPUs kept busy (CPU per tick / wall per tick) and the flight's excess
over the floor, per part.

Why: with both processes keeping most of two CPUs busy, a flight's share of the floor is close to the ratio of
their CPU per tick (README "Lockstep speed"), so this says which process and which thread a cut must come from.
The flight's sampler reads /proc five times a second (its own CPU is not counted). Benchmarks measure, they do
not assert.

Usage: python benchmarks/cpu_split.py [--mode moments] [--rounds 3] [--seed 1]
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

import loop_bench  # this folder: the matched floor

SAMPLE_S = 0.2
WINDOW = (0.2, 0.8)  # the flight's rows sampled: from 20 % to 80 % of its ticks
PARTS = ("emulator main", "emulator other", "ground main", "ground other")


def thread_cpu_ns(pid: int) -> dict[int, int]:
    """{thread id: ns on a CPU} of a process's threads now ({} once it is gone)."""
    times = {}
    try:
        tids = os.listdir(f"/proc/{pid}/task")
    except OSError:
        return times
    for tid in tids:
        try:
            with open(f"/proc/{pid}/task/{tid}/schedstat") as f:
                times[int(tid)] = int(f.read().split()[0])
        except (OSError, ValueError, IndexError):
            pass  # the thread ended between listing and reading
    return times


def child_pid(pid: int) -> int | None:
    """The first child process of pid (the emulator `cfstack fly` starts), None before it has one."""
    try:
        for tid in os.listdir(f"/proc/{pid}/task"):
            with open(f"/proc/{pid}/task/{tid}/children") as f:
                children = f.read().split()
            if children:
                return int(children[0])
    except OSError:
        pass
    return None


class RowCounter:
    """states.csv's lines so far, read incrementally (the file only grows during a flight)."""

    def __init__(self, path: Path):
        self.path, self.offset, self.lines = path, 0, 0

    def count(self) -> int:
        try:
            with open(self.path, "rb") as f:
                f.seek(self.offset)
                chunk = f.read()
        except OSError:
            return 0
        self.offset += len(chunk)
        self.lines += chunk.count(b"\n")
        return max(0, self.lines - 1)  # the header is not a tick


def split(before: dict[int, int], after: dict[int, int], main: int) -> tuple[float, float]:
    """(main thread, other threads) ns between two samples; threads that started meanwhile count from 0."""
    spent = {tid: ns - before.get(tid, 0) for tid, ns in after.items()}
    main_ns = spent.pop(main, 0)
    return main_ns, sum(spent.values())


def fly_flight(mode: str, seed: int) -> dict:
    """One circle, sampled; CPU us per tick per part over the window, wall us per tick over it."""
    with tempfile.TemporaryDirectory() as tmp:
        log = Path(tmp) / "flight"
        cmd = [sys.executable, "-m", "cfstack", "fly", "--trajectory", "circle", "--mode", mode, "--seed", str(seed),
               "--json", "--log", str(log)]
        process = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, text=True)
        rows = RowCounter(log / "states.csv")
        samples: list[tuple[int, float, dict, dict]] = []  # rows, time, emulator's and ground station's threads
        emulator: list[int] = []  # the child's pid, once it has one
        stop = threading.Event()

        def sample() -> None:
            while not stop.wait(SAMPLE_S):
                if not emulator and (pid := child_pid(process.pid)) is not None:
                    emulator.append(pid)
                if emulator:
                    samples.append((rows.count(), time.monotonic(), thread_cpu_ns(emulator[0]),
                                    thread_cpu_ns(process.pid)))

        sampler = threading.Thread(target=sample, daemon=True)
        sampler.start()
        out, _ = process.communicate()
        stop.set()
        sampler.join()
    if process.returncode != 0:
        raise RuntimeError(f"cfstack fly exited {process.returncode}")
    summary = json.loads(out)
    ticks = summary["timing"]["ticks"]
    inside = [s for s in samples if WINDOW[0] * ticks <= s[0] <= WINDOW[1] * ticks]
    if len(inside) < 2:
        raise RuntimeError(f"the flight was too short to sample ({len(inside)} samples in its window)")
    first, last = inside[0], inside[-1]
    n = last[0] - first[0]
    # a main thread's id is its process's
    ns = (*split(first[2], last[2], emulator[0]), *split(first[3], last[3], process.pid))
    return {"wall_us": (last[1] - first[1]) / n * 1e6, "ticks": n, "rtf": summary["timing"]["real_time_factor"],
            **{part: value / n / 1e3 for part, value in zip(PARTS, ns, strict=True)}}


def fly_floor(mode: str) -> dict:
    """The matched floor; CPU us per tick per part from tick 0 to the end."""
    run = loop_bench.matched_floor_run(mode)
    responder = run["responder"]
    per_tick = 1e6 / run["ticks"]
    return {"wall_us": run["us_per_tick"], "ticks": run["ticks"], "rtf": run["rtf"],
            "emulator main": run["main_cpu_us_per_tick"],
            "emulator other": run["cpu_us_per_tick"] - run["main_cpu_us_per_tick"],
            "ground main": responder["main_cpu_s"] * per_tick,
            "ground other": (responder["cpu_s"] - responder["main_cpu_s"]) * per_tick}


def line(name: str, r: dict) -> str:
    total = sum(r[p] for p in PARTS)
    cells = "".join(f"{r[p]:>16.0f}" for p in PARTS)
    return f"{name:<22}{r['rtf']:>7.2f}{r['wall_us']:>9.0f}{cells}{total:>9.0f}{total / r['wall_us']:>7.2f}"


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--mode", choices=("moments", "attitude"), default="moments")
    parser.add_argument("--rounds", type=int, default=3)
    parser.add_argument("--seed", type=int, default=1)
    args = parser.parse_args()
    if args.rounds < 1:
        print(f"cpu_split: --rounds {args.rounds}: needs at least 1", file=sys.stderr)
        return 1
    print(f"{args.mode}, {args.rounds} round(s), load average {os.getloadavg()[0]:.1f} on {os.cpu_count()} CPUs; "
          f"CPU us per tick ('ground' = the responder in the floor, the ground station in the flight)")
    header = f"{'':<22}{'RTF':>7}{'wall':>9}" + "".join(f"{p:>16}" for p in PARTS) + f"{'total':>9}{'CPUs':>7}"
    floors, flights = [], []
    for k in range(args.rounds):
        floors.append(fly_floor(args.mode))
        flights.append(fly_flight(args.mode, args.seed))
        print(f"round {k + 1}", flush=True)
        print(header)
        print(line("floor (matched)", floors[-1]))
        print(line("circle", flights[-1]))
    median = {name: {key: statistics.median(r[key] for r in runs) for key in runs[0]}
              for name, runs in (("floor", floors), ("flight", flights))}
    print(f"medians over {args.rounds} round(s)")
    print(header)
    print(line("floor (matched)", median["floor"]))
    print(line("circle", median["flight"]))
    excess = "".join(f"{median['flight'][p] - median['floor'][p]:>16.0f}" for p in PARTS)
    total = sum(median["flight"][p] - median["floor"][p] for p in PARTS)
    print(f"{'circle - floor':<22}{'':>7}{median['flight']['wall_us'] - median['floor']['wall_us']:>9.0f}{excess}"
          f"{total:>9.0f}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
