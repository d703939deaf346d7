"""Failsafes injected mid-flight, through whole flight sessions (lockstep, seeded, real processes).

Issue "Timing and packet-loss verification", Tests item 5. Each test flies a short planned flight
across an empty test room (`cfstack fly`, airborne start, a straight minimum-snap dash that tilts the
vehicle) and injects a fault with the emulator's `--cut-radio` / `--cut-mocap`
(`cfstack fly --emulator-arg=...`). Expected times come from the parameter files (firmware watchdog,
mission failsafe thresholds, radio and mocap latencies, attitude gains), never from earlier runs:
- radio cut for good: the ground station reports the silent downlink after downlink_silent_after_s;
  the vehicle holds its last attitude setpoint, levels watchdog_level_timeout_s after the last setpoint
  it received, and stops its motors (free fall, -g) watchdog_shutdown_timeout_s after it;
- mocap cut for 0.5 s: failsafe hold after mocap_hold_after_s, then the mission resumes and completes;
- mocap cut for good: hold, then failsafe descent after mocap_descend_after_s (and a soft landing);
- signing on and a rogue publisher on the uplink key (unsigned commands, replayed signed frames): none
  is applied - the flight is byte-identical to one without the rogue - and the emulator counts them.
The `fly` flights use `--firmware ideal`: the expected attitude and descent figures are the ideal law's
(K_R). With the faithful firmware a mocap loss for good is worse than this: in flight the complementary
filter's accelerometer sees thrust, not gravity, so the attitude the vehicle holds drifts and the failsafe
descent ends in a wall (README, "The emulated Crazyflie").
"""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import threading
import time
import uuid
from collections import deque
from pathlib import Path

import numpy as np
import pytest

from groundstation.clocks import DEFAULT_RATE_HZ
from groundstation.logread import read_log
from groundstation.mission import load_mission_params
from link.keys import GROUND_STATION_SYSTEM_ID, VehicleKeys
from link.mavlink.codec import IFLAG_SIGNED, ActuatorLimits, Codec, FrameParser
from link.mavlink.signing import ENV_VAR, Signing
from link.mavlink.tlog import read_tlog
from link.messages import AttitudeTarget, CommandKind, Heartbeat, ThrustMoment, VehicleCommand
from link.transports import open_transport
from model.radio import load_radio_profile
from model.vehicle import GRAVITY_MPS2, load_mocap_room, load_vehicle
from simulator.cli import build_parser as build_emulator_parser
from simulator.firmware import load_firmware_params
from simulator.fleet import GroundFrameGate

sys.path.insert(0, str(Path(__file__).resolve().parent))

from testsupport import cfstack, free_port  # noqa: E402

VEHICLE = load_vehicle("crazyflie")
LIMITS = ActuatorLimits.from_vehicle(VEHICLE)
FIRMWARE = load_firmware_params()
MISSION = load_mission_params()
ROOM = load_mocap_room("vicon")
MODE = "attitude"  # the firmware holds the last attitude setpoint until its watchdog levels it
PERIOD_S = 1.0 / DEFAULT_RATE_HZ[MODE]
RADIO = "lab"  # 20..26 ms each way, 1 % loss
PROFILE = load_radio_profile(RADIO)
MAX_LATENCY_S = PROFILE.base_latency_s + PROFILE.jitter_bounds_s[1]
SEED = 3
# An empty room with room to coast: after a radio cut the vehicle flies on, level, at ~3 m/s for 1.5 s.
WORLD = {"bounds": {"extents": [-1.0, 12.0, -3.0, 3.0, 0.0, 3.0]}, "blocks": [],
         "start": [0.0, 0.0, 1.0], "goal": [3.0, 0.0, 1.0]}
PLAN_ARGS = ("--speed", "2", "--accel", "4")  # a brisk dash: ~16 degrees of tilt while accelerating
CUT_AT_S = 2.0  # simulated time: the dash is accelerating (about 1 s after tracking starts)
MIN_TILT_AT_CUT_RAD = np.radians(5.0)  # the scenario is only meaningful if the vehicle is tilted then
TIMEOUT_S = 120
PHYSICS_STEP_S = 1.0 / build_emulator_parser().get_default("physics_rate")  # what `fly` runs the emulator at
FIT_SLACK_S = 5e-4  # error of the fall time from two fitted velocity lines (noise-free truth)


@pytest.fixture(scope="module")
def world(tmp_path_factory) -> Path:
    path = tmp_path_factory.mktemp("world") / "dash.json"
    path.write_text(json.dumps(WORLD))
    return path


