"""Flight-loop benchmark (issues 4 and 6): lockstep speed, realtime tick timing and end-to-end latency.

Prints, from one run:
1. Lockstep real-time factor (simulated / wall seconds) of a 20 s circle flight and of a full lab-maze
   flight over zenoh, in each command mode at its default rate, flown by a git baseline (--baseline REV,
   extracted and run from PYTHONPATH) and by this tree in the same run, each as a ratio to the floor (issue
   19's target: >= 80 %). The floor of the layout is the lockstep real-time factor of the same emulator
   (in this process) against a ground station that does no work at all (emulator_bench's responder: it
   acks each tick and sends one fixed command), at the mode's rate, with the ideal and the crazyflie
   firmware: the median of FLOOR_RUNS runs before the flights and FLOOR_RUNS after them, each interleaved
   with a run of the baseline's own floor (its emulator and responder), and each floor's ratio to that one
   (issue 19: the floor not lower than the baseline's, with the faithful firmware too). Each flight's
   ratio is to the crazyflie firmware's floor (what `cfstack fly` flies) from floor runs just before
   its baseline flight and just after its new flight (the machine's load drifts within a run), flown two
   ways: as filed (one ThrustMoment(weight) per tick in both modes; the faithful vehicle sinks to the floor
   within the run) and matched (the flight's own mode and command, the height held on mocap, each pose
   forwarded as cfstack fly's --extpose does: the emulator does the flight's onboard work, airborne).
   Then each flight's ground-station work per tick by part (waiting, codec, estimator, controller,
   mission, logging; flight_parts.py), baseline -> new; and its critical path per tick (tick record
   taken -> ack sent, from the flight's summary), with what that predicts for its share of the floor and
   the critical path that 80 % needs (critical_path_table).
2. Realtime: the ground station at 500 Hz with the emulator at 1 kHz beside it for a hover flight: tick
   work time p50/p99, deadline-miss rate, achieved rates of both.
3. End-to-end latency in that realtime flight: from the sample time of the newest IMU sample a command
   was computed from (states.csv est_time_s) to the moment the vehicle applies that command (its uplink
   frame's delivery by the radio, from the emulator's ledger, then the next 500 Hz firmware tick), all on
   the vehicle's clock, p50/p99 - next to a bare UDP round trip of the same size measured in the same run.

With --rounds N each flight pair is flown N times, each time between its own floor runs, and section 1
reports medians over the rounds with the share's range (single runs on these machines vary by more than
a change: 55-70 % of the matched floor in attitude across three runs within an hour, the same flight code).

Usage: python benchmarks/loop_bench.py [--quick] [--baseline REV] [--rounds N]
"""

from __future__ import annotations

import argparse
import csv
import json
import math
import os
import platform
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
from bench_paths import NEUTRAL_CWD, SHARED_WORLDS
from git_baseline import baseline_tree

from groundstation.clocks import DEFAULT_RATE_HZ
from link.keys import GROUND_STATION_SYSTEM_ID
from link.mavlink.codec import ActuatorLimits, FrameParser
from link.mavlink.tlog import read_tlog
from link.messages import ThrustMoment
from link.transports.base import free_loopback_port
from model.firmwares import DEFAULT_FIRMWARE, FIRMWARE_VEHICLES
from model.radio import DEFAULT_MAVLINK_RADIO
from model.vehicle import load_vehicle
from simulator.emulator import Emulator

MAZE = "test_lab_1"
FLOOR_RUNS = 3
FLOOR_SECONDS = 10.0  # simulated seconds per floor run
TARGET_RTF = {"moments": 5.0, "attitude": 20.0}  # issue 4's lockstep targets, each at its mode's default rate
FLOOR_SHARE_TARGET = 0.8  # issue 19: each flight at >= 80 % of the floor's real-time factor
FLOOR_FIRMWARES = tuple(FIRMWARE_VEHICLES)  # the floor with each onboard side (cfstack fly flies DEFAULT_FIRMWARE)
BASELINE = "baseline"  # the floor key of the baseline revision's own floor
FILED, MATCHED = "as filed", "matched"  # each flight's floor: the responder as filed, and flown as the flight
# The baseline of section 1: the last commit before issue 19's work (--baseline REV to change it)
BASELINE_REV = "0f6b840"
HERE = Path(__file__).resolve().parent
PART_NAMES = ("waiting", "codec", "estimator", "controller", "mission", "logging")
FIRMWARE_RATE_HZ = 500.0  # simulator/params/firmware.toml commander rate: when a delivered setpoint acts


