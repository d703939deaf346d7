"""Sweep throughput: flights per minute with the dask runner, against the subprocess pool it replaced.

Takes in: --flights N (hover flights of the ideal vehicle in attitude mode, lockstep, one-way latencies
0, 1, ... N-1 ms, so every flight differs), --baseline-commit (the pool's commit), --repeats.
Gives out: a table on stdout, measured in the same run: wall time and flights per minute of
  - the subprocess pool (groundstation/sweep/runner.py at the baseline commit, --jobs = all cores);
  - the dask runner on a LocalCluster with 1, 2, ... all cores (cluster start-up included);
and the ratios dask/pool at all cores and dask(k)/dask(1) (the scaling). Medians over --repeats runs,
baseline and candidates interleaved. Run: `python benchmarks/sweep_bench.py [--flights 8] [--repeats 1]`.
"""

from __future__ import annotations

import argparse
import os
import statistics
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
from git_baseline import baseline_modules  # noqa: E402

from groundstation.sweep import cli  # noqa: E402
from groundstation.sweep.grid import load_base_profile  # noqa: E402
from groundstation.sweep.runner import DaskRunner  # noqa: E402
from model.radio import radio_profile_path  # noqa: E402

BASELINE_COMMIT = "77ef616"  # the last commit with the subprocess pool
FLY = ("--firmware", "ideal", "--mode", "attitude")
TRAJECTORY = ("--trajectory", "hover")


def _pool(commit: str, flights: int, jobs: int, out: Path, scratch: Path) -> float:
    """Wall seconds for the old pool to fly the grid."""
    old = baseline_modules(commit, {"grid": "groundstation/sweep/grid.py", "table": "groundstation/sweep/table.py",
                                    "runner": "groundstation/sweep/runner.py"}, scratch)
    latencies = tuple(float(i) for i in range(flights))
    opts = old["grid"].SweepOptions(world=None, modes=("attitude",), latencies_ms=latencies, losses_pct=(0.0,),
                                    jobs=jobs, out=out, seed=1, radio_base="ideal", extra=TRAJECTORY,
                                    firmware="ideal")
    base = old["grid"].load_base_profile(radio_profile_path("ideal"))
    todo = [(c, old["grid"].write_cell_profile(base, c.latency_ms, c.loss_pct, out / "profiles"))
            for c in old["grid"].grid_cells(opts)]
    rows = []
    start = time.perf_counter()
    old["runner"].run_cells(opts, todo, rows.append)
    elapsed = time.perf_counter() - start
    assert len(rows) == flights and all(r.result for r in rows)
    sys.path.remove(str(scratch))
    for name in [m for m in sys.modules if m.startswith("bench_baseline")]:
        del sys.modules[name]
    return elapsed


def _dask(flights: int, jobs: int, out: Path) -> float:
    """Wall seconds for the dask runner (LocalCluster start included) to fly the same grid."""
    latencies = ",".join(str(i) for i in range(flights))
    opts = cli.parse_options(["--mode", "attitude", "--latency", latencies, "--loss", "0", "--jobs", str(jobs),
                              "--firmware", "ideal", "--out", str(out), "--extra", " ".join(TRAJECTORY)])
    bases = {r: load_base_profile(r) for r in opts.radios}
    jobs_list = cli._jobs(opts, cli.grid_cells(opts, bases), bases)
    rows = []
    start = time.perf_counter()
    runner = DaskRunner(opts)
    try:
        runner.run(jobs_list, rows.append)
    finally:
        runner.close()
    elapsed = time.perf_counter() - start
    assert len(rows) == flights and all(r["cell_status"] == "flown" for r in rows)
    return elapsed


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--flights", type=int, default=8)
    parser.add_argument("--repeats", type=int, default=1)
    parser.add_argument("--baseline-commit", default=BASELINE_COMMIT)
    args = parser.parse_args(argv)
    cores = os.cpu_count() or 1
    core_counts = sorted({1, 2, cores} & set(range(1, cores + 1)))
    times: dict[str, list[float]] = {"pool": []} | {f"dask {k}": [] for k in core_counts}
    print(f"sweep bench: {args.flights} lockstep hovers (ideal vehicle, attitude mode) per run, {cores} cores, "
          f"baseline pool = {args.baseline_commit}, median of {args.repeats}", flush=True)
    with tempfile.TemporaryDirectory() as tmp:
        for repeat in range(args.repeats):
            order = list(times) if repeat % 2 == 0 else list(reversed(times))
            for name in order:
                out = Path(tmp) / f"{name.replace(' ', '')}-{repeat}"
                if name == "pool":
                    scratch = Path(tmp) / f"baseline-{repeat}"
                    scratch.mkdir()
                    times[name].append(_pool(args.baseline_commit, args.flights, cores, out, scratch))
                else:
                    times[name].append(_dask(args.flights, int(name.split()[1]), out))
                print(f"  {name:8s} run {repeat + 1}: {times[name][-1]:6.1f} s", flush=True)
    medians = {name: statistics.median(t) for name, t in times.items()}
    print(f"{'runner':18s} {'wall s':>8s} {'flights/min':>12s}")
    for name, seconds in medians.items():
        label = f"subprocess pool {cores}" if name == "pool" else f"dask, {name.split()[1]} worker(s)"
        print(f"{label:18s} {seconds:8.1f} {60.0 * args.flights / seconds:12.1f}")
    ratio = medians["pool"] / medians[f"dask {cores}"]
    print(f"dask {cores} workers / pool {cores} jobs: throughput ratio {ratio:.2f}")
    for k in core_counts[1:]:
        print(f"scaling dask {k} / dask 1: {medians['dask 1'] / medians[f'dask {k}']:.2f}x")


if __name__ == "__main__":
    main()