def fly(world: Path, folder: Path, *extra: str, radio: str = RADIO, env: dict | None = None):
    """`cfstack fly` with the emulator's radio report; (exit code, summary, states log, radio report)."""
    report = folder / "radio.json"
    folder.mkdir(parents=True, exist_ok=True)  # the emulator child checks the ledger's folder as it starts
    run = cfstack("fly", str(world), "--firmware", "ideal", "--mode", MODE, "--radio", radio, "--clock", "lockstep",
                  "--seed", str(SEED),
                  "--json", "--log", str(folder / "log"), "--id", f"fs{uuid.uuid4().hex[:8]}", *PLAN_ARGS,
                  f"--emulator-arg=--radio-ledger={report}", *extra, env=env)
    assert run.stdout.strip(), run.stderr
    return run.returncode, json.loads(run.stdout), read_log(folder / "log"), json.loads(report.read_text())


def tilt_rad(log) -> np.ndarray:
    """Angle between the body thrust axis and world up: cos(tilt) = 1 - 2 (qx^2 + qy^2)."""
    q = log.vec("truth_qw", "truth_qx", "truth_qy", "truth_qz")
    return np.arccos(np.clip(1.0 - 2.0 * (q[:, 1] ** 2 + q[:, 2] ** 2), -1.0, 1.0))


def first_time(log, phase: str, after_s: float = -np.inf) -> float:
    rows = np.flatnonzero((log.phase == phase) & (log.t_s > after_s))
    assert rows.size, f"no '{phase}' row after t={after_s} s (phases: {sorted(set(log.phase))})"
    return float(log.t_s[rows[0]])


def line_fit(t: np.ndarray, y: np.ndarray) -> tuple[float, float]:
    """(intercept, slope) of the least-squares line y = a + b t."""
    assert len(t) >= 4, "too few samples to fit a line"
    slope, intercept = np.polyfit(t, y, 1)
    return float(intercept), float(slope)


def attitude_settle_time_s() -> float:
    """Five time constants of the slowest roll/pitch mode of the firmware's attitude loop: per unit
    inertia, theta'' = -k_R theta - k_w theta' (small angles), poles s^2 + k_w s + k_R = 0."""
    slowest = np.inf
    for k_r, k_w in zip(FIRMWARE.k_r_per_s2[:2], FIRMWARE.k_w_per_s[:2], strict=True):
        disc = k_w**2 - 4.0 * k_r
        rate = (k_w - np.sqrt(disc)) / 2.0 if disc > 0 else k_w / 2.0
        slowest = min(slowest, rate)
    return 5.0 / slowest


# --- radio cut ------------------------------------------------------------------------------------


@pytest.fixture(scope="module")
def radio_cut(world, tmp_path_factory):
    """One flight, a radio cut for good at CUT_AT_S; checked by two tests."""
    return fly(world, tmp_path_factory.mktemp("radio_cut"), f"--emulator-arg=--cut-radio={CUT_AT_S}")


def last_setpoint_arrival_s(log, report) -> float:
    """When the vehicle received its last setpoint: the ground station's frames (tlog, in send order)
    matched one to one with the uplink radio's ledger (same order: frames offered before the cut)."""
    frames = read_tlog(log.folder / "link.mavlink.tlog", FrameParser(LIMITS))
    sent = [d for _, d in frames if d.system_id == GROUND_STATION_SYSTEM_ID]
    ledger = report["vehicles"]["1"]["uplink"]["ledger"]
    assert 0 < len(ledger) < len(sent)
    assert [entry[1] for entry in ledger] == [len(d.frame) for d in sent[:len(ledger)]]
    arrivals = [entry[3][0] for entry, d in zip(ledger, sent, strict=False)
                if isinstance(d.message, AttitudeTarget) and entry[2] is None and entry[3]]
    return max(arrivals)