def cfstack(*args: str, timeout: float = 900, env: dict | None = None) -> dict:
    run = subprocess.run([sys.executable, "-m", "cfstack", *args, "--json"], capture_output=True, text=True,
                         timeout=timeout, stdin=subprocess.DEVNULL, env=env, cwd=NEUTRAL_CWD)
    if not run.stdout.strip():
        raise SystemExit(f"cfstack {' '.join(args)} failed: {run.stderr.strip()[-300:]}")
    return json.loads(run.stdout)


def fly_timed(args: list[str], log: Path, tree: Path | None) -> tuple[dict, dict]:
    """One plain `cfstack fly` (its real-time factor) and one with the parts timed (flight_parts.py),
    from the working tree or, with `tree`, from that extracted revision (PYTHONPATH, emulator child too)."""
    env = dict(os.environ)
    if tree is not None:
        env["PYTHONPATH"] = str(tree)
    plain = cfstack(*args, "--log", str(log / "plain"), env=env)
    out = log / "parts.json"
    run = subprocess.run([sys.executable, str(HERE / "flight_parts.py"), str(out), *args, "--log", str(log / "parts")],
                         env=env, stdin=subprocess.DEVNULL, capture_output=True, text=True, timeout=900,
                         cwd=NEUTRAL_CWD)
    if run.returncode != 0:
        raise SystemExit(f"flight_parts.py {' '.join(args)} failed: {run.stderr.strip()[-300:]}")
    return plain, json.loads(out.read_text())


def floor_run(mode: str, firmware: str, flown: str = emulator_bench.FIXED, work_us: tuple[float, float] = (0.0, 0.0),
              seconds: float = FLOOR_SECONDS) -> dict:
    """One run of the layout's floor: the emulator against a ground station that does no work
    (emulator_bench's responder), at the mode's rate, `seconds` simulated; `flown`: what the responder
    sends (emulator_bench.FLOWN: FIXED as the issue was filed, or the mode's own command, airborne); `work_us`:
    the responder's busy waits per tick before its commands and after its ack (work_budget.py; none here)."""
    return emulator_bench.fly_zenoh(DEFAULT_MAVLINK_RADIO, seconds, 1.0 / DEFAULT_RATE_HZ[mode], True, 0,
                                    profile=False, firmware=firmware, flown=flown, work_us=work_us)


def matched_floor_run(mode: str, work_us: tuple[float, float] = (0.0, 0.0), seconds: float = FLOOR_SECONDS) -> dict:
    """One run of the matched floor: floor_run flown as a `cfstack fly` flight in `mode` is, with its command and
    its firmware (the default); `work_us` as floor_run's."""
    return floor_run(mode, DEFAULT_FIRMWARE, flown=mode, work_us=work_us, seconds=seconds)


# The baseline revision's own floor: its emulator and its responder (its emulator_bench, run from the extracted
# tree), on its MAVLink radio (named DEFAULT_MAVLINK_RADIO once the half-duplex Crazyradio model took the name
# "crazyradio"; before that "crazyradio" was the per-direction model, today's esb-duplex), its default firmware.
BASELINE_FLOOR_SCRIPT = """
import json, sys
sys.path.insert(0, "benchmarks")
import emulator_bench
from model import radio
run = emulator_bench.fly_zenoh(getattr(radio, "DEFAULT_MAVLINK_RADIO", "crazyradio"), {seconds!r}, {period_s!r},
                               True, 0, profile=False)
print(json.dumps({{"rtf": run["rtf"]}}))
"""


