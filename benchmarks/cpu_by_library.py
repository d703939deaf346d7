"""Where a lockstep tick's CPU goes by library, per process and thread, in a flight and its matched floor (issue 19).

Takes in: --mode (moments or attitude; default moments), --rounds N (default 3), --seed, --frequency (perf's
samples per second of CPU, default FREQUENCY_HZ).
Gives out (printed): for the matched floor (loop_bench.matched_floor_run: the emulator against emulator_bench's
responder flying the mode's own command, each pose forwarded, FLOOR_SIMULATED_S simulated) and for `cfstack fly
--trajectory circle` in that mode, each sampled whole under Linux `perf record` (cpu-clock), the CPU time per tick
(us) of the emulator's main thread, the ground side's main thread (the responder in the floor, the flight loop in
the flight) and each process's other threads (zenoh's), split by library: the Python interpreter (libpython:
bytecode, objects, attribute lookups, calls), the kernel (system calls, scheduling, interrupts), zenoh, numpy,
cfstack's compiled kernels (the *_kernel(s) extensions), libc and libm, and the rest; the mean over the rounds,
each over the middle WINDOW of its run's ticks (the samples are stamped on CLOCK_MONOTONIC, the ticks' times read
beside them: a flight's from its states.csv rows, the floor's from its first tick's and last tick's wall times).

Why: cpu_split.py says which thread a cut must come from; this says what kind of work it is: compiling more of
the Python can shrink only the interpreter's part.
Sampling slows a run (perf's timer interrupts; its real-time factor under sampling is printed beside): read the
shares and the split, not the speed. Benchmarks measure, they do not assert.

Needs: `perf` on PATH, allowed to sample the processes it starts (root, or kernel.perf_event_paranoid <= 2).

Usage: python benchmarks/cpu_by_library.py [--mode moments] [--rounds 3] [--frequency 1000]
"""

from __future__ import annotations

import argparse
import json
import os
import re
import shutil
import subprocess
import sys
import tempfile
import threading
import time
from collections import Counter
from pathlib import Path

# this folder: the flight's row counter, a process's child, the threads reported and the ticks' window
from cpu_split import PARTS, WINDOW, RowCounter, child_pid

HERE = Path(__file__).resolve().parent
FREQUENCY_HZ = 1000  # perf's samples per CPU second: 1 ms of CPU per sample (higher slowed the flights more)
MAX_FREQUENCY_HZ = 10000  # above this perf's own interrupts take much of the CPU it measures
SAMPLE_S = 0.05  # how often the flight's rows are counted (their times bound the window)
FLOOR_SIMULATED_S = 30.0  # longer than loop_bench's floor runs: a window of about a second of wall time to sample
# what a sample's shared object says its library is, first match wins
LIBRARY_OF = (
    ("interpreter", re.compile(r"libpython|^python3")),
    ("kernel", re.compile(r"kernel\.kallsyms|\[vdso\]")),
    ("zenoh", re.compile(r"zenoh")),
    ("numpy", re.compile(r"_multiarray|_umath|numpy|_generator|_pcg64|_bounded|bit_generator|_common")),
    ("cfstack kernels", re.compile(r"^_\w+_kernels?\.cpython")),
    ("libc, libm", re.compile(r"^lib[cm][.-]")),
)
LIBRARIES = (*(lib for lib, _ in LIBRARY_OF), "other")  # the table's columns; the interpreter's first
# the floor, in a child process under perf: the emulator in that process, its responder as the child's child
FLOOR_SCRIPT = """
import json, sys
sys.path.insert(0, {here!r})
import loop_bench
result = loop_bench.matched_floor_run({mode!r}, seconds={seconds!r})
first = result["first_tick_monotonic_s"]
print(json.dumps({{"ticks": result["ticks"], "rtf": result["rtf"], "first": first, "last": first + result["wall_s"]}}))
"""


def library(dso: str) -> str:
    name = dso.rsplit("/", 1)[-1]
    return next((lib for lib, pattern in LIBRARY_OF if pattern.search(name)), "other")


def last_line(text: str) -> str:
    """The last non-empty line of a child's stderr (perf says there why it could not sample)."""
    lines = [line for line in text.splitlines() if line.strip()]
    return lines[-1].strip() if lines else "no message"