def test_radio_cut_drops_every_frame_both_ways_and_the_ground_station_reports_the_silent_downlink(radio_cut):
    code, summary, log, report = radio_cut
    assert code == 1 and summary["result"] == "failsafe"
    assert "downlink" in summary["failsafe_reason"]
    v1 = report["vehicles"]["1"]
    for direction in ("uplink", "downlink"):
        assert v1[direction]["cut"] > 0
        assert max(entry[0] for entry in v1[direction]["ledger"]) < CUT_AT_S  # nothing offered after the cut

    # The ground station hears its last downlink frame when the radio delivers it (<= the link latency
    # after the cut), and gives up downlink_silent_after_s later, at its next tick.
    last_heard_s = max(max(entry[3]) for entry in v1["downlink"]["ledger"] if entry[3])
    detected_s = first_time(log, "done", after_s=CUT_AT_S)
    silent_s = MISSION.downlink_silent_after_s
    assert last_heard_s + silent_s < detected_s <= last_heard_s + silent_s + 2 * PERIOD_S
    assert silent_s < detected_s - CUT_AT_S <= silent_s + MAX_LATENCY_S + 2 * PERIOD_S
    # after the failsafe the log goes on (phase done, truth logged) long enough to see the watchdog act
    assert log.t_s[-1] >= detected_s + MISSION.failsafe_observe_s - PERIOD_S
    done = log.phase == "done"
    assert np.isfinite(log.columns["truth_z_m"][done]).all() and np.isnan(log.columns["ref_x_m"][done]).all()
    print(f"radio cut at {CUT_AT_S:.3f} s: downlink last heard {last_heard_s:.3f} s, "
          f"ground station failsafe at {detected_s:.3f} s ({detected_s - CUT_AT_S:.3f} s after the cut)")


def test_after_a_radio_cut_the_vehicle_levels_at_0_5_s_and_stops_its_motors_at_2_s(radio_cut):
    _, _, log, report = radio_cut
    t, tilt = log.t_s, tilt_rad(log)
    z, vz = log.columns["truth_z_m"], log.columns["truth_vz_mps"]
    t_sp = last_setpoint_arrival_s(log, report)
    assert CUT_AT_S - PERIOD_S - MAX_LATENCY_S < t_sp <= CUT_AT_S + MAX_LATENCY_S
    t_level = t_sp + FIRMWARE.watchdog_level_timeout_s
    t_off = t_sp + FIRMWARE.watchdog_shutdown_timeout_s
    assert log.t_s[-1] > t_off + 0.3  # the log covers the shutdown

    # Until the level timeout the vehicle holds its last attitude setpoint: still tilted.
    tilt_at_sp = float(np.interp(t_sp, t, tilt))
    assert tilt_at_sp >= MIN_TILT_AT_CUT_RAD
    holding = (t > t_sp) & (t <= t_level - PERIOD_S)
    assert holding.sum() >= 0.8 * (t_level - t_sp) / PERIOD_S - 2 and (tilt[holding] >= 0.8 * tilt_at_sp).all()
    # Then it levels: 10 % of the tilt gone within sqrt(0.2 / k_R) (theta'' = -k_R theta from rest; twice
    # that for the damping), then level within five time constants of the attitude loop.
    held = float(np.interp(t_level, t, tilt))
    onset = float(t[np.flatnonzero((t > t_level) & (tilt < 0.9 * held))[0]])
    assert onset <= t_level + 2.0 * np.sqrt(0.2 / min(FIRMWARE.k_r_per_s2[:2])) + PERIOD_S
    settle_s = attitude_settle_time_s()
    level = (t >= t_level + settle_s) & (t < t_off)
    assert level.sum() > 10 and (tilt[level] <= 0.05 * held).all()

    # Motors running until t_off: about the last thrust, level (|a_z| well below g), well above the floor.
    before = (t >= t_level + settle_s) & (t <= t_off - 2 * PERIOD_S)
    a0, a1 = line_fit(t[before], vz[before])
    assert abs(a1) < 0.25 * GRAVITY_MPS2 and (z[before] > 0.3).all()
    # Motors off: free fall, a_z = -g (no thrust, no rotor drag), until it meets the floor.
    falling = (t >= t_off + 2 * PERIOD_S) & (t <= t_off + 0.3) & (z > 0.05)
    b0, b1 = line_fit(t[falling], vz[falling])
    assert b1 == pytest.approx(-GRAVITY_MPS2, rel=0.03)
    # The fall starts where the two velocity lines meet: at t_off (+ half the motor lag, which the
    # thrust ~ w^2 decays with), late by at most a physics step (a frame is handed to the vehicle at the
    # start of the step it is due in), a firmware tick (the watchdog is checked once a tick) and a truth
    # period (a log row holds the newest truth sample), less FIT_SLACK_S for the line fits.
    fall_s = (b0 - a0) / (a1 - b1)
    expected = t_off + VEHICLE.motor_time_constant_s / 2.0
    late_s = PHYSICS_STEP_S + 1.0 / FIRMWARE.commander_rate_hz + 1.0 / FIRMWARE.truth_rate_hz
    assert -FIT_SLACK_S <= fall_s - expected <= late_s + FIT_SLACK_S
    print(f"last setpoint received {t_sp:.4f} s (cut {CUT_AT_S} s), tilt then {np.degrees(tilt_at_sp):.1f} deg; "
          f"levelling from {onset - t_sp:.3f} s after it (watchdog {FIRMWARE.watchdog_level_timeout_s} s), "
          f"level (< {np.degrees(0.05 * held):.2f} deg) by {settle_s:.2f} s later; "
          f"falling from {fall_s - t_sp:.4f} s after it (watchdog {FIRMWARE.watchdog_shutdown_timeout_s} s), "
          f"a_z {b1:.3f} m/s^2")


