"""What a flight costs outside its loop: `cfstack fly` start-up and teardown, baseline against this tree.

A sweep or a Monte Carlo study runs `cfstack fly` once per flight (groundstation/sweep/cell_task.py), and so
does every flight test: the start (imports, the emulator child, the first connect) and the end are paid
per flight, beside the loop that issue 19's loop_bench measures.

Takes in: --baseline REV (extracted with git archive and run from PYTHONPATH, its emulator child too),
--repeats N, --world FILE (default: ../shared/worlds/maze_2024_1.json, a short lab maze; a 20 s hover
where the shared worlds are absent).
Gives out, per command, baseline and new interleaved, medians over the repeats and the ratio new/baseline:
- `cfstack fly --mode foo`: the wall time of a bad option's one line and exit code 2;
- `cfstack fly WORLD --json` (lockstep, seeded): its wall time, the loop's own wall time (the summary's
  timing.loop_wall_s, first tick to last), and the rest (start-up + teardown = wall - loop);
and whether both trees flew the same flight (states.csv compared byte for byte);
- `cfstack sweep` of --sweep-flights hovers (attitude mode, ideal vehicle, latencies 0, 1, ... ms, all cores):
  wall time and flights per minute (dask's LocalCluster start included), once per repeat.

Run: `python benchmarks/startup_bench.py [--repeats 5] [--sweep-flights 8] [--baseline REV]`.
"""

from __future__ import annotations

import argparse
import filecmp
import json
import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from bench_paths import NEUTRAL_CWD, SHARED_WORLDS
from git_baseline import baseline_tree

# The last commit before fly started its emulator child ahead of the heavy imports.
BASELINE_REV = "254bc4d"
DEFAULT_WORLD = SHARED_WORLDS / "maze_2024_1.json"


def timed(args: list[str], env: dict) -> tuple[float, subprocess.CompletedProcess]:
    start = time.perf_counter()
    run = subprocess.run([sys.executable, "-m", "cfstack", *args], capture_output=True, text=True, timeout=600,
                         stdin=subprocess.DEVNULL, env=env, cwd=NEUTRAL_CWD)
    return time.perf_counter() - start, run


def bad_option(env: dict) -> float:
    wall, run = timed(["fly", "--mode", "foo"], env)
    if run.returncode != 2:
        raise SystemExit(f"cfstack fly --mode foo: exit {run.returncode}, expected 2: {run.stderr.strip()}")
    return wall


def flight(world_args: list[str], log: Path, env: dict) -> tuple[float, float]:
    """(wall s, loop wall s) of one seeded lockstep flight."""
    wall, run = timed(["fly", *world_args, "--clock", "lockstep", "--seed", "7", "--json", "--log", str(log)], env)
    if not run.stdout.strip():
        raise SystemExit(f"cfstack fly {' '.join(world_args)} failed: {run.stderr.strip()[-300:]}")
    return wall, json.loads(run.stdout)["timing"]["loop_wall_s"]


def sweep(flights: int, out: Path, env: dict) -> float:
    """Wall seconds of a sweep of `flights` hovers, each its own `cfstack fly` (as every sweep cell is)."""
    latencies = ",".join(str(i) for i in range(flights))
    wall, run = timed(["sweep", "--mode", "attitude", "--latency", latencies, "--loss", "0", "--firmware", "ideal",
                       "--jobs", str(os.cpu_count() or 1), "--out", str(out), "--extra", "--trajectory hover"], env)
    if run.returncode != 0:
        raise SystemExit(f"cfstack sweep failed: {run.stderr.strip()[-300:]}")
    return wall


def row(name: str, base: list[float], new: list[float]) -> str:
    b, n = statistics.median(base), statistics.median(new)
    return f"   {name:44} {b:7.3f} s -> {n:7.3f} s   new/base {n / b:5.2f}"


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--baseline", default=BASELINE_REV)
    ap.add_argument("--repeats", type=int, default=5)
    ap.add_argument("--world", type=Path, default=DEFAULT_WORLD)
    ap.add_argument("--sweep-flights", type=int, default=8, help="0: no sweep")
    opts = ap.parse_args()
    if opts.world.is_file():
        world_args, what = [str(opts.world)], opts.world.name
    else:
        world_args, what = ["--trajectory", "hover"], f"a hover ({opts.world} is absent)"
    with tempfile.TemporaryDirectory() as tmp_name:
        tmp = Path(tmp_name)
        envs = {"base": {**os.environ, "PYTHONPATH": str(baseline_tree(opts.baseline, tmp))},
                "new": dict(os.environ)}
        results = {label: {"option": [], "wall": [], "loop": [], "rest": [], "sweep": []} for label in envs}
        for k in range(opts.repeats):
            for label, env in envs.items():  # interleaved: the machine's load drifts
                results[label]["option"].append(bad_option(env))
                wall, loop = flight(world_args, tmp / f"{label}{k}", env)
                results[label]["wall"].append(wall)
                results[label]["loop"].append(loop)
                results[label]["rest"].append(wall - loop)
                if opts.sweep_flights:
                    results[label]["sweep"].append(sweep(opts.sweep_flights, tmp / f"sweep_{label}{k}", env))
            print(f"   repeat {k + 1}/{opts.repeats} done", file=sys.stderr, flush=True)  # progress
        same = filecmp.cmp(tmp / "base0" / "states.csv", tmp / "new0" / "states.csv", shallow=False)
    base, new = results["base"], results["new"]
    print(f"cfstack fly start-up and teardown: baseline git {opts.baseline} -> this tree, medians of "
          f"{opts.repeats} interleaved runs (wall seconds)")
    print(row("fly --mode foo (bad option, exit 2)", base["option"], new["option"]))
    print(row(f"fly {what}: whole command", base["wall"], new["wall"]))
    print(row("   its loop (timing.loop_wall_s)", base["loop"], new["loop"]))
    print(row("   outside the loop (start-up + teardown)", base["rest"], new["rest"]))
    print(f"   states.csv of the two trees' first flights: {'identical' if same else 'DIFFERENT'}")
    if opts.sweep_flights:
        print(row(f"sweep of {opts.sweep_flights} hovers", base["sweep"], new["sweep"]))
        per_min = [60.0 * opts.sweep_flights / statistics.median(results[label]["sweep"]) for label in envs]
        print(f"   flights per minute: {per_min[0]:.1f} -> {per_min[1]:.1f}")


if __name__ == "__main__":
    main()
