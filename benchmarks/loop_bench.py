"""Flight-loop benchmark (issues 4 and 6): lockstep speed, realtime tick timing and end-to-end latency.

Prints, from one run:
1. Lockstep real-time factor (simulated / wall seconds) of a 20 s circle flight and of a full lab-maze
   flight over zenoh, in each command mode (targets: >= 5x in moments mode at 500 Hz, >= 20x in attitude
   mode at 100 Hz).
   Next to each mode, in the same run: the floor of the layout, the lockstep real-time factor of the
   same emulator (in this process) against a ground station that does no work at all (emulator_bench's
   responder: it acks each tick and sends one fixed command), at the mode's rate, median of
   FLOOR_RUNS runs; and the per-tick wall-time budget the target allows. A ground station's own work
   (estimator, controller, logs) can only add to the floor.
2. Realtime: the ground station at 500 Hz with the emulator at 1 kHz beside it for a hover flight: tick
   work time p50/p99, deadline-miss rate, achieved rates of both.
3. End-to-end latency in that realtime flight: from the sample time of the newest IMU sample a command
   was computed from (states.csv est_time_s) to the moment the vehicle applies that command (its uplink
   frame's delivery by the radio, from the emulator's ledger, then the next 500 Hz firmware tick), all on
   the vehicle's clock, p50/p99 - next to a bare UDP round trip of the same size measured in the same run.

Usage: python benchmarks/loop_bench.py [--quick]
"""

from __future__ import annotations

import argparse
import csv
import json
import math
import os
import socket
import statistics
import subprocess
import sys
import time
import uuid
from pathlib import Path
from tempfile import TemporaryDirectory

import emulator_bench  # this folder: the zero-work responder and fly_zenoh (python puts it on sys.path)
import numpy as np
from bench_paths import SHARED_WORLDS

from groundstation.session import DEFAULT_RATE_HZ
from link.keys import GROUND_STATION_SYSTEM_ID
from link.mavlink.codec import ActuatorLimits, FrameParser
from link.mavlink.tlog import read_tlog
from link.messages import ThrustMoment
from link.transports.base import free_loopback_port
from model.vehicle import load_vehicle

MAZE = "test_lab_1"
FLOOR_RUNS = 3
FLOOR_SECONDS = 10.0  # simulated seconds per floor run
TARGET_RTF = {"moments": 5.0, "attitude": 20.0}  # issue 4's lockstep targets, each at its mode's default rate
FIRMWARE_RATE_HZ = 500.0  # simulator/params/firmware.toml commander rate: when a delivered setpoint acts


def cfstack(*args: str, timeout: float = 900) -> dict:
    run = subprocess.run([sys.executable, "-m", "cfstack", *args, "--json"], capture_output=True, text=True,
                         timeout=timeout, stdin=subprocess.DEVNULL)
    if not run.stdout.strip():
        raise SystemExit(f"cfstack {' '.join(args)} failed: {run.stderr.strip()[-300:]}")
    return json.loads(run.stdout)


def lockstep_table(tmp: Path, quick: bool) -> None:
    print("\n1. Lockstep real-time factor over zenoh (crazyradio profile)")
    print("   RTF = simulated s / wall s of the flight loop (first tick to last); whole = the same over the")
    print("   whole `cfstack fly` session, which also waits for the emulator child to boot")
    print(f"{'flight':28} {'mode':9} {'sim (s)':>8} {'loop (s)':>8} {'RTF':>6} {'whole':>6} {'us/tick':>8} "
          f"{'target':>7} {'result':>13}")
    flights = [("20 s circle", ["fly", "--trajectory", "circle"])]
    if SHARED_WORLDS.is_dir() and not quick:
        flights.append((f"maze {MAZE}", ["fly", str(SHARED_WORLDS / f"{MAZE}.json")]))
    for name, args in flights:
        for mode, target in TARGET_RTF.items():
            s = cfstack(*args, "--mode", mode, "--log", str(tmp / f"{name.replace(' ', '_')}_{mode}"))
            timing = s["timing"]
            rtf = timing["real_time_factor"]
            whole = s["sim_time_s"] / s["wall_time_s"]
            us_per_tick = timing["loop_wall_s"] / timing["ticks"] * 1e6
            print(f"{name:28} {mode:9} {s['sim_time_s']:8.2f} {timing['loop_wall_s']:8.2f} {rtf:6.1f} "
                  f"{whole:6.1f} {us_per_tick:8.0f} {target:7.0f} {s['result']:>13} "
                  f"{'PASS' if rtf >= target else 'MISS'}")
    print_floor()


def print_floor() -> None:
    """The layout's floor per mode: the emulator against a ground station that does no work."""
    print(f"   floor: the emulator against a zero-work ground station (emulator_bench responder), "
          f"median of {FLOOR_RUNS} runs of {FLOOR_SECONDS:g} s simulated; load average {os.getloadavg()[0]:.1f}")
    for mode, target in TARGET_RTF.items():
        rate_hz = DEFAULT_RATE_HZ[mode]
        period_s = 1.0 / rate_hz
        runs = [emulator_bench.fly_zenoh("crazyradio", FLOOR_SECONDS, period_s, True, 0, profile=False)
                for _ in range(FLOOR_RUNS)]
        rtfs = [r["rtf"] for r in runs]
        floor_us = period_s / statistics.median(rtfs) * 1e6
        budget_us = period_s / target * 1e6
        print(f"   {mode:9} at {rate_hz:3.0f} Hz: floor {statistics.median(rtfs):5.1f}x ({floor_us:4.0f} us/tick; "
              f"runs {', '.join(f'{x:.1f}x' for x in rtfs)}); the {target:.0f}x target allows {budget_us:4.0f} "
              f"us/tick: {budget_us - floor_us:+4.0f} us/tick beyond the floor for the ground station's work")