# --- mocap cuts -----------------------------------------------------------------------------------

# The estimator fuses a mocap sample once the IMU stream (one downlink latency behind) reaches its time;
# mocap age is the ground station's clock minus the newest fused sample's time (clock offset from
# TIMESYNC, uncertain by the radio's jitter). The last sample before a cut is up to a mocap period plus
# the mocap latency older than the cut; the failsafe acts at the first control tick past its threshold.
MOCAP_TOLERANCE_S = ROOM.latency_s + 1.0 / ROOM.rate_hz + PERIOD_S + 2.0 * PROFILE.jitter_bounds_s[1]


def test_a_half_second_mocap_cut_holds_after_0_2_s_then_the_mission_resumes_and_completes(world, tmp_path):
    duration_s = 0.5
    code, summary, log, report = fly(world, tmp_path, f"--emulator-arg=--cut-mocap={CUT_AT_S}:{duration_s}")
    assert code == 0 and summary["result"] == "reached_goal", summary
    cut = report["vehicles"]["1"]["mocap_cut"]
    assert 0.9 * duration_s * ROOM.rate_hz <= cut <= duration_s * ROOM.rate_hz + 1

    hold_s = first_time(log, "failsafe_hold")
    assert abs(hold_s - (CUT_AT_S + MISSION.mocap_hold_after_s)) <= MOCAP_TOLERANCE_S
    resumed_s = float(log.t_s[np.flatnonzero((log.t_s > hold_s) & (log.phase != "failsafe_hold"))[0]])
    assert log.phase[log.t_s == resumed_s][0] == "track"
    back_s = CUT_AT_S + duration_s  # first mocap frame published at or after this
    assert back_s <= resumed_s <= back_s + 1.0 / ROOM.rate_hz + ROOM.latency_s + MAX_LATENCY_S + 2 * PERIOD_S
    assert "failsafe_descent" not in set(log.phase)
    assert summary["rms_tracking_error_m"] < 0.5  # it went on tracking, not drifting off
    print(f"mocap cut {CUT_AT_S}..{back_s} s: hold at {hold_s:.3f} s (+{hold_s - CUT_AT_S:.3f} s), "
          f"resumed at {resumed_s:.3f} s (+{resumed_s - back_s:.3f} s after mocap returned)")


@pytest.fixture(scope="module")
def mocap_lost(world, tmp_path_factory):
    """One flight, mocap cut for good at CUT_AT_S; checked by two tests."""
    return fly(world, tmp_path_factory.mktemp("mocap_lost"), f"--emulator-arg=--cut-mocap={CUT_AT_S}")


def test_mocap_lost_for_good_holds_after_0_2_s_and_descends_after_1_s(mocap_lost):
    _, summary, log, report = mocap_lost
    assert summary["result"] in ("failsafe", "crashed") and "mocap lost" in summary["failsafe_reason"]
    assert report["vehicles"]["1"]["mocap_cut"] > 0
    hold_s = first_time(log, "failsafe_hold")
    descent_s = first_time(log, "failsafe_descent")
    assert abs(hold_s - (CUT_AT_S + MISSION.mocap_hold_after_s)) <= MOCAP_TOLERANCE_S
    assert abs(descent_s - (CUT_AT_S + MISSION.mocap_descend_after_s)) <= MOCAP_TOLERANCE_S
    assert set(log.phase[(log.t_s > hold_s) & (log.t_s < descent_s)]) == {"failsafe_hold"}
    # the descent is the vehicle's own LAND: no more setpoints from the drifting estimate, and it comes down
    descending = log.phase == "failsafe_descent"
    assert np.all(np.isnan(log.columns["ref_z_m"][descending]))
    assert np.all(np.isnan(log.columns["cmd_thrust_n"][descending]))
    z = log.columns["truth_z_m"][descending]
    assert z[-1] < z[0] - 0.5
    print(f"mocap lost at {CUT_AT_S} s: hold at {hold_s:.3f} s (+{hold_s - CUT_AT_S:.3f} s), "
          f"descent at {descent_s:.3f} s (+{descent_s - CUT_AT_S:.3f} s)")


