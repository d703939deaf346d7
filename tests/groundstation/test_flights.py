"""Whole flight sessions over zenoh against the emulator (lockstep, seeded): the ground station's job.

Issue 4 targets checked here: hover at 1 m for 10 s with the default radio profile (esb-duplex for MAVLink), RMS
position error
<= 1 cm in both command modes; the --json contract; logs (states.csv, link.mavlink.tlog, summary.json) that are
complete after a flight and readable after the ground station is killed; one-line errors for bad input.
"""

import json
import signal
import subprocess
import sys
import time
import uuid
from pathlib import Path

import numpy as np
import pytest

from groundstation.logread import read_log
from link.mavlink.codec import ActuatorLimits, FrameParser
from link.mavlink.tlog import read_tlog
from link.messages import ImuSample, ThrustMoment
from model.vehicle import load_vehicle

sys.path.insert(0, str(Path(__file__).resolve().parent))

from testsupport import cfstack, free_port, processes_with  # noqa: E402

SUMMARY_KEYS = {"result", "reached_goal", "collided", "min_clearance_m", "flight_time_s", "rms_tracking_error_m",
                "max_tracking_error_m", "final_position_error_m", "estimator", "link", "sim_time_s",
                "wall_time_s", "log_dir"}
LINK_KEYS = {"uplink_sent", "uplink_delivered", "downlink_sent", "downlink_delivered", "rtt_ms_p50", "rtt_ms_p99"}
HOVER_RMS_TARGET_M = 0.01  # issue 4


def check_summary(summary: dict) -> None:
    assert SUMMARY_KEYS <= summary.keys()
    assert LINK_KEYS <= summary["link"].keys()
    assert {"rms_position_error_m", "rms_velocity_error_mps"} <= summary["estimator"].keys()
    assert summary["result"] in ("reached_goal", "crashed", "timeout", "failsafe", "aborted")


def test_fly_hover_in_moments_mode_meets_the_hover_target_and_logs_everything(tmp_path):
    log = tmp_path / "log"
    run = cfstack("fly", "--trajectory", "hover", "--mode", "moments", "--json", "--log", str(log))
    assert run.returncode == 0, run.stderr
    lines = run.stdout.strip().splitlines()
    assert len(lines) == 1  # exactly one JSON object on stdout
    summary = json.loads(lines[0])
    check_summary(summary)
    assert summary["result"] == "reached_goal" and summary["reached_goal"] and not summary["collided"]
    assert summary["rms_tracking_error_m"] <= HOVER_RMS_TARGET_M
    assert summary["estimator"]["rms_position_error_m"] <= 0.003
    assert json.loads((log / "summary.json").read_text()) == summary
    # lockstep: the critical path per tick (tick record -> ack) is reported, a part of each tick's wall time
    timing = summary["timing"]
    tick_us = timing["loop_wall_s"] / timing["ticks"] * 1e6
    assert 0 < timing["ack_after_tick_us_p50"] < tick_us and 0 < timing["ack_after_tick_us_mean"] < tick_us
    # a tick's wall time holds its wait for the record and its critical path (and the work after the ack)
    assert timing["tick_record_wait_us_mean"] + timing["ack_after_tick_us_mean"] < tick_us
    # the loop's thread is one of the process's threads, and serial: its CPU per tick fits in the tick's wall time
    assert 0 < timing["loop_thread_cpu_us_per_tick"] <= timing["process_cpu_us_per_tick"]
    assert timing["loop_thread_cpu_us_per_tick"] < tick_us

    # The link figures agree with what the log holds, frame for frame.
    link = summary["link"]
    # thrust/moment frames are normalised by the vehicle's limits: the reader needs them to decode
    frames = read_tlog(log / "link.mavlink.tlog", FrameParser(ActuatorLimits.from_vehicle(load_vehicle())))
    sent = [d for _, d in frames if d.system_id == 255]
    received = [d for _, d in frames if d.system_id != 255]
    assert len(sent) == link["uplink_sent"]
    assert len(received) == link["downlink_delivered"]
    assert link["uplink_delivered"] <= link["uplink_sent"] and link["uplink_delivered"] >= 0.95 * link["uplink_sent"]
    assert any(isinstance(d.message, ThrustMoment) for d in sent)
    assert any(isinstance(d.message, ImuSample) for d in received)

    states = read_log(log)
    assert len(states.t_s) > 1000 and np.all(np.diff(states.t_s) > 0)
    track = np.isin(states.phase, ["track", "hover"])
    err = np.linalg.norm(states.position_m("truth")[track] - states.position_m("ref")[track], axis=1)
    # the summary's RMS is the same quantity recomputed from the log
    assert np.sqrt(np.mean(err**2)) == pytest.approx(summary["rms_tracking_error_m"], rel=1e-6)