def _baseline_floor_run(mode: str, tree: Path) -> dict:
    """One run of the floor as the baseline revision measured it (issue 19: the floor not lower than then)."""
    script = BASELINE_FLOOR_SCRIPT.format(seconds=FLOOR_SECONDS, period_s=1.0 / DEFAULT_RATE_HZ[mode])
    run = subprocess.run([sys.executable, "-c", script], cwd=tree, env={**os.environ, "PYTHONPATH": str(tree)},
                         capture_output=True, text=True, timeout=600, stdin=subprocess.DEVNULL)
    if run.returncode != 0:
        raise SystemExit(f"the baseline's floor failed: {run.stderr.strip()[-300:]}")
    return json.loads(run.stdout.strip().splitlines()[-1])


def floor_runs(tree: Path) -> dict[tuple[str, str], list[dict]]:
    """FLOOR_RUNS runs of the floor per (mode, firmware), and of the baseline's own floor (firmware BASELINE),
    interleaved so that the machine's drift falls on all of them alike."""
    keys = [(mode, firmware) for mode in TARGET_RTF for firmware in (BASELINE, *FLOOR_FIRMWARES)]
    runs = {key: [] for key in keys}
    for i in range(FLOOR_RUNS):
        for mode, firmware in keys:
            runs[mode, firmware].append(_baseline_floor_run(mode, tree) if firmware == BASELINE
                                        else floor_run(mode, firmware))
        print(f"   floor runs {i + 1}/{FLOOR_RUNS}", file=sys.stderr, flush=True)  # progress
    return runs


def floors(before: dict, after: dict, rev: str) -> None:
    """Print the floor per (mode, firmware): the median of its runs before and after the flights (the
    machine's load drifts over a run), and its ratio to the baseline revision's own floor from the same run
    (issue 19: not lower than the baseline's, with the faithful firmware too); an overview of the layout (each
    flight's ratio uses its own floor runs)."""
    print(f"   floor: the emulator against a zero-work ground station (emulator_bench responder), median of "
          f"{FLOOR_RUNS} runs before and {FLOOR_RUNS} after the flights, {FLOOR_SECONDS:g} s simulated each, "
          f"interleaved with git {rev}'s own floor; load average {os.getloadavg()[0]:.1f}")
    out = {key: statistics.median(run["rtf"] for run in before[key] + after[key]) for key in before}
    for (mode, firmware), rtf in out.items():
        period_s = 1.0 / DEFAULT_RATE_HZ[mode]
        runs = [", ".join(f"{run['rtf']:.1f}x" for run in group)
                for group in (before[mode, firmware], after[mode, firmware])]
        name = f"git {rev}" if firmware == BASELINE else f"firmware {firmware}"
        versus = "" if firmware == BASELINE else f", {rtf / out[mode, BASELINE]:.2f} of git {rev}'s"
        print(f"   {mode:9} at {DEFAULT_RATE_HZ[mode]:3.0f} Hz, {name:18}: floor {rtf:5.1f}x "
              f"({period_s / rtf * 1e6:4.0f} us/tick{versus}; runs before {runs[0]}; after {runs[1]})")


def _responder_critical_us(responder: dict) -> float:
    """The zero-work responder's mean tick record -> ack time (its frames, one command, the ack), us."""
    answered = max(1, responder["ticks"] - 1)  # it times every tick but the first (which also arms)
    return (responder["frames_wait_s"] + responder["work_s"]) / answered * 1e6


def overlapped_ticks(period_s: float, horizon_s: float) -> int:
    """How many ticks one emulator round covers: 2 when the lookahead horizon (after a tick at t = 0) reaches
    a whole tick past the one just published (the emulator computes tick k+1 while the ground station
    computes tick k), else 1."""
    return 2 if horizon_s >= period_s - 1e-9 else 1