def test_mocap_lost_for_good_lands_softly_and_disarms(mocap_lost):
    code, summary, log, report = mocap_lost
    assert report["vehicles"]["1"]["crash"] is None
    assert summary["result"] == "failsafe" and not summary["collided"]
    phases = list(dict.fromkeys(log.phase))
    assert phases[-3:] == ["failsafe_descent", "disarm", "done"]
    on_floor = log.columns["truth_z_m"] <= WORLD["bounds"]["extents"][4] + 1e-3
    first = np.flatnonzero(on_floor & (log.t_s > CUT_AT_S))[0]
    assert abs(log.columns["truth_vz_mps"][first - 1]) <= FIRMWARE.contact.landing_speed_max_mps


# --- signing and a rogue publisher --------------------------------------------------------------------

REPLAY_DELAY_S = 0.3  # wall time: by then the vehicle has accepted newer frames of the ground station
INJECT_PERIOD_S = 0.01  # wall time between unsigned injections


class Rogue(threading.Thread):
    """Another publisher on the vehicle's uplink key, without the key: it injects unsigned commands
    (zero thrust with full moments, DISARM) and replays the ground station's signed frames it overheard."""

    def __init__(self, endpoint: str, keys: VehicleKeys):
        super().__init__(daemon=True)
        self.transport = open_transport(f"zenoh:{endpoint}", tx=keys.uplink, rx=keys.uplink)
        self.codec = Codec(GROUND_STATION_SYSTEM_ID, limits=LIMITS)  # impersonates the ground station, unsigned
        self.vehicle_id = keys.vehicle_id
        self.stopping = threading.Event()
        self.unsigned_sent = 0
        self.replays_sent = 0
        self.captured: deque[tuple[float, bytes]] = deque()
        self.seen: set[bytes] = set()

    @property
    def sent(self) -> int:
        return self.unsigned_sent + self.replays_sent

    def attack_frame(self) -> bytes:
        if self.unsigned_sent % 2:
            return self.codec.encode(VehicleCommand(0.0, CommandKind.DISARM), self.vehicle_id)
        return self.codec.encode(ThrustMoment(0.0, 0.0, tuple(VEHICLE.max_moment_nm)), self.vehicle_id)

    def run(self) -> None:
        next_inject = 0.0
        while not self.stopping.is_set():
            for frame in self.transport.receive(0.002):
                if frame[2] & IFLAG_SIGNED and frame not in self.seen:  # the ground station's (ours are unsigned)
                    self.seen.add(frame)
                    self.captured.append((time.monotonic(), frame))
            if not self.seen:
                continue  # strike once the ground station flies
            now = time.monotonic()
            if now >= next_inject:
                self.transport.send(self.attack_frame())
                self.unsigned_sent += 1
                next_inject = now + INJECT_PERIOD_S
            while self.captured and now - self.captured[0][0] >= REPLAY_DELAY_S:
                self.transport.send(self.captured.popleft()[1])
                self.replays_sent += 1

    def stop(self) -> None:
        self.stopping.set()
        self.join(timeout=10)
        self.transport.close()


