"""Flight-time benchmark (issue 5): our link and emulator against the course's published best times.

Prints two tables, measured in one run:
1. Course flight maps, flown through the link with the esb-duplex profile (MAVLink's default; lockstep), minimum
   snap with
   the planning_aggressive limits and the full geometric controller, planned at a margin of 0.32 m;
   flight time against the best published course results (the course's ideal simulator, no radio) and
   the course's own collision check (course_grade.no_collision: no truth point within its 0.25 m robot radius).
2. Lab mazes: the report's 1 m/s constant-speed trajectory against minimum snap at the same planning
   margin (0.2 m); ratio of flight times (target: minimum snap at least twice as fast) and clearances.

Usage: python benchmarks/flight_time_bench.py [--jobs N] [--mode moments|attitude] [--only NAME ...]
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import time
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path
from tempfile import TemporaryDirectory

from bench_paths import SHARED_WORLDS

# Best published results for these maps in the course's own simulator (issue 5).
COURSE_BEST_S = {"test_maze": 9.04, "test_over_under": 13.17, "p13_test_window": 9.79}
COURSE_ARGS = ["--planning", "planning_aggressive", "--controller", "full", "--margin", "0.32"]
LAB_MINSNAP_ARGS = ["--trajectory", "minsnap", "--speed", "4", "--accel", "9", "--controller", "full"]
LAB_CONSTANT_ARGS = ["--trajectory", "constant-speed", "--speed", "1.0"]


def fly(world: str, args: list[str], mode: str, log: Path) -> dict:
    # the ideal vehicle, as the course's simulator (whose best times these are compared with) and the lab
    # report's ideal simulation: the faithful Crazyflie's attitude loop cannot fly these aggressive plans
    run = subprocess.run([sys.executable, "-m", "cfstack", "fly", str(SHARED_WORLDS / f"{world}.json"), "--mode", mode,
                          "--firmware", "ideal", "--radio", "esb-duplex", "--json", "--log", str(log), *args],
                         capture_output=True, text=True, stdin=subprocess.DEVNULL)
    if not run.stdout.strip():
        return {"result": f"error: {run.stderr.strip().splitlines()[-1] if run.stderr.strip() else run.returncode}"}
    return json.loads(run.stdout)


def fmt(v, digits=2):
    return "-" if v is None else f"{v:.{digits}f}"


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--jobs", type=int, default=2)
    p.add_argument("--mode", default="moments", choices=("moments", "attitude"))
    p.add_argument("--only", nargs="*", help="world names to run (default: all)")
    args = p.parse_args()
    if not SHARED_WORLDS.is_dir():
        print(f"shared worlds not found at {SHARED_WORLDS}: nothing to measure")
        return 0
    labs = (sorted(w.stem for w in SHARED_WORLDS.glob("test_lab_*.json"))
            + sorted(w.stem for w in SHARED_WORLDS.glob("maze_20*.json")))
    course = list(COURSE_BEST_S)
    if args.only:
        labs = [w for w in labs if w in args.only]
        course = [w for w in course if w in args.only]
    jobs = [(w, "course", COURSE_ARGS) for w in course]
    jobs += [(w, "constant", LAB_CONSTANT_ARGS) for w in labs] + [(w, "minsnap", LAB_MINSNAP_ARGS) for w in labs]
    results: dict = {}
    start = time.monotonic()
    with TemporaryDirectory() as tmp, ThreadPoolExecutor(args.jobs) as pool:
        futures = {(w, kind): pool.submit(fly, w, a, args.mode, Path(tmp) / f"{w}_{kind}") for w, kind, a in jobs}
        for i, (key, future) in enumerate(futures.items(), 1):
            results[key] = future.result()
            print(f"[{i}/{len(futures)}] {key[0]} {key[1]}: {results[key]['result']} "
                  f"({time.monotonic() - start:.0f} s)", file=sys.stderr, flush=True)

    print(f"\nCourse flight maps ({args.mode} mode, esb-duplex profile, lockstep)")
    print(f"{'map':18} {'ours (s)':>9} {'course best (s)':>16} {'ratio':>6} {'clearance (m)':>14} {'result':>13}")
    for w in course:
        r = results[(w, "course")]
        t = r.get("flight_time_s")
        ratio = None if t is None else COURSE_BEST_S[w] / t
        grade = r.get("course_grade") or {}  # the course's own rule: no point within its robot radius
        ok = r["result"] == "reached_goal" and grade.get("no_collision") is True and \
            t is not None and t < COURSE_BEST_S[w]
        print(f"{w:18} {fmt(t):>9} {COURSE_BEST_S[w]:>16.2f} {fmt(ratio):>6} {fmt(r.get('min_clearance_m'), 3):>14} "
              f"{r['result']:>13} {'BEATS' if ok else 'MISS'}")

    print(f"\nLab mazes ({args.mode} mode): report's constant speed 1 m/s vs minimum snap, same 0.2 m margin")
    print(f"{'maze':14} {'const (s)':>9} {'minsnap (s)':>11} {'speed-up':>8} {'clear const':>11} {'clear snap':>10}")
    for w in labs:
        c, s = results[(w, "constant")], results[(w, "minsnap")]
        tc, ts = c.get("flight_time_s"), s.get("flight_time_s")
        speedup = None if tc is None or ts is None else tc / ts
        ok = speedup is not None and speedup >= 2.0 and (s.get("min_clearance_m") or 0) >= 0.1
        print(f"{w:14} {fmt(tc):>9} {fmt(ts):>11} {fmt(speedup):>8} {fmt(c.get('min_clearance_m'), 3):>11} "
              f"{fmt(s.get('min_clearance_m'), 3):>10} {'>=2x' if ok else 'MISS'}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