def lockstep_table(tmp: Path, quick: bool, rev: str, rounds: int) -> None:
    print("\n1. Lockstep real-time factor over zenoh (esb-duplex, MAVLink's default radio, firmware crazyflie), "
          "against the floor")
    print(f"   baseline = git {rev} (extracted, run from PYTHONPATH; its emulator child too), new = this tree;")
    print("   RTF = simulated s / wall s of the flight loop (first tick to last); /floor = RTF over the floor's RTF")
    print("   (same mode, same firmware), target >= "
          f"{FLOOR_SHARE_TARGET:.0%} (issue 19); parts: us of ground-station work per tick (flight_parts.py)")
    # absolute figures depend on the interpreter's build (README "Lockstep speed": Debian's 3.11.2 flew circles
    # 1.06-1.14x as fast as pyenv's 3.11.7, the floor faster too)
    print(f"   python {platform.python_version()} ({sys.executable}; built {' '.join(platform.python_build())}, "
          f"{platform.python_compiler()}), every process of the run")
    tree = baseline_tree(rev, tmp)
    flights = [("20 s circle", ["fly", "--trajectory", "circle"])]
    if SHARED_WORLDS.is_dir() and not quick:
        flights.append((f"maze {MAZE}", ["fly", str(SHARED_WORLDS / f"{MAZE}.json")]))
    elif not quick:
        print(f"   (maze flights skipped: {SHARED_WORLDS} is absent)")
    results, around = {}, {}  # per (name, mode[, label]): one entry per round
    before = floor_runs(tree)
    for round_ in range(rounds):
        for name, args in flights:
            for mode in TARGET_RTF:
                # each flight pair is compared with floor runs flown just before and just after it, under the
                # same load
                runs_around = _flight_floor_runs(mode)
                for label, source in (("baseline", tree), ("new", None)):
                    log = tmp / f"{name.replace(' ', '_')}_{mode}_{label}_{round_}"
                    flown_pair = fly_timed([*args, "--mode", mode], log, source)
                    results.setdefault((name, mode, label), []).append(flown_pair)
                    print(f"   flew {name}, {mode}, {label} (round {round_ + 1}/{rounds})", file=sys.stderr,
                          flush=True)  # progress
                for flown, runs in _flight_floor_runs(mode).items():
                    runs_around[flown] += runs
                around.setdefault((name, mode), []).append(runs_around)
    floors(before, floor_runs(tree), rev)
    # each round's flight against its own floor runs; the tables give the median over rounds (and the range)
    round_floor = {(key, flown): [statistics.median(run["rtf"] for run in by_flown[flown]) for by_flown in rounds_]
                   for key, rounds_ in around.items() for flown in (FILED, MATCHED)}
    floor = {key: statistics.median(values) for key, values in round_floor.items()}
    every = {key: [run for by_flown in rounds_ for run in by_flown[MATCHED]] for key, rounds_ in around.items()}
    floor_critical = {key: statistics.median(_responder_critical_us(run["responder"]) for run in runs)
                      for key, runs in every.items()}
    grounded = sorted({f"{name} {mode} ({flown})" for (name, mode), rounds_ in around.items()
                       for by_flown in rounds_ for flown, runs in by_flown.items()
                       for run in runs if not run["airborne_at_end"]})
    print("\n   floor (crazyflie firmware) for each flight: the median of floor runs just before the baseline's flight "
          "and just after the new one, flown two ways:\n   'as filed' = one ThrustMoment(weight) per tick in either "
          "mode (issue 19's floor when it was filed); 'matched' = the\n   flight's own mode and command, the height "
          "held on mocap, each pose forwarded (cfstack fly's --extpose): the\n   emulator then does the flight's "
          "onboard work, airborne")
    if rounds > 1:
        print(f"   {rounds} rounds: RTF, floor and share are medians over the rounds, each round's flight against its "
              "own floor runs;\n   the share's range over the rounds in brackets (the target is read off the median)")
    if grounded:
        print(f"   floor runs that ended on the floor (less physics per step than a flight): {', '.join(grounded)}")
    share = {}
    print(f"\n{'flight':18} {'mode':9} {'RTF base':>8} {'RTF new':>8} {'new/base':>8} {'floor':>6} {'new/floor':>15} "
          f"{'target':>6} {'matched':>7} {'new/matched':>15} {'target':>6} {'result':>13}")
    for name, _ in flights:
        for mode in TARGET_RTF:
            rtf = {label: [plain["timing"]["real_time_factor"] for plain, _ in results[name, mode, label]]
                   for label in ("baseline", "new")}
            rb, rn = statistics.median(rtf["baseline"]), statistics.median(rtf["new"])
            cells = []
            for flown in (FILED, MATCHED):
                shares = [new / f for new, f in zip(rtf["new"], round_floor[(name, mode), flown], strict=True)]
                share[name, mode, flown] = statistics.median(shares)
                spread = f" ({min(shares):.0%}-{max(shares):.0%})" if rounds > 1 else ""
                verdict = "PASS" if share[name, mode, flown] >= FLOOR_SHARE_TARGET else "MISS"
                cells.append(f"{floor[(name, mode), flown]:6.1f} {share[name, mode, flown]:>5.0%}{spread:>10} "
                             f"{verdict:>6}")
            result = ",".join(sorted({plain["result"] for plain, _ in results[name, mode, "new"]}))
            print(f"{name:18} {mode:9} {rb:8.1f} {rn:8.1f} {rn / rb:8.2f} {cells[0]} {cells[1].strip():>30} "
                  f"{result:>13}")
    print("\n   per-component us per tick (exclusive; 'other' = loop wall - parts), baseline -> new"
          + (", medians over the rounds" if rounds > 1 else ""))
    print(f"{'flight':18} {'mode':9} " + " ".join(f"{p:>15}" for p in (*PART_NAMES, "other", "loop")))
    for name, _ in flights:
        for mode in TARGET_RTF:
            cells = []
            per_tick = [[_per_tick(parts) for _, parts in results[name, mode, label]] for label in ("baseline", "new")]
            for part in (*PART_NAMES, "other", "loop"):
                base, new = (statistics.median(ticks[part] for ticks in runs) for runs in per_tick)
                cells.append(f"{base:6.0f} -> {new:5.0f}")
            print(f"{name:18} {mode:9} " + " ".join(f"{c:>15}" for c in cells))
    critical_path_table(flights, results, {key: floor[key, MATCHED] for key in around}, floor_critical,
                        {key[:2]: value for key, value in share.items() if key[2] == MATCHED})