def perf_command(data: Path, frequency: int) -> list[str]:
    return ["perf", "record", "--quiet", "-e", "cpu-clock", "-F", str(frequency), "-k", "CLOCK_MONOTONIC",
            "-o", str(data), "--"]


def samples(data: Path) -> list[tuple[int, int, float, float, str]]:
    """(pid, tid, monotonic s, CPU us it stands for, library) of each sample in a perf.data file (cpu-clock's
    period is the CPU ns since the thread's previous sample, whatever rate perf could keep)."""
    run = subprocess.run(["perf", "script", "-i", str(data), "-F", "pid,tid,time,period,ip,dso"], capture_output=True,
                         text=True, check=True)
    out = []
    for line in run.stdout.splitlines():
        match = re.match(r"\s*(\d+)/(\d+)\s+([\d.]+):\s+(\d+)\s+[0-9a-f]+\s+\((.*)\)\s*$", line)
        if match:
            pid, tid, t, period_ns, dso = match.groups()
            out.append((int(pid), int(tid), float(t), int(period_ns) / 1e3, library(dso)))
    return out


def split(data: Path, processes: dict[int, str], window: tuple[float, float], ticks: int) -> dict[str, Counter]:
    """{part: {library: CPU us per tick}} over the window (monotonic s) holding `ticks` ticks; processes: {pid:
    "emulator" or "ground"}."""
    out = {part: Counter() for part in PARTS}
    for pid, tid, t, cpu_us, lib in samples(data):
        if pid in processes and window[0] <= t <= window[1]:
            out[f"{processes[pid]} {'main' if tid == pid else 'other'}"][lib] += cpu_us / ticks
    return out


def run_sampled(data: Path, frequency: int, command: list[str], what: str, rows: RowCounter | None = None,
                cwd: Path | None = None) -> tuple[str, list[int], list[tuple[int, float]]]:
    """Run `command` under perf (samples into `data`): its stdout, the pids of the command and of its first child,
    and with `rows` the (rows written, monotonic s) taken every SAMPLE_S while it ran. `what` names the run in a
    failure's line."""
    process = subprocess.Popen([*perf_command(data, frequency), *command], stdout=subprocess.PIPE,
                               stderr=subprocess.PIPE, text=True, cwd=cwd)
    pids: list[int] = []  # perf's child (the command), then its child
    marks: list[tuple[int, float]] = []
    stop = threading.Event()

    def watch() -> None:
        while not stop.wait(SAMPLE_S):
            if len(pids) < 2 and (pid := child_pid(pids[-1] if pids else process.pid)) is not None:
                pids.append(pid)
            if rows is not None:
                marks.append((rows.count(), time.monotonic()))

    watcher = threading.Thread(target=watch, daemon=True)
    watcher.start()
    out, err = process.communicate()
    stop.set()
    watcher.join()
    if process.returncode != 0 or len(pids) < 2:
        raise SystemExit(f"cpu_by_library: the sampled {what} failed (exit {process.returncode}): {last_line(err)}")
    return out, pids, marks


def fly_flight(mode: str, seed: int, frequency: int, tmp: Path) -> tuple[dict[str, Counter], float]:
    """The circle under perf; its split and its real-time factor under sampling."""
    data, log = tmp / "flight.data", tmp / "flight"
    command = [sys.executable, "-m", "cfstack", "fly", "--trajectory", "circle", "--mode", mode, "--seed", str(seed),
               "--json", "--log", str(log)]
    out, pids, marks = run_sampled(data, frequency, command, "circle", rows=RowCounter(log / "states.csv"))
    summary = json.loads(out)
    total = summary["timing"]["ticks"]
    first = next((m for m in marks if m[0] >= WINDOW[0] * total), None)
    last = next((m for m in marks if m[0] >= WINDOW[1] * total), None)
    if first is None or last is None or last[0] <= first[0]:
        raise SystemExit(f"cpu_by_library: the circle was too short to sample ({len(marks)} row counts taken)")
    parts = split(data, {pids[0]: "ground", pids[1]: "emulator"}, (first[1], last[1]), last[0] - first[0])
    return parts, summary["timing"]["real_time_factor"]