def test_signed_flight_ignores_a_rogue_publishers_unsigned_and_replayed_frames(world, tmp_path):
    env = {**os.environ, ENV_VAR: f"failsafe-test-{uuid.uuid4().hex}"}
    radio = "ideal"  # no random radio draws: rogue frames offered to the radio cannot shift the flight's own
    # Reference: the same flight, signed at both ends, without the rogue.
    code, reference, _, _ = fly(world, tmp_path / "reference", radio=radio, env=env)
    assert code == 0 and reference["result"] == "reached_goal"

    endpoint = f"tcp/127.0.0.1:{free_port()}"
    prefix = f"fs{uuid.uuid4().hex[:8]}"
    report_path = tmp_path / "radio.json"
    emulator = subprocess.Popen(
        [sys.executable, "-m", "cfstack", "emulator", "--listen", endpoint, "--clock", "lockstep", "--radio", radio,
         "--firmware", "ideal", "--seed", str(SEED), "--id", prefix, "--world", str(world), "--airborne", "--quiet",
         "--radio-ledger", str(report_path)],
        stdin=subprocess.DEVNULL, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True, env=env)
    rogue = None
    try:
        rogue = Rogue(endpoint, VehicleKeys(prefix, 1))
        rogue.start()
        log = tmp_path / "rogue"
        # as `fly --firmware ideal` flies it: the course model, no extpose (the ideal vehicle reads the truth)
        run = cfstack("groundstation", "--world", str(world), "--connect", endpoint, "--id", prefix,
                      "--clock", "lockstep", "--mode", MODE, "--vehicle-model", "crazyflie", "--no-extpose",
                      "--json", "--log", str(log), *PLAN_ARGS, env=env)
    finally:
        if rogue is not None:
            rogue.stop()
        time.sleep(0.3)  # let the emulator take in the rogue's last samples
        emulator.send_signal(signal.SIGINT)
        _, err = emulator.communicate(timeout=30)
    assert run.returncode == 0, run.stderr
    summary = json.loads(run.stdout)
    assert summary["result"] == "reached_goal"
    assert rogue.unsigned_sent > 20 and rogue.replays_sent > 20  # it did attack, during the flight
    # Nothing the rogue sent was applied: the flight is the reference flight, tick for tick.
    assert (log / "states.csv").read_bytes() == (Path(reference["log_dir"]) / "states.csv").read_bytes()
    assert summary["rms_tracking_error_m"] == reference["rms_tracking_error_m"]

    v1 = json.loads(report_path.read_text())["vehicles"]["1"]
    parser = v1["uplink_parser"]
    # every rogue sample was told apart on arrival (none counted as the ground station's) ...
    assert v1["uplink_foreign"] == rogue.sent
    # ... and rejected by the vehicle, unless still in the radio when the flight ended (ideal radio: no loss)
    assert 0 < parser["unsigned_rejected"] <= rogue.unsigned_sent
    assert 0 < parser["replays_rejected"] <= rogue.replays_sent
    assert parser["bad_signatures"] == 0
    assert parser["signature_failures"] + v1["uplink"]["pending"] == rogue.sent
    # the vehicle accepted exactly the ground station's own frames
    assert parser["frames_ok"] == summary["link"]["uplink_sent"]
    assert "signature failures" in err.strip().splitlines()[-1]
    print(f"rogue: {rogue.unsigned_sent} unsigned and {rogue.replays_sent} replayed frames; vehicle rejected "
          f"{parser['unsigned_rejected']} unsigned, {parser['replays_rejected']} replays "
          f"({v1['uplink']['pending']} still in the radio at the end)")


def test_the_uplink_gate_counts_only_the_ground_stations_own_fresh_signed_frames():
    key, other_key = bytes(range(32)), bytes(range(1, 33))
    beat = Heartbeat(armed=False, is_ground_station=True)
    ground = Codec(GROUND_STATION_SYSTEM_ID, limits=LIMITS, signing=Signing(key))
    gate = GroundFrameGate(require_signed=True, signing=Signing(key))
    first, second = ground.encode(beat), ground.encode(beat)
    assert gate.count(first) == 1 and gate.count(second) == 1
    assert gate.count(first) == 0  # a replay
    unsigned = Codec(GROUND_STATION_SYSTEM_ID, limits=LIMITS).encode(beat)
    assert gate.count(unsigned) == 0
    assert gate.count(Codec(GROUND_STATION_SYSTEM_ID, limits=LIMITS, signing=Signing(other_key)).encode(beat)) == 0
    assert gate.count(Codec(7, limits=LIMITS, signing=Signing(key)).encode(beat)) == 0  # not the ground station
    assert gate.count(ground.encode(beat) + ground.encode(beat)) == 2  # two frames in one sample
    unsigned_gate = GroundFrameGate(require_signed=False)
    assert unsigned_gate.count(unsigned) == 1
    assert unsigned_gate.count(b"not a mavlink frame") == 0


@pytest.mark.parametrize("option", ["--cut-radio=x", "--cut-mocap=2:0", "--cut-radio=-1", "--cut-mocap=1:2:3"])
def test_a_bad_cut_option_is_one_line_and_exit_code_2(option):
    run = cfstack("emulator", option, timeout=60)
    assert run.returncode == 2 and len(run.stderr.strip().splitlines()) == 1 and "--cut-" in run.stderr