def realtime_flight(tmp: Path) -> tuple[dict, Path, dict, str]:
    port = free_loopback_port()
    endpoint, prefix = f"tcp/127.0.0.1:{port}", f"b{uuid.uuid4().hex[:8]}"
    ledger, log = tmp / "ledger.json", tmp / "realtime"
    emulator = subprocess.Popen([sys.executable, "-m", "cfstack", "emulator", "--listen", endpoint, "--id", prefix,
                                 "--clock", "realtime", "--radio-ledger", str(ledger), "--quiet"],
                                stdin=subprocess.DEVNULL, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE,
                                text=True)
    try:
        time.sleep(1.0)
        summary = cfstack("groundstation", "--connect", endpoint, "--id", prefix, "--clock", "realtime",
                          "--trajectory", "hover", "--log", str(log))
    finally:
        emulator.send_signal(2)
        _, err = emulator.communicate(timeout=30)
    return summary, log, json.loads(ledger.read_text())["vehicles"]["1"], err.strip().splitlines()[-1]


def end_to_end_ms(log: Path, ledger: dict) -> np.ndarray:
    """Per command: (firmware tick applying it) - (sample time of the IMU data it was computed from)."""
    with open(log / "states.csv") as f:
        rows = [r for r in csv.DictReader(f) if r["est_time_s"] and r["cmd_thrust_n"]]
    basis = {round(float(r["t_s"]), 6): float(r["est_time_s"]) for r in rows}
    parser = FrameParser(ActuatorLimits.from_vehicle(load_vehicle()))
    sent = [d for _, d in read_tlog(log / "link.mavlink.tlog", parser) if d.system_id == GROUND_STATION_SYSTEM_ID]
    fates = ledger["uplink"]["ledger"]
    out = []
    for index, decoded in enumerate(sent[: len(fates)]):
        if not isinstance(decoded.message, ThrustMoment) or not fates[index][3]:
            continue
        issued = round(decoded.message.time_s, 6)
        if issued not in basis:
            continue
        applied = math.ceil(fates[index][3][0] * FIRMWARE_RATE_HZ - 1e-9) / FIRMWARE_RATE_HZ
        out.append((applied - basis[issued]) * 1e3)
    return np.array(out)


def bare_udp_rtt_ms(size: int, count: int = 2000) -> np.ndarray:
    """Round trips of `size`-byte datagrams through an echo in another process (loopback)."""
    port = free_loopback_port(socket.SOCK_DGRAM)
    echo = subprocess.Popen([sys.executable, "-c", (
        "import socket,sys\n"
        f"s=socket.socket(socket.AF_INET,socket.SOCK_DGRAM);s.bind(('127.0.0.1',{port}))\n"
        "print('ready',flush=True)\n"
        "while True:\n d,a=s.recvfrom(2048)\n if d==b'stop': break\n s.sendto(d,a)\n")],
        stdout=subprocess.PIPE, text=True)
    echo.stdout.readline()
    s = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    payload, rtts = b"x" * size, []
    for _ in range(count):
        t0 = time.perf_counter()
        s.sendto(payload, ("127.0.0.1", port))
        s.recvfrom(2048)
        rtts.append((time.perf_counter() - t0) * 1e3)
    s.sendto(b"stop", ("127.0.0.1", port))
    echo.wait(timeout=10)
    return np.array(rtts)


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--quick", action="store_true", help="skip the maze flights")
    args = p.parse_args()
    with TemporaryDirectory() as tmp_name:
        tmp = Path(tmp_name)
        lockstep_table(tmp, args.quick)
        summary, log, ledger, emulator_line = realtime_flight(tmp)
        t = summary.get("timing", {})
        print("\n2. Realtime: ground station 500 Hz, emulator 1 kHz, hover flight")
        print(f"ground station: {t.get('ticks')} ticks, achieved {t.get('achieved_rate_hz', 0):.1f} Hz, tick work "
              f"p50 {t.get('tick_ms_p50', 0):.3f} ms p99 {t.get('tick_ms_p99', 0):.3f} ms, deadline misses "
              f"{100 * t.get('deadline_miss_rate', 0):.2f} % ({summary['result']})")
        print(emulator_line)
        e2e = end_to_end_ms(log, ledger)
        frame = 12 + 22  # SET_ACTUATOR_CONTROL_TARGET: header + CRC + payload, the size of a command
        udp = bare_udp_rtt_ms(frame)
        print("\n3. End-to-end latency (IMU sample -> command applied on the vehicle), realtime, zenoh loopback")
        if e2e.size:
            p50, p99 = np.percentile(e2e, [50, 99])
            print(f"commands matched: {e2e.size}; p50 {p50:.2f} ms, p99 {p99:.2f} ms")
        else:
            print("no command could be matched to its IMU basis")
        print(f"bare UDP round trip ({frame} B, same run): p50 {np.percentile(udp, 50):.3f} ms, "
              f"p99 {np.percentile(udp, 99):.3f} ms")
    return 0


if __name__ == "__main__":
    sys.exit(main())