def _flight_floor_runs(mode: str) -> dict[str, list[dict]]:
    """One floor run of the firmware cfstack fly flies, each way (FILED, MATCHED), at the mode's rate."""
    return {FILED: [floor_run(mode, DEFAULT_FIRMWARE)], MATCHED: [matched_floor_run(mode)]}


def critical_path_table(flights, results, floor, floor_critical, measured_share) -> None:
    """What bounds each flight's speed: the ground station's critical path P (tick record taken -> ack sent).

    The emulator may not step past the tick after next before a tick's ack (the lookahead's horizon), so
    n ticks (overlapped_ticks) cost P + C of wall time, where C - the emulator's own step and the two
    zenoh hops - is read off the floor flown as the flight flies (MATCHED): C = n x floor period - P_floor.
    Hence a flight at its floor's share (P_floor + C) / (P + C), and 80 % needs P <= (P_floor + C) / 0.8 - C.
    The model holds while the ground station waits for each tick. `in` is the share of ticks whose record was
    already there when the ground station asked (it was the bottleneck: all its work per tick counts, the
    log row and truth after the ack too), `CPU` its process's CPU time per tick (us, all threads).
    What the model leaves out is measured too: X = the flight's wall time for n ticks - (P + C), the time
    only a flight spends (its processes' extra wake-ups, the ground station's work after the ack when it is
    the bottleneck). `if P = P_floor` is the share a flight would reach with X unchanged and a critical path
    no longer than the zero-work responder's, (P_floor + C) / (P_floor + C + X): the most that making the
    ground station's critical path cheaper can give.
    `loop CPU` is the CPU time per tick of the flight loop's own thread, which is serial: no tick can take
    less wall time than that, so a flight cannot reach 80 % while it exceeds `80 % wall`, the wall time per
    tick at 80 % of the matched floor (its period over 0.8 x the floor's real-time factor)."""
    print("\n   critical path per tick (tick record taken -> ack sent, mean us; the rest of a tick overlaps the "
          "emulator):\n   n ticks cost P + C, C = n x floor period - P_floor (the emulator's step and two zenoh "
          "hops; the matched floor's);\n   share of the matched floor predicted (P_floor + C) / (P + C); in = ticks "
          "whose record was already there\n   when asked for (the ground station was the bottleneck), CPU = its "
          "process's CPU us per tick (new);\n   X = the flight's wall time for n ticks - (P + C), what the model "
          "leaves out; 'if P = P_floor' = (P_floor + C) / (P_floor + C + X);\n   loop CPU = the flight loop's "
          "own thread's CPU us per tick (new): a lower bound on its wall time per tick, against '80% wall', the "
          "wall us per tick\n   at 80 % of the matched floor")
    print(f"{'flight':18} {'mode':9} {'n':>2} {'P base':>7} {'P new':>6} {'P floor':>7} {'C':>6} "
          f"{'predicted':>9} {'measured':>8} {'P for 80%':>9} {'in':>5} {'CPU':>5} {'X':>5} {'if P = P_floor':>14} "
          f"{'loop CPU':>8} {'80% wall':>8}")
    horizon_s = Emulator(emulator_bench.make_config(DEFAULT_MAVLINK_RADIO, 1, 0)).lockstep.lookahead_horizon_s()
    for name, _ in flights:
        for mode in TARGET_RTF:
            period_s = 1.0 / DEFAULT_RATE_HZ[mode]
            n = overlapped_ticks(period_s, horizon_s)
            p_floor = floor_critical[name, mode]
            c = n * period_s / floor[name, mode] * 1e6 - p_floor
            p = [_median_or_none([plain["timing"].get("ack_after_tick_us_mean")
                                  for plain, _ in results[name, mode, label]]) for label in ("baseline", "new")]
            measured = measured_share[name, mode]
            needed = (p_floor + c) / FLOOR_SHARE_TARGET - c
            base = "-" if p[0] is None else f"{p[0]:.0f}"  # a revision before the measure: not reported
            ready, cpu, loop_cpu = (
                _median_or_none([plain["timing"].get(key) for plain, _ in results[name, mode, "new"]])
                for key in ("tick_record_ready_fraction", "process_cpu_us_per_tick", "loop_thread_cpu_us_per_tick"))
            ready_cell = "-" if ready is None else f"{ready:.0%}"
            cpu_cell, loop_cpu_cell = ("-" if v is None else f"{v:.0f}" for v in (cpu, loop_cpu))
            wall_at_target_us = period_s / (FLOOR_SHARE_TARGET * floor[name, mode]) * 1e6
            x_us = (p_floor + c) / measured - (p[1] + c)  # the flight's n ticks: the floor's (P_floor + C) / share
            print(f"{name:18} {mode:9} {n:2d} {base:>7} {p[1]:6.0f} {p_floor:7.0f} {c:6.0f} "
                  f"{(p_floor + c) / (p[1] + c):9.0%} {measured:8.0%} {needed:9.0f} {ready_cell:>5} {cpu_cell:>5} "
                  f"{x_us:5.0f} {(p_floor + c) / (p_floor + c + x_us):14.0%} {loop_cpu_cell:>8} "
                  f"{wall_at_target_us:8.0f}")


def _median_or_none(values: list) -> float | None:
    """The median of the values, None if any is None (a revision before the measure)."""
    return None if any(v is None for v in values) else statistics.median(values)


def _per_tick(parts: dict) -> dict[str, float]:
    ticks = parts["ticks"]
    out = {p: parts["parts_s"].get(p, 0.0) / ticks * 1e6 for p in PART_NAMES}
    out["loop"] = parts["loop_wall_s"] / ticks * 1e6
    out["other"] = out["loop"] - sum(out[p] for p in PART_NAMES)
    return out


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
    p.add_argument("--baseline", default=BASELINE_REV, metavar="REV",
                   help=f"git revision of section 1's baseline (default {BASELINE_REV})")
    p.add_argument("--rounds", type=int, default=1,
                   help="flight pairs per flight and mode, each with its own floor runs; medians reported (default 1)")
    args = p.parse_args()
    if args.rounds < 1:
        p.error(f"--rounds must be >= 1, got {args.rounds}")
    with TemporaryDirectory() as tmp_name:
        tmp = Path(tmp_name)
        lockstep_table(tmp, args.quick, args.baseline, args.rounds)
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