def test_groundstation_flies_a_separately_started_emulator_in_attitude_mode(tmp_path):
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    prefix = f"t{uuid.uuid4().hex[:8]}"
    emulator = subprocess.Popen([sys.executable, "-m", "cfstack", "emulator", "--listen", endpoint, "--id", prefix,
                                 "--clock", "lockstep", "--quiet"], stdin=subprocess.DEVNULL, stdout=subprocess.DEVNULL,
                                stderr=subprocess.PIPE, text=True)
    try:
        run = cfstack("groundstation", "--connect", endpoint, "--id", prefix, "--clock", "lockstep",
                      "--mode", "attitude", "--trajectory", "hover", "--json", "--log", str(tmp_path / "log"))
    finally:
        emulator.send_signal(signal.SIGINT)
        _, err = emulator.communicate(timeout=20)
    assert run.returncode == 0, run.stderr
    summary = json.loads(run.stdout)
    check_summary(summary)
    assert summary["result"] == "reached_goal"
    assert summary["rms_tracking_error_m"] <= HOVER_RMS_TARGET_M
    assert emulator.returncode == 0
    assert err.strip().splitlines()[-1].startswith("emulator: stopped")  # Ctrl-C: a clean one-line summary


def test_a_killed_ground_station_leaves_readable_logs_and_no_emulator(tmp_path):
    log = tmp_path / "log"
    prefix = f"k{uuid.uuid4().hex[:8]}"
    proc = subprocess.Popen([sys.executable, "-m", "cfstack", "fly", "--trajectory", "hover", "--id", prefix,
                             "--log", str(log)], stdin=subprocess.DEVNULL, stdout=subprocess.DEVNULL,
                            stderr=subprocess.DEVNULL)
    states = log / "states.csv"
    deadline = time.monotonic() + 60
    while time.monotonic() < deadline and (not states.exists() or states.stat().st_size < 600_000):
        time.sleep(0.1)
    proc.send_signal(signal.SIGKILL)
    proc.wait(timeout=10)
    flight = read_log(log)  # tolerates the row being written when it died
    assert len(flight.t_s) > 500
    frames = read_tlog(log / "link.mavlink.tlog", FrameParser(ActuatorLimits.from_vehicle(load_vehicle())))
    assert len(frames) >= 2 * len(flight.t_s) - 10  # about an IMU sample in and a command out per tick
    # the child emulator was told to die with its parent (it would otherwise wait for acks forever)
    deadline = time.monotonic() + 10
    while time.monotonic() < deadline and processes_with(prefix):
        time.sleep(0.2)
    assert not processes_with(prefix)


@pytest.mark.parametrize("content, problem", [
    ('{"blocks": []}', "missing bounds"),
    ('{"bounds": {"extents": [0, 1, 0, 1, 0, NaN]}}', "not a finite number"),
    ('{"bounds": {"extents": [0, 1, 0, 1, 0, 1]}, "start": [0.5, 0.5', "not valid JSON"),
])
def test_bad_world_is_one_line_and_exit_code_2(tmp_path, content, problem):
    world = tmp_path / "bad.json"
    world.write_text(content)
    run = cfstack("fly", str(world), "--json", timeout=60)
    assert run.returncode == 2
    assert run.stdout == ""
    lines = run.stderr.strip().splitlines()
    assert len(lines) == 1 and str(world) in lines[0] and problem in lines[0]


GC_PROBE = """
import gc, json, sys
import groundstation.flight as flight
full_in_loop, in_loop = [], [False]
gc.callbacks.append(lambda phase, info: phase == "stop" and in_loop[0] and info["generation"] == 2
                    and full_in_loop.append(1))
tick = flight.FlightLoop.tick
def marked(self):
    in_loop[0] = True
    try:
        tick(self)  # the clock's wait for the next tick included
    finally:
        in_loop[0] = False
flight.FlightLoop.tick = marked
from cfstack.cli import main
code = main(["fly", *sys.argv[2:], "--json", "--log", sys.argv[1]])
print(json.dumps({"code": code, "full_collections_in_loop": len(full_in_loop)}))
"""


def test_no_full_garbage_collection_runs_inside_the_flight_loop(tmp_path):
    """A full collection walks the whole heap, which at the loop's start holds all of start-up (modules, world,
    plan, zenoh): 44 ms in one 500 Hz realtime flight, 22 ticks skipped at once. The loop collects in full
    once before its first tick, and CPython starts none during a tick (the clock's wait included)."""
    # Without the collection before, a lockstep moments circle ran one inside its loop; with it but without the
    # oldest generation's threshold raised, one ran at tick 10727 of this circle (29 ms), after cfstack's start-up
    # stopped importing scipy.optimize and the heap the loop starts with shrank (checked by taking each out).
    run = subprocess.run([sys.executable, "-c", GC_PROBE, str(tmp_path / "log"), "--trajectory", "circle"],
                         capture_output=True, text=True, timeout=240, stdin=subprocess.DEVNULL)
    probe = json.loads(run.stdout.strip().splitlines()[-1])
    assert probe["code"] == 0, run.stderr[-2000:]
    assert probe["full_collections_in_loop"] == 0