def fly_floor(mode: str, frequency: int, tmp: Path) -> tuple[dict[str, Counter], float]:
    """The matched floor under perf; its split and its real-time factor under sampling."""
    data = tmp / "floor.data"
    script = FLOOR_SCRIPT.format(here=str(HERE), mode=mode, seconds=FLOOR_SIMULATED_S)
    out, pids, _ = run_sampled(data, frequency, [sys.executable, "-c", script], "floor", cwd=HERE)
    result = json.loads(out)
    span = result["last"] - result["first"]
    window = (result["first"] + WINDOW[0] * span, result["first"] + WINDOW[1] * span)
    ticks = round((WINDOW[1] - WINDOW[0]) * result["ticks"])  # the floor's ticks come at an even pace
    parts = split(data, {pids[0]: "emulator", pids[1]: "ground"}, window, ticks)
    return parts, result["rtf"]


def table(name: str, parts: dict[str, Counter], rounds: int, rtfs: list[float]) -> None:
    print(f"\n{name} (RTF under sampling: {', '.join(f'{r:.1f}' for r in rtfs)}); CPU us per tick, mean of "
          f"{rounds} round(s)")
    print(f"{'':<16}" + "".join(f"{lib:>17}" for lib in LIBRARIES) + f"{'all':>8}{'interpreter':>13}")
    for part in PARTS:
        cells = [parts[part][lib] / rounds for lib in LIBRARIES]
        total = sum(cells)
        share = cells[0] / total if total else 0.0
        print(f"{part:<16}" + "".join(f"{c:>17.0f}" for c in cells) + f"{total:>8.0f}{share:>13.0%}")


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--mode", choices=("moments", "attitude"), default="moments")
    parser.add_argument("--rounds", type=int, default=3)
    parser.add_argument("--seed", type=int, default=1)
    parser.add_argument("--frequency", type=int, default=FREQUENCY_HZ)
    args = parser.parse_args()
    if args.rounds < 1:
        print(f"cpu_by_library: --rounds {args.rounds}: needs at least 1", file=sys.stderr)
        return 1
    if not 1 <= args.frequency <= MAX_FREQUENCY_HZ:
        print(f"cpu_by_library: --frequency {args.frequency}: needs 1 to {MAX_FREQUENCY_HZ} samples per CPU second",
              file=sys.stderr)
        return 1
    if shutil.which("perf") is None:
        print("cpu_by_library: needs Linux `perf` on PATH (not found)", file=sys.stderr)
        return 1
    print(f"{args.mode}, {args.rounds} round(s), perf at {args.frequency} samples per CPU second, load average "
          f"{os.getloadavg()[0]:.1f} on {os.cpu_count()} CPUs; 'ground' = the responder in the floor, the ground "
          "station in the flight")
    floor = {part: Counter() for part in PARTS}
    flight = {part: Counter() for part in PARTS}
    floor_rtf, flight_rtf = [], []
    with tempfile.TemporaryDirectory() as tmp:
        for k in range(args.rounds):
            folder = Path(tmp) / f"round{k}"  # a fresh states.csv per flight: its rows mark the window
            folder.mkdir()
            parts, rtf = fly_floor(args.mode, args.frequency, folder)
            floor_rtf.append(rtf)
            for part in PARTS:
                floor[part].update(parts[part])
            parts, rtf = fly_flight(args.mode, args.seed, args.frequency, folder)
            flight_rtf.append(rtf)
            for part in PARTS:
                flight[part].update(parts[part])
            print(f"round {k + 1}/{args.rounds} sampled", file=sys.stderr, flush=True)  # progress
    table("matched floor", floor, args.rounds, floor_rtf)
    table("circle", flight, args.rounds, flight_rtf)
    excess = {part: Counter({lib: flight[part][lib] - floor[part][lib] for lib in LIBRARIES}) for part in PARTS}
    print(f"\ncircle - floor, CPU us per tick by library{'':<4}"
          + "".join(f"{lib:>17}" for lib in LIBRARIES) + f"{'all':>8}")
    for part in PARTS:
        cells = [excess[part][lib] / args.rounds for lib in LIBRARIES]
        print(f"{part:<46}" + "".join(f"{c:>17.0f}" for c in cells) + f"{sum(cells):>8.0f}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
