"""What the displays cost the lockstep loop: real-time factor of one flight without and with the live view
(recorded to an .rrd, as the viewer's own process would receive it) and with GCS forwarding.

Takes in: --trajectory (built-in, default circle), --mode, --repeats.
Gives out: a table on stdout, measured in the same run, variants interleaved per repeat: the flight loop's
real-time factor (summary.timing.real_time_factor: simulated s per wall s of the loop) for
  - no display;  --view-save FILE.rrd;  --gcs udp:127.0.0.1:PORT (nobody listening: sends still happen);
and each one's median as a ratio to the no-display median.
Run: `python benchmarks/view_bench.py [--repeats 3] [--mode moments]`.
"""

from __future__ import annotations

import argparse
import json
import socket
import statistics
import subprocess
import sys
import tempfile
from pathlib import Path

from link.transports.base import free_loopback_port


def fly(extra: list[str], mode: str, trajectory: str, folder: Path) -> float:
    cmd = [sys.executable, "-m", "cfstack", "fly", "--trajectory", trajectory, "--mode", mode, "--json",
           "--log", str(folder), *extra]
    out = subprocess.run(cmd, capture_output=True, text=True, check=True, stdin=subprocess.DEVNULL)
    return json.loads(out.stdout)["timing"]["real_time_factor"]


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--repeats", type=int, default=3)
    p.add_argument("--mode", default="moments", choices=("moments", "attitude"))
    p.add_argument("--trajectory", default="circle")
    args = p.parse_args()
    results: dict[str, list[float]] = {"none": [], "view-save": [], "gcs": []}
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        for repeat in range(args.repeats):
            port = free_loopback_port(socket.SOCK_DGRAM)
            variants = {"none": [], "view-save": ["--view-save", str(tmp / f"v{repeat}.rrd")],
                        "gcs": ["--gcs", f"udp:127.0.0.1:{port}"]}
            for name, extra in variants.items():
                rtf = fly(extra, args.mode, args.trajectory, tmp / f"{name}{repeat}")
                results[name].append(rtf)
                print(f"repeat {repeat + 1}/{args.repeats} {name:9s} {rtf:5.2f}x real time", file=sys.stderr)
    base = statistics.median(results["none"])
    print(f"{args.mode} mode, {args.trajectory}, lockstep, median of {args.repeats}:")
    print(f"{'display':10s} {'real-time factor':>17s} {'ratio to none':>14s}")
    for name, values in results.items():
        median = statistics.median(values)
        print(f"{name:10s} {median:16.2f}x {median / base:14.3f}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
